"""Command settings: frozen, validated whole before any input is read, errors in parameter names
for a library caller and in flags on the command line.

For every command a bad flag value fails with one line naming the flag even when the input does
not exist (so the error cannot have come from reading it)."""

from __future__ import annotations

import dataclasses

import pytest

from jaxdefl import ConfigError
from jaxdefl._errors import ParameterError
from jaxdefl.cli import main
from jaxdefl.settings import (
    DIAGNOSE_FLAGS,
    EXTRACT_FLAGS,
    FIT_FLAGS,
    MONITOR_FLAGS,
    RECONCILE_FLAGS,
    RUN_FLAGS,
    SIMULATE_FLAGS,
    DiagnoseSettings,
    ExtractSettings,
    FitSettings,
    MonitorSettings,
    ReconcileSettings,
    RunSettings,
    SimulateSettings,
)


@pytest.mark.parametrize(
    "kw, message, flags",
    [
        (dict(window_s=-1.0), "window_s: expected a positive length in s, got -1", "--window"),
        (dict(window_s=float("nan")), "window_s: expected a finite number, got nan", "--window"),
        (dict(step_s=3.0), "step_s: needs window_s", "--step: needs --window"),
        (dict(fmin_hz=2.0, fmax_hz=1.0), "fmin_hz/fmax_hz: expected fmin < fmax, got 2 and 1",
         "--fmin/--fmax"),
        (dict(oversampling=0.5), "oversampling: expected a factor >= 1, got 0.5", "--oversampling"),
        (dict(fap_max=2.0), "fap_max: expected a probability in (0, 1], got 2", "--fap-max"),
        (dict(posterior=-3), "posterior: expected a number of windows >= 0, got -3", "--posterior"),
        (dict(posterior_noise="{pink}"), "posterior_noise: expected ar1 or white, got '{pink}'",
         "--posterior-noise"),
        (dict(axes="z,q"), "axes: expected a comma list of z, x, y; got 'z,q'", "--axes"),
        (dict(harmonics=2, posterior=0),
         "posterior: checks the σ's of the default model only; drop it, or drop model/harmonics/lines",
         "--posterior: checks the σ's of the default model only; drop it, or drop "
         "--model/--harmonics/--lines"),
    ],
)  # fmt: skip
def test_fit_settings_name_the_parameter(kw, message, flags):
    """A library caller reads parameter names; the command line reads its flags."""
    with pytest.raises(ParameterError) as err:
        FitSettings(**kw)
    assert str(err.value) == message
    flagged = str(err.value.renamed(FIT_FLAGS))
    expected = flags if ":" in flags else flags + ":" + message.split(":", 1)[1]
    assert flagged == expected


def test_fit_settings_are_frozen_and_normalised():
    s = FitSettings(window_s=30.0, axes=" z, x ")
    assert s.axes == ("z", "x")
    assert s.spec.is_default
    with pytest.raises(dataclasses.FrozenInstanceError):
        s.window_s = 10.0  # type: ignore[misc]
    assert FitSettings(model="damped", lines=2).spec.lines == 2
    with pytest.raises(ConfigError, match="--harmonics: expected a whole number"):
        FitSettings(harmonics=0)


def test_fit_refuses_bad_settings_before_reading_the_input(tmp_path, capsys):
    """Every flag is checked before the trajectory is opened: a missing input with a bad flag is
    reported as the bad flag, and nothing is written."""
    missing = tmp_path / "absent.parquet"
    for extra, message in (
        (["--window", "-2"], "--window: expected a positive length in s, got -2"),
        (["--step", "5"], "--step: needs --window"),
        (["--axes", "w"], "--axes: expected a comma list of z, x, y; got 'w'"),
        (["--posterior-noise", "pink"], "--posterior-noise: expected ar1 or white, got 'pink'"),
    ):
        assert main(["fit", str(missing), "--out", str(tmp_path / "e.csv"), *extra]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert err == [f"jaxdefl: error: {message}"]
    assert list(tmp_path.iterdir()) == []


# each command with a MISSING input (and output beside it)
COMMANDS = {
    "fit": ["fit", "{missing}.csv", "--out", "{out}.csv"],
    "diagnose": ["diagnose", "{missing}.csv", "--out", "{out}.json"],
    "reconcile": ["reconcile", "{missing}.csv", "--config", "{missing}.toml", "--out", "{out}"],
    "extract": ["extract", "{missing}.zarr", "--out", "{out}.csv"],
    "simulate": ["simulate", "{missing}.toml", "--out", "{out}"],
    "run": ["run", "{missing}.toml", "--out", "{out}"],
    "monitor": ["monitor", "--replay", "{missing}.csv", "--out", "{out}"],
    "follow": ["monitor", "{missing}.csv", "--out", "{out}"],
}
# (command, bad flags, the start of the one-line error)
BAD_FLAGS = [
    ("fit", "--window -5", "--window: expected a positive length"),
    ("fit", "--fmin 3 --fmax 2", "--fmin/--fmax: expected fmin < fmax"),
    ("diagnose", "--sensor sonar", "--sensor: expected one of tof, structured_light"),
    ("diagnose", "--frame-rate -20", "--frame-rate: expected a positive rate"),
    ("diagnose", "--modulation-mhz 0", "--modulation-mhz: expected a positive"),
    ("diagnose", "--effects drift,wobble", "--effects: unknown effect 'wobble'"),
    ("diagnose", "--timestamps later", "--timestamps: expected one of"),
    ("reconcile", "--null-sims 3", "--null-sims: expected at least 5"),
    ("reconcile", "--seed -1", "--seed: expected a seed >= 0"),
    ("extract", "--chunk-frames 0", "--chunk-frames: expected an integer >= 1"),
    ("extract", "--device gpu", "--device: expected cpu, cuda or cuda:N"),
    ("extract", "--timestamps merge", "--timestamps: expected strict or reclock"),
    ("simulate", "--duration -1", "--duration: expected a duration > 0 s"),
    ("simulate", "--live --speed 0", "--speed: expected a factor > 0"),
    ("run", "--scheduler local:0", "--scheduler: expected none, local"),
    ("run", "--timestamps later", "--timestamps: expected one of"),
    ("monitor", "--method kalman", "--method: expected one of ekf, rls"),
    ("monitor", "--block -5", "--block: expected a time > 0 s"),
    ("monitor", "--speed -1", "--speed: expected a factor >= 0"),
    ("monitor", "--alarms-per-day 0", "--alarms-per-day: expected a rate > 0"),
    ("follow", "--timestamps reclock", "--timestamps: reclock applies to --replay"),
]


@pytest.mark.parametrize("command, flags, message", BAD_FLAGS, ids=[f"{c} {f}" for c, f, _ in BAD_FLAGS])
def test_a_bad_flag_fails_on_the_flag_before_any_input_is_read(tmp_path, capsys, command, flags, message):
    missing, out = tmp_path / "missing", tmp_path / "out"
    argv = [a.format(missing=missing, out=out) for a in COMMANDS[command]] + flags.split()
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"jaxdefl: error: {message}"), err
    assert "missing" not in err, err  # the input was not opened
    assert not any(tmp_path.glob("out*")), "nothing is written"


