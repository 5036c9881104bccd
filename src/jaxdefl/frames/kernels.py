"""Batched image kernels on frame tensors (B, 1, H, W): Otsu, labelling, moments, morphology.

Every function works on a whole stack of frames at once, on the tensors' device (CPU or CUDA),
so a recording is processed in chunks of frames rather than frame by frame. Morphology is
kornia's; the labelling is a run-based union-find in torch (kornia's
``connected_components`` needs one max-pooling step per pixel of a component's extent, and
``connected_components_union_find``, which works on every 2x2 block of the image, is 10-12x
slower than this on the plates' chunks: experiments/bench_extract.py's kernel table). Reference
implementations the tests compare against: skimage.filters.threshold_otsu, scipy.ndimage.label,
scipy.ndimage.binary_erosion / binary_opening, skimage.measure.regionprops.
"""

from __future__ import annotations

import kornia
import numpy as np
import torch

__all__ = [
    "check_frames",
    "erode",
    "flat_indices",
    "label_components",
    "opening",
    "otsu_threshold",
    "region_stats",
]


def check_frames(x: torch.Tensor, name: str = "frames") -> None:
    """Raise ValueError unless ``x`` is a (B, 1, H, W) tensor."""
    if not isinstance(x, torch.Tensor) or x.ndim != 4 or x.shape[1] != 1:
        got = tuple(x.shape) if isinstance(x, torch.Tensor) else type(x).__name__
        raise ValueError(f"{name}: expected a tensor of shape (B, 1, H, W), got {got}")


def flat_indices(mask: torch.Tensor) -> torch.Tensor:
    """Indices (int64, ascending) of the true elements of ``mask`` flattened.

    On the CPU through numpy: torch's ``nonzero`` is 2-10x slower there on a chunk of frames,
    the more so the busier the machine (experiments/bench_extract.py's kernel table).
    """
    if mask.device.type == "cpu":
        return torch.from_numpy(np.flatnonzero(mask.numpy()))
    return mask.reshape(-1).nonzero()[:, 0]


def all_finite(x: torch.Tensor) -> bool:
    """True if no element of ``x`` is NaN or infinite (a finite sum says so in one pass)."""
    return bool(torch.isfinite(x.sum())) or bool(torch.isfinite(x).all())


def otsu_threshold(x: torch.Tensor, valid: torch.Tensor | None = None, bins: int = 256) -> torch.Tensor:
    """Otsu's threshold of every frame (thesis eq. 5.22-5.24), over its ``valid`` pixels.

    Same histogram convention as skimage's ``threshold_otsu``: ``bins`` bins between the frame's
    minimum and maximum, the threshold is the centre of the bin that maximises the between-class
    variance, and foreground is ``x > threshold``. Bin indices are computed in ``x``'s dtype,
    the class statistics in float64.

    Args:
        x: (B, 1, H, W) float frames. valid: optional (B, 1, H, W) bool mask.
    Returns:
        (B,) float64 thresholds (NaN for a frame without valid pixels).
    """
    check_frames(x, "x")
    b, dev = x.shape[0], x.device
    v = x.reshape(b, -1)
    every = valid is None and all_finite(v)
    if every:
        lo, hi = v.amin(dim=1), v.amax(dim=1)  # two reductions beat one aminmax on the CPU
        ok = torch.ones(b, 1, dtype=torch.bool, device=dev)
    else:
        ok = torch.isfinite(v) if valid is None else valid.reshape(b, -1) & torch.isfinite(v)
        big = torch.finfo(v.dtype).max
        lo = torch.where(ok, v, big).amin(dim=1)
        hi = torch.where(ok, v, -big).amax(dim=1)
    width = ((hi - lo) / bins).clamp_min(torch.finfo(v.dtype).tiny)
    t = (v - lo[:, None]).div_(width[:, None]).clamp_(0, bins - 1)
    idx = t.to(torch.int32)
    if not every:
        idx.masked_fill_(~ok, bins)  # invalid pixels go to a spare bin
    idx += torch.arange(0, b * (bins + 1), bins + 1, dtype=torch.int32, device=dev)[:, None]
    hist = torch.bincount(idx.reshape(-1), minlength=b * (bins + 1)).reshape(b, bins + 1)[:, :bins]
    hist = hist.to(torch.float64)
    lo64, width64 = lo.to(torch.float64), width.to(torch.float64)
    centers = lo64[:, None] + width64[:, None] * (torch.arange(bins, dtype=torch.float64, device=dev) + 0.5)
    # skimage's sums, term for term: the between-class variance is flat across empty bins, and
    # which bin wins the tie depends on the rounding
    w1 = hist.cumsum(1)
    w2 = hist.flip(1).cumsum(1).flip(1)
    m1 = (hist * centers).cumsum(1) / w1.clamp_min(1e-300)
    m2 = ((hist * centers).flip(1).cumsum(1) / w2.flip(1).clamp_min(1e-300)).flip(1)
    between = w1[:, :-1] * w2[:, 1:] * (m1[:, :-1] - m2[:, 1:]) ** 2
    thr = centers.gather(1, between.argmax(dim=1)[:, None])[:, 0]
    # A constant frame has no threshold to find: skimage returns its value.
    thr = torch.where(hi > lo, thr, lo64)
    return torch.where(ok.any(dim=1), thr, torch.full_like(thr, float("nan")))


