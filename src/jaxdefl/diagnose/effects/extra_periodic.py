"""``extra_periodic``: a vibration at a frequency unrelated to the loading, common to the plates.

Physics: a pump of the hydraulic actuator, the camera mount or the floor vibrate at their own
frequency; the camera sees the whole scene move, so every plate carries the same line (the
amplitude may differ by plate and axis). Typical magnitudes: 0.01–0.5 mm, 0.3 Hz to Nyquist.

Signature: the residual periodograms (normalised, Exp(1) under white noise) summed over the
series of an axis, away from the loading frequency, its harmonics and their modulation
sidebands (those belong to other effects); the sum of m series is Gamma(m, 1) under the null and
the peak's p-value is corrected for the number of frequencies scanned.

Model: y += a_s cos(2π f t) + b_s sin(2π f t), f shared by all series, (a_s, b_s) per series;
f refined by variable projection (optimistix Levenberg-Marquardt). Series whose own evidence
does not pay for their two amplitudes are left out of the proposal. Reported ``amplitude_mm``:
the median amplitude over the z series carrying the line (over the axis with most series when
no z series does); the other axes' medians are in the detail.
"""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np
from scipy import stats

from .._base import (
    Context,
    Effect,
    Proposal,
    State,
    keep_series,
    loglik,
    masked_periodogram,
    peak_offset,
    regress_offset,
)
from .._varpro import fit_shared

__all__ = ["ExtraPeriodic", "EFFECT"]

HARMONICS = 6  # k·f0 bands excluded: k = 0 (drift), 1..6 (loading, distortion)
SIDEBAND_HZ = 0.06  # half-width of the excluded band around each k·f0


def _columns(theta, t, aux):
    a = 2 * jnp.pi * theta[0] * t
    return jnp.stack([jnp.cos(a), jnp.sin(a)], axis=1)


