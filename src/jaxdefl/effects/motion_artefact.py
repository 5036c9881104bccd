"""``motion_artefact``: a ToF camera takes the four correlation samples of a frame one after the
other, so a moving plate is read as the mean of its positions at the four taps: a gain loss and
a lag against the LDS (thesis 5.47-5.52). A sampling effect: the camera's reading of each frame
is the mean of the true positions at ``tap_spread_s`` × (0, ¼, ½, ¾) after its time, beyond
the camera's own sampling (the frame renderer's taps, the diagnosis' nominal lag where the tap
offsets are known: what the diagnosis measures is the spread beyond them)."""

from __future__ import annotations

import numpy as np

from ._entry import Bench, Entry, Param, Report, positive

TAPS = (0.0, 0.25, 0.5, 0.75)  # the four taps' offsets, fractions of the spread (evenly spread)


def inject(e, t_rel) -> np.ndarray:
    """(4,) s: the taps' instants after the frame's time."""
    return np.asarray(TAPS) * e.p("tap_spread_s")


def from_diagnosis(r: Report) -> tuple[dict, tuple[int, ...]]:
    """The tap spread as reported (a camera's: every plate)."""
    return {"tap_spread_s": r.p["tap_spread_s"]}, ()


def draw(b) -> dict:
    """The benchmark's taps: spread over 0.4-1 frame period, on every plate and axis (ToF only)."""
    if b.spec.sensor != "tof":
        raise ValueError("motion_artefact: only for ToF recordings (spec.sensor)")
    t_span = float(b.rng.uniform(0.4, 1.0)) / b.spec.frame_rate_hz
    e = dict(
        kind="sequential_taps", parameters={"tap_spread_s": t_span}, plates=b.everyone, axes=list(b.axes)
    )
    return e | {"id": ENTRY.id}


def _taps(base, e) -> list[float]:
    """The four taps evenly over ``tap_spread_s`` after the frame's time."""
    tap = float(e["parameters"]["tap_spread_s"])
    return [k * tap / 4 for k in range(4)]


ENTRY = Entry(
    id="motion_artefact",
    record_kinds=("forced_harmonic",),
    meaning="gain loss and lag of the camera against the LDS from its sequential four-phase sampling",
    rank=1,
    sensors=("tof",),  # only a four-phase (ToF) camera samples its taps in sequence
    structural=False,  # the four taps' sequence of a ToF camera
    needs_reference=True,
    level="sampling",
    params=(Param("tap_spread_s", "s, T: the taps at 0, T/4, T/2 and 3T/4 after the frame's time"),),
    inject=inject,
    check=positive("tap_spread_s", "a spread > 0 s"),
    from_diagnosis=from_diagnosis,
    example={"tap_spread_s": 0.05},
    draw=draw,
    scored=lambda kind: {"tap_spread_s": True},
    bench=Bench(taps=_taps),
)
