"""`jaxdefl monitor`: a source of frames through the `Monitor`, to logs, snapshots and a dashboard.

Outputs in DIR:

- ``events.jsonl``: one JSON object per line — state changes (learning, monitoring, restarted,
  plate_recovered, stopped) and alarms (class, quantity, plates, axes, t_change, size, sigma,
  unit, message); each line is written and flushed (fsynced) when it happens, so a reader, or the
  record left by a killed monitor, has every event up to that moment and never half a line.
- ``estimates.csv``: every ``snapshot_s`` seconds of data the tracker's estimates, the estimates
  table's columns plus ``t_update`` (wall-clock epoch s of the snapshot); appended and flushed.
  Segment ``camera``; with ``--reference LDS.csv`` (read at the start) the LDS are monitored
  alongside up to the camera's time, as segment ``reference`` (their events: ``source: reference``).
- ``snapshot.png``: f0 and every plate's z amplitude ± σ against time with the alarms, replaced
  atomically every ``figure_s`` seconds of data and at the end.
- ``monitor.json``: the settings and the source, written atomically at the start.

The logs are the monitor's record, so they are appended as the run goes (a run restarted on the
same DIR starts them again) rather than staged and committed at the end like other commands'
outputs. SIGINT/SIGTERM stop the loop at the next chunk: a ``stopped`` event is written and the
logs are flushed before the command exits with 130/143.
"""

from __future__ import annotations

import json
import math
import os
import sys
import time
from collections import deque
from pathlib import Path

import numpy as np

from .._errors import ConfigError, InputError, Interrupted
from .._signals import check_interrupt
from ..io.output import Outputs, format_table
from ..progress import wrote
from ..settings import MonitorSettings
from .detect import DetectorSettings
from .engine import SNAPSHOT_COLUMNS, Monitor
from .estimator import TrackerSettings
from .sources import Source

__all__ = ["run_monitor", "OUTPUT_NAMES"]

OUTPUT_NAMES = ("events.jsonl", "estimates.csv", "snapshot.png", "monitor.json")
_SPARK = "▁▂▃▄▅▆▇█"


def _plain(x):
    if isinstance(x, (np.floating, float)):
        return float(x) if math.isfinite(x) else None
    if isinstance(x, np.integer):
        return int(x)
    if isinstance(x, (list, tuple)):
        return [_plain(v) for v in x]
    return x


class _Log:
    """Append-only JSON lines and CSV rows, flushed as written."""

    def __init__(self, out: Path):
        self.events = open(out / "events.jsonl", "w", encoding="utf-8")
        self.table = open(out / "estimates.csv", "w", encoding="utf-8")
        self.table.write(",".join(SNAPSHOT_COLUMNS) + "\n")
        self.table.flush()
        self.alarms: list[dict] = []

    def event(self, ev: dict) -> None:
        ev = {k: _plain(v) for k, v in ev.items()}
        self.events.write(json.dumps(ev, ensure_ascii=False) + "\n")
        self.events.flush()
        os.fsync(self.events.fileno())
        if ev.get("event") == "alarm":
            self.alarms.append(ev)

    def rows(self, df) -> None:
        text = format_table(df)
        self.table.write(text.split("\n", 1)[1])
        self.table.flush()

    def close(self) -> None:
        for fh in (self.events, self.table):
            fh.flush()
            os.fsync(fh.fileno())
            fh.close()


def _sparkline(values: list[float]) -> str:
    v = np.array([x for x in values if np.isfinite(x)])
    if v.size == 0:
        return ""
    lo, hi = v.min(), v.max()
    idx = (
        np.zeros(v.size, int)
        if hi - lo <= 0
        else ((v - lo) / (hi - lo) * (len(_SPARK) - 1)).round().astype(int)
    )
    return "".join(_SPARK[i] for i in idx[-30:])


