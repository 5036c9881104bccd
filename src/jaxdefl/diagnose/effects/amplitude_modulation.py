"""``amplitude_modulation``: the deflection amplitude changes during the record, alike on every plate.

Physics: the beam's stiffness drops under fatigue (the amplitude grows with the load cycles,
thesis Fig. 6.55), or the load controller hunts or drifts; either scales the motion of every
plate and axis by the same relative factor. Two shapes: A(t) = A0 (1 + r (t − t_mid)) (kind
"linear", ``relative_rate_per_s``; fatigue: 1e-5 to 1e-4 /s, i.e. 4-36 % per hour) and
A(t) = A0 (1 + m cos(2π f_m t + ψ)) (kind "sinusoidal", ``depth`` m of 1-10 %, ``freq_hz`` f_m from
about 2/duration to 0.2 Hz: controller hunting, pump pressure cycles).

Signature: the residual of each series demodulated at its carrier in phase (r · a cos arg), the
demodulated series combined across series on the frame clock, weighted by a²/σ̂² (only series
whose motion stands ≥ 10 σ_A above the noise carry information); the linear kind is the χ²₁ of a
shared trend, the sinusoidal kind the peak of the combined spectrum between 2/duration and 0.2 Hz
(Exp(1) powers, corrected for the independent frequencies scanned). Each is doubled for the two
kinds tried. The in-phase demodulation separates it from `frequency_modulation` (quadrature).

Model: y += a_s u(t) cos(arg_s(t)), arg_s and a_s the series' nominal harmonic, u(t) = r (t − t_mid)
or m cos(2π f_m t + ψ) shared by all series (parameters counted once: 1 or 3); fitted by
Levenberg-Marquardt on all carrying series with each series' free nuisance profiled out. The
series reported are those where the term is individually significant.
"""

from __future__ import annotations

import math

import numpy as np

from .._base import Context, Effect, Proposal, State
from ._common_b import Carriers, chi2_p_value, one_sided, param, scan_p_value

__all__ = ["AmplitudeModulation", "EFFECT"]

P_MAX = 1e-3  # weaker signatures cannot pass the search's Bonferroni (α = 0.01 over ~10 effects)
F_MAX_HZ = 0.2
KINDS = 2


def modulation_band(ctx: Context) -> tuple[float, float]:
    """Modulation frequencies scanned: from 2/duration to 0.2 Hz (and well below f0)."""
    return 2.0 / ctx.duration_s, min(F_MAX_HZ, ctx.f0_hz / 4)


def _linear_term(it, theta, jac, ctx):
    x = it.a * it.cos * (ctx.series[it.i].t - 0.5 * ctx.duration_s)
    m = theta[0] * x
    return (m, x[:, None]) if jac else m


def _sinusoidal_term(it, theta, jac, ctx):
    t = ctx.series[it.i].t
    al, be, f = theta
    ph = 2 * math.pi * f * t
    c, s = np.cos(ph), np.sin(ph)
    x = it.a * it.cos
    m = x * (al * c + be * s)
    if not jac:
        return m
    return m, np.stack([x * c, x * s, x * 2 * math.pi * t * (-al * s + be * c)], axis=1)


