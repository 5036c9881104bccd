"""Frames -> trajectory table: chunked extraction of a recording (`jaxdefl extract`).

`extract_frames` works on in-memory frame stacks (tests, notebooks); `extract_recording` streams
a `Recording` chunk by chunk; `extract_to_table` is the CLI's entry point.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pandas as pd
import torch

from .._errors import ConfigError, InputError, ParameterError
from .._signals import check_interrupt
from ..settings import ExtractSettings, resolve_device
from .pipeline import PlateGeometry, Scene, SceneError, calibrate_scene, detect_chunk
from .track import Tracker

__all__ = [
    "Extractor",
    "centroid_table",
    "extract_frames",
    "extract_recording",
    "extract_to_table",
    "resolve_device",
]

CPU_THREADS = 1  # torch intra-op threads per extracting process (see `Extractor`)


class Extractor:
    """Stateful chunk-by-chunk extraction: calibrates on the first chunk, then detects or tracks.

    Real-time mode tracks the calibrated pixel sets; frames where a plate is lost are re-detected
    with the full pipeline, and a chunk where any plate is lost in more than 5 % of the frames
    triggers a new calibration on that chunk (plate numbers kept by position).

    The per-frame stages run on ``device`` (`resolve_device`: None picks CUDA when available).
    On the CPU the process's torch intra-op threads are pinned to ``threads`` (default
    `CPU_THREADS` = 1): the kernels are many short passes over a chunk, and two threads on
    two shared cores wait for each other on every pass (experiments/bench_extract.py
    --threads 2 ran 2x slower than one thread at light load, 9x under heavy load); parallel
    work comes from processes (`jaxdefl run` units), not threads.
    """

    def __init__(
        self,
        intrinsics: dict,
        kind: str,
        geometry: PlateGeometry | None = None,
        realtime: bool = False,
        source: str = "<frames>",
        device: str | None = None,
        threads: int | None = CPU_THREADS,
    ):
        if kind not in ("range", "depth"):
            raise ValueError(f"kind: expected 'range' or 'depth', got {kind!r}")
        self.device = resolve_device(device)
        if self.device == "cpu" and threads:
            torch.set_num_threads(threads)
        self.intrinsics, self.kind, self.geometry = intrinsics, kind, geometry
        self.realtime, self.source = realtime, source
        self.scene: Scene | None = None
        self.tracker: Tracker | None = None
        self.recalibrations = 0

    def _calibrate(self, frames, amplitude):
        try:
            scene = calibrate_scene(
                frames, amplitude, self.intrinsics, self.kind, self.geometry, device=self.device
            )
        except SceneError as err:
            raise InputError(f"{self.source}: {err}") from None
        if self.scene is not None and self.geometry is None:
            # keep the first calibration's numbers: match the new plates by image column
            num = self.scene.number(np.full(scene.u.size, np.nan), scene.u)
            keep = num > 0
            for name in ("area", "ecc", "u", "v"):
                setattr(scene, name, getattr(scene, name)[keep])
            scene.track = [p for p, k in zip(scene.track, keep, strict=True) if k]
            scene.plates = num[keep]
            order = np.argsort(scene.plates)
            for name in ("plates", "area", "ecc", "u", "v"):
                setattr(scene, name, getattr(scene, name)[order])
            scene.track = [scene.track[i] for i in order]
        self.scene = scene
        self.tracker = Tracker(scene) if self.realtime else None

    def run(self, frames: np.ndarray, amplitude: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(frame, plate, 3) centroids and the plate numbers for one chunk."""
        if self.scene is None:
            self._calibrate(frames, amplitude)
        if not self.realtime:
            return detect_chunk(self.scene, frames, amplitude), self.scene.plates
        out, lost = self.tracker.centroids(frames)
        if lost.any() and lost.mean(axis=0).max() > 0.05 and frames.shape[0] >= 8:
            self.recalibrations += 1
            self._calibrate(frames, amplitude)
            out, lost = self.tracker.centroids(frames)
        rows = np.flatnonzero(lost.any(axis=1))
        if rows.size:
            det = detect_chunk(self.scene, frames[rows], None if amplitude is None else amplitude[rows])
            out[rows] = np.where(lost[rows][..., None], det, out[rows])
        return out, self.scene.plates


def centroid_table(t: np.ndarray, cents: np.ndarray, plates: np.ndarray, segment: str) -> pd.DataFrame:
    b, n, _ = cents.shape
    ok = np.isfinite(cents).all(axis=2)
    fi, pi = np.nonzero(ok)
    return pd.DataFrame(
        {
            "segment": segment,
            "t": t[fi],
            "plate": plates[pi].astype(np.int64),
            "x": cents[fi, pi, 0],
            "y": cents[fi, pi, 1],
            "z": cents[fi, pi, 2],
        }
    )


def _sort(df: pd.DataFrame) -> pd.DataFrame:
    return df.sort_values(["plate", "t"], kind="stable").reset_index(drop=True)


