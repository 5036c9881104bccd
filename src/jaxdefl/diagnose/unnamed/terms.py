"""The open world's generic terms, each chosen by BIC (`BUILDERS`: kind -> screening):

- ``line``: a sinusoid at the peak of the residual periodograms summed over an axis' series,
  optionally decaying (a free vibration), per-series amplitudes or one common to the axis;
- ``envelope``: a smooth complex envelope of the loading line (B-spline or exponential);
- ``trend``: a slow additive B-spline per series, shared, or common to an axis' series;

and the σ's of an accepted term's parameters (`term_sigmas`, under the noise model of
`jaxdefl.diagnose.unnamed.noise`)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import jax.numpy as jnp
import numpy as np
import scipy.sparse as sp
from scipy import stats
from scipy.interpolate import BSpline
from scipy.ndimage import median_filter

from ..._numerics import harmonic_design, wls
from .._base import Context, State, masked_periodogram, peak_offset, weights
from .._correlation import FrameCorrelation
from .._varpro import fit_shared
from .noise import Noise, gls_covariance, linear_sd

__all__ = ["BUILDERS", "Candidate", "KNOTS", "bspline", "shared_fit", "term_sigmas"]


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
# λ grid of the decays, in units of 1/duration (e-folds over the record)
_DECAY_GRID = np.concatenate([[0.0], np.geomspace(0.05, 40.0, 12)])  # refined by optimistix


def _nuisance(ctx: Context, i: int, offset_only: bool = False) -> np.ndarray:
    nu = ctx.nuisance(i)
    return nu[:, :1] if offset_only else nu


def _basis(noise: Noise, i: int, knots: int) -> np.ndarray:
    """Series i's cubic B-spline basis over the record (cached in the search's ``noise.bases``)."""
    key = (i, knots)
    if key not in noise.bases:
        b = bspline(noise.ctx.series[i].t, 0.0, noise.ctx.duration_s, knots)
        b.setflags(write=False)
        noise.bases[key] = b
    return noise.bases[key]


def bspline(t: np.ndarray, t_lo: float, t_hi: float, knots: int, sparse: bool = False):
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
class Candidate:
    kind: str
    series: list[int]
    means: dict[int, np.ndarray]
    n_params: int
    info: dict
    refine: object = None  # () -> Candidate or None: the full fit, run only on the chosen term


def _line(ctx: Context, states: list[State], noise: Noise, n_total: int) -> list[Candidate]:
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

                beta, m_ax, _ = shared_fit(ctx, states, idx, cols_of, proj)
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
            out.append(Candidate("line", idx, means, k_par, dict(info, common=True)))
            continue
        if best is None:
            continue
        amps = {i: float(math.hypot(*fits[i])) for i in kept}
        info = {"freq_hz": f, "decay_per_s": lam, "amplitudes_mm": amps, "axis": axis}
        cand = Candidate("line", kept, means, k_par, info)
        cand.refine = lambda c=cand: _refine_line(ctx, states, c)
        out.append(cand)
    return out


def _refine_line(ctx: Context, states: list[State], c: Candidate) -> Candidate | None:
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
    return Candidate("line", c.series, means, (2 if lam > 0 else 1) + 2 * len(c.series), info)


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


def shared_fit(ctx, states, idx, cols_of, projections=None):
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


def _envelope(ctx: Context, states: list[State], noise: Noise, n_total: int) -> list[Candidate]:
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
        beta, means, gammas = shared_fit(ctx, states, idx, cols_of, projections)
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
            b = _basis(noise, i, knots)
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

    def refine() -> Candidate | None:
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
        return Candidate("envelope", idx, means, 1 + 2 * len(idx), info)

    _, means, k_par, info = chosen
    info["relative_envelope"] = _relative_envelope(ctx, info)
    return [Candidate("envelope", idx, means, k_par, info, refine)]


def _relative_envelope(ctx: Context, info: dict) -> np.ndarray:
    """|1 + shift + u(t)| on 400 times over the record: the amplitude relative to the nominal."""
    t = np.linspace(0.0, ctx.duration_s, 400)
    if info["form"] == "spline":
        b = bspline(t, 0.0, ctx.duration_s, info["knots"])
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


def _trend(ctx: Context, states: list[State], noise: Noise, n_total: int) -> list[Candidate]:
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
            _, m_ax, _ = shared_fit(ctx, states, idx, cols_of)
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
            b = _basis(noise, i, knots)[:, 1:] if knots is not None else np.zeros((s.n, 0))
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
            return bspline(ctx.series[i].t, 0.0, ctx.duration_s, knots, sparse=True)[:, 1:]

        dbic = common(fine, knots + 3, 0, {"knots": knots, "step_s": None})
        worse = worse + 1 if dbic >= prev else 0
        prev = min(prev, dbic)
        if worse >= 2:
            break
    if best is None:
        return []
    _, kept, means, k_par, info = best
    info["swing_mm"] = {i: float(np.ptp(means[i] - states[i].mean)) for i in kept}
    return [Candidate("trend", kept, means, k_par, info)]


def _decaying_line(s, f: float, lam: float):
    """(τ since the series' start, e^{−λτ}, cos 2πft, sin 2πft) of a line at f Hz decaying at
    λ /s on series ``s``."""
    tau = s.t - s.t[0]
    _, ca, sa = harmonic_design(2 * np.pi * f * s.t).T
    return tau, np.exp(-lam * tau), ca, sa


def _frequency_sigmas(cov: np.ndarray, f: float, lam: float) -> dict:
    """σ of a line's frequency and, when it decays (λ > 0), of its decay rate and damping ratio
    ζ = λ / 2πf, from the covariance whose first rows are (f, λ)."""
    out = {"freq_hz": math.sqrt(max(cov[0, 0], 0.0))}
    if lam > 0:
        out["decay_per_s"] = math.sqrt(max(cov[1, 1], 0.0))
        zeta = lam / (2 * np.pi * f)
        out["damping_ratio"] = linear_sd(cov[:2, :2], np.array([-zeta / f, 1.0 / (2 * np.pi * f)]))
    return out


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
        tau, e, ca, sa = _decaying_line(s, f, lam)
        x = np.stack([e * ca, e * sa, np.ones_like(tau)], axis=1)
        a, b = wls(x, c.means[i] - states[i].mean, cov=False)[0][:2]
        js = [e * 2 * np.pi * s.t * (-a * sa + b * ca)]
        if free_decay:
            js.append(-tau * e * (a * ca + b * sa))
        blocks.append((i, np.stack(js, axis=1), x))
        ab.append((a, b))
    cov = gls_covariance(ctx, states, c, blocks, n_sh, corr)
    out = _frequency_sigmas(cov, f, lam)
    amps = {}
    for j, (i, (a, b)) in enumerate(zip(c.series, ab, strict=True)):
        amp = math.hypot(a, b)
        g = np.zeros(cov.shape[0])
        g[n_sh + 3 * j : n_sh + 3 * j + 2] = (a / amp, b / amp) if amp > 0 else (1.0, 0.0)
        amps[i] = linear_sd(cov, g)
    out["amplitudes_mm"] = amps
    return out


def _common_line_sigmas(ctx, states, c, corr, f, lam) -> dict:
    """`_line_sigmas` of a line common to the series: shared frequency, decay, amplitude and
    phase, each series' nuisance free."""
    free_decay = lam > 0
    cols, xs = {}, {}
    for i in c.series:
        cols[i] = tau, e, ca, sa = _decaying_line(ctx.series[i], f, lam)
        xs[i] = np.stack([e * ca, e * sa], axis=1)
    a, b = shared_fit(ctx, states, c.series, lambda i: xs[i])[0]
    blocks = []
    for i in c.series:
        tau, e, ca, sa = cols[i]
        js = [e * 2 * np.pi * ctx.series[i].t * (-a * sa + b * ca)]
        if free_decay:
            js.append(-tau * e * (a * ca + b * sa))
        blocks.append((i, np.concatenate([np.stack(js, axis=1), xs[i]], axis=1), _nuisance(ctx, i)))
    n_nl = 2 if free_decay else 1
    cov = gls_covariance(ctx, states, c, blocks, n_nl + 2, corr)
    out = _frequency_sigmas(cov, f, lam)
    amp = math.hypot(a, b)
    g = np.zeros(cov.shape[0])
    g[n_nl : n_nl + 2] = (a / amp, b / amp) if amp > 0 else (1.0, 0.0)
    sd = linear_sd(cov, g)
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
            b = bspline(ctx.series[i].t, 0.0, ctx.duration_s, knots)
            cc, ss = carrier[i]
            blocks.append((i, np.concatenate([b * cc[:, None], b * ss[:, None]], axis=1), _nuisance(ctx, i)))
        nb = knots + 4
        cov = gls_covariance(ctx, states, c, blocks, 2 * nb, corr)
        # |1 + shift + u(t)| at the extremes, shift from the reference series' harmonic (C, D)
        t = np.linspace(0.0, ctx.duration_s, 400)
        env = info["relative_envelope"]
        bt = bspline(t, 0.0, ctx.duration_s, knots)
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
            out[name] = linear_sd(cov, g)
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
    cov = gls_covariance(ctx, states, c, blocks, 1 if per_series else 3, corr)
    sl = math.sqrt(max(cov[0, 0], 0.0))
    return {"decay_per_s": sl, "damping_ratio": sl / (2 * math.pi * ctx.f0_hz)}


def _trend_sigmas(ctx, states, c, corr) -> dict:
    """σ of each series' swing (peak to peak of the term, at the times of its extremes), the step
    time held where the change point put it and the shared shape (``shared``) held fixed."""
    info = c.info
    knots, step, form = info["knots"], info["step_s"], info["form"]

    def cols(i):
        s = ctx.series[i]
        b = bspline(s.t, 0.0, ctx.duration_s, knots)[:, 1:] if knots is not None else np.zeros((s.n, 0))
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
        cov = gls_covariance(ctx, states, c, blocks, n_sh, corr if form == "common" else None)
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
            out[i] = linear_sd(cov, g)
            off += xo.shape[1]
    return {"swing_mm": out}


_SIGMAS = {"line": _line_sigmas, "envelope": _envelope_sigmas, "trend": _trend_sigmas}


def term_sigmas(ctx: Context, states: list[State], c, corr: FrameCorrelation | None = None) -> dict:
    """σ's of an accepted term's parameters (`gls_covariance`); {} when they cannot be had."""
    try:
        return _SIGMAS[c.kind](ctx, states, c, corr)
    except (np.linalg.LinAlgError, ValueError, KeyError, ZeroDivisionError):
        return {}


BUILDERS = {"line": _line, "envelope": _envelope, "trend": _trend}
