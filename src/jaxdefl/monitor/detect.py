"""Change detection on the block estimates: CUSUM charts, thresholds from alarms per day, and
what changed told by its pattern across plates.

Charts (two-sided CUSUM on standardised block statistics z, reference value k, threshold h;
Page 1954): the loading frequency (one chart for the beam: the block δω of every series whose
harmonic is clear, combined by generalised least squares with their noise correlation — a ToF
camera's range error is shared by the plates of a frame — against its reference), and per series
the amplitude, the offset and (one-sided, upward) the residual level ln s². References are the
means of the first ``learn_blocks`` blocks, then follow slowly (time constant ``reference_s``)
while a chart is in control, so fatigue's slow growth of the amplitude is not an alarm.

Threshold: the charts' sides together may give ``alarms_per_day`` false alarms per day of data,
so each side needs an in-control average run length ARL₀ = sides × blocks per day / rate
(Bonferroni over the plates × axes × quantities); h solves Siegmund's approximation
ARL₀ = (e^{2kb} − 2kb − 1)/(2k²), b = h + 1.166 (Siegmund 1985), averaged over the reference's own
error, which a chart sees as a steady shift of 1/√n block σ's when the reference holds n blocks.
So h is per series and follows its reference's n (`ThresholdTable`): high just after the learning
or after an alarm re-learnt the level (a reference of 60 blocks is off by 0.13 σ, half the
amplitude charts' k), down to its value for a full reference. Each block statistic is first made
N(0, 1) as the threshold assumes: standardised by its block's own σ it is Student's t (made normal
through its quantile), and it is divided by the spread its reference has seen beyond the model σ
(coloured or frame-common noise; never below 1, `_Reference.spread`).

An alarm names the quantity, the plate(s) and axes, the time of change (the start of the block
after the chart last left zero) and the size: the mean deviation since then with its σ. Its class
comes from the pattern across plates:

- ``structural``: the frequency changed on the plates alike (their per-plate δω agree), or the
  amplitude changed by the same relative amount on the other plates too (a stiffness change
  scales the whole deflection shape);
- ``plate``: one plate's amplitude changed and the others did not (a debonded plate, a local
  defect);
- ``sensor``: a plate lost (its samples stop), a jump of its reading (offset), more noise on it
  (or on all plates at once: the camera), a frequency change on some plates only.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from .blocks import BlockResult
from .layout import Layout

__all__ = [
    "DetectorSettings",
    "ChangeDetector",
    "ThresholdTable",
    "cusum_threshold",
    "cusum_arl",
    "gls_mean",
    "t_to_normal",
]

SECONDS_PER_DAY = 86400.0


@dataclass(frozen=True)
class DetectorSettings:
    block_s: float = 5.0
    learn_blocks: int = 60  # 5 min: the references' own error must stay small against k
    alarms_per_day: float = 1.0
    k: float = 0.5  # reference value, σ per block (optimal for shifts of 2k = 1 σ per block)
    # amplitude charts: tuned for half a σ per block (a 3 % step at mid-span on a 20-Hz ToF camera)
    k_amplitude: float = 0.25
    reference_s: float = 3600.0
    min_snr: float = 5.0  # amplitude / σ per block for a series' amplitude and phase to be charted
    lost_fraction: float = 0.5  # a series with fewer samples than this share of a block's frames


def cusum_arl(h: float, k: float) -> float:
    """In-control average run length (blocks) of a one-sided CUSUM on N(0, 1) (Siegmund)."""
    b = h + 1.166
    x = np.minimum(2 * k * b, 700.0)  # beyond, the run length is infinite for any purpose
    return (np.exp(x) - x - 1) / (2 * k * k)


_GH_X, _GH_W = np.polynomial.hermite_e.hermegauss(21)
_GH_W = _GH_W / _GH_W.sum()


def _alarm_rate(h: float, k: float, ref_sd: float) -> float:
    """1/ARL averaged over a reference offset δ ~ N(0, ref_sd²) that the chart sees as a shift
    (the reference is itself an estimate; it changes slowly against the CUSUM's memory)."""
    if ref_sd <= 0:
        return 1.0 / cusum_arl(h, k)
    x, w = _GH_X, _GH_W
    keff = k - ref_sd * x
    b = h + 1.166
    arl = np.where(keff > 0.02, cusum_arl(h, np.maximum(keff, 0.02)), b * b)  # no drift: ~b² steps
    return float(np.sum(w / arl))


def cusum_threshold(arl_blocks: float, k: float, ref_sd: float = 0.0) -> float:
    """The h whose one-sided in-control ARL is ``arl_blocks`` (bisection on `cusum_arl`), with
    the alarm rate averaged over the reference's own error ``ref_sd`` (σ per block) if given."""
    lo, hi = 0.0, 400.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if _alarm_rate(mid, k, ref_sd) > 1.0 / arl_blocks:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


class ThresholdTable:
    """h against the number n of blocks behind a chart's reference: `cusum_threshold` with the
    reference's error 1/√n block σ's (tabulated on n, interpolated in log n). A reference learnt
    on the first minutes, or re-learnt after an alarm, is far from the mean a full one reaches;
    a chart on it gets the threshold that keeps its false alarms at the rate of a full one."""

    def __init__(self, arl_blocks: float, k: float, n_max: int):
        self.n = np.unique(np.round(np.geomspace(1, max(n_max, 2), 40)))
        self.h = np.array([cusum_threshold(arl_blocks, k, 1 / np.sqrt(m)) for m in self.n])

    def __call__(self, count: np.ndarray) -> np.ndarray:
        m = np.clip(np.asarray(count, float), 1, self.n[-1])
        return np.interp(np.log(m), np.log(self.n), self.h)


def t_to_normal(t: np.ndarray, dof: np.ndarray) -> np.ndarray:
    """The standard normal quantile of Student's t with ``dof`` (a block statistic standardised
    by its own block's σ has heavier tails than N(0, 1), which a CUSUM threshold assumes)."""
    from scipy.special import ndtri, stdtr

    t = np.asarray(t, float)
    d = np.where(np.isfinite(dof) & (dof > 0), dof, np.inf)
    with np.errstate(invalid="ignore"):
        z = -ndtri(stdtr(d, -np.abs(t)))
    return np.where(np.isfinite(d), np.sign(t) * z, t)


def gls_mean(values: np.ndarray, sigmas: np.ndarray, corr: np.ndarray) -> tuple[float, float]:
    """Generalised least-squares mean of correlated estimates and its σ (NaN when none)."""
    ok = np.isfinite(values) & np.isfinite(sigmas) & (sigmas > 0)
    if not ok.any():
        return float("nan"), float("nan")
    v, s = values[ok], sigmas[ok]
    cov = corr[np.ix_(ok, ok)] * np.outer(s, s) + np.diag(1e-9 * s * s)
    try:
        w = np.linalg.solve(cov, np.ones(v.size))
    except np.linalg.LinAlgError:
        w = 1 / (s * s)
    tot = float(w.sum())
    if not tot > 0:  # a degenerate correlation: fall back to independent weights
        w = 1 / (s * s)
        tot = float(w.sum())
    return float(w @ v / tot), float(np.sqrt(1 / tot))


class _Reference:
    """The in-control level of a vector of block statistics: the running mean of the blocks
    (over the last ``n_max``), taken ``lag`` blocks late, with its σ. Every block is taken — no
    censoring by the chart, which would bias a one-sided chart — except those an alarm has since
    attributed to a change; the lag leaves a change time to be detected before it is absorbed."""

    def __init__(self, n: int, n_max: int, lag: int):
        self.value = np.full(n, np.nan)
        self.var = np.zeros(n)  # running mean of the blocks' σ²
        self.count = np.zeros(n)
        self.r2 = np.ones(n)  # running mean of the squared standardised prediction residuals
        self.n_max, self.lag = n_max, lag
        self.queue: deque[tuple[np.ndarray, np.ndarray, np.ndarray]] = deque()
        self.direct_until = np.zeros(n)  # after an alarm: take the new level's blocks at once

    def take(self, x: np.ndarray, var: np.ndarray, mask: np.ndarray) -> None:
        ok = mask & np.isfinite(x) & np.isfinite(var)
        a = 1.0 / np.minimum(self.count + 1, self.n_max)
        first = ok & ~np.isfinite(self.value)
        seen = ok & ~first & (self.count >= 2)
        with np.errstate(invalid="ignore", divide="ignore"):
            r2 = (x - self.value) ** 2 / (var + self.sigma() ** 2)
        m = np.minimum(self.count - 1, self.n_max)  # residuals taken so far
        self.r2 = np.where(seen, self.r2 + (r2 - self.r2) / np.maximum(m, 1), self.r2)
        self.value = np.where(first, x, self.value)
        self.value = np.where(ok & ~first, self.value + a * (x - self.value), self.value)
        self.var = np.where(ok, self.var + a * (var - self.var), self.var)
        self.count = np.where(ok, self.count + 1, self.count)

    def offer(self, x: np.ndarray, var: np.ndarray, mask: np.ndarray) -> None:
        direct = self.count < self.direct_until
        self.take(x, var, mask & direct)
        self.queue.append((np.array(x, float), np.array(var, float), np.array(mask & ~direct, bool)))
        if len(self.queue) > self.lag:
            self.take(*self.queue.popleft())

    def sigma(self) -> np.ndarray:
        return np.sqrt(self.var / np.maximum(np.minimum(self.count, self.n_max), 1))

    def spread(self) -> np.ndarray:
        """The blocks' spread around the reference in units of their model σ: the square root
        of the mean squared prediction residual, lowered by its standard error (so white noise
        reads 1) and never below 1 (the model's σ is a floor: the spread never lowers a
        threshold). Coloured or frame-common noise, or a wandering level, raise it."""
        m = np.minimum(np.maximum(self.count - 2, 0), self.n_max)
        with np.errstate(invalid="ignore", divide="ignore"):
            s = np.sqrt(self.r2) * (1 - 1 / np.sqrt(2 * np.maximum(m, 1)))
        return np.where(m >= 10, np.maximum(s, 1.0), 1.0)

    def blocks(self) -> np.ndarray:
        """The number of blocks behind the level (its error is 1/√ of it in block σ's)."""
        return np.maximum(np.minimum(self.count, self.n_max), 1)

    def restart(self, idx, value, count) -> None:
        """A change was found: the level is ``value`` (from ``count`` blocks); the next ``lag``
        blocks refine it at once (it is new, there is no change left to wait for)."""
        self.value[idx] = value
        self.count[idx] = count
        self.direct_until[idx] = self.count[idx] + self.lag
        for _, _, m in self.queue:  # blocks queued before the alarm belong to the old level
            m[idx] = False


class _Chart:
    """Two-sided (or upward) CUSUMs of a vector of statistics, with their change starts."""

    def __init__(self, n: int, k: float, table: ThresholdTable, upward_only: bool = False):
        self.k, self.table, self.up_only = k, table, upward_only
        self.h = np.full(n, float(table.h[-1]))  # per series: from its reference's blocks
        self.hi = np.zeros(n)
        self.lo = np.zeros(n)
        self.start_hi = np.zeros(n, np.int64)
        self.start_lo = np.zeros(n, np.int64)
        self.z: deque[np.ndarray] = deque(maxlen=720)
        self.block = 0

    def onset(self, j: int, up: bool) -> int:
        """The block where the change of series ``j`` most likely began: within the CUSUM's run,
        the start m blocks back that maximises the likelihood ratio (Σ z)²/m of a step."""
        start = int(self.start_hi[j] if up else self.start_lo[j])
        m_max = max(1, min(self.block - start + 1, len(self.z)))
        z = np.array([h[j] for h in list(self.z)[-m_max:]])[::-1]  # newest first
        z = np.where(np.isfinite(z), z, 0.0) * (1 if up else -1)
        cum = np.cumsum(z)
        m = np.arange(1, z.size + 1)
        score = np.where(cum > 0, cum * cum / m, 0.0)
        return self.block - int(np.argmax(score))

    def step(self, z: np.ndarray, block: int, ref_blocks: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        self.h = self.table(ref_blocks)
        self.z.append(np.array(z, float))
        self.block = block
        ok = np.isfinite(z)
        zz = np.where(ok, z, 0.0)
        hi = np.where(ok, np.maximum(0.0, self.hi + zz - self.k), self.hi)
        lo = np.where(ok, np.maximum(0.0, self.lo - zz - self.k), self.lo)
        if self.up_only:
            lo[:] = 0.0
        self.start_hi = np.where((self.hi == 0) & (hi > 0), block, self.start_hi)
        self.start_lo = np.where((self.lo == 0) & (lo > 0), block, self.start_lo)
        self.hi, self.lo = hi, lo
        return hi > self.h, lo > self.h

    def reset(self, idx) -> None:
        self.hi[idx] = 0.0
        self.lo[idx] = 0.0


class ChangeDetector:
    """Learns references on the first blocks, then charts every block (module doc).

    `step(block, corr)` takes a `BlockResult` and the (S, S) noise correlation of the series
    (the tracker's) and returns the events of that block (dicts for events.jsonl).
    """

    def __init__(self, layout: Layout, settings: DetectorSettings = DetectorSettings(), f0_hz: float = 1.0):
        self.layout, self.settings, self.f0_hz = layout, settings, f0_hz
        self.plate_of, self.axis_of = layout.plate_of(), layout.axis_of()
        self.blocks: deque[BlockResult] = deque(maxlen=720)
        self.index = 0
        self.learning: list[BlockResult] = []
        self.state = "learning"
        s = layout.n
        self.lost = np.zeros(s, bool)
        self.charted: np.ndarray | None = None
        self.h = float("nan")
        self.n_sides = 0
        self.f0_history: deque[tuple[float, float]] = deque(maxlen=720)  # (δω, σ)

    # -- references --------------------------------------------------------------------------

    def _learn(self) -> list[dict]:
        st = self.settings
        L = self.learning
        s = self.layout.n
        n_max = max(1, int(round(st.reference_s / st.block_s)))
        lag = st.learn_blocks
        self.ref_A, self.ref_C, self.ref_v = (_Reference(s, n_max, lag) for _ in range(3))
        self.ref_w = _Reference(1, n_max, lag)
        ones = np.ones(s, bool)
        for b in L:
            self.ref_A.take(b.amplitude_mm, b.sigma_amplitude_mm**2, ones)
            self.ref_C.take(b.offset_mm, b.sigma_offset_mm**2, ones)
            with np.errstate(invalid="ignore", divide="ignore"):
                self.ref_v.take(np.log(b.resid_var), 2 / b.dof, ones)
        snr = self.ref_A.value / np.sqrt(self.ref_A.var)
        self.charted = np.isfinite(snr) & (snr >= st.min_snr)
        for b in L:
            dw, sdw = self._combined_domega(b)
            self.ref_w.take(np.array([dw]), np.array([sdw**2]), np.ones(1, bool))
        n_amp = int(self.charted.sum())
        self.n_sides = 2 * (1 + n_amp + s) + s
        blocks_per_day = SECONDS_PER_DAY / st.block_s
        arl = self.n_sides * blocks_per_day / st.alarms_per_day
        # h against the blocks behind a reference (its error is 1/√n block σ's)
        table, table_amp = ThresholdTable(arl, st.k, n_max), ThresholdTable(arl, st.k_amplitude, n_max)
        self.h, self.h_amp = float(table.h[-1]), float(table_amp.h[-1])  # full references
        self.ch_f0 = _Chart(1, st.k, table)
        self.ch_amp = _Chart(s, st.k_amplitude, table_amp)
        self.ch_off = _Chart(s, st.k, table)
        self.ch_noise = _Chart(s, st.k, table, upward_only=True)
        self.state = "monitoring"
        return [
            {
                "event": "state",
                "state": "monitoring",
                "t": L[-1].t_end,
                "message": (
                    f"references learnt on {len(L)} blocks of {st.block_s:g} s; {n_amp} of {s} series "
                    f"charted for amplitude and frequency; CUSUM h = {self.h:.2f} (k = {st.k:g}; "
                    f"amplitude h = {self.h_amp:.2f}, k = {st.k_amplitude:g}) once the references "
                    f"hold {n_max} blocks, {float(table(len(L))):.1f} and "
                    f"{float(table_amp(len(L))):.1f} on the {len(L)} learnt, for "
                    f"{st.alarms_per_day:g} false alarm(s) per day over {self.n_sides} chart sides"
                ),
                "threshold_h": self.h,
                "charted_series": [self.layout.label(j) for j in np.flatnonzero(self.charted)],
            }
        ]

    # -- statistics --------------------------------------------------------------------------

    def _corr_phase(self, b: BlockResult, corr: np.ndarray) -> np.ndarray:
        psi = np.where(np.isfinite(b.psi_rad), b.psi_rad, 0.0)
        return corr * np.cos(psi[:, None] - psi[None, :])

    def _combined_domega(
        self, b: BlockResult, corr: np.ndarray | None = None, mask=None
    ) -> tuple[float, float]:
        sel = np.ones(self.layout.n, bool) if mask is None else mask
        if self.charted is not None:
            sel = sel & self.charted & ~self.lost
        else:
            snr = b.amplitude_mm / b.sigma_amplitude_mm
            sel = sel & (snr >= self.settings.min_snr)
        corr = self._corr if corr is None else corr
        v = np.where(sel, b.domega, np.nan)
        return gls_mean(v, b.sigma_domega, self._corr_phase(b, corr))

    # -- the step ----------------------------------------------------------------------------

    def step(self, b: BlockResult, corr: np.ndarray) -> list[dict]:
        """Chart one block; returns its events."""
        self._corr = corr
        self.blocks.append(b)
        self.index += 1
        events = self._lost_events(b)
        if self.state == "learning":
            if b.frames > 0:
                self.learning.append(b)
            self.f0_history.append(self._combined_domega(b))
            if len(self.learning) >= self.settings.learn_blocks:
                events += self._learn()
            return events
        i = self.index
        live = ~self.lost & np.isfinite(b.amplitude_mm)
        # frequency, the beam's
        dw, sdw = self._combined_domega(b)
        self.f0_history.append((dw, sdw))
        z_f0 = (dw - self.ref_w.value) / np.hypot(sdw, self.ref_w.sigma()) / self.ref_w.spread()
        up, down = self.ch_f0.step(z_f0, i, self.ref_w.blocks())
        if up[0] or down[0]:
            events.append(self._f0_alarm(b, bool(up[0])))
        # amplitude, offset, noise per series
        # standardised by the block's own σ (Student's t, made normal), then by the spread the
        # reference has seen beyond that σ (never below 1)
        with np.errstate(invalid="ignore", divide="ignore"):
            z_a = (b.amplitude_mm - self.ref_A.value) / np.hypot(b.sigma_amplitude_mm, self.ref_A.sigma())
            z_a = np.where(live & self.charted, t_to_normal(z_a, b.dof) / self.ref_A.spread(), np.nan)
            z_c = (b.offset_mm - self.ref_C.value) / np.hypot(b.sigma_offset_mm, self.ref_C.sigma())
            z_c = np.where(live, t_to_normal(z_c, b.dof) / self.ref_C.spread(), np.nan)
            z_n = (np.log(b.resid_var) - self.ref_v.value) / np.sqrt(2 / b.dof + self.ref_v.sigma() ** 2)
            z_n = np.where(live, z_n / self.ref_v.spread(), np.nan)
        a_up, a_dn = self.ch_amp.step(z_a, i, self.ref_A.blocks())
        c_up, c_dn = self.ch_off.step(z_c, i, self.ref_C.blocks())
        n_up, _ = self.ch_noise.step(z_n, i, self.ref_v.blocks())
        amp_alarm = np.flatnonzero(a_up | a_dn)
        if amp_alarm.size:
            events += self._amplitude_alarms(b, amp_alarm)
        off_alarm = np.flatnonzero(c_up | c_dn)
        if off_alarm.size:
            events.append(self._sensor_alarm(b, off_alarm, "offset", self.ch_off, self._offset_size))
        noise_alarm = np.flatnonzero(n_up)
        if noise_alarm.size:
            events.append(self._sensor_alarm(b, noise_alarm, "noise", self.ch_noise, self._noise_size))
        self._follow_references(b, live)
        return events

    def _follow_references(self, b: BlockResult, live: np.ndarray) -> None:
        self.ref_A.offer(b.amplitude_mm, b.sigma_amplitude_mm**2, live)
        self.ref_C.offer(b.offset_mm, b.sigma_offset_mm**2, live)
        with np.errstate(invalid="ignore", divide="ignore"):
            self.ref_v.offer(np.log(b.resid_var), 2 / b.dof, live)
        dw, sdw = self.f0_history[-1]
        self.ref_w.offer(np.array([dw]), np.array([sdw**2]), np.ones(1, bool))

    # -- alarms ------------------------------------------------------------------------------

    def _since(self, start_block: int) -> list[BlockResult]:
        m = max(1, self.index - int(start_block) + 1)
        return list(self.blocks)[-m:]

    def _base(
        self, b: BlockResult, quantity: str, cls: str, series: np.ndarray, since: list[BlockResult]
    ) -> dict:
        plates = sorted({int(p) for p in self.plate_of[series]})
        axes = sorted({str(a) for a in self.axis_of[series]})
        return {
            "event": "alarm",
            "t": b.t_end,
            "class": cls,
            "quantity": quantity,
            "plates": plates,
            "axes": axes,
            "t_change": since[0].t_start,
        }

    def _f0_alarm(self, b: BlockResult, up: bool) -> dict:
        since = self._since(self.ch_f0.onset(0, up))
        m = len(since)
        hist = list(self.f0_history)[-m:]
        vals = np.array([h[0] for h in hist])
        sig = np.array([h[1] for h in hist])
        ok = np.isfinite(vals)
        dw_ref, sdw_ref = float(self.ref_w.value[0]), float(self.ref_w.sigma()[0])
        dw = float(np.mean(vals[ok]) - dw_ref)
        sdw = float(np.hypot(np.sqrt(np.mean(sig[ok] ** 2) / ok.sum()), sdw_ref))
        # per plate: the same change?
        per, sper, plates = [], [], []
        for p in self.layout.plates:
            mask = self.plate_of == p
            pv = [self._combined_domega(x, mask=mask) for x in since]
            v = np.array([q[0] for q in pv])
            s = np.array([q[1] for q in pv])
            g = np.isfinite(v)
            if g.sum() == 0:
                continue
            plates.append(p)
            per.append(np.mean(v[g]) - dw_ref)
            sper.append(np.hypot(np.sqrt(np.mean(s[g] ** 2) / g.sum()), sdw_ref))
        per, sper = np.array(per), np.array(sper)
        agree = np.abs(per - dw) <= 4 * np.hypot(sper, sdw) if len(per) else np.zeros(0, bool)
        structural = len(per) >= 2 and agree.sum() >= max(2, 0.5 * len(per))
        series = (
            np.flatnonzero(self.charted)
            if structural
            else np.flatnonzero(np.isin(self.plate_of, np.array(plates)[~agree]) & self.charted)
        )
        if series.size == 0:
            series = np.flatnonzero(self.charted)
        ev = self._base(b, "f0", "structural" if structural else "sensor", series, since)
        df = dw / (2 * np.pi)
        ev.update(
            size=df,
            sigma=sdw / (2 * np.pi),
            unit="Hz",
            relative_size=df / self.f0_hz,
            plates_agreeing=int(agree.sum()),
            plates_tested=int(len(per)),
            message=(
                f"loading frequency {'rose' if df > 0 else 'dropped'} by {abs(df):.4g} "
                f"± {sdw / (2 * np.pi):.2g} Hz "
                f"({100 * df / self.f0_hz:+.3f} %) on {int(agree.sum())} of {len(per)} plates"
                + (
                    ": a stiffness change"
                    if structural
                    else ": not the beam (plates disagree): a sensor fault"
                )
            ),
        )
        self.ref_w.restart([0], dw_ref + dw, ok.sum())
        self.ch_f0.reset(0)
        return ev

    def _rel_change(self, since: list[BlockResult], j: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        A = np.array([x.amplitude_mm[j] for x in since])
        sA = np.array([x.sigma_amplitude_mm[j] for x in since])
        g = np.isfinite(A)
        m = np.maximum(g.sum(axis=0), 1)
        mean = np.nansum(np.where(g, A, 0.0), axis=0) / m
        ref = self.ref_A.value[j]
        sig = np.sqrt(np.nansum(np.where(g, sA**2, 0.0), axis=0) / m**2 + self.ref_A.sigma()[j] ** 2)
        return mean / ref - 1, sig / ref

    def _amplitude_alarms(self, b: BlockResult, alarm: np.ndarray) -> list[dict]:
        events = []
        done: set[int] = set()
        for j in alarm:
            if j in done:
                continue
            since = self._since(self.ch_amp.onset(j, bool(self.ch_amp.hi[j] > self.ch_amp.h[j])))
            same_axis = np.flatnonzero((self.axis_of == self.axis_of[j]) & self.charted & ~self.lost)
            alarming = set(int(a) for a in alarm if self.axis_of[a] == self.axis_of[j])
            others = np.array([k for k in same_axis if k not in alarming], np.int64)
            r_j, s_j = self._rel_change(since, np.array([j]))
            corr = self._corr_phase(b, self._corr)
            structural = False
            r_o = s_o = float("nan")
            if others.size >= 2:
                r, s = self._rel_change(since, others)
                r_o, s_o = gls_mean(r, s, corr[np.ix_(others, others)])
                structural = abs(r_o) > 3 * s_o and abs(r_j[0] - r_o) < 3 * np.hypot(s_j[0], s_o)
            if structural:
                series = same_axis
                r, s = self._rel_change(since, series)
                r_all, s_all = gls_mean(r, s, corr[np.ix_(series, series)])
                ev = self._base(b, "amplitude", "structural", series, since)
                ev.update(
                    size=r_all,
                    sigma=s_all,
                    unit="relative",
                    message=(
                        f"amplitude changed by {100 * r_all:+.2f} ± {100 * s_all:.2f} % on every plate alike "
                        "(coherent along the deflection shape): a stiffness change"
                    ),
                )
                self.ref_A.restart(series, self.ref_A.value[series] * (1 + r), len(since))
                self.ch_amp.reset(series)
                done.update(int(k) for k in series)
            else:
                a_ref = self.ref_A.value[j]
                size_mm = r_j[0] * a_ref
                ev = self._base(b, "amplitude", "plate", np.array([j]), since)
                ev.update(
                    size=size_mm,
                    sigma=s_j[0] * a_ref,
                    unit="mm",
                    relative_size=r_j[0],
                    others_relative_size=r_o,
                    others_sigma=s_o,
                    message=(
                        f"{self.layout.label(j)}: amplitude changed by {size_mm:+.3f} "
                        f"± {s_j[0] * a_ref:.3f} mm "
                        f"({100 * r_j[0]:+.2f} %), the other plates by {100 * r_o:+.2f} ± {100 * s_o:.2f} %: "
                        "local to the plate (debonding, a local defect)"
                    ),
                )
                self.ref_A.restart([j], a_ref * (1 + r_j[0]), len(since))
                self.ch_amp.reset([j])
                done.add(int(j))
            events.append(ev)
        return events

    def _offset_size(self, since: list[BlockResult], j: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        C = np.array([x.offset_mm[j] for x in since])
        sC = np.array([x.sigma_offset_mm[j] for x in since])
        m = np.maximum(np.isfinite(C).sum(axis=0), 1)
        d = np.nanmean(C, axis=0) - self.ref_C.value[j]
        s = np.sqrt(np.nansum(sC**2, axis=0) / m**2 + self.ref_C.sigma()[j] ** 2)
        self.ref_C.restart(j, self.ref_C.value[j] + d, m)
        return d, s

    def _noise_size(self, since: list[BlockResult], j: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        v = np.array([x.resid_var[j] for x in since])
        dof = np.array([x.dof[j] for x in since])
        m = np.maximum(np.isfinite(v).sum(axis=0), 1)
        lv = np.nanmean(np.log(v), axis=0)
        ratio = np.exp(0.5 * (lv - self.ref_v.value[j]))
        s = ratio * 0.5 * np.sqrt(np.nanmean(2 / dof, axis=0) / m + self.ref_v.sigma()[j] ** 2)
        self.ref_v.restart(j, lv, m)
        return ratio, s

    def _sensor_alarm(self, b: BlockResult, series: np.ndarray, quantity: str, chart: _Chart, sizer) -> dict:
        since = self._since(min(chart.onset(j, bool(chart.hi[j] > chart.h[j])) for j in series))
        size, sig = sizer(since, series)
        chart.reset(series)
        ev = self._base(b, quantity, "sensor", series, since)
        n_plates = len(ev["plates"])
        camera = n_plates >= max(2, 0.5 * len(self.layout.plates))
        if quantity == "offset":
            what = "the camera or scene moved" if camera else "a jump of the plate's reading"
            unit = "mm"
        else:
            what = "the camera's noise rose" if camera else "more noise on the plate's reading"
            unit = "noise ratio"
        ev.update(
            size=[float(x) for x in size],
            sigma=[float(x) for x in sig],
            unit=unit,
            series=[self.layout.label(j) for j in series],
            message=f"{quantity} of {', '.join(self.layout.label(j) for j in series)}: {what}",
        )
        return ev

    def _lost_events(self, b: BlockResult) -> list[dict]:
        lost = b.n < self.settings.lost_fraction * max(b.frames, 1)
        if b.frames == 0:
            return []
        events = []
        new, back = lost & ~self.lost, ~lost & self.lost
        for kind, sel in (("lost", new), ("recovered", back)):
            if not sel.any():
                continue
            plates = sorted({int(p) for p in self.plate_of[sel]})
            ev = {
                "event": "alarm" if kind == "lost" else "state",
                "t": b.t_end,
                "plates": plates,
                "axes": sorted({str(a) for a in self.axis_of[sel]}),
                "t_change": b.t_start,
            }
            if kind == "lost":
                ev.update(
                    {
                        "class": "sensor",
                        "quantity": "samples",
                        "size": float(np.mean(1 - b.n[sel] / b.frames)),
                        "sigma": 0.0,
                        "unit": "fraction missing",
                        "message": f"plate(s) {', '.join(map(str, plates))} lost: samples stopped",
                    }
                )
            else:
                ev.update(
                    {"state": "plate_recovered", "message": f"plate(s) {', '.join(map(str, plates))} back"}
                )
            events.append(ev)
        self.lost = lost
        return events
