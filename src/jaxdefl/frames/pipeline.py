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
   position as a template. The level search, the top surface and the plate layer use the same
   tensor kernels as the per-frame stages (on a stack of one frame, or of one mask per level).
2. **Per frame**, batched on (B, 1, h, w) torch tensors on the scene's device (the kernels of
   `kernels.py`: kornia morphology, run-based labelling, closed-form moments), over the rows
   where the plates can be: depth relative to that frame's beam-top level (a per-frame median,
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
import torch
import torch.nn.functional as F

from .._numerics import mad_sigma
from .floor import floor_targets
from .kernels import all_finite, erode, flat_indices, label_components, opening, otsu_threshold, region_stats

__all__ = ["PlateGeometry", "Scene", "calibrate_scene", "detect_chunk", "ray_factors", "SceneError"]

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
    device: str = "cpu"  # torch device of the per-frame stages
    cache: dict = field(default_factory=dict, repr=False, compare=False)  # tensors on the device

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


def _tensors(scene: Scene) -> dict:
    """The scene's per-pixel arrays as tensors on its device (made once, kept on the scene)."""
    t = scene.cache
    if not t:
        dev = scene.device
        t["inv"] = torch.as_tensor(scene.inv_norm, device=dev)
        t["xr"] = torch.as_tensor(scene.xr, device=dev).reshape(-1)
        t["yr"] = torch.as_tensor(scene.yr, device=dev).reshape(-1)
        t["top_idx"] = torch.as_tensor(scene.top_idx, device=dev)
        t["inv_top"] = t["inv"].reshape(-1)[t["top_idx"]]
    return t


def frames_tensor(frames, device) -> torch.Tensor:
    """(frame, h, w) frames as a float32 tensor on ``device`` (no copy for float32 on the CPU)."""
    if isinstance(frames, torch.Tensor):
        return frames.to(device=device, dtype=torch.float32)
    return torch.as_tensor(np.asarray(frames, np.float32), device=device)


