"""``motion_artefact``: the four correlation samples of a ToF frame are taken one after the other.

Physics (thesis 5.47-5.52, `jaxdefl.fit.motion`): the SR4000 integrates its four correlation
samples in sequence, at 0, T/4, T/2 and 3T/4 after the frame timestamp (T the tap spread, at most
the frame period); a moving plate is measured as the mean of its range at the four taps, so a
harmonic motion e^{iωt} is seen as H(ω; T) e^{iωt} with
H = (1 + e^{iωT/4} + e^{iωT/2} + e^{i3ωT/4})/4: the amplitude shrinks by
|H| = cos(ωT/4) cos(ωT/8) and the phase shifts by arg H = 3ωT/8 (the taps come after the stamp).
Magnitudes: 3 Hz loading and 20 Hz frames with the taps over the whole frame (T = 50 ms, the
thesis' Fig. 6.9): 3.5 % gain loss (0.14 mm of 4 mm) and a 20° lag; 1 Hz and 10 Hz: 1.5 %, 13.5°.

Signature: against the LDS only (the camera cannot see its own gain). On the tied series (z of the
plates with an LDS) the camera's own harmonic against the LDS's: amplitude ratio below 1 and a
phase lag, both consistent with one T for every plate (a camera property). The test is the
likelihood ratio of T (χ²₁) on all tied series jointly.

Model: on a tied series, mean = offset + Re[H(ω; T) (C − iD) e^{iω(t − t_ref)}] with (ω, C, D) the
LDS's harmonic and the camera's offset free; T is one parameter shared by all tied series, fitted
by Levenberg-Marquardt from a start at the frame period and one at the observed lag. The camera's
x and y series are not tied and are left alone. When `timing_error` is already in the model its
clock offset is re-estimated jointly (a clock offset is a pure phase shift and trades phase with
T; the gain loss is what separates them), at no parameter cost.
"""

from __future__ import annotations

import math

import numpy as np

from ..._numerics import P_MAX
from ...effects import timing_error
from ...effects.motion_artefact import ENTRY
from .._base import Context, Proposal, State
from .shared_fits import (
    AMBIGUOUS_CHI2,
    TiedEffect,
    chi2_p_value,
    motion_parameters,
    param,
    tap_response,
    tied_proposal_states,
)

__all__ = ["MotionArtefact", "EFFECT"]


class MotionArtefact(TiedEffect):
    id = ENTRY.id
    sensors, structural, needs_reference = ENTRY.sensors, ENTRY.structural, ENTRY.needs_reference
    meaning = "gain loss and lag of the camera against the LDS from its sequential four-phase sampling"
    plausible, plausible_unit, gate_params = 0.001, "seconds", 1  # 1 ms of lag against the LDS

    def propose_tied(self, ctx: Context, states: list[State], model, period: float) -> list[Proposal]:
        idx = model.idx
        free = [0] + ([1] if timing_error.ENTRY.id in model.accepted else [])
        t_max = 3.0 * period
        bounds = [(0.0, t_max)] + [(-0.5 / ctx.f0_hz, 0.5 / ctx.f0_hz)] * (len(free) - 1)

        # starts: the frame period, and the T whose lag matches the camera-vs-LDS phase
        gain_obs, lead_obs = model.observed_ratio()
        wts = np.abs(model.Z) ** 2
        lead = float(np.angle(np.sum(wts * np.exp(1j * lead_obs))))
        mean_tap = float(np.mean(ctx.tap_offsets))
        starts = {period}
        if lead > 0 and mean_tap > 0:
            starts.add(min(lead / (2 * math.pi * ctx.f0_hz * mean_tap), t_max))
        best = None
        for t_start in sorted(starts):
            theta0 = model.current.copy()
            theta0[0] = t_start
            res = model.fit(theta0, free, bounds=bounds)
            if best is None or res.chi2 < best.chi2:
                best = res
        chi2_now = model.chi2_at(model.current)
        delta = chi2_now - best.chi2
        p_value = chi2_p_value(delta, 1)
        T = float(best.theta[0])
        sigma_T = math.sqrt(max(best.cov[0, 0], 0.0))
        if not (best.converged and p_value < P_MAX and T > 0):
            return []
        kept, new_states, gains = tied_proposal_states(ctx, states, model, best.theta, self.id, 1)
        if not kept:
            return []

        # is the gain loss resolved? a pure clock offset (phase only) in place of T
        w0 = 2 * math.pi * ctx.f0_hz
        theta_d = model.current.copy()
        theta_d[1] -= float(np.angle(tap_response(w0, T, ctx.tap_offsets))) / w0
        phase_only = model.fit(
            theta_d, [1], bounds=[(theta_d[1] - 0.5 / ctx.f0_hz, theta_d[1] + 0.5 / ctx.f0_hz)]
        )
        gain_evidence = phase_only.chi2 - best.chi2
        parameters = motion_parameters(ctx, T, sigma_T)
        gain, lag = parameters["gain"]["value"], math.radians(parameters["lag_deg"]["value"])
        amp = float(np.median([ctx.nominal[i].amplitude for i in kept]))
        plates = sorted({ctx.series[i].plate for i in kept})
        frac = T / period
        spread = (
            "the taps spread over the whole frame period, as in the thesis' Fig. 6.9"
            if 0.8 <= frac <= 1.2
            else f"the taps spread over {frac:.0%} of the {1e3 * period:.0f}-ms frame period"
        )
        detail = {
            "gain_loss_evidence_chi2": float(gain_evidence),
            "frame_period_s": period,
            "tap_spread_over_frame_period": frac,
            "amplitude_loss_mm": (1 - gain) * amp,
            "observed_gain": {ctx.series[i].key: float(g) for i, g in zip(idx, gain_obs, strict=True)},
            "observed_lag_deg": {
                ctx.series[i].key: float(math.degrees(x)) for i, x in zip(idx, lead_obs, strict=True)
            },
            "loglik_gain": {ctx.series[i].key: float(g) for i, g in gains.items()},
            "equivalent_clock_offset_s": lag / w0,
        }
        if len(free) > 1:  # the accepted clock offset, refitted jointly (the report may update it)
            detail["reestimated"] = {
                timing_error.ENTRY.id: {
                    "offset_s": param(best.theta[1], math.sqrt(max(best.cov[1, 1], 0.0))),
                    "rate_ppm": param(best.theta[2], None),
                }
            }
        lo, hi = ctx.f0_hz, ctx.f0_hz
        return [
            Proposal(
                effect=self.id,
                series=kept,
                states=new_states,
                n_params=1,
                p_value=p_value,
                parameters=parameters,
                t_start=0.0,
                t_end=ctx.duration_s,
                band_hz=[lo, hi],
                explanation=(
                    f"Against the LDS the camera reports {100 * (1 - gain):.1f} % less amplitude "
                    f"(about {1e3 * (1 - gain) * amp:.0f} µm of {amp:.2f} mm) and a {math.degrees(lag):.1f}° "
                    f"lag at {ctx.f0_hz:.3f} Hz on plate(s) {', '.join(map(str, plates))}: the four "
                    f"correlation samples are taken one after the other over T = {1e3 * T:.1f} ± "
                    f"{1e3 * sigma_T:.1f} ms ({spread}) while the beam moves."
                    + (
                        ""
                        if gain_evidence >= AMBIGUOUS_CHI2
                        else f" The gain loss is not resolved: a camera clock {1e3 * lag / w0:.1f} ms early "
                        "would explain the lag alike (timing_error)."
                    )
                ),
                detail=detail,
            )
        ]


EFFECT = MotionArtefact()
