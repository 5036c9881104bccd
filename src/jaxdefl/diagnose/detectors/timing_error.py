"""``timing_error``: the camera's clock against the LDS's — a constant offset and/or a rate error.

Physics: the camera's frame timestamps come from its host PC, the LDS's from the data logger; the
two clocks are set apart by a latency (a few ms: USB transfer, exposure, driver buffering) and
their crystals run at slightly different rates (tens to a few hundred ppm). With
t_cam = t_true + δ + ε t_true, a camera sample stamped t (s since the table's first timestamp)
shows the beam at t/(1 + ε) − δ ≈ t − δ − ε t. Magnitudes: δ = 2-10 ms is 2-11° of phase at
3 Hz; ε = 100 ppm drifts by 0.36 s (3.3 cycles at 3 Hz) over an hour.

Signature: against the LDS only (the camera's own harmonic absorbs its clock). On the tied
series, the camera's own harmonic against the LDS's: a phase shift with no gain loss (offset; a
gain loss with a lag is `motion_artefact`, and both can be present) and a frequency ratio
f_cam/f_LDS = 1/(1 + ε) (rate). The test is the likelihood ratio of the variant's parameters
(χ² with 1 or 2 degrees of freedom) on all tied series jointly.

Model: on a tied series, mean = offset + (the LDS's harmonic at t/(1 + ε) − δ), the camera's
offset free, (δ, ε) shared by all tied series (one camera clock). Three variants are proposed —
offset only (``offset_s``), rate only (``rate_ppm``) and both — and BIC picks. A tap spread T
already in the model (`motion_artefact`) is re-estimated jointly at no parameter cost. The
camera's untied series (x, y, z without an LDS) are not touched: their own harmonic absorbs it.

Against `motion_artefact`: on a ToF camera, early stamps and sequential taps both make the camera
lead the LDS; only the taps' gain loss tells them apart. A clock offset whose lead a tap spread of
at most a frame period gives, with the gain loss unresolved (`AMBIGUOUS_CHI2`), is not proposed:
the camera's own mechanism is, and its report says a clock would explain it alike.
"""

from __future__ import annotations

import math

import numpy as np

from ..._numerics import P_MAX
from ...effects import motion_artefact
from ...effects.timing_error import ENTRY
from .._base import Context, Proposal, State
from .shared_fits import (
    AMBIGUOUS_CHI2,
    PPM,
    TiedEffect,
    TiedModel,
    chi2_p_value,
    motion_parameters,
    param,
    tied_proposal_states,
)

__all__ = ["TimingError", "EFFECT"]

VARIANTS = {"offset": [1], "rate": [2], "both": [1, 2]}


