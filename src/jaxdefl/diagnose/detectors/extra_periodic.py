"""``extra_periodic``: a vibration at a frequency unrelated to the loading, common to the plates.

Physics: a pump of the hydraulic actuator, the camera mount or the floor vibrate at their own
frequency; the camera sees the whole scene move, so every plate carries the same line (the
amplitude may differ by plate and axis). Typical magnitudes: 0.01–0.5 mm, 0.3 Hz to Nyquist.

Signature: away from the loading frequency, its harmonics and their modulation sidebands (those
belong to other effects), two statistics per axis on the residuals' Fourier coefficients
(normalised: unit power under white noise, 2× zero-padded): their powers summed over the m
series (Gamma(m, 1) under the null: a line of any phase per series) and the power of their sum
over m (Exp(1): a line in phase on every series, the scene moving as one body — what finds a
line below every series' own noise). Each statistic is divided by its running median over the
spectrum (the null's level: coloured noise, and noise shared by the plates of a frame, which
inflates the coherent sum by the design effect, raise it; a line does not), and the peak's
p-value is corrected for the independent frequencies scanned (≈ 2 ln n in evidence), the two
statistics and the three axes.

Model: y += a_s cos(2π f t) + b_s sin(2π f t), f shared by all series, (a_s, b_s) per series;
f refined by variable projection (optimistix Levenberg-Marquardt). Series whose own evidence
does not pay for their two amplitudes are left out of the proposal. Common mode, per axis:
(a, b) shared by the axis' series, f refined on a fine grid about the coherent peak (the exact
transform), 3 parameters. Reported ``amplitude_mm``:
the median amplitude over the z series carrying the line (over the axis with most series when
no z series does); the other axes' medians are in the detail.
"""

from __future__ import annotations

import math
import warnings

import jax.numpy as jnp
import numpy as np
from scipy import stats

from ..._numerics import harmonic_design
from ...effects.extra_periodic import ENTRY
from .._base import (
    Context,
    Detector,
    Proposal,
    State,
    keep_series,
    loglik,
    masked_fourier,
    peak_offset,
    regress_offset,
)
from .._varpro import fit_shared
from .screening import shared_amplitude, subset_trials

__all__ = ["ExtraPeriodic", "EFFECT", "local_median", "line_band", "OVERSAMPLE", "LOCAL_BINS"]

HARMONICS = 6  # k·f0 bands excluded: k = 0 (drift), 1..6 (loading, distortion)
SIDEBAND_HZ = 0.06  # half-width of the excluded band around each k·f0
OVERSAMPLE = 2  # zero-padding of the spectra: a line between Fourier frequencies loses ≤ 19 %, not 59 %
LOCAL_BINS = 201  # running-median window (frequency bins) of the spectra's null level


