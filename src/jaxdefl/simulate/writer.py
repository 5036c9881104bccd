"""Simulate a recording to disk, streamed in chunks of frames; and the frame-free fast path.

Output directory:
- ``recording.zarr``: ``range`` (ToF, mm, wrapped at the NAR) or ``depth`` (structured light, mm),
  ``amplitude`` (frame, h, w) float32 and ``timestamps`` (frame,) float64 epoch seconds, chunked
  along time; camera facts and intrinsics as attributes.
- ``truth.csv``: true plate centroids (segment, t, plate, x, y, z), camera frame, mm.
- ``lds.csv``: laser displacement sensors (segment, t, plate, z), deflection downward positive.
- ``config.json``: the effective config.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd

from .._errors import ConfigError, ParameterError
from .._resources import MEMORY_BUDGET_BYTES, check_disk, check_memory
from .._signals import check_interrupt
from ..io.output import Outputs
from .config import SimConfig, load_config
from .injection import FRAME_LEVELS, mode_displacement, range_offset, sampling_offsets, stamp_times
from .lds import LDS_BLOCK_S, frame_clock, lds_block, truth_table
from .multicam import camera_clock, camera_poses, camera_seed, label_origin_x, multicam_outputs
from .scene import kinematics, pixel_model

__all__ = ["simulate_to_dir", "simulate_trajectories", "tap_times", "render_frames"]

_COLUMNS = ("segment", "t", "plate", "x", "y", "z")
# every chunk is stored, even one of fill values only: a reader takes a missing chunk for damage
_EVERY_CHUNK = {"write_empty_chunks": True}


def _check_duration(cfg: SimConfig, duration_s: float | None) -> float:
    if duration_s is None:
        if not cfg.recording.duration_s > 0:
            raise ConfigError(
                f"recording.duration_s: expected a duration > 0 s, got {cfg.recording.duration_s:g}"
            )
        return cfg.recording.duration_s
    if not np.isfinite(duration_s) or duration_s <= 0:
        raise ParameterError("duration_s", f"expected a duration > 0 s, got {duration_s:g}")
    return float(duration_s)


# Memory of a simulation: its frame clock (random draws, times and indices of every frame) and
# one chunk of rendered frames (measured: 8-11 B per output pixel for both sensors, both arrays)
_CLOCK_BYTES_PER_FRAME = 48
_RENDER_BYTES_PER_PIXEL = 24
_STORED_BYTES_PER_PIXEL = 8  # range or depth, and amplitude: float32 each (before compression)


def check_size(cfg: SimConfig, duration: float, out: Path, duration_flag: str, source: str) -> None:
    """Refuse a duration or chunk size whose memory or disk space is out of reach, before any
    file is made. ``duration_flag`` names where the duration came from, ``source`` the config."""
    cam, chunk = cfg.camera, cfg.recording.chunk_frames
    n = int(np.floor(duration * cam.frame_rate_hz + 1e-9))
    px = cam.width * cam.height
    frames = f"{n:,} frames of {cam.width}x{cam.height}"
    # a Zarr chunk is allocated whole, however few frames it ends up holding
    check_memory(
        _RENDER_BYTES_PER_PIXEL * px * chunk,
        f"{source}: key 'recording.chunk_frames' {chunk:,}: chunks of {chunk:,} frames of "
        f"{cam.width}x{cam.height}",
        f"at most {MEMORY_BUDGET_BYTES // (_RENDER_BYTES_PER_PIXEL * px):,} frames per chunk",
    )
    check_memory(
        _CLOCK_BYTES_PER_FRAME * n + _RENDER_BYTES_PER_PIXEL * px * chunk,
        f"{duration_flag} {duration:g}: {frames}",
        "a shorter duration",
    )
    check_disk(
        n * (_STORED_BYTES_PER_PIXEL * px + 8),
        out,
        f"{duration_flag} {duration:g}: {frames} (uncompressed)",
        "a shorter duration or another --out",
    )


def tap_times(cfg: SimConfig, t_frame: np.ndarray) -> np.ndarray:
    """(frame, 4) times of the four correlation samples (ToF) or the exposure (structured light)."""
    cam = cfg.camera
    if cam.sensor != "sr4000":
        return np.repeat(np.asarray(t_frame, np.float64)[:, None], 4, axis=1)
    off = np.asarray(cam.tap_offsets, np.float64) / cam.frame_rate_hz
    return np.asarray(t_frame, np.float64)[:, None] + off[None, :]


def simulate_trajectories(
    config: SimConfig | str | Path, duration_s: float | None = None, seed: int | None = None
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """True plate trajectories at the delivered frame times and the LDS table, no frames.

    Returns exactly what `simulate_to_dir` writes to truth.csv and lds.csv for the same arguments.
    """
    cfg = config if isinstance(config, SimConfig) else load_config(config)
    duration = _check_duration(cfg, duration_s)
    seed = cfg.recording.seed if seed is None else int(seed)
    _, t = frame_clock(cfg, duration, seed)
    truth = truth_table(cfg, t)
    nblocks = int(np.ceil(duration / LDS_BLOCK_S))
    lds = pd.concat(
        [lds_block(cfg, seed, b, duration) for b in range(nblocks)] or [lds_block(cfg, seed, 0, 0)],
        ignore_index=True,
    )
    return truth, lds


class Renderer:
    """Holds the static pixel model of one camera and renders chunks of frames."""

    def __init__(self, cfg: SimConfig, seed: int, duration_s: float):
        self.cfg, self.seed, self.duration = cfg, seed, duration_s
        self.pm = pixel_model(
            cfg, supersample=None if cfg.camera.sensor == "sr4000" else min(cfg.camera.supersample, 2)
        )
        self.intr = self.pm.intr
        if cfg.camera.sensor == "sr4000":
            from .tof import device_model_of, tof_model

            self.tm = tof_model(cfg, self.pm)
            self.dev = device_model_of(self.tm)
            self.kind = "range"
        else:
            from .structured_light import kinect_model

            self.km = kinect_model(cfg, self.pm)
            self.kind = "depth"

    def facts(self) -> dict:
        cam = self.cfg.camera
        d = dict(
            self.intr.as_dict(),
            sensor=cam.sensor,
            camera=cam.name,
            frame_rate_hz=cam.frame_rate_hz,
            segment=self.cfg.recording.segment,
            day=self.cfg.recording.day,
            cycles_at_start=self.cfg.recording.cycles_at_start,
            units="mm",
            seed=self.seed,
            frame_kind=self.kind,
            frame_axes=["frame", "h", "w"],
            coordinates="camera frame: x along columns (beam), y along rows, z depth (down)",
            plate_x_mm=self.cfg.plate_x_mm(),
            camera_x_mm=float(cam.x_mm),
        )
        if cam.sensor == "sr4000":
            from .tof import calibration_unit as _calibration_unit

            d.update(
                modulation_mhz=cam.modulation_mhz,
                nar_mm=self.tm.nar_mm,
                integration_time_ms=self.tm.integration_ms,
                correlated_range_noise_mm=self.tm.sigma_corr_mm,
                centroid_residual_mm=self.tm.centroid_residual_mm,
                noise_calibration=_calibration_unit(self.cfg),
                tap_offsets=list(cam.tap_offsets),
            )
        else:
            d.update(modulation_mhz=None, baseline_mm=cam.baseline_mm, disparity_step_px=self.km.q_px)
        return d

    def render(self, frame_index: np.ndarray, t_frame: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        h, w = self.intr.height, self.intr.width
        taps = tap_times(self.cfg, t_frame)
        offs = sampling_offsets(self.cfg.effects, np.asarray(t_frame, np.float64) - self.cfg.t0_s)
        if offs is None:
            defl, dx, dy = kinematics(self.cfg, taps)
        else:  # each tap reads the mean of the motion over the sampling effects' instants
            parts = [kinematics(self.cfg, taps + offs[:, k, None]) for k in range(offs.shape[1])]
            defl, dx, dy = (sum(x) / len(parts) for x in zip(*parts, strict=True))
        if self.kind == "range":
            from .tof import render_tof

            r, a = render_tof(self.tm, frame_index, defl, dx, dy, self.seed, device_model=self.dev)
        else:
            from .structured_light import render_kinect, session_offsets_mm

            off = session_offsets_mm(self.cfg, t_frame, self.seed, self.duration)
            r, a = render_kinect(
                self.km, self.cfg, frame_index, defl[:, 0], dx[:, 0], dy[:, 0], off, self.seed
            )
        n = len(frame_index)
        r = r.reshape(n, h, w)
        if any(e.level == "range" for e in self.cfg.effects):
            # [[effect]] tables the camera adds to its ranges (warm-up drift, jumps, outliers)
            off = range_offset(self.cfg.effects, t_frame, self.cfg.t0_s, self.cfg.plates.count, self.seed)
            col = (self.pm.plate_idx + 1).reshape(h, w)
            r = (r + off[:, col]).astype(r.dtype, copy=False)
        xi = np.asarray(self.cfg.plate_x_mm()) / self.cfg.beam.span_mm
        modal = mode_displacement(self.cfg.effects, t_frame - self.cfg.t0_s, xi)
        if modal is not None:
            # other bending modes move each plate in its own shape: its pixels read the plate's
            # displacement along their rays (the beam top between the plates is left as it is)
            on = self.pm.plate_idx >= 0
            gain = self.pm.plate_gain[on] if self.kind == "range" else 1.0
            add = np.zeros((n, h * w), r.dtype)
            add[:, on] = modal[:, self.pm.plate_idx[on]] * gain
            r = r + add.reshape(n, h, w)
        return r, np.asarray(a, np.float32).reshape(n, h, w)


def _frames_show(cfg: SimConfig) -> None:
    """Rendered frames show the range, timestamp and motion levels of the registry."""
    local = [e.id for e in cfg.effects if e.level not in FRAME_LEVELS]
    if local:
        raise ConfigError(
            f"{cfg.source}: effect {local[0]} acts on trajectories only; use jaxdefl simulate --live "
            "(or jaxdefl monitor --config) for it, or remove it"
        )


def render_frames(config: SimConfig | str | Path, duration_s: float | None = None, seed: int | None = None):
    """All frames in memory (small simulations and tests): (timestamps, frames, amplitude, facts)."""
    cfg = config if isinstance(config, SimConfig) else load_config(config)
    _frames_show(cfg)
    duration = _check_duration(cfg, duration_s)
    seed = cfg.recording.seed if seed is None else int(seed)
    idx, t = frame_clock(cfg, duration, seed)
    rend = Renderer(cfg, seed, duration)
    frames, amp = rend.render(idx, t)
    return stamp_times(cfg.effects, t, cfg.t0_s), frames, amp, rend.facts()


def create_frame_arrays(root, kind: str, h: int, w: int, chunk: int):
    """The empty ``kind`` (range or depth), ``amplitude`` and ``timestamps`` arrays of a recording."""
    frames, amp = (
        root.create_array(
            name,
            shape=(0, h, w),
            chunks=(chunk, h, w),
            dtype="float32",
            dimension_names=("frame", "h", "w"),
            fill_value=np.nan,
            config=_EVERY_CHUNK,
        )
        for name in (kind, "amplitude")
    )
    stamps = root.create_array(
        "timestamps",
        shape=(0,),
        chunks=(max(chunk, 4096),),
        dtype="float64",
        dimension_names=("frame",),
        config=_EVERY_CHUNK,
    )
    frames.attrs.update(units="mm")
    stamps.attrs.update(units="s since 1970-01-01 (UTC)")
    return frames, amp, stamps


def append_csv(df: pd.DataFrame, path: Path, first: bool) -> None:
    # the format of jaxdefl.io.write_trajectory, appended chunk by chunk to bound memory
    cols = [c for c in _COLUMNS if c in df.columns]
    df[cols].to_csv(path, mode="w" if first else "a", header=first, index=False, float_format="%.6f")


def simulate_to_dir(
    config_path: Path | str,
    out_dir: Path | str,
    duration_s: float | None = None,
    seed: int | None = None,
    progress: bool = True,
    session: str | None = None,
) -> Path:
    """Simulate the recording described by ``config_path`` into ``out_dir`` (see module doc).

    ``session`` picks a ``[[session]]`` of the config (default: ``recording.session`` or the first).

    Frames are rendered and appended ``recording.chunk_frames`` at a time, so memory stays bounded
    for long durations. Deterministic for a seed (the config's ``recording.seed`` by default).

    Raises:
        ConfigError: a bad config file or a negative duration.
    """
    cfg = load_config(config_path, session)
    for name in cfg.camera_names:
        _frames_show(cfg.for_camera(name))
    duration = _check_duration(cfg, duration_s)
    seed = cfg.recording.seed if seed is None else int(seed)
    out = Path(out_dir)
    if cfg.cameras:  # [[camera]] tables: a recording per camera (`jaxdefl.simulate.multicam`)
        return _write_cameras(cfg, out, duration, seed, progress)
    if out.exists() and not out.is_dir():
        raise ConfigError(f"--out {out}: is a file; expected a directory")
    where = "recording.duration_s" if duration_s is None else "--duration"
    check_size(cfg, duration, out, where, str(config_path))
    outs = Outputs(inputs=[config_path])
    for name in ("config.json", "recording.zarr", "truth.csv", "lds.csv"):
        outs.reserve(out / name, f"--out {out}: {name}")
    with outs:
        _write_recording(cfg, outs, out, duration, seed, progress)
    return out


def _write_recording(cfg: SimConfig, outs: Outputs, out: Path, duration: float, seed: int, progress: bool):
    """Render and write everything to the temporary paths of ``outs`` (committed by the caller)."""
    import zarr

    from ..progress import progress_bar

    effective = cfg.to_dict()
    effective["recording"]["duration_s"] = duration
    effective["recording"]["seed"] = seed
    outs.text(out / "config.json", json.dumps(effective, indent=2))

    idx, t = frame_clock(cfg, duration, seed)
    rend = Renderer(cfg, seed, duration)
    h, w = rend.intr.height, rend.intr.width
    chunk = cfg.recording.chunk_frames
    store = outs.path(out / "recording.zarr")
    root = zarr.open_group(str(store), mode="w")
    root.attrs.update(rend.facts())
    frames, amp, stamps = create_frame_arrays(root, rend.kind, h, w, chunk)

    truth_path, lds_path = outs.path(out / "truth.csv"), outs.path(out / "lds.csv")
    append_csv(truth_table(cfg, t[:0]), truth_path, True)
    nblocks = int(np.ceil(duration / LDS_BLOCK_S))
    append_csv(lds_block(cfg, seed, 0, 0.0), lds_path, True)
    lds_done = 0
    with progress_bar(progress) as bar:
        task = bar.add_task(f"simulate {cfg.camera.sensor} {cfg.recording.segment} (frames)", total=len(idx))
        for s in range(0, len(idx), chunk):
            check_interrupt()
            fi, ti = idx[s : s + chunk], t[s : s + chunk]
            r, a = rend.render(fi, ti)
            frames.append(r, axis=0)
            amp.append(a, axis=0)
            stamps.append(stamp_times(cfg.effects, ti, cfg.t0_s), axis=0)  # timing errors
            append_csv(truth_table(cfg, ti), truth_path, False)
            # LDS blocks up to the time covered so far
            covered = (fi[-1] + 1) / cfg.camera.frame_rate_hz if s + chunk < len(idx) else duration
            while lds_done < nblocks and (lds_done + 1) * LDS_BLOCK_S <= covered + 1e-9:
                append_csv(lds_block(cfg, seed, lds_done, duration), lds_path, False)
                lds_done += 1
            bar.advance(task, len(fi))
    while lds_done < nblocks:
        append_csv(lds_block(cfg, seed, lds_done, duration), lds_path, False)
        lds_done += 1
    root.attrs["n_frames"] = int(len(idx))


def _write_cameras(cfg: SimConfig, out: Path, duration: float, seed: int, progress: bool) -> Path:
    """Write every camera's recording and the shared truth into ``out`` (`jaxdefl.simulate.multicam`)."""
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

    idx, stamp, t_true = camera_clock(cfg, duration, seed)
    rend = Renderer(cfg, seed, duration)
    h, w = rend.intr.height, rend.intr.width
    chunk = cfg.recording.chunk_frames
    root = zarr.open_group(str(outs.path(out / f"{name}.zarr")), mode="w")
    facts = rend.facts()
    facts.update(camera_x_mm=label_origin_x(cfg), seed=seed)
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
