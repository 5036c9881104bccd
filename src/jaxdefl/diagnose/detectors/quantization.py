"""Quantization: the measured depth moves in steps (structured-light disparity quantisation).

Physical meaning: a structured-light camera measures disparity in fractions of a pixel (1/8 px on
a Kinect), so depth comes in steps that grow as z² (Δz = z² Δd / (b f): about 1 mm at 1 m and
4-10 mm at 2-3 m for single pixels). Each pixel's reading is noisy *before* it is rounded: pixel i
of a plate at depth z reads o + q·round((z + e_i − o)/q), e_i ~ N(0, σ_d²) (σ_d the pixel noise
before rounding, the "dither"). The plate's centroid averages its pixels, so its mean is the
dither-smoothed staircase (`jaxdefl._lattice.smoothed_staircase`)

    m(h) = o + q·E[round((h − o)/q + (σ_d/q) Z)],  Z ~ N(0, 1),

and its residual against a smooth model is a smoothed sawtooth of the position,
m(h) − h = −q Σ_k (−1)^(k+1) exp(−2π²k²σ_d²/q²) sin(2πk (h − o)/q)/(πk): the hard staircase
−q·saw((h − o)/q) for σ_d = 0, washed out as σ_d grows (the first harmonic by
exp(−2π²σ_d²/q²): 45 % at σ_d = 0.2 q, 0.7 % at 0.5 q). The rounding also shapes the noise: a
rounded reading's variance q² Var[round(x + (σ_d/q) Z)] (`dithered_round_var`) is small next to a
level and largest halfway between two (for σ_d = 0.2 q: 0.02 q² against 0.25 q²), the centroid's
that over P pixels; once σ_d ≳ q/2 it is flat, ≈ σ_d² + q²/12.

Signature test: the residual binned by the current model value h (z series, whatever the
``--sensor`` hint says: the data decide — a ToF camera's range comes in steps too, and a wrong
hint must not hide a staircase), then for every step q of a grid uniform in 1/q (the "frequency"
along h, spaced a quarter of a cycle over the motion's span) the first harmonic of the sawtooth,
cos and sin of 2π h/q, is regressed on the binned residual with the offset and h itself free (the
harmonic's cosine is a function of h): a χ²_2 statistic per series, summed over the series for a
common step. The first harmonic is there whatever the dither (only its size changes), so the
screen finds hard and smoothed staircases alike. The p-value is the largest single-series
statistic Bonferroni-corrected over series × the grid, or the summed statistic (χ²_2S) corrected
over the grid, whichever is smaller (doubled). Then q, the dither and the staircase's phase are
refined on the smoothed staircase: the likelihood of y against staircase(h, q, φ_s, σ_d) (no free
amplitude: the dither sets the steps' size), on a grid of q × phase × σ_d/q (0-0.5), then by
Gauss-Newton on q, σ_d and the nuisance together (`_joint`). The phase is free per series because
the nominal offset is itself biased by the quantisation; the camera's levels o_s = φ_s + c_s (c_s
the refitted offset) come out alike on every plate when the levels are the camera's (reported:
their circular mean).

Model term: mean = staircase(h', q, φ_s, σ_d) + c_s, h' the current model with its free nuisance
refitted inside the rounding (`_inside`: the nominal harmonic fitted to a staircase is biased),
c_s the offset; noise scale × √((1 − λ) + λ v(h')/v̄), v the rounded reading's variance profile
and λ the share of the noise that is the pixels' before rounding (a grid 0-1 by likelihood; the
rest is taken as added after the rounding); q, σ_d and λ shared, φ_s per series (3 + S
parameters; 2 + S at σ_d = 0). q and σ_d are fitted on the series whose motion spans more than
a step (q < 2A); the others read the same lattice, their phase and nuisance fitted from searched
starts (`_phase`: the rounding flattens their nominal harmonic; a part of a step is a smooth
function of h, harmonics of f0 if left alone). One lattice per record: once accepted, no second
step is proposed.
Parameters: ``step_mm`` (q), ``offset_mm`` (the levels' circular mean, mod q), ``dither_mm``
(σ_d: the noise of a pixel before rounding, which is the centroid's noise times about √(pixels)
when the pixels' noises are independent), ``rounded_noise_share`` (λ).

Plausible magnitudes: q of 0.3-20 mm for structured light; σ_d from 0 to q/2 (beyond, the steps
are gone); the term's residual RMS is q/√12 for σ_d = 0 and ≈ q exp(−2π²σ_d²/q²)/(π√2) above
σ_d ≈ 0.2 q.
"""