def extract_frames(
    frames: np.ndarray,
    t_s: np.ndarray,
    intrinsics: dict,
    kind: str = "range",
    amplitude: np.ndarray | None = None,
    realtime: bool = False,
    geometry: PlateGeometry | None = None,
    segment: str = "",
    chunk_frames: int = 256,
    device: str | None = None,
) -> pd.DataFrame:
    """Plate centroid trajectories from in-memory frames.

    Args:
        frames: (frame, h, w) ToF range (``kind="range"``) or depth z (``"depth"``), mm.
        t_s: (frame,) timestamps. intrinsics: fx, fy, cx, cy (px). amplitude: (frame, h, w) or None.
        realtime: track plates detected once instead of detecting in every frame.
        geometry: plate positions for numbering (None: 1.. by image column).
        device: torch device (`resolve_device`).
    Returns:
        Trajectory table (segment, t, plate, x, y, z), camera frame, mm; missing = no row.
    """
    frames = np.asarray(frames)
    if frames.ndim != 3:
        raise ValueError(f"frames: expected shape (frame, h, w), got {frames.shape}")
    t_s = np.asarray(t_s, np.float64)
    if t_s.shape != (frames.shape[0],):
        raise ValueError(f"t_s: expected shape ({frames.shape[0]},), got {t_s.shape}")
    ex = Extractor(intrinsics, kind, geometry, realtime, device=device)
    parts = []
    for s in range(0, frames.shape[0], chunk_frames):
        e = min(frames.shape[0], s + chunk_frames)
        cents, plates = ex.run(frames[s:e], None if amplitude is None else amplitude[s:e])
        parts.append(centroid_table(t_s[s:e], cents, plates, segment))
    return _sort(pd.concat(parts, ignore_index=True))


def extract_recording(
    recording,
    realtime: bool = False,
    chunk_frames: int = 256,
    progress: bool = True,
    device: str | None = None,
) -> pd.DataFrame:
    """Stream a `jaxdefl.io.recording.Recording` through the extraction, chunk by chunk."""
    from ..progress import progress_bar

    rec = recording
    geo = PlateGeometry(rec.plate_x_mm, rec.camera_x_mm) if rec.plate_x_mm is not None else None
    ex = Extractor(rec.intrinsics, rec.kind, geo, realtime, source=str(rec.path), device=device)
    parts = []
    with progress_bar(progress) as bar:
        task = bar.add_task(f"extract {rec.path.name} (frames)", total=rec.n_frames)
        for ch in rec.chunks(chunk_frames):
            check_interrupt()
            cents, plates = ex.run(ch.frames, ch.amplitude)
            parts.append(centroid_table(ch.t, cents, plates, rec.segment))
            bar.advance(task, len(ch.t))
    if not parts:
        raise InputError(f"{rec.path}: the recording has no frames")
    return _sort(pd.concat(parts, ignore_index=True))


# Working memory of one batch per pixel of a frame: the frames and amplitude (float32), their
# tensors, the band masks and the morphology's intermediates (measured: 11 B on 640x480 Kinect
# frames, batches of 32 and 256 frames; twice that for a margin).
_BYTES_PER_PIXEL = 24


def _check_chunk_memory(rec, chunk_frames: int) -> None:
    """Refuse a --chunk-frames whose batch of frames would not fit in the memory budget."""
    from .._resources import MEMORY_BUDGET_BYTES, size_text

    frames = min(chunk_frames, max(rec.n_frames, 1))
    need = _BYTES_PER_PIXEL * rec.height * rec.width * frames
    if need > MEMORY_BUDGET_BYTES:
        most = MEMORY_BUDGET_BYTES // (_BYTES_PER_PIXEL * rec.height * rec.width)
        raise ParameterError(
            "chunk_frames",
            f"batches of {frames:,} frames of {rec.width}x{rec.height} would need ~{size_text(need)} "
            f"of memory; expected at most {size_text(MEMORY_BUDGET_BYTES)} (at most {most:,} frames "
            f"per batch), got {chunk_frames:,}",
        )


def extract_to_table(
    recording: Path,
    out: Path,
    settings: ExtractSettings | None = None,
) -> None:
    """Extract every frame of ``recording`` and write the trajectory table ``out`` (CSV/Parquet).

    ``settings`` (`jaxdefl.settings.ExtractSettings`, validated when made; default: its
    defaults): full or tracked mode, frames per batch, device, and the timestamp policy:
    ``strict`` (frame times must increase) or ``reclock`` (rounded or jittered frame times
    replaced by the recovered clock, `jaxdefl.io.recording.open_recording`; one line on stderr
    says what was recovered).

    Raises:
        ConfigError: ``out`` clashing with the input.
        InputError: a missing, corrupt, truncated or inconsistent recording, or no plates found.
    """
    from ..io.camera import camera_facts, camera_sidecar
    from ..io.output import TABLE_SUFFIXES, Outputs
    from ..io.recording import open_recording
    from ..io.trajectory import timestamp_note, write_trajectory

    s = settings if settings is not None else ExtractSettings()
    outs = Outputs(inputs=[recording])
    outs.reserve(out, "--out", suffixes=TABLE_SUFFIXES)
    if Path(out).resolve().is_relative_to(Path(recording).resolve()):
        raise ConfigError(f"--out {out}: lies inside the recording {recording}; choose another place")
    rec = open_recording(recording, timestamps=s.timestamps)
    _check_chunk_memory(rec, s.chunk_frames)
    if (note := timestamp_note(rec.clock)) is not None:
        print(f"jaxdefl extract: {rec.path}: {note}", file=sys.stderr)
    df = extract_recording(rec, realtime=s.realtime, chunk_frames=s.chunk_frames, device=s.device)
    with outs:
        write_trajectory(df, out, outs)
        # always written, so that no earlier extraction's facts stay beside a new table
        outs.json(camera_sidecar(out), {"recording": str(recording), **camera_facts(rec.attrs)})
