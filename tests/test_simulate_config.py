"""Simulation config validation: one pytest.raises(match=...) per error message."""

from pathlib import Path

import pytest

from jaxdefl._errors import ConfigError, ParameterError
from jaxdefl.cli import main
from jaxdefl.simulate import config_from_dict, load_config, simulate_trajectories

CONFIGS = Path(__file__).parents[1] / "configs"


def _write(tmp_path, text):
    p = tmp_path / "sim.toml"
    p.write_text(text)
    return p


@pytest.mark.parametrize(
    "name", ["exp1", "exp2_tof_1hz", "exp2_tof_3hz", "exp2_kinect_1hz", "exp2_kinect_3hz"]
)
def test_shipped_configs_load(name):
    cfg = load_config(CONFIGS / f"{name}.toml")
    assert cfg.camera.frame_rate_hz > 0


def test_sessions_pick_table_values():
    day11 = load_config(CONFIGS / "exp2_tof_3hz.toml", session="day11")
    assert day11.recording.cycles_at_start == 880286
    assert day11.loading.amplitude_mm == 2.63 and day11.recording.segment == "day11"
    cam4 = load_config(CONFIGS / "exp1.toml", session="cam4_40fps_3hz")
    assert (cam4.camera.modulation_mhz, cam4.camera.frame_rate_hz) == (31.0, 40.0)


def test_unknown_top_level_key(tmp_path):
    p = _write(tmp_path, "[camra]\nsensor = 'sr4000'\n")
    with pytest.raises(ConfigError, match=r"sim.toml: unknown key 'camra'; expected one of"):
        load_config(p)


def test_unknown_section_key(tmp_path):
    p = _write(tmp_path, "[camera]\nframe_rate = 20\n")
    with pytest.raises(ConfigError, match=r"unknown key 'camera.frame_rate'; expected one of sensor"):
        load_config(p)


def test_unknown_session_key(tmp_path):
    p = _write(tmp_path, "[[session]]\nname = 'd1'\nloadin = { amplitude_mm = 2 }\n")
    with pytest.raises(ConfigError, match=r"unknown key 'session\[d1\].loadin'"):
        load_config(p)


def test_unknown_session_name():
    with pytest.raises(ConfigError, match=r"key 'recording.session': expected one of day1, day2"):
        load_config(CONFIGS / "exp2_tof_3hz.toml", session="day6")


def test_frame_rate_above_sr4000_maximum(tmp_path):
    p = _write(tmp_path, "[camera]\nsensor = 'sr4000'\nframe_rate_hz = 60\n")
    with pytest.raises(
        ConfigError, match=r"sim.toml: key 'camera.frame_rate_hz': expected <= 54 Hz for the SR4000.*got 60$"
    ):
        load_config(p)


def test_frame_rate_above_kinect_maximum():
    with pytest.raises(
        ConfigError, match=r"key 'camera.frame_rate_hz': expected <= 30 Hz for the Kinect.*got 31"
    ):
        config_from_dict({"camera": {"sensor": "kinect", "frame_rate_hz": 31}}, "k.toml")


def test_plate_outside_field_of_view(tmp_path):
    p = _write(tmp_path, "[camera]\nplates = [6, 7, 12]\n")
    with pytest.raises(
        ConfigError,
        match=r"key 'camera.plates': expected plates inside the 176x144 field of view, got plate 12",
    ):
        load_config(p)


def test_negative_duration_in_config(tmp_path):
    p = _write(tmp_path, "[recording]\nduration_s = -5\n")
    with pytest.raises(ConfigError, match=r"key 'recording.duration_s': expected a duration > 0 s, got -5.0"):
        load_config(p)


def test_negative_duration_argument():
    with pytest.raises(ParameterError, match=r"duration_s: expected a duration > 0 s, got -1"):
        simulate_trajectories(CONFIGS / "exp2_tof_3hz.toml", duration_s=-1)


def test_wrong_type():
    with pytest.raises(ConfigError, match=r"key 'loading.amplitude_mm': expected a number, got 'big'"):
        config_from_dict({"loading": {"amplitude_mm": "big"}})


def test_unknown_sensor():
    with pytest.raises(
        ConfigError, match=r"key 'camera.sensor': expected one of sr4000, kinect, got 'lidar'"
    ):
        config_from_dict({"camera": {"sensor": "lidar"}})


def test_defective_lds_must_be_an_lds_plate():
    with pytest.raises(ConfigError, match=r"key 'lds.defective_plate': expected 0 or one of lds.plates"):
        config_from_dict({"lds": {"plates": [3, 5], "defective_plate": 9}})


def test_missing_file(tmp_path):
    with pytest.raises(ConfigError, match=r"nope.toml: file not found"):
        load_config(tmp_path / "nope.toml")


def test_cli_config_error_exit_code_2(tmp_path, capsys):
    p = _write(tmp_path, "[camera]\nframe_rate_hz = 60\n")
    assert main(["simulate", str(p), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "expected <= 54 Hz" in err and len(err.strip().splitlines()) == 1


def test_plates_below_the_floor_are_impossible():
    with pytest.raises(ConfigError, match=r"key 'plates.depth_below_top_mm': expected a depth between"):
        config_from_dict({"plates": {"depth_below_top_mm": 900.0}})


def test_noise_calibration_keys():
    with pytest.raises(ConfigError, match=r"key 'camera.calibration': expected one of cam2, cam3, cam4"):
        config_from_dict({"camera": {"calibration": "cam9"}})
    with pytest.raises(ConfigError, match=r"key 'camera.centroid_residual_mm': expected a value >= 0"):
        config_from_dict({"camera": {"centroid_residual_mm": -0.5}})
    with pytest.raises(ConfigError, match=r"key 'camera.correlated_spatial_fraction': expected a fraction"):
        config_from_dict({"camera": {"correlated_spatial_fraction": 1.5}})
    day10 = load_config(CONFIGS / "exp2_tof_3hz.toml", "day10")
    assert day10.camera.centroid_residual_mm == 0.57  # Table 6.17
