import json

import numpy as np
import pandas as pd
import pytest

from jaxdefl.cli import main
from jaxdefl.fit import ESTIMATE_COLUMNS
from jaxdefl.io import write_trajectory
from jaxdefl.synthetic import harmonic_experiment


@pytest.fixture
def recording(tmp_path):
    traj, lds = harmonic_experiment(duration_s=40, seed=3)
    traj = traj[traj["plate"].isin([3, 7])]
    write_trajectory(traj, tmp_path / "traj.csv")
    write_trajectory(lds, tmp_path / "lds.csv")
    return tmp_path


def test_fit_writes_the_estimates_contract(recording):
    out = recording / "est.csv"
    assert main(["fit", str(recording / "traj.csv"), "--out", str(out), "--window", "20"]) == 0
    est = pd.read_csv(out)
    assert list(est.columns) == ESTIMATE_COLUMNS
    assert len(est) == 2 * 3 * 2  # plates x axes x windows
    z = est[est["axis"] == "z"]
    assert (z["status"] == "converged").all()
    assert np.all(np.abs(z["f0_hz"] - 3.0672) < 5 * z["sigma_f0_hz"])
    meta = json.loads(out.with_suffix(".json").read_text())
    assert meta["window_s"] == 20 and meta["command"] == "fit"


def test_fit_with_reference_writes_differences(recording):
    out = recording / "est.csv"
    args = [
        "fit",
        str(recording / "traj.csv"),
        "--out",
        str(out),
        "--axes",
        "z",
        "--reference",
        str(recording / "lds.csv"),
    ]
    assert main(args) == 0
    cmp = pd.read_csv(recording / "est_comparison.csv")
    assert sorted(cmp["plate"]) == [3, 7]
    assert np.all(np.abs(cmp["delta_amplitude_mm"]) < 5 * cmp["sigma_delta_amplitude_mm"])
    assert np.all(np.abs(cmp["delta_f0_hz"]) < 5 * cmp["sigma_delta_f0_hz"])
    ref = pd.read_csv(recording / "est_reference.csv")
    assert (ref["status"] == "converged").all()