class AmplitudeModulation(Effect):
    id = "amplitude_modulation"
    meaning = (
        "the deflection amplitude changes during the record alike on every plate (fatigue, load controller)"
    )
    min_cycles = 50.0

    def propose(self, ctx: Context, states: list[State]) -> list[Proposal]:
        if self.cannot_tell(ctx) is not None:
            return []
        car = Carriers.cached(ctx, states)
        if not car.items:
            return []
        out = []
        t_mid = 0.5 * ctx.duration_s

        # linear: a shared relative rate
        stat, r0, _ = car.linear_stat("in_phase", lambda t: t - t_mid)
        p_lin = min(1.0, KINDS * chi2_p_value(stat, 1))
        if p_lin < P_MAX:
            prop = self._linear(ctx, states, car, r0, p_lin)
            if prop is not None:
                out.append(prop)

        # sinusoidal: the peak of the combined in-phase spectrum
        f_lo, f_hi = modulation_band(ctx)
        if f_hi > f_lo:
            freq, power, n_ind, grid, q = car.scan("in_phase", f_lo, f_hi)
            if power.size:
                j = int(np.argmax(power))
                p_sin = min(1.0, KINDS * scan_p_value(power[j], n_ind))
                if p_sin < P_MAX:
                    df = freq[1] - freq[0] if freq.size > 1 else 1.0 / ctx.duration_s
                    f_pk, p_pk, n_pk = car.refine_peak(grid, q, float(freq[j]), df)
                    if one_sided(p_pk, car.power_at("quadrature", f_pk)):
                        return out  # a line on one side of f0 (extra_periodic), not a modulation
                    prop = self._sinusoidal(ctx, states, car, f_pk, n_pk, q, p_sin)
                    if prop is not None:
                        out.append(prop)
        return out

    def _linear(self, ctx, states, car, r0, p_value):
        def term(it, th, jac):
            return _linear_term(it, th, jac, ctx)

        res = car.fit(term, np.array([r0]))
        if not res.converged:
            return None
        kept, new, gains = car.proposal_states(states, term, res.theta, self.id, 1)
        if not kept:
            return None
        r, sr = float(res.theta[0]), math.sqrt(max(res.cov[0, 0], 0.0))
        plates = sorted({ctx.series[i].plate for i in kept})
        change = r * ctx.duration_s
        return Proposal(
            effect=self.id,
            series=kept,
            states=new,
            n_params=1,
            p_value=p_value,
            parameters={"relative_rate_per_s": param(r, sr)},
            t_start=0.0,
            t_end=ctx.duration_s,
            band_hz=[ctx.f0_hz - 1.0 / ctx.duration_s, ctx.f0_hz + 1.0 / ctx.duration_s],
            explanation=(
                f"The deflection amplitude {'grows' if r > 0 else 'shrinks'} steadily by "
                f"{100 * abs(change):.1f} % over the record ({100 * 3600 * abs(r):.1f} ± "
                f"{100 * 3600 * sr:.1f} % per hour), alike on plate(s) {', '.join(map(str, plates))}: "
                "the beam softening under fatigue or the load controller drifting."
            ),
            detail={"kind": "linear", "loglik_gain": {ctx.series[i].key: float(g) for i, g in gains.items()}},
        )

    def _sinusoidal(self, ctx, states, car, f_pk, n_pk, q, p_value):
        def term(it, th, jac):
            return _sinusoidal_term(it, th, jac, ctx)

        al0, be0 = 2 * n_pk.real / q, -2 * n_pk.imag / q
        res = car.fit(term, np.array([al0, be0, f_pk]))
        f_lo, f_hi = modulation_band(ctx)
        al, be, f = res.theta
        if not (res.converged and 0.5 * f_lo <= f <= 1.5 * f_hi):
            return None
        kept, new, gains = car.proposal_states(states, term, res.theta, self.id, 3)
        if not kept:
            return None
        m = math.hypot(al, be)
        g = np.array([al, be]) / max(m, 1e-300)
        sm = math.sqrt(max(g @ res.cov[:2, :2] @ g, 0.0))
        sf = math.sqrt(max(res.cov[2, 2], 0.0))
        psi = math.atan2(-be, al)
        plates = sorted({ctx.series[i].plate for i in kept})
        return Proposal(
            effect=self.id,
            series=kept,
            states=new,
            n_params=3,
            p_value=p_value,
            parameters={"depth": param(m, sm), "freq_hz": param(f, sf)},
            t_start=0.0,
            t_end=ctx.duration_s,
            band_hz=[ctx.f0_hz - f, ctx.f0_hz + f],
            explanation=(
                f"The deflection amplitude swings by ±{100 * m:.1f} % every {1 / f:.0f} s "
                f"({f:.4f} Hz), alike on plate(s) {', '.join(map(str, plates))}: the load controller "
                "or the hydraulic supply modulates the load."
            ),
            detail={
                "kind": "sinusoidal",
                "phase_rad": psi,
                "loglik_gain": {ctx.series[i].key: float(g) for i, g in gains.items()},
            },
        )


EFFECT = AmplitudeModulation()
