"""Several cameras at once: [[camera]] tables, turned cameras, own clocks, one beam."""

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy.spatial.transform import Rotation

from jaxdefl._errors import ConfigError
from jaxdefl.cli import main
from jaxdefl.simulate import config_from_dict, load_config, measured_centroids, render_frames
from jaxdefl.simulate.centroids import plate_pixel_masks
from jaxdefl.simulate.lds import truth_table
from jaxdefl.simulate.scene import camera_rotation

CONFIGS = Path(__file__).parents[1] / "configs"


def _two(**over):
    cams = [
        dict(name="a", x_mm=950.0, roll_deg=2.0, pitch_deg=-1.5, yaw_deg=1.0, plates=[1, 2, 7]),
        dict(name="b", x_mm=2450.0, modulation_mhz=31.0, clock_offset_ms=-20.0, clock_drift_ppm=50.0),
    ]
    for c in cams:
        c["fov_deg"] = [69.0, 56.0]  # the ethernet SR4000s of Experiment I (Table 4.1)
    raw = {"camera": cams, "recording": {"duration_s": 2.0, "chunk_frames": 16}, "lds": {"plates": [7]}}
    raw.update(over)
    return raw


def test_camera_tables_parse_with_sensor_defaults_and_round_trip():
    cfg = config_from_dict(_two())
    assert cfg.camera_names == ("a", "b") and cfg.camera.name == "a"
    assert cfg.cameras[1].width == 176 and cfg.cameras[1].modulation_mhz == 31.0
    assert config_from_dict(cfg.to_dict()) == cfg
    one = cfg.for_camera("b")
    assert one.camera == cfg.cameras[1] and one.cameras == ()


def test_single_camera_table_is_unchanged():
    cfg = load_config(CONFIGS / "exp1.toml", session="cam3_20fps_1hz")
    assert cfg.cameras == () and cfg.camera_names == ("cam3",) and cfg.for_camera("cam3") is cfg


def test_rotation_matches_scipy_intrinsic_zyx():
    cfg = config_from_dict(_two())
    ours = camera_rotation(cfg.cameras[0])
    ref = Rotation.from_euler("ZYX", [1.0, -1.5, 2.0], degrees=True).as_matrix()
    np.testing.assert_allclose(ours, ref, atol=1e-12)
    assert camera_rotation(cfg.cameras[1]) is None


@pytest.mark.parametrize(
    "over, match",
    [
        (
            {"camera": [{"name": "a"}, {"name": "a"}]},
            r"key 'camera\[2\].name': expected a unique name",
        ),
        (
            {"camera": [{"name": "a"}, {"sensor": "sr4000"}]},
            r"key 'camera\[2\].name': expected a camera name",
        ),
        (
            {"camera": [{"name": "a"}, {"name": "b", "modulation_mhz": 90.0}]},
            r"key 'camera\[2\].modulation_mhz': expected a modulation frequency",
        ),
        (
            {"camera": [{"name": "a", "pitch_deg": 35.0}]},
            r"key 'camera\[1\].pitch_deg': expected an angle within \+-20 deg",
        ),
        (
            {"camera": [{"name": "a", "x_mm": 950.0, "plates": [13]}]},
            r"key 'camera\[1\].plates': expected plates inside",
        ),
        (
            {"effect": [{"id": "warmup_drift", "camera": "c", "size_mm": 1.0, "tau_s": 5.0}]},
            r"key 'effect\[1\].camera': expected one of the cameras a, b",
        ),
        (
            {"session": [{"name": "s1"}]},
            r"key 'camera': expected one \[camera\] table with \[\[session\]\] entries",
        ),
    ],
)
def test_bad_camera_tables(over, match):
    with pytest.raises(ConfigError, match=match):
        config_from_dict(_two(**over))