class _Display:
    """A rich live dashboard on a terminal, plain lines otherwise."""

    def __init__(self, layout, live: bool):
        self.layout, self.live = layout, live
        self.history: dict[int, deque] = {p: deque(maxlen=60) for p in layout.plates}
        self.last_alarms: deque[str] = deque(maxlen=6)
        self._live = None
        self._next = 0.0
        self.row: dict | None = None
        if live:
            from rich.live import Live

            self._live = Live(self._render(), refresh_per_second=4, transient=False)
            self._live.start()

    def _render(self):
        from rich.console import Group
        from rich.table import Table

        tab = Table(title="jaxdefl monitor", expand=False)
        for col in ("plate", "f0 Hz", "A_z mm ± σ", "A_z history", "state"):
            tab.add_column(col)
        r = self.row
        for p in self.layout.plates:
            if r is None:
                tab.add_row(str(p), "", "", "", "starting")
                continue
            q = r.get(p)
            tab.add_row(
                str(p),
                f"{q['f0']:.5f} ± {q['sf0']:.1e}",
                f"{q['a']:.3f} ± {q['sa']:.3f}",
                _sparkline(list(self.history[p])),
                q["state"],
            )
        return Group(tab, *(self.last_alarms or ["no alarm"]))

    def snapshot(self, df, lost_plates: set[int]) -> None:
        z = df[df["axis"] == "z"] if "z" in set(df["axis"]) else df
        row = {}
        for rec in z.itertuples():
            p = int(rec.plate)
            self.history[p].append(rec.amplitude_mm)
            row[p] = dict(
                f0=rec.f0_hz,
                sf0=rec.sigma_f0_hz,
                a=rec.amplitude_mm,
                sa=rec.sigma_amplitude_mm,
                state="lost" if p in lost_plates else "tracking",
            )
        self.row = row
        if self._live is not None and time.monotonic() >= self._next:
            self._live.update(self._render())
            self._next = time.monotonic() + 0.25

    def event(self, ev: dict) -> None:
        when = time.strftime("%H:%M:%S", time.gmtime(ev["t"])) if ev.get("t") else ""
        line = f"{when} {ev.get('event')} {ev.get('class', ev.get('state', ''))}: {ev.get('message', '')}"
        if ev.get("event") == "alarm":
            self.last_alarms.append(line)
        if self._live is not None:
            self._live.update(self._render())
        else:
            print(f"jaxdefl monitor: {line}", flush=True)

    def summary(self, t_data: float, fps: float) -> None:
        if self._live is not None or self.row is None:
            return
        q = next(iter(self.row.values()))
        amps = ", ".join(f"{p}:{v['a']:.3f}" for p, v in self.row.items())
        print(
            f"jaxdefl monitor: t={t_data:.1f} s f0={q['f0']:.5f}±{q['sf0']:.1e} Hz A_z[{amps}] mm "
            f"({fps:.0f} frames/s)",
            flush=True,
        )

    def close(self) -> None:
        if self._live is not None:
            self._live.update(self._render())
            self._live.stop()


def _figure(history: list, alarms: list[dict], layout, t0: float):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    if history:
        t = np.array([h[0] for h in history]) - t0
        f0 = np.array([h[1] for h in history])
        sf0 = np.array([h[2] for h in history])
        ax1.plot(t, f0, "k-", lw=1)
        ax1.fill_between(t, f0 - sf0, f0 + sf0, color="0.7")
        amps = np.array([h[3] for h in history])  # (snap, plate)
        samps = np.array([h[4] for h in history])
        cmap = plt.get_cmap("viridis")
        for j, p in enumerate(layout.plates):
            col = cmap(j / max(len(layout.plates) - 1, 1))
            ax2.plot(t, amps[:, j], color=col, lw=1, label=str(p))
            ax2.fill_between(t, amps[:, j] - samps[:, j], amps[:, j] + samps[:, j], color=col, alpha=0.2)
    for ev in alarms:
        for ax in (ax1, ax2):
            ax.axvline(ev["t"] - t0, color="r" if ev.get("class") == "structural" else "orange", lw=0.8)
    ax1.set_ylabel("f0 (Hz)")
    ax2.set_ylabel("A_z (mm)")
    ax2.set_xlabel("time since the first frame (s)")
    ax2.legend(ncol=7, fontsize=6, title="plate", title_fontsize=6)
    ax1.set_title("jaxdefl monitor (red: structural alarm, orange: plate or sensor)")
    fig.tight_layout()
    return fig


