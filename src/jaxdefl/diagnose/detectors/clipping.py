"""``clipping``: a plate's reading saturates at the peaks of its motion.

Physics: the camera measures depth within a band; a plate whose motion takes it beyond the band's
bound (or whose pixels saturate) is read at the bound, so its recorded motion is flat-topped on
that side: y = min(offset + A cos θ, bound) (far side) or max(·, bound) (near side). One or a few
plates (the ones nearest the band's edge). Typical levels: 50-98 % of the plate's amplitude.

Signature: per z series, the residual regressed on the clip column g_c(θ) = max(s cos θ − c, 0)
(θ the nominal motion's phase angle, s = ±1 the side, c the clip level as a fraction of the
amplitude on a grid 0.2-0.98) with the free nuisance (offset, the harmonic's C and D); the
largest χ²_1 over the grid and sides, Bonferroni-corrected over the grid, sides and series (or
the statistics summed over the kept series, whichever is smaller, doubled). A clip also puts
power at 2f0, 3f0 ... (`harmonic_distortion`), but with the phases and ratios of a flat top: one
clip column (2 parameters) explains what needs several harmonic orders (2 each), and BIC
decides.

Model: y += −β g_c(θ) per kept series (c and β per series: 2 parameters each); a clip gives
β ≈ A (a flat top), the refit C and D restore the amplitude the nominal fit lost to the clip.
Reported: ``level_mm`` (the bound from the offset, signed: + far side) and ``level`` (c, the
fraction of the amplitude) of the strongest series; every series' in the detail.
"""

from __future__ import annotations

import math

import numpy as np

from ..._numerics import wls
from ...effects.clipping import ENTRY
from .._base import Context, Detector, Proposal, State, keep_series
from .screening import chi2_sf, combined_p, gain, param, residual, screen_columns, updated, weights

__all__ = ["Clipping", "EFFECT", "LEVELS", "clip_column"]

LEVELS = np.linspace(0.2, 0.98, 21)  # clip level c: fraction of the amplitude


def clip_column(theta: np.ndarray, side: int, c: float) -> np.ndarray:
    """max(s cos θ − c, 0): the part of a unit cosine beyond the level c on side s (±1)."""
    return np.maximum(side * np.cos(theta) - c, 0.0)


class Clipping(Detector):
    id = ENTRY.id
    sensors, structural, needs_reference = ENTRY.sensors, ENTRY.structural, ENTRY.needs_reference
    meaning = "a plate's reading saturating at the peaks of its motion (the depth band's bound)"
    plausible, plausible_unit, gate_params = 0.03, "motion", 2

    def plausible_rms(self, ctx: Context, i: int) -> float:
        """A clip at 85 % of the amplitude leaves an RMS of about 3 % of it, on z series only."""
        return self.plausible * ctx.nominal[i].amplitude if ctx.series[i].axis == "z" else 0.0

    def propose(self, ctx: Context, states: list[State]) -> list[Proposal]:
        idx = [i for i in ctx.indices("z") if ctx.series[i].n >= 64]
        n_grid = 2 * len(LEVELS)
        stats, fits = {}, {}
        for i in idx:
            s, st = ctx.series[i], states[i]
            theta = ctx.nominal[i].argument(s.t)
            cols = np.stack([clip_column(theta, side, c) for side in (1, -1) for c in LEVELS], axis=1)
            nu = ctx.nuisance(i)
            w = weights(st)
            r = residual(ctx, i, st)
            stat, _ = screen_columns(nu, w, r, cols)
            stats[i] = stat
            k = int(np.argmax(stat))
            if stat[k] < 2.0 * math.log(s.n):  # cannot pay for its two parameters
                continue
            side, kc = (1, -1)[k // len(LEVELS)], k % len(LEVELS)
            c = float(LEVELS[kc])
            if 0 < kc < len(LEVELS) - 1:  # between the grid's levels: a parabola through the three
                a0, a1, a2 = stat[k - 1], stat[k], stat[k + 1]
                den = a0 - 2 * a1 + a2
                if den < 0:
                    c += float(np.clip(0.5 * (a0 - a2) / den, -0.5, 0.5)) * (LEVELS[1] - LEVELS[0])
            col = clip_column(theta, side, c)[:, None]
            beta, cov, fitted = wls(np.concatenate([col, nu], axis=1), r, w)
            if not -side * beta[0] > 0:  # a clip flattens the peak; a sharper one is another shape
                continue
            new = updated(st, self.id, 2, mean=st.mean + fitted)
            if not keep_series(gain(ctx, i, st, new), 2, s.n):
                continue
            h = ctx.nominal[i]
            amp = math.hypot(h.C + beta[2], h.D + beta[3]) if nu.shape[1] == 3 else h.amplitude
            fits[i] = (new, side, c, float(beta[0]), math.sqrt(max(cov[0, 0], 0.0)), amp, float(stat[k]))
        if not fits:
            return []
        series = sorted(fits)
        single = np.array([stats[i].max() for i in idx])
        p = combined_p(single, 1, n_grid, total=sum(fits[i][6] for i in series), dof_total=len(series))
        p = min(p, float(chi2_sf(single.max(), 1)) * n_grid * len(idx))
        top = max(series, key=lambda i: fits[i][6])
        _, side, c, beta, beta_sig, amp, _ = fits[top]
        level_mm = side * c * amp
        where = ", ".join(f"plate {ctx.series[i].plate}" for i in series)
        return [
            Proposal(
                effect=self.id,
                series=series,
                states={i: fits[i][0] for i in series},
                n_params=2 * len(series),
                p_value=p,
                trials=n_grid * len(idx),  # the grid × the series picked
                parameters={
                    "level_mm": param(level_mm, None),
                    "level": param(c, None),
                    "plate": param(ctx.series[top].plate, None),
                    "flatness": param(-side * beta / max(amp, 1e-300), beta_sig / max(amp, 1e-300)),
                },
                t_start=0.0,
                t_end=float(ctx.duration_s),
                band_hz=[2 * ctx.f0_hz, 5 * ctx.f0_hz],
                explanation=(
                    f"The recorded motion of {where} is flat-topped on its "
                    f"{'far' if side > 0 else 'near'} side: the reading stops at {abs(level_mm):.2f} mm "
                    f"from the mean ({100 * c:.0f} % of the amplitude), as when the plate leaves the "
                    "camera's depth band or its pixels saturate."
                ),
                detail={
                    "levels_mm": {ctx.series[i].key: fits[i][1] * fits[i][2] * fits[i][5] for i in series},
                    "sides": {ctx.series[i].key: "far" if fits[i][1] > 0 else "near" for i in series},
                },
            )
        ]


EFFECT = Clipping()
