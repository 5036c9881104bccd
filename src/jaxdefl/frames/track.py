"""Real-time mode: plates detected once, then centroids inside the tracked pixel sets per frame.

After `calibrate_scene` every plate has a set of eroded pixels. Per frame only those pixels (and
the beam-top pixels) are read, on the scene's torch device: their 3D points (eq. 3.10 / 3.16)
are averaged per plate with one matrix product over the whole chunk. A plate whose pixels no
longer sit in the plate layer (mean depth outside the band, or fewer than 80 % valid pixels) is
*lost* in that frame; the caller re-detects those frames with the full pipeline and
recalibrates when plates drift or vanish for longer.
"""

from __future__ import annotations

import numpy as np
import torch

from .kernels import all_finite
from .pipeline import Scene, frames_tensor, top_level

__all__ = ["Tracker"]


class Tracker:
    """Centroids of the plates of a `Scene` from their tracked pixels, batched over frames."""

    def __init__(self, scene: Scene):
        self.scene = scene
        dev = torch.device(scene.device)
        sizes = [len(p) for p in scene.track]
        pix = np.concatenate(scene.track).astype(np.int64) if sizes else np.zeros(0, np.int64)
        seg = np.repeat(np.arange(len(sizes)), sizes)
        # the plates' pixels and the top surface's, read together from every frame
        self.pix = torch.as_tensor(np.concatenate([pix, scene.top_idx]), device=dev)
        self.n_pix = pix.size
        self.m = torch.zeros(pix.size, len(sizes), dtype=torch.float64, device=dev)
        self.m[torch.arange(pix.size, device=dev), torch.as_tensor(seg, device=dev)] = 1.0
        self.seg = torch.as_tensor(seg, device=dev)
        self.size = torch.as_tensor(sizes, dtype=torch.float64, device=dev)
        inv = torch.as_tensor(scene.inv_norm.reshape(-1), device=dev)[self.pix]
        self.inv = inv if scene.kind == "range" else None
        # pixel -> plate sums of a value, of the value times xr and times yr: (P, 3 x plates)
        xr = torch.as_tensor(scene.xr.reshape(-1)[pix], dtype=torch.float64, device=dev)
        yr = torch.as_tensor(scene.yr.reshape(-1)[pix], dtype=torch.float64, device=dev)
        self.sums = torch.cat([self.m, self.m * xr[:, None], self.m * yr[:, None]], 1)

    def centroids(self, frames) -> tuple[np.ndarray, np.ndarray]:
        """(frame, plate, 3) centroids in mm and (frame, plate) bool ``lost``."""
        b = frames.shape[0]
        f = frames_tensor(frames, self.scene.device)
        vals = f.reshape(b, -1).index_select(1, self.pix)
        if self.inv is not None:
            vals = vals * self.inv
        top = top_level(vals[:, self.n_pix :]).to(torch.float64)
        zc = vals[:, : self.n_pix].to(torch.float64) - top[:, None]  # small numbers: sums keep precision
        n = self.m.shape[1]
        if self.scene.kind == "range" and all_finite(zc):
            sw = self.sums.sum(0).expand(b, -1)  # every pixel counts
        else:
            valid = torch.isfinite(zc)
            zc = zc.nan_to_num_(0.0, 0.0, 0.0)
            w = valid.to(torch.float64)
            if self.scene.kind == "depth":  # drop pixels > 3 sigma from their plate's mean (region growing)
                cnt = (w @ self.m).clamp_min(1)
                res = (zc - ((zc @ self.m) / cnt)[:, self.seg]) * w
                sd = torch.sqrt((res * res) @ self.m / cnt)
                w = w * (res.abs() <= 3.0 * sd[:, self.seg] + 1e-6)
                zc = zc * w
            sw = w @ self.sums
        # per plate: sums of w, w xr, w yr and of z w, z w xr, z w yr (zc is 0 where w is)
        sw, sz = sw.reshape(b, 3, n), (zc @ self.sums).reshape(b, 3, n)
        cnt = sw[:, 0]
        c = cnt.clamp_min(1)
        rel = sz[:, 0] / c
        out = ((sz + top[:, None, None] * sw) / c[:, None]).transpose(1, 2)  # (b, n, [z, x, y])
        lo, hi = self.scene.band
        lost = (cnt < 0.8 * self.size) | ~((rel > lo) & (rel < hi))
        out = out.roll(-1, dims=2)  # x, y, z
        out[lost] = float("nan")
        return out.cpu().numpy(), lost.cpu().numpy()