from __future__ import annotations

import math

import numpy as np

from ..._lattice import dithered_round, dithered_round_var
from ..._lattice import smoothed_staircase as staircase  # the mean reading (dither 0: hard steps)
from ..._numerics import P_MAX, wls
from ...effects.quantization import ENTRY
from .._base import Context, Detector, Proposal, State, keep_series
from ..record_kind import value_lattice
from .screening import bonferroni, chi2_sf, gain, param, residual, touched, updated, weights

__all__ = ["Quantization", "EFFECT"]

Q_MIN_MM = 0.1
Q_MAX_MM = 20.0
BINS_PER_STEP = 16
N_OFFSET = 48
N_REFINE = 17
N_INSIDE = 12
N_OUTER = 3
DITHERS = tuple(np.round(np.linspace(0.0, 0.5, 11), 3))  # the grid of σ_d / q
N_TABLE = 512  # samples of a smoothed sawtooth's period (the grid's lookup)
GAINS = (1.0, 1.5, 2.0, 2.5, 3.0)  # starts of a short motion's amplitude (`_phase`)
SHARES = (0.0, 0.25, 0.5, 0.75, 1.0)  # the grid of the noise's share that is rounded pixel noise


def saw(x: np.ndarray) -> np.ndarray:
    return x - np.round(x)


class _Saws:
    """The smoothed sawtooths x − E[round(x + sZ)] of the grid's s = σ_d/q, tabulated over one
    period (linear interpolation: within ~1e-4 q for s >= 0.05; s = 0 is the exact sawtooth)."""

    def __init__(self, dithers):
        self.dithers = tuple(float(v) for v in dithers)
        self.u = np.linspace(0.0, 1.0, N_TABLE + 1)
        self.tables = [self.u - dithered_round(self.u, s) for s in self.dithers]

    def __call__(self, x: np.ndarray) -> np.ndarray:
        """(dither, *x.shape) smoothed sawtooths at x."""
        frac = x - np.floor(x)
        out = np.empty((len(self.dithers), *x.shape))
        for k, (s, tab) in enumerate(zip(self.dithers, self.tables, strict=True)):
            out[k] = saw(x) if s == 0.0 else np.interp(frac, self.u, tab)
        return out


