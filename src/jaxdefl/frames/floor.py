"""Floor-target detection for the first depth threshold (thesis 5.1.1.1-5.1.1.3).

Canny edges of the amplitude image (kornia), 8-connected edge regions and their fake eccentricity
(the kernels of `kernels.py`, on any torch device: a ring round a circular target has a round
moment ellipse), Fitzgibbon's direct ellipse fit through the edge pixels, and the depth at the
ellipse centre by bilinear interpolation. The mean of those depths is the floor level.
"""

from __future__ import annotations

import numpy as np
import torch

from .ellipse import fit_ellipse
from .kernels import label_components, region_stats

__all__ = ["floor_targets", "bilinear"]


def bilinear(img: np.ndarray, u: float, v: float) -> float:
    """Bilinear interpolation of ``img`` (h, w) at column ``u``, row ``v`` (NaN outside)."""
    h, w = img.shape
    if not (0 <= u <= w - 1 and 0 <= v <= h - 1):
        return float("nan")
    u0, v0 = min(int(u), w - 2), min(int(v), h - 2)
    a, b = u - u0, v - v0
    p = img[v0 : v0 + 2, u0 : u0 + 2].astype(np.float64)
    return float((1 - b) * ((1 - a) * p[0, 0] + a * p[0, 1]) + b * ((1 - a) * p[1, 0] + a * p[1, 1]))


def floor_targets(
    amplitude: np.ndarray,
    z_mm: np.ndarray,
    min_axis_px: float = 1.5,
    max_axis_px: float = 40.0,
    min_roundness: float = 0.6,
    device: str = "cpu",
) -> np.ndarray:
    """Circular floor targets in one frame: (target, 3) rows of ellipse centre u, v and depth z.

    Args:
        amplitude: (h, w) amplitude (intensity) image. z_mm: (h, w) depth z in mm.
        device: torch device of the edge detection, labelling and moments.
    Returns:
        (n, 3) float64 array (n may be 0).
    """
    import kornia

    a = torch.as_tensor(np.nan_to_num(amplitude, nan=0.0), dtype=torch.float32, device=device)[None, None]
    a = a / a.amax().clamp_min(1e-12)
    _, edges = kornia.filters.canny(a, low_threshold=0.05, high_threshold=0.15)
    labels, n = label_components(edges > 0)
    if n == 0:
        return np.zeros((0, 3))
    st = region_stats(labels, n)
    # edge regions with enough pixels and a round moment ellipse (fake eccentricity)
    round_ = ((st["area"] >= 8) & (st["eccentricity"] >= min_roundness)).cpu().numpy()
    lab = labels[0, 0].cpu().numpy().ravel()
    idx = np.flatnonzero(round_[lab - 1] & (lab > 0))
    idx = idx[np.argsort(lab[idx], kind="stable")]  # pixels of every such region, in raster order
    out = []
    for pixels in np.split(idx, np.flatnonzero(np.diff(lab[idx])) + 1):
        if pixels.size == 0:
            continue
        vv, uu = np.divmod(pixels, amplitude.shape[1])
        ell = fit_ellipse(uu, vv)
        if (
            ell is None
            or not (min_axis_px <= ell.b and ell.a <= max_axis_px)
            or ell.b / ell.a < min_roundness
        ):
            continue
        zc = bilinear(z_mm, ell.xc, ell.yc)
        if np.isfinite(zc):
            out.append((ell.xc, ell.yc, zc))
    return np.asarray(out, np.float64).reshape(-1, 3)
