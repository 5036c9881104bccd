"""Noise shared by the plates of a frame, and what it does to the evidence for common effects.

A time-of-flight camera's range error has a part common to the whole frame (a modulation-phase
offset, a tilt across the image: `jaxdefl.simulate` calibrates it to the thesis' Tables 6.2 and
6.17), so the residuals of different plates in the same frame are correlated, often strongly.
The likelihood of `_base.loglik` treats series as independent. For an effect that adds the
same term to m plates, that overstates the evidence by Kish's design effect

    d = 1ᵀ R 1 / m = 1 + (m − 1) ρ̄        (R: the m plates' residual correlation matrix),

exactly for equal terms and noise levels: the generalised least-squares information about the
term's amplitude is m Σg² / (σ² d), the independent-noise one m Σg² / σ². Without it, the
frame-common noise itself is reported as level jumps, modulations and distortions alike on all
plates. The search divides each axis' share of a proposal's Δlog L by that axis' d.

ρ is estimated from first differences of the nominal residuals on the frame clock: differencing
keeps white frame-common noise whole (the correlation of differences of equicorrelated white
noise is ρ) and removes the slow structure (drift, jumps, modulations) that an effect common to
the plates would otherwise lend to ρ.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ._base import Context, Proposal, State

__all__ = ["FrameCorrelation", "frame_correlation"]

# Pairs with fewer common differences than this get no correlation (ρ = 0).
_MIN_PAIRS = 50


@dataclass(frozen=True)
class FrameCorrelation:
    """Correlation of the plates' residual noise within a frame, per axis.

    Attributes:
        index: series index -> (axis, column in that axis' matrix).
        matrix: axis -> (m, m) correlation matrix of the axis' series (1 on the diagonal).
    """

    index: dict[int, tuple[str, int]]
    matrix: dict[str, np.ndarray]
    n_frames: int = 0  # frames behind the estimate (0: unknown, no eigenvalue rule)

    def mean_offdiagonal(self, axis: str) -> float:
        r = self.matrix[axis]
        m = r.shape[0]
        return float((r.sum() - m) / (m * (m - 1))) if m > 1 else 0.0

    def design_effect(self, series: list[int], shape: dict[int, float] | None = None) -> dict[str, float]:
        """Per axis, d = λ_max(R) over the given series of that axis (≥ 1; = 1ᵀR1 / m for
        equicorrelated noise); for a term with a
        factor φ per series (`Proposal.shape`), d = φᵀRφ / φᵀφ (an antisymmetric pattern is not
        mimicked by noise common to the frame: d stays 1)."""
        cols: dict[str, list[int]] = {}
        wts: dict[str, list[float]] = {}
        for i in series:
            axis, c = self.index[i]
            cols.setdefault(axis, []).append(c)
            wts.setdefault(axis, []).append(1.0 if shape is None else float(shape.get(i, 0.0)))
        out = {}
        for axis, c in cols.items():
            r = self.matrix[axis][np.ix_(c, c)]
            if shape is None:
                # the term's pattern across the plates is not known (its size per plate follows
                # the plate's own motion, its sign the side of the camera the plate is on). A
                # common range error moves plates either side of the camera's axis in opposite x
                # directions: correlations of both signs, a mean near 0, yet as much shared noise
                # as on z. R's largest eigenvalue (the worst pattern) is taken when it stands
                # above what independent noise gives a sample correlation (the Marchenko-Pastur
                # edge (1 + √(m/n))²), else the equal-terms value.
                m = len(c)
                eq = float(r.sum()) / m
                lam = float(np.linalg.eigvalsh(r)[-1]) if m > 1 else 1.0
                edge = (1.0 + np.sqrt(m / max(self.n_frames, 1))) ** 2
                out[axis] = max(1.0, eq, lam if lam > edge else 1.0)
                continue
            w = np.asarray(wts[axis])
            out[axis] = max(1.0, float(w @ r @ w) / max(float(w @ w), 1e-300))
        return out

    def discount(self, ctx: Context, p: Proposal, dll: dict[int, float]) -> float:
        """Δlog L of proposal ``p`` (per-series ``dll``) with each axis' share divided by d."""
        d = self.design_effect(p.series, p.shape)
        return float(sum(v / d[ctx.series[i].axis] for i, v in dll.items()))


def frame_correlation(ctx: Context, states: list[State]) -> FrameCorrelation:
    """Correlation of first differences of the residuals ``y − mean`` of same-axis series."""
    index: dict[int, tuple[str, int]] = {}
    by_axis: dict[str, list[int]] = {}
    for i, s in enumerate(ctx.series):
        index[i] = (s.axis, len(by_axis.setdefault(s.axis, [])))
        by_axis[s.axis].append(i)
    matrix = {}
    n_frames = max(int(s.k.max()) for s in ctx.series) + 1 if ctx.series else 0
    for axis, members in by_axis.items():
        m = len(members)
        diffs = np.full((n_frames, m), np.nan)
        for c, i in enumerate(members):
            s, st = ctx.series[i], states[i]
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
        # d >= 1: negative correlation never credits evidence.
        r = np.clip(r, -1.0, 1.0)
        np.fill_diagonal(r, 1.0)
        matrix[axis] = r
    return FrameCorrelation(index, matrix, n_frames)