def run_monitor(
    source: Source,
    out_dir: Path,
    settings: MonitorSettings | None = None,
    *,
    figure_s: float = 60.0,
    dashboard: bool | None = None,
    inputs: tuple[Path, ...] = (),
    reference: Path | None = None,
) -> dict:
    """Run the monitor on ``source`` until it ends, ``until_s`` s of data, ``duration_s`` s of
    wall-clock time or a signal (``settings``: `jaxdefl.settings.MonitorSettings`, validated
    when made; default: its defaults). ``speed`` paces a replayed or simulated source (× real
    time; 0: as fast as it goes). Returns a summary (frames, alarms, per-frame update time).

    Raises:
        ConfigError: an output that is an input.
        Interrupted: SIGINT/SIGTERM (after the logs are flushed and a stopped event written).
    """
    from threadpoolctl import threadpool_limits

    s = settings if settings is not None else MonitorSettings()
    speed, until_s, duration_s, method = s.speed, s.until_s, s.duration_s, s.method
    alarms_per_day, block_s, snapshot_s = s.alarms_per_day, s.block_s, s.snapshot_s
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise ConfigError(f"--out {out}: is a file; expected a directory")
    plan = Outputs(inputs=inputs)
    for name in OUTPUT_NAMES:
        plan.reserve(out / name, f"--out {out}: {name}")
    out.mkdir(parents=True, exist_ok=True)
    settings = dict(
        source=source.name,
        reference=None if reference is None else str(reference),
        layout=dict(plates=list(source.layout.plates), axes=list(source.layout.axes)),
        speed=speed,
        until_s=until_s,
        duration_s=duration_s,
        method=method,
        alarms_per_day=alarms_per_day,
        block_s=block_s,
        snapshot_s=snapshot_s,
        figure_s=figure_s,
    )
    with Outputs() as o:
        o.json(out / "monitor.json", settings)
    mon = Monitor(
        source.layout,
        TrackerSettings(method=method),
        DetectorSettings(block_s=block_s, alarms_per_day=alarms_per_day),
        segment="camera",
    )
    live = sys.stdout.isatty() if dashboard is None else dashboard
    log, disp = _Log(out), _Display(source.layout, live)
    history: deque = deque(maxlen=5000)
    z_cols = [k for k, a in enumerate(source.layout.axis_of()) if a == source.layout.axes[0]]
    ref = _Reference(reference, method, block_s, alarms_per_day) if reference is not None else None
    wall0 = time.monotonic()
    t_first = next_snap = next_fig = None
    reason = "end of the source"
    try:
        with threadpool_limits(1, user_api="blas"):  # small matrices: threads only cost latency
            for t, Y in source.chunks:
                check_interrupt()
                if t.size == 0:
                    continue
                if t_first is None:
                    t_first = float(t[0])
                    next_snap, next_fig = t_first + snapshot_s, t_first + figure_s
                if until_s is not None and t[-1] - t_first >= until_s:
                    keep = t - t_first <= until_s
                    t, Y = t[keep], Y[keep]
                    reason = "--until"
                if speed > 0 and not source.live:
                    due = wall0 + (t[-1] - t_first) / speed
                    while (wait := due - time.monotonic()) > 0:
                        time.sleep(min(wait, 0.1))
                        check_interrupt()
                for ev in mon.feed(t, Y) + (ref.feed_until(float(t[-1])) if ref else []):
                    log.event(ev)
                    disp.event(ev)
                if mon.started and t[-1] >= next_snap:
                    df = mon.snapshot()
                    log.rows(df)
                    if ref is not None and ref.mon.started:
                        log.rows(ref.mon.snapshot())
                    lost = {int(p) for p in source.layout.plate_of()[mon.detector.lost]}
                    disp.snapshot(df, lost)
                    est = df.iloc[z_cols]
                    history.append(
                        (
                            float(t[-1]),
                            float(df["f0_hz"].iloc[0]),
                            float(df["sigma_f0_hz"].iloc[0]),
                            est["amplitude_mm"].to_numpy(),
                            est["sigma_amplitude_mm"].to_numpy(),
                        )
                    )
                    next_snap = float(t[-1]) + snapshot_s
                if mon.started and t[-1] >= next_fig:
                    _write_figure(out, history, log.alarms, source.layout, t_first)
                    disp.summary(float(t[-1] - t_first), mon.frames / max(time.monotonic() - wall0, 1e-9))
                    next_fig = float(t[-1]) + figure_s
                if reason == "--until":
                    break
                if duration_s is not None and time.monotonic() - wall0 >= duration_s:
                    reason = "--duration"
                    break
    except Interrupted as err:
        reason = f"interrupted ({err})"
        raise
    finally:
        learning = _still_learning(mon)
        stop = {
            "event": "state",
            "state": "stopped",
            "t": mon.t_last if np.isfinite(mon.t_last) else None,
            "reason": reason,
            "frames": mon.frames,
            "message": f"stopped: {reason}; {mon.frames} frames, {len(log.alarms)} alarm(s)"
            + (f"; {learning}" if learning else ""),
        }
        if learning:
            stop["still_learning"] = True
        log.event(stop)
        disp.event(stop)
        if learning:
            print(f"jaxdefl monitor: warning: {learning}", file=sys.stderr, flush=True)
        if mon.started:
            log.rows(mon.snapshot())
        log.close()
        disp.close()
    if mon.started:
        _write_figure(out, history, log.alarms, source.layout, t_first)
    if not mon.started and reason == "end of the source":
        raise InputError(
            f"{source.name}: the source ended after {mon.frames} frames, before the monitor could start "
            f"(it fits the first {mon.init_s:g} s)"
        )
    wrote(
        "monitor",
        *(out / n for n in OUTPUT_NAMES if (out / n).exists()),
        detail=f"{mon.frames} frames, {len(log.alarms)} alarm(s); stopped: {reason}"
        + ("; still learning" if learning else ""),
    )
    tracked = max(mon.tracker.frames if mon.started else 0, 1)
    return {
        "frames": mon.frames,
        "alarms": log.alarms,
        "update_ms_per_frame": 1e3 * mon.update_seconds / tracked,
        "reason": reason,
    }