def top_level(ztop: torch.Tensor) -> torch.Tensor:
    """Per-frame beam-top depth (B,): lower median over the top-surface pixels (B, K), NaN ignored.

    The lower of the two middle values (``torch.nanmedian``); NaN for a frame without valid pixels.
    On the CPU by a numpy sort: torch's selection (nanmedian, kthvalue) is several times slower there.
    """
    if ztop.device.type != "cpu":
        return torch.nanmedian(ztop, dim=1).values
    t = np.sort(ztop.numpy(), axis=1)  # NaN sort last
    n = (~np.isnan(t)).sum(1)
    med = t[np.arange(t.shape[0]), np.maximum(n - 1, 0) // 2]
    med[n == 0] = np.nan
    return torch.from_numpy(med)


def _box_mean(z: torch.Tensor, k: int) -> torch.Tensor:
    """k x k mean of every frame (B, 1, h, w) over the pixels inside the frame (a NaN spoils its windows)."""
    if k <= 1:
        return z
    return F.avg_pool2d(z, k, stride=1, padding=k // 2, count_include_pad=False)


def _segment(z: torch.Tensor, amp: torch.Tensor | None, top: torch.Tensor, band, smooth: int) -> torch.Tensor:
    """Foreground (B, 1, h, w) bool: depth band relative to ``top`` (B,), then Otsu on ``amp``.

    ``z`` and ``amp`` (B, 1, h, w) float32 hold the same rows of the frames.
    """
    zs = _box_mean(z, smooth)
    rel = zs - top[:, None, None, None]
    fg = (rel > band[0]) & (rel < band[1])
    if smooth > 1:
        # smoothness constraint (as in region growing, Rabbani et al. 2006): the plates are
        # flat, the side faces of the spreader beam and the mixed edges are steep
        lim = 2 * _GRAD_MAX_MM_PER_PX
        flat = torch.ones_like(fg)
        flat[..., 1:-1] = (zs[..., 2:] - zs[..., :-2]).abs() < lim
        flat[..., 1:-1, :] &= (zs[..., 2:, :] - zs[..., :-2, :]).abs() < lim
        fg &= flat
    if amp is not None:
        # Otsu on the amplitude masked by the band (eq. 5.22-5.24): the other pixels count as zeros
        masked = amp * fg if all_finite(amp) else torch.where(fg, amp, 0.0)
        thr = otsu_threshold(masked).to(amp.dtype)
        fg &= amp > thr[:, None, None, None]
    return fg


def _regions(
    fg: torch.Tensor,
    z: torch.Tensor,
    r0: int,
    scene_px: dict,
    clip_sigma: float | None,
    keep_pixels: bool = False,
) -> dict:
    """Label, measure, erode and average: per-region numpy arrays (labels over the whole stack).

    ``fg`` and ``z`` (B, 1, h, w) hold rows r0:r0+h of frames ``scene_px["height"]`` rows high;
    ``scene_px``: ``xr``, ``yr`` (flat, whole frame) tensors. Every array has one entry per region
    (n of them); ``pixels``: per eroded pixel its region and flat pixel index in the frame.
    """
    # only the rows where some frame has foreground: the others change no label, moment or erosion
    rows = flat_indices(fg.any(dim=3).any(dim=0)[0])
    if rows.numel() == 0:
        return {"n": 0}
    c0, c1 = int(rows[0]), int(rows[-1]) + 1
    fg, z, r0 = fg[:, :, c0:c1], z[:, :, c0:c1], r0 + c0
    b, _, h, w = fg.shape
    labels, n = label_components(fg)
    out: dict = {"n": n}
    st = region_stats(labels, n, row0=r0, height=scene_px["height"])
    # erosion drops the mixed pixels at plate edges (thesis 5.1.4)
    idx = flat_indices(erode(fg))
    zz = z.reshape(-1)[idx].to(torch.float64)
    finite = torch.isfinite(zz)
    if not bool(finite.all()):
        idx, zz = idx[finite], zz[finite]
    lab = labels.reshape(-1)[idx].long() - 1
    pix = idx % (h * w) + r0 * w  # flat pixel index in the full frame
    if clip_sigma is not None and idx.numel():
        # pixels farther than clip_sigma x the region's scatter from its mean depth are not the plate's
        cnt = torch.bincount(lab, minlength=n).clamp_min(1)
        res = zz - (torch.bincount(lab, zz, minlength=n) / cnt)[lab]
        sd = torch.sqrt(torch.bincount(lab, res * res, minlength=n) / cnt)
        ok = res.abs() <= clip_sigma * sd[lab] + 1e-6
        lab, pix, zz = lab[ok], pix[ok], zz[ok]
    ne = torch.bincount(lab, minlength=n).to(torch.float64)
    nn = ne.clamp_min(1)
    xr, yr = scene_px["xr"][pix].to(torch.float64), scene_px["yr"][pix].to(torch.float64)
    res = dict(
        area=st["area"],
        u=st["u"],
        v=st["v"],
        ecc=st["eccentricity"],
        minor=st["minor"],
        border=st["border"],
        frame=st["frame"],
        n_eroded=ne,
        x=torch.bincount(lab, zz * xr, minlength=n) / nn,
        y=torch.bincount(lab, zz * yr, minlength=n) / nn,
        z=torch.bincount(lab, zz, minlength=n) / nn,
    )
    if keep_pixels:
        res["pixels"] = (lab, pix)
    for k, v in res.items():
        out[k] = tuple(x.cpu().numpy() for x in v) if k == "pixels" else v.cpu().numpy()
    return out


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
    ok = (reg["area"] >= min_area) & ~reg["border"] & (reg["n_eroded"] >= 3)
    lab = np.flatnonzero(ok)
    if lab.size == 0:
        return lab
    med = np.median(reg["area"][lab])
    lab = lab[(reg["area"][lab] > 0.3 * med) & (reg["area"][lab] < 3 * med)]
    if lab.size < 2:
        return lab
    tol = max(2.0, float(np.median(reg["minor"][lab])))
    keep, _ = _line_fit(reg["u"][lab], reg["v"][lab], tol)
    return lab[keep]


def _regions_of(masks: torch.Tensor) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Labels (B, h, w), per-region area (n,) and per-region frame (n,) of masks (B, 1, h, w)."""
    labels, n = label_components(masks)
    if n == 0:
        return labels[:, 0].cpu().numpy(), np.zeros(0), np.zeros(0, np.int64)
    st = region_stats(labels, n)
    return labels[:, 0].cpu().numpy(), st["area"].cpu().numpy(), st["frame"].cpu().numpy()


def calibrate_scene(
    frames: np.ndarray,
    amplitude: np.ndarray | None,
    intrinsics: dict,
    kind: str,
    geometry: PlateGeometry | None = None,
    n_median: int = 15,
    device: str = "cpu",
) -> Scene:
    """Find the floor, the beam top and the plates in the first frames of a recording.

    Args:
        frames: (frame, h, w) range (``kind="range"``) or depth (``"depth"``) in mm.
        amplitude: (frame, h, w) or None. intrinsics: fx, fy, cx, cy.
        geometry: plate positions for numbering; None numbers plates 1.. by image column.
        device: torch device of the per-frame stages (here and in `detect_chunk`, `Tracker`).
    Raises:
        SceneError: no plate layer found.
    """
    _, h, w = frames.shape
    dev = torch.device(device)
    inv, xr, yr = ray_factors(
        h, w, intrinsics["fx"], intrinsics["fy"], intrinsics["cx"], intrinsics["cy"], kind
    )
    nm = min(n_median, frames.shape[0])
    z_all = _zimage(frames[:nm], inv if kind == "range" else None)
    with np.errstate(all="ignore"):
        zmed = np.nanmedian(z_all, axis=0).astype(np.float32)
    amed = None if amplitude is None else np.median(np.asarray(amplitude[:nm], np.float32), axis=0)
    # 1. floor targets (first depth threshold)
    floor = (
        floor_targets(amed, zmed, device=device)
        if amed is not None and np.ptp(amed) > 0
        else np.zeros((0, 3))
    )
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
    if pk.size == 0:
        raise SceneError("no depth level found")
    levels = centres[pk]
    # opened by one pixel: a surface is thicker than the thin strip where a slanted side face
    # (the beam's, next to the plates bonded at its bottom) crosses the level; all levels at once
    near = torch.as_tensor(np.abs(zmed[None] - levels[:, None, None].astype(np.float32)) < 10, device=dev)
    _, area, frame = _regions_of(opening(near[:, None]))
    biggest = np.zeros(levels.size)
    np.maximum.at(biggest, frame, area)
    large = levels[biggest >= 0.2 * biggest.max()]
    if not np.isfinite(floor_z) and len(large) > 1:
        large = large[:-1]  # no floor targets: the farthest large level is the floor
    mode = large.max()
    lab, sizes, _ = _regions_of(torch.as_tensor(np.abs(zmed - mode) < 10, device=dev)[None, None])
    big = np.flatnonzero(sizes >= 0.25 * sizes.max()) + 1
    surface = torch.as_tensor(np.isin(lab, big), device=dev)[:, None]
    top_mask = erode(surface, 5)[0, 0].cpu().numpy()  # two 3x3 erosions
    if top_mask.sum() < 20:
        top_mask = surface[0, 0].cpu().numpy()
    top_idx = np.flatnonzero(top_mask.ravel())
    top_z = float(np.median(zmed.ravel()[top_idx]))
    if top_idx.size > 2048:
        top_idx = top_idx[np.linspace(0, top_idx.size - 1, 2048).astype(np.int64)]
    smooth = 5 if kind == "depth" else 0
    use_amp = kind == "range" and amplitude is not None
    zmed_t = torch.as_tensor(zmed, device=dev)[None, None]
    # per-pixel noise of the segmentation image on the top surface (one frame, not the median)
    z0 = torch.as_tensor(z_all[:1], device=dev)[:, None]
    zs0 = _box_mean(z0, smooth).reshape(-1).cpu().numpy()[top_idx]
    sigma = mad_sigma(zs0[~np.isnan(zs0)])
    gap = max(5.0, 4.0 * sigma)
    far = (floor_z - top_z - 50.0) if np.isfinite(floor_z) else 400.0
    bands = [(-100.0, -gap), (gap, max(gap + 5.0, min(far, 400.0)))]
    # 3. the plate layer: the band holding the longest row of similar, collinear regions
    best = None
    top1 = torch.tensor([top_z], dtype=torch.float32, device=dev)
    amp1 = torch.as_tensor(amed, device=dev)[None, None] if use_amp else None
    px = dict(
        height=h,
        xr=torch.as_tensor(xr, device=dev).reshape(-1),
        yr=torch.as_tensor(yr, device=dev).reshape(-1),
    )
    for band in bands:
        fg = _segment(zmed_t, amp1, top1, band, smooth)  # all rows
        reg = _regions(fg, zmed_t, 0, px, 3.0 if kind == "depth" else None, keep_pixels=True)
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
        device=str(dev),
    )


def detect_chunk(scene: Scene, frames, amplitude=None) -> np.ndarray:
    """Full detection in every frame of a chunk: (frame, plate, 3) centroids x, y, z in mm.

    ``frames``, ``amplitude``: (frame, h, w) arrays or tensors; the work runs on ``scene.device``.
    Plates follow ``scene.plates``; NaN where a plate was not extracted.
    """
    b = frames.shape[0]
    n_pl = scene.plates.size
    out = np.full((b, n_pl, 3), np.nan)
    if b == 0 or n_pl == 0:
        return out
    r0, r1 = scene.rows
    t = _tensors(scene)
    f = frames_tensor(frames, scene.device)
    # only the rows searched and the top-surface pixels are converted to depth
    z = f[:, None, r0:r1]
    ztop = f.reshape(b, -1)[:, t["top_idx"]]
    if scene.kind == "range":
        z = z * t["inv"][r0:r1]
        ztop = ztop * t["inv_top"]
    amp = None
    if scene.use_amplitude and amplitude is not None:
        amp = frames_tensor(amplitude, scene.device)[:, None, r0:r1]
    fg = _segment(z, amp, top_level(ztop), scene.band, scene.smooth)
    px = dict(height=scene.height, xr=t["xr"], yr=t["yr"])
    reg = _regions(fg, z, r0, px, 3.0 if scene.kind == "depth" else None)
    if reg["n"] == 0:
        return out
    num = np.where(reg["n_eroded"] >= 3, scene.number(reg["x"], reg["u"]), 0)
    slot = np.clip(np.searchsorted(scene.plates, num), 0, n_pl - 1)
    known = (num > 0) & (scene.plates[slot] == num)
    # the region must look like its plate did at calibration (size, shape, on the line)
    ar = reg["area"] / scene.area[slot]
    ok = (
        known
        & ~reg["border"]
        & (ar > 0.6)
        & (ar < 1.6)
        & (np.abs(reg["ecc"] - scene.ecc[slot]) < 0.2)
        & (reg["n_eroded"] >= 3)
        & (np.abs(reg["v"] - (scene.line[0] + scene.line[1] * reg["u"])) <= 2 * scene.line_tol_px)
    )
    fr = reg["frame"]
    key = fr * n_pl + slot
    # two plate-like regions claiming one plate in one frame: neither is trusted
    claims = np.bincount(key[ok], minlength=b * n_pl)
    ok &= claims[key] == 1
    out[fr[ok], slot[ok]] = np.stack([reg["x"][ok], reg["y"][ok], reg["z"][ok]], axis=1)
    return out
