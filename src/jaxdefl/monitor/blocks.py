"""Short-block harmonic estimates for change detection, from sufficient statistics.

Every ``block_s`` seconds, each series gets an independent least-squares fit of its own block of
frames (non-overlapping, so the estimates of successive blocks are independent under white
noise): y = C + U cos θ + V sin θ + τ (U' cos θ + V' sin θ), where θ = ω_ref (t − t_anchor) is
the detector's reference oscillator and τ = t − t_mid(block). For a harmonic at ω_ref + δω,
U' = δω V and V' = −δω U, so δω = (U' V − V' U)/(U² + V²); the amplitude at the block's middle is
A = √(U² + V²), its phase ψ = atan2(−V, U); the residual variance s² has n − 5 degrees of freedom.
σ's: s² (XᵀX)⁻¹ and the delta method. Only the normal equations are kept (5 × 5 per series), so
a frame costs O(S) and nothing is stored.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["BlockResult", "BlockAccumulator", "MIN_BLOCK_SAMPLES"]

MIN_BLOCK_SAMPLES = 12


@dataclass(frozen=True)
class BlockResult:
    """Per-series estimates of one block: arrays (S,), NaN where a series had too few samples."""

    t_start: float
    t_end: float
    frames: int
    n: np.ndarray
    offset_mm: np.ndarray
    sigma_offset_mm: np.ndarray
    amplitude_mm: np.ndarray
    sigma_amplitude_mm: np.ndarray
    psi_rad: np.ndarray
    domega: np.ndarray  # rad/s, against the reference oscillator
    sigma_domega: np.ndarray
    resid_var: np.ndarray  # mm²
    dof: np.ndarray


class BlockAccumulator:
    """Normal equations of the current block for every series; `add` returns finished blocks.

    Args:
        n_series: S. omega_ref: the reference oscillator's ω (rad/s). t_anchor: its zero phase.
        block_s: block length. t_first: the start of the first block. centre: (S,) values
            subtracted before summing (keeps y² sums precise on large offsets).
    """

    def __init__(
        self,
        n_series: int,
        omega_ref: float,
        t_anchor: float,
        block_s: float,
        t_first: float,
        centre: np.ndarray,
    ):
        self.s = n_series
        self.omega_ref, self.t_anchor, self.block_s = float(omega_ref), float(t_anchor), float(block_s)
        self.centre = np.where(np.isfinite(centre), centre, 0.0).astype(np.float64)
        self.t_block = float(t_first)
        self._reset()

    def _reset(self) -> None:
        self.N = np.zeros((self.s, 5, 5))
        self.b = np.zeros((self.s, 5))
        self.yy = np.zeros(self.s)
        self.n = np.zeros(self.s)
        self.frames = 0

    def add(self, t: np.ndarray, Y: np.ndarray) -> list[BlockResult]:
        """Take frames ``t`` (frame,), ``Y`` (frame, S); return the blocks they completed."""
        out = []
        t = np.asarray(t, np.float64)
        Y = np.asarray(Y, np.float64)
        while t.size:
            end = self.t_block + self.block_s
            k = int(np.searchsorted(t, end, side="left"))
            if k:
                self._accumulate(t[:k], Y[:k])
            if k == t.size:
                break
            out.append(self.finish())
            t, Y = t[k:], Y[k:]
        return out

    def _accumulate(self, t: np.ndarray, Y: np.ndarray) -> None:
        th = self.omega_ref * (t - self.t_anchor)
        tau = t - (self.t_block + self.block_s / 2)
        c, s = np.cos(th), np.sin(th)
        X = np.stack([np.ones_like(t), c, s, tau * c, tau * s], axis=1)  # (B, 5)
        M = np.isfinite(Y)
        Yc = np.where(M, Y - self.centre, 0.0)
        Mf = M.astype(np.float64)
        XX = (X[:, :, None] * X[:, None, :]).reshape(len(t), 25)
        self.N += (Mf.T @ XX).reshape(self.s, 5, 5)
        self.b += Yc.T @ X
        self.yy += (Yc * Yc).sum(axis=0)
        self.n += Mf.sum(axis=0)
        self.frames += len(t)

    def finish(self) -> BlockResult:
        """Solve the current block's normal equations and start the next block."""
        s = self.s
        ok = self.n >= MIN_BLOCK_SAMPLES
        beta = np.full((s, 5), np.nan)
        cov = np.full((s, 5, 5), np.nan)
        if ok.any():
            Ninv = np.linalg.inv(self.N[ok])
            cov[ok] = Ninv
            beta[ok] = np.einsum("sij,sj->si", Ninv, self.b[ok])
        dof = np.where(ok, self.n - 5, np.nan)
        rss = self.yy - np.einsum("si,si->s", beta, self.b)
        s2 = np.maximum(rss, 0.0) / dof
        cov = cov * s2[:, None, None]
        C, U, V, Ud, Vd = beta.T
        A = np.hypot(U, V)
        A2 = np.where(A > 0, A * A, np.nan)
        gA = np.stack([U / np.sqrt(A2), V / np.sqrt(A2)], axis=1)
        var_A = np.einsum("si,sij,sj->s", gA, cov[:, 1:3, 1:3], gA)
        dw = (Ud * V - Vd * U) / A2
        gw = np.stack([(-Vd - 2 * U * dw) / A2, (Ud - 2 * V * dw) / A2, V / A2, -U / A2], axis=1)
        var_w = np.einsum("si,sij,sj->s", gw, cov[:, 1:5, 1:5], gw)
        res = BlockResult(
            t_start=self.t_block,
            t_end=self.t_block + self.block_s,
            frames=self.frames,
            n=self.n.copy(),
            offset_mm=C + self.centre,
            sigma_offset_mm=np.sqrt(cov[:, 0, 0]),
            amplitude_mm=A,
            sigma_amplitude_mm=np.sqrt(var_A),
            psi_rad=np.arctan2(-V, U),
            domega=dw,
            sigma_domega=np.sqrt(var_w),
            resid_var=s2,
            dof=dof,
        )
        self.t_block += self.block_s
        self._reset()
        return res
