"""``drift``: a camera warming up: every pixel (or the listed plates' pixels) reads
a·exp(−t_rel/τ) farther."""

from __future__ import annotations

import numpy as np

from ._entry import Bench, Entry, Param, Report, bench_plates, positive
from ._range import columns


def inject(e, trel, n_plates, seed):
    return columns(e, n_plates, off_plates=True), (e.p("amplitude_mm") * np.exp(-trel / e.p("tau_s")))[
        :, None
    ]


def from_diagnosis(r: Report) -> tuple[dict, tuple[int, ...]]:
    """The range size through the calibration's gains; a polynomial drift (slower than the
    record) is simulated as a warm-up whose time constant starts at the record's length
    (`jaxdefl.reconcile.engine.refine_range_effects` fits it); the whole image when seen on at
    least half of the plates."""
    p = r.p
    amp = r.per_range(r.detail.get("amplitudes_mm") or {}, p["amplitude_mm"])
    tau = p["tau_s"] if r.kind == "exponential" and p.get("tau_s") else r.duration_s
    return {"amplitude_mm": amp, "tau_s": tau}, () if r.whole else r.plates


def draw(b) -> dict:
    """The benchmark's warm-up: τ 60-400 s, every plate, its size at most σ (more shows by eye)."""
    e = dict(
        kind="exponential",
        parameters={
            "amplitude_mm": float(b.rng.choice([-1.0, 1.0])) * 0.1,
            "tau_s": round(b.loguniform(60.0, 400.0), 2),
        },
        plates=b.everyone,
        axes=["z"],
    )
    return b.sized(e, "amplitude_mm", (0.0, b.sigma_z(e["plates"])))


def _camera(base, e, pos, trel):
    p = e["parameters"]
    pos[:, bench_plates(e), 2] += (float(p["amplitude_mm"]) * np.exp(-trel / float(p["tau_s"])))[:, None]


def _truth(base, e, p, out, t_tab, extras):
    """A warm-up is over after three time constants."""
    out["t_end"] = min(float(t_tab[-1]), float(t_tab[0]) + 3.0 * float(p["tau_s"]))


ENTRY = Entry(
    id="drift",
    record_kinds=("forced_harmonic", "multi_tone"),
    meaning="a camera warming up: every pixel reads a·exp(−t_rel/τ) farther",
    rank=3,
    level="range",
    params=(Param("amplitude_mm", "mm at t_rel = 0, signed"), Param("tau_s", "s")),
    inject=inject,
    check=positive("tau_s", "a time constant > 0 s"),
    from_diagnosis=from_diagnosis,
    example={"amplitude_mm": 1.5, "tau_s": 60.0},
    draw=draw,
    scored=lambda kind: {"amplitude_mm": True, "tau_s": True},
    bench=Bench(camera=_camera, truth=_truth),
    footprint=("a slow change of the mean",),
)
