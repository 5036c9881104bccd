"""``mode_shape``: another bending mode of the beam, each plate moving in the mode's shape.

Physics: besides the motion the load imposes (one shape, the two-point-load deflection), the beam
vibrates in its own modes: the n-th bending mode of a simply supported span has the shape
sin(nπ x/L), x from a support, and its own frequency (a hammer blow, the actuator's pump or the
floor exciting it). The second mode is antisymmetric: the plates either side of mid-span move in
opposite directions, so the mode cancels in any sum over the plates, and a mid-span LDS (a node)
does not see it. Typical magnitudes: 0.01-0.5 mm at the antinode, 0.3 Hz to Nyquist (a mode far
above the frame rate aliases to its folded frequency).

Signature: the residuals' Fourier coefficients of the z series (normalised: unit power under
white noise, 2× zero-padded), combined with the weights C⁻¹v of a shape φ, v = φ_p/σ_p and C the
coefficients' covariance across the series (generalised least squares: noise shared by the plates
of a frame is not mistaken for the mode, and a shape's part it does not mimic counts at its full
precision; Exp(1) power over vᵀC⁻¹v under the null, whatever the signs across the plates), for
the shapes sin(nπ ξ),
n = 2, 3 (the modes whose plates move in opposition; a line in the first mode's shape, alike in
sign on every plate, is `extra_periodic`'s: one name for one shape), ξ = the plates' positions
along the span with the supports a gap g beyond the end plates (g on a grid of 0-80 % of the
plates' extent: the camera may see the middle of the span only; positions from the x series'
offsets, else equally spaced plates). Each shape's statistic is divided by its own running
median over the spectrum (coloured noise
and noise shared by the plates of a frame raise the null's level, a line does not), away from the
loading's harmonics and sidebands (`extra_periodic.line_band`); the peak's p-value is corrected
for the independent frequencies scanned and the shapes tried.

Model: y_p += φ_n(ξ_p) (a cos 2π f t + b sin 2π f t) on the z series, one (a, b) shared by all
plates (the mode's amplitude and phase), f refined on a fine grid about the matched peak, each
series' offset free: 4 parameters (f, a, b, g). One proposal per n; BIC chooses the mode, and
chooses between a mode (one amplitude in a known shape) and `extra_periodic` (a line common to
the plates, or free amplitudes per plate). The search scores the term by the generalised
least-squares statistic along it (`_correlation.gls_gain`), as the screen finds it. Reported:
``mode`` (n), ``freq_hz``, ``amplitude_mm`` (at the antinode), ``phase_rad`` (a cos(2π f t_rel +
ψ)); the shape per plate in the detail.
"""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np

from ..._numerics import harmonic_design
from ...effects.mode_shape import ENTRY
from .._base import Context, Detector, Proposal, State, loglik, masked_fourier
from .._correlation import floored_inverse
from .._varpro import fit_shared
from .extra_periodic import LOCAL_BINS, OVERSAMPLE, line_band, local_median
from .screening import param, scanned, shared_amplitude

__all__ = ["ModeShape", "EFFECT", "ORDERS", "GAPS", "plate_positions", "mode_shapes"]

ORDERS = (2, 3)  # the first mode's shape is the load's deflection shape: `extra_periodic`'s line
# Supports beyond the end plates, fraction of the plates' extent: up to 0.8 — a camera that sees
# the middle seven of thirteen plates has its supports 0.67 of the extent beyond the end ones.
GAPS = np.linspace(0.0, 0.8, 9)


def plate_positions(ctx: Context, idx: list[int]) -> np.ndarray:
    """(len(idx),) position along the beam of each series' plate: the offset of its x series
    (mm, camera frame), or its plate number when the table has no x."""
    xs = {s.plate: ctx.nominal[i].offset for i, s in enumerate(ctx.series) if s.axis == "x"}
    plates = [ctx.series[i].plate for i in idx]
    if all(p in xs for p in plates):
        return np.array([xs[p] for p in plates], float)
    return np.array(plates, float)


