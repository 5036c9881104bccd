"""``harmonic_distortion``: the load's k-th harmonic, a cos(k θ(t) − ψ) at mid-span with θ the
load's phase (support contact, a cyclic range error)."""

from __future__ import annotations

import numpy as np

from ._entry import PHASE, Bench, Entry, Motion, Param, Report, bench_plates


def inject(e, m: Motion):
    k, a, psi = int(e.p("order")), e.p("amplitude_mm"), e.p("phase_rad")
    m.extra.append(lambda theta: a * np.cos(k * theta - psi))


def check(e, bad):
    if not (e.p("order") >= 2 and e.p("order") == round(e.p("order"))):
        raise bad("order", "an integer >= 2")


def from_diagnosis(r: Report) -> tuple[dict, tuple[int, ...]]:
    """The order, mid-span amplitude and phase as fitted; one motion of the beam (no plates)."""
    p = r.p
    return {
        "order": p["order"],
        "amplitude_mm": p["amplitude_mm"],
        "phase_rad": p.get("phase_rad") or 0.0,
    }, ()


def draw(b) -> dict:
    """The benchmark's harmonic: order 2 or 3 on 1-3 adjacent plates (mixed pixels) or on all."""
    rng, n_pl = b.rng, b.n_plates
    plates = b.adjacent(n_pl, int(rng.integers(1, 4))) if rng.random() < 0.6 else b.everyone
    e = dict(
        kind="mixed_pixels" if len(plates) < n_pl else "cyclic_error",
        parameters={"order": int(rng.choice([2, 3])), "amplitude_mm": 0.1, "phase_rad": b.psi},
        plates=plates,
        axes=["z"],
    )
    return b.sized(e, "amplitude_mm")


def _camera(base, e, pos, trel):
    """z += a cos(k ω t_rel − ψ) on its plates (the camera's: the LDS does not see it)."""
    p = e["parameters"]
    k, a, psi = int(p["order"]), float(p["amplitude_mm"]), float(p["phase_rad"])
    pos[:, bench_plates(e), 2] += (a * np.cos(k * base.omega * trel - psi))[:, None]


def _truth(base, e, p, out, t_tab, extras):
    p["order"] = int(p["order"])


ENTRY = Entry(
    id="harmonic_distortion",
    record_kinds=("forced_harmonic",),
    meaning="the load's k-th harmonic a cos(k θ − ψ)",
    rank=2,
    level="motion",
    params=(Param("order", "k"), Param("amplitude_mm", "mm at mid-span"), PHASE),
    inject=inject,
    check=check,
    from_diagnosis=from_diagnosis,
    locator=("order", 1.0),
    example={"order": 2, "amplitude_mm": 0.3, "phase_rad": 0.5},
    draw=draw,
    scored=lambda kind: {"order": True, "amplitude_mm": False},
    bench=Bench(camera=_camera, truth=_truth),
)
