"""Harmonic fit h(t) = C cos ωt + D sin ωt + E for every window at once (thesis 5.29-5.46).

Per window: linear least squares for [C, D, E] at the periodogram frequency (5.32-5.35), then
Gauss-Newton on [C, D, E, ω] with optimistix (5.36-5.41), then the variance factor (5.42),
the parameter covariance (5.43), σ_A by the delta method (5.44-5.45) and the residual σ (5.46).
The kernel is written for one window and batched with `jax.vmap`; a window that fails gets a
status and NaNs, never an exception.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from .._jax import persistent_jit
from .._shapes import bucket, chunk_rows, pow2_at_most
from .._sincos import sincos
from ..series import Windows

__all__ = [
    "HarmonicFit",
    "fit_harmonic",
    "fit_harmonics",
    "N_PARAMS",
    "batch_windows",
    "gauss_newton",
    "normal_equations",
]

N_PARAMS = 4
# Step tolerances of Gauss-Newton, in units of each parameter's σ and of the noise σ (the
# problem is scaled, see `fit_harmonic`). Gauss-Newton converges linearly here at a rate of
# about 2σ/(A √n) per step, so once a step is below 1e-2 σ the remaining error is far smaller
# (on workload W at most 1.4e-3 σ from the loop of scipy's 'lm'; with the start step of
# `fit_harmonic` every window takes the minimum of 2 evaluations, and a vmapped loop runs as
# many steps as its slowest window).
RTOL = 1e-2
ATOL = 1e-2
MAX_STEPS = 30
_CHUNK_CELLS = 1 << 18  # ~200 windows a call
# Windows solved together inside a call. A vmapped Gauss-Newton loop carries the residuals and
# the linearised model of every window it holds and rewrites them on every step; ~64 windows
# of ~1000 samples (0.5 MB an array) stay in a core's L2 cache, a whole call's ~200 do not.
# `jax.lax.map` runs these groups one after the other, each stopping when its own windows
# have converged: on workload W the fit takes 1.5x less CPU time than one vmap over the call
# (`experiments/bench_fit.py`).
_GROUP_CELLS = 1 << 16


@jax.custom_jvp
def _model(p, t):
    s, c = sincos(p[3] * t)
    return p[0] * c + p[1] * s + p[2]


@_model.defjvp
def _model_jvp(primals, tangents):
    # The Jacobian columns (5.40) reuse the primal's sines and cosines: no autodiff through
    # the polynomial kernels, and linearising costs a few multiply-adds per sample.
    p, t = primals
    dp, dt = tangents
    s, c = sincos(p[3] * t)
    out = p[0] * c + p[1] * s + p[2]
    slope = -p[0] * s + p[1] * c
    return out, c * dp[0] + s * dp[1] + dp[2] + slope * (t * dp[3] + p[3] * dt)


def normal_equations(cols, w, y):
    """GᵀWG and GᵀWy for design columns ``cols`` (explicit sums: XLA fuses them, while a batched
    (sample x param) matmul is slow on the CPU)."""
    k = len(cols)
    wc = [w * c for c in cols]
    gtg = [[None] * k for _ in range(k)]
    for i in range(k):
        for j in range(i, k):
            gtg[i][j] = gtg[j][i] = jnp.sum(wc[i] * cols[j])
    return jnp.stack([jnp.stack(row) for row in gtg]), jnp.stack([jnp.sum(a * y) for a in wc])


def gauss_newton(residual, n_params: int, rtol: float, atol: float, max_steps: int, has_aux: bool = False):
    """The Gauss-Newton solve of every fit: optimistix from 0 on a problem scaled to units of σ.

    ``residual(u, None)`` is the weighted residual in units of the noise σ at the parameters
    ``p0 + u * scale`` (the caller's start and scale), so that ``rtol``/``atol`` mean "a step
    below that many σ". Failure is a value (``sol.result``), never an exception, so a vmapped
    solve reports per window. With ``has_aux``, ``residual`` returns (residual, aux) and
    ``sol.state.aux`` is the aux at the solution.
    """
    import lineax as lx  # imported when a kernel is traced (a traced kernel is kept on disk)
    import optimistix as optx

    solver = optx.GaussNewton(rtol=rtol, atol=atol, linear_solver=lx.Normal(lx.Cholesky()))
    return optx.least_squares(
        residual, solver, jnp.zeros(n_params), has_aux=has_aux, max_steps=max_steps, throw=False
    )


def fit_harmonic(t, y, w, omega0, rtol=RTOL, atol=ATOL, max_steps=MAX_STEPS, refine=False):
    """Fit one window. Arrays are (sample,); ``w`` are weights (1/variance, 0 = masked).

    Returns a dict of scalars: C, D, E (the mean of y added back), omega, A, phase, their
    covariance ``cov`` (param param), sigma_A, sigma_omega, variance factor s0sq, residual σ,
    n, number of Gauss-Newton steps and ``ok`` (solver converged and numbers finite); and the
    ``residual`` y - model at the estimates (sample,), 0 where masked, from the same pass (the
    residual statistics need it: no second evaluation of the model in numpy).

    With ``refine``, the estimates take one Newton step more, from sums of the covariance pass
    (no further pass over the samples; `_newton_step`). Gauss-Newton converges linearly here,
    at about 2σ/(A √n) a step, so the loop's endpoint (its last step below ``rtol`` σ) lies
    ~1e-2 σ times that rate from the optimum: 1e-4 to 2e-3 σ on whole records; the Newton step
    takes it to ~1e-5 σ. The covariance, σ0² and the residual σ stay those of the loop's
    endpoint: the sum of squares is stationary at the optimum, so they move by ~(1e-3)²
    relative at most.
    """
    valid = w > 0
    sw = jnp.sqrt(w)
    n = jnp.sum(valid)
    ybar = jnp.sum(w * y) / jnp.sum(w)
    yc = jnp.where(valid, y - ybar, 0.0)  # centring y conditions the offset column

    # Linear least squares at the periodogram frequency (5.33-5.35 with R^-1 = diag(w)).
    s0, c0 = sincos(omega0 * t)
    gtg, gty = normal_equations([c0, s0, jnp.ones_like(t)], w, yc)
    lin = jnp.linalg.solve(gtg, gty)

    # One Gauss-Newton step on all four parameters from the linear fit, with the sines and
    # cosines already at hand (no new evaluation): the periodogram's peak is within ~0.3 σ of
    # the optimum, so this lands within ~1e-2 σ, and the optimistix loop below takes the two
    # evaluations it needs to confirm convergence instead of three. A step longer than a
    # quarter cycle over the window (a start far from any optimum) is not taken.
    r_lin = yc - (lin[0] * c0 + lin[1] * s0 + lin[2])
    cols = [c0, s0, jnp.ones_like(t), t * (-lin[0] * s0 + lin[1] * c0)]
    jtj0, jtr0 = normal_equations(cols, w, jnp.where(valid, r_lin, 0.0))
    step = jnp.linalg.solve(jtj0, jtr0)
    span = jnp.max(jnp.where(valid, jnp.abs(t), 0.0))
    near = jnp.all(jnp.isfinite(step)) & (jnp.abs(step[3]) * span < 0.5 * jnp.pi)
    p0 = jnp.concatenate([lin, jnp.atleast_1d(omega0)]) + jnp.where(near, step, 0.0)

    # Solve in units of standard deviations: parameters scaled by their approximate σ (linear
    # fit covariance; Fisher information A²/2 Σ w t² for ω) and residuals by the noise σ, so
    # that the tolerances mean "a step below 1e-2 σ" for every window, short or long.
    # The noise is that of the residual after the start step, from the same sums (linearised:
    # Σ w (r − J δ)² = Σ w r² − δ·Jᵀr): the residual at the periodogram's frequency holds the
    # misfit of the frequency too, which on nearly noise-free data would loosen the tolerances.
    rss_lin = jnp.sum(w * r_lin**2)
    rss = jnp.where(near, rss_lin - step @ jtr0, rss_lin)
    rss = jnp.maximum(rss, 1e-20 * rss_lin)
    noise = jnp.sqrt(jnp.maximum(rss / jnp.maximum(n - N_PARAMS, 1), 1e-300))
    sig_lin = noise * jnp.sqrt(jnp.abs(jnp.diag(jnp.linalg.inv(gtg))))
    amp0 = jnp.maximum(jnp.hypot(lin[0], lin[1]), 1e-300)
    sig_om = noise / (amp0 * jnp.sqrt(0.5 * jnp.sum(w * t**2)))
    scale = jnp.concatenate([sig_lin, jnp.atleast_1d(sig_om)])

    def residual(u, _):
        return sw * (yc - _model(p0 + u * scale, t)) / noise

    import optimistix as optx  # imported when the kernel is traced

    sol = gauss_newton(residual, N_PARAMS, rtol, atol, max_steps)
    p = p0 + sol.value * scale

    # Jacobian of the model (5.40, with t_i in every row), covariance (5.42-5.43).
    s, c = sincos(p[3] * t)
    r = yc - (p[0] * c + p[1] * s + p[2])
    jtj, jtr = normal_equations([c, s, jnp.ones_like(t), t * (-p[0] * s + p[1] * c)], w, r)
    dof = n - N_PARAMS
    s0sq = jnp.sum(w * r**2) / dof
    cov = s0sq * jnp.linalg.inv(jtj)
    sigma_res = jnp.sqrt(jnp.sum(jnp.where(valid, r, 0.0) ** 2) / dof)  # (5.46)
    if refine:  # one Newton step from the same pass (see the docstring)
        last = _newton_step(p, t, w, r, s, c, jtj, jtr, span)
        slope = -p[0] * s + p[1] * c
        r = r - (last[0] * c + last[1] * s + last[2] + t * slope * last[3])  # at p + last, to O(last²)
        p = p + last
    amp = jnp.hypot(p[0], p[1])
    alpha = jnp.stack([p[0], p[1]]) / amp  # (5.45)
    var_a = alpha @ cov[:2, :2] @ alpha  # (5.44)
    out = dict(
        C=p[0],
        D=p[1],
        E=p[2] + ybar,
        omega=p[3],
        A=amp,
        phase=jnp.arctan2(p[1], p[0]),
        cov=cov,
        sigma_A=jnp.sqrt(var_a),
        sigma_omega=jnp.sqrt(cov[3, 3]),
        s0sq=s0sq,
        sigma_res=sigma_res,
        n=n,
        steps=sol.stats["num_steps"],
        residual=jnp.where(valid, r, 0.0),
    )
    finite = jnp.all(jnp.isfinite(p)) & jnp.isfinite(var_a) & (var_a >= 0) & (cov[3, 3] >= 0)
    out["ok"] = (sol.result == optx.RESULTS.successful) & finite
    return out


def _newton_step(p, t, w, r, s, c, jtj, jtr, span):
    """Newton's step on ½ Σ w r² at ``p``, from the Gauss-Newton sums ``jtj``, ``jtr`` and the
    second derivatives of the model (only those with ω are not 0): H = JᵀWJ − Σ w r ∂²f.

    Newton converges quadratically where Gauss-Newton converges linearly (at a rate that nears
    1 as the amplitude nears the noise), so one step from the loop's endpoint reaches the
    optimum to ~1e-6 σ even on weak records. Where H is not positive definite, or the step
    would be longer than a quarter cycle over the window, the Gauss-Newton step is taken, or
    none.
    """
    wrt = w * r * t
    k03 = -jnp.sum(wrt * s)  # Σ w r ∂²f/∂C∂ω
    k13 = jnp.sum(wrt * c)  # Σ w r ∂²f/∂D∂ω
    k33 = -jnp.sum(wrt * t * (p[0] * c + p[1] * s))  # Σ w r ∂²f/∂ω²
    k = jnp.zeros((N_PARAMS, N_PARAMS)).at[0, 3].set(k03).at[3, 0].set(k03)
    k = k.at[1, 3].set(k13).at[3, 1].set(k13).at[3, 3].set(k33)
    hess = jtj - k
    chol = jnp.linalg.cholesky(hess)
    newton = jax.scipy.linalg.cho_solve((chol, True), jtr)
    gn = jnp.linalg.solve(jtj, jtr)
    step = jnp.where(jnp.all(jnp.isfinite(newton)), newton, gn)
    small = jnp.all(jnp.isfinite(step)) & (jnp.abs(step[3]) * span < 0.5 * jnp.pi)
    return jnp.where(small, step, 0.0)


@persistent_jit(static_argnames=("rtol", "atol", "max_steps", "group", "refine"))
def _fit_batch(t, y, w, omega0, *, rtol, atol, max_steps, group, refine=False):
    """`fit_harmonic` over the leading axis, vmapped in groups of ``group`` windows."""

    def one(args):
        return fit_harmonic(*args, rtol, atol, max_steps, refine)

    return jax.lax.map(one, (t, y, w, omega0), batch_size=group)


@dataclass(frozen=True)
class HarmonicFit:
    """Fitted harmonic of every window (NaN where a window was not fitted).

    Model: y(t) = offset + A cos(2π f0 (t - t_c) - phase), i.e. C = A cos(phase),
    D = A sin(phase), with t_c the time origin of the windows (`Windows.table.t_centre`; the
    estimates table re-references the phase to the window's t_mid).

    Attributes (all (window,) unless noted):
        f0_hz, sigma_f0_hz, amplitude_mm, sigma_amplitude_mm, phase_rad, offset_mm,
        sigma_residual_mm: estimates and σ's (5.42-5.46).
        variance_factor: σ0² (5.42); 1 when weights are 1/variance and the model fits.
        params: (window, param) [C, D, E, ω]; cov: (window, param, param).
        n: valid samples; steps: Gauss-Newton iterations; converged: solver succeeded.
    """

    f0_hz: np.ndarray
    sigma_f0_hz: np.ndarray
    amplitude_mm: np.ndarray
    sigma_amplitude_mm: np.ndarray
    phase_rad: np.ndarray
    offset_mm: np.ndarray
    sigma_residual_mm: np.ndarray
    variance_factor: np.ndarray
    params: np.ndarray
    cov: np.ndarray
    n: np.ndarray
    steps: np.ndarray
    converged: np.ndarray


def _weights(w: Windows, weights: np.ndarray | None, rows: np.ndarray) -> np.ndarray:
    """Per-sample weights of ``rows``: 1 (or the given weight) where valid, 0 where masked."""
    if weights is None:
        return w.mask[rows].astype(np.float64)
    return np.where(w.mask[rows], weights[rows], 0.0)


def _width(a: np.ndarray, s: int) -> np.ndarray:
    """``a`` (window, sample) cut or zero-padded to ``s`` samples."""
    if a.shape[1] >= s:
        return a[:, :s]
    return np.concatenate([a, np.zeros((a.shape[0], s - a.shape[1]), a.dtype)], axis=1)


def batch_windows(
    fit_batch,
    w: Windows,
    rows: np.ndarray,
    weights: np.ndarray | None,
    *per_window: np.ndarray,
    group_cells: int = _GROUP_CELLS,
) -> dict[str, np.ndarray]:
    """Run a batched kernel on the windows at ``rows``, chunk by chunk, in few compiled shapes.

    ``fit_batch(t, y, w, *per_window, group=G)`` takes (window, sample) arrays and (window, ...)
    arrays and returns a dict of (window, ...) arrays; ``per_window`` are indexed by window of
    ``w``; G windows of about ``group_cells`` samples in all are solved together. Returns the
    dict for ``rows`` (in their order), as numpy arrays.
    """
    s_used = int(w.mask[rows].sum(axis=1).max())
    # Valid samples come first in every row; pad the sample axis to a shape bucket and
    # the batch to a power of two so that few shapes are ever compiled.
    s_pad = bucket(s_used)
    chunk = chunk_rows(rows.size, _CHUNK_CELLS // s_pad)
    group = min(chunk, pow2_at_most(group_cells // s_pad))
    res: dict[str, np.ndarray] = {}
    for c0 in range(0, rows.size, chunk):
        sel = rows[c0 : c0 + chunk]
        pad = np.concatenate([sel, np.repeat(sel[:1], chunk - sel.size)])
        out = fit_batch(
            _width(w.t[pad], s_pad),  # numpy arrays straight into the kernel (no eager op)
            _width(w.y[pad], s_pad),
            _width(_weights(w, weights, pad), s_pad),
            *(np.asarray(a)[pad] for a in per_window),
            group=group,
        )
        for k, v in out.items():
            v = np.asarray(v)[: sel.size]
            if k not in res:
                res[k] = np.empty((rows.size,) + v.shape[1:], v.dtype)
            res[k][c0 : c0 + sel.size] = v
    return res


def fit_harmonics(
    w: Windows,
    freq0_hz: np.ndarray,
    rows: np.ndarray | None = None,
    weights: np.ndarray | None = None,
    rtol: float = RTOL,
    atol: float = ATOL,
    max_steps: int = MAX_STEPS,
    refine: bool = False,
    residual: np.ndarray | None = None,
) -> HarmonicFit:
    """Fit the harmonic model to the windows at ``rows`` (default: all), starting at ``freq0_hz``.

    Args:
        w: the windows (times already centred on each window's mid time).
        freq0_hz: (window,) start frequency, e.g. `Periodogram.freq_hz`.
        rows: windows to fit; the others come back NaN and not converged.
        weights: optional (window, sample) weights, 1/σ² per sample (default 1).
        refine: one more Gauss-Newton step from the covariance pass' sums (see
            `fit_harmonic`): estimates within ~1e-6 σ of the optimum instead of ~1e-2 of the
            convergence rate. Whole records take it; the windows keep the loop's endpoint.
        residual: an array shaped like ``w.y`` whose rows at ``rows`` get y - model at the
            estimates (as `jaxdefl.fit.residual_noise.harmonic_residual`, from the fit's own
            last pass; masked samples anything).
    Returns:
        HarmonicFit with one entry per window of ``w``.
    """
    b, s_all = w.t.shape
    rows = np.flatnonzero(w.mask.sum(axis=1) > N_PARAMS) if rows is None else np.asarray(rows)

    res = {
        k: np.full(b, np.nan)
        for k in (
            "C",
            "D",
            "E",
            "omega",
            "A",
            "phase",
            "sigma_A",
            "sigma_omega",
            "s0sq",
            "sigma_res",
        )
    }
    cov = np.full((b, N_PARAMS, N_PARAMS), np.nan)
    n = np.zeros(b, np.int64)
    steps = np.zeros(b, np.int64)
    ok = np.zeros(b, bool)
    if rows.size:
        fit_batch = partial(_fit_batch, rtol=rtol, atol=atol, max_steps=max_steps, refine=refine)
        out = batch_windows(fit_batch, w, rows, weights, 2 * np.pi * np.asarray(freq0_hz))
        for k in res:
            res[k][rows] = out[k]
        cov[rows] = out["cov"]
        if residual is not None:
            width = min(residual.shape[1], out["residual"].shape[1])
            residual[rows, :width] = out["residual"][:, :width]
        n[rows] = out["n"]
        steps[rows] = out["steps"]
        ok[rows] = out["ok"]
    bad = ~ok
    for k in res:
        res[k][bad] = np.nan
    cov[bad] = np.nan
    two_pi = 2 * np.pi
    return HarmonicFit(
        f0_hz=res["omega"] / two_pi,
        sigma_f0_hz=res["sigma_omega"] / two_pi,
        amplitude_mm=res["A"],
        sigma_amplitude_mm=res["sigma_A"],
        phase_rad=res["phase"],
        offset_mm=res["E"],
        sigma_residual_mm=res["sigma_res"],
        variance_factor=res["s0sq"],
        params=np.stack([res["C"], res["D"], res["E"], res["omega"]], axis=-1),
        cov=cov,
        n=n,
        steps=steps,
        converged=ok,
    )
