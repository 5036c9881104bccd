"""A live simulated camera at the trajectory level: measured plate centroids, block by block.

`camera_blocks` yields what the tracked extraction would deliver, without rendering frames: the
true centroids (`truth_table`, with the config's scheduled changes) at the delivered frame times
(drop-outs and jitter of `frame_clock`, read over the sampling effects' instants) plus the
camera's centroid noise, and the measurement effects (scheduled sensor faults, a noise level with
the motion, a lattice). The noise follows the frame renderer's calibration: z has the
plate-centroid residual of the thesis for the camera unit (``camera.centroid_residual_mm`` or the
unit's table value, see `jaxdefl.simulate.tof`; structured light: ``camera.frame_noise_mm``), of
which `COMMON_FRACTION` of the variance is shared by the plates of a frame (the ToF per-frame range
error); x and y get the ratios of the thesis' residuals (0.39 and 0.13 of z), independent.

`write_live` appends the blocks to ``DIR/trajectory.csv`` (the trajectory-table schema) at the
camera's rate times ``speed`` — a growing table that ``jaxdefl monitor DIR/trajectory.csv``
follows (``jaxdefl simulate CONFIG --live``).
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pandas as pd

from .._errors import ConfigError, ParameterError
from .._resources import check_disk
from .._signals import check_interrupt
from .config import SimConfig, load_config
from .injection import measurement_faults, sampled
from .lds import frame_clock, truth_table

__all__ = ["COMMON_FRACTION", "AXIS_NOISE_RATIO", "centroid_noise_mm", "camera_blocks", "write_live"]

COMMON_FRACTION = 0.7  # share of the z noise variance common to the plates of a frame (ToF)
AXIS_NOISE_RATIO = {"x": 0.39, "y": 0.13, "z": 1.0}  # Table 6.17-style residuals, x and y vs z


def centroid_noise_mm(cfg: SimConfig) -> float:
    """The z noise σ (mm) of a plate centroid for the config's camera."""
    cam = cfg.camera
    if cam.sensor != "sr4000":
        return float(cam.frame_noise_mm * cam.noise_scale)
    if cam.centroid_residual_mm >= 0:
        return float(cam.centroid_residual_mm * cam.noise_scale)
    from .tof import calibration_unit, centroid_residual_mm, integration_time_ms

    t_int = cam.integration_time_ms or integration_time_ms(cam.frame_rate_hz)
    return float(centroid_residual_mm(calibration_unit(cfg), t_int, cam.modulation_mhz) * cam.noise_scale)


def camera_blocks(
    cfg: SimConfig, duration_s: float, seed: int, block_frames: int = 300
) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """(t (frame,), xyz (frame, plate, 3)) blocks of measured centroids (mm, camera frame;
    NaN where a sensor fault loses a plate). Deterministic for a seed, whatever is consumed."""
    _, t_all = frame_clock(cfg, duration_s, seed)
    n_pl = cfg.plates.count
    sz = centroid_noise_mm(cfg)
    sig = np.array([AXIS_NOISE_RATIO[a] for a in ("x", "y", "z")]) * sz
    common = COMMON_FRACTION if cfg.camera.sensor == "sr4000" else 0.3
    ld = cfg.loading

    def centroids(tt: np.ndarray) -> np.ndarray:
        tr = truth_table(cfg, tt)
        return tr[["x", "y", "z"]].to_numpy(dtype=np.float64, copy=True).reshape(len(tt), n_pl, 3)

    for b, s in enumerate(range(0, len(t_all), block_frames)):
        t = t_all[s : s + block_frames]
        xyz = sampled(cfg.effects, t, cfg.t0_s, centroids)  # a camera's taps spread in time
        rng = np.random.default_rng([seed, 23, b])
        noise = rng.standard_normal((len(t), n_pl, 3)) * sig
        shared = rng.standard_normal((len(t), 1)) * sz * np.sqrt(common)
        noise[..., 2] = noise[..., 2] * np.sqrt(1 - common) + shared
        # the load's angle, 0 at the peak of the deflection (z down: the plates' z alike)
        arg = 2 * np.pi * ld.frequency_hz * (t - cfg.t0_s) + ld.phase_rad - np.pi / 2
        # sensor faults, a noise level with the motion, a lattice
        measurement_faults(
            cfg.effects, t - cfg.t0_s, xyz, noise, sigma=sig, arg=np.repeat(arg[:, None], n_pl, 1), seed=seed
        )
        yield t, xyz + noise


_CSV_BYTES_PER_ROW = 80  # segment, t to the microsecond, plate, x, y, z to 6 decimals


def write_live(
    config: Path | str,
    out_dir: Path | str,
    duration_s: float | None = None,
    seed: int | None = None,
    speed: float = 1.0,
    session: str | None = None,
) -> Path:
    """Append measured centroids to ``out_dir/trajectory.csv`` as a live camera would.

    Blocks of a second of frames are appended (flushed) when their last frame is due at
    ``speed`` times real time. An interrupt stops between blocks; the table holds whole rows.

    Raises:
        ConfigError: a bad config, duration or speed; ``out_dir`` is a file.
    """
    cfg = load_config(config, session)
    duration = cfg.recording.duration_s if duration_s is None else float(duration_s)
    if not np.isfinite(duration) or duration <= 0:
        raise ParameterError("duration_s", f"expected a duration > 0 s, got {duration:g}")
    if not np.isfinite(speed) or speed <= 0:
        raise ParameterError("speed", f"expected a factor > 0, got {speed:g}")
    seed = cfg.recording.seed if seed is None else int(seed)
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise ConfigError(f"--out {out}: is a file; expected a directory")
    rows = int(duration * cfg.camera.frame_rate_hz) * cfg.plates.count
    check_disk(
        _CSV_BYTES_PER_ROW * rows, out, f"--duration {duration:g}: {rows:,} rows", "a shorter duration"
    )
    out.mkdir(parents=True, exist_ok=True)
    path = out / "trajectory.csv"
    per = max(1, int(round(cfg.camera.frame_rate_hz)))
    start = time.monotonic()
    with open(path, "w") as fh:
        fh.write("segment,t,plate,x,y,z\n")
        fh.flush()
        for t, xyz in camera_blocks(cfg, duration, seed, block_frames=per):
            check_interrupt()
            due = start + (t[-1] - cfg.t0_s) / speed
            wait = due - time.monotonic()
            while wait > 0:
                time.sleep(min(wait, 0.2))
                check_interrupt()
                wait = due - time.monotonic()
            n, m = xyz.shape[:2]
            df = pd.DataFrame(
                {
                    "segment": cfg.recording.segment,
                    "t": np.repeat(t, m),
                    "plate": np.tile(np.arange(1, m + 1), n),
                    "x": xyz[..., 0].ravel(),
                    "y": xyz[..., 1].ravel(),
                    "z": xyz[..., 2].ravel(),
                }
            )
            fh.write(df.to_csv(index=False, header=False, float_format="%.6f"))
            fh.flush()
    return path
