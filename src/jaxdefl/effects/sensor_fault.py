"""``sensor_fault``: the live camera's centroids of one plate lost, jumping by ``size`` mm in z,
or noisier by a factor ``size`` (`jaxdefl.simulate.live`). Not named by the diagnosis."""

from __future__ import annotations

import numpy as np

from ._entry import WHEN, Entry, Param, Reading, active, check_when


def inject(e, r: Reading) -> None:
    on = active(e, r.t_rel)
    for j in r.columns((e.p("plate"),)):
        if e.p("fault") == "noise":
            r.noise[on, j, :] *= e.p("size")
        elif e.p("fault") == "jump":
            r.xyz[on, j, 2] += e.p("size")
        else:
            r.xyz[on, j, :] = np.nan


def resolve(p: dict, bad) -> dict:
    p.setdefault("size", {"lost": 0.0, "jump": 1.0, "noise": 3.0}.get(p.get("fault"), 0.0))
    return p


def check(e, bad):
    check_when(e, bad)
    if e.p("fault") == "noise" and e.p("size") < 0:
        raise bad("size", "a noise factor >= 0")


ENTRY = Entry(
    id="sensor_fault",
    meaning="a plate's centroids lost, jumping by size mm in z, or noisier by a factor size",
    rank=17,
    sensors=("tof", "structured_light", "camera_tracking"),  # a live camera's centroids
    structural=False,  # the measurement's
    detectable=False,
    level="measurement",
    params=(
        *WHEN,
        Param("plate", "plate number", plate=True),
        Param("fault", "kind", choices=("lost", "jump", "noise")),
        Param("size", "mm or factor"),
    ),
    inject=inject,
    check=check,
    resolve=resolve,
    example={"t_s": 10.0, "plate": 1, "fault": "jump"},
)
