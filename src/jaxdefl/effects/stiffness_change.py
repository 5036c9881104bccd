"""``stiffness_change``: a crack at ``t_s``: the stiffness changes by the relative
``stiffness_change`` s, so f0 × √(1 + s) and (under load control) the deflection amplitude
× 1/(1 + s), or ``f0_change`` / ``amplitude_change`` given directly; the load's phase stays
continuous."""

from __future__ import annotations

import math

import numpy as np

from ._entry import (
    WHEN,
    Bench,
    Entry,
    Motion,
    Param,
    Report,
    active,
    bench_load,
    check_when,
    elapsed,
    relative,
)


def inject(e, m: Motion):
    """k ∝ f0² and, under load control, deflection ∝ 1/k: phase continuous at the change."""
    if e.p("f0_change"):
        m.load_phase = m.load_phase + 2 * np.pi * m.f0_hz * e.p("f0_change") * elapsed(e, m.tau)
    m.amplitude = m.amplitude * np.where(active(e, m.tau), 1.0 + e.p("amplitude_change"), 1.0)


def resolve(p: dict, bad) -> dict:
    """f0_change and amplitude_change from stiffness_change s (which is not kept)."""
    s = p.pop("stiffness_change", 0.0)
    if not s > -1:
        raise bad("stiffness_change", "a relative change > -1", s)
    p.setdefault("f0_change", math.sqrt(1.0 + s) - 1.0)
    p.setdefault("amplitude_change", 1.0 / (1.0 + s) - 1.0)
    return p


def check(e, bad):
    check_when(e, bad)
    relative("f0_change")(e, bad)
    relative("amplitude_change")(e, bad)


def from_diagnosis(r: Report) -> tuple[dict, tuple[int, ...]]:
    """The crack's time and its fitted frequency and amplitude changes; the beam's (no plates)."""
    return {k: r.p[k] for k in ("t_s", "f0_change", "amplitude_change")}, ()


def draw(b) -> dict:
    """The benchmark's crack: at 20-80 % of the record, costing at most 30 % of the stiffness."""
    e = dict(
        kind="crack",
        parameters={
            "t_s": round(float(b.rng.uniform(0.2, 0.8)) * b.base.duration, 3),
            "stiffness_change": -1e-4,
        },
        plates=b.everyone,
        axes=list(b.axes),
    )
    return b.sized(e, "stiffness_change", (0.0, 0.3))


def _truth(base, e, p, out, t_tab, extras):
    out["t_start"] = float(t_tab[0]) + float(p["t_s"])


ENTRY = Entry(
    id="stiffness_change",
    record_kinds=("forced_harmonic",),
    meaning="a crack: f0 × (1 + f0_change), the deflection amplitude × (1 + amplitude_change)",
    rank=15,
    level="motion",
    params=(
        *WHEN,
        Param("stiffness_change", "relative", 0.0),
        Param("f0_change", "relative"),
        Param("amplitude_change", "relative"),
    ),
    inject=inject,
    check=check,
    resolve=resolve,
    from_diagnosis=from_diagnosis,
    locator=("t_s", 1.0),
    example={"t_s": 120.0, "stiffness_change": -0.0005},
    draw=draw,
    scored=lambda kind: {"stiffness_change": True, "t_s": True},
    bench=Bench(load=bench_load, truth=_truth),
    footprint=("a change of the loading frequency", "a change of the amplitude"),
)
