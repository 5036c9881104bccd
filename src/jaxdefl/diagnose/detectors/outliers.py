"""Outliers: a small fraction of samples far from the model (heavy tails of the residuals).

Physical meaning: mixed pixels at a plate's edge pulled into its centroid (ToF), a segmentation
that caught part of the background or lost part of the plate, multipath and flying pixels, a
structured-light speckle that failed to decode: single frames whose centroid is off by several σ,
on the plates where the segmentation is fragile.

Signature test: the count of residuals beyond c·σ̂ (σ̂ from the median absolute deviation,
robust to the outliers themselves) against its Gaussian expectation, for c = 3.5, 4, 5, 6, 8
(Poisson tail, Bonferroni over thresholds and series). The series that show it get a
two-component mixture fitted by EM (inlier N(0, σ² scale²), outlier N(0, s²), fraction ε).

Model term: the hard-assigned mixture `_base.loglik` evaluates: samples whose posterior favours
the outlier component leave the Gaussian fit and pay log ε + N(0, s²); the others pay
log(1 − ε). Two parameters per series (ε, s); the offset (and C, D) are refitted on the inliers.
Reported: ``fraction`` (ε, the share of contaminated samples), ``scale_mm`` (the size of the
contaminating error, √(s² − σ²): the outliers are the clean sample plus that error).

Plausible magnitudes: ε of 0.1-2 %, errors of 4-20 σ (a few mm to a few cm).
"""

from __future__ import annotations

import math

import numpy as np
from scipy import stats

from ..._numerics import mad_sigma, wls
from ...effects.outliers import ENTRY
from .._base import Context, Detector, Proposal, State, keep_series
from .screening import bonferroni, gain, param, residual, subset_trials, touched, updated

__all__ = ["Outliers", "EFFECT"]

THRESHOLDS = (3.5, 4.0, 5.0, 6.0, 8.0)
EM_STEPS = 60
S_MIN = 3.5  # the outlier component's σ at least this many inlier σ's


def _robust_sigma(z: np.ndarray) -> float:
    return mad_sigma(z) or 1e-300


def _tail_p(z: np.ndarray, sigma: float) -> float:
    """Smallest Poisson tail p-value of the exceedance counts over THRESHOLDS (uncorrected)."""
    a = np.abs(z) / sigma
    n = z.size
    best = 1.0
    for c in THRESHOLDS:
        k = int(np.count_nonzero(a > c))
        mu = n * 2.0 * stats.norm.sf(c)
        if k > mu:
            best = min(best, float(stats.poisson.sf(k - 1, mu)))
    return best


def _em(r: np.ndarray, scale: np.ndarray, sigma0: float, kind: str):
    """EM of the zero-mean mixture (1 − ε) N(0, σ² scale²) + ε g(r), with the outlier density g
    either N(0, s²) (``gaussian``: errors drawn from a normal law) or ½ N(±s, σ² scale²)
    (``sign``: errors of a fixed size and random sign).

    Returns (ε, σ, s, outlier responsibility (sample,), mixture log-likelihood).
    """
    eps, sig = 0.01, sigma0
    big = np.abs(r) > 4 * sigma0 * scale
    s = float(np.sqrt(np.mean(r[big] ** 2))) if big.sum() >= 2 else 6 * sigma0
    r2 = r * r
    ar = np.abs(r)
    med = float(np.median(scale))
    resp = np.zeros_like(r)
    ll = -np.inf
    for _ in range(EM_STEPS):
        si = sig * scale
        li = math.log1p(-eps) - np.log(si) - 0.5 * r2 / si**2
        if kind == "gaussian":
            lo = math.log(eps) - math.log(s) - 0.5 * r2 / s**2
        else:  # ½ N(s, si²) + ½ N(−s, si²), written stably
            lo = (
                math.log(eps)
                - np.log(si)
                - 0.5 * (ar - s) ** 2 / si**2
                + np.log1p(np.exp(-2 * ar * s / si**2))
                - math.log(2)
            )
        ll = float(np.sum(np.logaddexp(li, lo)))
        resp = 1.0 / (1.0 + np.exp(np.clip(li - lo, -700, 700)))
        n_out = float(resp.sum())
        eps_new = min(max(n_out / r.size, 1e-7), 0.5)
        if kind == "gaussian":
            sig_new = math.sqrt(float(np.sum((1 - resp) * r2 / scale**2)) / max(r.size - n_out, 1.0))
            s_new = math.sqrt(float(np.sum(resp * r2)) / max(n_out, 1e-12)) if n_out > 1e-9 else s
        else:
            sig_new = math.sqrt(float(np.sum(((1 - resp) * r2 + resp * (ar - s) ** 2) / scale**2)) / r.size)
            s_new = float(np.sum(resp * ar)) / max(n_out, 1e-12) if n_out > 1e-9 else s
        done = abs(eps_new - eps) < 1e-6 * max(eps, 1e-6) and abs(s_new - s) < 1e-6 * s
        # the outlier component stays far (S_MIN σ): a misfit one slides in to absorb the tails
        eps, sig, s = eps_new, sig_new, max(s_new, S_MIN * sig_new * med)
        if done:
            break
    return eps, sig, s, resp, ll


