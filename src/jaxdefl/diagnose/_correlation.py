"""Noise shared by the series of a frame, and what it does to the evidence for common effects.

A time-of-flight camera's range error has a part common to the whole frame (a modulation-phase
offset, a tilt across the image: `jaxdefl.simulate` calibrates it to the thesis' Tables 6.2 and
6.17), so the residuals of different plates in the same frame are correlated, often strongly.
And a plate's x, y and z all come from the same ranges along the same rays: a range error moves
the plate's centroid along its line of sight, so its three axes share one noise (|ρ| ≈ 1, the
sign set by the side of the camera the plate is on). The likelihood of `_base.loglik` treats
series as independent. For an effect that adds the same term to m series, that overstates the
evidence by Kish's design effect

    d = 1ᵀ R 1 / m = 1 + (m − 1) ρ̄        (R: the m series' residual correlation matrix),

exactly for equal terms and noise levels: the generalised least-squares information about the
term's amplitude is m Σg² / (σ² d), the independent-noise one m Σg² / σ². Without it, the
frame-common noise itself is reported as level jumps, modulations and distortions alike on all
plates, and one plate's range noise counts three times, once per axis. R is one matrix over all
the series, axes included; the search divides a proposal's Δlog L by the d of its series.

ρ is estimated from first differences of the nominal residuals on the frame clock: differencing
keeps white frame-common noise whole (the correlation of differences of equicorrelated white
noise is ρ) and removes the slow structure (drift, jumps, modulations) that an effect common to
the plates would otherwise lend to ρ.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ._base import Context, State

__all__ = ["D_MIN", "FrameCorrelation", "ar1_rho", "floored_inverse", "frame_correlation", "gls_gain"]

# Pairs with fewer common differences than this get no correlation (ρ = 0).
_MIN_PAIRS = 50
# The smallest design effect credited to a term of known pattern (at most 1/D_MIN times the
# independent-noise evidence).
D_MIN = 0.15


@dataclass(frozen=True)
class FrameCorrelation:
    """Correlation of the series' residual noise within a frame, over all plates and axes.

    Attributes:
        axes: the axis of each series (the rows and columns of ``matrix``, in series order).
        matrix: (n, n) correlation matrix of the n series (1 on the diagonal).
        n_frames: frames behind the estimate (0: unknown, no eigenvalue rule).
    """

    axes: tuple[str, ...]
    matrix: np.ndarray
    n_frames: int = 0

    def mean_offdiagonal(self, axis: str) -> float:
        """Mean correlation between different series of one axis."""
        c = [i for i, a in enumerate(self.axes) if a == axis]
        r = self.matrix[np.ix_(c, c)]
        m = len(c)
        return float((r.sum() - m) / (m * (m - 1))) if m > 1 else 0.0

    def design_effect(self, series: list[int], shape: dict[int, float] | None = None) -> float:
        """d over the given series, axes together: for a term with a factor φ per series
        (`Proposal.shape`), d = φᵀRφ / φᵀφ (≥ D_MIN; below 1 for a pattern in which noise common
        to the frame cancels, as in an antisymmetric mode); for a term whose pattern is not known,
        R's largest eigenvalue (the worst pattern; = 1ᵀR1 / m for equicorrelated noise; ≥ 1)."""
        c = sorted(set(series))
        r = self.matrix[np.ix_(c, c)]
        if shape is None:
            # The term's size per series follows the plate's own motion, its sign the side of
            # the camera the plate is on: correlations of both signs (x either side of the
            # camera's axis, x against z), a mean near 0, yet as much shared noise as on z.
            # R's largest eigenvalue is taken when it stands above what independent noise gives
            # a sample correlation (the Marchenko-Pastur edge (1 + √(m/n))²), else the
            # equal-terms value.
            m = len(c)
            eq = float(r.sum()) / m
            lam = float(np.linalg.eigvalsh(r)[-1]) if m > 1 else 1.0
            edge = (1.0 + np.sqrt(m / max(self.n_frames, 1))) ** 2
            return max(1.0, eq, lam if lam > edge else 1.0)
        # A known pattern φ: the series-by-series fit's amplitude has variance d times the
        # independent-noise one, so Δlog L / d is calibrated whether d is above or below 1 (an
        # antisymmetric mode in frame-common noise: the common part cancels in φ, d = 1 − ρ,
        # and the term carries more evidence than independent noise would give it). Floored:
        # R is estimated, and a pattern it calls nearly noise-free is not trusted beyond D_MIN.
        w = np.asarray([float(shape.get(i, 0.0)) for i in c])
        return max(D_MIN, float(w @ r @ w) / max(float(w @ w), 1e-300))

    def discount(self, dll: dict[int, float], shape: dict[int, float] | None = None) -> float:
        """Σ Δlog L over a term's series (per-series ``dll``) divided by their design effect."""
        return float(sum(dll.values())) / self.design_effect(list(dll), shape)


