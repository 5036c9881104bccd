"""Drift: a slow change of the measured position, mostly the camera's warm-up.

Physical meaning: a ToF camera's range offset changes while its sensor and illumination warm up
(an exponential approach to equilibrium with a time constant of minutes; SR4000: a few mm over
the first 10-40 min), a structured-light camera's projector-sensor geometry creeps as the housing
warms, and a slow settling of the camera mount or the beam's supports adds to it.

Signature test: per plate and axis, the residual is regressed on exp(−t/τ) (t since the record's
first timestamp) with the free nuisance (offset; C and D on untied series), over a log grid of τ
from a few loading cycles to twice the record; each series' statistic is χ²_1 at a fixed τ. The
p-value is the largest single-series statistic Bonferroni-corrected over series × grid, or the
statistic summed over all series (χ²_S) corrected over the grid, whichever is smaller (doubled).
Common mode: a camera's warm-up shifts the range of the whole image alike, so the same grid also
scores one amplitude shared by the series of an axis ((Σ β·info)²/Σ info at each τ, χ²_1,
Bonferroni over the grid and the axes): the form under the noise, where no series pays for an
amplitude of its own. The polynomial alternative (Legendre polynomials of degree 1..3 in the
centred time, the degree chosen by BIC over the series) is proposed beside them; BIC decides
between them and a level jump on the same data (a common warm-up and a common jump both cost 2
parameters: the better fit wins, and a smooth approach fits an exponential better than a step).
Every statistic uses the series' long-run variance (`screening.long_run_factor`): noise
correlated from frame to frame has its power where a drift lives.

Model term: y += a_s exp(−t/τ), τ shared by the series it touches (refined by variable
projection on log τ, optimistix Levenberg-Marquardt), a_s per series (signed): 1 + S parameters;
common mode y += a exp(−t/τ) on every series of the axis, τ refined on a fine grid: 2 parameters.
Polynomial: y += Σ_d c_sd P_d(u), u = (t − t_mid)/(duration/2): degree × S parameters.

Plausible magnitudes: 0.1-5 mm over τ = 1-30 min for ToF warm-up (more when the camera starts
cold), well below 1 mm once warm; structured light 0.5-3 mm.
"""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np

from ..._numerics import P_MAX, wls
from ...effects.drift import ENTRY
from .._base import Context, Detector, Proposal, State, keep_series, peak_offset
from .._varpro import fit_shared
from .screening import (
    bonferroni,
    chi2_sf,
    combined_p,
    gain,
    long_run_factor,
    median_signed,
    open_series,
    param,
    residual,
    screen_grid,
    shared_amplitude,
    subset_trials,
    updated,
    weights,
)

__all__ = ["Drift", "EFFECT"]

N_GRID = 24
MAX_DEGREE = 3
MODES = 3  # per-series and common exponentials, polynomial: the look-elsewhere of the shapes


def _columns(theta, t, aux):
    return jnp.exp(-t * jnp.exp(-theta[0]))[:, None]


def _pad3(nu: np.ndarray) -> np.ndarray:
    """The free nuisance padded with zero columns to three (variable projection wants one q)."""
    if nu.shape[1] < 3:
        nu = np.concatenate([nu, np.zeros((nu.shape[0], 3 - nu.shape[1]))], axis=1)
    return nu


def _legendre(u: np.ndarray, degree: int) -> np.ndarray:
    cols = [u]
    if degree >= 2:
        cols.append(0.5 * (3 * u * u - 1))
    if degree >= 3:
        cols.append(0.5 * (5 * u**3 - 3 * u))
    return np.stack(cols, axis=1)


