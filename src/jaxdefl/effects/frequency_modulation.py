"""``frequency_modulation``: the load's phase + π d (t_rel − t_ref)² + β sin(2π f_m t_rel + ψ): its
frequency drifts or wanders alike on every plate."""

from __future__ import annotations

import math

import numpy as np

from ._entry import MODULATION_MIN_CYCLES, Bench, Entry, Motion, Report, bench_load, modulation_params


def inject(e, m: Motion):
    d, tr, beta, fm, psi = (
        e.p(k) for k in ("drift_hz_per_s", "t_ref_s", "depth_rad", "freq_hz", "phase_rad")
    )
    m.shift = m.shift + math.pi * d * (m.tau - tr) ** 2 + beta * np.sin(2 * math.pi * fm * m.tau + psi)


def from_diagnosis(r: Report) -> tuple[dict, tuple[int, ...]]:
    """Linear about the record's middle (``t_ref_s`` = duration / 2, as the diagnosis fits it),
    or sinusoidal; one motion of the beam (no plates)."""
    p = r.p
    if "drift_hz_per_s" in p:
        return {"drift_hz_per_s": p["drift_hz_per_s"], "t_ref_s": r.duration_s / 2}, ()
    return {
        "depth_rad": p["depth_rad"],
        "freq_hz": p["freq_hz"],
        "phase_rad": r.detail.get("phase_rad", 0.0),
    }, ()


def draw(b) -> dict:
    """The benchmark's frequency: a linear drift about the middle or a sinusoidal wobble
    (5-50 mHz, and at least `MODULATION_MIN_CYCLES` cycles in the record: the detector's band starts there;
    within 0.5 rad)."""
    rng = b.rng
    if rng.random() < 0.5:
        e = dict(kind="linear", parameters={"drift_hz_per_s": float(rng.choice([-1.0, 1.0])) * 1e-7})
        key, bounds = "drift_hz_per_s", (0.0, math.inf)
    else:
        lo = max(0.005, MODULATION_MIN_CYCLES / b.base.duration)
        pars = {"depth_rad": 0.05, "freq_hz": round(b.loguniform(lo, max(lo, 0.05)), 5), "phase_rad": b.psi}
        e = dict(kind="sinusoidal", parameters=pars)
        key, bounds = "depth_rad", (0.0, 0.5)
    e |= dict(plates=b.everyone, axes=list(b.axes))
    return b.sized(e, key, bounds)


def _truth(base, e, p, out, t_tab, extras):
    """The load's modulation is told within ±0.1 Hz of f0."""
    out["band_hz"] = [base.f0 - 0.1, base.f0 + 0.1]


ENTRY = Entry(
    id="frequency_modulation",
    record_kinds=("forced_harmonic",),
    meaning="the load's phase + π d (t_rel − t_ref)² + β sin(2π f_m t_rel + ψ)",
    rank=6,
    level="motion",
    params=modulation_params("drift_hz_per_s", "Hz/s", "depth_rad", "rad"),
    inject=inject,
    from_diagnosis=from_diagnosis,
    locator=("freq_hz", 1e-3),
    example={"depth_rad": 0.2, "freq_hz": 0.02, "phase_rad": 0.3},
    draw=draw,
    scored=lambda kind: (
        {"drift_hz_per_s": True} if kind == "linear" else {"depth_rad": False, "freq_hz": True}
    ),
    bench=Bench(load=bench_load, truth=_truth),
    footprint=("a change of the loading frequency",),
)
