"""The search: nominal model → residual structure → candidate effects → selection → report.

Forward selection, one effect per round. Every applicable effect screens the current residuals
and proposes (cheaply: grids, FFTs, linear fits); proposals are scored by

    ΔBIC = −2 Δlog L + k log N     (N: all samples of the record, k: parameters added)

with log L from `_base.loglik` (so mean terms and noise models are scored alike). The best
proposal is refitted in full (its ``refine``, optimistix), scored again, and accepted by a
calibrated test (`Calibration`): its likelihood-ratio statistic 2 Δlog L (under the search's noise
model: AR(1)-aware for mean terms, frame-common noise discounted by its design effect) exceeds
the null's critical value at the family-wise level α = 0.05 split over the effects screened,
with the look-elsewhere effect of the effect's own scan (`Proposal.trials`); its signature's
p-value survives the same level; and the likelihood-equivalent RMS of the series it touches goes
down. BIC chooses between competing explanations (the lowest ΔBIC that passes goes first) and is
reported; it no longer decides detection: with 10⁵ samples its k log N penalty asks for 35-45 χ²
units where the test at α = 0.05/11 asks for 12-25. Rounds continue until nothing passes. Then
the residuals of every series are tested for whiteness (`_whiteness`); what fails is reported as
unexplained, located.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from scipy import stats
from threadpoolctl import threadpool_limits

from .._errors import InputError
from .._numerics import DELTA_BIC_MAX
from .._signals import check_interrupt
from ..effects import REGISTRY, quantization
from ..settings import ALPHA_NAMED, DiagnoseSettings
from ._base import Context, Proposal, State, loglik, rms_equivalent
from ._context import build_context
from ._correlation import FrameCorrelation, frame_correlation, gls_gain
from ._sensor_nominal import nominal_level_jumps, within_configured
from ._whiteness import residual_tests, series_whiteness_p
from .detectors import load_detectors
from .record_kind import SEARCHED, RecordKind, kind_nominal, recognise, value_lattice
from .unnamed import MAX_TERMS, UnnamedTerm, apply_term, best_term, colored_gain, search_unnamed

# see the open world's competition in `run_diagnosis`: 2 let a level jump claim an exponential
# warm-up it explained 84 % of (held-out benchmark), and a step can only tie a generic step
GENERIC_FIRST_RATIO = 1.1
# A named effect whose rival (an id of a shared `Entry.footprint`) fits the same residual within
# this ΔBIC is reported as not told apart from it (6: a Bayes factor of about 20, Kass & Raftery's
# "strong"), and within it by AIC (a parameter costs 2 instead of BIC's ln n: what an extra
# parameter gains on noise alone, twice): a name told apart by BIC alone wins by its parameter
# count, a prior's verdict, not the data's (a small crack's new frequency and a frequency drift
# fit a 3-minute record alike, and the drift is one parameter cheaper: ln n ≈ 10.5 of BIC's
# margin). Reported, not acted on: as a rule that withholds the name it cost most
# of a warm-up's detection on 3-minute records (docs/benchmarks.md, "Rivals: tried and left out").
RIVAL_MARGIN = 6.0

__all__ = [
    "Diagnosis",
    "run_diagnosis",
    "diagnose",
    "Calibration",
    "DELTA_BIC_MAX",
    "ALPHA",
    "ALPHA_NAMED",
    "MAX_EFFECTS",
]

ALPHA = 0.01  # the residual tests' level (`Diagnosis.unexplained`)
MAX_EFFECTS = 8
FINALISTS = 2  # effects refined before BIC chooses one in a round
# Residual RMS below which a table is taken for noise-free (0.1 µm: far below any range camera's
# or laser sensor's noise; a simulation's truth written with 6 decimals sits near 3e-7 mm).
NOISE_FLOOR_MM = 1e-4
# Relevance: an effect that explains less than this share of the residual on its series, or whose
# term is smaller than this share of the motion, is a minor finding (listed apart, never first).
MINOR_RESIDUAL_SHARE = 0.02
MINOR_MOTION_SHARE = 0.002


@dataclass
class Accepted:
    proposal: Proposal
    delta_bic: float
    rms_before: float
    rms_after: float
    before: dict[int, State]
    lr: float = math.nan
    lr_critical: float = math.nan
    # rivals of a shared footprint fitted to the same residual (`_rival_margins`)
    rivals: list[dict] = field(default_factory=list)


@dataclass
class Dropped:
    """A named effect the backward step took out again, and why."""

    effect: str
    reason: str
    lr: float
    lr_critical: float
    replaced_by: str | None = None


@dataclass
class Calibration:
    """The acceptance test of named effects, calibrated for one search.

    Under the nominal model, the likelihood-ratio statistic 2 Δlog L of a term of known form with
    k linear parameters is χ²_k when the noise model is right: `_score` computes it against AR(1)
    noise for mean terms (`unnamed.colored_gain`) and discounts noise shared by the plates of a
    frame (`_correlation`), so coloured and frame-common noise do not inflate it. A proposal is
    the best of its effect's scan: the maximum of ``trials`` such statistics (frequencies, jump
    times, orders, series), whose tail is at most ``trials`` times one's (Bonferroni, the
    look-elsewhere effect; `Proposal.trials` holds each effect's count, its scanned nonlinear
    parameters go there, not into k). With ``n_tests`` effects screened, the critical value is
    the χ²_k quantile at 1 − α / (n_tests · trials): at most α of the records without any effect
    get one named. Critical values are cached per (effect, k, trials) for this search.
    """

    n_tests: int
    alpha: float = ALPHA_NAMED
    cache: dict = field(default_factory=dict)

    def critical(self, p: Proposal) -> float:
        dof = max(int(p.n_params) - int(p.scan_params), 1)
        key = (p.effect, dof, float(p.trials))
        c = self.cache.get(key)
        if c is None:
            level = self.alpha / (max(self.n_tests, 1) * max(float(p.trials), 1.0))
            c = self.cache[key] = float(stats.chi2.isf(level, dof))
        return c

    def passes(self, p: Proposal, lr: float, rms0: float, rms1: float) -> bool:
        """The statistic beyond its critical value, the signature's p-value at the same level
        and the RMS of the touched series down."""
        return lr > self.critical(p) and rms1 < rms0 and p.p_value * max(self.n_tests, 1) < self.alpha


@dataclass
class Diagnosis:
    """The outcome: context, nominal and final states, accepted effects, residual tests."""

    ctx: Context
    nominal: list[State]
    final: list[State]
    accepted: list[Accepted]
    cannot_tell: list[dict]
    notes: list[str]
    tests_nominal: list[dict]
    tests_final: list[dict]
    seconds: float
    rounds: list[list[dict]] = field(default_factory=list)
    corr: FrameCorrelation | None = None
    # the open world (`unnamed`): generic terms on what the named effects leave, and the states
    # with them (the full model; ``final`` holds the named effects alone)
    unnamed: list[UnnamedTerm] = field(default_factory=list)
    open_final: list[State] | None = None
    # what kind of record this is (`record_kind`) and the effects the backward step took out
    record: RecordKind | None = None
    dropped: list[Dropped] = field(default_factory=list)
    # the configured sensor's own physics (`_sensor_nominal`): the level jumps the nominal model
    # holds, and the named effects within the configured sizes (kept in the model, not missing)
    sensor_jumps: list[dict] = field(default_factory=list)
    configured: list[tuple[Accepted, str]] = field(default_factory=list)
    alpha: float = ALPHA_NAMED  # the family-wise level named effects were accepted at

    # --- summaries --------------------------------------------------------------------------
    def _summary(self, states: list[State], tests: list[dict]) -> dict:
        ll = [loglik(s.y, st) for s, st in zip(self.ctx.series, states, strict=True)]
        n_tot = sum(s.n for s in self.ctx.series)
        k_tot = sum(st.n_params for st in states)
        p = [series_whiteness_p(t) for t in tests]
        return {
            "rms_mm": rms_equivalent(float(np.sum(ll)), n_tot),
            "bic": float(-2 * np.sum(ll) + k_tot * math.log(n_tot)),
            "whiteness_p": float(min(1.0, len(p) * min(p))) if p else 1.0,
            "n_params": int(k_tot),
            "n_samples": int(n_tot),
        }

    def unexplained(self) -> list[dict]:
        """Residual structure left by the final model, grouped by test and location."""
        ctx = self.ctx
        m = len(ctx.series)
        groups: dict[tuple, dict] = {}
        for i, tests in enumerate(self.tests_final):
            s = ctx.series[i]
            for name, v in tests.items():
                p = min(1.0, v["p"] * len(tests) * m)
                if p >= ALPHA:
                    continue
                if v["band_hz"] is not None and name == "spectrum":
                    centre = 0.5 * (v["band_hz"][0] + v["band_hz"][1])
                    key = (name, round(centre * ctx.duration_s / 2))
                else:
                    key = (name,)
                g = groups.setdefault(
                    key,
                    {
                        "test": name,
                        "plates": set(),
                        "axes": set(),
                        "p_value": 1.0,
                        "band_hz": v["band_hz"],
                        "times": [],
                    },
                )
                g["plates"].add(s.plate)
                g["axes"].add(s.axis)
                g["p_value"] = min(g["p_value"], p)
                if v["t"] is not None:
                    g["times"].append(v["t"])
        out = []
        for g in groups.values():
            times = g.pop("times")
            t_lo = min(times) if times else 0.0
            t_hi = max(times) if times else ctx.duration_s
            out.append(
                {
                    "test": g["test"],
                    "plates": sorted(g["plates"]),
                    "axes": sorted(g["axes"]),
                    "t_start": ctx.t0 + t_lo,
                    "t_end": ctx.t0 + t_hi,
                    "band_hz": g["band_hz"],
                    "p_value": g["p_value"],
                    "description": _UNEXPLAINED[g["test"]],
                }
            )
        return sorted(out, key=lambda u: u["p_value"])

    def relevance(self, a: Accepted) -> dict:
        """An effect's share of the nominal residual it explains on its series and its size
        against the motion there; ``minor`` when either is negligible (`MINOR_RESIDUAL_SHARE`,
        `MINOR_MOTION_SHARE`)."""
        ctx, p = self.ctx, a.proposal
        resid0 = motion = size = 0.0
        for i in p.series:
            y = ctx.series[i].y
            nom = self.nominal[i].mean
            resid0 += float(np.mean((y - nom) ** 2))
            motion += float(np.var(nom))
            size += float(np.mean((p.states[i].mean - a.before[i].mean) ** 2))
        m = max(len(p.series), 1)
        resid0, motion, size = resid0 / m, motion / m, size / m
        explained = max(a.rms_before**2 - a.rms_after**2, 0.0)
        if size == 0.0:  # a noise model: its size is the variance it accounts for
            size = explained
        share = explained / resid0 if resid0 > 0 else 0.0
        vs_motion = math.sqrt(size / motion) if motion > 0 else math.inf
        return {
            "residual_share": share,
            "size_vs_motion": vs_motion,
            "minor": bool(share < MINOR_RESIDUAL_SHARE or vs_motion < MINOR_MOTION_SHARE),
        }

    def to_json(self) -> dict:
        """The DIAG.json contract of DESIGN.md (plus inputs, notes and what cannot be told)."""
        ctx = self.ctx
        effects = []
        for a in self.accepted:
            p = a.proposal
            rel = self.relevance(a)
            effects.append(
                {
                    "id": p.effect,
                    **_where(ctx, p.series, p.t_start, p.t_end, p.band_hz),
                    "parameters": _jsonable(p.parameters),
                    "delta_bic": a.delta_bic,
                    "lr": a.lr,
                    "lr_critical": a.lr_critical,
                    # the test's degrees of freedom and look-elsewhere count (`Calibration`)
                    "lr_dof": max(int(p.n_params) - int(p.scan_params), 1),
                    "trials": float(p.trials),
                    "rms_before_mm": a.rms_before,
                    "rms_after_mm": a.rms_after,
                    "p_value": p.p_value,
                    "explanation": p.explanation,
                    "detail": _jsonable(p.detail),
                    "relevance": rel,
                    "rivals": a.rivals,
                    "not_told_from": [
                        r["id"] for r in a.rivals if min(r["margin"], r["aic_margin"]) < RIVAL_MARGIN
                    ],
                }
            )
        # A later effect may refit an earlier one's parameters at no cost (a clock offset and a
        # tap spread trade phase against the LDS): the report carries the joint values.
        latest: dict[str, dict] = {}
        for a, e in zip(self.accepted, effects, strict=True):
            for eid, params in (a.proposal.detail or {}).get("reestimated", {}).items():
                if eid in latest:
                    latest[eid]["parameters"].update(_jsonable(params))
                    latest[eid].setdefault("reestimated_by", []).append(e["id"])
            latest[e["id"]] = e
        nominal = self._summary(self.nominal, self.tests_nominal)
        if self.corr is not None:
            axes = sorted(set(self.corr.axes))
            nominal["frame_correlation"] = {a: self.corr.mean_offdiagonal(a) for a in axes}
        nominal["series"] = [
            {
                "plate": s.plate,
                "axis": s.axis,
                "n": s.n,
                "tied_to_reference": s.tied,
                "f0_hz": h.f0_hz,
                "amplitude_mm": h.amplitude,
                "offset_mm": h.offset,
                "rms_mm": float(np.sqrt(np.mean((s.y - st.mean) ** 2))),
            }
            for s, h, st in zip(ctx.series, ctx.nominal, self.nominal, strict=True)
        ]
        return _jsonable(
            {
                "input": {
                    "plates": ctx.plates,
                    "axes": sorted({s.axis for s in ctx.series}),
                    "n_series": len(ctx.series),
                    "t_start": ctx.t0,
                    "duration_s": ctx.duration_s,
                    "frame_interval_s": ctx.dt_s,
                    "f0_hz": ctx.f0_hz,
                    "sensor": ctx.sensor,
                    "frame_rate_hz": ctx.frame_rate_hz,
                    "modulation_mhz": ctx.modulation_mhz,
                    "reference_plates": sorted(ctx.reference_harmonic),
                    "alpha": self.alpha,
                },
                "record_kind": self.record.kind if self.record is not None else "forced_harmonic",
                "record": self.record.to_json() if self.record is not None else None,
                "nominal": nominal,
                "effects": effects,
                "minor": [e["id"] for e in effects if e["relevance"]["minor"]],
                "dropped": [
                    {
                        "id": d.effect,
                        "reason": d.reason,
                        "lr": d.lr,
                        "lr_critical": d.lr_critical,
                        "replaced_by": d.replaced_by,
                    }
                    for d in self.dropped
                ],
                "unnamed": [_unnamed_json_of(ctx, u) for u in self.unnamed],
                "nominal_physics": [
                    {
                        "id": a.proposal.effect,
                        **{
                            k: v
                            for k, v in _where(ctx, a.proposal.series, 0.0, 0.0, None).items()
                            if k in ("plates", "axes")
                        },
                        "lr": a.lr,
                        "parameters": _jsonable(a.proposal.parameters),
                        "reason": why,
                    }
                    for a, why in self.configured
                ],
                "sensor_nominal": {"level_jumps": self.sensor_jumps},
                "unexplained": self.unexplained(),
                "final": self._summary(
                    self.open_final if self.open_final is not None else self.final, self.tests_final
                ),
                "cannot_tell": self.cannot_tell,
                "left_out": list(self.ctx.left_out),
                "notes": self.notes,
                "seconds": self.seconds,
            }
        )


def _where(ctx: Context, series, t_start: float, t_end: float, band_hz) -> dict:
    """Where a term acts, as DIAG.json says it: plates, axes, series, time span, band."""
    return {
        "plates": sorted({ctx.series[i].plate for i in series}),
        "axes": sorted({ctx.series[i].axis for i in series}),
        "series": [ctx.series[i].key for i in series],
        "t_start": ctx.t0 + t_start,
        "t_end": ctx.t0 + t_end,
        "band_hz": band_hz,
    }


def _unnamed_json_of(ctx: Context, u: UnnamedTerm) -> dict:
    return {
        "kind": u.kind,
        **_where(ctx, u.series, u.t_start, u.t_end, u.band_hz),
        "parameters": _jsonable(u.parameters),
        "n_params": u.n_params,
        "delta_bic": u.delta_bic,
        "rms_before_mm": u.rms_before_mm,
        "rms_after_mm": u.rms_after_mm,
        "rms_gain": u.rms_before_mm / u.rms_after_mm if u.rms_after_mm > 0 else None,
        "explanation": u.explanation,
        "detail": _jsonable(u.detail),
    }


_UNEXPLAINED = {
    "spectrum": "a spectral line in the residual that no candidate effect explains",
    "mean_shift": (
        "a slow change of the residual's mean (drift, jump or modulation) that no candidate explains"
    ),
    "variance_shift": "the noise level changes with time beyond what the model allows",
    "tails": "heavier tails than Gaussian noise (outliers or a mixture) that no candidate explains",
    "variance_vs_phase": "the noise depends on the motion phase beyond what the model allows",
}


def _jsonable(x):
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.generic):
        x = x.item()
    if isinstance(x, float) and not math.isfinite(x):
        return None
    if isinstance(x, np.ndarray):
        return _jsonable(x.tolist())
    return x


def _score(
    ctx: Context, states: list[State], p: Proposal, n_total: int, corr: FrameCorrelation | None = None
) -> tuple[float, float, float, float]:
    """(ΔBIC, RMS before, RMS after, LR = 2 Δlog L) of a proposal; RMS likelihood-equivalent
    over its series.

    With ``corr``, Δlog L is divided by the series' design effect: noise shared by the plates
    of a frame, or by a plate's axes, is not evidence for a term they share (`_correlation`);
    a term of known pattern across the series (``Proposal.shape``) is scored by the generalised
    least-squares statistic along its change instead (`_correlation.gls_gain`).
    """
    ll0 = ll1 = 0.0
    n = 0
    dll = {}
    for i in p.series:
        y = ctx.series[i].y
        a, b = loglik(y, states[i]), loglik(y, p.states[i])
        q = p.states[i]
        if q.scale is states[i].scale and q.inlier is states[i].inlier:
            # a mean term under coloured noise: its evidence against AR(1) noise (`unnamed`)
            c = colored_gain(ctx.series[i], states[i], q.mean)
            if c is not None:
                b = a + c
        ll0 += a
        ll1 += b
        dll[i] = b - a
        n += ctx.series[i].n
    if not (math.isfinite(ll0) and math.isfinite(ll1)) or n == 0:
        return math.inf, math.nan, math.nan, -math.inf
    # a known pattern: the generalised least-squares statistic under its series' covariance
    gls = gls_gain(ctx, states, p.states) if corr is not None and p.shape is not None else None
    if gls is not None:
        gain = gls
    else:
        gain = ll1 - ll0 if corr is None else corr.discount(dll, p.shape)
    dbic = -2.0 * gain + p.n_params * math.log(n_total)
    return dbic, rms_equivalent(ll0, n), rms_equivalent(ll1, n), 2.0 * gain / max(p.inflation, 1.0)


def _rebase(p: Proposal, base: list[State], states: list[State]) -> Proposal:
    """The proposal's change (mean increment, noise model, parameters) applied to ``states``."""
    new = {}
    for i in p.series:
        b, q, st = base[i], p.states[i], states[i]
        kw = {"mean": st.mean + (q.mean - b.mean), "n_params": st.n_params + (q.n_params - b.n_params)}
        if q.scale is not b.scale:
            kw["scale"] = q.scale
        if q.inlier is not b.inlier:
            kw.update(
                inlier=q.inlier, outlier_fraction=q.outlier_fraction, outlier_scale_mm=q.outlier_scale_mm
            )
        new[i] = st.with_(**kw)
    return dataclasses.replace(p, states=new)