def mode_shapes(x: np.ndarray, n: int, gaps: np.ndarray = GAPS) -> np.ndarray:
    """(gap, plate) sin(nπ ξ), ξ = (x − x_min + g E)/(E (1 + 2 g)), E the plates' extent."""
    lo, ext = float(x.min()), max(float(x.max() - x.min()), 1e-9)
    g = np.asarray(gaps, float)[:, None]
    xi = (x[None, :] - lo + g * ext) / (ext * (1 + 2 * g))
    return np.sin(n * math.pi * xi)


def _term(theta, t, aux):
    """φ_n(ξ; g) (a cos 2π f t + b sin 2π f t), θ = (f, g, a, b); aux: u = (x − x_min)/E, n."""
    f, g, a, b = theta[0], theta[1], theta[2], theta[3]
    phi = jnp.sin(aux["n"] * jnp.pi * (aux["u"] + g) / (1.0 + 2.0 * g))
    arg = 2 * jnp.pi * f * t
    return phi * (a * jnp.cos(arg) + b * jnp.sin(arg))


def _weighted_residual(ctx: Context, states: list[State], i: int):
    """Series ``i``'s weights (inliers over their scale²), residual, weighted-mean-free residual
    and that residual's weighted variance."""
    s, st = ctx.series[i], states[i]
    w = np.where(st.inlier, 1.0 / st.scale**2, 0.0)
    r = s.y - st.mean
    rc = r - np.sum(w * r) / max(np.sum(w), 1e-300)
    s2 = float(np.sum(w * rc * rc)) / max(float(np.sum(w)), 1e-300) or 1e-300
    return w, r, rc, s2