class _Binned:
    """A series' weighted residual binned by the model value h (bin width ``width``)."""

    def __init__(self, h: np.ndarray, r: np.ndarray, w: np.ndarray, width: float):
        self.width = width
        lo = float(h.min())
        b = np.floor((h - lo) / width).astype(np.int64)
        m = int(b.max()) + 1
        self.W = np.bincount(b, w, minlength=m)
        self.R = np.bincount(b, w * r, minlength=m)
        hw = np.bincount(b, w * h, minlength=m)
        ok = self.W > 0
        self.H = hw[ok] / self.W[ok]
        self.W, self.R = self.W[ok], self.R[ok]
        nu = np.stack([np.ones_like(self.H), self.H - self.H.mean()], axis=1)
        gram = (nu * self.W[:, None]).T @ nu
        self._nu, self._ginv = nu, np.linalg.pinv(gram)
        # the residual with offset and h removed (sums of w r per bin)
        coef = self._ginv @ (nu.T @ self.R)
        self.R0 = self.R - self.W * (nu @ coef)
        n_used = max(int((w > 0).sum()) - 3, 1)
        self.s2 = float(np.sum(w * r * r) - self.R @ (nu @ coef)) / n_used or 1e-300

    def project(self, cols: np.ndarray) -> np.ndarray:
        """(c, bin) columns W-orthogonal to offset and h."""
        coef = (cols * self.W[None, :]) @ self._nu @ self._ginv
        return cols - coef @ self._nu.T

    def first_harmonic(self, nu_inv_mm: np.ndarray) -> np.ndarray:
        """(freq,) χ²_2 statistic of cos, sin(2π ν h) against the binned residual."""
        a = 2 * np.pi * nu_inv_mm[:, None] * self.H[None, :]
        c = self.project(np.cos(a))
        s = self.project(np.sin(a))
        cw, sw = c * self.W, s * self.W
        gcc = np.sum(cw * c, axis=1)
        gss = np.sum(sw * s, axis=1)
        gcs = np.sum(cw * s, axis=1)
        bc = c @ self.R0
        bs = s @ self.R0
        det = np.maximum(gcc * gss - gcs * gcs, 1e-300)
        quad = (gss * bc * bc - 2 * gcs * bc * bs + gcc * bs * bs) / det
        return quad / self.s2

    def staircase_gain(self, q: float, o: np.ndarray, saws: _Saws) -> np.ndarray:
        """(o, dither) twice the log-likelihood gain (≈ −ΔRSS/σ̂²) of the smoothed staircase of
        step q, levels o and σ_d/q = ``saws.dithers``, binned."""
        x = (self.H[None, :] - o[:, None]) / q
        d = -q * saws(x)  # (dither, o, bin): staircase − h
        flat = d.reshape(-1, self.H.size)
        dp = self.project(flat)
        # RSS(r − d⊥) − RSS(r) = −2 d⊥·R0 + Σ W d⊥²
        drss = -2 * dp @ self.R0 + np.sum(self.W * dp * dp, axis=1)
        return (-drss / self.s2).reshape(len(saws.dithers), o.size).T


def _inside(
    ctx: Context, i: int, st: State, h: np.ndarray, q: float, phi: float, dither: float
) -> tuple[np.ndarray, np.ndarray, float]:
    """The staircase of series i with its free nuisance refitted inside the rounding: (h', mean
    = staircase(h', q, φ, σ_d) + c, the outer offset c).

    The nominal harmonic was fitted to the quantised data, so its amplitude and phase are biased
    by the staircase (by up to a fifth when the motion spans one or two steps). Refitting the
    nuisance outside the rounding leaves the steps at the wrong phases of every cycle: a residual
    periodic at f0, reported as harmonic_distortion and aliased extra_periodic lines. Inside,
    h' = h + nuisance·β by Gauss-Newton on the exact staircase, its derivative along each
    nuisance column a central difference over ±q/4 (the staircase's slope seen at the scale of a
    step: the mean slope is far from 1 when the motion spans few steps, and a plain fixed point
    oscillates), halving steps that do not lower the residual.
    """
    s = ctx.series[i]
    nu = ctx.nuisance(i)
    w = weights(st)
    one = np.ones((s.n, 1))
    d = 0.25 * q if dither <= 0 else min(0.25 * q, 0.5 * dither)  # smooth on the dither's scale

    def rss(hh):
        stair = staircase(hh, q, phi, dither)
        beta, _, fitted = wls(one, s.y - stair, w)
        return float(np.sum(w * (s.y - stair - fitted) ** 2)), stair + fitted, float(beta[0])

    best = (h, *rss(h))
    for _ in range(N_INSIDE):
        jac = np.stack(
            [
                (staircase(h + d * c, q, phi, dither) - staircase(h - d * c, q, phi, dither)) / (2 * d)
                for c in nu.T
            ],
            axis=1,
        )
        beta = wls(jac, s.y - staircase(h, q, phi, dither), w)[0]
        lam = 1.0
        while lam > 0.1:
            trial = h + lam * (nu @ beta)
            cand = rss(trial)
            if cand[0] < best[1]:
                break
            lam *= 0.5
        else:
            break
        h, best = trial, (trial, *cand)
        if float(np.max(np.abs(lam * (nu @ beta)))) < 1e-3 * q:
            break
    return best[0], best[2], best[3]