def _resolution(ctx: Context, nominal: list[State]) -> dict | None:
    """The lattice the values sit on, read from their spacing (`record_kind.value_lattice`),
    against the noise: a lattice below the residual noise is the record's resolution (an ADC's
    step, a table's written decimals), not missing physics. None when the values are on no
    common lattice (a centroid averaged over many pixels)."""
    steps = [value_lattice(s.y) for s in ctx.series]
    if not steps or any(q is None for q in steps):
        return None
    q = float(np.median(steps))
    noise = float(
        np.median([np.sqrt(np.mean((s.y - st.mean) ** 2)) for s, st in zip(ctx.series, nominal, strict=True)])
    )
    decimal = abs(math.log10(q) - round(math.log10(q))) < 0.005
    return {"step": q, "noise": noise, "below_noise": bool(q < noise), "written_decimals": bool(decimal)}


def _without(states: list[State], a: Accepted) -> list[State]:
    """``states`` with an accepted effect's change taken out: its mean increment and its
    parameters, and its noise model where no later effect replaced it."""
    out = list(states)
    eid = a.proposal.effect
    for i in a.proposal.series:
        st, q, b = states[i], a.proposal.states[i], a.before[i]
        effects = list(st.effects)
        if eid in effects:
            effects.remove(eid)
        kw = {
            "mean": st.mean - (q.mean - b.mean),
            "n_params": st.n_params - (q.n_params - b.n_params),
            "effects": tuple(effects),
        }
        if q.scale is not b.scale and st.scale is q.scale:
            kw["scale"] = b.scale
        if q.inlier is not b.inlier and st.inlier is q.inlier:
            kw.update(
                inlier=b.inlier, outlier_fraction=b.outlier_fraction, outlier_scale_mm=b.outlier_scale_mm
            )
        out[i] = st.with_(**kw)
    return out