class TimingError(TiedEffect):
    id = ENTRY.id
    sensors, structural, needs_reference = ENTRY.sensors, ENTRY.structural, ENTRY.needs_reference
    meaning = "the camera's clock runs late or at another rate than the reference's"
    plausible, plausible_unit, gate_params = 0.002, "seconds", 1  # 2 ms late (stamped on delivery)

    def propose_tied(self, ctx: Context, states: list[State], model, period: float) -> list[Proposal]:
        idx = model.idx
        extra = [0] if motion_artefact.ENTRY.id in model.accepted else []
        half = 0.5 / ctx.f0_hz

        # starts: the rate from the camera's own frequency against the LDS's, the offset from
        # the phase of the camera's harmonic against the LDS's at mid-record
        wts = np.abs(model.Z) ** 2
        om_free = np.array([ctx.free[i].omega for i in idx])
        eps0 = float(np.sum(wts * (model.omega / om_free - 1.0)) / np.sum(wts)) / PPM
        _, lead = model.observed_ratio()
        lead = float(np.angle(np.sum(wts * np.exp(1j * lead))))
        mid = 0.5 * ctx.duration_s
        w0 = float(np.sum(wts * model.omega) / np.sum(wts))
        chi2_now = model.chi2_at(model.current)
        out = []
        for kind, own in VARIANTS.items():
            free = extra + own
            theta0 = model.current.copy()
            if kind == "offset":
                theta0[1] = model.current[1] - lead / w0
            elif kind == "rate":
                theta0[2] = eps0
            else:
                theta0[2] = eps0
                theta0[1] = -lead / w0 - eps0 * PPM * mid
            bounds = [(0.0, 3 * period)] * bool(extra) + [
                (-half + theta0[1], half + theta0[1]) if j == 1 else (-1e5, 1e5) for j in own
            ]
            res = model.fit(theta0, free, bounds=bounds)
            delta = chi2_now - res.chi2
            p_value = chi2_p_value(delta, len(own))
            if not (res.converged and p_value < P_MAX):
                continue
            if 1 in own and self._taps_explain(ctx, model, res, own, extra, period):
                continue
            kept, new_states, gains = tied_proposal_states(ctx, states, model, res.theta, self.id, len(own))
            if not kept:
                continue
            d, e = float(res.theta[1]), float(res.theta[2])
            sd = math.sqrt(max(res.cov[1, 1], 0.0)) if 1 in own else None
            se = math.sqrt(max(res.cov[2, 2], 0.0)) if 2 in own else None
            plates = sorted({ctx.series[i].plate for i in kept})
            parts = []
            if 1 in own:
                parts.append(
                    f"stamps its frames {1e3 * abs(d):.1f} ± {1e3 * sd:.1f} ms "
                    f"{'late' if d > 0 else 'early'} ({math.degrees(w0 * d):.1f}° of phase)"
                )
            if 2 in own:
                parts.append(
                    f"runs {abs(e):.1f} ± {se:.1f} ppm {'fast' if e > 0 else 'slow'} "
                    f"({1e3 * abs(e) * PPM * ctx.duration_s:.0f} ms over the record)"
                )
            detail = {
                "variant": kind,
                "loglik_gain": {ctx.series[i].key: float(g) for i, g in gains.items()},
                "rate_from_frequencies_ppm": eps0,
            }
            if extra:  # the accepted tap spread, refitted jointly (the report may update it)
                t_sig = math.sqrt(max(res.cov[0, 0], 0.0))
                detail["reestimated"] = {
                    motion_artefact.ENTRY.id: motion_parameters(ctx, float(res.theta[0]), t_sig)
                }
            out.append(
                Proposal(
                    effect=self.id,
                    series=kept,
                    states=new_states,
                    n_params=len(own),
                    p_value=p_value,
                    trials=len(VARIANTS),  # three variants fitted, the best proposed
                    parameters={"offset_s": param(d, sd), "rate_ppm": param(e, se)},
                    t_start=0.0,
                    t_end=ctx.duration_s,
                    band_hz=[ctx.f0_hz, ctx.f0_hz],
                    explanation=(
                        f"Against the LDS the camera's clock {' and '.join(parts)} on plate(s) "
                        f"{', '.join(map(str, plates))}: a shift of the motion's phase without the "
                        "gain loss of a motion artefact, so the timestamps, not the ranges, are off."
                    ),
                    detail=detail,
                )
            )
        return out

    @staticmethod
    def _taps_explain(ctx: Context, model: TiedModel, res, own: list[int], extra: list[int], period: float):
        """Whether a ToF camera's tap spread explains the fitted clock offset as well.

        Sequential taps sample after the frame's stamp: the camera leads the LDS by arg H/ω ≈
        mean tap offset × T, as early stamps would. When the lead is within what a spread of at
        most a frame period gives and the gain loss that tells them apart is not resolved
        (`AMBIGUOUS_CHI2`), the camera's own mechanism is proposed (`motion_artefact`, whose
        report says a clock offset would do alike), not both.
        """
        if ctx.sensor != "tof" or extra:
            return False
        d = float(res.theta[1])
        mean_tap = float(np.mean(ctx.tap_offsets))
        if not (d < 0 and -d <= mean_tap * period):
            return False
        theta = model.current.copy()
        theta[0] = -d / mean_tap
        theta[2] = res.theta[2]
        free = [0] + [j for j in own if j != 1]
        bounds = [(0.0, 3 * period)] + [(-1e5, 1e5)] * (len(free) - 1)
        taps = model.fit(theta, free, bounds=bounds)
        return taps.converged and taps.chi2 <= res.chi2 + AMBIGUOUS_CHI2


EFFECT = TimingError()