def _phase(
    ctx: Context, i: int, st: State, q: float, dither: float, phases: np.ndarray, level: float
) -> tuple[float, np.ndarray, np.ndarray, float]:
    """The staircase's phase on series i at a known step and dither: (φ, h', mean, outer offset).

    A motion that spans less than a step reads mostly one or two levels, so the nominal harmonic
    fitted to it is flattened (to half the amplitude and less), and inside the rounding a
    flattened motion fits nearly as well as the true one (`_inside` stays there). So the start
    is searched too: the motion scaled by ``GAINS`` about its mean × every phase, scored with the
    nuisance refitted outside the rounding (linear); the best three are refined inside it, and so
    is the best start at the camera's ``level`` (the other plates' levels: the lattice is the
    camera's, and a short motion's own phase has shallow false optima).
    """
    s = ctx.series[i]
    nu = ctx.nuisance(i)
    w = weights(st)
    centre = float(np.sum(w * st.mean) / max(float(w.sum()), 1e-300))
    scored, at_level = [], []
    for g in GAINS:
        h0 = centre + g * (st.mean - centre)
        for phi, out in [*((float(f), scored) for f in phases), (level, at_level)]:
            stair = staircase(h0, q, phi, dither)
            fitted = wls(nu, s.y - stair, w)[2]
            out.append((float(np.sum(w * (s.y - stair - fitted) ** 2)), h0, phi))
    scored.sort(key=lambda x: x[0])
    best = None
    for _, h0, phi in [*scored[:3], min(at_level, key=lambda x: x[0])]:
        h_i, mean_i, c_i = _inside(ctx, i, st, h0, q, phi, dither)
        r = float(np.sum(w * (s.y - mean_i) ** 2))
        if best is None or r < best[0]:
            best = (r, (phi, h_i, mean_i, c_i))
    return best[1]


