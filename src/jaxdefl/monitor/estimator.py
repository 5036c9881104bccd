"""Recursive harmonic estimation for every plate and axis at once, one frame at a time.

Model (thesis eq. 5.29, written about a moving reference time t_r): for every series s (a plate
and an axis), y_s(t) = c_s + d_s cos ω(t − t_r) + e_s sin ω(t − t_r) + noise, with ONE ω for the
beam — the loading frequency is the actuator's, every plate and axis moves at it. The state is
x = [ω, c_1..c_S, d_1..d_S, e_1..e_S]. Each frame moves t_r to the frame's time: (d, e) rotate by
ωΔ (a nonlinear transition whose Jacobian couples ω to every (d, e)); the measurement is then
linear, y_s = c_s + d_s. This is an extended Kalman filter; the two covariance propagations
compared in ``experiments/monitor_estimators.py`` are:

- ``ekf``: P ← F P Fᵀ + Q Δ, Q a random walk on ω (``f0_walk_hz``, Hz/√s) and on the amplitudes
  and offsets (``amplitude_walk``, relative/√s; ``offset_walk_mm``, mm/√s): slow process noise
  where the physics drifts (fatigue, temperature) and none where it does not;
- ``rls``: P ← F P Fᵀ / λ with λ = exp(−Δ/``memory_s``): recursive least squares with
  exponential forgetting (every parameter forgets alike). Its P is σ² (Σ λᵏ JᵀJ)⁻¹; the
  variance of an exponentially weighted estimate about a constant truth is that times 1/(1+λ₁)
  per-frame λ₁ → 1: the σ's reported are corrected so.

Measurement noise: R = D ρ D per frame, D the per-series noise σ's and ρ their correlation (a ToF
camera's range error is largely common to all plates of a frame), both learnt from the
innovations (exponential memory ``noise_memory_s``, ρ shrunk 10 % toward the identity). With a
shared ω and a common error, treating R as diagonal would make σ_f0 several times too small.

Start: `initial_state` fits the first seconds with the batch estimator (`jaxdefl.fit`) for ω,
then linear least squares for (c, d, e) of every series at that ω, referenced to the middle of
the span (where the phase is uncorrelated with ω).

All arrays are numpy, shaped (series, ...) or (state, state); one update costs a few dense
operations on (1 + 3S)² matrices (S = 39: 118 states): well under a millisecond.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
import pandas as pd

from .._numerics import harmonic_design, wls
from ..status import Status

__all__ = ["TrackerSettings", "HarmonicTracker", "initial_state", "METHODS"]

Method = Literal["ekf", "rls"]


@dataclass(frozen=True)
class TrackerSettings:
    """How the tracker forgets (see the module doc)."""

    method: Method = "ekf"
    memory_s: float = 60.0  # rls: forgetting time constant
    f0_walk_hz: float = 2e-5  # ekf: f0 random walk, Hz/√s
    amplitude_walk: float = 5e-4  # ekf: relative amplitude random walk, 1/√s
    offset_walk_mm: float = 2e-3  # ekf: offset random walk, mm/√s
    noise_memory_s: float = 120.0
    correlation_shrink: float = 0.1


def _propagate_ekf(tr: HarmonicTracker, dt: float) -> None:
    s = tr.n
    q = np.empty(tr.dim)
    q[0] = (2 * np.pi * tr.settings.f0_walk_hz) ** 2
    q[1 : 1 + s] = tr.settings.offset_walk_mm**2
    amp2 = tr.x[1 + s : 1 + 2 * s] ** 2 + tr.x[1 + 2 * s :] ** 2
    q[1 + s : 1 + 2 * s] = tr.settings.amplitude_walk**2 * amp2 / 2
    q[1 + 2 * s :] = q[1 + s : 1 + 2 * s]
    tr.P[np.diag_indices(tr.dim)] += q * dt


def _propagate_rls(tr: HarmonicTracker, dt: float) -> None:
    tr.P /= np.exp(-dt / tr.settings.memory_s)


METHODS = {"ekf": _propagate_ekf, "rls": _propagate_rls}


class HarmonicTracker:
    """Extended Kalman filter / forgetting RLS on [ω, c, d, e] of S series (module doc).

    Args:
        omega: start ω (rad/s); c, d, e: (S,) start values at ``t_ref``; P: (1+3S, 1+3S) start
        covariance; noise_sd: (S,) noise σ's; corr: (S, S) noise correlation; t_ref: epoch s.
    """

    def __init__(
        self,
        omega: float,
        c: np.ndarray,
        d: np.ndarray,
        e: np.ndarray,
        P: np.ndarray,
        noise_sd: np.ndarray,
        corr: np.ndarray,
        t_ref: float,
        settings: TrackerSettings = TrackerSettings(),
        n_start: int = 1,
    ):
        if settings.method not in METHODS:
            raise ValueError(f"method: expected one of {', '.join(METHODS)}, got {settings.method!r}")
        self.settings = settings
        self.n = s = len(c)
        self.dim = 1 + 3 * s
        self.x = np.concatenate([[omega], c, d, e]).astype(np.float64)
        self.P = np.array(P, np.float64)
        self.noise_var = np.asarray(noise_sd, np.float64) ** 2
        self.corr = np.array(corr, np.float64)
        self.t_ref = float(t_ref)
        self.t_start = float(t_ref)
        self.frames = 0
        self.ic = 1 + np.arange(s)
        self.id = 1 + s + np.arange(s)
        self.ie = 1 + 2 * s + np.arange(s)
        self.last_innovation = np.full(s, np.nan)
        self._w1 = self._w2 = float(n_start)  # RLS: Σλᵏ and Σλ²ᵏ over the frames taken, for the σ's
        self._t_noise = self.t_ref

    # -- the filter ---------------------------------------------------------------------------

    def _rotate_rows(self, M: np.ndarray, cs: float, sn: float, u: np.ndarray) -> np.ndarray:
        """F M for F = R(ωΔ) on every (d, e) pair plus the ω column u (see `predict`)."""
        out = M.copy()
        out[self.id] = cs * M[self.id] + sn * M[self.ie]
        out[self.ie] = -sn * M[self.id] + cs * M[self.ie]
        out += u[:, None] * M[0][None, :]
        return out

    def predict(self, t: float) -> None:
        """Move the reference time to ``t``: (d, e) rotate by ωΔ, P ← F P Fᵀ, then forget."""
        dt = t - self.t_ref
        if dt == 0.0:
            return
        w = self.x[0]
        cs, sn = np.cos(w * dt), np.sin(w * dt)
        d, e = self.x[self.id], self.x[self.ie]
        d1 = cs * d + sn * e
        e1 = -sn * d + cs * e
        u = np.zeros(self.dim)
        u[self.id] = dt * e1  # ∂d'/∂ω
        u[self.ie] = -dt * d1  # ∂e'/∂ω
        self.x[self.id], self.x[self.ie] = d1, e1
        fp = self._rotate_rows(self.P, cs, sn, u)
        self.P = self._rotate_rows(fp.T.copy(), cs, sn, u).T
        METHODS[self.settings.method](self, abs(dt))
        self.t_ref = t
        if self.settings.method == "rls" and dt > 0:
            lam = np.exp(-dt / self.settings.memory_s)
            self._w1, self._w2 = lam * self._w1 + 1.0, lam * lam * self._w2 + 1.0

    def update(self, t: float, y: np.ndarray) -> np.ndarray:
        """Take one frame: ``y`` (S,) with NaN where a plate is missing. Returns the innovations."""
        self.predict(t)
        y = np.asarray(y, np.float64)
        v = np.flatnonzero(np.isfinite(y))
        innov = np.full(self.n, np.nan)
        if v.size == 0:
            return innov
        ic, id_ = self.ic[v], self.id[v]
        eps = y[v] - (self.x[ic] + self.x[id_])
        pht = self.P[:, ic] + self.P[:, id_]  # P Hᵀ, H picks c + d
        sd = np.sqrt(self.noise_var[v])
        R = self.corr[np.ix_(v, v)] * sd[:, None] * sd[None, :]
        S = pht[ic] + pht[id_] + R
        try:
            sol = np.linalg.solve(S, np.column_stack([pht.T, eps]))  # S⁻¹ [H P, ε]
        except np.linalg.LinAlgError:
            return innov
        self.x += pht @ sol[:, -1]  # K ε with K = P Hᵀ S⁻¹
        self.P -= pht @ sol[:, :-1]
        self.P = 0.5 * (self.P + self.P.T)
        innov[v] = eps
        self._learn_noise(v, eps, np.diag(S) - np.diag(R), t)
        self.last_innovation = innov
        self.frames += 1
        return innov

    def _learn_noise(self, v: np.ndarray, eps: np.ndarray, hph: np.ndarray, t: float) -> None:
        """Noise σ's and correlation from the innovations (exponential memory)."""
        a = float(np.clip((t - self._t_noise) / self.settings.noise_memory_s, 1e-5, 1.0))
        self._t_noise = t
        var = np.maximum(eps**2 - hph, 0.05 * self.noise_var[v])
        self.noise_var[v] = (1 - a) * self.noise_var[v] + a * var
        z = eps / np.sqrt(self.noise_var[v] + hph)
        shrink = self.settings.correlation_shrink
        full = v.size == self.n
        block = self.corr if full else self.corr[np.ix_(v, v)]
        block = (1 - a) * block + (a * (1 - shrink)) * np.outer(z, z)
        block[np.diag_indices(v.size)] += a * shrink
        dg = 1 / np.sqrt(np.diag(block))
        block *= dg[:, None]
        block *= dg[None, :]
        if full:
            self.corr = block
        else:
            self.corr[np.ix_(v, v)] = block

    # -- results ------------------------------------------------------------------------------

    def _var_scale(self) -> float:
        # exponentially weighted LS about a constant truth: Var = P Σλ²ᵏ / Σλᵏ (→ P/(1+λ))
        return self._w2 / self._w1 if self.settings.method == "rls" else 1.0

    def estimates(self) -> dict[str, np.ndarray]:
        """Per series: f0_hz, sigma_f0_hz (shared), amplitude_mm, sigma_amplitude_mm, psi_rad
        (phase at t_ref: y = c + A cos(ω(t − t_ref) + ψ)), offset_mm, sigma_offset_mm,
        sigma_residual_mm."""
        k = self._var_scale()
        s = self.n
        d, e = self.x[self.id], self.x[self.ie]
        amp = np.hypot(d, e)
        safe = np.where(amp > 0, amp, 1.0)
        gd, ge = d / safe, e / safe
        pdd = self.P[self.id, self.id]
        pee = self.P[self.ie, self.ie]
        pde = self.P[self.id, self.ie]
        var_a = (gd * gd * pdd + ge * ge * pee + 2 * gd * ge * pde) * k
        f0 = self.x[0] / (2 * np.pi)
        sf0 = np.sqrt(max(self.P[0, 0], 0.0) * k) / (2 * np.pi)
        return {
            "f0_hz": np.full(s, f0),
            "sigma_f0_hz": np.full(s, sf0),
            "amplitude_mm": amp,
            "sigma_amplitude_mm": np.sqrt(np.maximum(var_a, 0.0)),
            "psi_rad": np.arctan2(-e, d),
            "offset_mm": self.x[self.ic].copy(),
            "sigma_offset_mm": np.sqrt(np.maximum(self.P[self.ic, self.ic] * k, 0.0)),
            "sigma_residual_mm": np.sqrt(self.noise_var),
        }


