"""The open world: residual structure that no named effect explains, located and modelled by
generic terms, reported under ``"unnamed"`` and never given a vocabulary name.

After the named search (`_search`) the residuals are searched again, greedily, with three
generic terms, each chosen by BIC:

- ``line``: a sinusoid at the peak of the residual periodograms summed over an axis' series,
  each normalised by its running median (the local noise level, whatever its colour), when that
  peak is significant after the frequencies scanned (α = 0.01); per-series amplitudes, shared
  frequency, optionally decaying, e^{−λ(t − t_s)} from the
  series' start (a free vibration: its damping ratio ζ = λ / 2πf is reported). Sparse: one line
  per round, the next one from the new residual.
- ``envelope``: a smooth complex envelope u(t) of the loading line, shared by the series that
  carry the motion: y += a_s Re[u(t) e^{i arg_s(t)}], u a cubic B-spline with K interior knots
  (K by BIC), or an exponential e^{−λ(t − t_ref)} (a free decay: ζ reported).
- ``trend``: a slow additive cubic B-spline in time per series (K by BIC), its constant free;
  or one common to an axis' series (a camera's sway), which may go finer (`COMMON_KNOTS`, down
  to 4 loading periods a knot span): it pays its coefficients once for the axis.

Evidence. The noise of the residual is modelled as AR(1) on the frame clock, ρ estimated per
series from the lag-1 autocorrelation of the residual's first differences (−(1 − ρ)/2 for
AR(1); slow structure hardly moves it) and re-estimated after the term is added, σ profiled.
So coloured noise is not taken for structure. Terms shared by the plates are discounted by the
frame correlation's design effect (`_correlation`). A term is accepted when

    ΔBIC = −2 Δlog L + k log N < −10

(N all samples of the record, k every parameter added: frequencies, decay rates, amplitudes,
spline coefficients). Reported: where (plates, axes, time span, band), the term's parameters,
ΔBIC and the residual RMS of the series it touches before and after.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import jax.numpy as jnp
import numpy as np
import scipy.sparse as sp
from scipy import stats
from scipy.interpolate import BSpline
from scipy.ndimage import median_filter

from .._numerics import DELTA_BIC_MAX, harmonic_design, wls
from ._base import LOG_2PI, Context, State, masked_periodogram, peak_offset
from ._correlation import FrameCorrelation, ar1_rho
from ._varpro import fit_shared
from .effects.screening import weights

__all__ = [
    "UnnamedTerm",
    "search_unnamed",
    "best_term",
    "apply_term",
    "colored_gain",
    "ar1_loglik",
    "ar1_rho",
    "ar1_whiten",
    "term_sigmas",
    "MAX_TERMS",
    "KINDS",
]

KINDS = ("line", "envelope", "trend")
MAX_TERMS = 4
MAX_KNOTS = 12
# a line's signature: its locally normalised power against a running median of ±LOCAL_BINS
# bins, significant at LINE_ALPHA after the frequencies and axes scanned
LOCAL_BINS = 25
LINE_ALPHA = 0.01
# interior knots tried (BIC picks among them, up to what the record can carry)
KNOTS = (0, 1, 2, 3, 5, 8, 12)
# finer knots for the trend common to an axis' series (a camera's sway has power up to a few
# loading periods): it pays its coefficients once for the axis, not once per series
COMMON_KNOTS = (16, 24, 32, 48, 64, 96, 128)
# the chosen term is refined only when its screening already shows evidence (a refit moves ΔBIC
# by a few units, not from nothing to −10); a refit costs a compilation per shape
REFINE_BELOW = 0.0
# λ grid of the decays, in units of 1/duration (e-folds over the record)
_DECAY_GRID = np.concatenate([[0.0], np.geomspace(0.05, 40.0, 12)])  # refined by optimistix


@dataclass
class UnnamedTerm:
    """An accepted generic term.

    Attributes:
        kind: ``line``, ``envelope`` or ``trend``.
        series: indices into `Context.series`; means: {series index: new mean}.
        n_params: parameters added; parameters: {name: {"value", "sigma"}} (JSON-able).
        t_start, t_end: located span (s since t0); band_hz: [lo, hi] or None.
        delta_bic, rms_before_mm, rms_after_mm: evidence and the plain residual RMS of its series.
        explanation: one or two sentences for a structural engineer.
    """

    kind: str
    series: list[int]
    means: dict[int, np.ndarray]
    n_params: int
    parameters: dict
    t_start: float
    t_end: float
    band_hz: list[float] | None
    explanation: str
    delta_bic: float = math.nan
    rms_before_mm: float = math.nan
    rms_after_mm: float = math.nan
    detail: dict = field(default_factory=dict)
    # the fitted term itself (its mean change per series), for the search's backfitting
    change: dict = field(default_factory=dict, repr=False)
    candidate: object = field(default=None, repr=False)


# ---------------------------------------------------------------------------------------------
# AR(1) noise


def ar1_loglik(r: np.ndarray, k: np.ndarray, rho: float) -> float:
    """Exact Gaussian log-likelihood of r under AR(1) noise on the frame clock k (gaps allowed),
    the innovation σ profiled: e_j = r_j − ρ^g r_{j−1}, var ∝ (1 − ρ^{2g})/(1 − ρ²), g the gap."""
    n = r.size
    if n == 0:
        return -math.inf
    if rho <= 0.0:
        s2 = max(float(np.mean(r * r)), 1e-300)
        return -0.5 * n * (math.log(s2) + LOG_2PI + 1.0)
    g = np.diff(k).astype(np.float64)
    rg = rho**g
    # in units of the innovation variance σ²: the first sample at the stationary 1/(1 − ρ²), the
    # others given the previous one g frames before at (1 − ρ^{2g})/(1 − ρ²) (1 when g = 1)
    v = np.concatenate([[1.0], 1.0 - rg * rg]) / (1.0 - rho * rho)
    e = np.concatenate([r[:1], r[1:] - rg * r[:-1]])
    s2 = max(float(np.mean(e * e / v)), 1e-300)
    return -0.5 * (n * (math.log(s2) + LOG_2PI + 1.0) + float(np.sum(np.log(v))))


def _ar1_of(s, st: State, mean: np.ndarray) -> tuple[float, float]:
    """(AR(1) log-likelihood, ρ̂) of a series' residual about ``mean`` under its state's scale."""
    inl = st.inlier
    z = ((s.y - mean) / st.scale)[inl]
    k = s.k[inl]
    z = z - z.mean()
    rho = ar1_rho(z, k)
    return ar1_loglik(z, k, rho) - (st.log_scale_sum if not st.unit_scale else 0.0), rho


def colored_gain(s, st: State, mean: np.ndarray) -> float | None:
    """Δlog L of a new ``mean`` (same noise model) under AR(1) noise, ρ profiled on each side;
    None when the noise is white on both sides (then the white likelihood holds as it is)."""
    a, ra = _ar1_of(s, st, st.mean)
    b, rb = _ar1_of(s, st, mean)
    if ra == 0.0 and rb == 0.0:
        return None
    return b - a


class _Noise:
    """Per series: the inlier times, frames, the scale, and the AR(1) log-likelihood of a mean."""

    def __init__(self, ctx: Context, states: list[State], bases: dict | None = None, corr=None):
        self.ctx = ctx
        self.states = states
        self.corr = corr
        self._base: dict[int, float] = {}
        self.bases = {} if bases is None else bases

    def basis(self, i: int, knots: int) -> np.ndarray:
        """Series i's cubic B-spline basis over the record (cached by the search)."""
        key = (i, knots)
        if key not in self.bases:
            b = _bspline(self.ctx.series[i].t, 0.0, self.ctx.duration_s, knots)
            b.setflags(write=False)
            self.bases[key] = b
        return self.bases[key]

    def base(self, i: int) -> float:
        """The log-likelihood of the current mean of series i (cached)."""
        if i not in self._base:
            self._base[i] = self.loglik(i, self.states[i].mean)
        return self._base[i]

    def loglik(self, i: int, mean: np.ndarray) -> float:
        return _ar1_of(self.ctx.series[i], self.states[i], mean)[0]

    def gain(self, means: dict[int, np.ndarray]) -> float:
        """Δlog L of new means of a term over its series, divided by the frame
        correlation's design effect (`_correlation`) when the search has one."""
        dll = {i: self.loglik(i, m) - self.base(i) for i, m in means.items()}
        if self.corr is None:
            return sum(dll.values())
        return self.corr.discount(dll)


