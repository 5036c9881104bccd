"""The open world's search: greedy generic terms on the residual after the named effects, each
accepted at ΔBIC < `DELTA_BIC_MAX`, then backfitted (`search_unnamed`); `best_term` for the named
search's comparisons."""

from __future__ import annotations

import math

import numpy as np

from ..._numerics import DELTA_BIC_MAX
from .._base import Context, State
from .._correlation import FrameCorrelation
from .noise import Noise
from .report import UnnamedTerm, describe_term
from .terms import BUILDERS, term_sigmas

__all__ = ["KINDS", "MAX_TERMS", "apply_term", "best_term", "search_unnamed"]


KINDS = ("line", "envelope", "trend")
MAX_TERMS = 4
# the chosen term is refined only when its screening already shows evidence (a refit moves ΔBIC
# by a few units, not from nothing to −10); a refit costs a compilation per shape
REFINE_BELOW = 0.0


def _score(ctx, noise, states, corr, cand, n_total) -> float:
    dll = {}
    for i in cand.series:
        dll[i] = noise.loglik(i, cand.means[i]) - noise.base(i)
    if corr is not None:
        gain = corr.discount(dll)
    else:
        gain = sum(dll.values())
    return -2.0 * gain + cand.n_params * math.log(n_total)


def best_term(
    ctx: Context,
    states: list[State],
    corr: FrameCorrelation | None = None,
    bases: dict | None = None,
    kinds: tuple[str, ...] = KINDS,
):
    """The best generic term on the residual of ``states``: (ΔBIC, candidate) or None. Every
    kind of ``kinds`` screens (grids, linear fits); the best candidate alone is refined (its
    ``refine``) when its ΔBIC is below `REFINE_BELOW`, and kept refined when that scores better.
    ``bases``: the search's cache of spline bases."""
    n_total = sum(s.n for s in ctx.series)
    noise = Noise(ctx, states, bases, corr)
    best = None
    for kind in kinds:
        try:
            cands = BUILDERS[kind](ctx, states, noise, n_total)
        except np.linalg.LinAlgError:  # one generic term that cannot be fitted never stops the rest
            cands = []
        for c in cands:
            d = _score(ctx, noise, states, corr, c, n_total)
            if best is None or d < best[0]:
                best = (d, c)
    if best is not None and best[1].refine is not None and best[0] < REFINE_BELOW:
        q = best[1].refine()
        if q is not None:
            d = _score(ctx, noise, states, corr, q, n_total)
            if d < best[0]:
                best = (d, q)
    return best


def _term_states(ctx: Context, base: list[State], deltas: list[dict[int, np.ndarray]], cands) -> list[State]:
    """``base`` with every accepted term's mean change added."""
    states = list(base)
    for d, c in zip(deltas, cands, strict=True):
        for i, v in d.items():
            st = states[i]
            states[i] = st.with_(
                mean=st.mean + v,
                n_params=st.n_params + max(1, round(c.n_params / len(c.series))),
                effects=st.effects + ("unnamed",),
            )
    return states


def _as_term(ctx: Context, states: list[State], best, corr: FrameCorrelation | None = None) -> UnnamedTerm:
    dbic, c = best
    rms0 = float(np.sqrt(np.mean(np.concatenate([ctx.series[i].y - states[i].mean for i in c.series]) ** 2)))
    rms1 = float(np.sqrt(np.mean(np.concatenate([ctx.series[i].y - c.means[i] for i in c.series]) ** 2)))
    term = describe_term(ctx, c, states, term_sigmas(ctx, states, c, corr))
    term.delta_bic, term.rms_before_mm, term.rms_after_mm = float(dbic), rms0, rms1
    term.change = {i: c.means[i] - states[i].mean for i in c.series}
    term.candidate = c
    return term


def apply_term(
    ctx: Context, states: list[State], best, corr: FrameCorrelation | None = None
) -> tuple[UnnamedTerm, list[State]]:
    """The accepted term's report and the states with it."""
    c = best[1]
    delta = {i: c.means[i] - states[i].mean for i in c.series}
    return _as_term(ctx, states, best, corr), _term_states(ctx, states, [delta], [c])


def search_unnamed(
    ctx: Context,
    states: list[State],
    corr: FrameCorrelation | None = None,
    max_terms: int = MAX_TERMS,
    check=None,
    bases: dict | None = None,
    backfit: int = 2,
    prior: list[UnnamedTerm] = (),
) -> tuple[list[UnnamedTerm], list[State]]:
    """Greedy generic terms on the residual of ``states``: (accepted terms, the states after).
    ``prior``: terms already in ``states`` (accepted while competing with the named effects):
    they are backfitted with the new ones and returned first.

    Then ``backfit`` passes: each term, in turn, is fitted again (its kind's best) on the residual
    of all the others, and dropped when, given them, it no longer reaches ΔBIC < −10 (a line
    fitted while a larger decay was still in the residual leaves a spurious neighbour)."""
    bases = {} if bases is None else bases
    deltas: list[dict[int, np.ndarray]] = [dict(u.change) for u in prior]
    cands: list = [u.candidate for u in prior]
    base = list(states)
    for d in deltas:
        for i, v in d.items():
            base[i] = base[i].with_(mean=base[i].mean - v)
    for _ in range(max_terms - len(prior)):
        cur = _term_states(ctx, base, deltas, cands)
        best = best_term(ctx, cur, corr, bases)
        if check is not None:
            check()
        if best is None or not best[0] < DELTA_BIC_MAX:
            break
        c = best[1]
        deltas.append({i: c.means[i] - cur[i].mean for i in c.series})
        cands.append(c)
    scores = [None] * len(cands)
    for _ in range(backfit if len(cands) > 1 else 0):
        j = 0
        while j < len(cands):
            others = _term_states(ctx, base, deltas[:j] + deltas[j + 1 :], cands[:j] + cands[j + 1 :])
            best = best_term(ctx, others, corr, bases, kinds=(cands[j].kind,))
            if check is not None:
                check()
            if best is None or not best[0] < DELTA_BIC_MAX:
                del deltas[j], cands[j], scores[j]
                continue
            c = best[1]
            deltas[j] = {i: c.means[i] - others[i].mean for i in c.series}
            cands[j] = c
            scores[j] = (best[0], others)
            j += 1
    terms = []
    for j, c in enumerate(cands):
        others = _term_states(ctx, base, deltas[:j] + deltas[j + 1 :], cands[:j] + cands[j + 1 :])
        if scores[j] is None:  # no backfit: the greedy's own evidence, on the terms before it
            before = _term_states(ctx, base, deltas[:j], cands[:j])
            n_total = sum(s.n for s in ctx.series)
            d = _score(ctx, Noise(ctx, before, bases), before, corr, c, n_total)
            terms.append(_as_term(ctx, before, (d, c), corr))
        else:
            terms.append(_as_term(ctx, others, (scores[j][0], c), corr))
    return terms, _term_states(ctx, base, deltas, cands)
