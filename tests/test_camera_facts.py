"""The camera facts an extracted table carries (``TRAJ.camera.json``) and what diagnose takes
from them: the sensor kind comes from the recording when no flag or config says it."""

import json

import pytest
import zarr

from jaxdefl._errors import InputError
from jaxdefl.cli import main
from jaxdefl.io.camera import camera_facts, camera_sidecar, read_camera_sidecar
from jaxdefl.pipeline import _with_sensor_facts
from jaxdefl.settings import SENSORS, DiagnoseSettings


def test_camera_models_map_to_sensor_kinds():
    attrs = {"sensor": "sr4000", "frame_rate_hz": 20, "modulation_mhz": 29, "tap_offsets": [0, 0.5]}
    tof = camera_facts(attrs)
    assert tof == {"sensor": "tof", "frame_rate_hz": 20.0, "modulation_mhz": 29.0, "tap_offsets": [0.0, 0.5]}
    # a structured-light camera has no modulation or taps, whatever its attributes say
    assert camera_facts({"sensor": "Kinect", "frame_rate_hz": 30, "modulation_mhz": 29}) == {
        "sensor": "structured_light",
        "frame_rate_hz": 30.0,
    }
    for kind in SENSORS:  # the vocabulary's own names pass through
        assert camera_facts({"sensor": kind})["sensor"] == kind
    assert camera_facts({"sensor": "lidar"}) == {} and camera_facts({}) == {}


def test_a_bad_sidecar_is_one_line_naming_it(tmp_path):
    table = tmp_path / "traj.csv"
    assert camera_sidecar(table) == tmp_path / "traj.camera.json"
    assert read_camera_sidecar(table) == {}  # none beside it
    camera_sidecar(table).write_text("{not json")
    with pytest.raises(InputError, match=r"traj\.camera\.json: not valid JSON"):
        read_camera_sidecar(table)
    camera_sidecar(table).write_text(json.dumps({"sensor": "lidar"}))
    with pytest.raises(InputError, match=r"traj\.camera\.json: sensor 'lidar' is not one of tof, "):
        read_camera_sidecar(table)


@pytest.fixture(scope="module")
def extracted(tmp_path_factory):
    d = tmp_path_factory.mktemp("facts")
    args = ["simulate", "exp2_tof_3hz", "--session", "day1", "--duration", "6", "--out", str(d / "sim")]
    assert main(args) == 0
    rec = d / "sim" / "recording.zarr"
    assert main(["extract", str(rec), "--out", str(d / "traj.csv"), "--device", "cpu"]) == 0
    return d, dict(zarr.open_group(str(rec), mode="r").attrs)


def test_extract_writes_the_recordings_camera_beside_the_table(extracted):
    d, attrs = extracted
    facts = json.loads((d / "traj.camera.json").read_text())
    assert facts["sensor"] == "tof" and attrs["sensor"] == "sr4000"
    assert facts["frame_rate_hz"] == attrs["frame_rate_hz"]
    assert facts["modulation_mhz"] == attrs["modulation_mhz"]
    assert facts["tap_offsets"] == list(attrs["tap_offsets"])


def test_diagnose_takes_the_sensor_from_the_recording_unless_told(extracted):
    d, attrs = extracted
    traj = d / "traj.csv"
    s, note = _with_sensor_facts(DiagnoseSettings(), None, traj)
    assert (s.sensor, s.frame_rate_hz) == ("tof", attrs["frame_rate_hz"])
    assert s.modulation_mhz == attrs["modulation_mhz"]
    assert s.tap_offsets == tuple(attrs["tap_offsets"])
    assert note == "sensor: tof, from the recording's attributes (traj.camera.json)"
    # a flag wins, and the disagreement is said
    s, note = _with_sensor_facts(DiagnoseSettings(sensor="structured_light"), None, traj)
    assert s.sensor == "structured_light" and note.endswith("the recording's attributes say tof")
    assert s.frame_rate_hz == attrs["frame_rate_hz"]  # what the flags leave open still comes from it
    # a table with no sidecar: nothing is assumed
    bare = d / "bare.csv"
    bare.write_bytes(traj.read_bytes())
    s, note = _with_sensor_facts(DiagnoseSettings(), None, bare)
    assert s.sensor is None and note is None
