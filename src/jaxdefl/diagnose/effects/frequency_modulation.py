"""``frequency_modulation``: the loading frequency wanders during the record, alike on every plate.

Physics: the actuator's controller holds the load's frequency only so well: it hunts around the
set point (kind "sinusoidal": the motion's phase gets + β sin(2π f_m t + ψ), ``depth_rad`` β of
0.01-0.2 rad, ``freq_hz`` f_m from about 2/duration to 0.2 Hz) or drifts (kind "linear":
f(t) = f0 + d (t − t_mid), ``drift_hz_per_s`` d of 1e-8 to 1e-6 Hz/s, i.e. a phase
π d (t − t_mid)²). The whole beam follows, so every plate and axis carries the same phase
wander δφ(t); the LDS sees it too (it is the load, not the camera).

Signature: the residual of each series demodulated in quadrature (r · (−a sin arg)), combined
across series weighted by a²/σ̂² (series whose motion stands ≥ 10 σ_A above the noise); the
linear kind is the χ²₁ of a shared quadratic phase, the sinusoidal kind the peak of the combined
spectrum between 2/duration and 0.2 Hz (corrected for the frequencies scanned); each doubled for
the two kinds. Quadrature, not in phase: `amplitude_modulation` is the in-phase twin. A constant
frequency offset is absorbed by each series' own harmonic and a linear phase trend on the
LDS-tied series is a clock rate (`timing_error`): the linear kind is quadratic in time and the
scan projects a phase trend out of the tied series.

Model: y += a_s [cos(arg_s + δφ(t)) − cos(arg_s)] ≈ −a_s δφ(t) sin(arg_s), δφ shared by all
series (1 or 3 parameters counted once), arg_s and a_s from the series' nominal harmonic;
Levenberg-Marquardt on the exact term with each series' free nuisance profiled out, started from
the demodulation's estimate. The series reported are those where the term is individually
significant.
"""

from __future__ import annotations

import math

import numpy as np

from .._base import Context, Effect, Proposal, State
from ._common_b import Carriers, chi2_p_value, one_sided, param, scan_p_value
from .amplitude_modulation import modulation_band

__all__ = ["FrequencyModulation", "EFFECT"]

P_MAX = 1e-3  # weaker signatures cannot pass the search's Bonferroni (α = 0.01 over ~10 effects)
KINDS = 2


def _quadratic(ctx: Context, t: np.ndarray) -> np.ndarray:
    """π ((t − t_mid)² − D²/12): the phase of a unit linear frequency drift, its mean removed."""
    d = ctx.duration_s
    return math.pi * ((t - 0.5 * d) ** 2 - d * d / 12.0)


def _linear_term(it, theta, jac, ctx):
    u = _quadratic(ctx, ctx.series[it.i].t)
    arg = it.arg + theta[0] * u
    m = it.a * (np.cos(arg) - it.cos)
    return (m, (-it.a * np.sin(arg) * u)[:, None]) if jac else m


def _sinusoidal_term(it, theta, jac, ctx):
    t = ctx.series[it.i].t
    bc, bs, f = theta
    ph = 2 * math.pi * f * t
    c, s = np.cos(ph), np.sin(ph)
    arg = it.arg + bc * c + bs * s
    m = it.a * (np.cos(arg) - it.cos)
    if not jac:
        return m
    q = -it.a * np.sin(arg)
    return m, np.stack([q * c, q * s, q * 2 * math.pi * t * (-bc * s + bs * c)], axis=1)