def _joint(ctx: Context, states: list[State], use: list[int], h: dict, q: float, phi: dict, dither: float):
    """Gauss-Newton on the shared step q and dither σ_d and every series' nuisance inside the
    rounding.

    A step and the motion's amplitude scaled alike put the steps at the same instants; only the
    levels tell them apart, so the grid in q and the per-series refit (`_inside`) converge slowly
    along that valley, and a step off by 2 % leaves a periodic residual of levels (taken as
    harmonic_distortion). Here all move at once: each series' levels are counted from the one
    nearest its motion (L_s ≡ φ_s mod q, so that q moves the few levels the motion crosses, not
    the ~10³ down to 0 mm), the derivatives are central differences over a quarter step at the
    extreme level (σ_d's over ±q/100, one-sided at 0), the nuisance is eliminated series by series
    (Schur complement), and steps that do not lower the summed weighted RSS are halved (the normal
    equations weigh each series by 1/σ̂², so that their inverse is the covariance of (q, σ_d)).
    σ_d stays at 0 when it starts there: the staircase is flat in σ_d at 0 (the grid decides).

    Returns (q, σ_q, σ_d, its standard error (None at 0), {i: (L_s, h', mean, outer offset)}).
    """
    data = {}
    for i in use:
        s = ctx.series[i]
        nu = ctx.nuisance(i)
        w = weights(states[i])
        level = phi[i] + q * float(np.round((np.median(h[i]) - phi[i]) / q))
        data[i] = (s.y, w, nu, level)
    free_d = dither > 0.0
    n_shared = 2 if free_d else 1

    def evaluate(hs, qq, dd):
        out, chi = {}, 0.0
        for i in use:
            y, w, _, level = data[i]
            stair = staircase(hs[i], qq, level, dd)
            c = float(np.sum(w * (y - stair)) / max(float(w.sum()), 1e-300))
            rss = float(np.sum(w * (y - stair - c) ** 2))
            s2 = rss / max(int((w > 0).sum()) - 1, 1) or 1e-300
            out[i] = (stair + c, c, s2)
            chi += rss
        return chi, out

    chi, fit = evaluate(h, q, dither)
    info = np.zeros((n_shared, n_shared))
    for _ in range(N_INSIDE):
        info = np.zeros((n_shared, n_shared))
        grad = np.zeros(n_shared)
        parts = {}
        for i in use:
            y, w, nu, level = data[i]
            hi = h[i]
            ww = w / fit[i][2]
            k_max = max(float(np.max(np.abs(np.round((hi - level) / q)))), 1.0)
            d, dq = 0.25 * q, 0.25 * q / k_max
            cols = [
                (staircase(hi + d * c, q, level, dither) - staircase(hi - d * c, q, level, dither)) / (2 * d)
                for c in nu.T
            ]
            jac = np.stack([*cols, np.ones_like(hi)], axis=1)
            shared = [
                (staircase(hi, q + dq, level, dither) - staircase(hi, q - dq, level, dither)) / (2 * dq)
            ]
            if free_d:
                dd = 0.01 * q
                lo = max(dither - dd, 0.0)
                up = staircase(hi, q, level, lo + 2 * dd)
                shared.append((up - staircase(hi, q, level, lo)) / (2 * dd))
            jq = np.stack(shared, axis=1)
            r = y - staircase(hi, q, level, dither)
            jw = jac * ww[:, None]
            a_inv = np.linalg.pinv(jw.T @ jac)
            b, g = jw.T @ r, jw.T @ jq
            info += (jq * ww[:, None]).T @ jq - g.T @ a_inv @ g
            grad += (jq * ww[:, None]).T @ r - g.T @ a_inv @ b
            parts[i] = (a_inv, b, g, nu)
        step = np.linalg.pinv(info) @ grad
        lam = 1.0
        while lam > 0.1:
            qn = q + lam * step[0]
            dn = max(dither + lam * step[1], 0.0) if free_d else dither
            hn = {
                i: h[i] + lam * (nu @ (a_inv @ (b - g @ step))[: nu.shape[1]])
                for i, (a_inv, b, g, nu) in parts.items()
            }
            chi_n, fit_n = evaluate(hn, qn, dn)
            if chi_n < chi:
                break
            lam *= 0.5
        else:
            break
        small = chi - chi_n <= 1e-9 * chi
        q, dither, h, chi, fit = qn, dn, hn, chi_n, fit_n
        if small:
            break
    cov = np.linalg.pinv(info)
    sig_q = math.sqrt(cov[0, 0]) if cov[0, 0] > 0 else None
    sig_d = math.sqrt(cov[1, 1]) if free_d and cov[1, 1] > 0 else None
    return q, sig_q, dither, sig_d, {i: (data[i][3], h[i], fit[i][0], fit[i][1]) for i in use}


MAX_PIXELS = 500  # the most readings a centroid averages whose lattice q/P is still told apart


def _on_lattices(q: float, lattice: dict[int, float]) -> bool:
    """The step is a whole multiple of every series' own lattice (checked where the multiple is
    small enough, ≤ 20, for the step's precision to tell it)."""
    for q_i in lattice.values():
        m = q / q_i
        if round(m) < 1 or (m <= 20.5 and abs(m - round(m)) > 0.1):
            return False
    return True


MIN_STEPS_ONE_SERIES = 10.0  # steps a single series' motion must span for its lattice to be told


