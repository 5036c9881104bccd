"""The shared scan and fit of `amplitude_modulation` and `frequency_modulation`.

Both are a slow shared function u(t) acting on the loading motion of every carrying series; they
differ in the demodulation that sees it (in phase for the amplitude, quadrature for the phase),
in the model term and in what is reported. `ModulationEffect` holds what is common: the linear
kind's χ²₁ test and the sinusoidal kind's scan of the combined demodulated spectrum between
2/duration and 0.2 Hz (each doubled for the two kinds tried), the rejection of a line on one side
of f0 (`extra_periodic`), the optimistix fit over all carriers (`Carriers.fit`) and the
selection of the series that keep the term. Subclasses give the terms and the reports.
"""

from __future__ import annotations

import abc
import math

import numpy as np

from ..._numerics import P_MAX
from ...effects._entry import MODULATION_MIN_CYCLES
from .._base import Context, Detector, Proposal, State
from .shared_fits import Carriers, chi2_p_value, one_sided, param, scan_p_value

__all__ = ["ModulationEffect", "modulation_band", "KINDS"]

F_MAX_HZ = 0.2
KINDS = 2


def modulation_band(ctx: Context) -> tuple[float, float]:
    """Modulation frequencies scanned: from `MODULATION_MIN_CYCLES` (2) cycles in the record to
    0.2 Hz (and well below f0)."""
    return MODULATION_MIN_CYCLES / ctx.duration_s, min(F_MAX_HZ, ctx.f0_hz / 4)


