"""Plate centroids measured from simulated ToF frames (a reference extraction).

z (and, without amplitude images, x and y): the simulator knows which pixels lie inside each
plate at rest; eroded by one pixel (mixed edge pixels left out), their ranges are back-projected
with eq. 3.10 and averaged, as the thesis does (5.1.4). The engine's `frames/` stage does the same
from the images alone.

x and y with amplitude images: a range camera's interior pixel looks along a fixed ray, and a
plate sliding in its own plane (the beam's longitudinal and lateral motion) leaves that ray's
range unchanged, so the mean of fixed interior pixels cannot follow the plate in x and y (and
gains a spurious perspective term, the fixed rays meeting the plate farther out as it moves
down). Only the mixed pixels at the plate's edges see the motion, through how much of them the
plate covers. With ``amplitude`` frames the plate's image position is therefore the
coverage-weighted mean of the pixel directions over the plate and a one-pixel ring around it
(coverage from the amplitude, between the background ring's level and the plate interior's),
back-projected at the interior's depth: sub-pixel, and free of the perspective term.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from .config import SimConfig
from .scene import PixelModel, intrinsics, pixel_model

__all__ = ["measured_centroids", "plate_pixel_masks", "plate_pixel_rings"]


def plate_pixel_masks(
    cfg: SimConfig, pm: PixelModel | None = None, erode_px: float = 1.0
) -> dict[int, np.ndarray]:
    """{plate: flat pixel indices} of pixels whose footprint lies inside the plate, eroded."""
    pm = pm if pm is not None else pixel_model(cfg, supersample=1)
    fp, e = pm.plate_foot, pm.plate_edges
    wx = (fp[:, 1] - fp[:, 0]) * erode_px
    wy = (fp[:, 3] - fp[:, 2]) * erode_px
    out = {}
    for p in range(len(e)):
        inside = (
            (pm.plate_idx == p)
            & (fp[:, 0] - wx >= e[p, 0])
            & (fp[:, 1] + wx <= e[p, 1])
            & (fp[:, 2] - wy >= e[p, 2])
            & (fp[:, 3] + wy <= e[p, 3])
            & (pm.plate_occ == 0)
        )
        idx = np.flatnonzero(inside)
        if idx.size:
            out[p + 1] = idx
    return out


def plate_pixel_rings(
    cfg: SimConfig, pm: PixelModel | None = None
) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """{plate: (extent, ring)} flat pixel indices, unoccluded: ``extent`` overlaps the plate's
    rectangle grown by one pixel (interior, mixed edges, and where the edges move to); ``ring``
    the next pixel layer out (background only)."""
    pm = pm if pm is not None else pixel_model(cfg, supersample=1)
    fp, e = pm.plate_foot, pm.plate_edges
    wx, wy = fp[:, 1] - fp[:, 0], fp[:, 3] - fp[:, 2]
    free = pm.plate_occ == 0

    def overlaps(p, grow):
        return (
            (fp[:, 1] > e[p, 0] - grow * wx)
            & (fp[:, 0] < e[p, 1] + grow * wx)
            & (fp[:, 3] > e[p, 2] - grow * wy)
            & (fp[:, 2] < e[p, 3] + grow * wy)
        )

    out = {}
    for p in range(len(e)):
        one, two = overlaps(p, 1.0), overlaps(p, 2.0)
        if (one & free).any():
            out[p + 1] = (np.flatnonzero(one & free), np.flatnonzero(two & ~one & free))
    return out


def measured_centroids(
    cfg: SimConfig,
    t_s: np.ndarray,
    range_mm: np.ndarray,
    masks: dict[int, np.ndarray] | None = None,
    amplitude: np.ndarray | None = None,
) -> pd.DataFrame:
    """Centroids (segment, t, plate, x, y, z) from ToF range frames (frame, h, w), eq. 3.10.

    With ``amplitude`` frames (frame, h, w), x and y follow the plate's image (see module doc).
    """
    k = intrinsics(cfg)
    pm = pixel_model(cfg, supersample=1) if masks is None or amplitude is not None else None
    masks = masks if masks is not None else plate_pixel_masks(cfg, pm)
    rings = plate_pixel_rings(cfg, pm) if amplitude is not None else {}
    v, u = np.divmod(np.arange(k.width * k.height), k.width)
    x = (u - k.cx) / k.fx
    y = (v - k.cy) / k.fy
    norm = np.sqrt(x * x + y * y + 1)
    flat = np.asarray(range_mm).reshape(len(t_s), -1)
    amp = None if amplitude is None else np.asarray(amplitude, np.float64).reshape(len(t_s), -1)
    rows = []
    for plate, idx in masks.items():
        z = flat[:, idx] / norm[idx]
        zc = np.nanmean(z, axis=1)
        if plate in rings and rings[plate][1].size:
            ext, ring = rings[plate]
            a_in = np.nanmedian(amp[:, idx], axis=1)[:, None]
            a_bg = np.nanmedian(amp[:, ring], axis=1)[:, None]
            w = np.clip((amp[:, ext] - a_bg) / (a_in - a_bg), 0.0, 1.0)
            w[:, np.isin(ext, idx)] = 1.0  # the eroded interior is covered whatever the noise
            sw = w.sum(axis=1)
            xc = zc * (w @ x[ext]) / sw
            yc = zc * (w @ y[ext]) / sw
        else:
            xc = np.nanmean(z * x[idx], axis=1)
            yc = np.nanmean(z * y[idx], axis=1)
        rows.append(
            pd.DataFrame(
                {
                    "segment": cfg.recording.segment,
                    "t": np.asarray(t_s),
                    "plate": plate,
                    "x": xc,
                    "y": yc,
                    "z": zc,
                }
            )
        )
    return pd.concat(rows, ignore_index=True)