# ---------------------------------------------------------------------------------------------
# linear fits


def _nuisance(ctx: Context, i: int, offset_only: bool = False) -> np.ndarray:
    nu = ctx.nuisance(i)
    return nu[:, :1] if offset_only else nu


def _bspline(t: np.ndarray, t_lo: float, t_hi: float, knots: int, sparse: bool = False):
    """(sample, knots + 4) cubic B-spline basis on [t_lo, t_hi] with ``knots`` interior knots
    (a CSR matrix with ``sparse``: 4 non-zeros a row)."""
    inner = np.linspace(t_lo, t_hi, knots + 2)
    kv = np.concatenate([[t_lo] * 3, inner, [t_hi] * 3])
    x = np.clip(t, t_lo, t_hi - 1e-12 * max(1.0, abs(t_hi)))
    b = BSpline.design_matrix(x, kv, 3)
    return b.tocsr() if sparse else b.toarray()


def _line_columns(theta, t, aux):
    """A line at θ0 Hz decaying at θ1 /s from the series' start."""
    e = jnp.exp(-theta[1] * (t - aux["t_s"]))
    a = 2 * jnp.pi * theta[0] * t
    return jnp.stack([e * jnp.cos(a), e * jnp.sin(a)], axis=1)


def _decay_columns(theta, t, aux):
    """The loading line's carrier scaled by e^{−θ0 (t − t_mid)}."""
    e = jnp.exp(-theta[0] * (t - aux["t_mid"]))
    return jnp.stack([e * aux["c"], e * aux["s"]], axis=1)


def _varpro(ctx, states, idx, columns, theta0, scale, aux, offset_only, bounds=None):
    """Refine shared nonlinear θ (optimistix, `_varpro.fit_shared`): {i: new mean} and θ, or None."""
    ts = [ctx.series[i].t for i in idx]
    rs = [ctx.series[i].y - states[i].mean for i in idx]
    ws = [weights(states[i]) for i in idx]
    nus = [_nuisance(ctx, i, offset_only) for i in idx]
    q = max(nu.shape[1] for nu in nus)  # a tied series has the offset only: zero columns pad it
    nus = [np.pad(nu, ((0, 0), (0, q - nu.shape[1]))) for nu in nus]
    fit = fit_shared(
        columns, np.asarray(theta0, float), ts, rs, ws, nus, aux=aux, scale=np.asarray(scale), bounds=bounds
    )
    if not fit.converged or not np.all(np.isfinite(fit.theta)):
        return None
    return {i: states[i].mean + fit.fitted[j] for j, i in enumerate(idx)}, np.asarray(fit.theta), fit


@dataclass
class _Candidate:
    kind: str
    series: list[int]
    means: dict[int, np.ndarray]
    n_params: int
    info: dict
    refine: object = None  # () -> _Candidate or None: the full fit, run only on the chosen term


def _score(ctx, noise, states, corr, cand, n_total) -> float:
    dll = {}
    for i in cand.series:
        dll[i] = noise.loglik(i, cand.means[i]) - noise.base(i)
    if corr is not None:
        gain = corr.discount(dll)
    else:
        gain = sum(dll.values())
    return -2.0 * gain + cand.n_params * math.log(n_total)


# ---------------------------------------------------------------------------------------------
# the generic terms


def _line(ctx: Context, states: list[State], noise: _Noise, n_total: int) -> list[_Candidate]:
    """One sparse sinusoid per axis at the significant peak of the summed locally normalised
    periodograms."""
    out = []
    by_axis: dict[str, list[int]] = {}
    for i, s in enumerate(ctx.series):
        by_axis.setdefault(s.axis, []).append(i)
    for axis, idx in by_axis.items():
        total = None
        freq = None
        for i in idx:
            s, st = ctx.series[i], states[i]
            r = np.where(st.inlier, (s.y - st.mean) / st.scale, 0.0)
            freq, p = masked_periodogram(ctx, i, r, oversample=2)
            # against the local noise level (running median of the periodogram: Exp(1) powers
            # under any smooth noise spectrum, coloured or not)
            local = median_filter(p, size=2 * LOCAL_BINS + 1, mode="nearest") / math.log(2.0)
            p = p / np.maximum(local, 1e-300)
            total = p if total is None else total + p
        allowed = (freq > 2.0 / ctx.duration_s) & (np.abs(freq - ctx.f0_hz) > 1.0 / ctx.duration_s)
        allowed &= freq < 0.5 / ctx.dt_s - 1.0 / ctx.duration_s
        if not allowed.any():
            continue
        j = int(np.argmax(np.where(allowed, total, -np.inf)))
        # the signature: the peak of the m summed local powers (Gamma(m, 1)) against the
        # independent frequencies scanned (two bins each) on the three axes
        n_freq = max(1.0, allowed.sum() / 2.0)
        logp = float(stats.gamma.logsf(total[j], len(idx)))
        if logp + math.log(3.0 * n_freq) > math.log(LINE_ALPHA):
            continue
        j = min(max(j, 1), freq.size - 2)
        f = float(freq[j] + peak_offset(total[j - 1], total[j], total[j + 1]) * (freq[1] - freq[0]))
        best = None
        for lam_u in _DECAY_GRID:
            lam = lam_u / ctx.duration_s
            means, fits = {}, {}
            gains = {}
            for i in idx:
                s, st = ctx.series[i], states[i]
                tau = s.t - s.t[0]
                cols = np.exp(-lam * tau)[:, None] * harmonic_design(2 * np.pi * f * s.t, offset=False)
                g = np.concatenate([cols, _nuisance(ctx, i, offset_only=True)], axis=1)
                beta, _, fitted = wls(g, s.y - st.mean, weights(st), cov=False)
                means[i] = st.mean + fitted
                fits[i] = beta[:2]
                gains[i] = noise.loglik(i, means[i]) - noise.base(i)
            kept = [i for i in idx if 2 * gains[i] > 2 * math.log(n_total) + 6.0]
            if not kept:
                continue
            k_par = 1 + (1 if lam_u > 0 else 0) + 2 * len(kept)
            dbic = -2 * sum(gains[i] for i in kept) + k_par * math.log(n_total)
            if best is None or dbic < best[0]:
                best = (dbic, lam, kept, {i: means[i] for i in kept}, {i: fits[i] for i in kept}, k_par)
        # the common line: one amplitude and phase for every series of the axis (a vibration of
        # the camera or of the whole scene), worth its fewer parameters when the plates share
        # their noise (the design effect discounts a per-series line's evidence as much)
        common = None
        if len(idx) > 1:
            proj = _projections(ctx, states, idx)
            for lam_u in _DECAY_GRID:
                lam = lam_u / ctx.duration_s

                def cols_of(i, lam=lam, f=f):
                    s = ctx.series[i]
                    env = np.exp(-lam * (s.t - s.t[0]))
                    return env[:, None] * harmonic_design(2 * np.pi * f * s.t, offset=False)

                beta, m_ax, _ = _shared_fit(ctx, states, idx, cols_of, proj)
                k_par = 1 + (1 if lam_u > 0 else 0) + 2
                dbic = -2 * noise.gain(m_ax) + k_par * math.log(n_total)
                if common is None or dbic < common[0]:
                    common = (dbic, lam, m_ax, beta, k_par)
        if best is not None:
            _, lam, kept, means, fits, k_par = best
            own = -2 * noise.gain(means) + k_par * math.log(n_total)
        if common is not None and (best is None or common[0] < own):
            _, lam, means, beta, k_par = common
            amp = float(math.hypot(*beta))
            info = {"freq_hz": f, "decay_per_s": lam, "amplitudes_mm": {i: amp for i in idx}, "axis": axis}
            out.append(_Candidate("line", idx, means, k_par, dict(info, common=True)))
            continue
        if best is None:
            continue
        amps = {i: float(math.hypot(*fits[i])) for i in kept}
        info = {"freq_hz": f, "decay_per_s": lam, "amplitudes_mm": amps, "axis": axis}
        cand = _Candidate("line", kept, means, k_par, info)
        cand.refine = lambda c=cand: _refine_line(ctx, states, c)
        out.append(cand)
    return out


