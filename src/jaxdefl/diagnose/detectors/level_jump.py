"""Level jump: the measured position steps at one instant and stays there.

Physical meaning: a structured-light camera re-calibrates or its projector pattern shifts (the
"session jumps" of a Kinect), a ToF camera changes its integration time (its range offset depends
on it), the camera or a plate is knocked, or the segmentation switches to another pixel set.
When the cause is the camera, every plate jumps at the same instant; a segmentation change moves
one plate.

Signature test: a CUSUM scan of the residuals (after the free nuisance) on the frame clock: for a
split at every frame, the weighted likelihood-ratio statistic of a mean change (χ²_1 per series at
a fixed split), summed over the series (χ²_S) for a common jump, and its sparse version
(Σ max(T_s − log n, 0)) for a jump on a few series. The p-value is the largest single-series
statistic Bonferroni-corrected over series × candidate splits, or the summed statistic corrected
over the candidate splits, whichever is smaller (doubled); the splits are counted as the scan's
effective number of independent ones (`screening.changepoint_trials`, Siegmund's approximation:
neighbouring splits are nearly the same test: thousands of splits count as ~100). The jump time
is refined to the frame on the series that keep it. σ̂² is the long-run variance
(`screening.long_run_factor`): AR(1)-like noise wanders like steps.

Common mode: the same scan with one size shared by the series of an axis (Σ_s b_s/σ_s² over
Σ_s M_s/σ_s² of the CUSUM pieces: χ²_1 at a fixed split, corrected over the effective splits ×
axes): the camera shifting every plate alike, too little on each plate alone. Both proposals go to the
search; BIC decides.

Model term: y += δ_s H(t − t_j), t_j shared by the series it touches, δ_s per series: 1 + S
parameters (common mode: t_j and one δ, 2 parameters). A series keeps a per-series jump when its
own evidence pays for δ_s and for being chosen among the S series scanned (log n + 2 log S in
−2 log L). One jump per proposal: the search calls again after accepting one.

Plausible magnitudes: 0.1-2 mm for ToF integration-time changes; 1-10 mm for structured-light
session jumps (thesis Table 6.21), less on the centroids of large plates.
"""

from __future__ import annotations

import math

import numpy as np

from ..._numerics import P_MAX, wls
from ...effects.level_jump import ENTRY
from .._base import Context, Detector, Proposal, State, keep_series
from .screening import (
    bonferroni,
    changepoint_trials,
    chi2_sf,
    combined_p,
    gain,
    long_run_factor,
    median_signed,
    param,
    project_out,
    shared_amplitude,
    subset_trials,
    updated,
    weights,
)

__all__ = ["LevelJump", "EFFECT"]

EDGE = 0.01  # fraction of the record at each end where no split is tried (drift and outliers' ground)


def _cusum(ctx: Context, i: int, st: State):
    """(frame − 1,) χ²_1 statistic of a mean change after each frame, σ̂² of the series, and the
    pieces of the statistic: b = Σ_{k<=m} w (r − r̄), M = W_m (W − W_m)/W (stat = b²/(σ̂² M))."""
    s = ctx.series[i]
    w = weights(st)
    r = s.y - st.mean
    nu = ctx.nuisance(i)
    r0 = project_out(nu, w, r[:, None])[:, 0]
    n_used = max(int((w > 0).sum()) - nu.shape[1], 1)
    # frame-to-frame correlated noise wanders like a jump: its long-run variance is the scale
    s2 = (float(np.sum(w * r0 * r0) / n_used) or 1e-300) * long_run_factor(ctx, i, r0)
    wk = np.zeros(ctx.n_frames)
    rk = np.zeros(ctx.n_frames)
    wk[s.k] = w
    rk[s.k] = w * r0
    cw = np.cumsum(wk)[:-1]
    cr = np.cumsum(rk)[:-1]
    wt = float(wk.sum())
    rbar = float(rk.sum()) / max(wt, 1e-300)
    den = s2 * cw * (wt - cw) / max(wt, 1e-300)
    b = cr - cw * rbar
    with np.errstate(divide="ignore", invalid="ignore"):
        stat = np.where(den > 0, b * b / den, 0.0)
    return stat, s2, b, den / s2


