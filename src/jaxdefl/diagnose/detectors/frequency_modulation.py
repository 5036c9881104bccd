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
series (1 or 3 parameters counted once), arg_s and a_s from the series' nominal harmonic, or
its current motion when an amplitude modulation is already in the model (`current_motion`);
Levenberg-Marquardt on the exact term with each series' free nuisance profiled out, started from
the demodulation's estimate. On a tied series the term's part along the carrier is left out:
the LDS's harmonic holds it (`shared_fits.visible`). The series reported are those where the term
is individually significant. Scan and fit are shared with `amplitude_modulation`
(`_modulation.ModulationEffect`).
"""

from __future__ import annotations

import math

import jax.numpy as jnp

from ...effects.frequency_modulation import ENTRY
from ._modulation import ModulationEffect
from .shared_fits import param

__all__ = ["FrequencyModulation", "EFFECT"]


class FrequencyModulation(ModulationEffect):
    id = ENTRY.id
    sensors, structural, needs_reference = ENTRY.sensors, ENTRY.structural, ENTRY.needs_reference
    meaning = "the loading frequency wanders or drifts during the record alike on every plate"
    demodulation = "quadrature"
    trend = True
    depth_name = "depth_rad"
    plausible = 3e-7  # linear kind: Hz/s of frequency drift

    @staticmethod
    def shape(t, half):
        """π ((t − t_mid)² − D²/12): the phase of a unit linear frequency drift, its mean removed."""
        return math.pi * ((t - half) ** 2 - half * half / 3.0)

    @staticmethod
    def linear_term(theta, t, aux):
        u = FrequencyModulation.shape(t, aux["half"])
        return aux["a"] * (jnp.cos(aux["arg"] + theta[0] * u) - aux["cos"])

    @staticmethod
    def sinusoidal_term(theta, t, aux):
        ph = 2 * jnp.pi * theta[2] * t
        arg = aux["arg"] + theta[0] * jnp.cos(ph) + theta[1] * jnp.sin(ph)
        return aux["a"] * (jnp.cos(arg) - aux["cos"])

    def linear_report(self, ctx, d, sd, plates):
        return (
            {"drift_hz_per_s": param(d, sd)},
            sorted([ctx.f0_hz - abs(d) * ctx.duration_s / 2, ctx.f0_hz + abs(d) * ctx.duration_s / 2]),
            f"The loading frequency {'rises' if d > 0 else 'falls'} steadily by "
            f"{1e3 * abs(d) * ctx.duration_s:.2f} mHz over the record ({d:.2e} ± {sd:.1e} Hz/s), "
            f"alike on plate(s) {', '.join(map(str, plates))}: the actuator's frequency drifts, "
            "so one frequency does not fit the whole record.",
            {"kind": "linear"},
        )

    def sinusoidal_text(self, theta, beta, f, plates):
        return (
            f"The motion's phase swings by ±{math.degrees(beta):.1f}° every {1 / f:.0f} s ({f:.4f} Hz; "
            f"the loading frequency wanders by ±{1e3 * beta * f:.2f} mHz), alike on plate(s) "
            f"{', '.join(map(str, plates))}: the actuator's controller hunts around its set frequency.",
            {
                "kind": "sinusoidal",
                "phase_rad": math.atan2(theta[0], theta[1]),
                "frequency_excursion_hz": beta * f,
            },
        )


EFFECT = FrequencyModulation()