def initial_state(
    t: np.ndarray, Y: np.ndarray, fit_table: pd.DataFrame, settings: TrackerSettings = TrackerSettings()
) -> HarmonicTracker:
    """A tracker started from a batch fit of the first frames.

    Args:
        t: (frame,) epoch s. Y: (frame, S) values, NaN = missing.
        fit_table: the `jaxdefl.fit` estimates of the same span, one row per series in the order
            of Y's columns (``f0_hz``, ``sigma_f0_hz``, ``status``).
    Raises:
        ValueError: no series converged (no loading frequency to start from).
    """
    converged = fit_table["status"].to_numpy() == Status.CONVERGED
    ok = converged & np.isfinite(fit_table["sigma_f0_hz"].to_numpy())
    if not ok.any():
        raise ValueError("no series of the first frames gives a loading frequency (none converged)")
    f = fit_table["f0_hz"].to_numpy()[ok]
    sf = fit_table["sigma_f0_hz"].to_numpy()[ok]
    med = np.median(f)
    keep = np.abs(f - med) <= 5 * sf + 1e-3 * med
    w = 1 / sf[keep] ** 2
    omega = 2 * np.pi * float(np.sum(w * f[keep]) / np.sum(w))
    # the best single series' σ: the plates share much of their noise, so do not divide further
    sd_omega = 2 * np.pi * float(sf[keep].min())
    t_ref = 0.5 * (float(np.nanmin(t)) + float(np.nanmax(t)))
    tau = t - t_ref
    X = harmonic_design(omega * tau)
    s = Y.shape[1]
    c, d, e = np.zeros(s), np.zeros(s), np.zeros(s)
    P = np.zeros((1 + 3 * s, 1 + 3 * s))
    P[0, 0] = sd_omega**2
    noise = np.ones(s)
    resid = np.full(Y.shape, np.nan)
    unit = np.zeros((s, 3, 3))  # (XᵀX)⁻¹ of every series
    fitted = np.zeros(s, bool)
    for j in range(s):
        m = np.isfinite(Y[:, j])
        if m.sum() < 8:
            P[1 + j, 1 + j] = P[1 + s + j, 1 + s + j] = P[1 + 2 * s + j, 1 + 2 * s + j] = 1e6
            continue
        Xm, ym = X[m], Y[m, j]
        beta, _, fit = wls(Xm, ym, cov=False)
        r = ym - fit
        s2 = float(r @ r) / max(m.sum() - 4, 1)
        unit[j] = np.linalg.inv(Xm.T @ Xm)
        fitted[j] = True
        c[j], d[j], e[j] = beta
        noise[j] = np.sqrt(s2)
        resid[m, j] = r / np.sqrt(s2)
    good = np.isfinite(resid)
    z = np.where(good, resid, 0.0)
    cnt = good.astype(float).T @ good.astype(float)
    corr = (z.T @ z) / np.maximum(cnt, 1)
    corr = (1 - settings.correlation_shrink) * corr + settings.correlation_shrink * np.eye(s)
    dg = np.sqrt(np.clip(np.diag(corr), 1e-12, None))
    corr = corr / np.outer(dg, dg)
    # the start values' errors share the noise's correlation across series: P = Σ ⊗ (XᵀX)⁻¹
    # (with a block-diagonal P the filter would weigh the later frames against a wrong prior)
    f = np.flatnonzero(fitted)
    for j in f:
        for k in f:
            blk = corr[j, k] * noise[j] * noise[k] * 0.5 * (unit[j] + unit[k])
            P[np.ix_([1 + j, 1 + s + j, 1 + 2 * s + j], [1 + k, 1 + s + k, 1 + 2 * s + k])] = blk
    n_start = int(np.isfinite(Y).any(axis=1).sum())
    tr = HarmonicTracker(omega, c, d, e, P, noise, corr, t_ref, settings, n_start=n_start)
    tr.t_start = float(np.nanmin(t))
    return tr
