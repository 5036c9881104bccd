"""``quantization``: depth read in steps (a structured-light camera's disparity lattice, a
logger's ADC). Not injected by the simulator's registry (the concealed benchmark rounds its
readings, `jaxdefl.simulate.effects`)."""

from ._entry import Entry

ENTRY = Entry(
    id="quantization",
    meaning="depth measured in steps (structured-light disparity quantisation, a logger's ADC)",
    rank=11,
    # a disparity or a converter's lattice; a ToF camera's phase is not read in steps
    sensors=("structured_light", "lds", "accelerometer", "camera_tracking", "logger"),
    structural=False,
)