def _refine_line(ctx: Context, states: list[State], c: _Candidate) -> _Candidate | None:
    """The line's frequency and decay refined together (optimistix variable projection); a line
    screened without decay keeps none (its frequency alone refined, its parameters as counted)."""
    f, lam = c.info["freq_hz"], c.info["decay_per_s"]
    aux = {"t_s": [float(ctx.series[i].t[0]) for i in c.series]}
    scale = [0.1 / ctx.duration_s, max(lam, 1.0 / ctx.duration_s)]
    bounds = None if lam > 0 else (np.array([-np.inf, 0.0]), np.array([np.inf, 0.0]))
    ref = _varpro(ctx, states, c.series, _line_columns, [f, lam], scale, aux, True, bounds)
    if ref is None or abs(ref[1][0] - f) > 2.0 / ctx.duration_s or ref[1][1] < 0:
        return None
    means, theta, fit = ref
    amps = {i: float(math.hypot(*fit.beta[j][:2])) for j, i in enumerate(c.series)}
    info = dict(c.info, freq_hz=float(theta[0]), decay_per_s=float(theta[1]), amplitudes_mm=amps)
    return _Candidate("line", c.series, means, (2 if lam > 0 else 1) + 2 * len(c.series), info)


def _carriers(ctx: Context, states: list[State]) -> list[int]:
    """Series whose loading motion stands above their noise (≥ 1 σ: the envelope is shared, a
    series of little motion adds little evidence and no parameter)."""
    return [
        i for i in range(len(ctx.series)) if ctx.nominal[i].amplitude >= 1.0 * max(ctx.noise_sigma(i), 1e-12)
    ]


def _projections(ctx, states, idx) -> dict:
    """Per series: (weights, nuisance, its weighted projector, residual, residual less nuisance)."""
    out = {}
    for i in idx:
        s, st = ctx.series[i], states[i]
        w = weights(st) / max(ctx.noise_sigma(i), 1e-12) ** 2
        nu = _nuisance(ctx, i)
        r = s.y - st.mean
        nw = nu * w[:, None]
        proj = np.linalg.pinv(nw.T @ nu) @ nw.T
        out[i] = (w, nu, proj, r, r - nu @ (proj @ r))
    return out


def _shared_fit(ctx, states, idx, cols_of, projections=None):
    """Coefficients shared by the series ``idx`` (each with its free nuisance profiled out, FWL),
    returning (coefficients, {i: new mean}, {i: nuisance coefficients}).

    ``cols_of(i)`` may be dense or a scipy sparse matrix (a B-spline basis: 4 non-zeros a row).
    With c = νᵀWx and P = (νᵀWν)⁺, the columns less their nuisance part, x̃ = x − νPc, give
    x̃ᵀWx̃ = xᵀWx − cᵀPc and x̃ᵀWr̃ = xᵀWr̃ − cᵀP(νᵀWr̃): no (sample × column) product is formed
    but xᵀWx itself, which a sparse basis makes O(sample)."""
    projections = _projections(ctx, states, idx) if projections is None else projections
    lhs = rhs = None
    per = {}
    for i in idx:
        w, nu, proj, r, rt = projections[i]
        x = cols_of(i)
        nw = nu * w[:, None]
        if sp.issparse(x):
            xw = x.multiply(w[:, None]).tocsc()
            xwx = (x.T @ xw).toarray()
            c = np.asarray((xw.T @ nu).T)
            xwr = np.asarray(xw.T @ rt).ravel()
        else:
            xw = x * w[:, None]
            xwx = xw.T @ x
            c = nw.T @ x
            xwr = xw.T @ rt
        pc = np.linalg.pinv(nw.T @ nu) @ c
        a = xwx - c.T @ pc
        b = xwr - pc.T @ (nw.T @ rt)
        lhs = a if lhs is None else lhs + a
        rhs = b if rhs is None else rhs + b
        per[i] = (x, nu, proj, r)
    beta = np.linalg.lstsq(lhs, rhs, rcond=None)[0]
    means, gammas = {}, {}
    for i, (x, nu, proj, r) in per.items():
        fx = np.asarray(x @ beta).ravel()
        gammas[i] = proj @ (r - fx)
        means[i] = states[i].mean + fx + nu @ gammas[i]
    return beta, means, gammas


def _carrier(ctx: Context, i: int) -> tuple[np.ndarray, np.ndarray]:
    """The nominal motion's in-phase and quadrature carriers on series i: (A cos φ, −A sin φ)."""
    h = ctx.nominal[i]
    _, c, s = harmonic_design(h.argument(ctx.series[i].t)).T
    return h.amplitude * c, -h.amplitude * s


