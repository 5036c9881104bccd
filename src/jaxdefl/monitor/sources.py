"""Where the monitor's frames come from: chunks of (t (frame,), Y (frame, S)) and a `Layout`.

- `table_source`: a trajectory table (CSV/Parquet) read whole and replayed;
- `follow_table`: a CSV trajectory table that is being appended (polled; a frame whose timestamp
  is the last one read waits for the next, since a writer may be half-way through it);
- `recording_source`: a frame recording (.zarr, TUM folder, .npz) through the real-time tracked
  extraction (`jaxdefl.frames.Extractor`); with ``follow`` a .zarr store being appended is polled;
- `simulated_source`: the live simulated camera of `jaxdefl.simulate.live` with the config's
  scheduled changes.

Pacing (``speed`` × real time) and stopping are the runner's; `follow_*` sources end after
``idle_s`` seconds without new data.
"""

from __future__ import annotations

import io
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from .._errors import InputError
from .._signals import check_interrupt
from .layout import Layout, frames_from_table

__all__ = ["Source", "table_source", "follow_table", "recording_source", "simulated_source", "open_source"]

TABLE_SUFFIXES = (".csv", ".parquet", ".pq")


@dataclass
class Source:
    """A stream of frame chunks; ``layout`` is known before the first chunk is consumed."""

    name: str
    layout: Layout
    chunks: Iterator[tuple[np.ndarray, np.ndarray]]
    live: bool = False  # frames arrive at their own pace (no replay pacing needed)


def _split(t: np.ndarray, Y: np.ndarray, chunk: int) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    for s in range(0, len(t), chunk):
        yield t[s : s + chunk], Y[s : s + chunk]


def table_source(
    path: Path, axes: tuple[str, ...] | None = None, chunk: int = 32, timestamps: str = "strict"
) -> Source:
    """Replay a whole trajectory table (validated by `jaxdefl.io.read_trajectory` under the
    ``timestamps`` policy)."""
    from ..io import read_trajectory

    df = read_trajectory(path, timestamps=timestamps)
    if df["segment"].nunique() > 1:
        first = df["segment"].iloc[0]
        df = df[df["segment"] == first]
    t, Y, layout = frames_from_table(df, None if axes is None else _layout_for(df, axes))
    return Source(str(path), layout, _split(t, Y, chunk))


def _layout_for(df: pd.DataFrame, axes: tuple[str, ...]) -> Layout:
    missing = [a for a in axes if a not in df.columns]
    if missing:
        raise InputError(f"--axes: axis {missing[0]} is not in the table")
    return Layout(tuple(int(p) for p in np.unique(df["plate"].to_numpy())), axes)


class _Follower:
    """Reads the rows appended to a CSV since the last call (whole lines only)."""

    def __init__(self, path: Path):
        self.path = path
        self.offset = 0
        self.header = ""
        self.rest = b""

    def read(self) -> pd.DataFrame | None:
        try:
            with open(self.path, "rb") as fh:
                fh.seek(self.offset)
                data = fh.read()
        except FileNotFoundError:
            return None
        if not data:
            return None
        self.offset += len(data)
        data = self.rest + data
        cut = data.rfind(b"\n")
        if cut < 0:
            self.rest = data
            return None
        lines, self.rest = data[: cut + 1].decode(), data[cut + 1 :]
        if not self.header:
            self.header, _, lines = lines.partition("\n")
            self.header += "\n"
        if not lines.strip():
            return None
        from ..io import validate_trajectory

        raw = pd.read_csv(io.StringIO(self.header + lines))
        return validate_trajectory(raw, self.path)


def follow_table(path: Path, idle_s: float = 10.0, poll_s: float = 0.05) -> Source:
    """Follow a CSV trajectory table as it grows (see the module doc).

    Raises:
        InputError: not a CSV; no rows arrived within ``idle_s``.
    """
    if path.suffix.lower() != ".csv":
        raise InputError(
            f"{path}: only a CSV table can be followed as it grows; use --replay for {path.suffix}"
        )
    fol = _Follower(path)
    first = None
    t0 = time.monotonic()
    while first is None or first.empty:
        check_interrupt()
        first = fol.read()
        if (first is None or first.empty) and time.monotonic() - t0 > idle_s:
            raise InputError(f"{path}: no rows arrived within {idle_s:g} s")
        if first is None:
            time.sleep(poll_s)
    axes = tuple(a for a in ("z", "x", "y") if a in first.columns)
    layout = Layout(tuple(int(p) for p in np.unique(first["plate"].to_numpy())), axes)

    def gen():
        pending = first
        last = time.monotonic()
        while True:
            new = fol.read()
            if new is not None and not new.empty:
                pending = pd.concat([pending, new], ignore_index=True)
                last = time.monotonic()
            done = time.monotonic() - last > idle_s
            if pending is not None and not pending.empty:
                t_last = pending["t"].max()
                ready = pending if done else pending[pending["t"] < t_last]
                if not ready.empty:
                    t, Y, _ = frames_from_table(ready, layout)
                    yield t, Y
                    pending = pending[pending["t"] >= t_last] if not done else None
            if done:
                return
            if new is None:
                check_interrupt()
                time.sleep(poll_s)

    return Source(str(path), layout, gen(), live=True)


