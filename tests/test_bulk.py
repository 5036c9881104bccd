import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import xarray as xr
from threadpoolctl import threadpool_info

from jaxdefl import ConfigError
from jaxdefl.bulk import load_campaign, run_campaign
from jaxdefl.cli import main
from jaxdefl.io import write_trajectory
from jaxdefl.synthetic import harmonic_experiment

AMPS = [2.37, 2.42, 2.43, 2.44, 2.46, 2.47]
CYCLES = [32400, 60050, 92450, 154200, 226400, 332900]


def make_campaign(tmp: Path, days=3, duration_s=40.0, extra="", processing="window_s = 20.0\n"):
    lines = ['[campaign]\nname = "t"\n', f"[processing]\n{processing}"]
    for d in range(1, days + 1):
        traj, lds = harmonic_experiment(duration_s=duration_s, seed=d, amplitude_mm=AMPS[d - 1])
        traj = traj[traj["plate"].isin([3, 5, 7, 9])]
        write_trajectory(traj, tmp / f"traj{d}.csv")
        write_trajectory(lds[lds["plate"].isin([5, 7])], tmp / f"lds{d}.csv")
        lines.append(
            f'[[recording]]\nday = {d}\ncamera = "cam2"\ncycles = {CYCLES[d - 1]}\n'
            f'trajectories = "traj{d}.csv"\nlds = "lds{d}.csv"\n'
        )
    (tmp / "campaign.toml").write_text("\n".join(lines) + extra)
    return tmp / "campaign.toml"


def test_campaign_tables_follow_the_truth(tmp_path):
    cfg = make_campaign(tmp_path)
    units = run_campaign(load_campaign(cfg), tmp_path / "out", progress=False)
    assert (units["status"] == "ok").all()
    day = pd.read_csv(tmp_path / "out" / "per_day.csv")
    assert day["cycles"].tolist() == CYCLES[:3]
    # plate 7 sits at 0.99 of the mid-span deflection on the demo beam
    from jaxdefl.synthetic import LOAD_A_M, PLATE_X_M, SPAN_M, beam_shape

    truth = np.array(AMPS[:3]) * beam_shape(PLATE_X_M[6], SPAN_M, LOAD_A_M)
    assert np.all(np.abs(day["amplitude_mm"] - truth) < 4 * day["sigma_amplitude_mm"])
    assert np.all(
        np.abs(day["delta_amplitude_mm"])
        < 5 * np.hypot(day["sigma_amplitude_mm"], day["sigma_amplitude_mm_lds"])
    )
    prof = pd.read_csv(tmp_path / "out" / "profile.csv")
    assert np.all(
        np.abs(prof["midspan_amplitude_mm"] - np.array(AMPS[:3])) < 4 * prof["sigma_midspan_mm"] + 0.01
    )
    ds = xr.open_zarr(tmp_path / "out" / "results.zarr")
    assert set(ds["amplitude_mm"].dims) == {"day", "camera", "window", "plate", "axis"}
    assert ds.sizes["day"] == 3 and ds.sizes["window"] == 2
    for name in ("report.md", "fatigue.png", "profile.png", "units.csv"):
        assert (tmp_path / "out" / name).exists()
    # every unit records its stages' seconds (bench_bulk.py's breakdown), inside its own time
    for man in (tmp_path / "out" / "units").glob("*/manifest.json"):
        man = json.loads(man.read_text())
        stages = man["stage_seconds"]
        assert {"reading", "validation", "windowing", "kernel", "whole-record fit", "residual"} <= set(stages)
        assert {"LDS comparison", "writing"} <= set(stages)
        assert min(stages.values()) >= 0 and sum(stages.values()) <= man["seconds"] + 0.01


