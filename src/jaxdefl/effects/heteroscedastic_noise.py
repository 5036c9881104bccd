"""``heteroscedastic_noise``: a noise level that depends on the motion's phase or changes over the
record. A noise structure, not a mean: the simulator's registry does not inject it (the concealed
benchmark scales its noise, `jaxdefl.simulate.effects`)."""

from ._entry import Entry

ENTRY = Entry(
    id="heteroscedastic_noise",
    meaning="noise level that depends on the motion's phase or changes over the record",
    rank=10,
    structural=False,  # a noise structure: the measurement's
)