def _retest(ctx, states, a: Accepted, base: list[State], calib, corr, n_total):
    """The accepted effect's test given ``base`` (the model without it): (passes, LR, critical)."""
    q = _rebase(a.proposal, a.before, base)
    _, r0, r1, lr = _score(ctx, base, q, n_total, corr)
    return calib.passes(q, lr, r0, r1), lr, calib.critical(q), q


def _backward(ctx, states, accepted, dropped, calib, corr, n_total, usable):
    """Backward elimination after an addition (issue 23, Build item 2): every earlier effect is
    tested again given all the others, (a) as it stands and (b) with the newest effect refitted
    in its absence (a term fitted on what the earlier one left may explain it all once refitted:
    a quantisation staircase after the lines its harmonics made); the first that no longer passes
    is dropped, and the pass repeats. Returns (states, accepted)."""
    newest = accepted[-1]
    while True:
        for a in accepted[:-1]:
            base = _without(states, a)
            ok, lr, crit, _ = _retest(ctx, states, a, base, calib, corr, n_total)
            if not ok:
                dropped.append(
                    Dropped(
                        a.proposal.effect,
                        f"no longer needed once {newest.proposal.effect} is in the model: given all the "
                        f"other terms its statistic is {lr:.1f}, below the critical {crit:.1f}",
                        lr,
                        crit,
                        newest.proposal.effect,
                    )
                )
                accepted = [x for x in accepted if x is not a]
                states = base
                break
            if a.proposal.effect == newest.proposal.effect or newest.proposal.effect not in usable:
                continue
            # (b) the newest refitted without a: does a still pay for itself?
            both = _without(_without(states, newest), a)
            best = None
            for p in usable[newest.proposal.effect].propose(ctx, both):
                if not p.series:
                    continue
                d, r0, r1, lr_n = _score(ctx, both, p, n_total, corr)
                if not calib.passes(p, lr_n, r0, r1):
                    continue
                if p.refine is not None:
                    q = p.refine()
                    if q is not None:
                        d2, q0, q1, lr2 = _score(ctx, both, q, n_total, corr)
                        if calib.passes(q, lr2, q0, q1) and d2 < d:
                            d, r0, r1, lr_n, p = d2, q0, q1, lr2, q
                if best is None or d < best[0]:
                    best = (d, r0, r1, lr_n, p)
            if best is None:
                continue
            d, r0, r1, lr_n, p = best
            alt = list(both)
            for i in p.series:
                alt[i] = p.states[i]
            ok, lr, crit, _ = _retest(ctx, alt, a, alt, calib, corr, n_total)
            if ok:
                continue
            renewed = Accepted(p, d, r0, r1, {i: both[i] for i in p.series}, lr_n, calib.critical(p))
            dropped.append(
                Dropped(
                    a.proposal.effect,
                    f"no longer needed once {newest.proposal.effect} is refitted without it: given all "
                    f"the other terms its statistic is {lr:.1f}, below the critical {crit:.1f}",
                    lr,
                    crit,
                    newest.proposal.effect,
                )
            )
            accepted = [renewed if x is newest else x for x in accepted if x is not a]
            newest = renewed
            states = alt
            break
        else:
            return states, accepted