class Drift(Detector):
    id = ENTRY.id
    sensors, structural, needs_reference = ENTRY.sensors, ENTRY.structural, ENTRY.needs_reference
    meaning = "slow drift of the measured position (camera warm-up, settling): exponential or polynomial"
    plausible, plausible_unit, gate_params = 1.0 / 600, "mm_per_s", 2  # 1 mm in 10 minutes (warm-up)

    def propose(self, ctx: Context, states: list[State]) -> list[Proposal]:
        idx = open_series(ctx, states, self.id)
        if not idx:
            return []
        nus = {i: ctx.nuisance(i) for i in idx}
        exp_prop, common = self._exponential(ctx, states, idx, nus)
        kinds = (exp_prop, *common, self._polynomial(ctx, states, idx, nus))
        return [p for p in kinds if p is not None]

    # -- exponential -------------------------------------------------------------------------
    def _exponential(self, ctx: Context, states: list[State], idx: list[int], nus: dict):
        """(per-series proposal or None, [common-mode proposals, one per axis])."""
        dur = float(ctx.duration_s)
        tau_lo = max(5.0 / max(ctx.f0_hz, 1e-9), 10 * ctx.dt_s, 0.01 * dur)
        grid = np.geomspace(tau_lo, 2.0 * dur, N_GRID)
        # the columns on the frame clock once (exp is the cost), screened for all series by GEMMs
        e_grid = np.exp(-(np.arange(ctx.n_frames) * ctx.dt_s)[:, None] / grid[None, :])
        stat, beta, info = screen_grid(ctx, states, idx, nus, e_grid)
        axes = sorted({ctx.series[i].axis for i in idx})
        common = []
        for ax in axes:
            rows = [j for j, i in enumerate(idx) if ctx.series[i].axis == ax]
            on_axis = [idx[j] for j in rows]
            prop = self._common(ctx, states, on_axis, nus, grid, beta[rows], info[rows], len(axes))
            if prop is not None:
                common.append(prop)
        logn = np.array([math.log(ctx.series[i].n) for i in idx])
        crit = np.maximum(stat - logn[:, None], 0.0).sum(axis=0)
        g = int(np.argmax(crit))
        if crit[g] <= 0:
            return None, common
        p_value = combined_p(
            stat.ravel(),
            1,
            N_GRID,
            total=float(stat.sum(axis=0).max()),
            dof_total=len(idx),
            n_scan_total=N_GRID,
        )
        log_tau = math.log(grid[g])
        if 0 < g < N_GRID - 1:
            log_tau += peak_offset(*(math.exp(v / max(crit[g], 1.0)) for v in crit[g - 1 : g + 2])) * (
                math.log(grid[1] / grid[0])
            )
        sel = [i for j, i in enumerate(idx) if stat[j, g] > logn[j]]
        prop = self._linear(ctx, states, sel, nus, math.exp(log_tau), None, p_value, len(idx))
        if prop is None:
            return None, common
        prop.refine = lambda: self._refined(ctx, states, prop, nus, p_value, len(idx))
        return prop, common

    def _common(self, ctx, states, idx, nus, grid, beta, info, n_axes) -> Proposal | None:
        """One warm-up of the same size on every series of an axis (the camera's range offset
        drifts for the whole image): τ and one amplitude, 2 parameters. Against per-series
        amplitudes (1 + S parameters) it is what a camera warm-up under the noise looks like,
        and against a common level jump (also 2 parameters) BIC compares the two shapes on the
        same data: a smooth approach is not a step.

        Signature: the shared coefficient's χ²_1 statistic (Σ β info)² / Σ info at each τ of the
        grid, Bonferroni over the grid and the axes; τ refined (``refine``) on a finer grid about
        the peak."""
        if len(idx) < 2:
            return None
        c = (beta * info).sum(axis=0) ** 2 / np.maximum(info.sum(axis=0), 1e-300)
        g = int(np.argmax(c))
        p_value = bonferroni(float(chi2_sf(c[g], 1)), N_GRID * n_axes)
        if p_value >= P_MAX:
            return None
        prop = self._common_at(ctx, states, idx, nus, float(grid[g]), None, p_value)
        if prop is not None:
            lo, hi = math.log(grid[max(g - 1, 0)]), math.log(grid[min(g + 1, grid.size - 1)])
            prop.refine = lambda: self._common_refined(ctx, states, idx, nus, lo, hi, p_value)
        return prop

    def _common_refined(self, ctx, states, idx, nus, lo, hi, p_value) -> Proposal | None:
        """τ of the common warm-up on a fine grid in log τ between the screening grid's
        neighbours of the peak, with its σ from the curvature of the profile (Δχ² = 1)."""
        fine = np.exp(np.linspace(lo, hi, 17))
        cols = np.exp(-(np.arange(ctx.n_frames) * ctx.dt_s)[:, None] / fine[None, :])
        _, b2, i2 = screen_grid(ctx, states, idx, nus, cols)
        c2 = (b2 * i2).sum(axis=0) ** 2 / np.maximum(i2.sum(axis=0), 1e-300)
        k = int(np.argmax(c2))
        tau = float(fine[k])
        sig_tau = None
        if 0 < k < fine.size - 1:  # a parabola in log τ through the peak
            x = np.log(fine[k - 1 : k + 2])
            curv = (c2[k - 1] - 2 * c2[k] + c2[k + 1]) / (x[1] - x[0]) ** 2
            if curv < 0:
                sig_tau = tau * math.sqrt(2.0 / -curv)
        return self._common_at(ctx, states, idx, nus, tau, sig_tau, p_value)

    def _common_at(self, ctx, states, idx, nus, tau, sig_tau, p_value) -> Proposal | None:
        """The common warm-up at a given τ: its shared amplitude by weighted least squares."""
        fit = shared_amplitude(
            ctx, states, idx, lambda i: np.exp(-ctx.series[i].t / tau)[:, None], nus, self.id
        )
        if fit is None:
            return None
        amp = float(fit.beta[0])
        amp_sigma = math.sqrt(max(float(fit.cov[0, 0]), 0.0))
        return _exponential_proposal(
            ctx,
            fit.series,
            fit.states,
            2,
            p_value,
            (amp, amp_sigma),
            (tau, sig_tau),
            "all drift by {amp:+.3f} mm",
            "the camera warming up shifts its range for the whole image alike.",
            {"mode": "common"},
            MODES * N_GRID * 3,  # τ grid, axes
        )

    def _linear(self, ctx, states, sel, nus, tau, sig_tau, p_value, n_candidates) -> Proposal | None:
        """The exponential at a given τ on each series (linear amplitude + nuisance); the series
        that pay for their amplitude make the proposal."""
        new, amps, sds = {}, {}, {}
        for i in sel:
            s, st = ctx.series[i], states[i]
            col = np.exp(-s.t / tau)[:, None]
            beta, cov, fitted = wls(np.concatenate([col, nus[i]], axis=1), residual(ctx, i, st), weights(st))
            cand = updated(st, self.id, 1, mean=st.mean + fitted)
            if keep_series(gain(ctx, i, st, cand), 1, s.n):
                new[i], amps[i], sds[i] = cand, float(beta[0]), math.sqrt(max(float(cov[0, 0]), 0.0))
        if not new:
            return None
        return self._proposal(ctx, new, amps, sds, tau, sig_tau, p_value, n_candidates)

    def _refined(self, ctx, states, prop, nus, p_value, n_candidates) -> Proposal | None:
        """τ by variable projection (optimistix) on the proposal's series, then the states again."""
        sel = prop.series
        tau0 = float(prop.parameters["tau_s"]["value"])
        ts = [ctx.series[i].t for i in sel]
        rs = [residual(ctx, i, states[i]) for i in sel]
        ws = [weights(states[i]) for i in sel]
        nu3 = [_pad3(nus[i]) for i in sel]
        fit = fit_shared(_columns, np.array([math.log(tau0)]), ts, rs, ws, nu3, scale=np.array([0.1]))
        if not fit.converged or not np.isfinite(fit.theta[0]):
            return None
        tau = float(math.exp(fit.theta[0]))
        dur = float(ctx.duration_s)
        if not (0.002 * dur <= tau <= 10 * dur):
            return None
        sig_tau = tau * math.sqrt(max(float(fit.theta_cov[0, 0]), 0.0))
        out = self._linear(ctx, states, sel, nus, tau, sig_tau, p_value, n_candidates)
        if out is not None:
            out.n_params = 1 + len(out.series)
        return out

    def _proposal(self, ctx, new, amps, sds, tau, sig_tau, p_value, n_candidates) -> Proposal:
        kept = sorted(new)
        a = np.array([amps[i] for i in kept])
        sa = np.array([sds[i] for i in kept])
        amp = median_signed(a)
        amp_sigma = 1.2533 * math.sqrt(float(np.mean(sa**2)) / a.size)
        return _exponential_proposal(
            ctx,
            kept,
            new,
            1 + len(kept),
            p_value,
            (amp, amp_sigma),
            (tau, sig_tau),
            "drift by {amp:+.3f} mm",
            "the camera warming up (or its mount settling) adds a slowly vanishing offset.",
            {"amplitudes_mm": {ctx.series[i].key: amps[i] for i in kept}},
            MODES * N_GRID * subset_trials(len(kept), n_candidates),
        )

    # -- polynomial --------------------------------------------------------------------------
    def _polynomial(self, ctx: Context, states: list[State], idx: list[int], nus: dict) -> Proposal | None:
        dur = float(ctx.duration_s)
        t_mid = 0.5 * dur
        stat = np.zeros((len(idx), MAX_DEGREE))
        grams = {}
        for j, i in enumerate(idx):
            s, st = ctx.series[i], states[i]
            g = np.concatenate([_legendre((s.t - t_mid) / (0.5 * dur), MAX_DEGREE), nus[i]], axis=1)
            w = weights(st)
            r = residual(ctx, i, st)
            gw = g * w[:, None]
            gtg = gw.T @ g
            b = gw.T @ r
            rr = float(np.sum(w * r * r))
            q = nus[i].shape[1]
            rss = {}
            for d in range(0, MAX_DEGREE + 1):
                cols = list(range(d)) + list(range(MAX_DEGREE, MAX_DEGREE + q))
                sub = gtg[np.ix_(cols, cols)]
                rss[d] = rr - float(b[cols] @ np.linalg.lstsq(sub, b[cols], rcond=None)[0])
            n_used = max(int((w > 0).sum()) - MAX_DEGREE - q, 1)
            s2 = max(rss[MAX_DEGREE] / n_used, 1e-300) * long_run_factor(ctx, i, r)
            for d in range(1, MAX_DEGREE + 1):
                stat[j, d - 1] = max(rss[0] - rss[d], 0.0) / s2
            grams[i] = g
        logn = np.array([math.log(ctx.series[i].n) for i in idx])
        degrees = np.arange(1, MAX_DEGREE + 1)
        crit = np.maximum(stat - degrees[None, :] * logn[:, None], 0.0).sum(axis=0)
        dj = int(np.argmax(crit))
        if crit[dj] <= 0:
            return None
        d = int(degrees[dj])
        p_single = min(1.0, float(chi2_sf(stat[:, dj].max(), d)) * len(idx) * MAX_DEGREE)
        p_total = min(1.0, float(chi2_sf(stat[:, dj].sum(), d * len(idx))) * MAX_DEGREE)
        p_value = min(1.0, 2 * min(p_single, p_total))
        new, amps = {}, {}
        for j, i in enumerate(idx):
            if stat[j, dj] <= d * logn[j]:
                continue
            st = states[i]
            g = grams[i][:, list(range(d)) + list(range(MAX_DEGREE, grams[i].shape[1]))]
            beta, _, fitted = wls(g, residual(ctx, i, st), weights(st))
            cand = updated(st, self.id, d, mean=st.mean + fitted)
            if keep_series(gain(ctx, i, st, cand), d, ctx.series[i].n):
                drift = g[:, :d] @ beta[:d]
                new[i], amps[i] = cand, float(drift[0] - drift.mean())
        if not new:
            return None
        kept = sorted(new)
        amp = median_signed(np.array([amps[i] for i in kept]))
        where = ", ".join(ctx.series[i].key for i in kept)
        return Proposal(
            effect=self.id,
            series=kept,
            states=new,
            n_params=d * len(kept),
            p_value=p_value,
            parameters={
                "amplitude_mm": param(amp, None),
                "tau_s": param(None),
                "kind": param("polynomial"),
                "degree": param(d),
            },
            t_start=0.0,
            t_end=dur,
            band_hz=[0.0, float(d / (2 * dur))],
            explanation=(
                f"The measured positions of {where} drift slowly over the record (a degree-{d} "
                f"polynomial; {amp:+.3f} mm at the start against the record's mean): camera warm-up "
                "or a settling mount."
            ),
            detail={"amplitudes_mm": {ctx.series[i].key: amps[i] for i in kept}},
            trials=MODES * MAX_DEGREE * subset_trials(len(kept), len(idx)),
        )


