"""Heteroscedastic noise: the noise level changes with the motion's phase or over the record.

Physical meaning: a ToF camera's range noise goes as 1/amplitude of the returned light, which
changes with the plate's distance and incidence angle, so a plate moving through its cycle sees
its noise breathe at f0 (kind "phase"); the centroid of a plate whose edge crosses a depth
threshold loses or gains pixels at one end of the stroke; the noise grows or falls over the
record as the camera warms, the ambient light changes or the plate gets dirty (kind "time").

Signature test: per plate and axis, maximum likelihood of σ_i = σ0 · scale_i · (1 + θ·x_i)
(σ0 profiled) by Newton steps on θ, with x = (cos φ_i, sin φ_i) for kind "phase" (φ the
nominal harmonic's phase angle ω(t − t_ref) − phase, 0 at the peak of the motion) and x = u_i =
(t − t_mid)/(duration/2) for kind "time"; the squared residuals are summed in 72 bins of the
phase or 240 bins of time (σ hardly changes within a bin) and the gain is recomputed exactly.
Twice the likelihood gain is χ²_2 (χ²_1) under the nominal model; the p-value is the largest
single-series gain Bonferroni-corrected over series × the two kinds, or the gain summed over all
series (χ²_2S or χ²_S) corrected for the two kinds, whichever is smaller (doubled). One proposal
per kind: BIC decides.

Model term: the noise model only (`State.scale` multiplied by 1 + m u_i, u = cos(φ − ψ) or the
centred time); the offset (and C, D) are refitted with the new weights for free. Two parameters
per series for "phase" (m cos ψ, m sin ψ), one for "time" (m, signed).

Plausible magnitudes: m of 0.1-0.5 (ToF noise changes by tens of per cent over a few-mm stroke
near the edge of the illuminated field; warm-up changes of 10-30 % over an hour).
"""

from __future__ import annotations

import math

import numpy as np

from ..._numerics import harmonic_design, wls
from ...effects.heteroscedastic_noise import ENTRY
from .._base import Context, Detector, Proposal, State, keep_series
from .screening import (
    combined_p,
    gain,
    long_run_factor,
    median_signed,
    open_series,
    param,
    residual,
    subset_trials,
    updated,
)

__all__ = ["HeteroscedasticNoise", "EFFECT"]

KINDS = ("phase", "time")
NEWTON_STEPS = 12
N_BINS = {"phase": 72, "time": 240}  # the likelihood on bins of the motion's phase or of time
M_MAX = 0.95  # |1 + θ·x| stays >= 0.05


def _features(ctx: Context, i: int, kind: str) -> np.ndarray:
    s = ctx.series[i]
    if kind == "phase":
        return harmonic_design(ctx.nominal[i].argument(s.t), offset=False)
    mid = 0.5 * ctx.duration_s
    return ((s.t - mid) / (0.5 * ctx.duration_s))[:, None]


def _objective(theta: np.ndarray, x: np.ndarray, v: np.ndarray, c: np.ndarray) -> float:
    s = 1.0 + x @ theta
    if np.any(s <= 0):
        return np.inf
    return float(c @ np.log(s) + 0.5 * c.sum() * math.log(float(np.sum(v / s**2))))


def fit_scale(
    x: np.ndarray, v: np.ndarray, c: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, float]:
    """Maximum likelihood of θ in σ_i = σ0 (1 + θ·x_i), σ0 profiled, from squared residuals v.

    Args:
        x: (bin, k) features; v: (bin,) sums of squared standardised residuals; c: (bin,) sample
            counts (1 each when x and v are per sample).
    Returns:
        (θ (k,), cov (k, k), twice the log-likelihood gain over θ = 0).
    """
    c = np.ones_like(v) if c is None else c
    k = x.shape[1]
    n = float(c.sum())
    theta = np.zeros(k)
    f0 = f = _objective(theta, x, v, c)
    hess = np.eye(k)
    for _ in range(NEWTON_STEPS):
        s = 1.0 + x @ theta
        q = float(np.sum(v / s**2))
        g_v = (v / s**3) @ x
        xs = x / s[:, None]
        grad = c @ xs - n / q * g_v
        hess = -(xs * c[:, None]).T @ xs + 3.0 * n / q * (xs * (v / s**2)[:, None]).T @ xs
        hess -= 2.0 * n / q**2 * np.outer(g_v, g_v)
        try:
            step = -np.linalg.solve(hess, grad)
        except np.linalg.LinAlgError:
            break
        if not np.all(np.isfinite(step)):
            break
        lam = 1.0
        while lam > 1e-4:
            cand = theta + lam * step
            if np.linalg.norm(cand) < M_MAX:
                fc = _objective(cand, x, v, c)
                if fc <= f:
                    break
            lam *= 0.5
        else:
            break
        theta, f_old, f = cand, f, fc
        if f_old - f < 1e-10:
            break
    try:
        cov = np.linalg.inv(hess)
    except np.linalg.LinAlgError:
        cov = np.full((k, k), np.nan)
    return theta, cov, 2.0 * (f0 - f)


def _binned(x: np.ndarray, v: np.ndarray, key: np.ndarray, n_bins: int):
    """Per-bin mean features, sums of v and counts (bins empty of samples dropped)."""
    c = np.bincount(key, minlength=n_bins).astype(float)
    vb = np.bincount(key, v, minlength=n_bins)
    xb = np.stack([np.bincount(key, x[:, j], minlength=n_bins) for j in range(x.shape[1])], axis=1)
    ok = c > 0
    return xb[ok] / c[ok, None], vb[ok], c[ok]


