"""``quantization``: depth read in steps (a structured-light camera's disparity lattice, a
logger's ADC). Not injected by the simulator's registry (the concealed benchmark rounds its
readings, `jaxdefl.simulate.effects`)."""

from ._entry import Entry

# the benchmark's pixels averaged per reading (log-uniform) and their noise before rounding σ_d / q
PIXELS_RANGE = (20.0, 200.0)
DITHER_RATIO_RANGE = (0.12, 0.25)


def draw(b) -> dict:
    """The benchmark's lattice (structured light only): P pixels of noise σ_d before the rounding,
    the step the smallest that reaches the target (`Draw.quantization_step`), a random offset."""
    if b.spec.sensor != "structured_light":
        raise ValueError("quantization: only for structured-light recordings (spec.sensor)")
    rng = b.rng
    pixels = int(round(b.loguniform(*PIXELS_RANGE)))
    ratio = float(rng.uniform(*DITHER_RATIO_RANGE))
    e = dict(
        id=ENTRY.id,
        kind="depth_steps",
        parameters={"step_mm": 1.0, "offset_mm": 0.0, "pixels": pixels, "dither_mm": ratio},
        plates=b.everyone,
        axes=["z"],
    )
    q = b.quantization_step(e, ratio)
    e["parameters"] |= {"step_mm": q, "dither_mm": ratio * q, "offset_mm": float(rng.uniform(0, q))}
    return e


ENTRY = Entry(
    id="quantization",
    meaning="depth measured in steps (structured-light disparity quantisation, a logger's ADC)",
    rank=11,
    # a disparity or a converter's lattice; a ToF camera's phase is not read in steps
    sensors=("structured_light", "lds", "accelerometer", "camera_tracking", "logger"),
    structural=False,
    draw=draw,
    scored=lambda kind: {"step_mm": True},
)