def test_bad_input_is_one_line_and_exit_2(recording, capsys):
    bad = recording / "bad.csv"
    bad.write_text("t,plate,z\n0,1,1\n0.05,1,x\n")
    assert main(["fit", str(bad), "--out", str(recording / "e.csv")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "row 3 column 'z'" in err[0]


@pytest.mark.parametrize(
    "args, message",
    [
        (["--axes", "z,w"], "--axes: expected a comma list of z, x, y; got 'z,w'"),
        (["--window", "-3"], "--window: expected a positive length in s, got -3"),
        (["--step", "5"], "--step: needs --window"),
        (["--window", "10", "--step", "0"], "--step: expected a positive length in s, got 0"),
        (["--fap-max", "0"], "--fap-max: expected a probability in (0, 1], got 0"),
    ],
)
def test_bad_arguments_exit_2(recording, capsys, args, message):
    code = main(["fit", str(recording / "traj.csv"), "--out", str(recording / "e.csv"), *args])
    assert code == 2
    assert message in capsys.readouterr().err


def test_reference_without_common_plates(recording, capsys):
    ref = recording / "ref.csv"
    pd.DataFrame({"t": [1.7e9, 1.7e9 + 1], "plate": [99, 99], "z": [0.0, 1.0]}).to_csv(ref, index=False)
    code = main(
        [
            "fit",
            str(recording / "traj.csv"),
            "--out",
            str(recording / "e.csv"),
            "--reference",
            str(ref),
        ]
    )
    assert code == 2
    assert "no plate of the reference (plates 99) is in" in capsys.readouterr().err
    assert not (recording / "e.csv").exists()


def test_axes_default_to_the_columns_present_and_missing_ones_are_errors(tmp_path, capsys):
    p = tmp_path / "z_only.csv"
    pd.DataFrame(
        {"t": np.arange(100) * 0.05, "plate": 1, "z": np.sin(2 * np.pi * 3 * np.arange(100) * 0.05)}
    ).to_csv(p, index=False)
    assert main(["fit", str(p), "--out", str(tmp_path / "e.csv")]) == 0
    assert pd.read_csv(tmp_path / "e.csv")["axis"].tolist() == ["z"]
    assert main(["fit", str(p), "--out", str(tmp_path / "e.csv"), "--axes", "z,x,y"]) == 2
    assert "--axes: the table has no column x, y" in capsys.readouterr().err


@pytest.mark.slow
def test_demo_runs_frames_to_report(tmp_path, capsys):
    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out), "--duration", "20"]) == 0
    # off a terminal: plain lines, each step named, and the closing line (issue 25.16)
    err = capsys.readouterr().err
    assert f"jaxdefl demo: wrote {out / 'summary.md'}" in err and "\x1b" not in err and "\r" not in err
    assert "jaxdefl demo: extracting" in err and "jaxdefl demo: emcee posteriors" in err
    # the summary says why plates are missing, which windows have no fit and why, and which
    # LDS is defective (issue 25.17)
    summary = (out / "summary.md").read_text()
    assert "lie whole inside the image" in summary and "outside the camera's view" in summary
    assert "marked defective in the config (`lds.defective_plate = 9`" in summary
    windows = pd.read_csv(out / "estimates_30s.csv")
    bad = windows[windows["status"] != "converged"]
    if len(bad):
        assert f"{len(bad)} of {len(windows)} windows have no fit" in summary
        for r in bad.itertuples():
            assert f"plate {r.plate} {r.axis}, window" in summary and f"`{r.status}`" in summary
    else:
        assert "Every window was fitted." in summary
    for name in (
        "summary.md",
        "frame.png",
        "psd.png",
        "fit.png",
        "estimates_whole.csv",
        "comparison_lds.csv",
        "trajectories.csv",
        "simulation/recording.zarr",
    ):
        assert (out / name).exists(), name
    est = pd.read_csv(out / "estimates_whole.csv")
    z = est[est["axis"] == "z"]
    # the plates in the demo camera's view: a contiguous run about mid-span (plates 5-9 at least;
    # how many more depends on the plates' depth below the beam top)
    plates = sorted(z["plate"])
    assert plates == list(range(plates[0], plates[-1] + 1)) and {5, 6, 7, 8, 9} <= set(plates)
    assert (z["status"] == "converged").all()
    # Experiment II day 1 loads at 3.0680 Hz (configs/exp2_tof_3hz.toml)
    assert np.all(np.abs(z["f0_hz"] - 3.0680) < 5 * z["sigma_f0_hz"] + 1e-4)


def test_fit_posterior_writes_flags_and_posteriors(recording, capsys):
    out = recording / "est.csv"
    args = [
        "fit",
        str(recording / "traj.csv"),
        "--out",
        str(out),
        "--axes",
        "z",
        "--window",
        "20",
        "--posterior",
        "2",
    ]
    assert main(args) == 0
    unc = pd.read_csv(recording / "est_uncertainty.csv")
    est = pd.read_csv(out)
    assert len(unc) == len(est)
    flags = {"ok", "low_snr", "few_cycles", "heavy_dropouts", "coloured_noise", "inadequate_model"}
    flags.add("not_fitted")
    assert set(unc["flag"]) <= flags | {
        f for f in unc["flag"] if "+" in f
    }
    post = pd.read_csv(recording / "est_posterior.csv")
    assert len(post) == 2 and post["converged_chain"].all()
    # at this SNR the posterior and the linearised σ_A agree (issue 6: within 10 %)
    assert np.all(np.abs(post["sigma_ratio_amplitude"] - 1) < 0.15)
    assert (recording / "est_posterior.png").exists()
    assert main([*args[:-1], "-1"]) == 2
    assert "--posterior: expected a number of windows >= 0, got -1" in capsys.readouterr().err
    assert main([*args, "--posterior-noise", "pink"]) == 2
    assert "--posterior-noise: expected ar1 or white, got 'pink'" in capsys.readouterr().err