def _envelope(ctx: Context, states: list[State], noise: _Noise, n_total: int) -> list[_Candidate]:
    """A shared smooth complex envelope of the loading line (B-spline, K by BIC) or a decay."""
    idx = _carriers(ctx, states)
    if not idx:
        return []
    cycles = ctx.f0_hz * ctx.duration_s
    carrier = {i: _carrier(ctx, i) for i in idx}
    base = sum(noise.base(i) for i in idx)

    # the series the report's envelope is read on: the largest motion against its noise
    ref = max(idx, key=lambda i: ctx.nominal[i].amplitude / max(ctx.noise_sigma(i), 1e-12))

    projections = _projections(ctx, states, idx)

    def evaluate(cols_of, k_par):
        beta, means, gammas = _shared_fit(ctx, states, idx, cols_of, projections)
        gain = sum(noise.loglik(i, means[i]) for i in idx) - base
        # the re-estimated harmonic (C, D) of the reference series as a relative complex factor
        h, g = ctx.nominal[ref], gammas[ref]
        shift = (
            0j
            if ctx.series[ref].tied
            else (g[1] - 1j * g[2]) * np.exp(1j * h.phase) / max(h.amplitude, 1e-300)
        )
        return -2 * gain + k_par * math.log(n_total), (beta, shift), means

    best = None
    # K interior knots: the envelope varies slower than the carrier (≥ 1 cycle per knot span)
    k_max = int(min(MAX_KNOTS, max(0, cycles - 1)))
    for knots in (k for k in KNOTS if k <= k_max):

        def cols_of(i, knots=knots):
            b = noise.basis(i, knots)
            c, s = carrier[i]
            return np.concatenate([b * c[:, None], b * s[:, None]], axis=1)

        nb = knots + 4
        dbic, beta, means = evaluate(cols_of, 2 * nb - 2)  # the constant is the nominal's C, D
        if best is None or dbic < best[0]:
            best = (dbic, means, 2 * nb - 2, {"form": "spline", "knots": knots, "coef": beta})
    best_exp = None
    for lam_u in _DECAY_GRID[1::2]:  # a coarse start: the chosen decay is refined
        for sign in (1.0, -1.0):
            lam = sign * lam_u / ctx.duration_s

            def cols_of(i, lam=lam):
                e = np.exp(-lam * (ctx.series[i].t - 0.5 * ctx.duration_s))
                c, s = carrier[i]
                return np.stack([e * c, e * s], axis=1)

            dbic, beta, means = evaluate(cols_of, 3)
            if best_exp is None or dbic < best_exp[0]:
                best_exp = (dbic, means, 3, {"form": "exponential", "decay_per_s": lam, "coef": beta})
    for b in (best, best_exp):
        b[3]["coef"], b[3]["shift"] = b[3]["coef"]
    chosen = best_exp if best_exp[0] < best[0] else best

    def refine() -> _Candidate | None:
        """The decay refined (optimistix): compared with the grid's best by the search."""
        lam = best_exp[3]["decay_per_s"]
        aux = {
            "t_mid": [0.5 * ctx.duration_s] * len(idx),
            "c": [carrier[i][0] for i in idx],
            "s": [carrier[i][1] for i in idx],
        }
        scale = [max(abs(lam), 1.0 / ctx.duration_s)]
        refit = _varpro(ctx, states, idx, _decay_columns, [lam], scale, aux, False)
        if refit is None:
            return None
        means, theta, fit = refit
        j = idx.index(ref)
        coef = fit.beta[j, :2]
        h = ctx.nominal[ref]
        shift = 0j
        if not ctx.series[ref].tied:  # the re-estimated harmonic: what the term leaves of the fit
            term = _decay_columns(theta, ctx.series[ref].t, {k: v[j] for k, v in aux.items()}) @ coef
            gam = wls(_nuisance(ctx, ref), means[ref] - states[ref].mean - np.asarray(term), cov=False)[0]
            shift = (gam[1] - 1j * gam[2]) * np.exp(1j * h.phase) / h.amplitude
        info = {"form": "exponential", "decay_per_s": float(theta[0]), "coef": coef, "shift": shift}
        info["relative_envelope"] = _relative_envelope(ctx, info)
        return _Candidate("envelope", idx, means, 1 + 2 * len(idx), info)

    _, means, k_par, info = chosen
    info["relative_envelope"] = _relative_envelope(ctx, info)
    return [_Candidate("envelope", idx, means, k_par, info, refine)]


def _relative_envelope(ctx: Context, info: dict) -> np.ndarray:
    """|1 + shift + u(t)| on 400 times over the record: the amplitude relative to the nominal."""
    t = np.linspace(0.0, ctx.duration_s, 400)
    if info["form"] == "spline":
        b = _bspline(t, 0.0, ctx.duration_s, info["knots"])
        nb = b.shape[1]
        u = b @ info["coef"][:nb] + 1j * (b @ info["coef"][nb:])
    else:
        co = info["coef"]
        u = np.exp(-info["decay_per_s"] * (t - 0.5 * ctx.duration_s)) * (co[0] + 1j * co[1])
    return np.abs(1.0 + info["shift"] + u)


