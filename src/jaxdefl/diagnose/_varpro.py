"""Variable projection with optimistix: nonlinear parameters shared by many series, linear
amplitudes per series solved in closed form.

An effect's model on series s is r_s ≈ G_s(θ) β_s + N_s γ_s: columns G_s that depend on a few
nonlinear parameters θ shared by all series (a frequency, a time constant, a jump time, a tap
spread), per-series linear amplitudes β_s and the free nuisance columns N_s (offset, harmonic).
For fixed θ the β's are a weighted linear least squares per series; Levenberg-Marquardt
(optimistix) then minimises the projected residual over θ alone (Golub & Pereyra 1973). The
covariance of θ is σ̂² (JᵀJ)⁻¹ with J the Jacobian of the projected residual, which is the
profile covariance of θ; the β's get their covariance at the fitted θ.

An effect may also carry a term m_s(θ) with no amplitude of its own (``term_fn``: a modulation
depth, a tap spread, a clock offset shared by all series, each series' scale known): then
r_s − m_s(θ) ≈ G_s(θ) β_s + N_s γ_s, with or without effect columns. This is the one nonlinear
solver of the diagnosis: ``bounds`` keep θ in a box (a component with equal bounds stays fixed).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optimistix as optx

from .._jax import float64
from .._shapes import bucket, pow2_at_least

__all__ = ["SharedFit", "fit_shared", "pad_series"]

_RIDGE = 1e-10


@dataclass(frozen=True)
class SharedFit:
    """Result of `fit_shared`.

    Attributes:
        theta, theta_cov: (p,), (p, p) shared nonlinear parameters and their covariance.
        beta, beta_cov: (series, k), (series, k, k) effect amplitudes (nuisance excluded).
        fitted: list of (sample,) fitted effect + nuisance per series (unpadded).
        rss: (series,) weighted residual sum of squares per series.
        converged: the solver succeeded.
        term: list of (sample,) the ``term_fn`` part at θ per series (zeros without one).
    """

    theta: np.ndarray
    theta_cov: np.ndarray
    beta: np.ndarray
    beta_cov: np.ndarray
    fitted: list[np.ndarray]
    rss: np.ndarray
    converged: bool
    term: list[np.ndarray] | None = None

    @property
    def chi2(self) -> float:
        """Σ rss: χ² when the weights are 1/σ² (`fit_shared` with ``known_scale``)."""
        return float(np.sum(self.rss))

    @property
    def cov(self) -> np.ndarray:
        return self.theta_cov


def pad_series(arrays: list[np.ndarray], width: int | None = None, fill: float = 0.0) -> np.ndarray:
    """Stack (sample, ...) arrays into (series, width, ...) padded with ``fill`` (width bucketed)."""
    width = bucket(max(a.shape[0] for a in arrays)) if width is None else width
    out = np.full((len(arrays), width) + arrays[0].shape[1:], fill, dtype=np.float64)
    for i, a in enumerate(arrays):
        out[i, : a.shape[0]] = a
    return out


def _project(g, r, w):
    """Weighted LS of r on the columns g (sample, k): (beta, weighted residual)."""
    sw = jnp.sqrt(w)
    gw = g * sw[:, None]
    k = g.shape[1]
    gtg = gw.T @ gw
    gtg = gtg + (_RIDGE * jnp.trace(gtg) / k + 1e-30) * jnp.eye(k)
    beta = jnp.linalg.solve(gtg, gw.T @ (r * sw))
    return beta, sw * r - gw @ beta


_SOLVERS: dict = {}


def _solver(columns_fn: Callable | None, term_fn: Callable | None, max_steps: int):
    key = (columns_fn, term_fn, max_steps)
    if key in _SOLVERS:
        return _SOLVERS[key]

    def model(theta, t, aux):
        g = columns_fn(theta, t, aux) if columns_fn is not None else jnp.zeros((t.shape[0], 0))
        m = term_fn(theta, t, aux) if term_fn is not None else jnp.zeros_like(t)
        return g, m

    def at(u, theta0, scale, lo, hi):
        return jnp.where(lo == hi, lo, jnp.clip(theta0 + u * scale, lo, hi))

    def residual(u, args):
        theta0, scale, lo, hi, t, r, w, nu, aux, qn = args
        theta = at(u, theta0, scale, lo, hi)

        def one(t, r, w, nu, aux, qn):
            g, m = model(theta, t, aux)
            if columns_fn is None:  # the nuisance alone: its projector, computed once
                x = jnp.sqrt(w) * (r - m)
                return x - qn @ (qn.T @ x)
            return _project(jnp.concatenate([g, nu], axis=1), r - m, w)[1]

        return jax.vmap(one)(t, r, w, nu, aux, qn)

    def basis(w, nu):
        """Orthonormal columns spanning √w·nu (zero columns, e.g. padding, left out)."""
        q, rr = jnp.linalg.qr(nu * jnp.sqrt(w)[:, None])
        d = jnp.abs(jnp.diagonal(rr))
        return q * (d > 1e-12 * (jnp.max(d) + 1e-300))[None, :]

    @jax.jit
    def solve(theta0, scale, lo, hi, t, r, w, nu, aux):
        qn = jax.vmap(basis)(w, nu) if columns_fn is None else nu
        args = (theta0, scale, lo, hi, t, r, w, nu, aux, qn)
        # θ in units of ``scale`` (about one σ or one resolution step): tolerances mean the same
        # for every parameter, and a start from the signature's grid converges in a few steps.
        solver = optx.LevenbergMarquardt(rtol=1e-6, atol=1e-3, linear_solver=lx.Normal(lx.Cholesky()))
        sol = optx.least_squares(
            residual, solver, jnp.zeros_like(theta0), args=args, max_steps=max_steps, throw=False
        )
        u = sol.value
        theta = at(u, theta0, scale, lo, hi)
        jac = jax.jacfwd(lambda v: residual(v, args).reshape(-1))(u) / scale[None, :]

        def one(t, r, w, nu, aux):
            g, m = model(theta, t, aux)
            g = jnp.concatenate([g, nu], axis=1)
            beta, res = _project(g, r - m, w)
            gw = g * jnp.sqrt(w)[:, None]
            return beta, jnp.sum(res**2), jnp.linalg.pinv(gw.T @ gw), g @ beta, m

        beta, rss, ginv, fitted, term = jax.vmap(one)(t, r, w, nu, aux)
        ok = sol.result == optx.RESULTS.successful
        return theta, jac.T @ jac, beta, rss, ginv, fitted, term, ok

    _SOLVERS[key] = solve
    return solve


@float64()
def fit_shared(
    columns_fn: Callable,
    theta0: np.ndarray,
    t: list[np.ndarray],
    r: list[np.ndarray],
    w: list[np.ndarray],
    nuisance: list[np.ndarray],
    aux: dict | None = None,
    scale: np.ndarray | None = None,
    max_steps: int = 40,
    term_fn: Callable | None = None,
    bounds: tuple[np.ndarray, np.ndarray] | None = None,
    known_scale: bool = False,
) -> SharedFit:
    """Fit shared θ and per-series amplitudes by variable projection (Levenberg-Marquardt).

    Args:
        columns_fn: ``columns_fn(theta, t, aux) -> (sample, k)`` effect columns of one series in
            jax.numpy (the same function object each call: its compiled solver is cached), or
            None for a term without amplitudes.
        theta0: (p,) start value (e.g. from a grid search of the signature).
        t, r, w: per series (sample,) times, current residuals, weights (1/scale², 0 skip).
        nuisance: per series (sample, q) free columns (`Context.nuisance`).
        aux: {name: per-series list of (sample,) arrays or (series,) scalars} passed to
            ``columns_fn`` as a dict for the one series (e.g. the harmonic's phase angle).
        scale: (p,) typical size of a step in θ (one σ or one grid step); default |θ0| or 1.
        term_fn: ``term_fn(theta, t, aux) -> (sample,)``, a term of one series with no amplitude
            of its own, subtracted before the projection (jax.numpy, the same object each call).
        bounds: (lo, hi) per component of θ; lo == hi keeps it fixed at that value.
        known_scale: the weights are 1/σ² already: θ's covariance is (JᵀJ)⁻¹, not scaled by σ̂².
    """
    n_series = len(t)
    theta0 = np.asarray(theta0, np.float64)
    scale = np.where(theta0 != 0, np.abs(theta0), 1.0) if scale is None else np.asarray(scale, np.float64)
    width = bucket(max(a.size for a in t))
    # Pad the series axis to a power of two with weightless series: few shapes to compile.
    extra = (pow2_at_least(n_series) if n_series <= 16 else bucket(n_series)) - n_series
    pad = [np.zeros(1)] * extra
    tp, rp, wp = (pad_series(list(x) + pad, width) for x in (t, r, w))
    q = max(a.shape[1] for a in nuisance)  # fewer columns on some series: zero columns (no fit)
    nuisance = [a if a.shape[1] == q else np.pad(a, ((0, 0), (0, q - a.shape[1]))) for a in nuisance]
    nup = pad_series(list(nuisance) + [np.zeros((1, q))] * extra, width)
    auxp = {}
    for name, vals in (aux or {}).items():
        if np.ndim(vals[0]) == 0:
            auxp[name] = np.asarray(list(vals) + [0.0] * extra, np.float64)
        else:
            auxp[name] = pad_series([np.asarray(v, np.float64) for v in vals] + pad, width)
    lo, hi = (np.full(theta0.size, -np.inf), np.full(theta0.size, np.inf)) if bounds is None else bounds
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    solve = _solver(columns_fn, term_fn, max_steps)
    theta, jtj, beta, rss, ginv, fitted, term, ok = solve(
        jnp.asarray(theta0), jnp.asarray(scale), jnp.asarray(lo), jnp.asarray(hi), tp, rp, wp, nup, auxp
    )
    theta, jtj, beta, rss, ginv, fitted, term = (
        np.asarray(a) for a in (theta, jtj, beta, rss, ginv, fitted, term)
    )
    beta, rss, ginv, fitted = beta[:n_series], rss[:n_series], ginv[:n_series], fitted[:n_series]
    k = beta.shape[1] - nup.shape[2]
    n_used = sum(int((x > 0).sum()) for x in w)
    dof = max(n_used - theta.size - beta.size, 1)
    s2 = 1.0 if known_scale else float(rss.sum() / dof)
    theta_cov = s2 * np.linalg.pinv(jtj)
    s2_each = rss / np.maximum(np.array([(x > 0).sum() for x in w]) - beta.shape[1], 1)
    beta_cov = s2_each[:, None, None] * ginv
    return SharedFit(
        theta=theta,
        theta_cov=theta_cov,
        beta=beta[:, :k],
        beta_cov=beta_cov[:, :k, :k],
        fitted=[fitted[i, : a.size] for i, a in enumerate(t)],
        rss=rss,
        converged=bool(ok) and bool(np.all(np.isfinite(theta))),
        term=[term[i, : a.size] for i, a in enumerate(t)],
    )