def local_median(x: np.ndarray, width: int = LOCAL_BINS) -> np.ndarray:
    """Running median of ``x`` over ``width`` bins, NaNs (excluded bins) ignored; the global
    median where a window holds too few values. The null level changes slowly along the
    spectrum: the median is taken every width/32 bins and interpolated between (a 20-minute
    record's spectrum has ~10⁵ bins, and a window's median per bin cost seconds)."""
    n = x.size
    pad = width // 2
    step = max(1, width // 32)
    xp = np.concatenate([np.full(pad, np.nan), x, np.full(pad, np.nan)])
    win = np.lib.stride_tricks.sliding_window_view(xp, width)
    at = np.unique(np.r_[np.arange(0, n, step), n - 1])
    with warnings.catch_warnings():  # all-NaN windows (excluded bands): the global median
        warnings.simplefilter("ignore", RuntimeWarning)
        med = np.nanmedian(win[at], axis=1)
    count = np.sum(np.isfinite(win[at]), axis=1)
    glob = np.nanmedian(x)
    level = np.where((count >= width // 4) & np.isfinite(med), med, glob)
    return np.interp(np.arange(n), at, level)


def line_band(ctx: Context, freq: np.ndarray) -> np.ndarray:
    """(freq,) True where a line unrelated to the loading may be: away from k·f0 (k = 0..6, with
    their modulation sidebands) and their aliases below Nyquist, and from Nyquist itself."""
    excl = np.zeros(freq.size, bool)
    half = max(SIDEBAND_HZ, 3.0 / max(ctx.duration_s, 1e-9))
    fs = 1.0 / ctx.dt_s
    for k in range(HARMONICS + 1):
        for alias in (k * ctx.f0_hz, fs - k * ctx.f0_hz):  # k·f0 and its alias below Nyquist
            excl |= np.abs(freq - alias) < half
    excl |= np.abs(freq - fs / 2) < half
    return ~excl


def _columns(theta, t, aux):
    a = 2 * jnp.pi * theta[0] * t
    return jnp.stack([jnp.cos(a), jnp.sin(a)], axis=1)


class ExtraPeriodic(Detector):
    id = ENTRY.id
    sensors, structural, needs_reference = ENTRY.sensors, ENTRY.structural, ENTRY.needs_reference
    meaning = "a vibration at a frequency unrelated to the loading (pump, mount, floor), common to the plates"
    plausible, plausible_unit, gate_params = 0.05, "mm", 3  # a 0.05-mm vibration (pump, mount)
    min_plates = 2  # "common to the plates" cannot be told on one

    def propose(self, ctx: Context, states: list[State]) -> list[Proposal]:
        freq = None
        spectra = {}
        for i, s in enumerate(ctx.series):
            st = states[i]
            r = np.where(st.inlier, (s.y - st.mean) / st.scale, 0.0)
            freq, spectra[i] = masked_fourier(ctx, i, r, OVERSAMPLE)
        allowed = line_band(ctx, freq)
        m_freq = int(allowed.sum()) // OVERSAMPLE  # independent frequencies scanned
        if m_freq < LOCAL_BINS:
            return []
        best = None
        lines = []
        for axis in ("z", "x", "y"):
            idx = ctx.indices(axis)
            if not idx:
                continue
            coef = np.stack([spectra[i] for i in idx])  # (series, freq) complex, unit noise power
            total = np.sum(np.abs(coef) ** 2, axis=0)
            coherent = np.abs(coef.sum(axis=0)) ** 2 / len(idx)
            for kind, stat, null in (
                ("incoherent", total, stats.gamma(len(idx))),
                ("coherent", coherent, stats.expon()),
            ):
                if kind == "coherent" and len(idx) < 2:
                    continue
                # the null's scale from the spectrum itself about each frequency (running median):
                # coloured noise and noise shared by the plates of a frame (which inflates the
                # coherent sum by the design effect) raise it, a line does not
                level = local_median(np.where(allowed, stat, np.nan)) / null.median()
                z = stat / level
                j = int(np.argmax(np.where(allowed, z, -np.inf)))
                logp = float(null.logsf(z[j]))
                # false-alarm probability of the largest of m_freq statistics; two statistics of
                # three axes scanned
                p = 1.0 if logp > 0 else -math.expm1(m_freq * math.log1p(-math.exp(logp)))
                p = min(1.0, 6 * p)
                jj = min(max(j, 1), freq.size - 2)
                off = peak_offset(stat[jj - 1], stat[jj], stat[jj + 1])
                f_peak = freq[jj] + off * (freq[1] - freq[0])
                if kind == "coherent":
                    lines.append((p, axis, idx, f_peak, 6 * m_freq))
                if best is None or p < best[0]:
                    best = (p, f_peak)
        out = [q for q in (self._common(ctx, states, *line) for line in lines) if q is not None]
        p_value, f_peak = best

        # Screen: a linear fit of the line at the grid peak on every series; keep the series
        # where it pays for its two amplitudes.
        fits = {}
        for i, s in enumerate(ctx.series):
            cols = harmonic_design(2 * np.pi * f_peak * s.t, offset=False)
            beta, cov, mean = regress_offset(ctx, i, states[i], s.y, cols)
            gain = loglik(s.y, states[i], mean) - loglik(s.y, states[i])
            if keep_series(gain, 2, s.n, margin=6.0):
                fits[i] = (beta, cov, mean)
        if not fits:
            return out
        kept = sorted(fits)
        trials = 6 * m_freq * subset_trials(len(kept), len(ctx.series))
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
            trials,
        )
        prop.refine = lambda: self._refine(ctx, states, kept, f_peak, p_value, trials)
        return out + [prop]

    def _common(self, ctx, states, p_value, axis, idx, f_peak, trials) -> Proposal | None:
        """The line with one cosine and one sine amplitude shared by the series of an axis (the
        scene moves as one body: 3 parameters, against 1 + 2 S for amplitudes per series).
        The frequency is refined on a fine grid about the periodogram's peak (the coherent sum's
        maximum); the amplitudes by weighted least squares with each series' offset free."""
        rs = {}
        for i in idx:
            s, st = ctx.series[i], states[i]
            w = np.where(st.inlier, 1.0 / st.scale**2, 0.0)
            r = s.y - st.mean
            rc = r - np.sum(w * r) / max(np.sum(w), 1e-300)
            sw = float(np.sum(w))
            rs[i] = (s.t, w * rc, sw * sw / max(float(np.sum(w * rc * rc)), 1e-300))  # Σw / σ̂²
        step = 1.0 / (ctx.n_frames * ctx.dt_s)
        grid = f_peak + np.linspace(-step, step, 21)

        def power(f):
            c = sum(np.exp(-2j * np.pi * f[:, None] * t[None, :]) @ r for t, r, _ in rs.values())
            return np.abs(c) ** 2

        f_hat = float(grid[int(np.argmax(power(grid)))])
        nus = {i: ctx.nuisance(i)[:, :1] for i in idx}  # the offset only: the line is far from f0

        def cols(i):
            return harmonic_design(2 * np.pi * f_hat * ctx.series[i].t, offset=False)

        fit = shared_amplitude(ctx, states, idx, cols, nus, self.id, k_own=0)
        if fit is None:
            return None
        amp = float(np.hypot(*fit.beta))
        g = fit.beta / max(amp, 1e-300)
        amp_sig = math.sqrt(max(float(g @ fit.cov @ g), 0.0))
        # σ_f of a line of amplitude a in noise of total information I = Σ n/σ²:
        # √6 / (π T a √I) (the Cramér-Rao bound of a sinusoid's frequency), I = Σ n/σ̂²
        info = sum(rs[i][2] for i in fit.series)
        sigma_f = math.sqrt(6.0 / max(info, 1e-300)) / (math.pi * ctx.duration_s * max(amp, 1e-300))
        half = max(3 * sigma_f, 0.5 / ctx.duration_s)
        keys = [ctx.series[i].key for i in fit.series]
        where = f"{len(keys)} series" if len(keys) > 3 else ", ".join(keys)
        return _line_proposal(
            ctx, fit.series, fit.states, 3, p_value, f_hat, sigma_f, half, (amp, amp_sig),
            f"moves {where} alike by about {amp:.3f} mm along {axis}",
            {"mode": "common", "amplitude_axis": axis},
            trials,
        )

    def _refine(self, ctx, states, kept, f_peak, p_value, trials) -> Proposal | None:
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
            ctx, states, kept, float(fit.theta[0]), sigma_f, fit.beta_cov, fit.beta, means, p_value, trials
        )

    def _proposal(self, ctx, states, kept, f_hat, sigma_f, covs, betas, means, p_value, trials) -> Proposal:
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
        return _line_proposal(
            ctx, list(kept), new_states, 1 + 2 * len(kept), p_value, f_hat,
            sigma_f if np.isfinite(sigma_f) else None, half, (amp_med, amp_sig_med),
            f"moves {len(plates)} plate(s) by about {amp_med:.3f} mm along {main}",
            {
                "amplitudes_mm": {ctx.series[i].key: float(a) for i, a in zip(kept, amps, strict=True)},
                "median_amplitude_by_axis_mm": {ax: float(np.median(v)) for ax, v in by_axis.items()},
                "amplitude_axis": main,
            },
            trials,
        )


EFFECT = ExtraPeriodic()


def _line_proposal(
    ctx: Context,
    series: list[int],
    states: list[State],
    n_params: int,
    p_value: float,
    f_hat: float,
    sigma_f: float | None,
    half: float,
    amplitude: tuple[float, float],
    moves: str,
    detail: dict,
    trials: float,
) -> Proposal:
    """An extra line's proposal over the whole record: frequency and amplitude with σ's, the band
    f ± ``half`` and its explanation (``moves`` says what moves how much)."""
    return Proposal(
        effect=ExtraPeriodic.id,
        series=series,
        states=states,
        n_params=n_params,
        p_value=p_value,
        parameters={
            "freq_hz": {"value": f_hat, "sigma": sigma_f},
            "amplitude_mm": {"value": amplitude[0], "sigma": amplitude[1]},
        },
        t_start=0.0,
        t_end=ctx.duration_s,
        band_hz=[f_hat - half, f_hat + half],
        explanation=(
            f"A periodic motion at {f_hat:.4f} Hz ({f_hat / ctx.f0_hz:.3f} × the loading frequency, "
            f"not one of its harmonics) {moves}: a vibration of the pump, the camera mount or the "
            "floor that the nominal model leaves out."
        ),
        detail=detail,
        trials=trials,  # frequencies × statistics × axes (× series picked)
        scan_params=1,  # the frequency
    )