def _passes_afresh(ctx, states, effect, calib, corr, n_total) -> tuple[bool, float, float]:
    """Does the effect, proposed afresh on ``states`` (refined where its screening is coarse),
    pass its test? (passes, the best statistic seen, that proposal's critical value)."""
    best, crit = 0.0, math.inf
    for p in effect.propose(ctx, states):
        if not p.series:
            continue
        q = p
        for refined in (False, True):
            if refined:  # refined only where the screening's proposal fails
                q = p.refine() if p.refine is not None else None
                if q is None:
                    break
            _, r0, r1, lr = _score(ctx, states, q, n_total, corr)
            if calib.passes(q, lr, r0, r1):
                return True, lr, calib.critical(q)
            if lr > best:
                best, crit = lr, calib.critical(q)
    return False, best, crit


def _events(ctx, eid: str, group: list[Accepted]) -> int:
    """How many events the accepted instances of one effect are. A range effect or a knock is
    seen on a plate's three axes (the centroid moves along its line of sight) and may be named on
    each: instances on different axes that share at least half of the smaller one's plates and
    whose locators agree within half its resolution (`Entry.locator`: a jump's time; as
    reconcile's `_same_injection`) are one event."""
    loc = REGISTRY[eid].locator if eid in REGISTRY else None

    def where(a):
        plates = {ctx.series[i].plate for i in a.proposal.series}
        axes = {ctx.series[i].axis for i in a.proposal.series}
        x = None
        if loc is not None:
            v = a.proposal.parameters.get(loc[0])
            x = v.get("value") if isinstance(v, dict) else v
        return plates, axes, x

    events: list[list[tuple]] = []
    for a in group:
        w = where(a)
        for ev in events:
            if all(
                not (w[1] & o[1])
                and len(w[0] & o[0]) >= 0.5 * min(len(w[0]), len(o[0]))
                and (w[2] is None) == (o[2] is None)
                and (w[2] is None or abs(w[2] - o[2]) <= 0.5 * loc[1])
                for o in ev
            ):
                ev.append(w)
                break
        else:
            events.append([w])
    return len(events)


