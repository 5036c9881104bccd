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

Model: y += a_s u(t) cos(arg_s(t)), arg_s and a_s the series' nominal harmonic (or its current
motion when a phase modulation is already in the model: `current_motion`), u(t) = r (t − t_mid)
or m cos(2π f_m t + ψ) shared by all series (parameters counted once: 1 or 3); fitted by
Levenberg-Marquardt on all carrying series with each series' free nuisance profiled out. On a
tied series the term's part along the carrier is left out: the LDS's harmonic holds it
(`shared_fits.visible`). The series reported are those where the term is individually significant.
Scan and fit are shared with `frequency_modulation` (`_modulation.ModulationEffect`).
"""

from __future__ import annotations

import math

import jax.numpy as jnp

from ...effects.amplitude_modulation import ENTRY
from ._modulation import ModulationEffect
from .shared_fits import param

__all__ = ["AmplitudeModulation", "EFFECT"]


class AmplitudeModulation(ModulationEffect):
    id = ENTRY.id
    sensors, structural, needs_reference = ENTRY.sensors, ENTRY.structural, ENTRY.needs_reference
    meaning = (
        "the deflection amplitude changes during the record alike on every plate (fatigue, load controller)"
    )
    demodulation = "in_phase"
    trend = False
    depth_name = "depth"
    plausible = 1e-4  # linear kind: relative change per s (fatigue: 1e-5 to 1e-4 /s)

    @staticmethod
    def shape(t, half):
        return t - half

    @staticmethod
    def linear_term(theta, t, aux):
        return theta[0] * aux["a"] * aux["cos"] * (t - aux["half"])

    @staticmethod
    def sinusoidal_term(theta, t, aux):
        ph = 2 * jnp.pi * theta[2] * t
        return aux["a"] * aux["cos"] * (theta[0] * jnp.cos(ph) + theta[1] * jnp.sin(ph))

    def linear_report(self, ctx, r, sr, plates):
        change = r * ctx.duration_s
        return (
            {"relative_rate_per_s": param(r, sr)},
            [ctx.f0_hz - 1.0 / ctx.duration_s, ctx.f0_hz + 1.0 / ctx.duration_s],
            f"The deflection amplitude {'grows' if r > 0 else 'shrinks'} steadily by "
            f"{100 * abs(change):.1f} % over the record ({100 * 3600 * abs(r):.1f} ± "
            f"{100 * 3600 * sr:.1f} % per hour), alike on plate(s) {', '.join(map(str, plates))}: "
            "the beam softening under fatigue or the load controller drifting.",
            {"kind": "linear"},
        )

    def sinusoidal_text(self, theta, m, f, plates):
        return (
            f"The deflection amplitude swings by ±{100 * m:.1f} % every {1 / f:.0f} s "
            f"({f:.4f} Hz), alike on plate(s) {', '.join(map(str, plates))}: the load controller "
            "or the hydraulic supply modulates the load.",
            {"kind": "sinusoidal", "phase_rad": math.atan2(-theta[1], theta[0])},
        )


EFFECT = AmplitudeModulation()
