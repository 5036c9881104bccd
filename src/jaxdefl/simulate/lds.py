"""Laser displacement sensors and the true plate trajectories (no frames rendered).

LDS: vertical deflection under the plate centroid, downward positive (the same sign as the
camera-frame z of the truth table), sampled at 300 Hz with 2 µm white noise. A defective sensor
(the thesis' plate 9) reads the deflection with a wrong gain and much more noise.

Truth: the plate top-face centroids in the camera frame (mm) at the delivered frame timestamps.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from .config import SimConfig
from .injection import mode_displacement, plate_motion
from .scene import beam_shape, camera_origin, camera_rotation, kinematics, plate_centres_world

__all__ = ["frame_clock", "truth_table", "lds_block", "usable_reference", "LDS_BLOCK_S"]

LDS_BLOCK_S = 60.0  # LDS noise is drawn per block of this length, whatever the chunking


def frame_clock(cfg: SimConfig, duration_s: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(frame indices, epoch timestamps) of the delivered frames: drop-outs removed.

    Frame k starts at t0 + k / f_s (+ optional Gaussian jitter); each frame is lost with
    probability ``camera.dropout_prob``.
    """
    cam = cfg.camera
    n = int(np.floor(duration_s * cam.frame_rate_hz + 1e-9))
    rng = np.random.default_rng([seed, 11])
    keep = rng.random(n) >= cam.dropout_prob
    jitter = rng.normal(0.0, cam.timestamp_jitter_ms * 1e-3, n) if cam.timestamp_jitter_ms > 0 else 0.0
    t = cfg.t0_s + np.arange(n) / cam.frame_rate_hz + jitter
    idx = np.flatnonzero(keep)
    return idx, t[idx]


def truth_table(cfg: SimConfig, t_s: np.ndarray, frame: str = "camera") -> pd.DataFrame:
    """True plate centroids (segment, t, plate, x, y, z) at times ``t_s``: in the camera frame,
    or with ``frame="beam"`` in the world (beam) frame: x along the beam from the left support, y
    lateral, z down from the beam top."""
    t_s = np.asarray(t_s, np.float64)
    defl, dx, dy = kinematics(cfg, t_s)
    c = plate_centres_world(cfg) - np.array([cfg.camera.x_mm, cfg.camera.y_mm, -cfg.camera.standoff_mm])
    shape = beam_shape(c[:, 0] + cfg.camera.x_mm, cfg.beam.span_mm, cfg.beam.load_a_mm)
    n, m = len(t_s), len(c)
    motion = shape[None, :] * defl[:, None]
    modal = mode_displacement(cfg.effects, t_s - cfg.t0_s, (c[:, 0] + cfg.camera.x_mm) / cfg.beam.span_mm)
    if modal is not None:  # other bending modes, each in its own shape
        motion = motion + modal
    dxp, dyp = np.repeat(dx[:, None], m, axis=1), np.repeat(dy[:, None], m, axis=1)
    # a plate's own motion (a debonded plate follows the beam only partly)
    plate_motion(cfg.effects, t_s - cfg.t0_s, motion, dxp, dyp, cfg.loading.mean_mm * shape)
    xyz = np.stack([c[:, 0][None, :] + dxp, c[:, 1][None, :] + dyp, c[:, 2][None, :] + motion], -1)
    if frame == "camera":
        rot = camera_rotation(cfg.camera)
        if rot is not None:  # a turned camera: R^T (p - C)
            xyz = xyz @ rot
    else:
        xyz = xyz + camera_origin(cfg.camera)
    # time-major rows (every plate at one instant, then the next), so that files written in
    # chunks of frames are identical whatever the chunk size
    return pd.DataFrame(
        {
            "segment": cfg.recording.segment,
            "t": np.repeat(t_s, m),
            "plate": np.tile(np.arange(1, m + 1), n),
            "x": xyz[..., 0].ravel(),
            "y": xyz[..., 1].ravel(),
            "z": xyz[..., 2].ravel(),
        }
    )


def lds_block(cfg: SimConfig, seed: int, block: int, duration_s: float) -> pd.DataFrame:
    """LDS table (segment, t, plate, z) for block ``block`` of `LDS_BLOCK_S` seconds."""
    lds = cfg.lds
    if not lds.enabled or not lds.plates:
        return pd.DataFrame({"segment": [], "t": [], "plate": [], "z": []})
    k0 = int(np.ceil(block * LDS_BLOCK_S * lds.rate_hz - 1e-9))
    k1 = int(np.ceil(min((block + 1) * LDS_BLOCK_S, duration_s) * lds.rate_hz - 1e-9))
    k = np.arange(k0, max(k0, k1))
    t = cfg.t0_s + k / lds.rate_hz
    defl, _, _ = kinematics(cfg, t)
    rng = np.random.default_rng([seed, 41, block])
    xs = np.asarray(cfg.plate_x_mm())
    frames = []
    for p in lds.plates:
        shape = float(beam_shape(xs[p - 1], cfg.beam.span_mm, cfg.beam.load_a_mm))
        z = shape * defl + lds.noise_um * 1e-3 * rng.standard_normal(t.size)
        modal = mode_displacement(cfg.effects, t - cfg.t0_s, np.array([xs[p - 1] / cfg.beam.span_mm]))
        if modal is not None:
            z = z + modal[:, 0]
        if p == lds.defective_plate:
            z = lds.defect_gain * z + lds.defect_noise_um * 1e-3 * rng.standard_normal(t.size)
        frames.append(pd.DataFrame({"segment": cfg.recording.segment, "t": t, "plate": p, "z": z}))
    return pd.concat(frames, ignore_index=True)


def usable_reference(reference: pd.DataFrame, cfg: SimConfig, source: str = "--reference"):
    """(``reference`` without the plate whose sensor ``cfg`` marks defective, a note or None).

    A defective LDS (``lds.defective_plate``) reads the deflection with ``lds.defect_gain`` and
    ``lds.defect_noise_um``: tied to it, that plate's camera z would show a line at f0 that is the
    sensor's, not the camera's. Its rows are dropped and the note says so; None when no other
    plate is left."""
    bad = int(cfg.lds.defective_plate)
    if not bad or "plate" not in reference or not (reference["plate"] == bad).any():
        return reference, None
    note = (
        f"{source}: plate {bad} left out of the reference: the config marks its LDS defective "
        f"(lds.defective_plate = {bad}, gain {cfg.lds.defect_gain:g}, noise {cfg.lds.defect_noise_um:g} µm)"
    )
    kept = reference[reference["plate"] != bad].reset_index(drop=True)
    if kept.empty:
        return None, note + "; no other plate is left: diagnosed without a reference"
    return kept, note