class HeteroscedasticNoise(Detector):
    id = ENTRY.id
    sensors, structural, needs_reference = ENTRY.sensors, ENTRY.structural, ENTRY.needs_reference
    meaning = "noise level that depends on the motion's phase or changes over the record"
    plausible, plausible_unit, gate_params = 0.15, "noise", 2  # the variance ±30 % with the phase
    noise_structure = True

    def propose(self, ctx: Context, states: list[State]) -> list[Proposal]:
        idx = open_series(ctx, states, self.id)
        if not idx:
            return []
        fits = {kind: {} for kind in KINDS}
        stat = {kind: np.zeros(len(idx)) for kind in KINDS}
        infl = np.ones(len(idx))
        for j, i in enumerate(idx):
            st = states[i]
            r = residual(ctx, i, st)
            # noise correlated from frame to frame (AR(1), ρ) correlates the squared residuals
            # as ρ²ᵏ: a variance statistic varies (1 + ρ²)/(1 − ρ²) times more than white noise's
            lr = long_run_factor(ctx, i, r)
            rho = (lr - 1.0) / (lr + 1.0)
            infl[j] = (1.0 + rho * rho) / (1.0 - rho * rho)
            inl = st.inlier
            v = (r[inl] / st.scale[inl]) ** 2
            for kind in KINDS:
                x = _features(ctx, i, kind)
                xi = x[inl]
                if kind == "phase":
                    frac = np.arctan2(xi[:, 1], xi[:, 0]) / (2 * np.pi) + 0.5
                else:
                    frac = 0.5 * (xi[:, 0] + 1.0)
                key = np.clip((frac * N_BINS[kind]).astype(np.int64), 0, N_BINS[kind] - 1)
                theta, cov, two_gain = fit_scale(*_binned(xi, v, key, N_BINS[kind]))
                fits[kind][i] = (theta, cov, x)
                stat[kind][j] = two_gain / infl[j]
        out = []
        for kind in KINDS:
            k = 2 if kind == "phase" else 1
            p_value = combined_p(
                stat[kind],
                k,
                len(KINDS),
                total=float(stat[kind].sum()),
                dof_total=k * len(idx),
                n_scan_total=len(KINDS),
            )
            prop = self._proposal(ctx, states, idx, kind, k, stat[kind], fits[kind], p_value, infl)
            if prop is not None:
                out.append(prop)
        return out

    def _proposal(self, ctx, states, idx, kind, k, stat, fits, p_value, infl) -> Proposal | None:
        new, thetas, covs = {}, {}, {}
        for j, i in enumerate(idx):
            if stat[j] <= k * math.log(ctx.series[i].n):
                continue
            st = states[i]
            theta, cov, x = fits[i]
            scale = st.scale * (1.0 + x @ theta)
            w = np.where(st.inlier, 1.0 / scale**2, 0.0)
            _, _, fitted = wls(ctx.nuisance(i), residual(ctx, i, st), w)
            cand = updated(st, self.id, k, mean=st.mean + fitted, scale=scale)
            if keep_series(gain(ctx, i, st, cand) / infl[j], k, ctx.series[i].n):
                new[i], thetas[i], covs[i] = cand, theta, cov
        if not new:
            return None
        kept = sorted(new)
        where = ", ".join(ctx.series[i].key for i in kept)
        if kind == "phase":
            ms = np.array([math.hypot(*thetas[i]) for i in kept])
            sig_m = []
            for i in kept:
                g = thetas[i] / max(math.hypot(*thetas[i]), 1e-300)
                sig_m.append(math.sqrt(max(float(g @ covs[i] @ g), 0.0)))
            vec = np.sum([thetas[i] / max(math.hypot(*thetas[i]), 1e-300) for i in kept], axis=0)
            psi = float(math.atan2(vec[1], vec[0]))
            r_len = float(np.hypot(*vec)) / len(kept)
            psi_sig = math.sqrt(max(-2 * math.log(max(r_len, 1e-12)), 0.0)) if len(kept) > 1 else None
            m = float(np.median(ms))
            params = {
                "kind": param("phase"),
                "modulation": param(m, 1.2533 * math.sqrt(float(np.mean(np.square(sig_m))) / len(kept))),
                "phase_rad": param(psi, psi_sig),
            }
            text = (
                f"The noise of {where} rises and falls with the motion's cycle by ±{100 * m:.0f} % "
                f"(largest {math.degrees(psi):.0f}° after the peak of the motion): the camera's range "
                "noise depends on where the plate is in its stroke (distance, angle, edge pixels)."
            )
            band = [ctx.f0_hz, ctx.f0_hz]
        else:
            ms = np.array([thetas[i][0] for i in kept])
            sig_m = np.array([math.sqrt(max(covs[i][0, 0], 0.0)) for i in kept])
            m = median_signed(ms)
            params = {
                "kind": param("time"),
                "modulation": param(m, 1.2533 * math.sqrt(float(np.mean(sig_m**2)) / len(kept))),
            }
            text = (
                f"The noise of {where} {'grows' if m > 0 else 'falls'} steadily over the record "
                f"(±{100 * abs(m):.0f} % from the middle to the ends): the camera warming up, changing "
                "ambient light or a deteriorating target."
            )
            band = None
        return Proposal(
            effect=self.id,
            series=kept,
            states=new,
            n_params=k * len(kept),
            p_value=p_value,
            trials=len(KINDS) * subset_trials(len(kept), len(idx)),  # kinds × series picked
            inflation=float(max(infl[idx.index(i)] for i in kept)),
            parameters=params,
            t_start=0.0,
            t_end=float(ctx.duration_s),
            band_hz=band,
            explanation=text,
            detail={
                "kind": kind,
                "theta": {ctx.series[i].key: [float(v) for v in thetas[i]] for i in kept},
            },
        )


EFFECT = HeteroscedasticNoise()
