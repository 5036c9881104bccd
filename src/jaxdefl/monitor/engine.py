"""The monitor without I/O: frames in, estimates and events out.

The first ``init_s`` seconds are buffered and fitted in batch (`jaxdefl.fit`) to start the
tracker; from then on every frame updates the tracker (`HarmonicTracker.update`, the per-frame
latency) and the block accumulator, and every finished block goes through the change detector.
"""

from __future__ import annotations

import time
from collections import deque

import numpy as np
import pandas as pd

from .._errors import InputError
from ..fit import ESTIMATE_COLUMNS
from ..status import Status
from .blocks import BlockAccumulator
from .detect import ChangeDetector, DetectorSettings
from .estimator import HarmonicTracker, TrackerSettings, initial_state
from .layout import Layout, fit_span

__all__ = ["Monitor", "SNAPSHOT_COLUMNS"]

SNAPSHOT_COLUMNS = [*ESTIMATE_COLUMNS, "t_update"]


class Monitor:
    """Tracker + blocks + detector over one stream of frames (see the module doc)."""

    def __init__(
        self,
        layout: Layout,
        tracker: TrackerSettings | None = None,
        detector: DetectorSettings | None = None,
        init_s: float = 10.0,
        segment: str = "",
        track: bool = True,
    ):
        """``track=False``: detection only (detection studies over simulated days): the tracker
        is started (reference frequency, noise correlation) but not updated frame by frame."""
        self.layout = layout
        self.tracker_settings = tracker or TrackerSettings()
        self.detector_settings = detector or DetectorSettings()
        self.init_s, self.segment, self.track = init_s, segment, track
        self._buf_t: list[np.ndarray] = []
        self._buf_y: list[np.ndarray] = []
        self.tracker: HarmonicTracker | None = None
        self.blocks: BlockAccumulator | None = None
        self.detector: ChangeDetector | None = None
        self.t_last = float("nan")
        self.frames = 0
        self.snapshots = 0
        self.update_seconds = 0.0  # time spent in per-frame updates (tracker + blocks)
        self._recent: deque[tuple[np.ndarray, np.ndarray]] = deque()  # the last init_s of frames

    @property
    def started(self) -> bool:
        return self.tracker is not None

    def feed(self, t: np.ndarray, Y: np.ndarray) -> list[dict]:
        """Take a chunk of frames (t increasing); returns the events it caused."""
        t = np.asarray(t, np.float64)
        Y = np.asarray(Y, np.float64)
        if t.size == 0:
            return []
        if np.isfinite(self.t_last):
            keep = t > self.t_last  # a frame repeated by a source is taken once
            t, Y = t[keep], Y[keep]
            if t.size == 0:
                return []
        if np.any(np.diff(t) <= 0):
            raise InputError("frames: timestamps must increase")
        self.t_last = float(t[-1])
        self.frames += t.size
        if self.tracker is None:
            self._buf_t.append(t)
            self._buf_y.append(Y)
            tb = np.concatenate(self._buf_t)
            if tb[-1] - tb[0] < self.init_s:
                return []
            return self._start(tb, np.concatenate(self._buf_y))
        return self._track(t, Y)

    def _start(self, t: np.ndarray, Y: np.ndarray) -> list[dict]:
        n0 = int(np.searchsorted(t, t[0] + self.init_s, side="right"))
        fit = fit_span(t[:n0], Y[:n0], self.layout)
        try:
            self.tracker = initial_state(t[:n0], Y[:n0], fit, self.tracker_settings)
        except ValueError as err:
            # not yet: keep buffering (a longer span may show the loading), but bounded
            if t[-1] - t[0] > 6 * self.init_s:
                raise InputError(f"monitor: {err} in the first {t[-1] - t[0]:.0f} s") from None
            self.init_s *= 1.5
            return []
        tr = self.tracker
        self.detector = ChangeDetector(self.layout, self.detector_settings, f0_hz=tr.x[0] / (2 * np.pi))
        self.blocks = BlockAccumulator(
            self.layout.n,
            tr.x[0],
            tr.t_ref,
            self.detector_settings.block_s,
            float(t[n0 - 1]) + 1e-9,
            tr.x[tr.ic],
        )
        self._buf_t, self._buf_y = [], []
        events = [
            {
                "event": "state",
                "state": "learning",
                "t": float(t[n0 - 1]),
                "message": (
                    f"started from a batch fit of the first {t[n0 - 1] - t[0]:.1f} s: f0 = "
                    f"{tr.x[0] / (2 * np.pi):.5f} Hz; learning the references"
                ),
            }
        ]
        return events + self._track(t[n0:], Y[n0:])

    def _track(self, t: np.ndarray, Y: np.ndarray) -> list[dict]:
        tr = self.tracker
        c0 = time.perf_counter()
        if self.track:
            for k in range(t.size):
                tr.update(t[k], Y[k])
        finished = self.blocks.add(t, Y)
        self.update_seconds += time.perf_counter() - c0
        self._recent.append((t, Y))
        while len(self._recent) > 1 and self._recent[-1][0][-1] - self._recent[1][0][0] >= self.init_s:
            self._recent.popleft()
        events = []
        for b in finished:
            events += self.detector.step(b, tr.corr)
        if any(e.get("class") == "structural" and e.get("quantity") == "f0" for e in events):
            events += self._restart()
        return events

    def _restart(self) -> list[dict]:
        """After a frequency change the tracker starts again from a batch fit of the last frames
        (its slow process noise on ω is meant for drifts, not for steps)."""
        t = np.concatenate([c[0] for c in self._recent])
        Y = np.concatenate([c[1] for c in self._recent])
        try:
            tracker = initial_state(t, Y, fit_span(t, Y, self.layout), self.tracker_settings)
        except ValueError:
            return []
        tracker.predict(float(t[-1]))
        self.tracker = tracker
        return [
            {
                "event": "state",
                "state": "restarted",
                "t": float(t[-1]),
                "message": (
                    f"tracker restarted after the frequency change: f0 = {tracker.x[0] / (2 * np.pi):.5f} Hz"
                ),
            }
        ]

    def snapshot(self, t_update: float | None = None) -> pd.DataFrame:
        """The current estimates as rows of the estimates table plus ``t_update`` (wall clock)."""
        tr = self.tracker
        if tr is None:
            return pd.DataFrame(columns=SNAPSHOT_COLUMNS)
        est = tr.estimates()
        t_end = tr.t_ref
        t_start = max(tr.t_start, t_end - self.tracker_settings.memory_s)
        t_mid = 0.5 * (t_start + t_end)
        phase = np.mod(tr.x[0] * (t_end - t_mid) - est["psi_rad"] + np.pi, 2 * np.pi) - np.pi
        lost = self.detector.lost if self.detector is not None else np.zeros(self.layout.n, bool)
        status = np.where(lost, Status.TOO_FEW_SAMPLES, Status.CONVERGED)
        nan = np.full(self.layout.n, np.nan)
        df = pd.DataFrame(
            {
                "segment": self.segment,
                "window": self.snapshots,
                "t_start": t_start,
                "t_end": t_end,
                "plate": self.layout.plate_of(),
                "axis": self.layout.axis_of(),
                "n": self.frames,
                "f0_hz": est["f0_hz"],
                "sigma_f0_hz": est["sigma_f0_hz"],
                "amplitude_mm": est["amplitude_mm"],
                "sigma_amplitude_mm": est["sigma_amplitude_mm"],
                "phase_rad": phase,
                "offset_mm": est["offset_mm"],
                "sigma_residual_mm": est["sigma_residual_mm"],
                "peak_fap": nan,
                "status": status,
                # harmonic share of the variance; the recursive σ's assume noise white in time,
                # so the white-noise σ's are the same numbers and no whiteness test is made
                "r2": (est["amplitude_mm"] ** 2 / 2)
                / (est["amplitude_mm"] ** 2 / 2 + est["sigma_residual_mm"] ** 2),
                "whiteness_p": nan,
                "sigma_amplitude_white_mm": est["sigma_amplitude_mm"],
                "sigma_f0_white_hz": est["sigma_f0_hz"],
                "t_update": time.time() if t_update is None else t_update,
            }
        )
        self.snapshots += 1
        return df[SNAPSHOT_COLUMNS]
