"""Batched image kernels on frame tensors (B, 1, H, W): Otsu, labelling, moments, erosion, 3D.

Every function works on a whole stack of frames at once (torch, CPU), so a recording is
processed in chunks of frames rather than frame by frame. Reference implementations the tests
compare against: skimage.filters.threshold_otsu, scipy.ndimage.label, skimage.measure.regionprops.
"""

from __future__ import annotations

import kornia
import torch

__all__ = [
    "check_frames",
    "erode",
    "label_components",
    "otsu_threshold",
    "points_from_depth",
    "points_from_range",
    "region_stats",
]


def check_frames(x: torch.Tensor, name: str = "frames") -> None:
    """Raise ValueError unless ``x`` is a (B, 1, H, W) tensor."""
    if not isinstance(x, torch.Tensor) or x.ndim != 4 or x.shape[1] != 1:
        got = tuple(x.shape) if isinstance(x, torch.Tensor) else type(x).__name__
        raise ValueError(f"{name}: expected a tensor of shape (B, 1, H, W), got {got}")


def otsu_threshold(x: torch.Tensor, valid: torch.Tensor | None = None, bins: int = 256) -> torch.Tensor:
    """Otsu's threshold of every frame (thesis eq. 5.22-5.24), over its ``valid`` pixels.

    Same histogram convention as skimage's ``threshold_otsu``: ``bins`` bins between the frame's
    minimum and maximum, the threshold is the centre of the bin that maximises the between-class
    variance, and foreground is ``x > threshold``.

    Args:
        x: (B, 1, H, W) float frames. valid: optional (B, 1, H, W) bool mask.
    Returns:
        (B,) thresholds (NaN for a frame without valid pixels).
    """
    check_frames(x, "x")
    b = x.shape[0]
    v = x.reshape(b, -1).to(torch.float64)
    ok = torch.isfinite(v) if valid is None else valid.reshape(b, -1) & torch.isfinite(v)
    big = torch.finfo(torch.float64).max
    lo = torch.where(ok, v, big).amin(dim=1)
    hi = torch.where(ok, v, -big).amax(dim=1)
    width = (hi - lo).clamp_min(1e-300) / bins
    idx = ((v - lo[:, None]) / width[:, None]).floor().clamp(0, bins - 1).long()
    idx = torch.where(ok, idx, torch.full_like(idx, bins))  # invalid pixels go to a spare bin
    hist = torch.zeros(b, bins + 1, dtype=torch.float64).scatter_add_(1, idx, torch.ones_like(v))[:, :bins]
    centers = lo[:, None] + width[:, None] * (torch.arange(bins, dtype=torch.float64) + 0.5)
    w1 = hist.cumsum(1)
    w2 = hist.flip(1).cumsum(1).flip(1)
    m1 = (hist * centers).cumsum(1) / w1.clamp_min(1e-300)
    m2 = ((hist * centers).flip(1).cumsum(1) / w2.flip(1).clamp_min(1e-300)).flip(1)
    between = w1[:, :-1] * w2[:, 1:] * (m1[:, :-1] - m2[:, 1:]) ** 2
    k = between.argmax(dim=1)
    thr = centers.gather(1, k[:, None])[:, 0]
    # A constant frame has no threshold to find: skimage returns its value.
    thr = torch.where(hi > lo, thr, lo)
    return torch.where(ok.any(dim=1), thr, torch.full_like(thr, float("nan")))


def label_components(mask: torch.Tensor) -> tuple[torch.Tensor, int]:
    """8-connected components of every frame, labelled 1..K consecutively per frame.

    Returns:
        labels (B, 1, H, W) int64 (0 = background) and K, the largest count in any frame.
    """
    check_frames(mask, "mask")
    raw = kornia.contrib.connected_components_union_find(mask.to(torch.bool))
    b = raw.shape[0]
    flat = raw.reshape(b, -1)
    # Consecutive labels per frame: rank the distinct raw labels within each frame.
    offset = torch.arange(b, dtype=torch.int64)[:, None] * (flat.max() + 1)
    keyed = torch.where(flat > 0, flat + offset, torch.zeros_like(flat))
    uniq, inverse = torch.unique(keyed, return_inverse=True)
    frame_of = torch.div(uniq, flat.max() + 1, rounding_mode="floor")
    frame_of = torch.where(uniq > 0, frame_of, torch.full_like(frame_of, -1))
    # position of each unique label among those of its frame
    first = torch.searchsorted(frame_of.contiguous(), frame_of.contiguous(), right=False)
    rank = torch.arange(uniq.numel()) - first + 1
    rank = torch.where(uniq > 0, rank, torch.zeros_like(rank))
    labels = rank[inverse].reshape(raw.shape)
    counts = (
        torch.bincount(frame_of[uniq > 0], minlength=b) if uniq.numel() else torch.zeros(b, dtype=torch.long)
    )
    return labels, int(counts.max().item()) if counts.numel() else 0