def _repeats(ctx, p: Proposal, accepted: list[Accepted]) -> bool:
    """Whether ``p`` is an accepted instance again: the same id with a locator (`Entry.locator`:
    a mode's number, a jump's time, a line's frequency), on an axis and plates it shares, located
    within half the locator's resolution and, for a line or a mode, at the same frequency (within
    the record's frequency resolution). One mode has one amplitude and phase over the span: two
    instances of mode 3 at one frequency on overlapping plates, with opposite signs, stood in for
    one line in the load's shape (frame-level seed 417)."""
    loc = REGISTRY[p.effect].locator if p.effect in REGISTRY else None
    if loc is None:
        return False

    def value(q, name):
        v = q.parameters.get(name)
        v = v.get("value") if isinstance(v, dict) else v
        return None if v is None else float(v)

    plates = {ctx.series[i].plate for i in p.series}
    axes = {ctx.series[i].axis for i in p.series}
    df = 1.0 / max(ctx.duration_s, 1e-9)
    for a in accepted:
        q = a.proposal
        if q.effect != p.effect:
            continue
        if not (axes & {ctx.series[i].axis for i in q.series}) or not (
            plates & {ctx.series[i].plate for i in q.series}
        ):
            continue
        x, y = value(p, loc[0]), value(q, loc[0])
        if x is None or y is None or abs(x - y) > 0.5 * loc[1]:
            continue
        f, g = value(p, "freq_hz"), value(q, "freq_hz")
        if f is not None and g is not None and abs(f - g) > df:
            continue
        return True
    return False


def _flexible_alternative(ctx, states, accepted, dropped, terms, calib, corr, n_total, library, bases):
    """A named mean effect must beat its flexible unnamed alternative on the same residual: all
    the accepted instances of an effect (several level jumps) are taken out together, the best
    generic term (a line, an envelope, a smooth trend, a decay) is fitted on what they leave,
    and they stay when they explain as much as that term (within GENERIC_FIRST_RATIO, as in the
    forward competition: a warm-up's exponential against a spline) or when the effect, proposed
    afresh given the term, still passes its test. Otherwise the generic term takes their place.
    One event named on several axes (`_events`: a warm-up on a plate's x, y and z) is one
    instance here: each met the generic term when it was chosen, and their sum, discounted once
    for the axes' shared noise, would pay every instance's parameters. Returns (states, accepted,
    terms)."""
    for eid in list(dict.fromkeys(a.proposal.effect for a in accepted)):
        group = [a for a in accepted if a.proposal.effect == eid]
        # one instance met the best generic term when it was chosen (the forward competition,
        # GENERIC_FIRST_RATIO); several (jumps) never met one generic term together
        if len(group) < 2 or library[eid].noise_structure or len(terms) >= MAX_TERMS:
            continue
        if _events(ctx, eid, group) < 2:
            continue
        base = states
        for a in group:
            base = _without(base, a)
        generic = best_term(ctx, base, corr, bases)
        if generic is None or not generic[0] < DELTA_BIC_MAX:
            continue
        named = base
        for a in group:
            named = [*named]
            for i, st in _rebase(a.proposal, a.before, named).states.items():
                named[i] = st
        series = sorted({i for a in group for i in a.proposal.series})
        both = dataclasses.replace(
            group[0].proposal,
            series=series,
            states={i: named[i] for i in series},
            n_params=sum(a.proposal.n_params for a in group),
        )
        d_named = _score(ctx, base, both, n_total, corr)[0]
        if not generic[0] < GENERIC_FIRST_RATIO * d_named:
            continue
        term, alt = apply_term(ctx, base, generic, corr)
        kept, lr, crit = _passes_afresh(ctx, alt, library[eid], calib, corr, n_total)
        if kept:
            continue
        why = (
            f"its best statistic is {lr:.1f}, below the critical {crit:.1f}"
            if lr <= crit
            else f"its best statistic, {lr:.1f} against the critical {crit:.1f}, fails its signature "
            "test or does not lower the RMS"
        )
        for _a in group:
            dropped.append(
                Dropped(
                    eid,
                    f"an unnamed {term.kind} explains the same residual: given it, {why}",
                    lr,
                    crit,
                    f"unnamed {term.kind}",
                )
            )
        accepted = [x for x in accepted if x.proposal.effect != eid]
        terms = [*terms, term]
        states = alt
    return states, accepted, terms