class Quantization(Detector):
    id = ENTRY.id
    sensors, structural, needs_reference = ENTRY.sensors, ENTRY.structural, ENTRY.needs_reference
    meaning = "depth measured in steps (structured-light disparity quantisation, a logger's ADC)"
    # A ToF camera's range is a 14-bit phase (a lattice of ~0.3 mm per pixel, averaged away over
    # a plate's pixels): no lattice a plate's centroid can show. Disparity, ADCs and trackers do.
    causes = {  # noqa: RUF012
        "structured_light": "the structured-light camera measures disparity in fractions of a pixel",
        "camera_tracking": "the tracker reports positions on a sub-pixel lattice",
        "*": "the sensor's converter (ADC) reports its readings in steps",
    }
    plausible, plausible_unit, gate_params = 0.3, "noise", 2  # a step of about σ (RMS q/√12)
    dithers: tuple[float, ...] = DITHERS  # the grid of σ_d/q ((0.0,): the hard staircase alone)

    def propose(self, ctx: Context, states: list[State]) -> list[Proposal]:
        if any(touched(st, self.id) for st in states):
            return []  # one camera, one lattice: a second step would fit what the first left
        idx = []
        for i in ctx.indices("z"):
            if touched(states[i], self.id) or ctx.series[i].n < 64:
                continue
            idx.append(i)
        if not idx:
            return []
        spans = {i: float(np.ptp(states[i].mean)) for i in idx}
        s2 = {}
        for i in idx:
            st = states[i]
            r = residual(ctx, i, st)
            w = weights(st)
            s2[i] = float(np.sum(w * r * r) / max(int((w > 0).sum()), 1))
        n_tot = sum(ctx.series[i].n for i in idx)
        sigma = math.sqrt(float(np.median(list(s2.values()))))
        # the smallest step whose staircase could pay for its parameters on all the series
        # together: n_tot (q²/12)/σ² > (1 + S) log n_tot + 10 (a per-series floor would miss
        # the steps that only the plates together show)
        need = (1 + len(idx)) * math.log(max(n_tot, 2)) + 10.0
        q_min = max(Q_MIN_MM, sigma * math.sqrt(12.0 * need / max(n_tot, 1)))
        q_max = min(Q_MAX_MM, max(spans.values()))
        if len(idx) == 1:
            # one series: a staircase over a few steps is any smooth memoryless nonlinearity of
            # the reading (a shaker's, an amplifier's); a lattice shows as one over many steps
            # (several plates sharing one lattice are the other evidence)
            q_max = min(q_max, spans[idx[0]] / MIN_STEPS_ONE_SERIES)
        # The lattice read from the values themselves (`record_kind.value_lattice`): a series
        # whose values sit on a lattice q_i (an ADC's step, a disparity camera's depth, or q/P
        # for a centroid of P rounded pixels) can only carry a staircase whose step is a whole
        # multiple of it, of at most MAX_PIXELS: a logger's 0.0015-mm ADC step under 3 mm of
        # residual is the record's resolution, not an 8.5-mm quantisation. A table's written
        # decimals (a power of ten) say nothing of the sensor.
        lattice = {}
        for i in idx:
            q_i = value_lattice(ctx.series[i].y)
            if q_i is not None and abs(math.log10(q_i) - round(math.log10(q_i))) >= 0.005:
                lattice[i] = q_i
        if lattice:
            q_max = min(q_max, MAX_PIXELS * min(lattice.values()))
        if q_max <= q_min:
            return []
        width = q_min / BINS_PER_STEP
        bins = {}
        for i in idx:
            st = states[i]
            bins[i] = _Binned(st.mean, residual(ctx, i, st), weights(st), width)
        # the grid in ν = 1/q, a quarter cycle over the largest span
        d_nu = 1.0 / (4.0 * q_max + 4.0 * max(spans.values()))
        nus = np.arange(1.0 / q_max, 1.0 / q_min + d_nu, d_nu)
        stat = np.zeros((len(idx), nus.size))
        for j, i in enumerate(idx):
            ok = 1.0 / nus < spans[i]  # the motion spans more than a step
            if ok.any():
                stat[j, ok] = bins[i].first_harmonic(nus[ok])
        total = stat.sum(axis=0)
        p_single = bonferroni(chi2_sf(stat.max(), 2), stat.size)
        p_total = bonferroni(chi2_sf(total.max(), 2 * len(idx)), nus.size)
        p_value = min(1.0, 2 * min(p_single, p_total))
        if p_value >= P_MAX:  # the search's test could not pass it: no refit of a staircase
            return []
        logn = np.array([math.log(ctx.series[i].n) for i in idx])
        crit = np.maximum(stat - 2 * logn[:, None], 0.0).sum(axis=0)
        best = None
        for g in {int(np.argmax(total)), int(np.argmax(crit))}:
            cand = self._refine(ctx, states, idx, bins, spans, float(1.0 / nus[g]), d_nu)
            if cand is not None and (best is None or cand["score"] > best["score"]):
                best = cand
        # the refit may walk the step off the grid: it stays within the bounds set above
        if best is None or best["q"] > 1.25 * q_max or not _on_lattices(best["q"], lattice):
            return []
        return [self._proposal(ctx, best, p_value, float(nus.size))]  # the step's grid

    def _refine(self, ctx, states, idx, bins, spans, q0, d_nu) -> dict | None:
        """(q, σ_d, φ_s) on the smoothed staircase near q0: q and σ_d shared, the staircase's
        phase φ_s per series.

        The grid runs over q, the levels' phase and σ_d/q (``dithers``, 0-0.5: beyond, the steps'
        first harmonic is below exp(−2π²/4) ≈ 0.7 % of the hard staircase's). The nominal offset
        is itself biased by the quantisation, so the staircase's phase is free per series; the
        camera's absolute levels o_s = φ_s + c_s (c_s the refitted offset) should then agree
        between plates. So is the nominal amplitude, and a step measured on a scaled h is scaled
        alike: the grid and the refit of h inside the rounding (`_inside`) alternate
        (``N_OUTER`` times), the grid binning the residual by the refitted h; `_joint` then
        refines q, σ_d and every nuisance together.
        """
        fr = np.arange(N_OFFSET) / N_OFFSET  # fractions of q
        use = [i for i in idx if spans[i] > q0]
        if not use:
            return None
        logn_all = math.log(sum(ctx.series[i].n for i in use))
        width = next(iter(bins.values())).width
        saws = _Saws(self.dithers)
        h = {i: states[i].mean for i in use}
        q = q0
        for outer in range(N_OUTER):
            if outer:
                bins = {i: _Binned(h[i], ctx.series[i].y - h[i], weights(states[i]), width) for i in use}
            qs = 1.0 / (1.0 / q + np.linspace(-d_nu, d_nu, N_REFINE))
            gains = np.zeros((len(use), qs.size, N_OFFSET, len(saws.dithers)))
            for j, i in enumerate(use):
                for a, qa in enumerate(qs):
                    gains[j, a] = bins[i].staircase_gain(float(qa), fr * qa, saws)
            per = gains.max(axis=2).sum(axis=0)  # (q, dither)
            a, b = np.unravel_index(int(np.argmax(per)), per.shape)
            q = float(qs[a])
            dither = saws.dithers[b] * q
            sig_q = None
            if 0 < a < qs.size - 1:
                d2 = (per[a - 1, b] - 2 * per[a, b] + per[a + 1, b]) / ((qs[a + 1] - qs[a - 1]) / 2) ** 2
                if d2 < 0:
                    sig_q = math.sqrt(2.0 / -d2)
            phi = {}
            for j, i in enumerate(use):
                phi[i] = float(fr[int(np.argmax(gains[j, a, :, b]))] * q)
                h[i] = _inside(ctx, i, states[i], h[i], q, phi[i], dither)[0]
        q, sig_joint, dither, sig_d, fits = _joint(ctx, states, use, h, q, phi, dither)
        sig_q = sig_joint if sig_joint is not None else sig_q
        # the series whose motion spans less than a step read the same lattice: a part of the
        # smoothed sawtooth, there too (left alone, it is a function of h, i.e. harmonics of f0)
        ang = [2 * np.pi * ((fits[i][0] + fits[i][3]) % q) / q for i in use]  # the levels, on a circle
        level = (math.atan2(np.mean(np.sin(ang)), np.mean(np.cos(ang))) % (2 * math.pi)) * q / (2 * math.pi)
        for i in idx:
            if i not in use:
                fits[i] = _phase(ctx, i, states[i], q, dither, fr * q, level)
        use = list(idx)
        # the noise: a rounded reading spreads little next to a level and most between two
        # (Var round(x + sZ): for s = 0.2, 0.02 at a level and 0.25 halfway), so where the
        # noise is the pixels' before rounding its variance follows the staircase too; its share
        # λ of the noise (the rest: added after the rounding) by likelihood
        shares = SHARES if dither > 0 else (0.0,)
        profile = {}
        for i in use:
            level, hh = fits[i][0], fits[i][1]
            v = dithered_round_var((hh - level) / q, dither / q)
            profile[i] = np.maximum(v / max(float(np.mean(v)), 1e-300), 0.01)
        best_share, best_total, cands = 0.0, -math.inf, {}
        for lam in shares:
            trial = {}
            for i in use:
                st = states[i]
                scale = st.scale * np.sqrt((1.0 - lam) + lam * profile[i])
                cand = updated(st, self.id, 1, mean=fits[i][2], scale=scale)
                trial[i] = (cand, gain(ctx, i, st, cand))
            total = sum(g for _, g in trial.values())
            if total > best_total:
                best_share, best_total, cands = lam, total, trial
        new, kept_gain, levels = {}, {}, {}
        for i in use:
            phi, _, _, offset = fits[i]
            cand, g = cands[i]
            if keep_series(g, 1, ctx.series[i].n):
                new[i], kept_gain[i] = cand, g
                levels[i] = float((phi + offset) % q)
        if not new:
            return None
        kept = sorted(new)
        n_params = 2 + (len(shares) > 1) + len(kept)  # q, σ_d, the share λ, a phase per series
        score = 2 * sum(kept_gain.values()) - n_params * logn_all
        return dict(
            score=score,
            q=q,
            sig_q=sig_q,
            dither=dither,
            sig_dither=sig_d,
            share=best_share,
            offsets=levels,
            new=new,
            kept=kept,
            n_params=n_params,
        )

    def _proposal(self, ctx: Context, best: dict, p_value: float, trials: float) -> Proposal:
        kept, q = best["kept"], best["q"]
        offs = np.array([best["offsets"][i] for i in kept])
        # a circular median of the offsets on the step's circle
        ang = 2 * np.pi * offs / q
        o = float(
            (math.atan2(np.mean(np.sin(ang)), np.mean(np.cos(ang))) % (2 * math.pi)) * q / (2 * math.pi)
        )
        # the levels sit ~h/q steps from 0 mm: an error of q moves them by h·σ_q/q, so o is only
        # determined (below a uniform's q/√12) when q is known that well
        level = float(np.median([np.median(np.abs(best["new"][i].mean)) for i in kept]))
        sig_o = q / math.sqrt(12.0)
        if best["sig_q"] is not None:
            sig_o = min(sig_o, math.hypot(level * best["sig_q"] / q, q / (2 * N_OFFSET)))
        where = ", ".join(ctx.series[i].key for i in kept)
        return Proposal(
            effect=self.id,
            series=kept,
            states=best["new"],
            n_params=best["n_params"],
            p_value=p_value,
            trials=trials,
            scan_params=1,  # the step
            parameters={
                "step_mm": param(q, best["sig_q"]),
                "offset_mm": param(o, sig_o),
                "dither_mm": param(best["dither"], best["sig_dither"]),
                "rounded_noise_share": param(best["share"]),
            },
            t_start=0.0,
            t_end=float(ctx.duration_s),
            band_hz=None,
            explanation=(
                f"The depth of {where} moves in steps of {q:.3f} mm (levels at {o:.3f} mm + k·{q:.3f} mm), "
                f"smoothed by {best['dither']:.3f} mm of noise before the rounding: "
                f"{self.cause(ctx)}, so a smooth motion is recorded as a staircase."
            ),
            detail={
                "offsets_mm": {ctx.series[i].key: best["offsets"][i] for i in kept},
            },
        )


EFFECT = Quantization()