class LevelJump(Detector):
    id = ENTRY.id
    sensors, structural, needs_reference = ENTRY.sensors, ENTRY.structural, ENTRY.needs_reference
    meaning = "a step of the measured position (structured-light instability, integration-time change)"
    causes = {  # noqa: RUF012
        "structured_light": "a structured-light re-calibration or a knock",
        "tof": "an integration-time change or a knock",
        "*": "a re-zeroing of the sensor, a slip of its mounting or a knock",
    }
    plausible, plausible_unit, gate_params = 0.15, "noise", 2  # a step of 0.3 σ at mid-record

    def propose(self, ctx: Context, states: list[State]) -> list[Proposal]:
        idx = [i for i in range(len(ctx.series)) if ctx.series[i].n >= 64]
        if not idx or ctx.n_frames < 20:
            return []
        nf = ctx.n_frames
        lo = max(int(math.ceil(EDGE * nf)), 2)
        hi = nf - 1 - lo  # splits m in [lo, hi): the jump falls between frames m and m + 1
        if hi <= lo:
            return []
        stat = np.zeros((len(idx), hi - lo))
        s2 = np.zeros(len(idx))
        axes = sorted({ctx.series[i].axis for i in idx})
        cb = {a: np.zeros(hi - lo) for a in axes}  # common mode: Σ b/σ̂², Σ M/σ̂² per axis
        cm = {a: np.zeros(hi - lo) for a in axes}
        for j, i in enumerate(idx):
            full, s2[j], b, m_ = _cusum(ctx, i, states[i])
            stat[j] = full[lo:hi]
            ax = ctx.series[i].axis
            cb[ax] += b[lo:hi] / s2[j]
            cm[ax] += m_[lo:hi] / s2[j]
        out = []
        for ax in axes:
            prop = self._common(
                ctx, states, [i for i in idx if ctx.series[i].axis == ax], cb[ax], cm[ax], lo, len(axes)
            )
            if prop is not None:
                out.append(prop)
        logn = np.array([math.log(ctx.series[i].n) for i in idx])
        n_cand = changepoint_trials(EDGE, hi - lo)  # effective splits
        total = stat.sum(axis=0)
        sparse = np.maximum(stat - logn[:, None], 0.0).sum(axis=0)
        p_value = combined_p(
            stat.max(axis=1), 1, n_cand, total=float(total.max()), dof_total=len(idx), n_scan_total=n_cand
        )
        # choosing which of S series jump costs log S per series kept (extended BIC): without it
        # one series in a few dozen passes the plain BIC at the split another series found
        margin = 2.0 * math.log(len(idx))
        best = None
        for m in {int(np.argmax(total)), int(np.argmax(sparse))}:
            cand = self._at(ctx, states, idx, lo + m, margin)
            if cand is not None and (best is None or cand[0] > best[0]):
                best = cand
        if best is None:
            return out
        _, m, kept, _ = best
        # refine the split on the series that keep the jump, then rebuild
        rows = [idx.index(i) for i in kept]
        m_ref = lo + int(np.argmax(stat[rows].sum(axis=0)))
        if m_ref != m:
            again = self._at(ctx, states, kept, m_ref, margin)
            if again is not None and again[0] >= best[0]:
                best = again
        score, m, kept, fits = best
        new = {i: fits[i][0] for i in kept}
        deltas = np.array([fits[i][1] for i in kept])
        sig_d = np.array([fits[i][2] for i in kept])
        size = median_signed(deltas)
        size_sigma = 1.2533 * math.sqrt(float(np.mean(sig_d**2)) / deltas.size)
        snr = float(sum(fits[i][1] ** 2 / s2[idx.index(i)] for i in kept))
        t_j = (m + 0.5) * ctx.dt_s
        sig_t = ctx.dt_s * max(0.5, math.sqrt(26.0) / max(snr, 1e-300))
        where = ", ".join(ctx.series[i].key for i in kept)
        who = "the camera (all these plates at once)" if len(kept) > 1 else "one plate"
        return out + [
            self._proposal(
                ctx,
                kept,
                new,
                1 + len(kept),
                p_value,
                2 * n_cand * subset_trials(len(kept), len(idx)),  # splits, common or per series
                (t_j, sig_t, size, size_sigma),
                f"The measured position of {where} steps by {size:+.3f} mm at t = {t_j:.2f} s "
                f"and stays there: {who}"
                f" changed its level — {self.cause(ctx)}.",
                {
                    "mode": "per_series",
                    "sizes_mm": {ctx.series[i].key: float(d) for i, d in zip(kept, deltas, strict=True)},
                },
            )
        ]

    def _common(self, ctx, states, idx, cb, cm, lo, n_axes) -> Proposal | None:
        """One jump of the same size on the series of an axis (the camera moved its levels)."""
        if len(idx) < 2:
            return None
        with np.errstate(divide="ignore", invalid="ignore"):
            c = np.where(cm > 0, cb * cb / cm, 0.0)
        j = int(np.argmax(c))
        n_splits = changepoint_trials(EDGE, c.size)  # effective splits
        p_value = bonferroni(float(chi2_sf(c[j], 1)), n_splits * n_axes)
        if p_value >= P_MAX:
            return None
        m = lo + j
        fit = shared_amplitude(
            ctx, states, idx, lambda i: (ctx.series[i].k > m).astype(float)[:, None], None, self.id
        )
        if fit is None:
            return None
        size = float(fit.beta[0])
        size_sigma = math.sqrt(max(float(fit.cov[0, 0]), 0.0))
        t_j = (m + 0.5) * ctx.dt_s
        # location: the argmax of a two-sided random walk with drift, var ≈ 26 / (δ²/σ²)² frames²
        snr = (
            size
            * size
            * sum(1.0 / max(float(np.var(ctx.series[i].y - states[i].mean)), 1e-300) for i in fit.series)
        )
        sig_t = ctx.dt_s * max(0.5, math.sqrt(26.0) / max(snr, 1e-300))
        where = ", ".join(ctx.series[i].key for i in fit.series)
        return self._proposal(
            ctx,
            fit.series,
            fit.states,
            2,
            p_value,
            2 * n_splits * n_axes,  # splits × axes, common or per series
            (t_j, sig_t, size, size_sigma),
            f"All of {where} step by {size:+.3f} mm at t = {t_j:.2f} s and stay there: the camera "
            f"changed its levels at once — {self.cause(ctx)}.",
            {"mode": "common"},
        )

    def _proposal(
        self, ctx, series, states, n_params, p_value, trials, jump, explanation, detail
    ) -> Proposal:
        """A jump's proposal: ``jump`` = (t_j, σ_t, size, σ_size); it lasts to the record's end."""
        t_j, sig_t, size, size_sigma = jump
        return Proposal(
            effect=self.id,
            series=series,
            states=states,
            n_params=n_params,
            p_value=p_value,
            parameters={"t_jump_s": param(t_j, sig_t), "size_mm": param(size, size_sigma)},
            t_start=float(t_j),
            t_end=float(ctx.duration_s),
            band_hz=None,
            explanation=explanation,
            detail=detail,
            trials=trials,
            scan_params=1,  # the jump time
        )

    def _at(self, ctx: Context, states: list[State], idx: list[int], m: int, margin: float):
        """Fit a jump after frame m on each series; keep those whose evidence pays for the jump
        and for being chosen (``margin``, in units of −2 log L). (score, m, kept, fits)."""
        fits = {}
        score = 0.0
        for i in idx:
            s, st = ctx.series[i], states[i]
            col = (s.k > m).astype(float)[:, None]
            if col.sum() == 0 or col.sum() == s.n:
                continue
            nu = ctx.nuisance(i)
            w = weights(st)
            beta, cov, fitted = wls(np.concatenate([col, nu], axis=1), s.y - st.mean, w)
            new = updated(st, self.id, 1, mean=st.mean + fitted)
            d_ll = gain(ctx, i, st, new)
            if keep_series(d_ll, 1, s.n, margin):
                fits[i] = (new, float(beta[0]), math.sqrt(max(float(cov[0, 0]), 0.0)))
                score += 2 * d_ll - math.log(s.n)
        if not fits:
            return None
        return score, m, sorted(fits), fits


EFFECT = LevelJump()
