"""``level_jump``: a range offset from ``t_jump_s`` on (structured-light instability, an
integration-time change)."""

from __future__ import annotations

from ._entry import Bench, Entry, Param, Report, bench_plates, non_negative
from ._range import columns


def inject(e, trel, n_plates, seed):
    return columns(e, n_plates, off_plates=True), (e.p("size_mm") * (trel >= e.p("t_jump_s")))[:, None]


def from_diagnosis(r: Report) -> tuple[dict, tuple[int, ...]]:
    """The jump's time and its range size through the calibration's gains; the whole image when
    seen on at least half of the plates."""
    size = r.per_range(r.detail.get("sizes_mm") or {}, r.p["size_mm"])
    return {"t_jump_s": r.p["t_jump_s"], "size_mm": size}, () if r.whole else r.plates


def draw(b) -> dict:
    """The benchmark's jump: at 15-85 % of the record, on every plate or one, at most σ."""
    rng, n_pl = b.rng, b.n_plates
    plates = b.everyone if rng.random() < 0.6 else [int(rng.integers(1, n_pl + 1))]
    t_j = round(float(rng.uniform(0.15, 0.85)) * b.base.duration, 3)
    e = dict(
        kind="all_plates" if len(plates) > 1 else "one_plate",
        parameters={"t_jump_s": t_j, "size_mm": float(rng.choice([-1.0, 1.0])) * 0.1},
        plates=plates,
        axes=["z"],
    )
    return b.sized(e, "size_mm", (0.0, b.sigma_z(e["plates"])))


def _camera(base, e, pos, trel):
    p = e["parameters"]
    pos[:, bench_plates(e), 2] += (float(p["size_mm"]) * (trel >= float(p["t_jump_s"])))[:, None]


def _truth(base, e, p, out, t_tab, extras):
    out["t_start"] = out["t_end"] = float(t_tab[0]) + float(p["t_jump_s"])


ENTRY = Entry(
    id="level_jump",
    record_kinds=("forced_harmonic", "multi_tone", "free_decay"),
    meaning="a range offset from t_jump_s on",
    rank=4,
    level="range",
    params=(Param("t_jump_s", "s"), Param("size_mm", "mm")),
    inject=inject,
    check=non_negative("t_jump_s", "a time >= 0 s"),
    from_diagnosis=from_diagnosis,
    locator=("t_jump_s", 1.0),
    example={"t_jump_s": 90.0, "size_mm": 1.0},
    draw=draw,
    scored=lambda kind: {"size_mm": True},
    bench=Bench(camera=_camera, truth=_truth),
    footprint=("a slow change of the mean",),
)