def _best_rival(ctx, base, effect, corr, n_total) -> tuple[float, int]:
    """(ΔBIC, parameters) of ``effect``'s best proposal afresh on ``base`` (refined where its
    screening is coarse), passing its own test or not: what the rival's shape explains of the
    same residual."""
    best, k = math.inf, 0
    for p in effect.propose(ctx, base):
        if not p.series:
            continue
        for q in (p, p.refine() if p.refine is not None else None):
            if q is None:
                continue
            d = _score(ctx, base, q, n_total, corr)[0]
            if d < best:
                best, k = d, int(q.n_params)
    return best, k


def _rival_margins(ctx, states, accepted, usable, corr, n_total) -> None:
    """Each named effect against its rivals (usable ids sharing an `Entry.footprint` tag: a
    warm-up and a level jump are both a slow change of the mean). The effect's instances are
    taken out together; each rival is proposed afresh on what they leave; the margin is the
    rival's ΔBIC there minus the effect's best instance's (rebased onto the same residual):
    positive when the named shape fits better; ``aic_margin`` the same with AIC's cost of a
    parameter (2) for BIC's (ln n). Sets ``Accepted.rivals`` (most similar first)."""
    for eid in dict.fromkeys(a.proposal.effect for a in accepted):
        tags = set(REGISTRY[eid].footprint) if eid in REGISTRY else set()
        rivals = [r for r in usable if r != eid and r in REGISTRY and tags & set(REGISTRY[r].footprint)]
        if not rivals:
            continue
        group = [a for a in accepted if a.proposal.effect == eid]
        base = states
        for a in group:
            base = _without(base, a)
        # instance against proposal, each on what the group leaves: a proposal is one instance
        # (one axis, say), and a plate's three axes share one noise (the line of sight), so a
        # group's sum would be discounted once but pay every instance's parameters
        scored = []
        for a in group:
            q = _rebase(a.proposal, a.before, base)
            scored.append((_score(ctx, base, q, n_total, corr)[0], int(q.n_params)))
        d_named, k_named = min(scored)
        found = []
        for r in rivals:
            check_interrupt()
            d, k = _best_rival(ctx, base, usable[r], corr, n_total)
            if math.isfinite(d) and math.isfinite(d_named):
                shared = sorted(tags & set(REGISTRY[r].footprint))
                margin = d - d_named
                aic = margin - (k - k_named) * (math.log(n_total) - 2.0)
                found.append(
                    {"id": r, "delta_bic": d, "margin": margin, "aic_margin": aic, "footprint": shared}
                )
        found.sort(key=lambda x: x["margin"])
        for a in group:
            a.rivals = found


