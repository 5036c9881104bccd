"""What the scene holds still: the beam geometry, and a camera's static points.

`BeamGeometry` is the beam frame's known landmarks (from a simulation config's ``[beam]``,
``[plates]`` and ``[scene]`` tables): x along the beam from the left support, y lateral from the
beam axis (plates on +y), z down from the beam top. `scene_points` back-projects a recording's
median frame (eq. 3.10) into camera-frame points; `plane_landmarks` keeps those that lie, under
the current pose, on the floor or on the beam top, averaged over blocks of pixels (neighbouring
pixels share their systematic range errors: a block is one landmark). `floor_targets` finds the
white disks on the black floor in the median amplitude image (the thesis' ellipses: a disk seen
at an angle): each is the amplitude-weighted mean of its pixels' points, matched to the nearest
disk of the known grid.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..simulate.scene import plate_centres_world

__all__ = ["BeamGeometry", "scene_points", "plane_landmarks", "floor_targets"]


@dataclass(frozen=True)
class BeamGeometry:
    plate_centres_mm: np.ndarray  # (plate, 3) top-face centres at rest, beam frame
    span_mm: float
    overhang_mm: float
    width_mm: float
    load_a_mm: float
    floor_z_mm: float  # the floor's depth below the beam top
    target_spacing_mm: float = 400.0  # white disks on the floor, centres at (k + 1/2) spacing
    target_radius_mm: float = 30.0

    @classmethod
    def from_config(cls, cfg) -> BeamGeometry:
        """From a `jaxdefl.simulate.SimConfig` (its beam, plates and scene tables)."""
        b = cfg.beam
        return cls(
            plate_centres_world(cfg),
            b.span_mm,
            b.overhang_mm,
            b.width_mm,
            b.load_a_mm,
            cfg.scene.floor_below_top_mm,
            cfg.scene.target_spacing_mm,
            cfg.scene.target_radius_mm,
        )

    def plate_x_mm(self) -> np.ndarray:
        return self.plate_centres_mm[:, 0]


def scene_points(frames: np.ndarray, intrinsics: dict, kind: str) -> np.ndarray:
    """(h, w, 3) camera-frame points of the per-pixel median of ``frames`` (frame, h, w), mm.

    ``kind`` "range": distance along each pixel's ray (ToF); "depth": camera Z (structured light).
    """
    med = np.nanmedian(np.asarray(frames, np.float64), axis=0)
    h, w = med.shape
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    ray = np.stack(
        [
            (u - intrinsics["cx"]) / intrinsics["fx"],
            (v - intrinsics["cy"]) / intrinsics["fy"],
            np.ones_like(u),
        ],
        -1,
    )
    scale = med / np.linalg.norm(ray, axis=-1) if kind == "range" else med
    return ray * scale[..., None]


def plane_landmarks(
    pts: np.ndarray, rot: np.ndarray, origin: np.ndarray, geo: BeamGeometry, tol_mm: float, block: int = 6
) -> tuple[np.ndarray, np.ndarray]:
    """Block means of the points on the floor and on the beam top under the pose (rot, origin).

    Returns:
        (landmark, 3) camera-frame points and (landmark,) their planes' beam-frame z.
    """
    h, w, _ = pts.shape
    beam = pts @ rot.T + origin
    x, y, z = beam[..., 0], beam[..., 1], beam[..., 2]
    ok = np.isfinite(z)
    far_from_supports = (np.abs(x) > 200) & (np.abs(x - geo.span_mm) > 200)
    # the floor, away from the supports and from under the beam and its plates
    floor = ok & (np.abs(z - geo.floor_z_mm) < tol_mm) & far_from_supports & (np.abs(y) > geo.width_mm)
    # the beam top, away from its edges and from under the spreader beam (mid-span, above it)
    spreader = (x > geo.load_a_mm - 200) & (x < geo.span_mm - geo.load_a_mm + 200)
    top = (
        ok
        & (np.abs(z) < tol_mm)
        & (np.abs(y) < geo.width_mm / 2 - 20)
        & (x > 50)
        & (x < geo.span_mm - 50)
        & ~spreader
    )
    out_p, out_z = [], []
    hb, wb = h // block, w // block
    for mask, height in ((floor, geo.floor_z_mm), (top, 0.0)):
        m = mask[: hb * block, : wb * block].reshape(hb, block, wb, block)
        p = np.where(mask[..., None], pts, 0.0)[: hb * block, : wb * block].reshape(hb, block, wb, block, 3)
        cnt = m.sum(axis=(1, 3))
        keep = cnt >= block * block // 3
        mean = p.sum(axis=(1, 3)) / np.maximum(cnt, 1)[..., None]
        out_p.append(mean[keep])
        out_z.append(np.full(int(keep.sum()), height))
    return np.concatenate(out_p), np.concatenate(out_z)


def floor_targets(
    pts: np.ndarray, amp: np.ndarray, rot: np.ndarray, origin: np.ndarray, geo: BeamGeometry, tol_mm: float
) -> tuple[np.ndarray, np.ndarray]:
    """Floor disks seen whole: (disk, 3) camera-frame centres and (disk, 3) their grid centres
    (beam frame, on the floor), under the pose (rot, origin)."""
    from scipy import ndimage

    beam = pts @ rot.T + origin
    floor = np.isfinite(beam[..., 2]) & (np.abs(beam[..., 2] - geo.floor_z_mm) < tol_mm)
    a = np.where(floor, np.asarray(amp, np.float64), np.nan)
    if not np.isfinite(a).any():
        return np.zeros((0, 3)), np.zeros((0, 3))
    bg = float(np.nanmedian(a))
    bright = floor & (a > 3.0 * bg)
    labels, n = ndimage.label(bright)
    if n == 0:
        return np.zeros((0, 3)), np.zeros((0, 3))
    h, w = floor.shape
    cams, grid = [], []
    sp = geo.target_spacing_mm
    for k, sl in enumerate(ndimage.find_objects(labels), start=1):
        comp = labels == k
        grown = ndimage.binary_dilation(comp)
        ring = ndimage.binary_dilation(grown) & ~grown
        r0, r1, c0, c1 = sl[0].start, sl[0].stop, sl[1].start, sl[1].stop
        # whole, on the floor all round, away from the image's edge
        if r0 < 2 or c0 < 2 or r1 > h - 2 or c1 > w - 2 or not floor[ring].all() or comp.sum() > 60:
            continue
        wgt = np.clip(a[grown] - bg, 0.0, None)
        if wgt.sum() <= 0:
            continue
        centre = (wgt[:, None] * pts[grown]).sum(axis=0) / wgt.sum()
        xb, yb = (centre @ rot.T + origin)[:2]
        gx, gy = (np.floor(xb / sp) + 0.5) * sp, (np.floor(yb / sp) + 0.5) * sp
        if np.hypot(xb - gx, yb - gy) < sp / 4:
            cams.append(centre)
            grid.append([gx, gy, geo.floor_z_mm])
    return np.reshape(cams, (-1, 3)), np.reshape(grid, (-1, 3))
