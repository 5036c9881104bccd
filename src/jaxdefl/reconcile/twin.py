"""The simulation a user would set up for a recording, at the trajectory level.

Same frame times (drop-outs included), same plates and axes, each series the loading harmonic
with the recording's own fitted offset, amplitude and phase at the recording's f0, plus noise at
the series' short-term noise level (first differences: slow structure does not inflate it),
shared by the plates of a frame as the frame simulator shares it (`SensorCalibration`).
``[[effect]]`` specs (`jaxdefl.simulate.injection`) are injected as the frame simulator injects
them: range effects through the calibrated range-to-centroid gains of each plate and axis (z
alone, gain 1, without a calibration), timing errors on the written stamps, motion effects on the
harmonic (AM, FM) and, on every series, in the way the series carries the beam's motion (extra
lines, harmonics: the series' harmonic over the largest z harmonic, signed by their phases — a
plate's x and y see the beam's motion through the camera's geometry as they see the load), other
bending modes on z in their own shape at each plate's place along the span (known from the
config's calibration only); a camera's sampling effects (a ToF camera's taps spread in time) read
each series' motion over their instants, and the measurement effects (a noise level with the
motion, a lattice) act on each series' reading and its noise, the series' own harmonic giving
the motion's angle. A plate's axes share their noise as the recording's do (their
correlation from the residuals' frame-to-frame changes: a ToF camera's range noise moves a
centroid along its line of sight). With a calibration, each series also has the extraction's outliers
at the rate and size the calibration clip shows them (`SensorCalibration.outliers`; the rate drawn
per simulation from its posterior, Gamma(k + ½) / n, so that the null band carries the clip's
uncertainty), and a structured-light camera's configured level jumps (`SensorCalibration`:
Poisson in time at the configured rate over the record, each N(0, jump_mm), the whole depth image
stepping, through each plate's and axis' range gain), drawn anew for every simulation as the
frame simulator draws them. What the twin cannot render (a mode without a calibration, one plate's clipping)
leaves its output unchanged: `reconcile` checks each effect and says so.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pandas as pd

from .._numerics import harmonic_design, wls
from ..effects import REGISTRY
from ..simulate.injection import (
    EffectSpec,
    measurement_faults,
    mode_displacement,
    motion_modulations,
    range_offset,
    sampled,
    stamp_times,
)
from ..simulate.structured_light import level_jump_path
from .metrics import short_term_noise

__all__ = ["AXES", "Twin", "line_key"]

AXES = ("z", "x", "y")


@dataclass
class _Series:
    plate: int
    axis: str
    rows: np.ndarray  # positions in the table
    t: np.ndarray  # s since the table's first stamp
    coef: np.ndarray  # offset, cos, sin at ω
    sigma: float


def line_key(spec: EffectSpec) -> tuple:
    """What tells an additive motion term apart: its id and its locator (a line's frequency, a
    harmonic's order: `jaxdefl.effects` ``Entry.locator``)."""
    locator = REGISTRY[spec.id].locator
    if locator is None:
        return (spec.id,)
    return (spec.id, round(float(spec.p(locator[0])), 9))


class Twin:
    """Fitted once from a recording; `simulate` renders it with or without effects."""

    def __init__(
        self, df: pd.DataFrame, f0_hz: float, calibration=None, axes: tuple[str, ...] = ("z", "x", "y")
    ):
        self.df = df.reset_index(drop=True)
        self.calibration = calibration
        self.frame = np.unique(self.df["t"].to_numpy(), return_inverse=True)[1]  # rows -> frame
        self.f0_hz = float(f0_hz)
        self.omega = 2 * math.pi * self.f0_hz
        self.t_first = float(self.df["t"].min())
        self.plates = sorted(int(p) for p in self.df["plate"].unique())
        self.series: list[_Series] = []
        t_all = self.df["t"].to_numpy() - self.t_first
        for plate, idx in self.df.groupby("plate", sort=True).indices.items():
            for axis in axes:
                if axis not in self.df:
                    continue
                y = self.df[axis].to_numpy()[idx]
                ok = np.isfinite(y)
                if ok.sum() < 10:
                    continue
                rows, t = idx[ok], t_all[idx][ok]
                a = harmonic_design(self.omega * t)
                coef = wls(a, y[ok], cov=False)[0]
                sigma = short_term_noise(y[ok] - a @ coef)
                self.series.append(_Series(int(plate), axis, rows, t, coef, sigma))
        self.axis_corr = self._axis_correlations(axes)
        # the beam's motion as each series carries it: its harmonic over the largest z harmonic's
        # (the mid-span's, as the simulator sizes motion effects), signed by their phases
        polar = {
            (s.plate, s.axis): (math.hypot(s.coef[1], s.coef[2]), math.atan2(s.coef[2], s.coef[1]))
            for s in self.series
        }
        zs = [k for k in polar if k[1] == "z"] or list(polar)
        top_key = max(zs, key=lambda k: polar[k][0], default=None)
        top, self.phi_ref = polar[top_key] if top_key is not None else (0.0, 0.0)
        # a line's or a harmonic's size on each axis against the axis that sizes it, where the
        # recording shows it otherwise than the transfer at f0 says (a ToF camera's range channel
        # passes a faster motion less than the image's x and y): {line_key: {axis: gain}}
        self.line_gain: dict[tuple, dict[str, float]] = {}
        self.transfer = {
            k: (a / top * math.copysign(1.0, math.cos(phi - self.phi_ref)) if top > 0 else 0.0)
            for k, (a, phi) in polar.items()
        }

    def _axis_correlations(self, axes: tuple[str, ...]) -> dict[int, np.ndarray]:
        """Per plate, the correlation of its axes' noise (axes in ``AXES`` order; identity where
        an axis is missing), from the residuals' frame-to-frame changes (blind to slow
        structure), each clipped at 6 σ (outliers): a ToF camera's range noise moves a centroid
        along its line of sight, so a plate's x, y and z noise are nearly one variable, and a
        twin with independent axes has a null band too narrow for every per-series metric."""
        out = {}
        by_plate: dict[int, dict[str, _Series]] = {}
        for s in self.series:
            by_plate.setdefault(s.plate, {})[s.axis] = s
        for plate, series in by_plate.items():
            c = np.eye(len(AXES))
            cols, keys = [], []
            rows = None
            for axis in AXES:
                if axis in series and axis in axes:
                    rows = series[axis].rows if rows is None else np.intersect1d(rows, series[axis].rows)
                    keys.append(axis)
            if rows is not None and len(keys) > 1 and rows.size > 20:
                for axis in keys:
                    ser = series[axis]
                    r = self.df[axis].to_numpy()[rows] - self._harmonic(ser, rows)
                    d = np.diff(r) / (math.sqrt(2.0) * max(ser.sigma, 1e-12))
                    cols.append(np.clip(d, -6.0, 6.0))
                m = np.corrcoef(np.stack(cols))
                if np.all(np.isfinite(m)):
                    w, v = np.linalg.eigh(m)  # nearest positive definite, unit diagonal
                    m = (v * np.maximum(w, 1e-6)) @ v.T
                    m = m / np.sqrt(np.outer(np.diag(m), np.diag(m)))
                    idx = [AXES.index(a) for a in keys]
                    c[np.ix_(idx, idx)] = m
            out[plate] = c
        return out

    def _harmonic(self, s: _Series, rows: np.ndarray) -> np.ndarray:
        """The series' offset and harmonic at table rows ``rows``."""
        t = self.df["t"].to_numpy()[rows] - self.t_first
        return harmonic_design(self.omega * t) @ s.coef

    def noise_without_lines(self, freqs_hz) -> None:
        """Each series' noise level again, from its residual about the harmonic *and* lines at
        ``freqs_hz``: the level comes from first differences, which a line well above the load's
        frequency inflates (a 5.5-Hz line at 20 Hz moves 1.5× its amplitude a frame), so a
        named line would otherwise be rendered twice, once as noise."""
        freqs = [float(f) for f in freqs_hz if f > 0]
        if not freqs:
            return
        y_all = {axis: self.df[axis].to_numpy() for axis in ("z", "x", "y") if axis in self.df}
        for s in self.series:
            w = [self.omega, *(2 * math.pi * f for f in freqs)]
            a = np.stack([np.ones_like(s.t)] + [g(x * s.t) for x in w for g in (np.cos, np.sin)], 1)
            y = y_all[s.axis][s.rows]
            s.sigma = short_term_noise(y - wls(a, y, cov=False)[2])

    def _configured_jumps(self, frame_t: np.ndarray, seed: int) -> np.ndarray | None:
        """(frame,) mm: a structured-light camera's level jumps as the frame simulator draws
        them (`simulate.structured_light.level_jump_path`), or None without configured jumps."""
        cal = self.calibration
        if cal is None or not (cal.jumps_per_minute > 0 and cal.jump_mm > 0) or not frame_t.size:
            return None
        rng = np.random.default_rng([int(seed), 9303])
        duration = float(frame_t[-1] - frame_t[0])
        return level_jump_path(rng, cal.jumps_per_minute, cal.jump_mm, frame_t, frame_t[0], duration)

    def shows(self, effect: EffectSpec, seed: int = 0) -> bool:
        """Whether ``effect`` changes the simulated table (same seed, with and without it)."""
        a, b = self.simulate((), seed), self.simulate((effect,), seed)
        cols = [c for c in ("t", "x", "y", "z") if c in a]
        x, y = a[cols].to_numpy(float), b[cols].to_numpy(float)
        same = (x == y) | (np.isnan(x) & np.isnan(y))
        return not bool(same.all())

    def simulate(self, effects: tuple[EffectSpec, ...] = (), seed: int = 0) -> pd.DataFrame:
        """A table like the recording (same rows), rendered with ``effects``."""
        out = self.df.copy()
        rng = np.random.default_rng([int(seed), 9301])
        rng_far = np.random.default_rng([int(seed), 9302])  # the outliers: apart from the noise
        gain, shift, _ = motion_modulations(effects, 0.0, self.f0_hz)
        # each additive motion term with its axes' gains (`line_gain`, set by the refit)
        extra = [
            (f, self.line_gain.get(line_key(e), {}))
            for e in effects
            for f in motion_modulations((e,), 0.0, self.f0_hz)[2]
        ]
        stamps = stamp_times(effects, self.df["t"].to_numpy(), self.t_first)
        cal = self.calibration
        n_frames = int(self.frame.max()) + 1
        # unit noise per frame and axis: each plate's own (its axes correlated as the recording's
        # are), and the part every plate of a frame shares (the plates' mean correlation)
        mean_corr = np.mean(list(self.axis_corr.values()), axis=0) if self.axis_corr else np.eye(3)
        common = rng.standard_normal((n_frames, len(AXES))) @ np.linalg.cholesky(mean_corr).T
        own = {
            p: rng.standard_normal((n_frames, len(AXES))) @ np.linalg.cholesky(c).T
            for p, c in self.axis_corr.items()
        }
        off = None
        frame_t = np.unique(self.df["t"].to_numpy()) - self.t_first
        if any(e.level == "range" for e in effects):  # once per frame, indexed per series below
            off = range_offset(effects, frame_t, 0.0, max(self.plates), seed)
        jumps = self._configured_jumps(frame_t, seed)
        if jumps is not None:  # the whole depth image steps: every plate's range, column 0 off
            off = (off if off is not None else 0.0) + jumps[:, None] * np.ones(max(self.plates) + 1)
        measuring = any(e.level == "measurement" for e in effects)
        for s in self.series:
            t = s.t
            c, a, b = s.coef
            amp, phi = math.hypot(a, b), math.atan2(b, a)  # a cos + b sin = amp cos(ωt − φ)
            k = self.transfer.get((s.plate, s.axis), 0.0)
            xi = cal.plate_xi.get(s.plate) if cal is not None and s.axis == "z" else None

            def motion(tt, c=c, amp=amp, phi=phi, k=k, xi=xi, axis=s.axis):
                theta = self.omega * tt - phi
                g = gain(tt) if gain is not None else 1.0
                dphi = shift(tt) if shift is not None else 0.0
                y = c + amp * g * np.cos(theta + dphi)
                for f, by_axis in extra:  # the simulator's phase θ is the twin's + π/2 (sin against cos)
                    y = y + k * by_axis.get(axis, 1.0) * f(tt, self.omega * tt - self.phi_ref + math.pi / 2)
                modal = mode_displacement(effects, tt, np.array([xi])) if xi is not None else None
                if modal is not None:  # another bending mode, in its own shape at the plate
                    y = y + modal[:, 0]
                return y

            y = sampled(effects, t, 0.0, motion)  # a camera's taps spread in time
            if off is not None:
                g_range = cal.gain_of(s.plate, s.axis) if cal is not None else float(s.axis == "z")
                y = y + g_range * off[self.frame[s.rows], s.plate]
            rho = cal.frame_common.get(s.axis, 0.0) if cal is not None else 0.0
            j, frames = AXES.index(s.axis), self.frame[s.rows]
            eps = math.sqrt(1 - rho) * own[s.plate][frames, j] + math.sqrt(rho) * common[frames, j]
            far = cal.outliers.get((s.plate, s.axis)) if cal is not None else None
            if far is not None and far[1]:  # the extraction's outliers, as the clip has them
                n_clip, sizes = far
                rate = rng_far.gamma(len(sizes) + 0.5) / n_clip
                hit = rng_far.random(t.size) < rate
                eps[hit] = rng_far.choice(np.asarray(sizes), int(hit.sum()))
            noise = s.sigma * eps
            if measuring:  # the reading's noise and lattice, on the series' own axis
                ax = "xyz".index(s.axis)
                xyz, nz = np.zeros((t.size, 1, 3)), np.zeros((t.size, 1, 3))
                xyz[:, 0, ax], nz[:, 0, ax] = y, noise
                arg = (self.omega * t - phi)[:, None]  # 0 at the peak of the series' harmonic
                measurement_faults(effects, t, xyz, nz, plates=[s.plate], sigma=s.sigma, arg=arg, seed=seed)
                y, noise = xyz[:, 0, ax], nz[:, 0, ax]
            y = y + noise
            out.loc[s.rows, s.axis] = y
        out["t"] = stamps
        return out