def test_bad_units_get_reasons_and_the_rest_finishes(tmp_path):
    cfg = make_campaign(
        tmp_path,
        days=2,
        extra=(
            '[[recording]]\nday = 7\ncamera = "cam2"\ncycles = 1\ntrajectories = "nowhere.csv"\n'
            '[[recording]]\nday = 8\ncamera = "cam2"\ncycles = 2\ntrajectories = "garbage.csv"\n'
            '[[recording]]\nday = 9\ncamera = "cam2"\ncycles = 3\ntrajectories = "empty.csv"\n'
        ),
    )
    (tmp_path / "garbage.csv").write_text("t,plate,z\n0,1,abc\n")
    pd.DataFrame({"t": np.arange(50) * 0.05, "plate": 1, "z": np.nan}).to_csv(
        tmp_path / "empty.csv", index=False
    )

    def blas():  # threads of each BLAS library loaded
        return {i["filepath"]: i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"}

    before = blas()
    units = run_campaign(load_campaign(cfg), tmp_path / "out", progress=False).set_index("unit")
    # the units ran with single-threaded BLAS; the process gets its setting back, failures or not
    assert {k: v for k, v in blas().items() if k in before} == before
    assert units.loc["day01-cam2", "status"] == "ok" and units.loc["day02-cam2", "status"] == "ok"
    assert "nowhere.csv: file not found" in units.loc["day07-cam2", "reason"]
    assert "row 2 column 'z': expected a number" in units.loc["day08-cam2", "reason"]
    assert "no plate and axis could be fitted (too_few_samples)" in units.loc["day09-cam2", "reason"]
    assert "day07-cam2" in (tmp_path / "out" / "report.md").read_text()


def test_rerun_skips_finished_units_and_recomputes_stale_ones(tmp_path):
    cfg = make_campaign(tmp_path, days=2)
    camp = load_campaign(cfg)
    run_campaign(camp, tmp_path / "out", progress=False)
    stamp = {
        u: json.loads((tmp_path / "out" / "units" / u / "manifest.json").read_text())["computed_at"]
        for u in ("day01-cam2", "day02-cam2")
    }
    # changing one input file makes only that unit stale
    traj, _ = harmonic_experiment(duration_s=40, seed=99)
    write_trajectory(traj[traj["plate"].isin([3, 5, 7, 9])], tmp_path / "traj2.csv")
    units = run_campaign(camp, tmp_path / "out", progress=False).set_index("unit")
    assert units.loc["day01-cam2", "skipped"] and not units.loc["day02-cam2", "skipped"]
    man1 = json.loads((tmp_path / "out" / "units" / "day01-cam2" / "manifest.json").read_text())
    assert man1["computed_at"] == stamp["day01-cam2"]
    # a corrupted output is detected and recomputed
    (tmp_path / "out" / "units" / "day01-cam2" / "whole.csv").write_text("truncated")
    units = run_campaign(camp, tmp_path / "out", progress=False).set_index("unit")
    assert not units.loc["day01-cam2", "skipped"]


@pytest.mark.slow
def test_sigkill_then_resume_equals_an_uninterrupted_run(tmp_path):
    cfg = make_campaign(tmp_path, days=6, duration_s=30.0)
    ref = tmp_path / "ref"
    assert main(["run", str(cfg), "--out", str(ref)]) == 0
    out = tmp_path / "killed"
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen(
        [sys.executable, "-m", "jaxdefl.cli", "run", str(cfg), "--out", str(out)],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    deadline = time.time() + 240
    while time.time() < deadline:
        done = list((out / "units").glob("*/manifest.json")) if (out / "units").exists() else []
        if len(done) >= 2:
            break
        time.sleep(0.05)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    finished = {
        p.parent.name: json.loads(p.read_text())["computed_at"]
        for p in (out / "units").glob("*/manifest.json")
    }
    assert 2 <= len(finished) < 6, finished
    assert main(["run", str(cfg), "--out", str(out)]) == 0
    units = pd.read_csv(out / "units.csv").set_index("unit")
    for u, stamp in finished.items():
        assert units.loc[u, "skipped"]
        assert json.loads((out / "units" / u / "manifest.json").read_text())["computed_at"] == stamp
    a = pd.read_csv(ref / "estimates_windows.csv")
    b = pd.read_csv(out / "estimates_windows.csv")
    pd.testing.assert_frame_equal(a, b)
    pd.testing.assert_frame_equal(pd.read_csv(ref / "per_day.csv"), pd.read_csv(out / "per_day.csv"))


@pytest.mark.slow
def test_local_cluster_equals_in_process(tmp_path):
    cfg = make_campaign(tmp_path, days=2, duration_s=30.0)
    camp = load_campaign(cfg)
    run_campaign(camp, tmp_path / "a", scheduler="none", progress=False)
    units = run_campaign(camp, tmp_path / "b", scheduler="local", progress=False)
    assert (units["status"] == "ok").all()
    for name in (
        "estimates_whole.csv",
        "estimates_windows.csv",
        "comparison_lds.csv",
        "per_day.csv",
    ):
        pd.testing.assert_frame_equal(pd.read_csv(tmp_path / "a" / name), pd.read_csv(tmp_path / "b" / name))


@pytest.mark.parametrize(
    "toml, message",
    [
        ("[campaign]\nname='x'\n[oops]\n", "key 'oops': unknown key"),
        (
            "[processing]\nwindow_s = -5\n[[recording]]\nday=1\ncamera='c'\ntrajectories='t.csv'\n",
            "key 'processing.window_s': expected a positive number, got -5",
        ),
        (
            "[processing]\naxes = ['q']\n[[recording]]\nday=1\ncamera='c'\ntrajectories='t.csv'\n",
            "key 'processing.axes': expected a list of z, x, y",
        ),
        ("[[recording]]\nday=1\ncamera='c'\n", "key 'recording[0].trajectories': missing"),
        (
            "[[recording]]\nday='one'\ncamera='c'\ntrajectories='t.csv'\n",
            "key 'recording[0].day': expected an integer",
        ),
        (
            "[[recording]]\nday=1\ncamera='c'\ntrajectories='t.csv'\ncolor='red'\n",
            "key 'recording[0].color': unknown key",
        ),
        (
            "[[recording]]\nday=1\ncamera='c'\ntrajectories='t.csv'\n[[recording]]\nday=1\ncamera='c'\ntrajectories='u.csv'\n",
            "day 1 camera 'c' appears twice",
        ),
        ("[campaign]\nname='x'\n", "key 'recording': no recordings"),
        (
            "[[recording]]\nday=1\ncamera='c'\ncycles=-3\ntrajectories='t.csv'\n",
            "key 'recording[0].cycles': expected a count >= 0",
        ),
        ("this is not toml", "not valid TOML"),
    ],
)
def test_campaign_config_errors(tmp_path, toml, message):
    p = tmp_path / "c.toml"
    p.write_text(toml)
    with pytest.raises(ConfigError, match=message.replace("(", r"\(").replace("[", r"\[")):
        load_campaign(p)


def test_run_cli_exit_codes(tmp_path, capsys):
    assert main(["run", str(tmp_path / "none.toml")]) == 2
    assert "campaign file not found" in capsys.readouterr().err
    cfg = make_campaign(tmp_path, days=1)
    assert main(["run", str(cfg), "--out", str(tmp_path / "o"), "--scheduler", "tcp://127.0.0.1:1"]) == 2
    assert "cannot reach a dask scheduler" in capsys.readouterr().err


@pytest.mark.slow
def test_simulated_campaign_frames_to_fatigue_curve(tmp_path):
    """[simulate]: the simulator makes the frames, extraction units the trajectories."""
    cfg_path = Path(__file__).resolve().parents[1] / "configs" / "exp2_tof_3hz.toml"
    (tmp_path / "c.toml").write_text(
        f'[processing]\nwindow_s = 10.0\ncorrect_motion_artefact = true\n[simulate]\nconfig = "{cfg_path}"\nsessions = ["day1", "day11"]\n'
        "duration_s = 20.0\nunit_frames = 150\n"
    )
    camp = load_campaign(tmp_path / "c.toml")
    units = run_campaign(camp, tmp_path / "out", progress=False)
    assert (units["status"] == "ok").all()
    assert len(list((tmp_path / "out" / "units").glob("ext-day01-cam2-*"))) == 3
    day = pd.read_csv(tmp_path / "out" / "per_day.csv").set_index("day")
    # The fatigue law of the config: LDS 2.32 mm at day 1, 2.63 mm at day 11 (Table 6.16)
    assert day.loc[1, "amplitude_mm_lds"] == pytest.approx(2.32, abs=0.01)
    assert day.loc[11, "amplitude_mm_lds"] == pytest.approx(2.63, abs=0.01)
    # camera amplitudes follow, lowered by the ToF motion artefact (-0.14 mm per 4 mm at 3 Hz / 20 Hz)
    assert 0.2 < day.loc[11, "amplitude_mm"] - day.loc[1, "amplitude_mm"] < 0.4
    assert np.all((day["delta_amplitude_mm"] < 0) & (day["delta_amplitude_mm"] > -0.15))
    # corrected for the artefact, the camera recovers the simulated truth per day within 0.05 mm
    assert np.all(np.abs(day["amplitude_corrected_mm"] - day["amplitude_truth_mm"]) < 0.05)
    # a rerun reuses every unit: simulation, extraction and estimates
    stamps = {p.parent.name: p.stat().st_mtime for p in (tmp_path / "out" / "units").glob("*/manifest.json")}
    run_campaign(camp, tmp_path / "out", progress=False)
    assert stamps == {
        p.parent.name: p.stat().st_mtime for p in (tmp_path / "out" / "units").glob("*/manifest.json")
    }


def test_simulate_table_errors(tmp_path):
    cfg_path = Path(__file__).resolve().parents[1] / "configs" / "exp2_tof_3hz.toml"
    for body, msg in [
        ('[simulate]\nconfig = "nope.toml"\n', "key 'simulate.config': file not found"),
        (
            f'[simulate]\nconfig = "{cfg_path}"\nsessions = ["day6"]\n',
            "'day6' is not a session of exp2_tof_3hz.toml",
        ),
        (f'[simulate]\nconfig = "{cfg_path}"\nspeed = 2\n', "key 'simulate.speed': unknown key"),
        (
            f'[simulate]\nconfig = "{cfg_path}"\nduration_s = -1\n',
            "key 'simulate.duration_s': expected a positive",
        ),
    ]:
        (tmp_path / "c.toml").write_text(body)
        with pytest.raises(ConfigError, match=msg):
            load_campaign(tmp_path / "c.toml")


def test_csv_text_equals_pandas_to_csv():
    """The units' and the aggregate's CSV writer gives pandas' text, byte for byte: on estimate
    tables (NaNs, statuses, ints) and on cells that need quoting or are missing."""
    from jaxdefl.bulk.store import csv_text
    from jaxdefl.fit import estimate_table
    from jaxdefl.io import validate_trajectory

    traj, _ = harmonic_experiment(duration_s=40.0, seed=3)
    traj = validate_trajectory(traj[traj["plate"].isin([3, 7])])
    tables = [
        estimate_table(traj, window_s=20.0).table.assign(day=1, camera="cam2", cycles=32400),
        estimate_table(traj).table,
        pd.DataFrame(
            {
                "f": [0.1, -0.0, np.nan, np.inf, -np.inf, 1e-300, 123456789012.5, 2.0 / 3.0],
                "i": np.arange(8, dtype=np.int64) - 3,
                "u": np.arange(8, dtype=np.uint8),
                "b": [True, False] * 4,
                "o": ["a,b", 'say "x"', "two\nlines", "", None, np.nan, 0.1 + 0.2, 7],
                "s": ["plain"] * 8,
            }
        ),
        pd.DataFrame({"only": ["", "x", ""]}),
        pd.DataFrame({"str": pd.array(["a", None, "b,c"], dtype="string"), "i": [1, 2, 3]}),
        pd.DataFrame({"a": pd.Series([], dtype=float), "b": pd.Series([], dtype=object)}),
        pd.DataFrame({"cat": pd.Categorical(["a", "b"]), "f": [1.5, np.nan]}),  # pandas' own path
    ]
    for df in tables:
        assert csv_text(df) == df.to_csv(index=False, float_format="%.10g")
    assert csv_text(tables[2], float_format="%.3f") == tables[2].to_csv(index=False, float_format="%.3f")