def _change_point(ctx: Context, states: list[State]) -> float | None:
    """The most likely time of a step common to the series: the argmax over time of the summed
    squared standardised CUSUMs of their residuals (on the frame clock), or None."""
    n_frames = ctx.n_frames
    total = np.zeros(n_frames)
    for i, s in enumerate(ctx.series):
        st = states[i]
        z = np.where(st.inlier, (s.y - st.mean) / st.scale, 0.0)
        z = z - z.mean()
        sd = float(np.std(z)) or 1.0
        c = np.cumsum(z) / sd
        n = z.size
        j = np.arange(1, n)
        stat = np.zeros(n_frames)
        stat[s.k[:-1]] = c[:-1] ** 2 * n / (j * (n - j))
        total += stat
    margin = max(2, n_frames // 50)
    if n_frames <= 2 * margin:
        return None
    k = margin + int(np.argmax(total[margin:-margin]))
    return (k + 0.5) * ctx.dt_s


def _trend(ctx: Context, states: list[State], noise: _Noise, n_total: int) -> list[_Candidate]:
    """A slow additive B-spline (K knots by BIC), optionally with a step at the common change
    point, or that step alone: per series (series that pay for it), one shape shared by the
    series with a scale each (rank one: a support that settles), or one motion common to the
    series of an axis (a camera that warms up or moves: the same millimetres on every plate),
    that one also at the finer `COMMON_KNOTS` (a camera's sway: power up to a few loading
    periods)."""
    k_max = int(min(MAX_KNOTS, max(0, ctx.f0_hz * ctx.duration_s / 4.0 - 1)))
    t_c = _change_point(ctx, states)
    logn = math.log(n_total)
    by_axis: dict[str, list[int]] = {}
    for i, s in enumerate(ctx.series):
        by_axis.setdefault(s.axis, []).append(i)
    shapes = [
        (k, step) for k in KNOTS if k <= k_max for step in ((False, True) if t_c is not None else (False,))
    ]
    if t_c is not None:
        shapes.append((None, True))  # the step alone
    best = None

    def offer(dbic, kept, means, k_par, info):
        nonlocal best
        if best is None or dbic < best[0]:
            best = (dbic, kept, means, k_par, info)

    def common(cols_of, k_own, extra, info) -> float:
        """Offers the motion common to each axis' series (the axes where it pays); its ΔBIC."""
        co_means, co_kept, k_co = {}, [], extra
        for idx in by_axis.values():
            _, m_ax, _ = _shared_fit(ctx, states, idx, cols_of)
            g_ax = noise.gain(m_ax)  # noise common to the plates is no evidence for it
            if 2 * g_ax > k_own * logn + 6.0:
                co_kept += idx
                co_means.update(m_ax)
                k_co += k_own
        if not co_kept:
            return math.inf
        dbic = -2 * noise.gain(co_means) + k_co * logn
        offer(dbic, co_kept, co_means, k_co, dict(info, form="common"))
        return dbic

    for knots, step in shapes:
        cols, betas, means, gains = {}, {}, {}, {}
        for i, s in enumerate(ctx.series):
            st = states[i]
            # the spline's constant is the offset
            b = noise.basis(i, knots)[:, 1:] if knots is not None else np.zeros((s.n, 0))
            if step:
                b = np.concatenate([b, (s.t > t_c).astype(float)[:, None]], axis=1)
            cols[i] = b
            g = np.concatenate([b, _nuisance(ctx, i)], axis=1)
            beta, _, fitted = wls(g, s.y - st.mean, weights(st), cov=False)
            betas[i] = beta[: b.shape[1]] / max(ctx.noise_sigma(i), 1e-12)
            means[i] = st.mean + fitted
            gains[i] = noise.loglik(i, means[i]) - noise.base(i)
        k_own = cols[0].shape[1]
        extra = 1 if step else 0  # the step time, shared
        info = {"knots": knots, "step_s": t_c if step else None}
        kept = [i for i in gains if 2 * gains[i] > k_own * logn + 6.0]
        if kept:
            dbic = -2 * noise.gain({i: means[i] for i in kept}) + (k_own * len(kept) + extra) * logn
            offer(dbic, kept, {i: means[i] for i in kept}, k_own * len(kept) + extra, dict(info, form="own"))
        # the common motion: per axis one set of coefficients for all its series (each series'
        # offset and harmonic still free)
        common(cols.__getitem__, k_own, extra, info)
        if k_own < 2:
            continue
        # the shared shape: the first right singular vector of the noise-scaled coefficients
        m = np.stack([betas[i] for i in range(len(ctx.series))])
        v = np.linalg.svd(m, full_matrices=False)[2][0]
        sh_means, sh_gains = {}, {}
        for i, s in enumerate(ctx.series):
            st = states[i]
            g = np.concatenate([(cols[i] @ v)[:, None], _nuisance(ctx, i)], axis=1)
            fitted = wls(g, s.y - st.mean, weights(st), cov=False)[2]
            sh_means[i] = st.mean + fitted
            sh_gains[i] = noise.loglik(i, sh_means[i]) - noise.base(i)
        kept = [i for i in sh_gains if 2 * sh_gains[i] > logn + 6.0]
        if kept:
            k_par = k_own - 1 + len(kept) + extra
            dbic = -2 * noise.gain({i: sh_means[i] for i in kept}) + k_par * logn
            offer(dbic, kept, {i: sh_means[i] for i in kept}, k_par, dict(info, form="shared", shape=v))
    # the common motion at finer knots, down to 4 loading periods a knot span, while BIC keeps
    # improving (two finer grids without a better ΔBIC end it); their bases are built when fitted
    # and not cached (a record's series at 128 knots would hold a few hundred MB)
    k_fine = int(max(0, ctx.f0_hz * ctx.duration_s / 4.0 - 1))
    prev, worse = math.inf, 0
    for knots in (k for k in COMMON_KNOTS if k <= k_fine):

        def fine(i, knots=knots):
            return _bspline(ctx.series[i].t, 0.0, ctx.duration_s, knots, sparse=True)[:, 1:]

        dbic = common(fine, knots + 3, 0, {"knots": knots, "step_s": None})
        worse = worse + 1 if dbic >= prev else 0
        prev = min(prev, dbic)
        if worse >= 2:
            break
    if best is None:
        return []
    _, kept, means, k_par, info = best
    info["swing_mm"] = {i: float(np.ptp(means[i] - states[i].mean)) for i in kept}
    return [_Candidate("trend", kept, means, k_par, info)]


# ---------------------------------------------------------------------------------------------
# uncertainty of a term's parameters


def ar1_whiten(x: np.ndarray, k: np.ndarray, rho: float) -> np.ndarray:
    """Rows of x (sample[, column]) prewhitened for AR(1) noise on the frame clock k, in units
    of the innovation σ (the transform whose squared sum is `ar1_loglik`'s quadratic form)."""
    if rho <= 0.0:
        return x
    rg = rho ** np.diff(k).astype(np.float64)
    v = np.concatenate([[1.0], 1.0 - rg * rg]) / (1.0 - rho * rho)
    tail = (slice(None),) + (None,) * (x.ndim - 1)
    out = np.concatenate([x[:1], x[1:] - rg[tail] * x[:-1]])
    return out / np.sqrt(v)[tail]


def _gls_covariance(ctx, states, c, blocks, n_shared, corr=None) -> np.ndarray:
    """Covariance of a term's parameters: n_shared shared ones, then each block's own columns.

    ``blocks``: per series (i, J_shared (sample, n_shared), X_own (sample, k)), the Jacobian of
    the series' mean with respect to the parameters. The noise: per series AR(1) (ρ from the
    residual after the term, `ar1_rho`) and its state's scale; the innovation σ² from the
    whitened residual (degrees of freedom removed), so the covariance is the generalised least
    squares one, (Jᵀ Σ⁻¹ J)⁻¹. With ``corr``, the shared block is inflated by the design effect
    of the term's series (noise common to the plates of a frame carries no information twice).
    """
    sizes = [x.shape[1] for _, _, x in blocks]
    p = n_shared + sum(sizes)
    m = np.zeros((p, p))
    off = n_shared
    for (i, js, x), k in zip(blocks, sizes, strict=True):
        s, st = ctx.series[i], states[i]
        inl = st.inlier
        sc = st.scale[inl] if np.ndim(st.scale) else st.scale
        z = ((s.y - c.means[i])[inl]) / sc
        kk = s.k[inl]
        rho = ar1_rho(z - z.mean(), kk)
        j = np.concatenate([js, x], axis=1)[inl] / np.reshape(sc, (-1, 1))
        jw = ar1_whiten(j, kk, rho)
        zw = ar1_whiten(z - z.mean(), kk, rho)
        s2 = float(zw @ zw) / max(zw.size - n_shared / max(len(blocks), 1) - k, 1.0)
        g = jw.T @ jw / s2
        sel = np.r_[np.arange(n_shared), off + np.arange(k)]
        m[np.ix_(sel, sel)] += g
        off += k
    cov = np.linalg.pinv(m, rcond=1e-12, hermitian=True)
    if corr is not None and n_shared:
        f = math.sqrt(corr.design_effect([b[0] for b in blocks]))
        cov[:n_shared, :] *= f
        cov[:, :n_shared] *= f
    return cov


def _sd(cov: np.ndarray, grad: np.ndarray) -> float:
    v = float(grad @ cov @ grad)
    return math.sqrt(v) if v > 0 else 0.0


def _line_sigmas(ctx, states, c, corr) -> dict:
    """σ of a line's frequency, decay, damping ratio and per-series amplitudes."""
    f, lam = c.info["freq_hz"], c.info["decay_per_s"]
    free_decay = lam > 0
    n_sh = 2 if free_decay else 1
    if c.info.get("common"):
        return _common_line_sigmas(ctx, states, c, corr, f, lam)
    blocks, ab = [], []
    for i in c.series:
        s = ctx.series[i]
        tau = s.t - s.t[0]
        e = np.exp(-lam * tau)
        _, ca, sa = harmonic_design(2 * np.pi * f * s.t).T
        x = np.stack([e * ca, e * sa, np.ones_like(tau)], axis=1)
        a, b = wls(x, c.means[i] - states[i].mean, cov=False)[0][:2]
        js = [e * 2 * np.pi * s.t * (-a * sa + b * ca)]
        if free_decay:
            js.append(-tau * e * (a * ca + b * sa))
        blocks.append((i, np.stack(js, axis=1), x))
        ab.append((a, b))
    cov = _gls_covariance(ctx, states, c, blocks, n_sh, corr)
    out = {"freq_hz": math.sqrt(max(cov[0, 0], 0.0))}
    if free_decay:
        out["decay_per_s"] = math.sqrt(max(cov[1, 1], 0.0))
        zeta = lam / (2 * np.pi * f)
        out["damping_ratio"] = _sd(cov[:2, :2], np.array([-zeta / f, 1.0 / (2 * np.pi * f)]))
    amps = {}
    for j, (i, (a, b)) in enumerate(zip(c.series, ab, strict=True)):
        amp = math.hypot(a, b)
        g = np.zeros(cov.shape[0])
        g[n_sh + 3 * j : n_sh + 3 * j + 2] = (a / amp, b / amp) if amp > 0 else (1.0, 0.0)
        amps[i] = _sd(cov, g)
    out["amplitudes_mm"] = amps
    return out


def _common_line_sigmas(ctx, states, c, corr, f, lam) -> dict:
    """`_line_sigmas` of a line common to the series: shared frequency, decay, amplitude and
    phase, each series' nuisance free."""
    free_decay = lam > 0
    cols, xs = {}, {}
    for i in c.series:
        s = ctx.series[i]
        tau = s.t - s.t[0]
        e = np.exp(-lam * tau)
        _, ca, sa = harmonic_design(2 * np.pi * f * s.t).T
        cols[i] = (tau, e, ca, sa)
        xs[i] = np.stack([e * ca, e * sa], axis=1)
    a, b = _shared_fit(ctx, states, c.series, lambda i: xs[i])[0]
    blocks = []
    for i in c.series:
        tau, e, ca, sa = cols[i]
        js = [e * 2 * np.pi * ctx.series[i].t * (-a * sa + b * ca)]
        if free_decay:
            js.append(-tau * e * (a * ca + b * sa))
        blocks.append((i, np.concatenate([np.stack(js, axis=1), xs[i]], axis=1), _nuisance(ctx, i)))
    n_nl = 2 if free_decay else 1
    cov = _gls_covariance(ctx, states, c, blocks, n_nl + 2, corr)
    out = {"freq_hz": math.sqrt(max(cov[0, 0], 0.0))}
    if free_decay:
        out["decay_per_s"] = math.sqrt(max(cov[1, 1], 0.0))
        zeta = lam / (2 * np.pi * f)
        out["damping_ratio"] = _sd(cov[:2, :2], np.array([-zeta / f, 1.0 / (2 * np.pi * f)]))
    amp = math.hypot(a, b)
    g = np.zeros(cov.shape[0])
    g[n_nl : n_nl + 2] = (a / amp, b / amp) if amp > 0 else (1.0, 0.0)
    sd = _sd(cov, g)
    out["amplitudes_mm"] = {i: sd for i in c.series}
    return out


def _envelope_sigmas(ctx, states, c, corr) -> dict:
    """σ of the envelope's extremes (spline) or of its decay rate and damping ratio."""
    info = c.info
    idx = c.series
    carrier = {i: _carrier(ctx, i) for i in idx}
    if info["form"] == "spline":
        knots = info["knots"]
        blocks = []
        for i in idx:
            b = _bspline(ctx.series[i].t, 0.0, ctx.duration_s, knots)
            cc, ss = carrier[i]
            blocks.append((i, np.concatenate([b * cc[:, None], b * ss[:, None]], axis=1), _nuisance(ctx, i)))
        nb = knots + 4
        cov = _gls_covariance(ctx, states, c, blocks, 2 * nb, corr)
        # |1 + shift + u(t)| at the extremes, shift from the reference series' harmonic (C, D)
        t = np.linspace(0.0, ctx.duration_s, 400)
        env = info["relative_envelope"]
        bt = _bspline(t, 0.0, ctx.duration_s, knots)
        co = info["coef"]
        w = 1.0 + info["shift"] + bt @ co[:nb] + 1j * (bt @ co[nb:])
        ref = max(idx, key=lambda i: ctx.nominal[i].amplitude / max(ctx.noise_sigma(i), 1e-12))
        j_ref = idx.index(ref)
        q = _nuisance(ctx, ref).shape[1]
        out = {}
        for name, jt in (("envelope_min", int(np.argmin(env))), ("envelope_max", int(np.argmax(env)))):
            g = np.zeros(cov.shape[0])
            u = np.conj(w[jt]) / max(abs(w[jt]), 1e-300)
            g[:nb] = np.real(u * bt[jt])
            g[nb : 2 * nb] = np.real(u * 1j * bt[jt])
            if not ctx.series[ref].tied and q >= 3:
                h = ctx.nominal[ref]
                e = np.exp(1j * h.phase) / max(h.amplitude, 1e-300)
                k0 = 2 * nb + q * j_ref
                g[k0 + 1], g[k0 + 2] = np.real(u * e), np.real(u * (-1j) * e)
            out[name] = _sd(cov, g)
        return out
    lam = info["decay_per_s"]
    per_series = c.n_params == 1 + 2 * len(idx)
    blocks, coefs = [], []
    for i in idx:
        t = ctx.series[i].t
        e = np.exp(-lam * (t - 0.5 * ctx.duration_s))
        cc, ss = carrier[i]
        x = np.stack([e * cc, e * ss], axis=1)
        nu = _nuisance(ctx, i)
        a, b = wls(np.concatenate([x, nu], axis=1), c.means[i] - states[i].mean, cov=False)[0][:2]
        coefs.append((a, b))
        dl = (-(t - 0.5 * ctx.duration_s) * (a * x[:, 0] + b * x[:, 1]))[:, None]
        if per_series:
            blocks.append((i, dl, np.concatenate([x, nu], axis=1)))
        else:
            blocks.append((i, np.concatenate([dl, x], axis=1), nu))
    cov = _gls_covariance(ctx, states, c, blocks, 1 if per_series else 3, corr)
    sl = math.sqrt(max(cov[0, 0], 0.0))
    return {"decay_per_s": sl, "damping_ratio": sl / (2 * math.pi * ctx.f0_hz)}


def _trend_sigmas(ctx, states, c, corr) -> dict:
    """σ of each series' swing (peak to peak of the term, at the times of its extremes), the step
    time held where the change point put it and the shared shape (``shared``) held fixed."""
    info = c.info
    knots, step, form = info["knots"], info["step_s"], info["form"]

    def cols(i):
        s = ctx.series[i]
        b = _bspline(s.t, 0.0, ctx.duration_s, knots)[:, 1:] if knots is not None else np.zeros((s.n, 0))
        if step is not None:
            b = np.concatenate([b, (s.t > step).astype(float)[:, None]], axis=1)
        return b

    out = {}
    groups: list[list[int]] = []
    if form == "common":
        by_axis: dict[str, list[int]] = {}
        for i in c.series:
            by_axis.setdefault(ctx.series[i].axis, []).append(i)
        groups = list(by_axis.values())
    else:
        groups = [[i] for i in c.series]
    for grp in groups:
        blocks = []
        for i in grp:
            x = cols(i)
            if form == "shared":
                x = (x @ info["shape"])[:, None]
            if form == "common":
                blocks.append((i, x, _nuisance(ctx, i)))
            else:
                blocks.append((i, np.zeros((x.shape[0], 0)), np.concatenate([x, _nuisance(ctx, i)], axis=1)))
        n_sh = blocks[0][1].shape[1]
        cov = _gls_covariance(ctx, states, c, blocks, n_sh, corr if form == "common" else None)
        off = n_sh
        for i, js, xo in blocks:
            d = c.means[i] - states[i].mean
            x = js if form == "common" else xo[:, : cols(i).shape[1] if form != "shared" else 1]
            beta = wls(np.concatenate([x, _nuisance(ctx, i)], axis=1), d, cov=False)[0][: x.shape[1]]
            term = x @ beta
            g_rows = x[int(np.argmax(term))] - x[int(np.argmin(term))]
            g = np.zeros(cov.shape[0])
            if form == "common":
                g[:n_sh] = g_rows
            else:
                g[off : off + x.shape[1]] = g_rows
            out[i] = _sd(cov, g)
            off += xo.shape[1]
    return {"swing_mm": out}


_SIGMAS = {"line": _line_sigmas, "envelope": _envelope_sigmas, "trend": _trend_sigmas}


def term_sigmas(ctx: Context, states: list[State], c, corr: FrameCorrelation | None = None) -> dict:
    """σ's of an accepted term's parameters (`_gls_covariance`); {} when they cannot be had."""
    try:
        return _SIGMAS[c.kind](ctx, states, c, corr)
    except (np.linalg.LinAlgError, ValueError, KeyError, ZeroDivisionError):
        return {}


_BUILDERS = {"line": _line, "envelope": _envelope, "trend": _trend}


# ---------------------------------------------------------------------------------------------
# the search


def _median_sigma(values: dict, sigmas: dict) -> float | None:
    """σ of the series whose value is nearest the reported median (the typical series')."""
    if not sigmas:
        return None
    med = float(np.median(list(values.values())))
    i = min(values, key=lambda j: abs(values[j] - med))
    return sigmas.get(i)


def _report(
    ctx: Context, c: _Candidate, states: list[State], corr: FrameCorrelation | None = None
) -> UnnamedTerm:
    sig = term_sigmas(ctx, states, c, corr)
    plates = sorted({ctx.series[i].plate for i in c.series})
    axes = sorted({ctx.series[i].axis for i in c.series})
    where = f"plate(s) {', '.join(map(str, plates))} ({', '.join(axes)})"
    # located span: where the term moves the model most (its mean change above 10 % of its peak)
    t_lo, t_hi = math.inf, -math.inf
    for i in c.series:
        d = np.abs(c.means[i] - states[i].mean)
        on = d >= 0.1 * d.max() if d.size and d.max() > 0 else np.ones(d.size, bool)
        t = ctx.series[i].t[on]
        if t.size:
            t_lo, t_hi = min(t_lo, float(t.min())), max(t_hi, float(t.max()))
    if not math.isfinite(t_lo):
        t_lo, t_hi = 0.0, ctx.duration_s
    info = c.info
    if c.kind == "line":
        f, lam = info["freq_hz"], info["decay_per_s"]
        amps = info["amplitudes_mm"]
        a_med = float(np.median(list(amps.values())))
        amp_sig = sig.get("amplitudes_mm", {})
        par = {
            "freq_hz": {"value": f, "sigma": sig.get("freq_hz")},
            "amplitude_mm": {"value": a_med, "sigma": _median_sigma(amps, amp_sig)},
        }
        half = max(1.0 / ctx.duration_s, lam / (2 * math.pi))
        text = (
            f"A periodic motion at {f:.4g} Hz ({f / ctx.f0_hz:.3f} × the loading frequency) of about "
            f"{a_med:.3g} mm on {where}"
        )
        if lam > 0:
            zeta = lam / (2 * math.pi * f)
            par["damping_ratio"] = {"value": zeta, "sigma": sig.get("damping_ratio")}
            par["decay_per_s"] = {"value": lam, "sigma": sig.get("decay_per_s")}
            text += (
                f", dying away with a damping ratio of {100 * zeta:.2g} % (a free vibration of a "
                "mode the loading does not drive)"
            )
        if info.get("common"):
            text += " (the same motion on every one of them: the camera or the whole scene vibrating)"
        text += ": structure no named effect explains."
        return UnnamedTerm(
            "line",
            c.series,
            c.means,
            c.n_params,
            par,
            t_lo,
            t_hi,
            [f - half, f + half],
            text,
            detail={
                "amplitudes_mm": {
                    ctx.series[i].key: {"value": a, "sigma": amp_sig.get(i)} for i, a in amps.items()
                }
            },
        )
    if c.kind == "envelope":
        env = info["relative_envelope"]
        lo, hi = float(env.min()), float(env.max())
        par = {
            "form": info["form"],
            "envelope_min": {"value": lo, "sigma": sig.get("envelope_min")},
            "envelope_max": {"value": hi, "sigma": sig.get("envelope_max")},
        }
        if info["form"] == "spline":
            par["knots"] = int(info["knots"])
            shape = f"a smooth envelope ({info['knots']} interior knots)"
        else:
            lam = info["decay_per_s"]
            par["decay_per_s"] = {"value": lam, "sigma": sig.get("decay_per_s")}
            par["damping_ratio"] = {
                "value": lam / (2 * math.pi * ctx.f0_hz),
                "sigma": sig.get("damping_ratio"),
            }
            shape = (
                f"an exponential {'decay' if lam > 0 else 'growth'} (damping ratio "
                f"{100 * lam / (2 * math.pi * ctx.f0_hz):.2g} %)"
            )
        text = (
            f"The amplitude of the motion at {ctx.f0_hz:.4g} Hz changes during the record on {where}: "
            f"{shape}, from {lo:.2f} to {hi:.2f} times the nominal amplitude: structure no named "
            "effect explains (a load ramp, a free decay, a changing stiffness)."
        )
        df = 1.0 / ctx.duration_s
        return UnnamedTerm(
            "envelope",
            c.series,
            c.means,
            c.n_params,
            par,
            t_lo,
            t_hi,
            [
                ctx.f0_hz - 2 * df * (1 + info.get("knots", 0)),
                ctx.f0_hz + 2 * df * (1 + info.get("knots", 0)),
            ],
            text,
        )
    swing = info["swing_mm"]
    s_med = float(np.median(list(swing.values())))
    par = {
        "knots": None if info["knots"] is None else int(info["knots"]),
        "form": info["form"],
        "swing_mm": {"value": s_med, "sigma": _median_sigma(swing, sig.get("swing_mm", {}))},
    }
    shape = {
        "own": "each plate its own way",
        "shared": "one shape shared by the plates, a scale each",
        "common": "the same motion on every plate: the camera or the whole scene moving",
    }[info["form"]]
    if info["knots"] is None:
        shape += ", a step alone"
    if info["step_s"] is not None:
        par["step_at_s"] = {"value": float(info["step_s"]), "sigma": None}
        shape += f", with a step at {info['step_s']:.1f} s"
    text = (
        f"The measured position wanders slowly by about {s_med:.3g} mm (peak to peak) on {where} "
        f"({shape}): structure no named effect explains."
    )
    return UnnamedTerm(
        "trend",
        c.series,
        c.means,
        c.n_params,
        par,
        t_lo,
        t_hi,
        [0.0, ((info["knots"] or 0) + 1) / ctx.duration_s],
        text,
        detail={
            "swing_mm": {
                ctx.series[i].key: {"value": v, "sigma": sig.get("swing_mm", {}).get(i)}
                for i, v in swing.items()
            }
        },
    )


def best_term(
    ctx: Context,
    states: list[State],
    corr: FrameCorrelation | None = None,
    bases: dict | None = None,
    kinds: tuple[str, ...] = KINDS,
):
    """The best generic term on the residual of ``states``: (ΔBIC, candidate) or None. Every
    kind of ``kinds`` screens (grids, linear fits); the best candidate alone is refined (its
    ``refine``) when its ΔBIC is below `REFINE_BELOW`, and kept refined when that scores better.
    ``bases``: the search's cache of spline bases."""
    n_total = sum(s.n for s in ctx.series)
    noise = _Noise(ctx, states, bases, corr)
    best = None
    for kind in kinds:
        try:
            cands = _BUILDERS[kind](ctx, states, noise, n_total)
        except np.linalg.LinAlgError:  # one generic term that cannot be fitted never stops the rest
            cands = []
        for c in cands:
            d = _score(ctx, noise, states, corr, c, n_total)
            if best is None or d < best[0]:
                best = (d, c)
    if best is not None and best[1].refine is not None and best[0] < REFINE_BELOW:
        q = best[1].refine()
        if q is not None:
            d = _score(ctx, noise, states, corr, q, n_total)
            if d < best[0]:
                best = (d, q)
    return best


def _term_states(ctx: Context, base: list[State], deltas: list[dict[int, np.ndarray]], cands) -> list[State]:
    """``base`` with every accepted term's mean change added."""
    states = list(base)
    for d, c in zip(deltas, cands, strict=True):
        for i, v in d.items():
            st = states[i]
            states[i] = st.with_(
                mean=st.mean + v,
                n_params=st.n_params + max(1, round(c.n_params / len(c.series))),
                effects=st.effects + ("unnamed",),
            )
    return states


def _as_term(ctx: Context, states: list[State], best, corr: FrameCorrelation | None = None) -> UnnamedTerm:
    dbic, c = best
    rms0 = float(np.sqrt(np.mean(np.concatenate([ctx.series[i].y - states[i].mean for i in c.series]) ** 2)))
    rms1 = float(np.sqrt(np.mean(np.concatenate([ctx.series[i].y - c.means[i] for i in c.series]) ** 2)))
    term = _report(ctx, c, states, corr)
    term.delta_bic, term.rms_before_mm, term.rms_after_mm = float(dbic), rms0, rms1
    term.change = {i: c.means[i] - states[i].mean for i in c.series}
    term.candidate = c
    return term


def apply_term(
    ctx: Context, states: list[State], best, corr: FrameCorrelation | None = None
) -> tuple[UnnamedTerm, list[State]]:
    """The accepted term's report and the states with it."""
    c = best[1]
    delta = {i: c.means[i] - states[i].mean for i in c.series}
    return _as_term(ctx, states, best, corr), _term_states(ctx, states, [delta], [c])


def search_unnamed(
    ctx: Context,
    states: list[State],
    corr: FrameCorrelation | None = None,
    max_terms: int = MAX_TERMS,
    check=None,
    bases: dict | None = None,
    backfit: int = 2,
    prior: list[UnnamedTerm] = (),
) -> tuple[list[UnnamedTerm], list[State]]:
    """Greedy generic terms on the residual of ``states``: (accepted terms, the states after).
    ``prior``: terms already in ``states`` (accepted while competing with the named effects):
    they are backfitted with the new ones and returned first.

    Then ``backfit`` passes: each term, in turn, is fitted again (its kind's best) on the residual
    of all the others, and dropped when, given them, it no longer reaches ΔBIC < −10 (a line
    fitted while a larger decay was still in the residual leaves a spurious neighbour)."""
    bases = {} if bases is None else bases
    deltas: list[dict[int, np.ndarray]] = [dict(u.change) for u in prior]
    cands: list = [u.candidate for u in prior]
    base = list(states)
    for d in deltas:
        for i, v in d.items():
            base[i] = base[i].with_(mean=base[i].mean - v)
    for _ in range(max_terms - len(prior)):
        cur = _term_states(ctx, base, deltas, cands)
        best = best_term(ctx, cur, corr, bases)
        if check is not None:
            check()
        if best is None or not best[0] < DELTA_BIC_MAX:
            break
        c = best[1]
        deltas.append({i: c.means[i] - cur[i].mean for i in c.series})
        cands.append(c)
    scores = [None] * len(cands)
    for _ in range(backfit if len(cands) > 1 else 0):
        j = 0
        while j < len(cands):
            others = _term_states(ctx, base, deltas[:j] + deltas[j + 1 :], cands[:j] + cands[j + 1 :])
            best = best_term(ctx, others, corr, bases, kinds=(cands[j].kind,))
            if check is not None:
                check()
            if best is None or not best[0] < DELTA_BIC_MAX:
                del deltas[j], cands[j], scores[j]
                continue
            c = best[1]
            deltas[j] = {i: c.means[i] - others[i].mean for i in c.series}
            cands[j] = c
            scores[j] = (best[0], others)
            j += 1
    terms = []
    for j, c in enumerate(cands):
        others = _term_states(ctx, base, deltas[:j] + deltas[j + 1 :], cands[:j] + cands[j + 1 :])
        if scores[j] is None:  # no backfit: the greedy's own evidence, on the terms before it
            before = _term_states(ctx, base, deltas[:j], cands[:j])
            n_total = sum(s.n for s in ctx.series)
            d = _score(ctx, _Noise(ctx, before, bases), before, corr, c, n_total)
            terms.append(_as_term(ctx, before, (d, c), corr))
        else:
            terms.append(_as_term(ctx, others, (scores[j][0], c), corr))
    return terms, _term_states(ctx, base, deltas, cands)
