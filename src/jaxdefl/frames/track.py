"""Real-time mode: plates detected once, then centroids inside the tracked pixel sets per frame.

After `calibrate_scene` every plate has a set of eroded pixels. Per frame only those pixels are
read: their 3D points (eq. 3.10 / 3.16) are averaged per plate with one matrix product over the
whole chunk. A plate whose pixels no longer sit in the plate layer (mean depth outside the band,
or fewer than 80 % valid pixels) is *lost* in that frame; the caller re-detects those frames with
the full pipeline and recalibrates when plates drift or vanish for longer.
"""

from __future__ import annotations

import numpy as np

from .pipeline import Scene, top_level

__all__ = ["Tracker"]


class Tracker:
    """Centroids of the plates of a `Scene` from their tracked pixels, batched over frames."""

    def __init__(self, scene: Scene):
        self.scene = scene
        sizes = [len(p) for p in scene.track]
        self.pix = np.concatenate(scene.track) if sizes else np.zeros(0, np.int64)
        seg = np.repeat(np.arange(len(sizes)), sizes)
        self.m = np.zeros((self.pix.size, len(sizes)))
        self.m[np.arange(self.pix.size), seg] = 1.0
        self.seg = seg
        self.size = np.asarray(sizes, np.float64)
        inv = scene.inv_norm.reshape(-1) if scene.kind == "range" else None
        self.inv = None if inv is None else inv[self.pix].astype(np.float64)
        self.inv_top = None if inv is None else inv[scene.top_idx]
        self.xr = scene.xr.reshape(-1)[self.pix].astype(np.float64)
        self.yr = scene.yr.reshape(-1)[self.pix].astype(np.float64)

    def centroids(self, frames: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(frame, plate, 3) centroids in mm and (frame, plate) bool ``lost``."""
        b = frames.shape[0]
        flat = frames.reshape(b, -1)
        vals = flat[:, self.pix].astype(np.float64)
        z = vals if self.inv is None else vals * self.inv
        ztop = flat[:, self.scene.top_idx]
        ztop = ztop if self.inv_top is None else ztop * self.inv_top
        top = top_level(ztop, np.arange(ztop.shape[1]))
        zc = z - top[:, None]  # small numbers: sums keep their precision
        valid = np.isfinite(zc)
        zc = np.where(valid, zc, 0.0)
        w = valid.astype(np.float64)
        if self.scene.kind == "depth":  # drop pixels > 3 sigma from their plate's mean (region growing)
            cnt = np.maximum(w @ self.m, 1)
            mean = (zc @ self.m) / cnt
            res = np.where(valid, zc - mean[:, self.seg], 0.0)
            sd = np.sqrt((res * res) @ self.m / cnt)
            w = w * (np.abs(res) <= 3.0 * sd[:, self.seg] + 1e-6)
        cnt = w @ self.m
        c = np.maximum(cnt, 1)
        zw = zc * w
        rel = (zw @ self.m) / c
        zabs = rel + top[:, None]
        x = ((zw * self.xr) @ self.m + top[:, None] * ((w * self.xr) @ self.m)) / c
        y = ((zw * self.yr) @ self.m + top[:, None] * ((w * self.yr) @ self.m)) / c
        lo, hi = self.scene.band
        lost = (cnt < 0.8 * self.size) | ~((rel > lo) & (rel < hi))
        out = np.stack([x, y, zabs], axis=-1)
        out[lost] = np.nan
        return out, lost
