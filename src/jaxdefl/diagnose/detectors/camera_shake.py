"""``camera_shake``: the camera moves, so every plate (and the static scene) moves with it.

Physics: the camera stands on a tripod or a bracket near a hydraulic rig; the floor carries the
actuator's reaction, people walk by, the bracket creeps as it warms. A camera that moves by d(t)
along an axis of its own frame shifts every point it sees by −d(t) on that axis: all plates
alike, whatever their motion, and the floor targets and the beam top too (the simulator injects
it there: `jaxdefl.simulate.injection`, ``camera_shake``). On the trajectories it is a common
ADDITIVE series, the same displacement added to every plate's position on an axis — not a gain
on the loading motion (`amplitude_modulation`), not a shift of its phase (`timing_error`,
`frequency_modulation`: those are proportional to the motion's velocity, so they vanish where
the plates' amplitude does and change sign with the motion), and not a line per plate in the
beam's shape (`extra_periodic`).

Signature test: per axis, the residuals (after each series' free nuisance) are averaged across
the series on the frame clock (weights 1/σ̂_s²), and the per-frame mean ū(t) is regressed on a
cubic B-spline basis in time (its constant direction left out: the offsets hold it), the knot
spacing on a grid from half the record down to four loading periods (2 to 128 intervals). At
each spacing the statistic is the explained weighted sum of squares of ū over the *long-run*
variance of ū's remainder (its variance × (1 + ρ)/(1 − ρ), ρ its lag-one autocorrelation on
the frame clock): χ²_K under noise, white or AR(1)-like, independent across plates or shared by
them within a frame (frame-common noise is in ū's own variance). The spacing with the largest
statistic − K log N is kept; its p-value is Bonferroni over the spacings and the axes.

Model term: y_s += u(t) on every series s of the axis, u = B(t) c the common spline, shared
coefficients (K parameters, counted once; none per series), each series' free nuisance refitted.
The series whose likelihood does not rise are left out (`screening.shared_amplitude`). A shake
goes and comes back: a common motion that only goes one way (monotone, or one step: `one_way`) is
what a camera warm-up or a range offset leaves on the trajectories, and the same data cannot tell
a creeping bracket from them, so the shake leaves it to `drift` and `level_jump` (and, with those
out of the vocabulary, to an unnamed common trend).

Reported: ``rms_mm`` (RMS of u over the record), ``corner_hz`` (the frequency below which half
of u's power lies: a first-order low-pass motion's corner), ``knot_spacing_s`` and, in the
detail, u on a coarse grid. Plausible magnitudes: 0.05-1 mm of slow sway or creep of a tripod;
more on a bracket on the rig's frame.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.interpolate import BSpline

from ...effects.camera_shake import ENTRY
from .._base import Context, Detector, Proposal, State
from .screening import bonferroni, chi2_sf, open_series, param, project_out, shared_amplitude, weights

__all__ = ["CameraShake", "EFFECT", "spline_basis"]

GRID = (2, 3, 4, 6, 8, 12, 16, 24, 32, 48, 64, 96, 128)  # knot intervals over the record
ONE_WAY = 0.9  # a single step explaining this share: a jump, not a shake (`one_way`)
MONOTONE = 0.98  # steps adding up to this share of their absolute sum: a drift
MIN_PERIODS = 4.0  # the shortest knot spacing, in loading periods (the spline stays below f0)


def spline_basis(t: np.ndarray, duration: float, intervals: int) -> np.ndarray:
    """(sample, intervals + 3) cubic B-splines with equally spaced knots over [0, duration], as a
    sparse matrix (four nonzeros a row)."""
    inner = np.linspace(0.0, duration, intervals + 1)
    knots = np.concatenate([[0.0] * 3, inner, [duration] * 3])
    return BSpline.design_matrix(np.clip(t, 0.0, duration), knots, 3).tocsr()


def _long_run(e: np.ndarray, ok: np.ndarray) -> float:
    """(1 + ρ)/(1 − ρ) of a frame series ``e`` (``ok``: frames present), ρ in [0, 0.95]."""
    a, b = e[:-1], e[1:]
    both = ok[:-1] & ok[1:]
    if both.sum() < 32:
        return 1.0
    rho = float(np.sum(a[both] * b[both]) / math.sqrt(np.sum(a[both] ** 2) * np.sum(b[both] ** 2) or 1e-300))
    rho = min(max(rho, 0.0), 0.95)
    return (1.0 + rho) / (1.0 - rho)


class CameraShake(Detector):
    id = ENTRY.id
    sensors, structural, needs_reference = ENTRY.sensors, ENTRY.structural, ENTRY.needs_reference
    meaning = "the camera moves: a displacement common to every plate (and the static scene) on an axis"
    plausible, plausible_unit, gate_params = 0.1, "noise", 8
    min_plates = 2

    def propose(self, ctx: Context, states: list[State]) -> list[Proposal]:
        if self.cannot_tell(ctx) is not None:
            return []
        idx = open_series(ctx, states, self.id)
        axes = sorted({ctx.series[i].axis for i in idx})
        out = []
        for ax in axes:
            on = [i for i in idx if ctx.series[i].axis == ax]
            if len({ctx.series[i].plate for i in on}) >= self.min_plates:
                prop = self._axis(ctx, states, on, len(axes))
                if prop is not None:
                    out.append(prop)
        return out

    def _axis(self, ctx: Context, states: list[State], idx: list[int], n_axes: int) -> Proposal | None:
        nf = ctx.n_frames
        num = np.zeros(nf)
        den = np.zeros(nf)
        nus = {}
        for i in idx:
            s, st = ctx.series[i], states[i]
            w = weights(st)
            nus[i] = ctx.nuisance(i)
            r0 = project_out(nus[i], w, (s.y - st.mean)[:, None])[:, 0]
            s2 = float(np.sum(w * r0 * r0)) / max(int((w > 0).sum()) - nus[i].shape[1], 1) or 1e-300
            num += np.bincount(s.k, weights=w * r0 / s2, minlength=nf)[:nf]
            den += np.bincount(s.k, weights=w / s2, minlength=nf)[:nf]
        ok = den > 0
        if ok.sum() < 64:
            return None
        u = np.where(ok, num / np.where(ok, den, 1.0), 0.0)
        t = np.arange(nf) * ctx.dt_s
        dur = max(float(ctx.duration_s), ctx.dt_s)
        shortest = max(MIN_PERIODS / max(ctx.f0_hz, 1e-9), 8 * ctx.dt_s)
        top = int(min(dur / shortest, ok.sum() / 16))
        grid = [k for k in GRID if k <= top]
        if not grid:
            return None
        n_total = sum(s.n for s in ctx.series)
        wk = den[ok]
        uc = u[ok] - np.average(u[ok], weights=wk)
        fits = {}
        for k in grid:
            # B-splines sum to one: the fit about the weighted mean has k + 2 free directions
            b = spline_basis(t[ok], dur, k)
            g = (b.T @ b.multiply(wk[:, None])).toarray()
            coef = np.linalg.solve(g + 1e-10 * np.trace(g) / g.shape[0] * np.eye(g.shape[0]), b.T @ (wk * uc))
            fits[k] = (b @ coef, k + 2)
        # the noise of ū: its remainder after the finest spline, with its long-run variance
        fine, _ = fits[grid[-1]]
        e = np.zeros(nf)
        e[ok] = uc - fine
        var = float(np.sum(wk * e[ok] ** 2)) / max(int(ok.sum()) - fits[grid[-1]][1] - 1, 1)
        var *= _long_run(np.where(ok, e * np.sqrt(np.where(ok, den, 0.0)), 0.0), ok)
        best = None
        for k in grid:
            fit, n_par = fits[k]
            stat = float(np.sum(wk * fit * (2 * uc - fit))) / max(var, 1e-300)
            crit = stat - n_par * math.log(n_total)
            if best is None or crit > best[0]:
                best = (crit, k, stat, n_par, fit)
        crit, k, stat, n_par, fit = best
        if crit <= 0 or one_way(fit, wk):
            return None
        p_value = bonferroni(float(chi2_sf(stat, n_par)), len(grid) * n_axes)
        shape = np.zeros(nf)
        shape[ok] = fit
        # gaps: the spline between the frames present (its value on every frame of the clock)
        if not ok.all():
            shape = np.interp(t, t[ok], fit)
        sh = shared_amplitude(ctx, states, idx, lambda i: shape[ctx.series[i].k][:, None], nus, self.id)
        if sh is None or float(sh.beta[0]) <= 0:
            return None
        motion = float(sh.beta[0]) * shape
        rms = float(np.sqrt(np.mean(motion[ok] ** 2)))
        corner = _median_power_frequency(motion[ok], ctx.dt_s)
        first = sh.series[0]
        sh.states[first] = sh.states[first].with_(n_params=sh.states[first].n_params + n_par)
        step = max(1, nf // 200)
        where = ", ".join(ctx.series[i].key for i in sh.series)
        return Proposal(
            effect=self.id,
            series=sh.series,
            states=sh.states,
            n_params=n_par,
            p_value=p_value,
            trials=len(grid) * n_axes,  # knot spacings × axes
            parameters={
                "rms_mm": param(rms, rms / math.sqrt(max(stat, 1.0))),
                "corner_hz": param(corner),
                "knot_spacing_s": param(dur / k),
                "axis": param(ctx.series[idx[0]].axis),
            },
            t_start=0.0,
            t_end=float(ctx.duration_s),
            band_hz=[0.0, float(k / (2 * dur))],
            explanation=(
                f"All of {where} move together by the same {rms:.3f} mm RMS, slowly (half of the "
                f"motion's power below {corner:.3g} Hz), whatever their own deflection: the camera "
                "moves (its tripod or bracket sways or creeps), not the beam."
            ),
            detail={"t_s": (t[::step]).tolist(), "displacement_mm": motion[::step].tolist()},
        )


def one_way(u: np.ndarray, w: np.ndarray) -> bool:
    """Whether the common motion ``u`` (weighted mean removed) only goes one way: monotone (its
    steps add up to at least `MONOTONE` of their absolute sum) or a single step (two levels explain
    `ONE_WAY` of its weighted variance). On the trajectories such a motion is a camera warm-up or a
    range offset (`drift`, `level_jump`), which the shake leaves to them."""
    if u.size < 4:
        return False
    d = np.diff(u)
    if abs(float(d.sum())) >= MONOTONE * float(np.abs(d).sum()):
        return True
    ss = float(np.sum(w * u * u))
    cw, cu = np.cumsum(w)[:-1], np.cumsum(w * u)[:-1]
    n = float(w.sum())
    between = cu**2 / np.maximum(cw, 1e-300) + cu**2 / np.maximum(n - cw, 1e-300)  # mean 0: S1² (1/n1 + 1/n2)
    return ss > 0 and float(between.max()) >= ONE_WAY * ss


def _median_power_frequency(x: np.ndarray, dt: float) -> float:
    """The frequency below which half of the power of ``x`` lies (its mean removed)."""
    x = x - x.mean()
    if x.size < 8:
        return float("nan")
    p = np.abs(np.fft.rfft(x))[1:] ** 2
    f = np.arange(1, p.size + 1) / (x.size * dt)
    c = np.cumsum(p)
    if c[-1] <= 0:
        return float("nan")
    return float(f[int(np.searchsorted(c, 0.5 * c[-1]))])


EFFECT = CameraShake()
