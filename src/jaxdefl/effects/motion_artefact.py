"""``motion_artefact``: a ToF camera takes the four correlation samples of a frame one after the
other, so a moving plate is read as the mean of four positions: a gain loss and a lag against
the LDS. Not injected by the simulator's registry (the concealed benchmark renders the four taps,
`jaxdefl.simulate.effects`)."""

from ._entry import Entry

ENTRY = Entry(
    id="motion_artefact",
    meaning="gain loss and lag of the camera against the LDS from its sequential four-phase sampling",
    rank=1,
    sensors=("tof",),  # only a four-phase (ToF) camera samples its taps in sequence
    structural=False,  # the four taps' sequence of a ToF camera
    needs_reference=True,
)
