import json
import sys

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
    assert set(unc["flag"]) <= flags | {f for f in unc["flag"] if "+" in f}
    post = pd.read_csv(recording / "est_posterior.csv")
    assert len(post) == 2 and post["converged_chain"].all()
    # at this SNR the posterior and the linearised σ_A agree (issue 6: within 10 %)
    assert np.all(np.abs(post["sigma_ratio_amplitude"] - 1) < 0.15)
    assert (recording / "est_posterior.png").exists()
    assert main([*args[:-1], "-1"]) == 2
    assert "--posterior: expected a number of windows >= 0, got -1" in capsys.readouterr().err
    assert main([*args, "--posterior-noise", "pink"]) == 2
    assert "--posterior-noise: expected ar1 or white, got 'pink'" in capsys.readouterr().err


@pytest.mark.parametrize(
    "args, names",
    [
        (["fit", "{traj}", "--out", "{out}", "--windw", "3"], ["--windw", "--window"]),
        (["run", "{traj}", "--jobs", "3"], ["--jobs", "jaxdefl run --help"]),
        (["fit", "{traj}", "extra", "--out", "{out}"], ["extra", "jaxdefl fit --help"]),
        (["fit", "{traj}", "--out", "{out}", "--window", "ten"], ["--window: expected a number, got 'ten'"]),
        (["fit", "{traj}", "--out", "{out}", "--harmonics", "1.5"], ["--harmonics: expected an integer"]),
        (["fit", "{traj}", "--out"], ["--out"]),
        (["fit", "{traj}"], ["--out"]),
        (["bogus"], ["bogus"]),
        (["run", "{traj}", "--scheduler", "banana"], ["--scheduler", "host:port", "'banana'"]),
        (["run", "{traj}", "--scheduler", "tcp://host"], ["--scheduler", "'tcp://host'"]),
        (["run", "{traj}", "--scheduler", "host:99999"], ["--scheduler"]),
        (["run", "{traj}", "--scheduler", "local:0"], ["--scheduler"]),
    ],
)
def test_every_usage_error_is_one_line_naming_the_flag_and_exit_2(recording, capsys, args, names):
    out = recording / "e.csv"
    argv = [a.format(traj=recording / "traj.csv", out=out) for a in args]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("jaxdefl: error: "), err
    for name in names:
        assert name in err[0]
    assert "Error" not in err[0] and "Exception" not in err[0]  # no class names leak
    assert not out.exists()


@pytest.mark.parametrize("address", ["none", "local", "local:3", "10.0.0.5:8786", "tcp://[::1]:8786"])
def test_valid_schedulers_pass_the_flag_check(address):
    from jaxdefl.settings import RunSettings

    assert RunSettings(scheduler=address).scheduler == address


def test_no_arguments_shows_the_help(capsys):
    assert main([]) == 0
    assert "Usage" in capsys.readouterr().out


# -- TUM depth folders in a base install: no OpenCV (issue 25 item 12) --------------------------

TUM_INTR = dict(fx=100.0, fy=100.0, cx=63.5, cy=31.5)


def _tum_folder(root, n=260):
    """A TUM-style folder (depth.txt, depth/*.png at 0.2 mm per unit, camera.json) of three
    plates moving at 3 Hz above a beam, written with OpenCV; the same frames as an .npz."""
    import cv2

    rng = np.random.default_rng(5)
    t = 100.0 + np.arange(n) / 20.0
    defl = 2.0 * np.sin(2 * np.pi * 3.0 * (t - t[0]))
    z = np.full((n, 64, 128), 2700.0)
    z[:, 8:24, :] = 1900.0 + defl[:, None, None]
    for c0, c1 in [(8, 34), (50, 76), (92, 118)]:
        z[:, 24:36, c0:c1] = 1880.0 + defl[:, None, None]
    z += rng.normal(0, 1.0, z.shape)
    img = np.round(z / 0.2).astype(np.uint16)
    img[:, 0, 0] = 0  # no measurement
    (root / "depth").mkdir(parents=True)
    lines = ["# timestamp filename"]
    for i in range(n):
        assert cv2.imwrite(str(root / "depth" / f"{i:04d}.png"), img[i])
        lines.append(f"{t[i]:.6f} depth/{i:04d}.png")
    (root / "depth.txt").write_text("\n".join(lines) + "\n")
    (root / "camera.json").write_text(json.dumps(TUM_INTR))
    frames = np.where(img == 0, np.nan, img.astype(np.float32) * np.float32(0.2))
    np.savez(root.parent / "same.npz", timestamps=t, depth=frames, intrinsics=list(TUM_INTR.values()))
    return root, img


def test_png_reading_agrees_with_opencv_and_skimage(tmp_path, monkeypatch):
    import cv2
    from skimage import io as skio

    from jaxdefl.io.recording import _read_png

    rng = np.random.default_rng(0)
    img = rng.integers(0, 65536, (37, 53), dtype=np.uint16)
    img[0, :3] = [0, 1, 65535]
    cv2.imwrite(str(tmp_path / "a.png"), img)
    monkeypatch.setitem(sys.modules, "cv2", None)  # a base install: no OpenCV
    ours = _read_png(tmp_path / "a.png")
    assert ours.dtype == np.uint16 and np.array_equal(ours, img)
    assert np.array_equal(ours, cv2.imread(str(tmp_path / "a.png"), cv2.IMREAD_UNCHANGED))
    assert np.array_equal(ours, skio.imread(tmp_path / "a.png"))
    assert _read_png(tmp_path / "missing.png") is None
    (tmp_path / "b.png").write_bytes(b"\x89PNG truncated")
    assert _read_png(tmp_path / "b.png") is None