def test_a_turned_camera_renders_what_its_truth_says():
    """The reference extraction of a turned camera's frames recovers its camera-frame truth."""
    raw = _two()
    raw["camera"] = [dict(raw["camera"][0], noise_scale=0.2, dropout_prob=0.0)]
    cfg = config_from_dict(raw).for_camera("a")
    t, frames, amp, _ = render_frames(cfg, duration_s=1.0, seed=3)
    # plates three pixels wide: erode by a third of a pixel to keep an interior when turned
    masks = plate_pixel_masks(cfg, erode_px=0.3)
    got = measured_centroids(cfg, t, frames, masks=masks, amplitude=amp)
    got = got.groupby("plate")[["x", "y", "z"]].mean()
    assert set(got.index) >= set(range(1, 8))
    got = got.loc[1:7]  # the plates wholly in view (exp1's Cam 3)
    true = truth_table(cfg, t).groupby("plate")[["x", "y", "z"]].mean().loc[got.index]
    # nadir and turned alike: the centroid follows the plate to well under a pixel (~15 mm)
    np.testing.assert_allclose(got["z"], true["z"], atol=1.0)
    np.testing.assert_allclose(got[["x", "y"]], true[["x", "y"]], atol=4.0)


def test_cli_writes_a_recording_per_camera_and_consistent_truths(tmp_path):
    toml = tmp_path / "two.toml"
    toml.write_text(
        """
[recording]
duration_s = 1.5
chunk_frames = 8
[lds]
plates = [7]
[[camera]]
name = "a"
fov_deg = [69.0, 56.0]
x_mm = 950.0
roll_deg = 2.0
pitch_deg = -1.5
yaw_deg = 1.0
clock_offset_ms = 12.0
clock_drift_ppm = 400.0
[[camera]]
name = "b"
fov_deg = [69.0, 56.0]
x_mm = 2450.0
yaw_deg = -2.5
clock_offset_ms = -35.0
"""
    )
    out = tmp_path / "out"
    assert main(["simulate", str(toml), "--out", str(out)]) == 0
    for name in ("a", "b"):
        assert (out / f"{name}.zarr").is_dir()
    poses = {p["camera"]: p for p in json.loads((out / "cameras.json").read_text())}
    beam = pd.read_csv(out / "truth.csv")
    t0 = load_config(toml).t0_s
    for name in ("a", "b"):
        cam = pd.read_csv(out / f"{name}_truth.csv")
        bt = beam[beam["camera"] == name]
        assert len(cam) == len(bt)
        rot, origin = np.array(poses[name]["rotation"]), np.array(poses[name]["origin_mm"])
        # beam = R cam + C, row by row
        np.testing.assert_allclose(
            cam[["x", "y", "z"]].to_numpy() @ rot.T + origin, bt[["x", "y", "z"]], atol=1e-5
        )
        # the camera's stamps run on its own clock
        off, ppm = poses[name]["clock_offset_ms"], poses[name]["clock_drift_ppm"]
        want = t0 + off * 1e-3 + (1 + ppm * 1e-6) * (bt["t"].to_numpy() - t0)
        np.testing.assert_allclose(cam["t"].to_numpy(), want, atol=2e-6)
    assert not np.allclose(poses["a"]["rotation"], np.eye(3))


def test_effect_scoped_to_one_camera_reaches_only_its_frames():
    raw = _two(effect=[{"id": "level_jump", "camera": "b", "t_jump_s": 0.0, "size_mm": 5.0}])
    cfg = config_from_dict(raw)
    assert [e.id for e in cfg.for_camera("b").effects] == ["level_jump"]
    assert cfg.for_camera("a").effects == ()
    assert config_from_dict(cfg.to_dict()) == cfg


def test_exp1_two_cameras_config_loads():
    cfg = load_config(CONFIGS / "exp1_two_cameras.toml")
    assert cfg.camera_names == ("cam3", "cam4")
    assert 7 in cfg.cameras[0].plates and 7 in cfg.cameras[1].plates
    assert {c.modulation_mhz for c in cfg.cameras} == {29.0, 31.0}


def test_live_simulation_takes_one_camera(tmp_path, capsys):
    cfg = str(CONFIGS / "exp1_two_cameras.toml")
    assert main(["simulate", cfg, "--out", str(tmp_path / "o"), "--live", "--duration", "1"]) == 2
    assert "--live simulates one camera; got 2 [[camera]] tables" in capsys.readouterr().err
