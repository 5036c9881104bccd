"""The numerics every stage shares: one weighted least squares, one harmonic design, one robust
noise scale and the selection thresholds (numpy; the jitted fits keep their own JAX kernels in
`jaxdefl.fit.harmonic` and `jaxdefl.diagnose._varpro`).

- `wls`: weighted linear least squares r ≈ cols @ beta with nuisance columns among ``cols``
  (the offset and the loading harmonic an effect may re-estimate for free), its covariance from
  the weighted residual.
- `harmonic_design`: the columns [1, cos φ, sin φ] of the thesis' model (5.29) at phase φ = ω t.
- `mad_sigma`, `difference_sigma`: σ of Gaussian noise from the median absolute deviation
  (of the values, or of their first differences: slow structure and outliers barely move it).
- `DELTA_BIC_MAX`, `P_MAX`: the thresholds the diagnosis selects by.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = [
    "DELTA_BIC_MAX",
    "MAD_TO_SIGMA",
    "P_MAX",
    "difference_sigma",
    "harmonic_design",
    "mad_sigma",
    "wls",
]

# ΔBIC = −2 Δlog L + k log N below this is very strong evidence (Kass & Raftery 1995): the bar
# a term must pass to enter the model, and the information gate of the effects.
DELTA_BIC_MAX = -10.0
# a screening p-value above this cannot pass the search's level (α = 0.05 over ~10 effects)
P_MAX = 5e-3
# σ / MAD of a Gaussian: 1 / Φ⁻¹(3/4)
MAD_TO_SIGMA = 1.4826


def wls(cols: np.ndarray, r: np.ndarray, w: np.ndarray | None = None, cov: bool = True):
    """Weighted linear least squares r ≈ cols @ beta.

    Args:
        cols: (sample, k) columns, the nuisance ones included.
        r: (sample,) or (sample, m) for m right-hand sides sharing the columns.
        w: (sample,) weights (1/scale², 0 to skip a sample) or None (all 1).
        cov: compute the covariance (the pseudo-inverse of the normal matrix times σ̂²).
    Returns:
        (beta (k,) or (k, m), cov (k, k) or (m, k, k) with σ̂² from the weighted residual
        (None unless ``cov``), fitted (sample,) or (sample, m)).
    """
    w = np.ones(r.shape[0]) if w is None else w
    gw = cols * w[:, None]
    gtg = gw.T @ cols
    beta = np.linalg.lstsq(gtg, gw.T @ r, rcond=None)[0]
    fitted = cols @ beta
    if not cov:
        return beta, None, fitted
    dof = max(int((w > 0).sum()) - cols.shape[1], 1)
    res = r - fitted
    wr = w * res**2 if res.ndim == 1 else w[:, None] * res**2
    s2 = np.sum(wr, axis=0) / dof
    ginv = np.linalg.pinv(gtg)
    return beta, (float(s2) * ginv if res.ndim == 1 else s2[:, None, None] * ginv), fitted


def harmonic_design(phase: np.ndarray, offset: bool = True) -> np.ndarray:
    """(sample, 3) columns [1, cos φ, sin φ] at the phase ``phase`` (sample,) = ω(t − t_ref);
    (sample, 2) [cos φ, sin φ] without ``offset``."""
    phase = np.asarray(phase, dtype=float)
    c, s = np.cos(phase), np.sin(phase)
    return np.stack([np.ones_like(c), c, s] if offset else [c, s], axis=1)


def mad_sigma(x: np.ndarray, axis: int | None = None):
    """σ of Gaussian values from their median absolute deviation: 1.4826 MAD (a float, or an
    array over the other axes with ``axis``)."""
    x = np.asarray(x, dtype=float)
    if axis is None:
        return MAD_TO_SIGMA * float(np.median(np.abs(x - np.median(x))))
    return MAD_TO_SIGMA * np.median(np.abs(x - np.median(x, axis=axis, keepdims=True)), axis=axis)


def difference_sigma(r: np.ndarray, k: np.ndarray | None = None, min_pairs: int = 8) -> float:
    """σ of the white noise in ``r`` from its first differences: 1.4826 MAD / √2.

    With frame indices ``k`` only the differences of consecutive frames count (a gap would add
    the signal's change over it), unless fewer than ``min_pairs`` are left. 0 for fewer than two
    values.
    """
    d = np.diff(r)
    if k is not None:
        on = d[np.diff(k) == 1]
        d = on if on.size >= min_pairs else d
    return mad_sigma(d) / math.sqrt(2) if d.size else 0.0
