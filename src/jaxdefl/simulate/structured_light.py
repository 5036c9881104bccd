"""Structured-light camera (Kinect-class): depth from quantised disparity, plus its instability.

Depth z follows from the disparity d = b f / z (eq. 3.11). The disparity is measured with noise
and quantised to a sub-pixel step q, so depth comes in steps Δz = z² q / (b f) that grow with z²;
q is set from the nominal depth resolution at 2 m (Table 4.2). Mixed pixels at plate edges take
the coverage-weighted depth (flying pixels). On top: a frame-common depth jitter, a per-session
mean shift (Table 6.21: sessions differ by about 17 mm) and level jumps inside a record (the
discontinuity of Fig. 6.64), arriving as a Poisson process.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .config import SimConfig
from .scene import KIND_BEAM_TOP, KIND_SPREADER, KIND_STATIC, PixelModel

__all__ = [
    "KinectModel",
    "kinect_model",
    "level_jump_path",
    "render_kinect",
    "session_offsets_mm",
    "quantisation_step_px",
]

_KINDS = (KIND_STATIC, KIND_BEAM_TOP, KIND_SPREADER)


def quantisation_step_px(cfg: SimConfig, fx: float) -> float:
    """Disparity step q such that the depth step at 2 m equals the nominal resolution."""
    cam = cfg.camera
    return cam.depth_resolution_mm_at_2m * cam.baseline_mm * fx / 2000.0**2


@dataclass(frozen=True)
class KinectModel:
    bf: float  # baseline x focal length (mm px)
    q_px: float
    bg_w: np.ndarray  # (p, 3) coverage of each component
    bg_depth: np.ndarray  # (p, 3) mean depth at rest
    bg_gain: np.ndarray  # (p, 3) d depth / d mid-span deflection
    plate_depth: np.ndarray  # (p,)
    plate_gain: np.ndarray  # (p,)
    plate_idx: np.ndarray
    plate_foot: np.ndarray
    plate_occ: np.ndarray
    plate_edges: np.ndarray
    ir: np.ndarray  # (p,) IR intensity (reflectivity-based), the amplitude image


def kinect_model(cfg: SimConfig, pm: PixelModel) -> KinectModel:
    """Aggregate the static ray-cast into per-pixel depth components."""
    nsub = pm.sub_kind.shape[1]
    w, dep, gain = [], [], []
    for kind in _KINDS:
        m = pm.sub_kind == kind
        cnt = m.sum(axis=1)
        w.append(cnt / nsub)
        safe = np.maximum(cnt, 1)
        dep.append((pm.sub_depth_mm * m).sum(axis=1) / safe)
        gain.append((pm.sub_gain_depth * m).sum(axis=1) / safe)
    pidx = pm.plate_idx
    shape = np.where(pidx >= 0, pm.plate_shape[np.maximum(pidx, 0)], 0.0)
    return KinectModel(
        bf=cfg.camera.baseline_mm * pm.intr.fx,
        q_px=quantisation_step_px(cfg, pm.intr.fx),
        bg_w=np.stack(w, 1),
        bg_depth=np.stack(dep, 1),
        bg_gain=np.stack(gain, 1),
        plate_depth=pm.plate_depth_mm,
        plate_gain=shape,
        plate_idx=pidx,
        plate_foot=pm.plate_foot,
        plate_occ=pm.plate_occ,
        plate_edges=pm.plate_edges,
        ir=(1000.0 * pm.sub_bright.mean(axis=1)).astype(np.float32),
    )


def session_offsets_mm(cfg: SimConfig, t_s: np.ndarray, seed: int, duration_s: float) -> np.ndarray:
    """Session mean shift plus level jumps (Poisson in time) at epoch times ``t_s``."""
    cam = cfg.camera
    rng = np.random.default_rng([seed, 31])
    shift = rng.normal(0.0, cam.session_shift_mm / np.sqrt(2.0))
    return shift + level_jump_path(rng, cam.jumps_per_minute, cam.jump_mm, t_s, cfg.t0_s, duration_s)


def level_jump_path(
    rng: np.random.Generator, per_minute: float, jump_mm: float, t_s, t0_s: float, duration_s: float
) -> np.ndarray:
    """The depth image's level jumps at times ``t_s``: a Poisson count at ``per_minute`` over
    ``duration_s`` from ``t0_s``, uniform times, N(0, ``jump_mm``) sizes, cumulated (mm)."""
    n_jumps = rng.poisson(per_minute * max(duration_s, 0.0) / 60.0)
    t_j = t0_s + np.sort(rng.uniform(0, max(duration_s, 1e-9), n_jumps))
    cum = np.concatenate([[0.0], np.cumsum(rng.normal(0.0, jump_mm, n_jumps))])
    return cum[np.searchsorted(t_j, np.asarray(t_s), side="right")]


def render_kinect(
    km: KinectModel,
    cfg: SimConfig,
    frame_index: np.ndarray,
    defl: np.ndarray,
    dx: np.ndarray,
    dy: np.ndarray,
    offsets_mm: np.ndarray,
    seed: int,
):
    """Depth (frame, p) in mm (NaN where no disparity) and the IR image for each frame."""
    cam = cfg.camera
    n, p = len(frame_index), km.bg_w.shape[0]
    out = np.empty((n, p), np.float32)
    # The background is linear in the deflection: z_bg = Σ_k w_k (depth_k + gain_k d) = a + b d.
    bg_a = (km.bg_w * km.bg_depth).sum(axis=1)
    bg_b = (km.bg_w * km.bg_gain).sum(axis=1)
    # Only pixels a plate's footprint can cover mix plate and background depth.
    on = np.flatnonzero((km.plate_idx >= 0) & (km.plate_occ < 1))
    ii = km.plate_idx[on]
    fp, e = km.plate_foot[on], km.plate_edges[ii]
    area = (fp[:, 1] - fp[:, 0]) * (fp[:, 3] - fp[:, 2])
    keep = 1 - km.plate_occ[on]
    p_depth, p_gain = km.plate_depth[on], km.plate_gain[on]
    sigma_px = cam.disparity_noise_px * cam.noise_scale
    z = np.empty(p)
    for j, fi in enumerate(frame_index):
        rng = np.random.default_rng([seed, 29, int(fi)])
        d = defl[j]
        ox = np.clip(np.minimum(fp[:, 1], e[:, 1] + dx[j]) - np.maximum(fp[:, 0], e[:, 0] + dx[j]), 0, None)
        oy = np.clip(np.minimum(fp[:, 3], e[:, 3] + dy[j]) - np.maximum(fp[:, 2], e[:, 2] + dy[j]), 0, None)
        f = ox * oy / area * keep
        np.multiply(bg_b, d, out=z)
        z += bg_a
        z[on] = (1 - f) * z[on] + f * (p_depth + p_gain * d)
        disp = km.bf / z
        disp += sigma_px * rng.standard_normal(p)
        np.round(disp / km.q_px, out=disp)
        disp *= km.q_px
        common = cam.frame_noise_mm * cam.noise_scale * rng.standard_normal()
        with np.errstate(divide="ignore"):
            out[j] = np.where(disp > 0, km.bf / disp + common + offsets_mm[j], np.nan)
    return out, np.broadcast_to(km.ir, (n, p))
