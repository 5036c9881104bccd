"""Screening series for an effect, and the state helpers every effect module uses: residuals and
weights of the current states, contract parameters, updated states (harmonic_distortion, drift,
level_jump, outliers, heteroscedastic_noise, quantization screen with the rest: weighted
projections out of the free nuisance, per-series likelihood gains and scan-corrected p-values).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import stats

from ..._numerics import wls
from .._base import Context, State, loglik, weights

__all__ = [
    "residual",
    "weights",
    "param",
    "gain",
    "updated",
    "chi2_sf",
    "bonferroni",
    "combined_p",
    "project_out",
    "screen_columns",
    "screen_grid",
    "touched",
    "long_run_factor",
    "open_series",
    "median_signed",
    "SharedAmplitude",
    "shared_amplitude",
    "subset_trials",
    "changepoint_trials",
    "scanned",
]


def subset_trials(n_kept: int, n_candidates: int) -> float:
    """The look-elsewhere factor of picking the series a per-series term is kept on: under no
    effect the likeliest pick is one series of ``n_candidates`` (Bonferroni over them); a term
    kept on all candidates was not picked."""
    return 1.0 if n_kept >= n_candidates else float(n_candidates)


def scanned(prop, trials: float, scan_params: int):
    """``prop`` (and the refit its ``refine`` returns) with its scan's look-elsewhere factor
    and the parameters the scan fixed (`Proposal.trials`, `Proposal.scan_params`)."""

    def mark(q):
        if q is not None:
            q.trials, q.scan_params = float(trials), int(scan_params)
        return q

    if prop is not None:
        mark(prop)
        if prop.refine is not None:
            prop.refine = (lambda f: lambda: mark(f()))(prop.refine)
    return prop


def changepoint_trials(edge: float, n_splits: int, u: float = 25.0) -> float:
    """The effective number of independent splits of a mean-change scan over the fractions
    [edge, 1 − edge] of a record: neighbouring splits are nearly the same test. Siegmund's
    approximation of the maximum of the standardised CUSUM (a Brownian bridge over √(s(1 − s))),
    P(max > u) ≈ √u φ(√u) · 2 log((1 − edge)/edge) + 4 φ(√u)/√u, over one split's χ²_1 tail, at
    u = 25 (above the critical values the search uses: the ratio grows with u, so this errs on
    the safe side); at most the number of splits. Checked by simulation: 7000 splits, edge 0.01,
    P(max > 15) 0.0087 simulated against 0.0081."""
    b = math.sqrt(u)
    phi = math.exp(-0.5 * u) / math.sqrt(2 * math.pi)
    tail = b * phi * 2.0 * math.log((1.0 - edge) / edge) + 4.0 * phi / b
    return float(min(max(tail / float(stats.chi2.sf(u, 1)), 1.0), max(n_splits, 1)))


def residual(ctx: Context, i: int, st: State) -> np.ndarray:
    """(sample,) y − mean of series i."""
    return ctx.series[i].y - st.mean


def param(value, sigma=None) -> dict:
    """A contract parameter {"value": v, "sigma": s} with JSON-able floats (None for NaN)."""

    def clean(x):
        if x is None or isinstance(x, str):
            return x
        x = float(x)
        return x if math.isfinite(x) else None

    return {"value": clean(value), "sigma": clean(sigma)}


def gain(ctx: Context, i: int, old: State, new: State) -> float:
    """Log-likelihood gain of series i from ``old`` to ``new`` (`_base.loglik`)."""
    y = ctx.series[i].y
    return loglik(y, new) - loglik(y, old)


def updated(st: State, effect: str, k_own: int, **kw) -> State:
    """The state with the effect's changes, its own parameter count and the effect id added."""
    return st.with_(n_params=st.n_params + int(k_own), effects=st.effects + (effect,), **kw)


def touched(st: State, effect: str) -> bool:
    return effect in st.effects


def open_series(ctx, states: list[State], effect: str, min_samples: int = 64) -> list[int]:
    """Series an effect may still propose on: not already carrying it, ``min_samples`` or more."""
    return [
        i for i in range(len(ctx.series)) if not touched(states[i], effect) and ctx.series[i].n >= min_samples
    ]


def chi2_sf(x, dof) -> np.ndarray:
    """Survival function of χ²_dof (vectorised, 1 for x <= 0)."""
    x = np.maximum(np.asarray(x, dtype=float), 0.0)
    return stats.chi2.sf(x, dof)


def bonferroni(p, m: float) -> float:
    return float(min(1.0, float(p) * max(float(m), 1.0)))