class Outliers(Detector):
    id = ENTRY.id
    sensors, structural, needs_reference = ENTRY.sensors, ENTRY.structural, ENTRY.needs_reference
    meaning = "heavy-tailed residuals: single frames far off (mixed pixels, segmentation failures)"
    plausible, plausible_unit, gate_params = 0.5, "noise", 2  # 1 % of the frames 5 σ off
    noise_structure = True

    def propose(self, ctx: Context, states: list[State]) -> list[Proposal]:
        cand = []
        p_tail = []
        for i, st in enumerate(states):
            if touched(st, self.id) or st.outlier_fraction > 0 or ctx.series[i].n < 64:
                continue
            r = residual(ctx, i, st)
            z = (r / st.scale)[st.inlier]
            p = _tail_p(z, _robust_sigma(z))
            p_tail.append(p)
            if p < 1e-3:
                cand.append(i)
        if not p_tail:
            return []
        m_tests = len(p_tail) * len(THRESHOLDS)
        p_value = bonferroni(min(p_tail), m_tests)
        new, info = {}, {}
        for i in cand:
            st = states[i]
            s = ctx.series[i]
            r = residual(ctx, i, st)
            sig0 = _robust_sigma((r / st.scale)[st.inlier])
            fits = {kind: _em(r, st.scale, sig0, kind) for kind in ("gaussian", "sign")}
            kind = max(fits, key=lambda k: fits[k][4])
            eps, sig, sc, resp, _ = fits[kind]
            # hard assignment: the outlier component wins the sample
            inlier = st.inlier & (resp < 0.5)
            n_flag = int((~inlier & st.inlier).sum())
            if n_flag == 0 or inlier.sum() < 16:
                continue
            # the state's mixture: the hard-assigned maximum-likelihood ε and s of `loglik`
            eps_st = n_flag / int(st.inlier.sum())
            sc_st = float(np.sqrt(np.mean(r[~inlier & st.inlier] ** 2)))
            # the offset (and C, D) refitted without the outliers: free nuisance
            w = np.where(inlier, 1.0 / st.scale**2, 0.0)
            _, _, fitted = wls(ctx.nuisance(i), r, w)
            cand_st = updated(
                st,
                self.id,
                2,
                mean=st.mean + fitted,
                inlier=inlier,
                outlier_fraction=eps_st,
                outlier_scale_mm=sc_st,
            )
            d_ll = gain(ctx, i, st, cand_st)
            if not keep_series(d_ll, 2, s.n):
                continue
            new[i] = cand_st
            # the contaminating error's size: the outlier component is the sample's noise plus it
            err = sc if kind == "sign" else math.sqrt(max(sc**2 - (sig * float(np.mean(st.scale))) ** 2, 0.0))
            n_out = float(resp.sum())
            info[i] = dict(
                eps=eps,
                eps_sigma=math.sqrt(eps * (1 - eps) / s.n),
                scale=err,
                scale_sigma=sc / math.sqrt(max(2 * n_out, 1.0)),
                n_out=n_flag,
                kind=kind,
            )
        if not new:
            return []
        kept = sorted(new)
        frac = float(np.median([info[i]["eps"] for i in kept]))
        frac_sig = float(np.median([info[i]["eps_sigma"] for i in kept])) / math.sqrt(len(kept))
        scale = float(np.median([info[i]["scale"] for i in kept]))
        scale_sig = float(np.median([info[i]["scale_sigma"] for i in kept])) / math.sqrt(len(kept))
        where = ", ".join(ctx.series[i].key for i in kept)
        n_flag = sum(info[i]["n_out"] for i in kept)
        return [
            Proposal(
                effect=self.id,
                series=kept,
                states=new,
                n_params=2 * len(kept),
                p_value=p_value,
                trials=len(THRESHOLDS) * subset_trials(len(kept), len(p_tail)),  # thresholds × series
                parameters={"fraction": param(frac, frac_sig), "scale_mm": param(scale, scale_sig)},
                t_start=0.0,
                t_end=float(ctx.duration_s),
                band_hz=None,
                explanation=(
                    f"About {100 * frac:.2g} % of the frames of {where} are off by about {scale:.2f} mm "
                    f"({n_flag} frames set aside): single-frame failures — mixed pixels at the plate's "
                    "edge or a segmentation that caught the background."
                ),
                detail={
                    "fractions": {ctx.series[i].key: info[i]["eps"] for i in kept},
                    "scales_mm": {ctx.series[i].key: info[i]["scale"] for i in kept},
                    "flagged": {ctx.series[i].key: info[i]["n_out"] for i in kept},
                    "error_law": {ctx.series[i].key: info[i]["kind"] for i in kept},
                },
            )
        ]


EFFECT = Outliers()