def ar1_rho(r: np.ndarray, k: np.ndarray, block: int = 10) -> float:
    """ρ of the AR(1) noise model, the larger of two estimates that slow structure hardly moves:

    - from the lag-1 autocorrelation c of first differences on consecutive frames (AR(1):
      c = −(1 − ρ)/2, so ρ = 1 + 2c);
    - from the noise power at low against high frequencies: q = B var(Δm_B) / var(d), m_B the
      means of blocks of B frames, Δm their differences and d the first differences (AR(1):
      q = (1 + ρ)/(1 − ρ)²), which also gives coloured noise that is not AR(1) (white plus
      AR(1)) its low-frequency power.

    Each is 0 unless 3 standard errors above white noise; clipped to 0.95."""
    cons = np.diff(k) == 1
    d = np.diff(r)
    both = cons[1:] & cons[:-1]
    if both.sum() < 16:
        return 0.0
    a, b = d[1:][both], d[:-1][both]
    c = float(np.sum(a * b) / max(math.sqrt(float(np.sum(a * a) * np.sum(b * b))), 1e-300))
    rho = 1.0 + 2.0 * c
    # under white noise c ≈ −1/2 with σ_c ≈ √(1/(2m)) (difference lags overlap): 3 σ in ρ
    if rho < 3.0 * 2.0 * math.sqrt(0.5 / both.sum()):
        rho = 0.0
    # block means on the frame clock (a block with a gap is left out)
    n_b = int(k[-1] // block) if k.size else 0
    if n_b >= 16:
        j = k // block
        cnt = np.bincount(j, minlength=n_b + 1)[:n_b]
        m = np.bincount(j, r, minlength=n_b + 1)[:n_b] / np.maximum(cnt, 1)
        full = cnt == block
        dm = np.diff(m)[full[1:] & full[:-1]]
        var_d = float(np.mean(d[cons] ** 2)) if cons.any() else 0.0
        if dm.size >= 16 and var_d > 0:
            q = block * float(np.mean(dm * dm)) / var_d
            if q > 1.0 + 3.0 * math.sqrt(2.0 / dm.size):
                rho = max(rho, ((2 * q + 1) - math.sqrt(8 * q + 1)) / (2 * q))
    return float(min(max(rho, 0.0), 0.95))


def floored_inverse(cov: np.ndarray) -> np.ndarray:
    """The inverse of a covariance across series with its correlation's eigenvalues floored at
    `D_MIN` (an estimated correlation that calls a pattern nearly noise-free is not trusted beyond
    it, as `FrameCorrelation.design_effect` floors d)."""
    sd = np.sqrt(np.maximum(np.diag(cov), 1e-300))
    lam, vec = np.linalg.eigh(cov / np.outer(sd, sd))
    return (vec / np.maximum(lam, D_MIN)) @ vec.T / np.outer(sd, sd)


def gls_gain(ctx: Context, states: list[State], new: dict[int, State]) -> float | None:
    """Δlog L of a term of known pattern under the noise covariance of its series: the generalised
    least-squares statistic along the term's change δ (``new`` against ``states``),

        2 Δlog L = (Σ_t δ_tᵀ Σ⁻¹ r_t)² / Σ_t δ_tᵀ Σ⁻¹ δ_t,

    δ_t and r_t the change and the residual of the term's series in frame t over their noise
    scales, on the frames they all have, each series' AR(1) colour filtered out first (its ρ from
    its residual, `ar1_rho`), and Σ the covariance of those filtered residuals across the
    series (estimated on them, so that the filter and the covariance agree; inverted by
    `floored_inverse`). For a fixed
    direction it is χ²₁ under the null; a direction fitted by the effect (a mode's phase at a
    scanned frequency and shape) keeps it below the χ²₂ of that frequency and shape, which the
    acceptance test's degrees of freedom and trials cover. Unlike Δlog L / d it weighs the
    part of the pattern that noise shared by the frame does not mimic at its full precision: a
    mode with a component alike on every plate is told by its other part. None when it cannot be
    formed (fewer than two series or 20 shared frames)."""
    c = sorted(new)
    if len(c) < 2:
        return None
    n_frames = max(int(ctx.series[i].k.max()) for i in c) + 1
    res = np.full((n_frames, len(c)), np.nan)
    dlt = np.full((n_frames, len(c)), np.nan)
    for j, i in enumerate(c):
        s, st = ctx.series[i], states[i]
        ok = st.inlier & new[i].inlier
        res[s.k[ok], j] = ((s.y - st.mean) / st.scale)[ok]
        dlt[s.k[ok], j] = ((new[i].mean - st.mean) / st.scale)[ok]
    keep = np.all(np.isfinite(res), axis=1)
    k = np.flatnonzero(keep)
    if k.size < 20:
        return None
    res, dlt = res[keep], dlt[keep]
    gap = np.diff(k).astype(np.float64)
    for j in range(len(c)):
        rho = ar1_rho(res[:, j] - res[:, j].mean(), k)
        if rho > 0:
            rg = rho**gap  # unit-variance innovations: x_j − ρ^g x_{j−1} over √(1 − ρ^{2g})
            root = np.sqrt(1.0 - rg * rg)
            for x in (res, dlt):
                x[:, j] = np.concatenate([x[:1, j], (x[1:, j] - rg * x[:-1, j]) / root])
    centred = res - res.mean(axis=0)
    if not np.all(np.mean(centred**2, axis=0) > 0):
        return None
    inv = floored_inverse(centred.T @ centred / k.size)
    dr = float(np.sum((dlt @ inv) * res))
    dd = float(np.sum((dlt @ inv) * dlt))
    return 0.5 * dr * dr / dd if dd > 0 else None


def frame_correlation(ctx: Context, states: list[State]) -> FrameCorrelation:
    """Correlation of first differences of the residuals ``y − mean`` of all series."""
    n_frames = max(int(s.k.max()) for s in ctx.series) + 1 if ctx.series else 0
    diffs = np.full((n_frames, len(ctx.series)), np.nan)
    for c, (s, st) in enumerate(zip(ctx.series, states, strict=True)):
        r = np.where(st.inlier, s.y - st.mean, np.nan)
        grid = np.full(n_frames + 1, np.nan)
        grid[s.k] = r
        diffs[:, c] = np.diff(grid)
    ok = np.isfinite(diffs)
    z = np.where(ok, diffs, 0.0)
    okf = ok.astype(np.float64)
    # Raw moments over the frames both series have: differences have mean ~0.
    count = okf.T @ okf
    cross = z.T @ z
    sq = (z**2).T @ okf  # (i, j): Σ of series i's squares over the frames j also has
    with np.errstate(invalid="ignore", divide="ignore"):
        r = cross / np.sqrt(sq * sq.T)
    r = np.where((count >= _MIN_PAIRS) & np.isfinite(r), r, 0.0)
    # Not clipped pair by pair: independent noise gives pair estimates ±1/√n about 0, and
    # clipping their negative half would bias d upwards by ~0.4 (m − 1)/√n (10-30 % of the
    # evidence of a term common to a dozen plates in white noise). `design_effect` keeps
    # d >= 1 for a term of unknown pattern (negative correlation never credits it evidence) and
    # d >= D_MIN for a known pattern.
    r = np.clip(r, -1.0, 1.0)
    np.fill_diagonal(r, 1.0)
    return FrameCorrelation(tuple(s.axis for s in ctx.series), r, n_frames)
