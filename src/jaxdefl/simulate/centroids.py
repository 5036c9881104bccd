"""Plate centroids measured from simulated ToF range frames (a reference extraction).

Uses the simulator's knowledge of which pixels lie inside each plate at rest (eroded by one pixel,
so mixed edge pixels are left out) and back-projects their ranges with eq. 3.10; the centroid is
the mean point. The engine's `frames/` stage does the same from the images alone.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from .config import SimConfig
from .scene import PixelModel, intrinsics, pixel_model

__all__ = ["measured_centroids", "plate_pixel_masks"]


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


def measured_centroids(
    cfg: SimConfig, t_s: np.ndarray, range_mm: np.ndarray, masks: dict[int, np.ndarray] | None = None
) -> pd.DataFrame:
    """Centroids (segment, t, plate, x, y, z) from ToF range frames (frame, h, w), eq. 3.10."""
    k = intrinsics(cfg)
    masks = masks if masks is not None else plate_pixel_masks(cfg)
    v, u = np.divmod(np.arange(k.width * k.height), k.width)
    x = (u - k.cx) / k.fx
    y = (v - k.cy) / k.fy
    norm = np.sqrt(x * x + y * y + 1)
    flat = np.asarray(range_mm).reshape(len(t_s), -1)
    rows = []
    for plate, idx in masks.items():
        z = flat[:, idx] / norm[idx]
        rows.append(
            pd.DataFrame(
                {
                    "segment": cfg.recording.segment,
                    "t": np.asarray(t_s),
                    "plate": plate,
                    "x": np.nanmean(z * x[idx], axis=1),
                    "y": np.nanmean(z * y[idx], axis=1),
                    "z": np.nanmean(z, axis=1),
                }
            )
        )
    return pd.concat(rows, ignore_index=True)