def _roots(parent: torch.Tensor, src: torch.Tensor, dst: torch.Tensor) -> torch.Tensor:
    """Union-find by minimum root: hook along the edges, compress fully, until nothing changes."""
    while True:
        rs, rd = parent[src], parent[dst]
        merged = parent.clone()
        merged.scatter_reduce_(0, torch.maximum(rs, rd), torch.minimum(rs, rd), reduce="amin")
        while True:
            jumped = merged[merged]
            if torch.equal(jumped, merged):
                break
            merged = jumped
        if torch.equal(merged, parent):
            return parent
        parent = merged


def _runs(rows: torch.Tensor) -> tuple[int, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Runs of true pixels along the rows of a (R, w) bool tensor: count, row, first and last column."""
    r, w = rows.shape
    pad = torch.zeros(r, w + 2, dtype=torch.bool, device=rows.device)
    pad[:, 1:-1] = rows
    ends = flat_indices(pad[:, 1:] ^ pad[:, :-1])  # raster order: a run's start, then one past its end
    first, stop = ends[0::2], ends[1::2]
    return first.numel(), first // (w + 1), first % (w + 1), stop % (w + 1) - 1


def label_components(mask: torch.Tensor) -> tuple[torch.Tensor, int]:
    """8-connected components of every frame, labelled 1..n over the whole batch.

    Labels run in raster order of each component's first pixel, frame after frame (as
    ``scipy.ndimage.label`` of the frames stacked into one tall image with an empty row between
    them); components never span two frames.

    Runs of foreground pixels along the rows are the nodes: a run joins every run in the row
    above that overlaps it or touches it diagonally (a contiguous range of runs, found by binary
    search), and a union-find on the runs gives the components.

    Returns:
        labels (B, 1, H, W) int32 (0 = background) and n, the number of components.
    """
    check_frames(mask, "mask")
    b, _, h, w = mask.shape
    dev = mask.device
    n_runs, row, first, last = _runs(mask.reshape(b * h, w) != 0)
    if n_runs == 0:
        return torch.zeros(mask.shape, dtype=torch.int32, device=dev), 0
    # runs of the row above (same frame) reaching columns first-1 .. last+1: a contiguous range
    stride = w + 2
    key_first, key_last = row * stride + first, row * stride + last
    lo = torch.searchsorted(key_last, (row - 1) * stride + first - 1)
    hi = torch.searchsorted(key_first, (row - 1) * stride + last + 1, right=True) - 1
    has = (row % h != 0) & (hi >= lo)
    lo, hi = lo[has], hi[has]
    # each run to the first run of its range, and neighbours inside every range to each other
    cover = torch.zeros(n_runs + 1, dtype=torch.int64, device=dev)
    cover.index_add_(0, lo, torch.ones_like(lo)).index_add_(0, hi, -torch.ones_like(hi))
    chain = (cover.cumsum(0)[:-1] > 0).nonzero()[:, 0]
    src = torch.cat([has.nonzero()[:, 0], chain + 1])
    dst = torch.cat([lo, chain])
    root = _roots(torch.arange(n_runs, device=dev), src, dst)
    uniq, comp = torch.unique(root, return_inverse=True)
    # labels painted run by run: +label at the start, -label one past the end, summed along rows
    paint = torch.zeros(b * h, w + 1, dtype=torch.int32, device=dev)
    lab = (comp + 1).to(torch.int32)
    paint[row, first] = lab
    paint[row, last + 1] = -lab
    labels = paint[:, :w].cumsum(1, dtype=torch.int32)
    return labels.reshape(b, 1, h, w), int(uniq.numel())


def region_stats(labels: torch.Tensor, n_labels: int, row0: int = 0, height: int | None = None) -> dict:
    """Frame, area, centroid, second moments and fake eccentricity of every labelled region.

    Moments follow thesis eq. 5.5-5.9 (pixel coordinates u = column, v = row + ``row0``); the
    fake eccentricity is the ratio of the minor to the major axis of the moment ellipse,
    sqrt(λ_min / λ_max) of [[μuu, μuv], [μuv, μvv]]: about 1 for a disc, small for a strip.

    Args:
        labels: (B, 1, H, W) labels 0..n_labels (0 = background), as from `label_components`,
            holding rows ``row0`` .. ``row0 + H - 1`` of frames ``height`` rows high
            (default: ``row0 + H``).
    Returns:
        dict of (n_labels,) tensors (label k is entry k-1): frame (int64), area, u, v, muu, mvv,
        muv, major, minor (axis lengths 4 sqrt λ as in skimage), eccentricity (float64) and
        border (bool: a pixel on the frame's first or last row or column).
    """
    check_frames(labels, "labels")
    b, _, h, w = labels.shape
    height = row0 + h if height is None else height
    dev, n = labels.device, n_labels
    # runs of one label along the rows (two labels never touch: they would be one component)
    _, row, first, last = _runs(labels.reshape(b * h, w) != 0)
    lab = labels.reshape(b * h, w)[row, first].long() - 1
    u0, u1 = first.to(torch.float64), last.to(torch.float64)
    vi = row % h + row0
    v = vi.to(torch.float64)
    # sums over a run's pixels u0..u1 in closed form (exact integers in float64)
    cnt = u1 - u0 + 1
    su = 0.5 * cnt * (u0 + u1)
    suu = (u1 * (u1 + 1) * (2 * u1 + 1) - (u0 - 1) * u0 * (2 * u0 - 1)) / 6

    def rsum(x):
        return torch.bincount(lab, x, minlength=n)

    area = rsum(cnt)
    a = area.clamp_min(1)
    ub, vb = rsum(su) / a, rsum(cnt * v) / a
    muu = (rsum(suu) / a - ub * ub).clamp_min(0)
    mvv = (rsum(cnt * v * v) / a - vb * vb).clamp_min(0)
    muv = rsum(su * v) / a - ub * vb
    half_tr = 0.5 * (muu + mvv)
    disc = torch.sqrt((0.5 * (muu - mvv)) ** 2 + muv**2)
    l1 = half_tr + disc
    l2 = (half_tr - disc).clamp_min(0)
    edge = (first == 0) | (last == w - 1) | (vi == 0) | (vi == height - 1)
    frame = torch.zeros(n, dtype=torch.int64, device=dev).index_put_((lab,), row // h)
    return dict(
        frame=frame,
        area=area,
        u=ub,
        v=vb,
        muu=muu,
        mvv=mvv,
        muv=muv,
        major=4 * torch.sqrt(l1),
        minor=4 * torch.sqrt(l2),
        eccentricity=torch.sqrt(l2 / l1.clamp_min(1e-300)),
        border=rsum(edge.to(torch.float64)) > 0,
    )


def _line(size: int, vertical: bool, device) -> torch.Tensor:
    return torch.ones((size, 1) if vertical else (1, size), device=device)


def erode(mask: torch.Tensor, size: int = 3) -> torch.Tensor:
    """Binary erosion with a size x size square, zero outside the frame (kornia).

    Drops the mixed pixels at plate edges (thesis 5.1.4); as ``scipy.ndimage.binary_erosion``
    with ``border_value=0``. The square is applied as a row then a column (2 x size shifted
    views instead of size², the same result).
    """
    check_frames(mask, "mask")
    x = mask.to(torch.float32)
    for vertical in (False, True):
        x = kornia.morphology.erosion(
            x, _line(size, vertical, mask.device), border_type="constant", border_value=0.0
        )
    return x > 0.5


def opening(mask: torch.Tensor, size: int = 3) -> torch.Tensor:
    """Binary opening with a size x size square, zero outside the frame (kornia).

    Removes strips thinner than ``size``; as ``scipy.ndimage.binary_opening``.
    """
    check_frames(mask, "mask")
    out = kornia.morphology.opening(
        mask.to(torch.float32),
        torch.ones(size, size, device=mask.device),
        border_type="constant",
        border_value=0.0,
    )
    return out > 0.5
