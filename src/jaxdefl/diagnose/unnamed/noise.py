"""The open world's noise model: AR(1) noise on the frame clock, σ profiled, ρ per series from
the residual (`ar1_rho`), so coloured noise is not taken for structure; the likelihood gain of a
generic term (`Noise`, `colored_gain`, discounted by the frame correlation's design effect) and
the generalised-least-squares covariance of its parameters (`gls_covariance`)."""

from __future__ import annotations

import math

import numpy as np

from .._base import LOG_2PI, Context, State
from .._correlation import ar1_rho

__all__ = [
    "Noise",
    "ar1_loglik",
    "ar1_rho",
    "ar1_whiten",
    "colored_gain",
    "gls_covariance",
    "linear_sd",
]


def ar1_loglik(r: np.ndarray, k: np.ndarray, rho: float) -> float:
    """Exact Gaussian log-likelihood of r under AR(1) noise on the frame clock k (gaps allowed),
    the innovation σ profiled: e_j = r_j − ρ^g r_{j−1}, var ∝ (1 − ρ^{2g})/(1 − ρ²), g the gap."""
    n = r.size
    if n == 0:
        return -math.inf
    if rho <= 0.0:
        s2 = max(float(np.mean(r * r)), 1e-300)
        return -0.5 * n * (math.log(s2) + LOG_2PI + 1.0)
    g = np.diff(k).astype(np.float64)
    rg = rho**g
    # in units of the innovation variance σ²: the first sample at the stationary 1/(1 − ρ²), the
    # others given the previous one g frames before at (1 − ρ^{2g})/(1 − ρ²) (1 when g = 1)
    v = np.concatenate([[1.0], 1.0 - rg * rg]) / (1.0 - rho * rho)
    e = np.concatenate([r[:1], r[1:] - rg * r[:-1]])
    s2 = max(float(np.mean(e * e / v)), 1e-300)
    return -0.5 * (n * (math.log(s2) + LOG_2PI + 1.0) + float(np.sum(np.log(v))))


def _ar1_of(s, st: State, mean: np.ndarray) -> tuple[float, float]:
    """(AR(1) log-likelihood, ρ̂) of a series' residual about ``mean`` under its state's scale."""
    inl = st.inlier
    z = ((s.y - mean) / st.scale)[inl]
    k = s.k[inl]
    z = z - z.mean()
    rho = ar1_rho(z, k)
    return ar1_loglik(z, k, rho) - (st.log_scale_sum if not st.unit_scale else 0.0), rho


def colored_gain(s, st: State, mean: np.ndarray) -> float | None:
    """Δlog L of a new ``mean`` (same noise model) under AR(1) noise, ρ profiled on each side;
    None when the noise is white on both sides (then the white likelihood holds as it is)."""
    a, ra = _ar1_of(s, st, st.mean)
    b, rb = _ar1_of(s, st, mean)
    if ra == 0.0 and rb == 0.0:
        return None
    return b - a


class Noise:
    """Per series: the inlier times, frames, the scale, and the AR(1) log-likelihood of a mean."""

    def __init__(self, ctx: Context, states: list[State], bases: dict | None = None, corr=None):
        self.ctx = ctx
        self.states = states
        self.corr = corr
        self._base: dict[int, float] = {}
        self.bases = {} if bases is None else bases  # the search's cache of spline bases

    def base(self, i: int) -> float:
        """The log-likelihood of the current mean of series i (cached)."""
        if i not in self._base:
            self._base[i] = self.loglik(i, self.states[i].mean)
        return self._base[i]

    def loglik(self, i: int, mean: np.ndarray) -> float:
        return _ar1_of(self.ctx.series[i], self.states[i], mean)[0]

    def gain(self, means: dict[int, np.ndarray]) -> float:
        """Δlog L of new means of a term over its series, divided by the frame
        correlation's design effect (`_correlation`) when the search has one."""
        dll = {i: self.loglik(i, m) - self.base(i) for i, m in means.items()}
        if self.corr is None:
            return sum(dll.values())
        return self.corr.discount(dll)


def ar1_whiten(x: np.ndarray, k: np.ndarray, rho: float) -> np.ndarray:
    """Rows of x (sample[, column]) prewhitened for AR(1) noise on the frame clock k, in units
    of the innovation σ (the transform whose squared sum is `ar1_loglik`'s quadratic form)."""
    if rho <= 0.0:
        return x
    rg = rho ** np.diff(k).astype(np.float64)
    v = np.concatenate([[1.0], 1.0 - rg * rg]) / (1.0 - rho * rho)
    tail = (slice(None),) + (None,) * (x.ndim - 1)
    out = np.concatenate([x[:1], x[1:] - rg[tail] * x[:-1]])
    return out / np.sqrt(v)[tail]


def gls_covariance(ctx, states, c, blocks, n_shared, corr=None) -> np.ndarray:
    """Covariance of a term's parameters: n_shared shared ones, then each block's own columns.

    ``blocks``: per series (i, J_shared (sample, n_shared), X_own (sample, k)), the Jacobian of
    the series' mean with respect to the parameters. The noise: per series AR(1) (ρ from the
    residual after the term, `ar1_rho`) and its state's scale; the innovation σ² from the
    whitened residual (degrees of freedom removed), so the covariance is the generalised least
    squares one, (Jᵀ Σ⁻¹ J)⁻¹. With ``corr``, the shared block is inflated by the design effect
    of the term's series (noise common to the plates of a frame carries no information twice).
    """
    sizes = [x.shape[1] for _, _, x in blocks]
    p = n_shared + sum(sizes)
    m = np.zeros((p, p))
    off = n_shared
    for (i, js, x), k in zip(blocks, sizes, strict=True):
        s, st = ctx.series[i], states[i]
        inl = st.inlier
        sc = st.scale[inl] if np.ndim(st.scale) else st.scale
        z = ((s.y - c.means[i])[inl]) / sc
        kk = s.k[inl]
        rho = ar1_rho(z - z.mean(), kk)
        j = np.concatenate([js, x], axis=1)[inl] / np.reshape(sc, (-1, 1))
        jw = ar1_whiten(j, kk, rho)
        zw = ar1_whiten(z - z.mean(), kk, rho)
        s2 = float(zw @ zw) / max(zw.size - n_shared / max(len(blocks), 1) - k, 1.0)
        g = jw.T @ jw / s2
        sel = np.r_[np.arange(n_shared), off + np.arange(k)]
        m[np.ix_(sel, sel)] += g
        off += k
    cov = np.linalg.pinv(m, rcond=1e-12, hermitian=True)
    if corr is not None and n_shared:
        f = math.sqrt(corr.design_effect([b[0] for b in blocks]))
        cov[:n_shared, :] *= f
        cov[:, :n_shared] *= f
    return cov


def linear_sd(cov: np.ndarray, grad: np.ndarray) -> float:
    v = float(grad @ cov @ grad)
    return math.sqrt(v) if v > 0 else 0.0