def combined_p(
    single: np.ndarray,
    dof_single: int,
    n_scan: float,
    total: float | None = None,
    dof_total: int | None = None,
    n_scan_total: float | None = None,
) -> float:
    """Scan-corrected p-value of a signature seen on some of many series.

    Two tests, each Bonferroni-corrected for the scan, and the smaller one doubled: the largest
    single-series statistic (χ²_dof_single, over all series and ``n_scan`` scanned alternatives),
    and optionally a statistic summed over all series (χ²_dof_total, over ``n_scan_total``).
    """
    single = np.asarray(single, dtype=float)
    p = bonferroni(chi2_sf(single.max(initial=0.0), dof_single), n_scan * max(single.size, 1))
    if total is not None:
        p = min(p, bonferroni(chi2_sf(total, dof_total), n_scan_total or 1.0))
        p = min(1.0, 2.0 * p)
    return float(p)


def project_out(nu: np.ndarray, w: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """(sample, k) columns made W-orthogonal to the nuisance columns ``nu`` (sample, q)."""
    nw = nu * w[:, None]
    gram = nw.T @ nu
    coef = np.linalg.solve(gram + 1e-12 * np.trace(gram) * np.eye(gram.shape[0]), nw.T @ cols)
    return cols - nu @ coef


def screen_columns(nu: np.ndarray, w: np.ndarray, r: np.ndarray, cols: np.ndarray):
    """Each column alone, with the nuisance free, against the residual: its χ²_1 statistic.

    Args:
        nu: (sample, q) nuisance; w: (sample,) weights; r: (sample,) residual;
        cols: (sample, c) candidate columns (e.g. one per grid value of a nonlinear parameter).
    Returns:
        (stat (c,), beta (c,)): the drop of the weighted RSS over σ̂² (σ̂² from ``r`` after the
        nuisance), and each column's coefficient.
    """
    nw = nu * w[:, None]
    gram = nw.T @ nu
    gram = gram + 1e-12 * np.trace(gram) * np.eye(gram.shape[0])
    a_r = np.linalg.solve(gram, nw.T @ r)
    r0 = r - nu @ a_r
    n_used = max(int((w > 0).sum()) - nu.shape[1], 1)
    s2 = float(np.sum(w * r0 * r0) / n_used) or 1e-300
    cw = cols * w[:, None]
    ctr = cw.T @ r0  # (c,) — r0 is W-orthogonal to nu, so this is the projected product
    ctn = cw.T @ nu  # (c, q)
    ctc = np.einsum("sc,sc->c", cw, cols) - np.einsum("cq,cq->c", ctn, np.linalg.solve(gram, ctn.T).T)
    ctc = np.maximum(ctc, 1e-300)
    beta = ctr / ctc
    return ctr * ctr / ctc / s2, beta


def long_run_factor(ctx: Context, i: int, r: np.ndarray) -> float:
    """(1 + ρ)/(1 − ρ), at least 1: how much more a slow term's statistic varies than white
    noise predicts, ρ the lag-one autocorrelation of the residual ``r`` of series i on the
    frame clock (pairs of consecutive frames). Noise correlated from frame to frame (AR(1),
    a camera's slowly wandering range error) has its power near zero frequency raised by this
    factor, where drifts and jumps live; the slow signatures divide their statistics by it.
    A slow effect in ``r`` raises ρ by its share of the variance (conservative)."""
    s = ctx.series[i]
    g = np.full(ctx.n_frames, np.nan)
    g[s.k] = r - r.mean()
    a, b = g[:-1], g[1:]
    ok = np.isfinite(a) & np.isfinite(b)
    if ok.sum() < 32:
        return 1.0
    rho = float(np.sum(a[ok] * b[ok]) / math.sqrt(np.sum(a[ok] ** 2) * np.sum(b[ok] ** 2)))
    rho = min(max(rho, 0.0), 0.95)
    return (1.0 + rho) / (1.0 - rho)


def median_signed(values: np.ndarray) -> float:
    """The median of signed per-series amplitudes; of their sizes when the signs disagree
    (between 20 and 80 % positive)."""
    values = np.asarray(values, dtype=float)
    pos = float(np.mean(values > 0))
    if 0.2 < pos < 0.8:
        return float(np.median(np.abs(values)))
    return float(np.median(values))


def screen_grid(
    ctx: Context, states: list[State], idx: list[int], nus: dict, cols: np.ndarray, chunk: int = 8
):
    """`screen_columns` for many series at once, with columns given on the frame clock.

    Args:
        idx: the series; nus: {series: (sample, q) nuisance}; cols: (frame, c) candidate columns
            on the frame clock (``k`` of each sample picks its row).
    Returns:
        (stat (series, c), beta (series, c), info (series, c)): χ²_1 statistic, coefficient and
        Fisher information (1/variance of the coefficient) of every column alone (nuisance free)
        on every series; stat = beta² info. A coefficient shared by several series has the
        information Σ info and the statistic (Σ beta info)² / Σ info. The products are GEMMs
        over the frame clock, a few series at a time (memory).
    """
    nf, c = cols.shape
    stat = np.zeros((len(idx), c))
    beta = np.zeros((len(idx), c))
    info = np.zeros((len(idx), c))
    sq = cols * cols
    for start in range(0, len(idx), chunk):
        part = idx[start : start + chunk]
        qmax = max(nus[i].shape[1] for i in part)
        wg = np.zeros((nf, len(part)))
        rg = np.zeros((nf, len(part)))
        ng = np.zeros((nf, len(part) * qmax))
        grams, s2 = [], []
        for j, i in enumerate(part):
            s, st = ctx.series[i], states[i]
            w = weights(st)
            nu = nus[i]
            nw = nu * w[:, None]
            gram = nw.T @ nu
            gram = gram + 1e-12 * np.trace(gram) * np.eye(gram.shape[0])
            r = s.y - st.mean
            r0 = r - nu @ np.linalg.solve(gram, nw.T @ r)
            n_used = max(int((w > 0).sum()) - nu.shape[1], 1)
            s2.append((float(np.sum(w * r0 * r0)) / n_used or 1e-300) * long_run_factor(ctx, i, r0))
            wg[s.k, j] = w
            rg[s.k, j] = w * r0
            ng[s.k, j * qmax : j * qmax + nu.shape[1]] = nw
            grams.append(gram)
        ctr = cols.T @ rg  # (c, part)
        ctc = sq.T @ wg  # (c, part)
        ctn = cols.T @ ng  # (c, part × q)
        for j, i in enumerate(part):
            q = nus[i].shape[1]
            cn = ctn[:, j * qmax : j * qmax + q]
            proj = np.einsum("cq,cq->c", cn, np.linalg.solve(grams[j], cn.T).T)
            den = np.maximum(ctc[:, j] - proj, 1e-300)
            row = start + j
            beta[row] = ctr[:, j] / den
            stat[row] = ctr[:, j] ** 2 / den / s2[j]
            info[row] = den / s2[j]
    return stat, beta, info


@dataclass
class SharedAmplitude:
    """A term with the same linear coefficients on every series it touches (a common mode).

    Attributes:
        beta, cov: (k,) the shared coefficients and their covariance.
        stat: χ²_k statistic of the shared term over all the candidate series (before any
            selection: the honest signature).
        series: the series kept (each one's own likelihood gain positive: it has no parameter
            of its own to pay for).
        states: {series: new State}; gains: {series: log-likelihood gain}.
    """

    beta: np.ndarray
    cov: np.ndarray
    stat: float
    series: list[int]
    states: dict
    gains: dict


def shared_amplitude(
    ctx: Context,
    states: list[State],
    idx: list[int],
    cols_of,
    nus: dict | None,
    effect: str,
    k_own: int = 0,
) -> SharedAmplitude | None:
    """Fit columns with one set of coefficients shared by the series ``idx`` (nuisance free per
    series), drop the series whose own gain is not positive, refit, and build the new states.

    Args:
        cols_of: ``cols_of(i) -> (sample, k)`` the columns on series i.
        nus: {series: nuisance} (computed when missing).
        k_own: parameters each kept series adds to its own `State.n_params` (0: all shared).
    """
    parts = {}
    for i in idx:
        s, st = ctx.series[i], states[i]
        c = cols_of(i)
        nu = nus[i] if nus is not None and i in nus else ctx.nuisance(i)
        w = weights(st)
        r = s.y - st.mean
        both = project_out(nu, w, np.concatenate([c, r[:, None]], axis=1))
        cp, rp = both[:, :-1], both[:, -1]
        cw = cp * w[:, None]
        n_used = max(int((w > 0).sum()) - nu.shape[1], 1)
        s2 = float(np.sum(w * rp * rp)) / n_used or 1e-300
        parts[i] = (cw.T @ cp, cw.T @ rp, s2, c, nu, w)
    if not parts:
        return None

    def solve(sel):
        a = sum(parts[i][0] / parts[i][2] for i in sel)
        b = sum(parts[i][1] / parts[i][2] for i in sel)
        cov = np.linalg.pinv(a)
        return cov @ b, cov, float(b @ cov @ b)

    beta, cov, stat = solve(list(parts))
    sel = list(parts)
    for _ in range(2):
        g = {i: (2 * beta @ parts[i][1] - beta @ parts[i][0] @ beta) / (2 * parts[i][2]) for i in sel}
        nxt = [i for i in sel if g[i] > 0]
        if not nxt or nxt == sel:
            break
        sel = nxt
        beta, cov, _ = solve(sel)
    new, gains = {}, {}
    for i in sel:
        st = states[i]
        _, _, _, c, nu, w = parts[i]
        term = c @ beta
        r = ctx.series[i].y - st.mean - term
        cand = updated(st, effect, k_own, mean=st.mean + term + wls(nu, r, w, cov=False)[2])
        d = gain(ctx, i, st, cand)
        if d > 0:
            new[i], gains[i] = cand, d
    if not new:
        return None
    return SharedAmplitude(beta=beta, cov=cov, stat=stat, series=sorted(new), states=new, gains=gains)
