"""``debond``: a plate no longer following the beam fully from ``t_s``: its motion about rest
scales by 1 + ``amplitude_change`` (trajectories). Not named by the diagnosis."""

from __future__ import annotations

import numpy as np

from ._entry import WHEN, Entry, Param, active, all_of, check_when, relative


def inject(e, trel, motion, dx, dy, rest):
    f = np.where(active(e, trel), 1.0 + e.p("amplitude_change"), 1.0)
    j = e.p("plate") - 1
    motion[:, j] = f * (motion[:, j] - rest[j]) + rest[j]
    dx[:, j] *= f
    dy[:, j] *= f


ENTRY = Entry(
    id="debond",
    meaning="a plate no longer following the beam fully: its motion about rest scales",
    rank=16,
    sensors=("tof", "structured_light", "lds", "camera_tracking"),  # the sensors that read a plate
    structural=False,  # the plate's bond to the beam, not the beam
    detectable=False,
    level="plate",
    params=(*WHEN, Param("plate", "plate number", plate=True), Param("amplitude_change", "relative", -0.5)),
    inject=inject,
    check=all_of(check_when, relative("amplitude_change")),
    example={"t_s": 10.0, "plate": 1, "amplitude_change": -0.5},
)
