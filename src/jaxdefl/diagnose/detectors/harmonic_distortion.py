"""Harmonic distortion: components at k·f0 (k = 2..5) on top of the loading harmonic.

Physical meaning: the recorded motion of a plate is periodic at the loading frequency but not a
pure sine. On a beam test this comes from the structure (support contact that opens and closes,
a non-linear stiffness near cracking), from a ToF camera's cyclic range error (the range error is
a periodic function of the range, so a moving plate picks it up at the harmonics of its motion),
or from mixed pixels at the plate's edges whose share changes with the plate's position.

Signature test: per plate and axis, the residual is regressed on cos/sin(k ω (t − t_ref)),
k = 2..5, with the nominal harmonic's ω and the free nuisance (offset; C and D on untied series);
each order's Wald statistic is χ²_2 under the nominal model. A (series, order) pair is kept when
its own evidence pays for its two amplitudes (BIC); the p-value is the largest pair's statistic
Bonferroni-corrected over series × orders, or the strongest order summed over all series
(χ²_2S) corrected over the orders, whichever is smaller (doubled).

Common mode: the same test with one amplitude and phase shared by all the series of an axis
(columns at the record's f0 and mid time; χ²_2 per order, Bonferroni over orders × axes): a
cyclic range error or a structural harmonic that every plate sees alike, too weak on each plate
alone. Both proposals go to the search; BIC decides.

Model term: y += Σ_k a_k cos(k ω (t − t_ref) − ψ_k) on the kept series and orders, two linear
parameters (a_k cos ψ_k, a_k sin ψ_k) each; in common mode two per order in all.

Plausible magnitudes: a few per cent of the motion amplitude (0.01–0.2 mm for a 4-mm motion) for
support contact; cyclic ToF range errors of 1–10 mm peak over a wavelength of c/(8 f_mod) (about
1.3 m at 29 MHz) give far less on a few-mm motion; mixed pixels up to 0.1–0.5 mm on small plates.
The information gate takes 0.1 mm (`plausible`): an absolute size, since mixed pixels do not scale
with the motion (1 % of a 1-mm motion gated a 0.24-mm distortion out of a 4-minute record).

Acceptance (`_search.Calibration`): the common mode's statistic against χ²_2 per order kept,
the look-elsewhere over orders × axes; the per-series mode's also over the series picked.
"""

from __future__ import annotations

import math

import numpy as np

from ..._numerics import P_MAX, wls
from ...effects.harmonic_distortion import ENTRY
from .._base import Context, Detector, Proposal, State, keep_series, masked_periodogram
from .screening import (
    bonferroni,
    chi2_sf,
    combined_p,
    gain,
    param,
    residual,
    shared_amplitude,
    subset_trials,
    updated,
    weights,
)

__all__ = ["HarmonicDistortion", "EFFECT"]

ORDERS = (2, 3, 4, 5)
MIN_LEVEL_BINS = 4  # bins about k·f0 the local noise level needs; fewer: the white level


def _local_levels(ctx: Context, i: int, r: np.ndarray) -> np.ndarray:
    """(orders,) the residual's noise power about each k·f0 relative to its mean (white: 1;
    at least 1): the median periodogram power between 1.5/duration and f0/2 from k·f0, over
    ln 2 (the median of Exp(1)). Coloured noise (AR(1) from frame to frame) has several times
    its mean power at a few Hz; the Wald statistics are divided by it so that it is not read as
    distortion (a short record at ρ = 0.8 named it in 2 of 15 controls)."""
    freq, power = masked_periodogram(ctx, i, r)
    out = np.ones(len(ORDERS))
    lo = 1.5 / max(ctx.duration_s, 1e-9)
    for j, k in enumerate(ORDERS):
        d = np.abs(freq - k * ctx.f0_hz)
        near = (d > lo) & (d < 0.5 * ctx.f0_hz)
        if int(near.sum()) >= MIN_LEVEL_BINS:
            out[j] = max(float(np.median(power[near])) / math.log(2.0), 1.0)
    return out


SCREEN_MARGIN = 8.0  # exact fits for series whose screen comes within this of the BIC bar


def _columns(ctx: Context, i: int, omega: float | None = None, t_ref: float | None = None) -> np.ndarray:
    """(sample, 2 × orders) cos, sin of k ω (t − t_ref) for k in ORDERS (angle-addition recurrence);
    ω and t_ref of the series' nominal harmonic unless given."""
    h = ctx.nominal[i]
    omega = h.omega if omega is None else omega
    t_ref = h.t_ref if t_ref is None else t_ref
    a = omega * (ctx.series[i].t - t_ref)
    c1, s1 = np.cos(a), np.sin(a)
    c, s = c1 * c1 - s1 * s1, 2 * s1 * c1
    cols = np.empty((a.size, 2 * len(ORDERS)))
    for j in range(len(ORDERS)):
        cols[:, 2 * j], cols[:, 2 * j + 1] = c, s
        c, s = c * c1 - s * s1, s * c1 + c * s1
    return cols