EFFECT = Drift()


def _exponential_proposal(
    ctx: Context,
    series: list[int],
    states: list[State],
    n_params: int,
    p_value: float,
    amplitude: tuple[float, float],
    tau: tuple[float, float],
    what: str,
    why: str,
    detail: dict,
    trials: float,
) -> Proposal:
    """An exponential warm-up's proposal: amplitude and τ with their σ's, the span 3τ, the band
    below 1/(2πτ) and its explanation (``what`` formatted with the amplitude, then ``why``)."""
    amp, t = amplitude[0], tau[0]
    where = ", ".join(ctx.series[i].key for i in series)
    return Proposal(
        effect=Drift.id,
        series=series,
        states=states,
        n_params=n_params,
        p_value=p_value,
        parameters={"amplitude_mm": param(*amplitude), "tau_s": param(*tau), "kind": param("exponential")},
        t_start=0.0,
        t_end=float(min(ctx.duration_s, 3.0 * t)),
        band_hz=[0.0, float(1.0 / (2 * math.pi * t))],
        explanation=(
            f"The measured positions of {where} {what.format(amp=amp)} at the start of the record, "
            f"decaying with a time constant of {t / 60:.1f} min: {why}"
        ),
        detail=detail,
        trials=trials,
        scan_params=1,  # τ
    )