def region_stats(labels: torch.Tensor, n_labels: int, values: torch.Tensor | None = None) -> dict:
    """Area, centroid, second moments and fake eccentricity of every labelled region.

    Moments follow thesis eq. 5.5-5.9 (pixel coordinates u = column, v = row); the fake
    eccentricity is the ratio of the minor to the major axis of the moment ellipse,
    sqrt(λ_min / λ_max) of [[μuu, μuv], [μuv, μvv]]: about 1 for a disc, small for a strip.

    Args:
        labels: (B, 1, H, W) labels 0..n_labels. values: optional (B, C, H, W) per-pixel values
            (e.g. 3D coordinates) whose region means are returned as ``mean``.
    Returns:
        dict of (B, K) tensors (K = n_labels; label k is column k-1): area, u, v, muu, mvv, muv,
        major, minor (axis lengths 4 sqrt λ as in skimage), eccentricity; ``mean`` (B, K, C).
    """
    check_frames(labels, "labels")
    b, _, h, w = labels.shape
    k = max(n_labels, 1)
    lab = labels.reshape(b, -1)
    vv, uu = torch.meshgrid(
        torch.arange(h, dtype=torch.float64), torch.arange(w, dtype=torch.float64), indexing="ij"
    )
    u = uu.reshape(1, -1).expand(b, -1)
    v = vv.reshape(1, -1).expand(b, -1)

    def rsum(x):
        return torch.zeros(b, k + 1, dtype=torch.float64).scatter_add_(1, lab, x)[:, 1:]

    area = rsum(torch.ones_like(u))
    a = area.clamp_min(1)
    ub, vb = rsum(u) / a, rsum(v) / a
    muu = rsum(u * u) / a - ub**2
    mvv = rsum(v * v) / a - vb**2
    muv = rsum(u * v) / a - ub * vb
    half_tr = 0.5 * (muu + mvv)
    disc = torch.sqrt((0.5 * (muu - mvv)) ** 2 + muv**2)
    l1 = half_tr + disc
    l2 = (half_tr - disc).clamp_min(0)
    out = dict(
        area=area,
        u=ub,
        v=vb,
        muu=muu,
        mvv=mvv,
        muv=muv,
        major=4 * torch.sqrt(l1),
        minor=4 * torch.sqrt(l2),
        eccentricity=torch.sqrt(l2 / l1.clamp_min(1e-300)),
    )
    if values is not None:
        c = values.shape[1]
        vals = values.reshape(b, c, -1).to(torch.float64)
        sums = torch.zeros(b, c, k + 1, dtype=torch.float64).scatter_add_(
            2, lab[:, None, :].expand(-1, c, -1), vals
        )[:, :, 1:]
        out["mean"] = (sums / a[:, None, :]).permute(0, 2, 1)
    return out


def erode(mask: torch.Tensor, size: int = 3) -> torch.Tensor:
    """Binary erosion with a size x size square (kornia): drops the mixed pixels at edges."""
    check_frames(mask, "mask")
    kernel = torch.ones(size, size)
    out = kornia.morphology.erosion(mask.to(torch.float32), kernel, border_type="constant", border_value=0.0)
    return out > 0.5


def points_from_range(range_mm: torch.Tensor, fx: float, fy: float, cx: float, cy: float) -> torch.Tensor:
    """3D points (B, 3, H, W) in mm from ToF radial range along each pixel's ray (eq. 3.9-3.10)."""
    check_frames(range_mm, "range_mm")
    _, _, h, w = range_mm.shape
    vv, uu = torch.meshgrid(
        torch.arange(h, dtype=range_mm.dtype), torch.arange(w, dtype=range_mm.dtype), indexing="ij"
    )
    x = (uu - cx) / fx
    y = (vv - cy) / fy
    norm = torch.sqrt(x * x + y * y + 1)
    z = range_mm / norm
    return torch.cat([z * x, z * y, z], dim=1)


def points_from_depth(depth_mm: torch.Tensor, fx: float, fy: float, cx: float, cy: float) -> torch.Tensor:
    """3D points (B, 3, H, W) in mm from structured-light depth z (eq. 3.12, 3.16)."""
    check_frames(depth_mm, "depth_mm")
    _, _, h, w = depth_mm.shape
    vv, uu = torch.meshgrid(
        torch.arange(h, dtype=depth_mm.dtype), torch.arange(w, dtype=depth_mm.dtype), indexing="ij"
    )
    return torch.cat([depth_mm * (uu - cx) / fx, depth_mm * (vv - cy) / fy, depth_mm], dim=1)