class HarmonicDistortion(Detector):
    id = ENTRY.id
    sensors, structural, needs_reference = ENTRY.sensors, ENTRY.structural, ENTRY.needs_reference
    meaning = "motion not purely sinusoidal: components at 2-5 x f0 (support contact, cyclic range error)"
    plausible, plausible_unit, gate_params = 0.1, "mm", 2  # a 0.1-mm 2nd harmonic (mixed pixels)
    min_plates = 1

    def propose(self, ctx: Context, states: list[State]) -> list[Proposal]:
        n_ord = len(ORDERS)
        wald = np.zeros((len(ctx.series), n_ord))
        fits = {}
        # common mode: the record's f0 and mid time, so that the columns are one for all series
        om0, tr0 = 2 * math.pi * ctx.f0_hz, 0.5 * ctx.duration_s
        common_b = np.zeros((len(ctx.series), 2 * n_ord))
        common_m = np.zeros((len(ctx.series), n_ord))
        levels = np.ones((len(ctx.series), n_ord))
        for i, st in enumerate(states):
            s = ctx.series[i]
            if s.n < 8 * (2 * n_ord + 3):
                continue
            # screen: the orders are nearly orthogonal to each other and to the nuisance over
            # many cycles, so |Σ w r e^{ikθ}|² stands for the regression (exact fits below)
            w = weights(st)
            r = residual(ctx, i, st)
            sw = float(w.sum())
            # sums, not 1-D BLAS dots: threaded ddot thrashes on busy cores
            r0 = r - float(np.sum(w * r)) / sw
            s2 = float(np.sum(w * r0 * r0)) / sw or 1e-300
            cols = _columns(ctx, i)
            z = (w * r0) @ cols
            lev = levels[i] = _local_levels(ctx, i, r0)
            wald[i] = 2.0 * (z[0::2] ** 2 + z[1::2] ** 2) / (s2 * sw) / lev
            common_b[i] = ((w * r0) @ _columns(ctx, i, om0, tr0)) / s2 / np.repeat(lev, 2)
            common_m[i] = 0.5 * sw / s2 / lev
            if wald[i].max() < 2.0 * math.log(s.n) - SCREEN_MARGIN:
                continue
            nu = ctx.nuisance(i)
            beta, cov, _ = wls(np.concatenate([cols, nu], axis=1), r, w)
            for j in range(n_ord):
                b = beta[2 * j : 2 * j + 2]
                c = cov[2 * j : 2 * j + 2, 2 * j : 2 * j + 2]
                try:
                    wald[i, j] = float(b @ np.linalg.solve(c, b)) / lev[j]
                except np.linalg.LinAlgError:
                    wald[i, j] = 0.0
            fits[i] = (cols, beta, cov)
        out = []
        for axis in ("z", "x", "y"):
            prop = self._common(ctx, states, ctx.indices(axis), common_b, common_m, levels, om0, tr0)
            if prop is not None:
                out.append(prop)
        prop = self._per_series(ctx, states, wald, fits, levels)
        if prop is not None:
            out.append(prop)
        return out

    def _per_series(self, ctx, states, wald, fits, levels) -> Proposal | None:
        n_ord = len(ORDERS)
        if not fits:
            return None
        n_screened = int(np.count_nonzero(wald.any(axis=1)))
        # a pair stays when its own evidence pays for its two amplitudes
        logn = np.array([math.log(max(ctx.series[i].n, 2)) for i in range(len(ctx.series))])
        keep_pair = wald > 2.0 * logn[:, None]
        new_states: dict[int, State] = {}
        kept_orders: dict[int, list[int]] = {}
        amps: dict[int, dict[int, tuple[float, float]]] = {}
        for i in np.flatnonzero(keep_pair.any(axis=1)):
            i = int(i)
            st = states[i]
            js = [j for j in range(n_ord) if keep_pair[i, j]]
            cols = fits[i][0][:, [c for j in js for c in (2 * j, 2 * j + 1)]]
            nu = ctx.nuisance(i)
            beta, cov, fitted = wls(np.concatenate([cols, nu], axis=1), residual(ctx, i, st), weights(st))
            k_own = 2 * len(js)
            new = updated(st, self.id, k_own, mean=st.mean + fitted)
            if not keep_series(gain(ctx, i, st, new) / float(levels[i, js].max()), k_own, ctx.series[i].n):
                continue
            new_states[i] = new
            kept_orders[i] = [ORDERS[j] for j in js]
            amps[i] = {}
            for m, j in enumerate(js):
                b = beta[2 * m : 2 * m + 2]
                a = float(np.hypot(*b))
                g = b / a if a > 0 else np.array([1.0, 0.0])
                sa = math.sqrt(max(float(g @ cov[2 * m : 2 * m + 2, 2 * m : 2 * m + 2] @ g), 0.0))
                amps[i][ORDERS[j]] = (a, sa)
        if not new_states:
            return None
        series = sorted(new_states)
        # the strongest order: the largest summed statistic over the series that keep it
        score = {k: sum(wald[i, ORDERS.index(k)] for i in series if k in kept_orders[i]) for k in ORDERS}
        order = max(score, key=score.get)
        a_of = np.array([amps[i][order][0] for i in series if order in amps[i]])
        s_of = np.array([amps[i][order][1] for i in series if order in amps[i]])
        amp = float(np.median(a_of))
        amp_sigma = 1.2533 * math.sqrt(float(np.mean(s_of**2)) / a_of.size)
        p = combined_p(
            wald.ravel(),
            2,
            1.0,
            total=float(wald[:, ORDERS.index(order)].sum()),
            dof_total=2 * n_screened,
            n_scan_total=n_ord,
        )
        all_orders = sorted({k for i in series for k in kept_orders[i]})
        n_params = sum(2 * len(kept_orders[i]) for i in series)
        f0 = ctx.f0_hz
        where = ", ".join(f"{ctx.series[i].plate}{ctx.series[i].axis}" for i in series)
        explanation = (
            f"The motion of {where} is not a pure sine: it carries a component at {order}×f0 "
            f"({order * f0:.2f} Hz) of {amp:.3f} mm"
            + (f" (orders {', '.join(map(str, all_orders))} in all)" if len(all_orders) > 1 else "")
            + ". Support contact, a cyclic range error of the camera or mixed pixels at the plate "
            "edges distort the recorded waveform."
        )
        return Proposal(
            effect=self.id,
            series=series,
            states=new_states,
            n_params=n_params,
            p_value=p,
            parameters={"order": param(order, None), "amplitude_mm": param(amp, amp_sigma)},
            t_start=0.0,
            t_end=float(ctx.duration_s),
            band_hz=[all_orders[0] * f0, all_orders[-1] * f0],
            explanation=explanation,
            trials=n_ord * subset_trials(len(series), n_screened),  # orders × series picked
            inflation=float(max(levels[i, ORDERS.index(k)] for i in series for k in kept_orders[i])),
            detail={
                "mode": "per_series",
                "orders": {ctx.series[i].key: kept_orders[i] for i in series},
                "amplitudes_mm": {
                    ctx.series[i].key: {str(k): amps[i][k][0] for k in kept_orders[i]} for i in series
                },
                "p_single_order": float(chi2_sf(wald.max(), 2)),
            },
        )

    def _common(self, ctx, states, idx, common_b, common_m, levels, om0, tr0) -> Proposal | None:
        """One distortion (same amplitude and phase in the record's time) on the series of an axis:
        a cyclic range error of the camera or a structural harmonic seen by every plate."""
        idx = [i for i in idx if common_m[i, 0] > 0]
        if len(idx) < 2:
            return None
        n_ord = len(ORDERS)
        b = common_b[idx].sum(axis=0)
        m = common_m[idx].sum(axis=0)
        stat = (b[0::2] ** 2 + b[1::2] ** 2) / m  # χ²_2 per order
        p_order = np.array([bonferroni(float(chi2_sf(x, 2)), 3 * n_ord) for x in stat])  # orders × axes
        orders = [ORDERS[j] for j in range(n_ord) if p_order[j] < P_MAX]
        if not orders:
            return None
        p = float(p_order.min())
        js = [ORDERS.index(k) for k in orders]
        pick = [c for j in js for c in (2 * j, 2 * j + 1)]
        fit = shared_amplitude(ctx, states, idx, lambda i: _columns(ctx, i, om0, tr0)[:, pick], None, self.id)
        if fit is None:
            return None
        order = ORDERS[int(np.argmax(stat))]
        jj = orders.index(order)
        bb = fit.beta[2 * jj : 2 * jj + 2]
        amp = float(np.hypot(*bb))
        g = bb / max(amp, 1e-300)
        amp_sigma = math.sqrt(max(float(g @ fit.cov[2 * jj : 2 * jj + 2, 2 * jj : 2 * jj + 2] @ g), 0.0))
        psi = float(math.atan2(bb[1], bb[0]))
        f0 = ctx.f0_hz
        where = ", ".join(ctx.series[i].key for i in fit.series)
        return Proposal(
            effect=self.id,
            series=fit.series,
            states=fit.states,
            n_params=2 * len(orders),
            p_value=p,
            parameters={
                "order": param(order, None),
                "amplitude_mm": param(amp, amp_sigma),
                "phase_rad": param(psi, amp_sigma / max(amp, 1e-300)),
            },
            t_start=0.0,
            t_end=float(ctx.duration_s),
            band_hz=[orders[0] * f0, orders[-1] * f0],
            explanation=(
                f"Every plate of {where} carries the same component at {order}×f0 "
                f"({order * f0:.2f} Hz) of {amp:.3f} mm: a distortion common to the plates, such as "
                "the camera's cyclic range error or a structural harmonic of the loading."
            ),
            detail={"mode": "common", "orders": orders, "t_ref_s": tr0},
            trials=3 * n_ord,  # orders × axes
            inflation=float(np.max(levels[np.ix_(idx, js)])),
        )


EFFECT = HarmonicDistortion()