def test_extract_reads_a_tum_folder_without_opencv(tmp_path, monkeypatch, capsys):
    folder, _ = _tum_folder(tmp_path / "tum")
    monkeypatch.setitem(sys.modules, "cv2", None)  # `import cv2` now fails, as in a base install
    assert main(["extract", str(folder), "--out", str(tmp_path / "tum.csv"), "--device", "cpu"]) == 0
    assert (
        main(["extract", str(tmp_path / "same.npz"), "--out", str(tmp_path / "npz.csv"), "--device", "cpu"])
        == 0
    )
    a, b = pd.read_csv(tmp_path / "tum.csv"), pd.read_csv(tmp_path / "npz.csv")
    assert (
        sorted(a["plate"].unique()) == [1, 2, 3] and len(a) == 3 * 260
    )  # 13 s: the monitor fits its first 10 s
    # the PNGs read exactly as the frames they hold
    pd.testing.assert_frame_equal(a.drop(columns="segment"), b.drop(columns="segment"))


@pytest.mark.slow
def test_monitor_replays_a_tum_folder_without_opencv(tmp_path, monkeypatch, capsys):
    folder, _ = _tum_folder(tmp_path / "tum")
    monkeypatch.setitem(sys.modules, "cv2", None)
    out = tmp_path / "mon"
    args = ["monitor", "--replay", str(folder), "--out", str(out), "--speed", "0"]
    assert main(args) == 0, capsys.readouterr().err
    assert (out / "estimates.csv").exists()


# -- shipped config names in campaign files, fit --help, the install (issue 25 item 19) ---------


def test_campaign_simulate_config_is_a_nearby_path_else_a_shipped_name(tmp_path):
    from jaxdefl import ConfigError
    from jaxdefl._configs import config_dir
    from jaxdefl.bulk import load_campaign

    camp = tmp_path / "c.toml"
    camp.write_text('[simulate]\nconfig = "exp2_tof_3hz"\nduration_s = 5.0\n')
    shipped = (config_dir() / "exp2_tof_3hz.toml").resolve()
    assert load_campaign(camp).recordings[0].simulate["config"] == str(shipped)
    # a file of that name beside the campaign wins over the shipped config
    (tmp_path / "exp2_tof_3hz").write_bytes(shipped.read_bytes())
    assert load_campaign(camp).recordings[0].simulate["config"] == str((tmp_path / "exp2_tof_3hz").resolve())
    camp.write_text('[simulate]\nconfig = "no_such_config"\n')
    with pytest.raises(
        ConfigError, match=r"key 'simulate.config': file not found: .*or the name of a shipped"
    ):
        load_campaign(camp)


def test_fit_help_names_every_table_format_it_writes(capsys):
    from jaxdefl.io.output import TABLE_SUFFIXES

    assert main(["fit", "--help"]) == 0
    text = " ".join(capsys.readouterr().out.split())
    assert "(CSV)" not in text
    for suffix in TABLE_SUFFIXES:
        assert suffix in text


def test_pyproject_licence_is_spdx_so_setuptools_prints_no_deprecation(monkeypatch):
    import tomllib
    import warnings
    from pathlib import Path

    from packaging.requirements import Requirement
    from packaging.version import Version
    from setuptools.config.pyprojecttoml import apply_configuration
    from setuptools.dist import Distribution
    from setuptools.warnings import SetuptoolsDeprecationWarning

    root = Path(__file__).resolve().parents[1]
    monkeypatch.chdir(root)  # the readme is found from the project's root, as a build does
    with warnings.catch_warnings():
        # the banner a build printed three times (`project.license` as a TOML table)
        warnings.simplefilter("error", SetuptoolsDeprecationWarning)
        dist = apply_configuration(Distribution(), root / "pyproject.toml")
    assert dist.metadata.license_expression == "MIT"
    build = tomllib.loads((root / "pyproject.toml").read_text())["build-system"]["requires"]
    setuptools = next(Requirement(r) for r in build if r.startswith("setuptools"))
    # the SPDX string form needs setuptools 77; an older one would be picked by an isolated build
    assert not setuptools.specifier.contains(Version("76.9")) and setuptools.specifier.contains(
        Version("77.0")
    )


def test_fit_of_a_shuffled_table_with_reclock_equals_the_ordered_fit(recording, capsys):
    traj = pd.read_csv(recording / "traj.csv")
    traj.sample(frac=1.0, random_state=4).to_csv(recording / "shuffled.csv", index=False)
    args = ["--axes", "z", "--timestamps", "reclock"]
    assert main(["fit", str(recording / "shuffled.csv"), "--out", str(recording / "a.csv"), *args]) == 0
    assert "sorted by t within their plate" in " ".join(capsys.readouterr().err.split())
    assert main(["fit", str(recording / "traj.csv"), "--out", str(recording / "b.csv"), *args]) == 0
    a, b = pd.read_csv(recording / "a.csv"), pd.read_csv(recording / "b.csv")
    pd.testing.assert_frame_equal(a, b)


def test_every_help_text_is_shown_whole(capsys, monkeypatch):
    """Rich markup would swallow a bracketed word ("[default: ...]", "[[session]]"): every
    option's help, as written, appears in its command's --help."""
    import typer.main

    from jaxdefl.cli import app

    monkeypatch.setenv("COLUMNS", "400")
    group = typer.main.get_command(app)
    for name, command in group.commands.items():
        assert main([name, "--help"]) == 0
        shown = " ".join(capsys.readouterr().out.split())
        for param in command.params:
            help_text = getattr(param, "help", None)
            if help_text and "[" in help_text:
                words = " ".join(help_text.replace("\\[", "[").split())
                assert words in shown, (name, param.name, words)