# One BLAS thread: the diagnosis' products are many small GEMMs and dots over one series, where
# OpenBLAS's threads cost more to wake than they save and, on cores shared with other jobs, spin
# against them (measured: the whole search twice as slow, drift's screening five times). JAX's
# solvers keep their own thread pool.
@threadpool_limits.wrap(limits=1, user_api="blas")
def run_diagnosis(
    traj: pd.DataFrame,
    reference: pd.DataFrame | None = None,
    settings: DiagnoseSettings | None = None,
    *,
    source: str = "<table>",
    reference_source: str = "--reference",
    on_round=None,
) -> Diagnosis:
    """Diagnose a trajectory table (DESIGN.md contract) against the nominal model.

    Args:
        traj: the camera's trajectory table; reference: an LDS table (t, plate, z) or None.
        settings: what is known of the camera, the segment, the effects searched, the timestamp
            policy and the open world (`jaxdefl.settings.DiagnoseSettings`; default: nothing
            known, every effect).
        source, reference_source: the tables' names in error messages.
        on_round: optional callback(round number, accepted effect id or None).
    """
    start = time.perf_counter()
    settings = settings if settings is not None else DiagnoseSettings()
    library = load_detectors()
    if settings.effects is not None:
        library = {k: v for k, v in library.items() if k in settings.effects}
    ctx, nominal, notes = build_context(
        traj, reference, settings, source, reference_source, allow_no_motion=True
    )
    # what kind of record this is, before anything is named (`record_kind`)
    record = recognise([(s.t, s.y) for s in ctx.series], ctx.dt_s)
    no_motion = "no plate and axis shows a significant periodic motion"
    if no_motion in notes and record.level_path is not None:
        # the series' own periodograms missed the line a level path hid: the nominal harmonic
        # at the line the record kind found under the path
        ctx, nominal, notes = build_context(
            traj, reference, settings, source, reference_source, f0_hint_hz=record.level_path["line_hz"]
        )
    if no_motion in notes:
        if record.kind not in ("quasi_static", "broadband"):
            raise InputError(f"{source}: {no_motion} to diagnose")
        notes.remove(no_motion)
    nominal, kind_notes = kind_nominal(ctx, nominal, record)
    notes[:0] = [f"record kind: {record.statement}", *kind_notes]
    sensor_jumps: list[dict] = []
    if record.kind in ("forced_harmonic", "multi_tone", "free_decay"):
        # a configured structured-light camera's level jumps are its nominal physics
        nominal, sensor_jumps = nominal_level_jumps(ctx, nominal)
        if sensor_jumps:
            notes.append(
                "nominal model: the configured structured-light camera's level jumps "
                f"({ctx.jumps_per_minute:g} a minute, RMS {ctx.jump_mm:g} mm): "
                f"{len(sensor_jumps)} common steps of "
                + ", ".join(f"{j['size_mm']:+.2f}" for j in sensor_jumps)
                + " mm fitted on every series"
            )
    record.resolution = _resolution(ctx, nominal)
    if record.resolution is not None and record.resolution["below_noise"]:
        notes.append(
            f"the values sit on a lattice of {record.resolution['step']:.4g} (read from their spacing), "
            f"below the noise ({record.resolution['noise']:.3g}): the record's resolution, "
            "not missing physics"
        )
    searched = SEARCHED[record.kind]
    cannot_tell = []
    usable = {}
    rms = [float(np.sqrt(np.mean((s.y - st.mean) ** 2))) for s, st in zip(ctx.series, nominal, strict=True)]
    noise_free = float(np.median(rms)) < NOISE_FLOOR_MM
    if noise_free:
        notes.append(
            f"the residuals about the nominal model are {np.median(rms):.1e} mm RMS (median over "
            "series): a noise-free table (a simulation's truth, rounded on writing)"
        )
    corr = frame_correlation(ctx, nominal)
    for eid, eff in library.items():
        why = None
        if searched is not None and eid not in searched:
            why = (
                f"the record is a {record.kind.replace('_', ' ')} record: {eid} is defined against one "
                "steady loading harmonic, which this record does not have"
            )
        why = why or eff.cannot_tell(ctx, corr)
        if why is None and noise_free:
            why = (
                f"the table carries no measurement noise (residual RMS below {NOISE_FLOOR_MM:g} mm): "
                "evidence cannot be weighed against rounding"
            )
        if why is None:
            usable[eid] = eff
        else:
            cannot_tell.append({"id": eid, "reason": why})

    n_total = sum(s.n for s in ctx.series)
    for axis in sorted(set(corr.axes)):
        rho = corr.mean_offdiagonal(axis)
        if rho > 0.05:
            notes.append(
                f"the plates' {axis} noise is correlated within a frame (mean ρ = {rho:.2f}, from "
                "frame-to-frame differences of the residuals): evidence for effects alike on "
                "several plates is discounted by the design effect 1 + (m − 1)ρ"
            )
    same_plate = [
        abs(corr.matrix[i, j])
        for i, a in enumerate(ctx.series)
        for j, b in enumerate(ctx.series)
        if i < j and a.plate == b.plate
    ]
    if same_plate and float(np.mean(same_plate)) > 0.5:
        notes.append(
            f"a plate's axes share their noise (mean |ρ| = {np.mean(same_plate):.2f} between the "
            "axes of a plate: a range error moves the centroid along its line of sight): an "
            "effect's evidence on a plate is counted once, not once per axis"
        )
    states = list(nominal)
    accepted: list[Accepted] = []
    terms: list[UnnamedTerm] = []
    open_world = settings.open_world and not noise_free
    bases: dict = {}  # the open world's spline bases, for this search
    rounds: list[list[dict]] = []
    calib = Calibration(max(len(usable), 1), alpha=settings.alpha)
    dropped: list[Dropped] = []
    # Proposals of every effect, with the states they were made on. After an effect is accepted
    # the others are re-scored on the new states by re-applying their change (`_rebase`), and
    # only the best one is proposed afresh: a round costs one effect's screening, not eleven.
    # When nothing passes, every effect not yet screened on the current states screens them once
    # more before stopping.
    cache: dict[str, list[tuple[Proposal, list[State]]]] = {}
    screened_on: dict[str, list[State]] = {}

    def screen(eid: str) -> None:
        base = list(states)
        screened_on[eid] = base
        cache[eid] = [(p, base) for p in usable[eid].propose(ctx, base) if p.series]

    def current(eid: str) -> bool:
        """The effect was screened on the current states (since the last acceptance): screening
        it again would return the same proposals."""
        base = screened_on.get(eid)
        return base is not None and all(b is st for b, st in zip(base, states, strict=True))

    for eid in usable:
        screen(eid)
    fresh_round = True
    models_seen: set = set()
    while len(accepted) < MAX_EFFECTS:
        scored = []
        for eid, props in cache.items():
            for p, base in props:
                q = (
                    p
                    if base is states or all(base[i] is states[i] for i in p.series)
                    else _rebase(p, base, states)
                )
                d, _, _, lr = _score(ctx, states, q, n_total, corr)
                scored.append((d, lr, calib.critical(q), eid))
        rounds.append([{"effect": e, "delta_bic": d, "lr": lr, "lr_critical": c} for d, lr, c, e in scored])
        scored.sort(key=lambda x: x[0])  # BIC chooses between the explanations that pass
        chosen = None
        tried = set()
        finalists: list[Accepted] = []
        for _, lr, crit, eid in scored:
            if eid in tried or not lr > crit:
                continue
            tried.add(eid)
            if not current(eid):
                screen(eid)  # propose again on the current states: the exact proposal
            for p, _ in sorted(cache[eid], key=lambda x: _score(ctx, states, x[0], n_total, corr)[0]):
                if _repeats(ctx, p, accepted):
                    continue
                d, r0, r1, lr = _score(ctx, states, p, n_total, corr)
                if not calib.passes(p, lr, r0, r1):
                    continue
                if p.refine is not None:
                    q = p.refine()
                    if q is not None:
                        d2, q0, q1, lr2 = _score(ctx, states, q, n_total, corr)
                        if calib.passes(q, lr2, q0, q1):
                            d, r0, r1, lr, p = d2, q0, q1, lr2, q
                finalists.append(
                    Accepted(p, d, r0, r1, {i: states[i] for i in p.series}, lr, calib.critical(p))
                )
                break
            # BIC chooses among the FINALISTS refined, not their screening proposals: a line's
            # coarse proposal near f0 scores far below its refined fit, and a neighbour's
            # (a mode on half of the plates) would otherwise go first
            if len(finalists) == FINALISTS:
                break
        if finalists:
            chosen = min(finalists, key=lambda a: a.delta_bic)
        # The open world competes: a generic term far better than the named candidate (a free
        # decay read as a noise level that changes, say) goes first, as unnamed. Far better means
        # a better mean than a noise-structure effect's (a decaying mode makes the residual's
        # variance fall), or, against a named mean shape, one the named shape explains less than
        # 1/GENERIC_FIRST_RATIO of: a flexible spline always beats a physical shape by some ΔBIC
        # on a strong signal (a camera warm-up seen through the extraction's gains), and that is
        # not missing physics.
        if open_world and chosen is not None and len(terms) < MAX_TERMS:
            generic = best_term(ctx, states, corr, bases)
            far_better = chosen.delta_bic + DELTA_BIC_MAX
            if not library[chosen.proposal.effect].noise_structure:  # a mean shape against a mean one
                far_better = min(far_better, GENERIC_FIRST_RATIO * chosen.delta_bic)
            if generic is not None and generic[0] < far_better:
                term, states = apply_term(ctx, states, generic, corr)
                terms.append(term)
                if on_round is not None:
                    on_round(len(rounds) - 1, "unnamed")
                for eid in usable:
                    screen(eid)
                fresh_round = False
                continue
        if on_round is not None:
            on_round(len(rounds) - 1, chosen.proposal.effect if chosen else None)
        check_interrupt()
        if chosen is None:
            if fresh_round:
                break
            for eid in usable:
                if not current(eid):
                    screen(eid)
            fresh_round = True
            continue
        accepted.append(chosen)
        states = list(states)
        for i in chosen.proposal.series:
            states[i] = chosen.proposal.states[i]
        if len(accepted) > 1:
            states, accepted = _backward(ctx, states, accepted, dropped, calib, corr, n_total, usable)
        # Two effects that explain the same residual can trade places for ever: one added drops
        # the other, which then passes again and drops the first. A model the search has had
        # before ends it, as it stands.
        model = (len(terms), tuple(sorted((a.proposal.effect, tuple(a.proposal.series)) for a in accepted)))
        if model in models_seen:
            last = dropped[-1] if dropped else None
            traded = sorted({last.effect, last.replaced_by} - {None}) if last else []
            notes.append(
                "the search came back to a model it had already had"
                + (
                    f" ({' and '.join(traded)} explain the same residual, each replacing the other)"
                    if traded
                    else ""
                )
                + ": it stopped there"
            )
            break
        models_seen.add(model)
        cache.pop(chosen.proposal.effect, None)
        screen(chosen.proposal.effect)  # the same effect may be there twice (a second line, jump)
        # An effect that proposed nothing has no cached change to re-score: it looks again at
        # once (a staircase hidden under a drift, say), or a lesser effect would take its
        # structure first. When nothing else passes, the last round then skips it.
        for eid in usable:
            if not cache.get(eid) and not current(eid):
                screen(eid)
        fresh_round = False

    if open_world and accepted:
        states, accepted, terms = _flexible_alternative(
            ctx, states, accepted, dropped, terms, calib, corr, n_total, library, bases
        )
    open_states = states
    if open_world and not noise_free:
        terms, open_states = search_unnamed(ctx, states, corr, MAX_TERMS, check_interrupt, bases, prior=terms)
        # the named terms tested once more with the flexible discrepancy in place: an effect
        # that only absorbed part of a structure the generic terms now model goes
        for a in list(accepted):
            base = _without(open_states, a)
            ok, lr, crit, _ = _retest(ctx, open_states, a, base, calib, corr, n_total)
            if ok:
                continue
            dropped.append(
                Dropped(
                    a.proposal.effect,
                    "no longer needed with the unnamed terms in place: given them and the other effects "
                    f"its statistic is {lr:.1f}, below the critical {crit:.1f}",
                    lr,
                    crit,
                    "unnamed",
                )
            )
            accepted = [x for x in accepted if x is not a]
            open_states = base
            states = _without(states, a)
    # named effects within the configured sensor's sizes are its nominal physics: kept in the
    # model, reported apart (`_sensor_nominal.within_configured`)
    configured = []
    for a in accepted:
        p = a.proposal
        # a step's size on each depth series (its reported size is one over every axis)
        steps = [
            float(np.ptp(p.states[i].mean - a.before[i].mean)) for i in p.series if ctx.series[i].axis == "z"
        ]
        why = within_configured(
            ctx,
            {
                "id": p.effect,
                "plates": sorted({ctx.series[i].plate for i in p.series}),
                "parameters": p.parameters,
                "depth_step_mm": max(steps) if steps else None,
            },
        )
        if why is not None:
            configured.append((a, why))
    accepted = [a for a in accepted if all(a is not c for c, _ in configured)]
    if accepted:
        _rival_margins(ctx, states, accepted, usable, corr, n_total)
    if (
        any(a.proposal.effect == quantization.ENTRY.id for a, _ in configured)
        and record.resolution is not None
    ):
        record.resolution["below_noise"] = False
        notes[:] = [n for n in notes if "the record's resolution" not in n]
    if any(a.proposal.effect == quantization.ENTRY.id for a in accepted) and record.resolution is not None:
        # the fine lattice is the staircase's own (a centroid of rounded pixels): not a resolution
        record.resolution["below_noise"] = False
        notes[:] = [n for n in notes if "the record's resolution" not in n]
    if noise_free:  # whiteness of rounding errors says nothing of the physics
        tests_nominal = tests_final = []
    else:
        tests_nominal = [residual_tests(ctx, i, st) for i, st in enumerate(nominal)]
        # a series no accepted effect touched keeps its nominal state and so its nominal tests
        tests_final = [
            tests_nominal[i] if st is nominal[i] else residual_tests(ctx, i, st)
            for i, st in enumerate(open_states)
        ]
    return Diagnosis(
        ctx=ctx,
        nominal=nominal,
        final=states,
        accepted=accepted,
        cannot_tell=cannot_tell,
        notes=notes,
        tests_nominal=tests_nominal,
        tests_final=tests_final,
        seconds=time.perf_counter() - start,
        rounds=rounds,
        corr=corr,
        unnamed=terms,
        open_final=open_states,
        record=record,
        dropped=dropped,
        sensor_jumps=sensor_jumps,
        configured=configured,
        alpha=calib.alpha,
    )


def diagnose(traj: pd.DataFrame, reference: pd.DataFrame | None = None, **settings) -> dict:
    """`run_diagnosis` returning the DIAG.json dict (DESIGN.md contract); ``settings`` are the
    fields of `DiagnoseSettings` (``sensor="tof", frame_rate_hz=20.0``, ...)."""
    return run_diagnosis(traj, reference, DiagnoseSettings(**settings)).to_json()
