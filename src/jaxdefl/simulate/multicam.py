"""Several cameras at once: one beam, one LDS, a recording per ``[[camera]]`` table.

Every camera has its own pose (position and roll/pitch/yaw, `jaxdefl.simulate.scene`), sensor,
modulation frequency, frame rate, noise and clock. A camera's clock stamps a frame taken at true
time t with ``t0 + clock_offset_ms / 1000 + (1 + clock_drift_ppm 1e-6) (t - t0)``: frames are
rendered at their true times and written with the camera's stamps.

Output directory (`jaxdefl.simulate.simulate_to_dir` of a config with ``[[camera]]`` tables):
- ``<camera>.zarr``: the camera's recording, as `jaxdefl.simulate.simulate_to_dir` writes it.
- ``<camera>_truth.csv``: its true plate centroids in its own camera frame, at its own stamps
  (what a perfect extraction gives).
- ``truth.csv``: the true plate centroids in the beam frame (x along the beam from the left
  support, y lateral, z down from the beam top) at the true instants of every camera's frames,
  with a ``camera`` column.
- ``cameras.json``: every camera's true pose (rotation camera -> beam, origin) and clock.
- ``lds.csv`` (true clock) and ``config.json`` (the effective config).
"""

from __future__ import annotations

import numpy as np

from .config import SimConfig
from .lds import frame_clock
from .scene import camera_origin, camera_rotation, plate_centres_world, to_camera

__all__ = ["camera_clock", "camera_seed", "camera_poses", "label_origin_x", "multicam_outputs"]


def camera_seed(seed: int, index: int) -> int:
    """The seed of the ``index``-th camera (0-based): the first keeps the recording's seed."""
    return int(seed) + 7919 * index


def camera_clock(cfg: SimConfig, duration_s: float, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(frame indices, the camera's stamps, the true times) of ``cfg.camera``'s delivered frames.

    The camera takes frame k when its own clock reads t0 + k / f_s (`frame_clock`); the true
    time of that instant inverts the clock model of the module doc.
    """
    cam = cfg.camera
    idx, stamp = frame_clock(cfg, duration_s, seed)
    rate = 1.0 + cam.clock_drift_ppm * 1e-6
    t_true = cfg.t0_s + (stamp - cfg.t0_s - cam.clock_offset_ms * 1e-3) / rate
    return idx, stamp, t_true


def camera_poses(cfg: SimConfig) -> list[dict]:
    """Every camera's true pose and clock (what ``cameras.json`` holds)."""
    out = []
    for name in cfg.camera_names:
        cam = cfg.for_camera(name).camera
        rot = camera_rotation(cam)
        out.append(
            dict(
                camera=name,
                rotation=(np.eye(3) if rot is None else rot).tolist(),
                origin_mm=camera_origin(cam).tolist(),
                roll_deg=cam.roll_deg,
                pitch_deg=cam.pitch_deg,
                yaw_deg=cam.yaw_deg,
                clock_offset_ms=cam.clock_offset_ms,
                clock_drift_ppm=cam.clock_drift_ppm,
                frame_rate_hz=cam.frame_rate_hz,
                modulation_mhz=cam.modulation_mhz,
                sensor=cam.sensor,
            )
        )
    return out


def label_origin_x(cfg: SimConfig) -> float:
    """The beam position that, added to a camera-frame x, numbers the plates in view
    (``camera_x_mm`` of the recording: for a turned camera, the mean over the plates in view of
    their beam x less their camera-frame x, as an operator's note of where the camera is)."""
    cam = cfg.camera
    if camera_rotation(cam) is None:
        return float(cam.x_mm)
    world = plate_centres_world(cfg)
    c = to_camera(cfg, world)
    inview = [p - 1 for p in cam.plates] or list(range(len(world)))
    return float(np.mean(world[inview, 0] - c[inview, 0]))


def multicam_outputs(cfg: SimConfig) -> list[str]:
    """The file names a multi-camera simulation writes, in its output directory."""
    names = ["config.json", "cameras.json", "truth.csv", "lds.csv"]
    for cam in cfg.camera_names:
        names += [f"{cam}.zarr", f"{cam}_truth.csv"]
    return names
