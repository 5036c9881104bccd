"""Plate extraction from frame stacks: ToF (thesis 5.1) and structured light (thesis 5.2).

Stages, on a chunk of frames (B, H, W) at a time:

1. **Scene calibration** (once per recording, again when plates drift or vanish), on the
   median of the first frames: floor targets (Canny, fake eccentricity, Fitzgibbon ellipse,
   bilinear depth: `floor.py`) give the floor level; the beam top is the dominant depth level
   nearer than the floor, segmented as large low-eccentricity regions; its depth is the second
   threshold. The plates are the depth layer next to the top surface (the thesis' scene, and the
   simulator's, has them between top and floor, bonded 295 mm below the top; a layer above the
   top is tried too, and the one holding a row of similar, collinear regions wins). Each plate
   found is numbered by its position along the beam and keeps its area, eccentricity and image
   position as a template.
2. **Per frame**, batched: depth relative to that frame's beam-top level (a per-frame median,
   so common depth shifts of structured-light cameras cancel); the plate layer's depth band
   (depth-based classification); ToF: Otsu on the amplitude image masked by the band (eq.
   5.22-5.24); structured light: depth only, smoothed 5x5 for segmentation. 8-connected
   components, area, centroid and fake eccentricity (eq. 5.5-5.9), the line through the plates,
   a 3x3 erosion that drops mixed edge pixels, and the mean of the eroded pixels' 3D points
   (eq. 3.10 for range, 3.16 for depth). Structured light: pixels farther than 3 sigma from their
   plate's mean depth are dropped (a one-step stand-in for region growing in 3D).
3. Each region is numbered by its position along the beam (`PlateGeometry`), then checked
   against that plate's template; a region that fails, or two regions claiming one plate, give
   NaN for that plate and frame: a plate is missing rather than mislabelled.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.ndimage as ndi

from .floor import floor_targets

__all__ = ["PlateGeometry", "Scene", "calibrate_scene", "detect_chunk", "ray_factors", "SceneError"]

_EIGHT = np.ones((3, 3), bool)
_GRAD_MAX_MM_PER_PX = 6.0  # structured light: steepest depth change across a plate (smoothed)


class SceneError(ValueError):
    """The calibration frame shows no plate layer (message says what was looked for)."""


@dataclass(frozen=True)
class PlateGeometry:
    """Plate centres along the beam and the camera's position on the same axis (mm).

    A detected centroid's camera-frame X plus ``camera_x_mm`` is its position along the beam; the
    nearest plate within ``tolerance`` x the plate spacing gives its number (1-based).
    """

    plate_x_mm: np.ndarray
    camera_x_mm: float
    tolerance: float = 0.3

    def number(self, x_cam_mm: np.ndarray) -> np.ndarray:
        """Plate numbers (0 = none) of camera-frame X positions."""
        px = np.asarray(self.plate_x_mm, np.float64)
        xw = np.asarray(x_cam_mm, np.float64) + self.camera_x_mm
        spacing = np.min(np.diff(px)) if px.size > 1 else np.inf
        j = np.clip(np.searchsorted(px, xw), 1, max(px.size - 1, 1))
        lo = np.clip(j - 1, 0, px.size - 1)
        hi = np.clip(j, 0, px.size - 1)
        k = np.where(np.abs(xw - px[lo]) <= np.abs(xw - px[hi]), lo, hi)
        ok = np.abs(xw - px[k]) <= self.tolerance * spacing
        return np.where(ok & np.isfinite(xw), k + 1, 0)


def ray_factors(h: int, w: int, fx: float, fy: float, cx: float, cy: float, kind: str):
    """Per-pixel factors (h, w) float32: z = value * inv_norm, x = z * xr, y = z * yr.

    ``range``: radial range along the pixel ray, z = r / sqrt(xr² + yr² + 1) (eq. 3.9-3.10);
    ``depth``: structured-light depth z itself (eq. 3.12, 3.16).
    """
    v, u = np.meshgrid(np.arange(h, dtype=np.float64), np.arange(w, dtype=np.float64), indexing="ij")
    xr = (u - cx) / fx
    yr = (v - cy) / fy
    inv = 1 / np.sqrt(xr * xr + yr * yr + 1) if kind == "range" else np.ones_like(xr)
    return inv.astype(np.float32), xr.astype(np.float32), yr.astype(np.float32)


@dataclass
class Scene:
    """Calibration of one camera view: thresholds, plate templates and tracked pixel sets."""

    kind: str
    height: int
    width: int
    inv_norm: np.ndarray
    xr: np.ndarray
    yr: np.ndarray
    top_idx: np.ndarray  # (K,) flat pixel indices on the beam top surface
    top_z_mm: float
    floor_z_mm: float  # NaN when no floor target was found
    n_floor_targets: int
    sigma_mm: float  # per-pixel noise of the segmentation image on the top surface
    band: tuple[float, float]  # plate layer, depth relative to the top (mm)
    smooth: int
    use_amplitude: bool
    rows: tuple[int, int]  # band of rows searched per frame
    plates: np.ndarray  # (n,) plate numbers
    area: np.ndarray  # (n,) px, before erosion
    ecc: np.ndarray  # (n,)
    u: np.ndarray  # (n,) px
    v: np.ndarray
    line: tuple[float, float]  # v = line[0] + line[1] * u
    line_tol_px: float
    geometry: PlateGeometry | None
    track: list = field(default_factory=list)  # per plate: flat pixel indices (eroded region)

    def number(self, x_cam_mm: np.ndarray, u_px: np.ndarray) -> np.ndarray:
        """Plate numbers (0 = none) of regions from their camera X (mm) or image column."""
        if self.geometry is not None:
            return self.geometry.number(x_cam_mm)
        # no geometry: the nearest calibration plate in image columns
        order = np.argsort(self.u)
        us = self.u[order]
        gap = np.min(np.diff(us)) if us.size > 1 else float(self.width)
        k = (
            np.argmin(np.abs(np.asarray(u_px)[:, None] - us[None, :]), axis=1)
            if us.size
            else np.zeros(0, int)
        )
        ok = np.abs(np.asarray(u_px) - us[k]) <= 0.3 * gap
        return np.where(ok, self.plates[order][k], 0)


def _zimage(frames: np.ndarray, inv_norm: np.ndarray | None) -> np.ndarray:
    """Depth z (frame, h, w) float32: range times the ray factor, or the depth itself."""
    f = np.asarray(frames, np.float32)
    return f if inv_norm is None else np.multiply(f, inv_norm, dtype=np.float32)


def _box_mean(z: np.ndarray, k: int) -> np.ndarray:
    """k x k mean of every frame (frame, h, w), over the pixels inside the frame only.

    Equals ``avg_pool2d(z, k, stride=1, padding=k // 2, count_include_pad=False)``; separable
    shifted sums, so a NaN spreads only to its k x k neighbourhood.
    """
    if k <= 1:
        return z
    r = k // 2
    b, h, w = z.shape
    zp = np.zeros((b, h + 2 * r, w), np.float32)
    zp[:, r : r + h] = z
    rows = zp[:, 0:h].copy()
    for d in range(1, k):
        rows += zp[:, d : d + h]
    cp = np.zeros((b, h, w + 2 * r), np.float32)
    cp[:, :, r : r + w] = rows
    out = cp[:, :, 0:w].copy()
    for d in range(1, k):
        out += cp[:, :, d : d + w]
    # in-frame pixel count of each window: separable too
    nv = np.convolve(np.ones(h), np.ones(k))[r : r + h]
    nu = np.convolve(np.ones(w), np.ones(k))[r : r + w]
    out *= (1.0 / np.outer(nv, nu)).astype(np.float32)
    return out


def _erode3(fg: np.ndarray) -> np.ndarray:
    """3x3 binary erosion of every frame (frame, h, w), zero border (equals `kernels.erode`, size 3).

    Separable: a pixel survives if its row triple survives in the rows above, at and below.
    """
    r = np.zeros_like(fg)
    np.logical_and(fg[:, :, :-2], fg[:, :, 1:-1], out=r[:, :, 1:-1])
    r[:, :, 1:-1] &= fg[:, :, 2:]
    out = np.zeros_like(fg)
    np.logical_and(r[:, :-2], r[:, 1:-1], out=out[:, 1:-1])
    out[:, 1:-1] &= r[:, 2:]
    return out


def _otsu_thresholds(hist: np.ndarray, lo: np.ndarray, width: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Otsu threshold (B,) float32 from per-frame histograms (B, bins) over [lo, lo + bins * width)."""
    b, bins = hist.shape
    centers = lo[:, None].astype(np.float64) + width[:, None].astype(np.float64) * (np.arange(bins) + 0.5)
    w1 = hist.cumsum(1)
    w2 = w1[:, -1:] - w1 + hist
    s1 = (hist * centers).cumsum(1)
    s2 = s1[:, -1:] - s1 + hist * centers
    m1 = s1 / np.maximum(w1, 1e-300)
    m2 = s2 / np.maximum(w2, 1e-300)
    between = w1[:, :-1] * w2[:, 1:] * (m1[:, :-1] - m2[:, 1:]) ** 2
    k = between.argmax(1)
    thr = centers[np.arange(b), k].astype(np.float32)
    return np.where(hi > lo, thr, lo)


def _otsu_masked(amp: np.ndarray, bins: int = 256) -> np.ndarray:
    """Otsu threshold of every frame (frame, h, w) float32 of a masked amplitude image (B,).

    Same convention as `kernels.otsu_threshold` (skimage's): ``bins`` bins between the frame's
    minimum and maximum, threshold at the centre of the best bin; the bin indices are computed
    in float32, the class statistics in float64. (Slow reference of `_otsu_in_mask`.)
    """
    b = amp.shape[0]
    v = amp.reshape(b, -1)
    hi = v.max(1)
    lo = v.min(1)
    width = np.maximum((hi - lo) / np.float32(bins), np.float32(1e-12))
    idx = ((v - lo[:, None]) / width[:, None]).astype(np.int32)
    np.clip(idx, 0, bins - 1, out=idx)
    idx += (np.arange(b, dtype=np.int32) * bins)[:, None]
    hist = np.bincount(idx.ravel(), minlength=b * bins).reshape(b, bins).astype(np.float64)
    return _otsu_thresholds(hist, lo, width, hi)


def _otsu_in_mask(vals: np.ndarray, fr: np.ndarray, n_pix: int, b: int, bins: int = 256) -> np.ndarray:
    """`_otsu_masked` of ``where(mask, amp, 0)`` from the masked pixels alone (B,) float32.

    Args:
        vals: amplitudes of the masked pixels, grouped by frame. fr: their frames (sorted).
        n_pix: pixels per frame; the unmasked ones count as zeros in the histogram.
    """
    nfg = np.bincount(fr, minlength=b)
    nbg = n_pix - nfg
    lo = np.zeros(b, np.float32)
    hi = np.zeros(b, np.float32)
    has = nfg > 0
    if vals.size:
        starts = np.concatenate([[0], np.cumsum(nfg)[:-1]])[has]
        lo[has] = np.minimum.reduceat(vals, starts)
        hi[has] = np.maximum.reduceat(vals, starts)
    # the zeros of the unmasked pixels take part in the minimum and maximum
    lo = np.where(nbg > 0, np.minimum(lo, 0), lo).astype(np.float32)
    hi = np.where(nbg > 0, np.maximum(hi, 0), hi).astype(np.float32)
    width = np.maximum((hi - lo) / np.float32(bins), np.float32(1e-12))
    idx = ((vals - lo[fr]) / width[fr]).astype(np.int32)
    np.clip(idx, 0, bins - 1, out=idx)
    idx += fr.astype(np.int32) * bins
    hist = np.bincount(idx, minlength=b * bins).astype(np.float64)
    zero = np.clip(((np.float32(0) - lo) / width).astype(np.int32), 0, bins - 1)
    hist[np.arange(b) * bins + zero] += nbg
    return _otsu_thresholds(hist.reshape(b, bins), lo, width, hi)


def _segment(
    z: np.ndarray, amp: np.ndarray | None, top: np.ndarray, band, smooth: int, use_amp: bool, r0: int, r1: int
) -> np.ndarray:
    """Foreground (frame, h, w) bool: depth band relative to ``top`` (frame,), then Otsu.

    ``z`` holds rows r0:r1 of the frames, ``amp`` the whole frames. Plain numpy on float32:
    on chunks this small, torch's intra-op threads cost more than they save when the cores
    are shared (measured in experiments/bench_extract.py).
    """
    zs = _box_mean(z, smooth)
    rel = zs - top.astype(np.float32)[:, None, None]
    fg = rel > band[0]
    fg &= rel < band[1]
    if smooth > 1:
        # smoothness constraint (as in region growing, Rabbani et al. 2006): the plates are
        # flat, the side faces of the spreader beam and the mixed edges are steep
        lim = 2 * _GRAD_MAX_MM_PER_PX
        steep = np.zeros_like(fg)
        steep[:, 1:-1] = ~(np.abs(zs[:, 2:] - zs[:, :-2]) < lim)
        steep[:, :, 1:-1] |= ~(np.abs(zs[:, :, 2:] - zs[:, :, :-2]) < lim)
        fg &= ~steep
    if use_amp and amp is not None:
        # Otsu on the amplitude masked by the band (eq. 5.22-5.24), from the band's pixels only
        b, h, w = fg.shape
        a = np.ascontiguousarray(amp, np.float32)
        fidx = np.flatnonzero(fg)
        fr, rem = np.divmod(fidx, h * w)
        vals = a.reshape(-1)[fr * a[0].size + r0 * w + rem]
        thr = _otsu_in_mask(vals, fr, h * w, b)
        fg.reshape(-1)[fidx[~(vals > thr[fr])]] = False
    return fg


def _regions(
    fg: np.ndarray,
    z: np.ndarray,
    r0: int,
    inv_norm,
    xr,
    yr,
    clip_sigma: float | None,
    keep_pixels: bool = False,
) -> dict:
    """Label, measure, erode and average: per-region arrays (global labels over the stack).

    ``fg`` and ``z`` (frame, h, w) hold rows r0:r0+h of the frames.
    """
    b, h, w = fg.shape
    # the frames stacked into one tall image, an empty row under each: one 2D labelling
    # (twice as fast as a 3D one with a flat structure)
    tall = np.zeros((b, h + 1, w), bool)
    tall[:, :h] = fg
    labels, n = ndi.label(tall.reshape(-1, w), structure=_EIGHT)
    H, W = inv_norm.shape
    out: dict = {"n": n}
    if n == 0:
        return out
    flat = labels.reshape(-1)
    idx = np.flatnonzero(tall)
    lab = flat[idx].astype(np.intp)
    fr, rem = np.divmod(idx, (h + 1) * w)
    v, u = np.divmod(rem, w)
    v = v + r0
    m = n + 1
    area = np.bincount(lab, minlength=m).astype(np.float64)
    a = np.maximum(area, 1)
    uf, vf = u.astype(np.float64), v.astype(np.float64)
    su, sv = np.bincount(lab, uf, m), np.bincount(lab, vf, m)
    ub, vb = su / a, sv / a
    muu = np.bincount(lab, uf * uf, m) / a - ub**2
    mvv = np.bincount(lab, vf * vf, m) / a - vb**2
    muv = np.bincount(lab, uf * vf, m) / a - ub * vb
    half, disc = 0.5 * (muu + mvv), np.sqrt((0.5 * (muu - mvv)) ** 2 + muv**2)
    l1, l2 = half + disc, np.maximum(half - disc, 0)
    border = np.bincount(lab, (u == 0) | (u == W - 1) | (v == 0) | (v == H - 1), m)
    frame = np.zeros(m, np.int64)
    frame[lab] = fr
    out.update(
        area=area,
        u=ub,
        v=vb,
        ecc=np.sqrt(l2 / np.maximum(l1, 1e-300)),
        minor=4 * np.sqrt(l2),
        border=border > 0,
        frame=frame,
    )
    # erosion drops the mixed pixels at plate edges (thesis 5.1.4); the empty rows act as the
    # zero border of every frame
    eidx = np.flatnonzero(_erode3(tall))
    elab = flat[eidx].astype(np.intp)
    efr, erem = np.divmod(eidx, (h + 1) * w)
    pix = erem + r0 * w  # flat pixel index in the full frame
    zz = z.reshape(-1)[efr * (h * w) + erem]  # z holds the rows r0:r0+h only
    ok = np.isfinite(zz)
    if not ok.all():
        elab, pix, zz = elab[ok], pix[ok], zz[ok]
    zz = zz.astype(np.float64)
    if clip_sigma is not None and elab.size:
        # pixels farther than clip_sigma x the region's scatter from its mean depth are not the plate's
        cnt = np.maximum(np.bincount(elab, minlength=m), 1)
        mean = np.bincount(elab, zz, m) / cnt
        res = zz - mean[elab]
        sd = np.sqrt(np.bincount(elab, res * res, m) / cnt)
        keep = np.abs(res) <= clip_sigma * sd[elab] + 1e-6
        elab, pix, zz = elab[keep], pix[keep], zz[keep]
    ne = np.bincount(elab, minlength=m).astype(np.float64)
    nn = np.maximum(ne, 1)
    out.update(
        n_eroded=ne,
        x=np.bincount(elab, zz * xr.reshape(-1)[pix], m) / nn,
        y=np.bincount(elab, zz * yr.reshape(-1)[pix], m) / nn,
        z=np.bincount(elab, zz, m) / nn,
    )
    if keep_pixels:
        out["pixels"] = (elab, pix)
    return out


def top_level(z: np.ndarray, top_idx: np.ndarray) -> np.ndarray:
    """Per-frame beam-top depth (B,) float64: lower median over the top-surface pixels, NaN ignored.

    The lower of the two middle values, as ``torch.nanmedian``; NaN for a frame without valid pixels.
    """
    t = np.sort(z.reshape(z.shape[0], -1)[:, top_idx], axis=1)  # NaN sort last
    n = (~np.isnan(t)).sum(1)
    med = t[np.arange(t.shape[0]), np.maximum(n - 1, 0) // 2].astype(np.float64)
    med[n == 0] = np.nan
    return med


def _line_fit(u: np.ndarray, v: np.ndarray, tol: float) -> tuple[np.ndarray, tuple[float, float]]:
    """Robust line v = a + b u through region centroids; mask of the regions on it."""
    keep = np.ones(u.size, bool)
    coef = (float(np.median(v)) if v.size else 0.0, 0.0)
    while keep.sum() >= 2:
        b, a = np.polyfit(u[keep], v[keep], 1)
        coef = (float(a), float(b))
        r = np.abs(v - (a + b * u))
        worst = np.argmax(np.where(keep, r, -1))
        if r[worst] <= tol:
            break
        keep[worst] = False
    return keep, coef


def _plate_candidates(reg: dict, min_area: float) -> np.ndarray:
    """Regions that look like a row of plates: similar size, off the border, collinear."""
    if reg["n"] == 0:
        return np.zeros(0, np.int64)
    lab = np.arange(1, reg["n"] + 1)
    ok = (reg["area"][lab] >= min_area) & ~reg["border"][lab] & (reg["n_eroded"][lab] >= 3)
    lab = lab[ok]
    if lab.size == 0:
        return lab
    med = np.median(reg["area"][lab])
    lab = lab[(reg["area"][lab] > 0.3 * med) & (reg["area"][lab] < 3 * med)]
    if lab.size < 2:
        return lab
    tol = max(2.0, float(np.median(reg["minor"][lab])))
    keep, _ = _line_fit(reg["u"][lab], reg["v"][lab], tol)
    return lab[keep]


def calibrate_scene(
    frames: np.ndarray,
    amplitude: np.ndarray | None,
    intrinsics: dict,
    kind: str,
    geometry: PlateGeometry | None = None,
    n_median: int = 15,
) -> Scene:
    """Find the floor, the beam top and the plates in the first frames of a recording.

    Args:
        frames: (frame, h, w) range (``kind="range"``) or depth (``"depth"``) in mm.
        amplitude: (frame, h, w) or None. intrinsics: fx, fy, cx, cy.
        geometry: plate positions for numbering; None numbers plates 1.. by image column.
    Raises:
        SceneError: no plate layer found.
    """
    _, h, w = frames.shape
    inv, xr, yr = ray_factors(
        h, w, intrinsics["fx"], intrinsics["fy"], intrinsics["cx"], intrinsics["cy"], kind
    )
    nm = min(n_median, frames.shape[0])
    z_all = _zimage(frames[:nm], inv if kind == "range" else None)
    with np.errstate(all="ignore"):
        zmed = np.nanmedian(z_all, axis=0).astype(np.float32)
    amed = None if amplitude is None else np.median(np.asarray(amplitude[:nm], np.float32), axis=0)
    # 1. floor targets (first depth threshold)
    floor = floor_targets(amed, zmed) if amed is not None and np.ptp(amed) > 0 else np.zeros((0, 3))
    floor_z = float(np.median(floor[:, 2])) if len(floor) else float("nan")
    # 2. beam top: the dominant depth level nearer than the floor, large and elongated regions
    zv = zmed[np.isfinite(zmed)]
    if np.isfinite(floor_z):
        zv = zv[zv < floor_z - 50]
    if zv.size == 0:
        raise SceneError("no valid depth nearer than the floor")
    hist, edges = np.histogram(zv, bins=np.arange(zv.min(), zv.max() + 10, 5.0))
    centres = 0.5 * (edges[:-1] + edges[1:])
    # depth levels: histogram peaks; the beam top is the farthest level that holds a large
    # connected surface (nearer ones are the spreader beam and actuator, farther the floor)
    hist = np.convolve(np.pad(hist, 1), np.ones(3), mode="valid")  # a level split between two bins
    hp = np.concatenate([[0.0], hist, [0.0]])
    pk = np.flatnonzero((hist >= 0.1 * hist.max()) & (hist >= hp[:-2]) & (hist > hp[2:]))
    levels = []
    for c in centres[pk]:
        # opened by one pixel: a surface is thicker than the thin strip where a slanted side face
        # (the beam's, next to the plates bonded at its bottom) crosses the level
        lab, n = ndi.label(ndi.binary_opening(np.abs(zmed - c) < 10, structure=_EIGHT), structure=_EIGHT)
        biggest = np.bincount(lab.ravel())[1:].max() if n else 0
        levels.append((c, biggest))
    if not levels:
        raise SceneError("no depth level found")
    biggest_all = max(b for _, b in levels)
    large = [c for c, b in levels if b >= 0.2 * biggest_all]
    if not np.isfinite(floor_z) and len(large) > 1:
        large = large[:-1]  # no floor targets: the farthest large level is the floor
    mode = max(large)
    near = np.abs(zmed - mode) < 10
    lab, n = ndi.label(near, structure=_EIGHT)
    sizes = np.bincount(lab.ravel(), minlength=n + 1)
    sizes[0] = 0
    big = np.flatnonzero(sizes >= 0.25 * sizes.max())
    top_mask = ndi.binary_erosion(np.isin(lab, big), structure=_EIGHT, iterations=2)
    if top_mask.sum() < 20:
        top_mask = np.isin(lab, big)
    top_idx = np.flatnonzero(top_mask.ravel())
    top_z = float(np.median(zmed.ravel()[top_idx]))
    if top_idx.size > 2048:
        top_idx = top_idx[np.linspace(0, top_idx.size - 1, 2048).astype(np.int64)]
    smooth = 5 if kind == "depth" else 0
    use_amp = kind == "range" and amplitude is not None
    # per-pixel noise of the segmentation image on the top surface (one frame, not the median)
    zs0 = _box_mean(z_all[:1], smooth)[0].ravel()[top_idx]
    sigma = float(1.4826 * np.nanmedian(np.abs(zs0 - np.nanmedian(zs0))))
    gap = max(5.0, 4.0 * sigma)
    far = (floor_z - top_z - 50.0) if np.isfinite(floor_z) else 400.0
    bands = [(-100.0, -gap), (gap, max(gap + 5.0, min(far, 400.0)))]
    # 3. the plate layer: the band holding the longest row of similar, collinear regions
    best = None
    top1 = np.array([top_z])
    amp1 = None if amed is None else amed[None].astype(np.float32)
    for band in bands:
        fg = _segment(zmed[None], amp1, top1, band, smooth, use_amp, 0, h)  # all rows
        reg = _regions(fg, zmed[None], 0, inv, xr, yr, 3.0 if kind == "depth" else None, keep_pixels=True)
        cand = _plate_candidates(reg, min_area=10)
        if geometry is not None and cand.size:
            num = geometry.number(reg["x"][cand])
            cand = cand[num > 0]
        if cand.size >= 2 and (best is None or cand.size > best[2].size):
            best = (band, reg, cand)
    if best is None:
        raise SceneError(
            f"no row of plates next to the beam top (top at {top_z:.0f} mm, bands {bands} mm relative to it)"
        )
    band, reg, cand = best
    u, v = reg["u"][cand], reg["v"][cand]
    tol = max(2.0, float(np.median(reg["minor"][cand])))
    _, line = _line_fit(u, v, tol)
    if geometry is not None:
        plates = geometry.number(reg["x"][cand])
    else:
        plates = np.argsort(np.argsort(u)) + 1
    # a plate claimed twice is left out rather than guessed
    uniq, cnt = np.unique(plates, return_counts=True)
    single = np.isin(plates, uniq[cnt == 1])
    cand, plates = cand[single], plates[single]
    order = np.argsort(plates)
    cand, plates = cand[order], plates[order]
    elab, pix = reg["pixels"]
    track = [np.sort(pix[elab == c]) for c in cand]
    # rows searched per frame: the plates' rows plus a margin of twice their height
    height = reg["minor"][cand]
    margin = int(np.ceil(2 * height.max())) + 4
    r0 = max(0, int(np.floor(v.min() - margin)))
    r1 = min(h, int(np.ceil(v.max() + margin)) + 1)
    return Scene(
        kind=kind,
        height=h,
        width=w,
        inv_norm=inv,
        xr=xr,
        yr=yr,
        top_idx=top_idx,
        top_z_mm=top_z,
        floor_z_mm=floor_z,
        n_floor_targets=len(floor),
        sigma_mm=sigma,
        band=band,
        smooth=smooth,
        use_amplitude=use_amp,
        rows=(r0, r1),
        plates=plates.astype(np.int64),
        area=reg["area"][cand],
        ecc=reg["ecc"][cand],
        u=reg["u"][cand],
        v=reg["v"][cand],
        line=line,
        line_tol_px=tol,
        geometry=geometry,
        track=track,
    )


def detect_chunk(scene: Scene, frames: np.ndarray, amplitude: np.ndarray | None = None) -> np.ndarray:
    """Full detection in every frame of a chunk: (frame, plate, 3) centroids x, y, z in mm.

    Plates follow ``scene.plates``; NaN where a plate was not extracted.
    """
    b = frames.shape[0]
    n_pl = scene.plates.size
    out = np.full((b, n_pl, 3), np.nan)
    if b == 0 or n_pl == 0:
        return out
    r0, r1 = scene.rows
    b, h, w = frames.shape
    rng = scene.kind == "range"
    # only the rows searched and the top-surface pixels are converted to depth
    z = _zimage(frames[:, r0:r1], scene.inv_norm[r0:r1] if rng else None)
    ztop = np.asarray(frames.reshape(b, -1)[:, scene.top_idx], np.float32)
    if rng:
        ztop = ztop * scene.inv_norm.reshape(-1)[scene.top_idx]
    top = top_level(ztop, np.arange(ztop.shape[1]))
    fg = _segment(z, amplitude, top, scene.band, scene.smooth, scene.use_amplitude, r0, r1)
    reg = _regions(fg, z, r0, scene.inv_norm, scene.xr, scene.yr, 3.0 if scene.kind == "depth" else None)
    if reg["n"] == 0:
        return out
    lab = np.arange(1, reg["n"] + 1)
    num = np.where(reg["n_eroded"][lab] >= 3, scene.number(reg["x"][lab], reg["u"][lab]), 0)
    slot = np.searchsorted(scene.plates, num)
    slot = np.clip(slot, 0, n_pl - 1)
    known = (num > 0) & (scene.plates[slot] == num)
    # the region must look like its plate did at calibration (size, shape, on the line)
    ar = reg["area"][lab] / scene.area[slot]
    ok = (
        known
        & ~reg["border"][lab]
        & (ar > 0.6)
        & (ar < 1.6)
        & (np.abs(reg["ecc"][lab] - scene.ecc[slot]) < 0.2)
        & (reg["n_eroded"][lab] >= 3)
        & (np.abs(reg["v"][lab] - (scene.line[0] + scene.line[1] * reg["u"][lab])) <= 2 * scene.line_tol_px)
    )
    fr = reg["frame"][lab]
    key = fr * n_pl + slot
    # two plate-like regions claiming one plate in one frame: neither is trusted
    claims = np.bincount(key[ok], minlength=b * n_pl)
    ok &= claims[key] == 1
    sel = lab[ok]
    out[fr[ok], slot[ok]] = np.stack([reg["x"][sel], reg["y"][sel], reg["z"][sel]], axis=1)
    return out
