"""Several cameras at once: one beam, one LDS, a recording per ``[[camera]]`` table.

Every camera has its own pose (position and roll/pitch/yaw, `jaxdefl.simulate.scene`), sensor,
modulation frequency, frame rate, noise and clock. A camera's clock stamps a frame taken at true
time t with ``t0 + clock_offset_ms / 1000 + (1 + clock_drift_ppm 1e-6) (t - t0)``: frames are
rendered at their true times and written with the camera's stamps.

Output directory (`simulate_cameras_to_dir`):
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

import json
from pathlib import Path

import numpy as np
import pandas as pd

from .._errors import ConfigError
from .._signals import check_interrupt
from ..io.output import Outputs
from .config import SimConfig
from .injection import stamp_times
from .lds import LDS_BLOCK_S, frame_clock, lds_block, truth_table
from .scene import camera_origin, camera_rotation, plate_centres_world, to_camera

__all__ = ["camera_clock", "camera_seed", "camera_poses", "simulate_cameras_to_dir", "multicam_outputs"]


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


def _label_origin_x(cfg: SimConfig) -> float:
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


def simulate_cameras_to_dir(cfg: SimConfig, out: Path, duration: float, seed: int, progress: bool) -> Path:
    """Write every camera's recording and the shared truth into ``out`` (see module doc)."""
    from .writer import check_size

    if out.exists() and not out.is_dir():
        raise ConfigError(f"--out {out}: is a file; expected a directory")
    for name in cfg.camera_names:
        check_size(cfg.for_camera(name), duration, out, "--duration", cfg.source)
    outs = Outputs(inputs=[cfg.source] if Path(cfg.source).exists() else [])
    for name in multicam_outputs(cfg):
        outs.reserve(out / name, f"--out {out}: {name}")
    with outs:
        effective = cfg.to_dict()
        effective["recording"]["duration_s"] = duration
        effective["recording"]["seed"] = seed
        outs.text(out / "config.json", json.dumps(effective, indent=2))
        outs.text(out / "cameras.json", json.dumps(camera_poses(cfg), indent=2))
        beam_rows = []
        for i, name in enumerate(cfg.camera_names):
            cfg_i = cfg.for_camera(name)
            beam_rows.append(_write_camera(cfg_i, outs, out, name, duration, camera_seed(seed, i), progress))
        pd.concat(beam_rows, ignore_index=True).to_csv(
            outs.path(out / "truth.csv"), index=False, float_format="%.6f"
        )
        nblocks = int(np.ceil(duration / LDS_BLOCK_S))
        structure = cfg.for_camera(cfg.camera_names[0])
        lds = [lds_block(structure, seed, b, duration) for b in range(nblocks)] or [
            lds_block(structure, seed, 0, 0)
        ]
        pd.concat(lds, ignore_index=True).to_csv(outs.path(out / "lds.csv"), index=False, float_format="%.6f")
    return out


def _write_camera(
    cfg: SimConfig, outs: Outputs, out: Path, name: str, duration: float, seed: int, progress: bool
) -> pd.DataFrame:
    """One camera's recording and camera-frame truth; returns its beam-frame truth."""
    import zarr

    from ..progress import progress_bar
    from .writer import append_csv, create_frame_arrays, Renderer

    idx, stamp, t_true = camera_clock(cfg, duration, seed)
    rend = Renderer(cfg, seed, duration)
    h, w = rend.intr.height, rend.intr.width
    chunk = cfg.recording.chunk_frames
    root = zarr.open_group(str(outs.path(out / f"{name}.zarr")), mode="w")
    facts = rend.facts()
    facts.update(camera_x_mm=_label_origin_x(cfg), seed=seed)
    root.attrs.update(facts)
    frames, amp, stamps = create_frame_arrays(root, rend.kind, h, w, chunk)
    truth_path = outs.path(out / f"{name}_truth.csv")
    append_csv(truth_table(cfg, t_true[:0]), truth_path, True)
    with progress_bar(progress) as bar:
        task = bar.add_task(f"simulate {name} {cfg.recording.segment} (frames)", total=len(idx))
        for s in range(0, len(idx), chunk):
            check_interrupt()
            fi, ti, si = idx[s : s + chunk], t_true[s : s + chunk], stamp[s : s + chunk]
            r, a = rend.render(fi, ti)
            frames.append(r, axis=0)
            amp.append(a, axis=0)
            stamps.append(stamp_times(cfg.effects, si, cfg.t0_s), axis=0)
            cam_truth = truth_table(cfg, ti)
            cam_truth["t"] = np.repeat(si, cfg.plates.count)
            append_csv(cam_truth, truth_path, False)
            bar.advance(task, len(fi))
    root.attrs["n_frames"] = int(len(idx))
    beam = truth_table(cfg, t_true, frame="beam")
    beam.insert(1, "camera", name)
    return beam
