"""``level_jump``: a range offset from ``t_jump_s`` on (structured-light instability, an
integration-time change)."""

from __future__ import annotations

from ._entry import Entry, Param, Report, non_negative
from ._range import columns


def inject(e, trel, n_plates, seed):
    return columns(e, n_plates, off_plates=True), (e.p("size_mm") * (trel >= e.p("t_jump_s")))[:, None]


def from_diagnosis(r: Report) -> tuple[dict, tuple[int, ...]]:
    """The jump's time and its range size through the calibration's gains; the whole image when
    seen on at least half of the plates."""
    size = r.per_range(r.detail.get("sizes_mm") or {}, r.p["size_mm"])
    return {"t_jump_s": r.p["t_jump_s"], "size_mm": size}, () if r.whole else r.plates


ENTRY = Entry(
    id="level_jump",
    meaning="a range offset from t_jump_s on",
    rank=4,
    level="range",
    params=(Param("t_jump_s", "s"), Param("size_mm", "mm")),
    inject=inject,
    check=non_negative("t_jump_s", "a time >= 0 s"),
    from_diagnosis=from_diagnosis,
    locator=("t_jump_s", 1.0),
    example={"t_jump_s": 90.0, "size_mm": 1.0},
)
