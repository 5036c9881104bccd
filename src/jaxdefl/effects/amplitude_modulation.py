"""``amplitude_modulation``: the load's amplitude A·(1 + r (t_rel − t_ref) + m cos(2π f_m t_rel + ψ)),
alike on every plate."""

from __future__ import annotations

import math

import numpy as np

from ._entry import MODULATION_MIN_CYCLES, Bench, Entry, Motion, Report, bench_load, modulation_params


def inject(e, m: Motion):
    r, tr, d, fm, psi = (e.p(k) for k in ("relative_rate_per_s", "t_ref_s", "depth", "freq_hz", "phase_rad"))
    m.gain = m.gain * (1.0 + r * (m.tau - tr) + d * np.cos(2 * math.pi * fm * m.tau + psi))


def check(e, bad):
    if abs(e.p("depth")) >= 1:
        raise bad("depth", "a modulation depth |m| < 1")


def from_diagnosis(r: Report) -> tuple[dict, tuple[int, ...]]:
    """Linear about the record's middle (``t_ref_s`` = duration / 2, as the diagnosis fits it),
    or sinusoidal; one motion of the beam (no plates)."""
    p = r.p
    if "relative_rate_per_s" in p:
        return {"relative_rate_per_s": p["relative_rate_per_s"], "t_ref_s": r.duration_s / 2}, ()
    return {"depth": p["depth"], "freq_hz": p["freq_hz"], "phase_rad": r.detail.get("phase_rad", 0.0)}, ()


def draw(b) -> dict:
    """The benchmark's envelope: linear about the middle or sinusoidal (5-50 mHz, and at least
    `MODULATION_MIN_CYCLES` cycles in the record: the detector's band starts there), within ±25 %."""
    rng = b.rng
    if rng.random() < 0.5:
        e = dict(kind="linear", parameters={"relative_rate_per_s": float(rng.choice([-1.0, 1.0])) * 1e-4})
        key, bound = "relative_rate_per_s", 0.25 / (0.5 * b.base.duration)
    else:
        lo = max(0.005, MODULATION_MIN_CYCLES / b.base.duration)
        pars = {"depth": 0.05, "freq_hz": round(b.loguniform(lo, max(lo, 0.05)), 5), "phase_rad": b.psi}
        e = dict(kind="sinusoidal", parameters=pars)
        key, bound = "depth", 0.25
    e |= dict(plates=b.everyone, axes=["z", "x"])
    return b.sized(e, key, (0.0, bound))  # an envelope changing by more than ±25 % would show


def _truth(base, e, p, out, t_tab, extras):
    """The load's modulation is told within ±0.1 Hz of f0."""
    out["band_hz"] = [base.f0 - 0.1, base.f0 + 0.1]


ENTRY = Entry(
    id="amplitude_modulation",
    record_kinds=("forced_harmonic",),
    meaning="the load's amplitude A·(1 + r (t_rel − t_ref) + m cos(2π f_m t_rel + ψ))",
    rank=5,
    level="motion",
    params=modulation_params("relative_rate_per_s", "1/s", "depth", "relative"),
    inject=inject,
    check=check,
    from_diagnosis=from_diagnosis,
    locator=("freq_hz", 1e-3),
    example={"depth": 0.1, "freq_hz": 0.02, "phase_rad": 0.3},
    draw=draw,
    scored=lambda kind: (
        {"relative_rate_per_s": True} if kind == "linear" else {"depth": False, "freq_hz": True}
    ),
    bench=Bench(load=bench_load, truth=_truth),
    footprint=("a change of the amplitude",),
)
