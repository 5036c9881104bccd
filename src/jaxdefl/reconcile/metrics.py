"""What a recording and a simulation are compared on, and how far apart two tables are.

Each table is reduced, per plate and axis, to statistics of its residual about the loading
harmonic (a linear least-squares fit at the recording's f0, so that the comparison does not
depend on the frequency estimate of a noisy table):

==============  =============  ==========================================================
metric          level          statistic per series (distance: RMS of log ratios)
==============  =============  ==========================================================
noise_mm        trajectories   the residual's short-term noise (first differences, MAD)
slow_mm         trajectories   RMS of the residual's means over 10-s bins (drifts, jumps)
line_ratio      trajectories   largest / mean power of the residual's periodogram above
                               0.1 Hz (lines)
frame_common    trajectories   correlation of the plates' frame-to-frame residual changes
                               (noise shared by a frame; distance: the absolute difference)
outlier_rate    trajectories   share of samples beyond 4.5 noise σ's (plus one, over n + 1)
envelope        estimates      RMS change of the harmonic's complex amplitude over ten
                               windows, relative to its size (modulations, fatigue)
==============  =============  ==========================================================

A distance is 0 for identical statistics; its null band comes from repeated simulation
(`jaxdefl.reconcile.reconcile`): the 95th percentile of the null distances (`null_95`). The
verdicts are read against `null_family`, the same distances' 1 − 0.05/`FAMILY` percentile: a
recording is judged on all the metrics at once, and with `FAMILY` = 9 metrics each at its own
95th percentile a recording of the simulated model itself would lie outside at least one band
1 − 0.95⁹ = 37 % of the time; at 1 − 0.05/9 it does so at most 5 % of the time (Bonferroni).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pandas as pd

from .._numerics import harmonic_design, mad_sigma, wls

__all__ = [
    "FAMILY",
    "METRICS",
    "TableStats",
    "distance",
    "frame_common_correlation",
    "null_95",
    "null_family",
    "outlier_sizes",
    "series_residuals",
    "short_term_noise",
    "table_stats",
]

# with fewer null distances than this, their empirical 95th percentile is an order statistic
# too near the maximum to trust (4 clips give about the 80th): a parametric bound is used
EMPIRICAL_MIN = 20

METRICS = {
    "noise_mm": "trajectories",
    "slow_mm": "trajectories",
    "line_ratio": "trajectories",
    "frame_common": "trajectories",
    "outlier_rate": "trajectories",
    "envelope": "estimates",
}
# the metrics a recording is judged on at once (these six, the frames level's two and the clock
# level's one, `jaxdefl.reconcile.clock`): the family over which the verdicts share α = 0.05
FAMILY = 9
FAMILY_Q = 1.0 - 0.05 / FAMILY
BIN_S = 10.0
N_WINDOWS = 10
MIN_SAMPLES = 40
OUTLIER_SIGMAS = 4.5  # `outlier_rate`: samples this many noise σ's from the residual's median


@dataclass
class TableStats:
    """Per-series statistics (index: "plate/axis") and the frame-common correlation."""

    series: pd.DataFrame
    frame_common: float


def short_term_noise(r: np.ndarray) -> float:
    """σ of the white part of a residual from its first differences: robust (MAD) unless the
    values sit on a lattice where most differences are 0 (then the plain deviation)."""
    d = np.diff(r)
    if d.size < 2:
        return float("nan")
    mad = mad_sigma(d) / math.sqrt(2.0)
    plain = float(np.std(d)) / math.sqrt(2.0)
    return mad if mad >= 0.5 * plain else plain


def frame_common_correlation(resid: np.ndarray) -> float:
    """Mean pairwise correlation across plates (columns) of the frame-to-frame changes of their
    residuals (frames as rows): noise shared by a frame's plates, blind to slow structure."""
    d = np.diff(resid, axis=0)
    d = d[:, d.std(0) > 0]
    if d.shape[1] < 2:
        return float("nan")
    c = np.corrcoef(d, rowvar=False)
    return float(c[np.triu_indices_from(c, 1)].mean())