class FrequencyModulation(Effect):
    id = "frequency_modulation"
    meaning = "the loading frequency wanders or drifts during the record alike on every plate"
    min_cycles = 50.0

    def propose(self, ctx: Context, states: list[State]) -> list[Proposal]:
        if self.cannot_tell(ctx) is not None:
            return []
        car = Carriers.cached(ctx, states)
        if not car.items:
            return []
        out = []
        stat, d0, _ = car.linear_stat("quadrature", lambda t: _quadratic(ctx, t), trend=True)
        p_lin = min(1.0, KINDS * chi2_p_value(stat, 1))
        if p_lin < P_MAX:
            prop = self._linear(ctx, states, car, d0, p_lin)
            if prop is not None:
                out.append(prop)
        f_lo, f_hi = modulation_band(ctx)
        if f_hi > f_lo:
            freq, power, n_ind, grid, q = car.scan("quadrature", f_lo, f_hi, trend=True)
            if power.size:
                j = int(np.argmax(power))
                p_sin = min(1.0, KINDS * scan_p_value(power[j], n_ind))
                if p_sin < P_MAX:
                    df = freq[1] - freq[0] if freq.size > 1 else 1.0 / ctx.duration_s
                    f_pk, p_pk, n_pk = car.refine_peak(grid, q, float(freq[j]), df)
                    if one_sided(p_pk, car.power_at("in_phase", f_pk)):
                        return out  # a line on one side of f0 (extra_periodic), not a modulation
                    prop = self._sinusoidal(ctx, states, car, f_pk, n_pk, q, p_sin)
                    if prop is not None:
                        out.append(prop)
        return out

    def _linear(self, ctx, states, car, d0, p_value):
        def term(it, th, jac):
            return _linear_term(it, th, jac, ctx)

        res = car.fit(term, np.array([d0]))
        if not res.converged:
            return None
        kept, new, gains = car.proposal_states(states, term, res.theta, self.id, 1)
        if not kept:
            return None
        d, sd = float(res.theta[0]), math.sqrt(max(res.cov[0, 0], 0.0))
        plates = sorted({ctx.series[i].plate for i in kept})
        return Proposal(
            effect=self.id,
            series=kept,
            states=new,
            n_params=1,
            p_value=p_value,
            parameters={"drift_hz_per_s": param(d, sd)},
            t_start=0.0,
            t_end=ctx.duration_s,
            band_hz=sorted(
                [ctx.f0_hz - abs(d) * ctx.duration_s / 2, ctx.f0_hz + abs(d) * ctx.duration_s / 2]
            ),
            explanation=(
                f"The loading frequency {'rises' if d > 0 else 'falls'} steadily by "
                f"{1e3 * abs(d) * ctx.duration_s:.2f} mHz over the record ({d:.2e} ± {sd:.1e} Hz/s), "
                f"alike on plate(s) {', '.join(map(str, plates))}: the actuator's frequency drifts, "
                "so one frequency does not fit the whole record."
            ),
            detail={"kind": "linear", "loglik_gain": {ctx.series[i].key: float(g) for i, g in gains.items()}},
        )

    def _sinusoidal(self, ctx, states, car, f_pk, n_pk, q, p_value):
        def term(it, th, jac):
            return _sinusoidal_term(it, th, jac, ctx)

        bc0, bs0 = 2 * n_pk.real / q, -2 * n_pk.imag / q
        res = car.fit(term, np.array([bc0, bs0, f_pk]))
        f_lo, f_hi = modulation_band(ctx)
        bc, bs, f = res.theta
        if not (res.converged and 0.5 * f_lo <= f <= 1.5 * f_hi):
            return None
        kept, new, gains = car.proposal_states(states, term, res.theta, self.id, 3)
        if not kept:
            return None
        beta = math.hypot(bc, bs)
        g = np.array([bc, bs]) / max(beta, 1e-300)
        sb = math.sqrt(max(g @ res.cov[:2, :2] @ g, 0.0))
        sf = math.sqrt(max(res.cov[2, 2], 0.0))
        psi = math.atan2(bc, bs)
        plates = sorted({ctx.series[i].plate for i in kept})
        return Proposal(
            effect=self.id,
            series=kept,
            states=new,
            n_params=3,
            p_value=p_value,
            parameters={"depth_rad": param(beta, sb), "freq_hz": param(f, sf)},
            t_start=0.0,
            t_end=ctx.duration_s,
            band_hz=[ctx.f0_hz - f, ctx.f0_hz + f],
            explanation=(
                f"The motion's phase swings by ±{math.degrees(beta):.1f}° every {1 / f:.0f} s ({f:.4f} Hz; "
                f"the loading frequency wanders by ±{1e3 * beta * f:.2f} mHz), alike on plate(s) "
                f"{', '.join(map(str, plates))}: the actuator's controller hunts around its set frequency."
            ),
            detail={
                "kind": "sinusoidal",
                "phase_rad": psi,
                "frequency_excursion_hz": beta * f,
                "loglik_gain": {ctx.series[i].key: float(g) for i, g in gains.items()},
            },
        )


EFFECT = FrequencyModulation()
