"""``extra_periodic``: a second motion of the beam in its deflection shape at a frequency
unrelated to the loading (pump, mount, floor)."""

from __future__ import annotations

import math

import numpy as np

from ._entry import PHASE, Bench, Entry, Motion, Param, Report, bench_plates, positive


def inject(e, m: Motion):
    f, a, psi, tau = e.p("freq_hz"), e.p("amplitude_mm"), e.p("phase_rad"), m.tau
    m.extra.append(lambda theta: a * np.cos(2 * math.pi * f * tau + psi))


def from_diagnosis(r: Report) -> tuple[dict, tuple[int, ...]]:
    """The line's frequency and mid-span amplitude (its phase is refitted by the
    reconciliation); one motion of the beam (no plates)."""
    return {"freq_hz": r.p["freq_hz"], "amplitude_mm": r.p["amplitude_mm"]}, ()


def draw(b) -> dict:
    """The benchmark's vibration: 0.3-8 Hz away from the load's harmonics and their aliases, on
    every plate (z, sometimes x) with per-plate factors 0.8-1.2 about their median."""
    rng, n_pl = b.rng, b.n_plates
    axes = ["z", "x"] if rng.random() < 0.3 else ["z"]
    fac = rng.uniform(0.8, 1.2, n_pl)
    fac = fac / np.median(fac)
    e = dict(
        kind="vibration",
        parameters={"freq_hz": b.extra_frequency(), "amplitude_mm": 0.1, "phase_rad": b.psi},
        plates=b.everyone,
        axes=axes,
        plate_factors={"z": fac.round(4).tolist()}
        | ({"x": (0.5 * fac).round(4).tolist()} if "x" in axes else {}),
    )
    return b.sized(e, "amplitude_mm")


def plate_amplitudes(e) -> dict[str, np.ndarray]:
    """Per-plate amplitudes (mm) of a drawn line by axis: ``amplitude_mm`` times the plate
    factors (``plate_factors`` {axis: [per plate]}; default 1 on z); ``amplitude_mm`` is the
    median over z."""
    a = float(e["parameters"]["amplitude_mm"])
    factors = e.get("plate_factors") or {"z": [1.0] * len(e["plates"])}
    return {ax: a * np.asarray(f, float) for ax, f in factors.items()}


def _camera(base, e, pos, trel):
    p = e["parameters"]
    c = np.cos(2 * math.pi * float(p["freq_hz"]) * trel + float(p["phase_rad"]))
    for a, amps in plate_amplitudes(e).items():
        pos[:, bench_plates(e), "xyz".index(a)] += c[:, None] * amps[None, :]


def _truth(base, e, p, out, t_tab, extras):
    """The realised amplitude per plate and axis; ``amplitude_mm`` their median over z."""
    amps = plate_amplitudes(e)
    out["plate_amplitudes_mm"] = {k: [round(float(v), 6) for v in a] for k, a in amps.items()}
    p["amplitude_mm"] = float(np.median(amps["z"]))


ENTRY = Entry(
    id="extra_periodic",
    record_kinds=("forced_harmonic",),
    meaning="a second motion of the beam in its deflection shape",
    rank=8,
    level="motion",
    params=(Param("freq_hz", "Hz"), Param("amplitude_mm", "mm at mid-span"), PHASE),
    inject=inject,
    check=positive("freq_hz", "a frequency > 0 Hz"),
    from_diagnosis=from_diagnosis,
    locator=("freq_hz", 1e-3),
    example={"freq_hz": 4.2, "amplitude_mm": 0.3, "phase_rad": 0.4},
    draw=draw,
    scored=lambda kind: {"freq_hz": True, "amplitude_mm": False},
    bench=Bench(camera=_camera, truth=_truth),
)
