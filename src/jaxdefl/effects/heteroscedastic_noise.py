"""``heteroscedastic_noise``: a noise level that depends on the motion's phase or changes over the
record. A noise structure, not a mean: the simulator's registry does not inject it (the concealed
benchmark scales its noise, `jaxdefl.simulate.effects`)."""

from ._entry import Entry

MODULATION_RANGE = (0.15, 0.4)  # the benchmark's modulation m


def draw(b) -> dict:
    """The benchmark's noise level: with the motion's phase or over the record, m 0.15-0.4 raised
    (up to the range's top) until the likelihood signal is enough."""
    rng = b.rng
    plates = b.everyone if rng.random() < 0.5 else b.adjacent(b.n_plates, int(rng.integers(1, 4)))
    kind = str(rng.choice(["phase", "time"]))
    e = dict(
        id=ENTRY.id,
        kind=kind,
        parameters={"modulation": round(float(rng.uniform(*MODULATION_RANGE)), 4)}
        | ({"phase_rad": b.psi} if kind == "phase" else {}),
        plates=plates,
        axes=["z"],
    )
    for _ in range(8):  # raise m (up to the range's top) until the signal is enough
        _, s = b.measure(e)
        if s >= b.signal_min or e["parameters"]["modulation"] >= MODULATION_RANGE[1]:
            break
        e["parameters"]["modulation"] = min(MODULATION_RANGE[1], e["parameters"]["modulation"] * 1.2)
    return e


ENTRY = Entry(
    id="heteroscedastic_noise",
    record_kinds=("forced_harmonic",),
    meaning="noise level that depends on the motion's phase or changes over the record",
    rank=10,
    structural=False,  # a noise structure: the measurement's
    draw=draw,
    # growing noise has a sign; with the motion's phase, ψ holds the sign
    scored=lambda kind: {"modulation": kind == "time"},
)
