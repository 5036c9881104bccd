"""``amplitude_modulation``: the load's amplitude A·(1 + r (t_rel − t_ref) + m cos(2π f_m t_rel + ψ)),
alike on every plate."""

from __future__ import annotations

import math

import numpy as np

from ._entry import Entry, Motion, Report, modulation_params


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


ENTRY = Entry(
    id="amplitude_modulation",
    meaning="the load's amplitude A·(1 + r (t_rel − t_ref) + m cos(2π f_m t_rel + ψ))",
    rank=5,
    level="motion",
    params=modulation_params("relative_rate_per_s", "1/s", "depth", "relative"),
    inject=inject,
    check=check,
    from_diagnosis=from_diagnosis,
    locator=("freq_hz", 1e-3),
    example={"depth": 0.1, "freq_hz": 0.02, "phase_rad": 0.3},
)
