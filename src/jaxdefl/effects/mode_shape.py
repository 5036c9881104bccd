"""``mode_shape``: the beam's n-th bending mode of a simply supported span,
a sin(nπ x/L) cos(2π f t_rel + ψ) at a plate at x (LDS, trajectories, the plates' pixels in
frames)."""

from __future__ import annotations

import math

import numpy as np

from ._entry import PHASE, Bench, Entry, Motion, Param, Report, bench_plates, positive


def inject(e, m: Motion):
    """The n-th bending mode of a simply supported span: shape sin(nπ x/L), antisymmetric for
    even n (zero at mid-span, so the LDS at mid-span and the load's own shape do not see n = 2)."""
    n, f, a, psi = int(e.p("mode")), e.p("freq_hz"), e.p("amplitude_mm"), e.p("phase_rad")
    m.modes.append(
        (lambda xi: np.sin(n * math.pi * np.asarray(xi, float)), a * np.cos(2 * math.pi * f * m.tau + psi))
    )


def check(e, bad):
    if not (e.p("mode") >= 1 and e.p("mode") == round(e.p("mode"))):
        raise bad("mode", "an integer >= 1")
    positive("freq_hz", "a frequency > 0 Hz")(e, bad)


def from_diagnosis(r: Report) -> tuple[dict, tuple[int, ...]]:
    """The diagnosis fits the injection's parameters; one motion of the beam (no plates)."""
    return {k: r.p[k] for k in ("mode", "freq_hz", "amplitude_mm", "phase_rad")}, ()


def draw(b) -> dict:
    """The benchmark's mode: n = 2 (70 %) or 3 at 0.3-8 Hz away from the load's harmonics."""
    e = dict(
        kind=f"mode_{int(b.rng.choice([2, 3], p=[0.7, 0.3]))}",
        parameters={"freq_hz": b.extra_frequency(), "amplitude_mm": 0.1, "phase_rad": b.psi},
        plates=b.everyone,
        axes=["z"],
    )
    e["parameters"]["mode"] = int(e["kind"][-1])
    return b.sized(e, "amplitude_mm")


def _camera(base, e, pos, trel):
    """z_p += a sin(nπ x_p/L) cos(2π f t_rel + ψ), x_p the plate's place on the span L (after
    the other additive terms)."""
    p = e["parameters"]
    idx = bench_plates(e)
    xi = np.asarray(base.cfg.plate_x_mm())[idx] / base.cfg.beam.span_mm
    arg = 2 * math.pi * float(p["freq_hz"]) * trel + float(p["phase_rad"])
    q = float(p["amplitude_mm"]) * np.cos(arg)
    pos[:, idx, 2] += q[:, None] * np.sin(int(p["mode"]) * math.pi * xi)[None, :]


ENTRY = Entry(
    id="mode_shape",
    record_kinds=("forced_harmonic",),
    meaning="the beam's n-th bending mode a sin(nπ x/L) cos(2π f t + ψ)",
    rank=12,
    level="motion",
    params=(Param("mode", "n"), Param("freq_hz", "Hz"), Param("amplitude_mm", "mm at the antinode"), PHASE),
    inject=inject,
    check=check,
    from_diagnosis=from_diagnosis,
    locator=("mode", 1.0),
    example={"mode": 2, "freq_hz": 5.3, "amplitude_mm": 0.5, "phase_rad": 0.7},
    draw=draw,
    scored=lambda kind: {"mode": True, "freq_hz": True, "amplitude_mm": False},
    bench=Bench(stage=1, camera=_camera),
)
