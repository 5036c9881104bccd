"""Command settings: frozen, validated whole before any input is read, errors in parameter names
for a library caller and in flags on the command line."""

from __future__ import annotations

import dataclasses

import pytest

from jaxdefl import ConfigError
from jaxdefl._errors import ParameterError
from jaxdefl.cli import main
from jaxdefl.settings import FIT_FLAGS, FitSettings


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
