"""``extra_periodic``: a second motion of the beam in its deflection shape at a frequency
unrelated to the loading (pump, mount, floor)."""

from __future__ import annotations

import math

import numpy as np

from ._entry import PHASE, Entry, Motion, Param, Report, positive


def inject(e, m: Motion):
    f, a, psi, tau = e.p("freq_hz"), e.p("amplitude_mm"), e.p("phase_rad"), m.tau
    m.extra.append(lambda theta: a * np.cos(2 * math.pi * f * tau + psi))


def from_diagnosis(r: Report) -> tuple[dict, tuple[int, ...]]:
    """The line's frequency and mid-span amplitude (its phase is refitted by the
    reconciliation); one motion of the beam (no plates)."""
    return {"freq_hz": r.p["freq_hz"], "amplitude_mm": r.p["amplitude_mm"]}, ()


ENTRY = Entry(
    id="extra_periodic",
    meaning="a second motion of the beam in its deflection shape",
    rank=8,
    level="motion",
    params=(Param("freq_hz", "Hz"), Param("amplitude_mm", "mm at mid-span"), PHASE),
    inject=inject,
    check=positive("freq_hz", "a frequency > 0 Hz"),
    from_diagnosis=from_diagnosis,
    locator=("freq_hz", 1e-3),
    example={"freq_hz": 4.2, "amplitude_mm": 0.3, "phase_rad": 0.4},
)