def recording_source(path: Path, follow: bool = False, idle_s: float = 10.0, chunk: int = 64) -> Source:
    """Frames through the real-time tracked extraction (plates detected once, then tracked)."""
    from ..frames import Extractor, PlateGeometry
    from ..io.recording import open_recording

    rec = open_recording(path)
    geo = PlateGeometry(rec.plate_x_mm, rec.camera_x_mm) if rec.plate_x_mm is not None else None
    ex = Extractor(rec.intrinsics, rec.kind, geo, realtime=True, source=str(rec.path))
    if rec.n_frames == 0 and not follow:
        raise InputError(f"{path}: the recording has no frames")
    # the plates are known once the first chunk is calibrated
    first = next(rec.chunks(chunk)) if rec.n_frames else None
    while first is None:
        check_interrupt()
        time.sleep(0.2)
        rec = open_recording(path)
        first = next(rec.chunks(chunk)) if rec.n_frames else None
    cents, plates = ex.run(first.frames, first.amplitude)
    layout = Layout(tuple(int(p) for p in plates), ("z", "x", "y"))

    def as_y(c: np.ndarray, pl: np.ndarray) -> np.ndarray:
        out = np.full((c.shape[0], len(layout.plates), 3), np.nan)
        index = {p: i for i, p in enumerate(layout.plates)}
        for k, p in enumerate(pl):
            if int(p) in index:
                out[:, index[int(p)], :] = c[:, k, [2, 0, 1]]
        return out.reshape(c.shape[0], -1)

    def gen():
        yield first.t, as_y(cents, plates)
        done = first.start + len(first.t)
        current = rec
        last = time.monotonic()
        broken = None  # the error of a store caught between its new shape and its new chunk
        while True:
            got = False
            for ch in current.chunks(chunk, start=done):
                check_interrupt()
                c, pl = ex.run(ch.frames, ch.amplitude)
                yield ch.t, as_y(c, pl)
                done = ch.start + len(ch.t)
                got = True
            if not follow:
                return
            if got:
                last = time.monotonic()
            elif time.monotonic() - last > idle_s:
                if broken is not None:  # never completed: a damaged store, not a slow writer
                    raise broken
                return
            time.sleep(0.1)
            try:
                current, broken = open_recording(path), None
            except InputError as err:  # a chunk appended right now: read it at the next poll
                broken = err

    return Source(str(path), layout, gen(), live=follow)


def simulated_source(config: Path, duration_s: float | None = None, seed: int | None = None) -> Source:
    """The live simulated camera (trajectory level) with the config's scheduled changes."""
    from ..simulate import camera_blocks, load_config

    cfg = load_config(config)
    duration = cfg.recording.duration_s if duration_s is None else float(duration_s)
    seed = cfg.recording.seed if seed is None else int(seed)
    layout = Layout(tuple(range(1, cfg.plates.count + 1)), ("z", "x", "y"))
    block = max(1, int(round(cfg.camera.frame_rate_hz)))

    def gen():
        for t, xyz in camera_blocks(cfg, duration, seed, block_frames=block):
            # (frame, plate, [x, y, z]) -> series order z, x, y
            yield t, xyz[..., [2, 0, 1]].reshape(len(t), -1)

    return Source(f"simulated {cfg.source}", layout, gen())


def open_source(
    source: Path | None,
    replay: Path | None,
    config: Path | None,
    idle_s: float = 10.0,
    timestamps: str = "strict",
) -> Source:
    """The source the CLI's arguments name (exactly one of SOURCE, --replay, --config).

    ``timestamps``: the policy of `jaxdefl.io` for a replayed table; a followed source is read
    as it arrives, where a clock can only be recovered from what came so far: strict only."""
    from .._errors import ConfigError
    from ..io import check_timestamp_policy

    check_timestamp_policy(timestamps)
    if timestamps != "strict" and replay is None:
        raise ConfigError(
            f"--timestamps {timestamps}: applies to --replay of a table; a followed or simulated "
            "source is read as it arrives (strict)"
        )

    given = [x for x in (source, replay, config) if x is not None]
    if len(given) != 1:
        raise ConfigError(
            "jaxdefl monitor: give exactly one of SOURCE (a growing table or recording), "
            "--replay RECORDING or --config CONFIG (a simulated camera)"
        )
    if config is not None:
        return simulated_source(config)
    path = Path(source if source is not None else replay)
    if not path.exists() and replay is not None:
        raise InputError(f"{path}: not found; expected a trajectory table or a recording")
    is_table = path.suffix.lower() in TABLE_SUFFIXES
    if replay is not None:
        if is_table:
            return table_source(path, timestamps=timestamps)
        if timestamps != "strict":
            raise ConfigError(f"--timestamps {timestamps}: applies to --replay of a table, not of frames")
        return recording_source(path)
    if is_table:
        return follow_table(path, idle_s=idle_s)
    if not path.exists():
        raise InputError(f"{path}: not found; expected a trajectory table or a recording")
    return recording_source(path, follow=True, idle_s=idle_s)
