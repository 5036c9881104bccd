"""``clipping``: a plate's reading saturates at ``level_mm`` from its rest position (the plate
leaves the camera's depth band, or its pixels saturate): its recorded motion is flat-topped on
that side. One table per plate."""

from __future__ import annotations

import numpy as np

from ._entry import Bench, Entry, Param, Report, bench_plates


def inject(e, trel, motion, dx, dy, rest):
    """The camera's reading of the plate saturates (the plate leaves the depth band, the pixels
    read the band's bound): its deflection from rest is clamped at ``level_mm`` on that side."""
    j, lv = e.p("plate") - 1, e.p("level_mm")
    d = motion[:, j] - rest[j]
    motion[:, j] = rest[j] + (np.minimum(d, lv) if lv > 0 else np.maximum(d, lv))


def check(e, bad):
    if e.p("level_mm") == 0:
        raise bad("level_mm", "a level != 0 mm (+ far side, − near side)")


def from_diagnosis(r: Report) -> tuple[dict, tuple[int, ...]]:
    """The strongest clipped plate and its bound (signed: + far side) as reported; the other
    clipped plates' bounds are in the report's detail (``levels_mm``), one table each would
    simulate them too."""
    return {"plate": int(round(float(r.p["plate"]))), "level_mm": r.p["level_mm"]}, ()


def draw(b) -> dict:
    """The benchmark's clip: 1-2 adjacent plates of the span's middle third (they move most), a
    side, the level c (fraction of the amplitude) from the target (`Draw.clip_level`)."""
    rng, n_pl = b.rng, b.n_plates
    mid = list(range(max(1, n_pl // 3), n_pl - n_pl // 3 + 1))  # the plates that move most
    plates = b.adjacent(len(mid), int(rng.integers(1, 3)))
    side = float(rng.choice([-1.0, 1.0]))
    e = dict(
        id=ENTRY.id,
        kind="far" if side > 0 else "near",
        parameters={"level": 0.9, "side": side},
        plates=[mid[k - 1] for k in plates],
        axes=["z"],
    )
    return b.clip_level(e)


def _camera(base, e, pos, trel):
    """Last: the reading saturates at c A_p from the plate's offset on its side, whatever moved
    the plate (before the noise: the pixels read the bound each with its own noise)."""
    side, c = float(e["parameters"]["side"]), float(e["parameters"]["level"])
    for j in bench_plates(e):
        off = base.static[j, 2] + base.shape[j] * base.cfg.loading.mean_mm
        bound = c * base.amp0 * abs(base.shape[j])
        pos[:, j, 2] = off + side * np.minimum(side * (pos[:, j, 2] - off), bound)


ENTRY = Entry(
    id="clipping",
    record_kinds=("forced_harmonic",),
    meaning="a plate's reading saturating at level_mm from its rest position (the depth band's bound)",
    rank=13,
    structural=False,  # a depth band's or a converter's bound
    level="plate",
    params=(Param("plate", "plate number", plate=True), Param("level_mm", "mm from rest, signed")),
    inject=inject,
    check=check,
    from_diagnosis=from_diagnosis,
    example={"plate": 6, "level_mm": 1.5},
    draw=draw,
    scored=lambda kind: {"level_mm": True},
    bench=Bench(stage=2, camera=_camera),
)
