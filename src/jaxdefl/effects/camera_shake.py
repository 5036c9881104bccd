"""``camera_shake``: the camera moves along its optical axis, so every pixel (plates, floor
targets, beam top) reads the same displacement: a random low-pass motion of RMS ``rms_mm`` and
corner ``corner_hz`` (seeded by the simulation's seed) and/or a sway ``amplitude_mm``,
``freq_hz``, ``phase_rad``."""

from __future__ import annotations

import math

import numpy as np

from ._entry import PHASE, Bench, Entry, Param, Report, bench_plates, spec_values

# the camera's random low-pass motion: a sum of sinusoids (spectral representation of a
# first-order low-pass process, S(f) ∝ 1/(1 + (f/f_c)²) on [f_c/20, 10 f_c]), so that its value at
# a time does not depend on how the frames are chunked
_SHAKE_LINES = 64


def displacement(e, t_rel: np.ndarray, seed: int) -> np.ndarray:
    """(frame,) mm the camera moved along its optical axis at ``t_rel``: the random low-pass
    motion of RMS ``rms_mm`` and corner ``corner_hz`` (deterministic for a seed) plus the sway
    ``amplitude_mm`` cos(2π ``freq_hz`` t_rel + ``phase_rad``)."""
    t_rel = np.asarray(t_rel, np.float64)
    out = e.p("amplitude_mm") * np.cos(2 * math.pi * e.p("freq_hz") * t_rel + e.p("phase_rad"))
    rms, fc = e.p("rms_mm"), e.p("corner_hz")
    if rms > 0 and fc > 0:
        rng = np.random.default_rng([int(seed) & 0xFFFFFFFF, 0x5A4B])
        edges = np.geomspace(fc / 20.0, 10.0 * fc, _SHAKE_LINES + 1)
        f = edges[:-1] * np.exp(rng.uniform(0, 1, _SHAKE_LINES) * np.log(edges[1:] / edges[:-1]))
        power = np.diff(np.arctan(edges / fc))  # ∫ S df over each band
        amp = np.sqrt(2.0 * power / power.sum()) * rng.rayleigh(1.0 / math.sqrt(2.0), _SHAKE_LINES)
        amp *= rms / math.sqrt(0.5 * float(np.sum(amp**2)))  # the realised RMS is rms_mm
        ph = rng.uniform(0, 2 * math.pi, _SHAKE_LINES)
        out = out + np.cos(2 * math.pi * t_rel[:, None] * f[None, :] + ph[None, :]) @ amp
    return out


def inject(e, trel, n_plates, seed):
    """Every pixel: the camera moves, so the plates and the static scene move together."""
    return np.arange(0, n_plates + 1), displacement(e, trel, seed)[:, None]


def check(e, bad):
    for name in ("rms_mm", "corner_hz", "freq_hz"):
        if not e.p(name) >= 0:
            raise bad(name, "a value >= 0")
    if e.p("rms_mm") > 0 and not e.p("corner_hz") > 0:
        raise bad("corner_hz", "a corner frequency > 0 Hz for a random motion (rms_mm > 0)")


def from_diagnosis(r: Report) -> tuple[dict, tuple[int, ...]]:
    """The camera moved: the whole image, a random motion alike in law (RMS and corner)."""
    return {"rms_mm": r.p["rms_mm"], "corner_hz": r.p["corner_hz"]}, ()


def draw(b) -> dict:
    """The benchmark's shake: a random low-pass motion of corner 3-30 mHz, every plate, at most σ."""
    e = dict(
        kind="low_pass",
        parameters={"rms_mm": 0.1, "corner_hz": round(b.loguniform(0.003, 0.03), 5)},
        plates=b.everyone,
        axes=["z"],
    )
    return b.sized(e, "rms_mm", (0.0, b.sigma_z(e["plates"])))


def _camera(base, e, pos, trel):
    """The same displacement on every listed axis of its plates (`displacement`)."""
    shake = displacement(spec_values(ENTRY, e["parameters"]), trel, base.seed)
    for a in e["axes"]:
        pos[:, bench_plates(e), "xyz".index(a)] += shake[:, None]


ENTRY = Entry(
    id="camera_shake",
    record_kinds=("forced_harmonic",),
    meaning="the camera moves along its optical axis: every pixel reads the same displacement",
    rank=14,
    sensors=("tof", "structured_light", "camera_tracking"),  # a sensor that sees every plate at once
    structural=False,  # the camera moves, not the beam
    level="range",
    params=(
        Param("rms_mm", "mm (random low-pass motion)", 0.0),
        Param("corner_hz", "Hz (its corner frequency)", 0.0),
        Param("amplitude_mm", "mm (sway)", 0.0),
        Param("freq_hz", "Hz (sway)", 0.0),
        PHASE,
    ),
    inject=inject,
    check=check,
    from_diagnosis=from_diagnosis,
    example={"rms_mm": 0.5, "corner_hz": 0.02},
    draw=draw,
    scored=lambda kind: {"rms_mm": False},
    bench=Bench(camera=_camera),
    footprint=("a slow change of the mean",),
)
