"""The camera facts an extracted table carries beside it (``TRAJ.camera.json``).

`jaxdefl extract` reads a recording whose attributes name its camera (the simulator's ``sensor``,
``frame_rate_hz``, ``modulation_mhz``, ``tap_offsets``; a TUM folder's ``camera.json``) and writes
them beside the table, so `jaxdefl diagnose` knows the sensor kind of the table without
``--sensor`` or ``--config``: which effects that sensor can produce, and its modelled lag.
"""

from __future__ import annotations

import json
from pathlib import Path

from .._errors import InputError
from ..settings import SENSORS

__all__ = ["camera_facts", "camera_sidecar", "read_camera_sidecar"]


# What a camera model's attribute says of its sensor kind (`jaxdefl.settings.SENSORS`).
_SENSOR_OF_MODEL = {"sr4000": "tof", "kinect": "structured_light"}


def camera_sidecar(table: Path | str) -> Path:
    """The camera facts written beside an extracted table: ``TRAJ.camera.json``."""
    table = Path(table)
    return table.with_name(table.name.rsplit(".", 1)[0] + ".camera.json")


def camera_facts(attrs: dict) -> dict:
    """Sensor kind, frame rate, modulation and tap offsets of a recording's attributes (what
    `jaxdefl diagnose` would otherwise need from ``--sensor``/``--config``); {} when the
    attributes do not name the sensor."""
    model = str(attrs.get("sensor", "")).lower()
    sensor = _SENSOR_OF_MODEL.get(model, model if model in SENSORS else None)
    if sensor is None:
        return {}
    facts: dict = {"sensor": sensor}
    if attrs.get("frame_rate_hz"):
        facts["frame_rate_hz"] = float(attrs["frame_rate_hz"])
    if sensor == "tof":
        if attrs.get("modulation_mhz"):
            facts["modulation_mhz"] = float(attrs["modulation_mhz"])
        if attrs.get("tap_offsets") is not None:
            facts["tap_offsets"] = [float(v) for v in attrs["tap_offsets"]]
    return facts


def read_camera_sidecar(table: Path | str) -> dict:
    """The camera facts beside ``table`` ({} when there is no ``TRAJ.camera.json``)."""
    path = camera_sidecar(table)
    if not path.is_file():
        return {}
    try:
        raw = json.loads(path.read_text())
    except ValueError as err:
        raise InputError(f"{path}: not valid JSON ({err}); remove it or extract the table again") from None
    if not isinstance(raw, dict):
        raise InputError(f"{path}: expected a JSON object of camera facts, got {type(raw).__name__}")
    facts = camera_facts(raw)
    if raw.get("sensor") is not None and not facts:
        raise InputError(f"{path}: sensor {raw['sensor']!r} is not one of {', '.join(SENSORS)}")
    if "tap_offsets" in facts:
        facts["tap_offsets"] = tuple(facts["tap_offsets"])
    return facts