def _still_learning(mon: Monitor) -> str | None:
    """Why no alarm could be raised, when the monitor never left ``learning``; else None."""
    if not mon.started or mon.detector.state != "learning":
        return None
    st = mon.detector.settings
    need_s = st.learn_blocks * st.block_s
    have_s = len(mon.detector.learning) * st.block_s
    return (
        f"it never left `learning`, so no change could be alarmed: the references are learnt on "
        f"{need_s / 60:g} min of data ({st.learn_blocks} blocks of --block {st.block_s:g} s) after "
        f"the first {mon.init_s:g} s that start the tracker, and it had {have_s:.0f} s; give it at "
        f"least {(mon.init_s + need_s) / 60:.1f} min of data"
    )


class _Reference:
    """The LDS (``--reference``, t, plate, z) monitored alongside, up to the camera's time: its
    estimates go to estimates.csv as segment ``reference``, its events carry ``source: reference``."""

    def __init__(self, path: Path, method: str, block_s: float, alarms_per_day: float):
        from ..io import read_reference
        from .layout import Layout, frames_from_table

        df = read_reference(path)
        layout = Layout(tuple(int(p) for p in np.unique(df["plate"].to_numpy())), ("z",))
        self.t, self.Y, _ = frames_from_table(df, layout)
        self.k = 0
        self.mon = Monitor(
            layout,
            TrackerSettings(method=method),
            DetectorSettings(block_s=block_s, alarms_per_day=alarms_per_day),
            segment="reference",
        )

    def feed_until(self, t_end: float) -> list[dict]:
        stop = int(np.searchsorted(self.t, t_end, side="right"))
        events = []
        while self.k < stop:  # a second of samples at a time
            e = min(stop, self.k + 512)
            events += self.mon.feed(self.t[self.k : e], self.Y[self.k : e])
            self.k = e
        for ev in events:
            ev["source"] = "reference"
            ev["message"] = "reference (LDS): " + ev.get("message", "")
        return events


def _write_figure(out: Path, history, alarms, layout, t0) -> None:
    import matplotlib.pyplot as plt

    fig = _figure(list(history), alarms, layout, t0)
    try:
        with Outputs() as o:
            o.figure(out / "snapshot.png", fig, dpi=90)
    finally:
        plt.close(fig)