class ModeShape(Detector):
    id = ENTRY.id
    sensors, structural, needs_reference = ENTRY.sensors, ENTRY.structural, ENTRY.needs_reference
    meaning = "another bending mode of the beam: every plate moving in the mode's shape sin(n pi x/L)"
    plausible, plausible_unit, gate_params = 0.1, "mm", 4  # 0.1 mm at the antinode
    min_plates = 3  # a shape across the plates

    def plausible_rms(self, ctx: Context, i: int) -> float:
        """The RMS of a plausible mode (0.1 mm at the antinode: a sin(nπξ) cos 2πft has an RMS of
        about a/2 over the plates and time), on the z series (the bending plane) only."""
        return self.plausible / 2 if ctx.series[i].axis == "z" else 0.0

    def gate_design_effect(self, ctx: Context, corr) -> float:
        """The smallest d of the shapes tried on the z series: in noise common to the frame an
        antisymmetric mode loses the common part (d ≈ 1 − ρ)."""
        idx = ctx.indices("z")
        if len(idx) < 2:
            return 1.0
        x = plate_positions(ctx, idx)
        return min(
            corr.design_effect(idx, dict(zip(idx, phi, strict=True)))
            for n in ORDERS
            for phi in mode_shapes(x, n)
        )

    def propose(self, ctx: Context, states: list[State]) -> list[Proposal]:
        idx = ctx.indices("z")
        if len({ctx.series[i].plate for i in idx}) < self.min_plates:
            return []
        coef, sd = [], []
        freq = None
        for i in idx:
            s, st = ctx.series[i], states[i]
            r = np.where(st.inlier, (s.y - st.mean) / st.scale, 0.0)
            freq, c = masked_fourier(ctx, i, r, OVERSAMPLE)
            coef.append(c)
            sd.append(float(np.std(r[st.inlier])) or 1.0)
        coef = np.stack(coef)  # (series, freq), unit noise power each
        allowed = line_band(ctx, freq)
        m_freq = int(allowed.sum()) // OVERSAMPLE
        if m_freq < LOCAL_BINS:
            return []
        x = plate_positions(ctx, idx)
        n_shapes = len(ORDERS) * len(GAPS)
        # the coefficients' covariance across the series (the noise shared by the plates of a
        # frame, and each series' level about the lines): the matched filter is whitened by it,
        # as the search scores a known pattern (`_correlation.gls_gain`)
        cs = coef[:, allowed]
        inv = floored_inverse(np.real(cs @ cs.conj().T) / max(cs.shape[1], 1))
        out = []
        for n in ORDERS:
            phi = mode_shapes(x, n)  # (gap, series)
            v = phi / np.asarray(sd)[None, :]  # matched weights φ/σ
            w = v @ inv  # generalised least squares: w = C⁻¹v, Exp(1) power over vᵀC⁻¹v
            stats = np.abs(w @ coef) ** 2 / np.maximum(np.sum(w * v, axis=1), 1e-300)[:, None]
            # the null's level (the noise's colour and its share common to the plates) depends on
            # the gap: a wide gap makes the third mode a hump alike in sign on the plates, which
            # frame-common noise fills, where a narrow one is not; one running median per shape
            best = None
            for gi in range(len(GAPS)):
                z = stats[gi] / (local_median(np.where(allowed, stats[gi], np.nan)) / math.log(2.0))
                j = int(np.argmax(np.where(allowed, z, -np.inf)))
                if best is None or z[j] > best[0]:
                    best = (float(z[j]), gi, j)
            z, gi, j = best
            # false-alarm probability of the largest of m_freq Exp(1) powers, shapes tried
            p = -math.expm1(m_freq * math.log1p(-math.exp(-z))) if z > 0 else 1.0
            p = min(1.0, n_shapes * p)
            prop = self._proposal(ctx, states, idx, n, float(GAPS[gi]), phi[gi], float(freq[j]), p, freq)
            prop = scanned(prop, m_freq * n_shapes, 1)  # frequencies × shapes; the frequency
            if prop is not None:
                out.append(prop)
        return out

    def _proposal(self, ctx, states, idx, n, gap, phi, f_peak, p_value, freq) -> Proposal | None:
        shape = dict(zip(idx, phi, strict=True))
        # the frequency on a fine grid about the peak: the matched sum's exact transform
        parts = []
        info = 0.0
        for i in idx:
            s = ctx.series[i]
            w, r, rc, s2 = _weighted_residual(ctx, states, i)
            parts.append((s.t, shape[i] * w * rc / s2))
            info += shape[i] ** 2 * float(np.sum(w)) / s2
        step = freq[1] - freq[0]
        grid = f_peak + np.linspace(-step, step, 21)
        power = [abs(sum(np.exp(-2j * np.pi * f * t) @ r for t, r in parts)) ** 2 for f in grid]
        f_hat = float(grid[int(np.argmax(power))])
        nus = {i: ctx.nuisance(i)[:, :1] for i in idx}  # the offset only: the line is far from f0

        def cols(i):
            return shape[i] * harmonic_design(2 * np.pi * f_hat * ctx.series[i].t, offset=False)

        fit = shared_amplitude(ctx, states, idx, cols, nus, self.id, k_own=0)
        if fit is None:
            return None
        a, b = (float(v) for v in fit.beta)
        g = fit.beta / max(math.hypot(a, b), 1e-300)
        amp_sig = math.sqrt(max(float(g @ fit.cov @ g), 0.0))
        amp = math.hypot(a, b)
        # Cramér-Rao σ_f of a sinusoid of amplitude amp seen with the information Σ φ² n/σ²
        sigma_f = math.sqrt(6.0 / max(info, 1e-300)) / (math.pi * ctx.duration_s * max(amp, 1e-300))
        prop = self._build(
            ctx, idx, n, gap, shape, fit.series, fit.states, (f_hat, sigma_f), (a, b), amp_sig, p_value
        )
        prop.refine = lambda: self._refine(ctx, states, idx, n, gap, f_hat, (a, b), amp_sig, p_value)
        return prop

    def _refine(self, ctx, states, idx, n, gap, f_hat, ab, amp_sig, p_value) -> Proposal | None:
        """f, g, a and b together by Levenberg-Marquardt (`fit_shared`: the term has no per-series
        amplitude), each series' offset free and its weights over its noise variance."""
        x = plate_positions(ctx, idx)
        lo, ext = float(x.min()), max(float(x.max() - x.min()), 1e-9)
        ts, rs, ws, nus = [], [], [], []
        for i in idx:
            s = ctx.series[i]
            w, r, rc, s2 = _weighted_residual(ctx, states, i)
            ts.append(s.t)
            rs.append(r)
            ws.append(w / s2)
            nus.append(ctx.nuisance(i)[:, :1])
        aux = {"u": list((x - lo) / ext), "n": [float(n)] * len(idx)}
        step = 1.0 / ctx.duration_s
        amp0 = max(math.hypot(*ab), 1e-6)
        fit = fit_shared(
            None,
            np.array([f_hat, gap, ab[0], ab[1]]),
            ts,
            rs,
            ws,
            nus,
            aux=aux,
            scale=np.array([0.1 * step, 0.02, 0.1 * amp0, 0.1 * amp0]),
            term_fn=_term,
            bounds=(
                np.array([f_hat - 2 * step, 0.0, -np.inf, -np.inf]),
                np.array([f_hat + 2 * step, float(GAPS[-1]), np.inf, np.inf]),
            ),
            known_scale=True,
        )
        if not fit.converged:
            return None
        f, g, a, b = (float(v) for v in fit.theta)
        shape = dict(zip(idx, mode_shapes(x, n, np.array([g]))[0], strict=True))
        new = {}
        for j, i in enumerate(idx):
            st = states[i]
            cand = st.with_(mean=st.mean + fit.term[j] + fit.fitted[j], effects=st.effects + (self.id,))
            if loglik(ctx.series[i].y, cand) > loglik(ctx.series[i].y, st):
                new[i] = cand
        if not new:
            return None
        cov = fit.theta_cov
        amp = math.hypot(a, b)
        gv = np.array([a, b]) / max(amp, 1e-300)
        amp_sig = math.sqrt(max(float(gv @ cov[2:, 2:] @ gv), 0.0))
        sigma_f = math.sqrt(max(float(cov[0, 0]), 0.0))
        return self._build(ctx, idx, n, g, shape, sorted(new), new, (f, sigma_f), (a, b), amp_sig, p_value)

    def _build(self, ctx, idx, n, gap, shape, series, new_states, f_sig, ab, amp_sig, p_value) -> Proposal:
        f_hat, sigma_f = f_sig
        a, b = ab
        amp = math.hypot(a, b)
        psi = -math.atan2(b, a)  # a cos(2π f t) + b sin(2π f t) = amp cos(2π f t + ψ)
        half = max(3 * sigma_f, 0.5 / ctx.duration_s)
        signs = np.sign([shape[i] for i in idx if abs(shape[i]) > 0.1])
        changes = int(np.count_nonzero(np.diff(signs)))
        plates = {str(ctx.series[i].plate): round(float(shape[i]), 4) for i in idx}
        return Proposal(
            effect=self.id,
            series=series,
            states=new_states,
            n_params=4,
            p_value=p_value,
            parameters={
                "mode": param(n, None),
                "freq_hz": param(f_hat, sigma_f),
                "amplitude_mm": param(amp, amp_sig),
                "phase_rad": param(psi, amp_sig / max(amp, 1e-300)),
            },
            t_start=0.0,
            t_end=float(ctx.duration_s),
            band_hz=[f_hat - half, f_hat + half],
            explanation=(
                f"The plates move at {f_hat:.4f} Hz ({f_hat / ctx.f0_hz:.3f} × the loading frequency) "
                f"in the shape of the beam's bending mode {n} (sin({n}πx/L)), {amp:.3f} mm at the "
                "antinode"
                + (
                    f": the plates either side of {'the node' if changes == 1 else 'its nodes'} move in "
                    "opposite directions"
                    if changes
                    else ""
                )
                + ". A vibration mode of the beam that the nominal model (one motion in the load's "
                "shape) leaves out."
            ),
            detail={"support_gap": gap, "shape": plates, "sign_changes": changes},
            shape={i: float(shape[i]) for i in series},
        )


EFFECT = ModeShape()