def _design(t: np.ndarray, omega: float) -> np.ndarray:
    """Offset, cos, sin at ω, and u·cos, u·sin (u = t − mid, per 100 s): the last two absorb a
    small error of ω, which would otherwise leave the motion, shared by every plate, in the
    residuals (and so in their frame-common correlation)."""
    u = (t - 0.5 * (t[0] + t[-1])) / 100.0
    h = harmonic_design(omega * t)
    return np.concatenate([h, u[:, None] * h[:, 1:]], axis=1)


def outlier_sizes(r: np.ndarray, noise: float) -> np.ndarray:
    """The residual's samples beyond `OUTLIER_SIGMAS` noise σ's from its median, in σ's (signed)."""
    u = (r - np.median(r)) / noise if noise > 0 else np.zeros_like(r)
    return u[np.abs(u) > OUTLIER_SIGMAS]


def _harmonic_fits(df: pd.DataFrame, f0_hz: float, axes: tuple[str, ...]):
    """(plate, axis, t since the table's first stamp, y, design, β, residual) of every series with
    at least `MIN_SAMPLES` finite values, fitted with the harmonic at ``f0_hz`` (`_design`)."""
    omega = 2 * math.pi * f0_hz
    t_first = float(df["t"].min())
    for plate, g in df.groupby("plate", sort=True):
        t_all = g["t"].to_numpy() - t_first
        for axis in axes:
            if axis not in g:
                continue
            y = g[axis].to_numpy()
            ok = np.isfinite(y)
            if ok.sum() < MIN_SAMPLES:
                continue
            t, y = t_all[ok], y[ok]
            a = _design(t, omega)
            beta, _, fitted = wls(a, y, cov=False)
            yield int(plate), axis, t, y, a, beta, y - fitted


def series_residuals(df: pd.DataFrame, f0_hz: float, axes: tuple[str, ...] = ("z", "x", "y")):
    """{(plate, axis): (t since the table's first stamp, residual, its short-term noise)} of the
    series `table_stats` measures (at least `MIN_SAMPLES` finite values), about the harmonic at
    ``f0_hz`` (`_design`)."""
    return {
        (plate, axis): (t, r, short_term_noise(r))
        for plate, axis, t, _, _, _, r in _harmonic_fits(df, f0_hz, axes)
    }


def _periodogram_ratio(t: np.ndarray, r: np.ndarray, dt: float) -> float:
    """Peak-to-mean power of the residual on the frame grid (gaps left at zero)."""
    k = np.round((t - t[0]) / dt).astype(np.int64)
    n = int(k[-1]) + 1
    if n > 1 << 22:  # a clock far from regular: no grid
        return float("nan")
    g = np.zeros(n)
    g[k] = r - r.mean()
    lo = max(2, int(np.ceil(n * dt / BIN_S)))  # below 1 / BIN_S: the slow statistic's business
    p = np.abs(np.fft.rfft(g)[lo:]) ** 2
    return float(p.max() / p.mean()) if p.size and p.mean() > 0 else float("nan")