def test_every_flag_names_an_option_of_its_command():
    """The maps from parameters to flags stay in step with the commands' options."""
    import typer.main

    from jaxdefl.cli import app

    group = typer.main.get_command(app)
    for name, flags, settings in (
        ("fit", FIT_FLAGS, FitSettings),
        ("diagnose", DIAGNOSE_FLAGS, DiagnoseSettings),
        ("reconcile", RECONCILE_FLAGS, ReconcileSettings),
        ("extract", EXTRACT_FLAGS, ExtractSettings),
        ("simulate", SIMULATE_FLAGS, SimulateSettings),
        ("run", RUN_FLAGS, RunSettings),
        ("monitor", MONITOR_FLAGS, MonitorSettings),
    ):
        options = {o for p in group.commands[name].params for o in p.opts}
        assert set(flags.values()) <= options, (name, set(flags.values()) - options)
        fields = {f.name for f in dataclasses.fields(settings)}
        assert set(flags) <= fields, (name, set(flags) - fields)


def test_other_settings_are_frozen_and_normalised():
    s = DiagnoseSettings(effects=" drift, outliers", tap_offsets=[0, 0.25, 0.5, 0.75], axes="z")
    assert s.effects == ("drift", "outliers") and s.tap_offsets == (0.0, 0.25, 0.5, 0.75) and s.axes == ("z",)
    with pytest.raises(dataclasses.FrozenInstanceError):
        s.sensor = "tof"
    assert ExtractSettings(device="CPU").device == "cpu"
    # the camera facts of a config fill only what the settings leave unsaid, and are checked too
    t = DiagnoseSettings(frame_rate_hz=10.0).with_camera({"sensor": "tof", "frame_rate_hz": 20.0})
    assert (t.sensor, t.frame_rate_hz) == ("tof", 10.0)
    with pytest.raises(ParameterError, match="sensor: expected one of"):
        DiagnoseSettings().with_camera({"sensor": "lidar"})


@pytest.mark.parametrize(
    "make, message",
    [
        (lambda: ReconcileSettings(n_null=4), "n_null: expected at least 5"),
        (lambda: ReconcileSettings(n_sims=0), "n_sims: expected at least 1"),
        (lambda: SimulateSettings(duration_s=float("nan")), "duration_s: expected a duration > 0 s"),
        (lambda: MonitorSettings(until_s=0.0), "until_s: expected a time > 0 s, got 0"),
        (lambda: MonitorSettings(timestamps="merge"), "timestamps: merge applies to replay"),
        (lambda: RunSettings(scheduler=" "), "scheduler: expected none, local"),
        (lambda: DiagnoseSettings(tap_offsets=(0.0, 0.25, 0.5, 1.0)), "tap_offsets: expected 4 fractions"),
    ],
)
def test_library_errors_name_the_parameter(make, message):
    with pytest.raises(ParameterError, match=message):
        make()


SETTINGS_OF = {
    "fit": (FitSettings, FIT_FLAGS),
    "diagnose": (DiagnoseSettings, DIAGNOSE_FLAGS),
    "reconcile": (ReconcileSettings, RECONCILE_FLAGS),
    "extract": (ExtractSettings, EXTRACT_FLAGS),
    "simulate": (SimulateSettings, SIMULATE_FLAGS),
    "run": (RunSettings, RUN_FLAGS),
    "monitor": (MonitorSettings, MONITOR_FLAGS),
}


@pytest.mark.parametrize("command", list(SETTINGS_OF))
def test_each_flag_is_one_field_with_one_default(command):
    """Every flag of a command's settings map is an option of the command, named as the map
    says, and its default is the settings field's default: a library call and the command line
    with no flags do the same thing."""
    import typer.main

    from jaxdefl.cli import app

    cls, flags = SETTINGS_OF[command]
    options = {opt: p for p in typer.main.get_command(app).commands[command].params for opt in p.opts}
    fields = {f.name: f for f in dataclasses.fields(cls)}
    for param, flag in flags.items():
        assert flag in options, (command, flag)
        assert param in fields, (command, param)
        assert options[flag].default == fields[param].default, (command, flag)
    assert len(set(flags.values())) == len(flags)
