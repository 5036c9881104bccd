"""``timing_error``: the camera's clock against the reference's: stamps = t + offset + rate·t_rel."""

from __future__ import annotations

from ._entry import Entry, Param, Report


def inject(e, trel):
    return e.p("offset_s") + e.p("rate_ppm") * 1e-6 * trel


def from_diagnosis(r: Report) -> tuple[dict, tuple[int, ...]]:
    """The offset and/or rate fitted; one clock (no plates)."""
    return {k: r.p[k] for k in ("offset_s", "rate_ppm") if r.p.get(k) is not None}, ()


ENTRY = Entry(
    id="timing_error",
    meaning="the camera's clock: stamps = t + offset + rate·t_rel",
    rank=7,
    structural=False,  # a clock's offset or rate: the measurement's
    needs_reference=True,
    level="timestamps",
    params=(Param("offset_s", "s", 0.0), Param("rate_ppm", "ppm", 0.0)),
    inject=inject,
    from_diagnosis=from_diagnosis,
    example={"offset_s": 0.01},
)
