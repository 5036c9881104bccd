"""``motion_artefact``: a ToF camera takes the four correlation samples of a frame one after the
other, so a moving plate is read as the mean of four positions: a gain loss and a lag against
the LDS. Not injected by the simulator's registry (the concealed benchmark renders the four taps,
`jaxdefl.simulate.effects`)."""

from ._entry import Entry


def draw(b) -> dict:
    """The benchmark's taps: spread over 0.4-1 frame period, on every plate and axis (ToF only)."""
    if b.spec.sensor != "tof":
        raise ValueError("motion_artefact: only for ToF recordings (spec.sensor)")
    t_span = float(b.rng.uniform(0.4, 1.0)) / b.spec.frame_rate_hz
    e = dict(
        kind="sequential_taps", parameters={"tap_spread_s": t_span}, plates=b.everyone, axes=list(b.axes)
    )
    return e | {"id": ENTRY.id}


ENTRY = Entry(
    id="motion_artefact",
    record_kinds=("forced_harmonic",),
    meaning="gain loss and lag of the camera against the LDS from its sequential four-phase sampling",
    rank=1,
    sensors=("tof",),  # only a four-phase (ToF) camera samples its taps in sequence
    structural=False,  # the four taps' sequence of a ToF camera
    needs_reference=True,
    draw=draw,
    scored=lambda kind: {"tap_spread_s": True},
)