class ExtraPeriodic(Effect):
    id = "extra_periodic"
    meaning = "a vibration at a frequency unrelated to the loading (pump, mount, floor), common to the plates"
    plausible, plausible_unit, gate_params = 0.05, "mm", 3  # a 0.05-mm vibration (pump, mount)
    min_plates = 2  # "common to the plates" cannot be told on one

    def propose(self, ctx: Context, states: list[State]) -> list[Proposal]:
        freq = None
        spectra = {}
        for i, s in enumerate(ctx.series):
            st = states[i]
            r = np.where(st.inlier, (s.y - st.mean) / st.scale, 0.0)
            freq, spectra[i] = masked_periodogram(ctx, i, r)
        excl = np.zeros(freq.size, bool)
        half = max(SIDEBAND_HZ, 3.0 / max(ctx.duration_s, 1e-9))
        fs = 1.0 / ctx.dt_s
        for k in range(HARMONICS + 1):
            for alias in (k * ctx.f0_hz, fs - k * ctx.f0_hz):  # k·f0 and its alias below Nyquist
                excl |= np.abs(freq - alias) < half
        excl |= np.abs(freq - fs / 2) < half
        allowed = ~excl
        m_freq = int(allowed.sum())
        if m_freq < 3:
            return []
        best = None
        for axis in ("z", "x", "y"):
            idx = ctx.indices(axis)
            if not idx:
                continue
            total = np.sum([spectra[i] for i in idx], axis=0)
            j = int(np.argmax(np.where(allowed, total, -np.inf)))
            logp = float(stats.gamma.logsf(total[j], len(idx)))
            # false-alarm probability of the largest of m_freq sums, three axes scanned
            p = 1.0 if logp > 0 else -math.expm1(m_freq * math.log1p(-math.exp(logp)))
            p = min(1.0, 3 * p)
            if best is None or p < best[0]:
                j = min(max(j, 1), freq.size - 2)
                off = peak_offset(total[j - 1], total[j], total[j + 1])
                best = (p, freq[j] + off * (freq[1] - freq[0]))
        p_value, f_peak = best

        # Screen: a linear fit of the line at the grid peak on every series; keep the series
        # where it pays for its two amplitudes.
        fits = {}
        for i, s in enumerate(ctx.series):
            a = 2 * np.pi * f_peak * s.t
            beta, cov, mean = regress_offset(ctx, i, states[i], s.y, np.stack([np.cos(a), np.sin(a)], axis=1))
            gain = loglik(s.y, states[i], mean) - loglik(s.y, states[i])
            if keep_series(gain, 2, s.n, margin=6.0):
                fits[i] = (beta, cov, mean)
        if not fits:
            return []
        kept = sorted(fits)
        prop = self._proposal(
            ctx,
            states,
            kept,
            f_peak,
            float("nan"),
            [fits[i][1] for i in kept],
            [fits[i][0] for i in kept],
            [fits[i][2] for i in kept],
            p_value,
        )
        prop.refine = lambda: self._refine(ctx, states, kept, f_peak, p_value)
        return [prop]

    def _refine(self, ctx, states, kept, f_peak, p_value) -> Proposal | None:
        ts, rs, ws, nus = [], [], [], []
        for i in kept:
            s, st = ctx.series[i], states[i]
            ts.append(s.t)
            rs.append(s.y - st.mean)
            ws.append(np.where(st.inlier, 1.0 / st.scale**2, 0.0))
            nus.append(ctx.nuisance(i)[:, :1])  # the offset only: the line is far from f0
        fit = fit_shared(
            _columns, np.array([f_peak]), ts, rs, ws, nus, scale=np.array([1.0 / ctx.duration_s])
        )
        if not fit.converged or abs(fit.theta[0] - f_peak) > 2.0 / ctx.duration_s:
            return None
        sigma_f = float(math.sqrt(max(fit.theta_cov[0, 0], 0.0)))
        means = [states[i].mean + fit.fitted[j] for j, i in enumerate(kept)]
        return self._proposal(
            ctx, states, kept, float(fit.theta[0]), sigma_f, fit.beta_cov, fit.beta, means, p_value
        )

    def _proposal(self, ctx, states, kept, f_hat, sigma_f, covs, betas, means, p_value) -> Proposal:
        new_states = {}
        amps, amp_sig = [], []
        for j, i in enumerate(kept):
            new_states[i] = states[i].with_(
                mean=means[j],
                n_params=states[i].n_params + 2,
                effects=states[i].effects + (self.id,),
            )
            a, b = betas[j][:2]
            amp = math.hypot(a, b)
            amps.append(amp)
            g = np.array([a, b]) / max(amp, 1e-300)
            amp_sig.append(math.sqrt(max(g @ np.asarray(covs[j])[:2, :2] @ g, 0.0)))
        plates = sorted({ctx.series[i].plate for i in kept})
        # one amplitude per axis: a vibration moves the scene more along some axes than others, so
        # a median over mixed axes describes none of them; reported: the depth axis's (the one the
        # camera measures best), or the axis with most series carrying the line
        axes = [ctx.series[i].axis for i in kept]
        by_axis = {ax: [a for a, x in zip(amps, axes, strict=True) if x == ax] for ax in sorted(set(axes))}
        main = "z" if "z" in by_axis else max(by_axis, key=lambda ax: len(by_axis[ax]))
        on_main = [x == main for x in axes]
        amp_med = float(np.median(np.asarray(amps)[on_main]))
        amp_sig_med = float(np.median(np.asarray(amp_sig)[on_main]))
        half = max(3 * sigma_f, 0.5 / ctx.duration_s) if np.isfinite(sigma_f) else 1.0 / ctx.duration_s
        return Proposal(
            effect=self.id,
            series=list(kept),
            states=new_states,
            n_params=1 + 2 * len(kept),
            p_value=p_value,
            parameters={
                "freq_hz": {"value": f_hat, "sigma": sigma_f if np.isfinite(sigma_f) else None},
                "amplitude_mm": {"value": amp_med, "sigma": amp_sig_med},
            },
            t_start=0.0,
            t_end=ctx.duration_s,
            band_hz=[f_hat - half, f_hat + half],
            explanation=(
                f"A periodic motion at {f_hat:.4f} Hz ({f_hat / ctx.f0_hz:.3f} × the loading frequency, "
                f"not one of its harmonics) moves {len(plates)} plate(s) by about {amp_med:.3f} mm along "
                f"{main}: a "
                "vibration of the pump, the camera mount or the floor that the nominal model leaves out."
            ),
            detail={
                "amplitudes_mm": {ctx.series[i].key: float(a) for i, a in zip(kept, amps, strict=True)},
                "median_amplitude_by_axis_mm": {ax: float(np.median(v)) for ax, v in by_axis.items()},
                "amplitude_axis": main,
            },
        )


EFFECT = ExtraPeriodic()