class ModulationEffect(Detector):
    """A shared slow modulation of the loading motion, linear or sinusoidal in time.

    Class attributes: ``demodulation`` ("in_phase" or "quadrature": the one that sees it; the
    other is its twin), ``trend`` (the scans also project a phase trend out of the tied series).
    """

    demodulation: str = ""
    trend: bool = False
    plausible_depth = 0.05  # the sinusoidal kind: relative depth (AM) or β in rad (FM)
    gate_params = 3

    def plausible_rms(self, ctx: Context, i: int) -> float:
        """The larger of the linear kind's term (``plausible`` × `linear_shape`) and, when the
        record spans the modulation band, the sinusoidal kind's (``plausible_depth``)."""
        u = self.linear_shape(ctx, np.linspace(0.0, ctx.duration_s, 257))
        lin = self.plausible * float(np.std(u))
        f_lo, f_hi = modulation_band(ctx)
        sin = self.plausible_depth / math.sqrt(2) if f_hi > f_lo else 0.0
        return ctx.nominal[i].amplitude / math.sqrt(2) * max(lin, sin)

    @property
    def twin(self) -> str:
        return "quadrature" if self.demodulation == "in_phase" else "in_phase"

    @staticmethod
    @abc.abstractmethod
    def shape(t, half):
        """u(t) of the linear kind per unit parameter, ``half`` = duration / 2 (numpy or jax)."""

    @staticmethod
    @abc.abstractmethod
    def linear_term(theta, t, aux):
        """The linear kind's term on one carrier (jax.numpy; `Carriers.fit`'s aux)."""

    @staticmethod
    @abc.abstractmethod
    def sinusoidal_term(theta, t, aux):
        """The sinusoidal kind's term, θ = (cosine, sine coefficient, f_m)."""

    def linear_shape(self, ctx: Context, t: np.ndarray) -> np.ndarray:
        return self.shape(t, 0.5 * ctx.duration_s)

    @abc.abstractmethod
    def linear_report(self, ctx: Context, value: float, sigma: float, plates: list[int]):
        """(parameters, band_hz, explanation, detail) of a fitted linear kind."""

    depth_name: str = ""  # the sinusoidal kind's depth parameter

    @abc.abstractmethod
    def sinusoidal_text(self, theta: np.ndarray, depth: float, f: float, plates: list[int]):
        """(explanation, detail) of a fitted sinusoidal kind of ``depth`` at ``f`` Hz."""

    def sinusoidal_report(self, ctx: Context, theta: np.ndarray, cov: np.ndarray, plates: list[int]):
        """(parameters, band_hz, explanation, detail) of a fitted sinusoidal kind: the depth
        √(a² + b²) of a cos + b sin and f_m with their σ's, the side lines at f0 ± f_m."""
        m = math.hypot(theta[0], theta[1])
        g = np.array([theta[0], theta[1]]) / max(m, 1e-300)
        sm = math.sqrt(max(float(g @ cov[:2, :2] @ g), 0.0))
        f, sf = float(theta[2]), math.sqrt(max(cov[2, 2], 0.0))
        parameters = {self.depth_name: param(m, sm), "freq_hz": param(f, sf)}
        return (parameters, [ctx.f0_hz - f, ctx.f0_hz + f], *self.sinusoidal_text(theta, m, f, plates))

    def propose(self, ctx: Context, states: list[State]) -> list[Proposal]:
        if self.cannot_tell(ctx) is not None:
            return []
        car = Carriers.cached(ctx, states)
        if not car.items:
            return []
        out = []
        stat, x0, sx = car.linear_stat(
            self.demodulation, lambda t: self.linear_shape(ctx, t), trend=self.trend
        )
        p_lin = min(1.0, KINDS * chi2_p_value(stat, 1))
        if p_lin < P_MAX:
            prop = self._linear(ctx, states, car, x0, sx, p_lin)
            if prop is not None:
                out.append(prop)
        f_lo, f_hi = modulation_band(ctx)
        if f_hi > f_lo:
            freq, power, n_ind, grid, q = car.scan(self.demodulation, f_lo, f_hi, trend=self.trend)
            if power.size:
                j = int(np.argmax(power))
                p_sin = min(1.0, KINDS * scan_p_value(power[j], n_ind))
                if p_sin < P_MAX:
                    df = freq[1] - freq[0] if freq.size > 1 else 1.0 / ctx.duration_s
                    f_pk, p_pk, n_pk = car.refine_peak(grid, q, float(freq[j]), df)
                    if one_sided(p_pk, car.power_at(self.twin, f_pk)):
                        return out  # a line on one side of f0 (extra_periodic), not a modulation
                    prop = self._sinusoidal(ctx, states, car, f_pk, n_pk, q, p_sin, n_ind)
                    if prop is not None:
                        out.append(prop)
        return out

    def _proposal(self, ctx, kept, new, gains, n_params, p_value, report, trials, scan_params=0) -> Proposal:
        parameters, band, explanation, detail = report
        detail["loglik_gain"] = {ctx.series[i].key: float(g) for i, g in gains.items()}
        return Proposal(
            effect=self.id,
            series=kept,
            states=new,
            n_params=n_params,
            p_value=p_value,
            parameters=parameters,
            t_start=0.0,
            t_end=ctx.duration_s,
            band_hz=band,
            explanation=explanation,
            detail=detail,
            trials=trials,
            scan_params=scan_params,
        )

    def _linear(self, ctx, states, car, x0, sx, p_value) -> Proposal | None:
        res = car.fit(self.linear_term, np.array([x0]), np.array([sx]))
        if not res.converged:
            return None
        kept, new, gains = car.proposal_states(states, res, self.id, 1)
        if not kept:
            return None
        plates = sorted({ctx.series[i].plate for i in kept})
        value, sigma = float(res.theta[0]), math.sqrt(max(res.cov[0, 0], 0.0))
        report = self.linear_report(ctx, value, sigma, plates)
        return self._proposal(ctx, kept, new, gains, 1, p_value, report, KINDS)

    def _sinusoidal(self, ctx, states, car, f_pk, n_pk, q, p_value, n_ind) -> Proposal | None:
        theta0 = np.array([2 * n_pk.real / q, -2 * n_pk.imag / q, f_pk])
        m0 = max(math.hypot(theta0[0], theta0[1]), 1e-12)  # steps: the depth, a tenth of 1/duration
        res = car.fit(self.sinusoidal_term, theta0, np.array([m0, m0, 0.1 / ctx.duration_s]))
        f_lo, f_hi = modulation_band(ctx)
        if not (res.converged and 0.5 * f_lo <= res.theta[2] <= 1.5 * f_hi):
            return None
        kept, new, gains = car.proposal_states(states, res, self.id, 3)
        if not kept:
            return None
        plates = sorted({ctx.series[i].plate for i in kept})
        report = self.sinusoidal_report(ctx, res.theta, res.cov, plates)
        # the modulation frequency was scanned over n_ind independent values
        return self._proposal(ctx, kept, new, gains, 3, p_value, report, KINDS * max(n_ind, 1.0), 1)