def table_stats(df: pd.DataFrame, f0_hz: float, axes: tuple[str, ...] = ("z", "x", "y")) -> TableStats:
    """Statistics of a validated trajectory table (one segment) about the harmonic at ``f0_hz``."""
    rows, resid = [], {}
    for plate, axis, t, y, a, beta, r in _harmonic_fits(df, f0_hz, axes):
        noise = short_term_noise(r)
        bins = np.floor(t / BIN_S).astype(np.int64)
        counts = np.bincount(bins)
        means = np.bincount(bins, r)[counts > 0] / counts[counts > 0]
        slow = float(np.sqrt(np.mean(means**2)))
        dt = float(np.median(np.diff(t))) if t.size > 1 else 1.0
        line = _periodogram_ratio(t, r, dt)
        z = complex(beta[1], -beta[2])
        env = float("nan")
        edges = np.linspace(t[0], t[-1], N_WINDOWS + 1)
        w = np.clip(np.searchsorted(edges, t, side="right") - 1, 0, N_WINDOWS - 1)
        # only harmonics well above each window's noise (|Z| > 10 σ_Z): the statistic then
        # measures the envelope, not the noise
        if abs(z) > 10 * noise * math.sqrt(2.0 * N_WINDOWS / t.size):
            zw = []
            for j in range(N_WINDOWS):
                m = w == j
                if m.sum() >= 10:
                    bj = wls(a[m, :3], y[m], cov=False)[0]
                    zw.append(complex(bj[1], -bj[2]))
            if len(zw) >= 3:
                env = float(np.sqrt(np.mean(np.abs(np.array(zw) - z) ** 2)) / abs(z))
        far = int(outlier_sizes(r, noise).size)
        rows.append(
            dict(
                key=f"{plate}/{axis}",
                plate=int(plate),
                axis=axis,
                noise_mm=noise,
                slow_mm=slow,
                line_ratio=line,
                outlier_rate=(far + 1) / (r.size + 1),
                envelope=env,
            )
        )
        resid[(int(plate), axis)] = pd.Series(r, index=np.round(t * 1e6).astype(np.int64))
    common = []
    for axis in axes:
        cols = {p: s for (p, a), s in resid.items() if a == axis}
        if len(cols) < 3:
            continue
        m = pd.DataFrame(cols).dropna()
        if len(m) >= MIN_SAMPLES:
            common.append(frame_common_correlation(m.to_numpy()))
    series = pd.DataFrame(rows).set_index("key") if rows else pd.DataFrame()
    return TableStats(series, float(np.mean(common)) if common else float("nan"))


def distance(a: TableStats, b: TableStats, metric: str) -> float:
    """How far apart two tables are on one metric (0 = the same)."""
    if metric == "frame_common":
        return abs(a.frame_common - b.frame_common)
    keys = a.series.index.intersection(b.series.index)
    if not len(keys):
        return float("nan")
    x = a.series.loc[keys, metric].to_numpy(float)
    y = b.series.loc[keys, metric].to_numpy(float)
    ok = np.isfinite(x) & np.isfinite(y) & (x > 0) & (y > 0)
    if not ok.any():
        return float("nan")
    return float(np.sqrt(np.mean(np.log(x[ok] / y[ok]) ** 2)))


def null_95(distances, method: str = "auto", q: float = 0.95) -> tuple[float, str]:
    """The ``q`` percentile (default the 95th) of a distance under the null, and how it was had.

    ``empirical``: the order statistic d₍ₖ₎, k = ⌈q (n + 1)⌉, of n ≥ `EMPIRICAL_MIN` distances
    (only for q ≤ 0.95: 20 distances do not reach further into the tail): a next draw exceeds it
    with probability (n + 1 − k)/(n + 1) ≤ 1 − q whatever their distribution (of 20, the largest:
    1/21), where the sample's own 95th percentile is exceeded about 9 % of the time;
    ``lognormal``: the one-sided ``q`` prediction bound of a log-normal fitted to them,
    exp(m + t_q,ₙ₋₁ · s · √(1 + 1/n)) (m, s: mean and deviation of their logs), which is a
    ``q`` percentile of the next draw whatever n ≥ 3; ``auto`` picks the first when there are
    enough distances. NaN with fewer than 3 finite positive ones.
    """
    from scipy import stats

    d = np.asarray([x for x in distances if np.isfinite(x)], float)
    if method == "auto":
        method = "empirical" if d.size >= EMPIRICAL_MIN and q <= 0.95 else "lognormal"
    if method == "empirical":
        if not d.size:
            return float("nan"), method
        k = min(math.ceil(q * (d.size + 1)), d.size)
        return float(np.sort(d)[k - 1]), method
    d = d[d > 0]
    if d.size < 3:
        return float("nan"), method
    logs = np.log(d)
    n = d.size
    bound = logs.mean() + stats.t.ppf(q, n - 1) * logs.std(ddof=1) * math.sqrt(1 + 1 / n)
    return float(np.exp(bound)), method


def null_family(distances) -> float:
    """The band the verdicts use: the 1 − 0.05/`FAMILY` percentile of the null distances (the
    log-normal prediction bound of `null_95`), so that a recording of the simulated model lies
    outside some metric's band at most 5 % of the time."""
    return null_95(distances, "lognormal", FAMILY_Q)[0]
