"""Bad and awkward inputs: every case asserts the exit code, a one-line message that names the
file, row, key or flag, and that no output was created and no existing file changed.

Interrupts: SIGINT/SIGTERM sent at random moments of `fit`, `diagnose`, `extract` and `run` never
leave a truncated or half-committed output and never exit 0 while the command was still working.
"""

from __future__ import annotations

import errno
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from jaxdefl.cli import main
from jaxdefl.fit import STATUSES
from jaxdefl.io import read_trajectory, write_trajectory
from jaxdefl.synthetic import harmonic_experiment

TMP = ".jaxdefl-tmp-"


def snapshot(root: Path) -> dict[str, bytes]:
    """Every file under ``root`` (relative name -> bytes): nothing created, nothing changed."""
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def no_temporaries(root: Path) -> bool:
    return not [p for p in root.rglob(f"{TMP}*")]


@pytest.fixture(scope="module")
def tables(tmp_path_factory):
    d = tmp_path_factory.mktemp("bad")
    traj, lds = harmonic_experiment(duration_s=60.0, seed=11)
    traj = traj[traj["plate"].isin([3, 5, 7])]
    write_trajectory(traj, d / "traj.csv")
    write_trajectory(lds[lds["plate"].isin([5, 7])], d / "lds.csv")
    return d


@pytest.fixture
def work(tables, tmp_path):
    """A directory with the tables and a previous good fit (EST.csv + EST.json)."""
    for name in ("traj.csv", "lds.csv"):
        (tmp_path / name).write_bytes((tables / name).read_bytes())
    assert main(["fit", str(tmp_path / "traj.csv"), "--out", str(tmp_path / "EST.csv")]) == 0
    return tmp_path


def run_cli(args, capsys) -> tuple[int, list[str]]:
    capsys.readouterr()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        code = main([str(a) for a in args])
    text = capsys.readouterr().err
    # numeric noise (NaN windows, empty slices) never reaches the user: statuses say it
    assert not [w for w in caught if issubclass(w.category, RuntimeWarning)], [str(w.message) for w in caught]
    assert "Traceback" not in text, text
    err = [line for line in text.splitlines() if line.startswith("jaxdefl: ")]
    return code, err


def assert_refused(work, capsys, args, message, code=2):
    before = snapshot(work)
    got, err = run_cli(args, capsys)
    assert got == code, err
    assert len(err) == 1, err
    assert message in err[0], err[0]
    assert "np.float64" not in err[0] and "Traceback" not in err[0]
    assert snapshot(work) == before
    assert no_temporaries(work)


# -- arguments are checked before anything is written ------------------------------------------


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--posterior", "-3"], "--posterior: expected a number of windows >= 0, got -3"),
        (["--window", "1e-5"], "--window 1e-05: shorter than 8 frame intervals"),
        (["--window", "nan"], "--window: expected a finite number, got nan"),
        (["--window", "30", "--step", "1e-6"], "would need"),
        (["--oversampling", "0.5"], "--oversampling: expected a factor >= 1, got 0.5"),
        (["--fmin", "2", "--fmax", "1"], "--fmin/--fmax: expected fmin < fmax, got 2 and 1"),
        (["--fap-max", "2"], "--fap-max: expected a probability in (0, 1], got 2"),
    ],
)
def test_fit_bad_arguments_leave_previous_outputs(work, capsys, extra, message):
    assert_refused(work, capsys, ["fit", work / "traj.csv", "--out", work / "EST.csv", *extra], message)


def test_fit_bad_reference_is_refused_before_writing(work, capsys):
    args = ["fit", work / "traj.csv", "--out", work / "EST.csv", "--reference"]
    assert_refused(work, capsys, [*args, work / "missing.csv"], "missing.csv: file not found")
    pd.DataFrame({"t": [1.7e9, 1.7e9 + 1], "plate": [99, 99], "z": [0.0, 1.0]}).to_csv(
        work / "other.csv", index=False
    )
    assert_refused(work, capsys, [*args, work / "other.csv"], "no plate of the reference (plates 99)")


def test_output_collisions_are_refused(work, capsys):
    traj = work / "traj.csv"
    assert_refused(work, capsys, ["fit", traj, "--out", traj], "is an input of this command")
    assert_refused(work, capsys, ["fit", traj, "--out", work / "est.json"], "expected a name ending in .csv")
    # EST.csv's sidecar is EST.json: an input named EST.json must not be overwritten by it
    (work / "x.json").write_text("{}")
    (work / "x.csv").write_bytes(traj.read_bytes())
    assert_refused(work, capsys, ["fit", work / "x.json", "--out", work / "x.csv"], "x.json")
    assert_refused(work, capsys, ["diagnose", traj, "--out", work / "d.md"], "--out " + str(work / "d.md"))
    assert_refused(
        work,
        capsys,
        ["fit", traj, "--out", work / "traj_in.csv", "--reference", work / "traj_in_reference.csv"],
        "traj_in_reference.csv: is an input of this command",
    )
    (work / "E_reference.csv").write_bytes(traj.read_bytes())
    assert_refused(
        work,
        capsys,
        ["fit", work / "E_reference.csv", "--out", work / "E.csv", "--reference", work / "lds.csv"],
        "is an input of this command",
    )


def test_parquet_out_is_parquet(work, capsys):
    code, _ = run_cli(["fit", work / "traj.csv", "--out", work / "e.parquet", "--window", "20"], capsys)
    assert code == 0
    pq = pd.read_parquet(work / "e.parquet")
    assert run_cli(["fit", work / "traj.csv", "--out", work / "e.csv", "--window", "20"], capsys)[0] == 0
    csv = pd.read_csv(work / "e.csv")
    assert list(pq.columns) == list(csv.columns)
    np.testing.assert_allclose(pq["amplitude_mm"], csv["amplitude_mm"], rtol=1e-9)


# -- table contents: true/false columns, row numbers, units, timestamp policy ------------------


@pytest.mark.parametrize("col", ["z", "x", "t", "plate"])
def test_a_true_false_column_is_refused_naming_it(work, capsys, col):
    df = pd.read_csv(work / "traj.csv")
    df[col] = df.index % 2 == 0
    df.to_parquet(work / "b.parquet")
    assert_refused(
        work,
        capsys,
        ["fit", work / "b.parquet", "--out", work / "EST.csv"],
        f"b.parquet: column '{col}' holds true/false",
    )


def test_parquet_rows_count_from_1_and_values_are_plain(work, capsys):
    df = pd.read_csv(work / "traj.csv")
    df["plate"] = df["plate"].astype(float)
    df.loc[2, "plate"] = 2.5  # the third data row
    df.to_parquet(work / "p.parquet")
    df.to_csv(work / "p.csv", index=False)
    args = ["fit", None, "--out", work / "EST.csv"]
    msg = "column 'plate': expected an integer plate number, got 2.5"
    assert_refused(work, capsys, [args[0], work / "p.parquet", *args[2:]], f"p.parquet: row 3 {msg}")
    assert_refused(work, capsys, [args[0], work / "p.csv", *args[2:]], f"p.csv: row 4 {msg}")


def test_implausible_units_are_refused_naming_the_likely_unit(work, capsys):
    df = pd.read_csv(work / "traj.csv")
    df.assign(t=df["t"] * 1000).to_csv(work / "ms.csv", index=False)
    assert_refused(
        work,
        capsys,
        ["fit", work / "ms.csv", "--out", work / "EST.csv"],
        "epoch milliseconds? rename the column t_ms",
    )
    df.assign(z=df["z"] / 1000.0).to_csv(work / "m.csv", index=False)  # camera ranges in metres
    assert_refused(
        work,
        capsys,
        ["diagnose", work / "m.csv", "--out", work / "d.json"],
        "metres, not mm? rename the column z_m",
    )


def test_timestamp_policy_errors(work, capsys):
    df = pd.read_csv(work / "traj.csv")
    rows = df[df["plate"] == 5].iloc[[10]].assign(z=0.0)
    pd.concat([df, rows]).sort_index(kind="stable").to_csv(work / "dup.csv", index=False)
    args = ["fit", work / "dup.csv", "--out", work / "EST.csv"]
    assert_refused(work, capsys, args, "with different values (1 such rows); rerun with --timestamps reclock")
    bogus = [*args, "--timestamps", "bogus"]
    assert_refused(work, capsys, bogus, "--timestamps: expected one of strict, reclock, merge")
    assert_refused(
        work, capsys, ["run", work / "c.toml", "--timestamps", "later"], "--timestamps: expected one of"
    )
    (work / "c.toml").write_text(
        '[processing]\ntimestamps = "later"\n'
        '[[recording]]\nday = 1\ncamera = "c"\ntrajectories = "traj.csv"\n'
    )
    assert_refused(
        work,
        capsys,
        ["run", work / "c.toml", "--out", work / "o"],
        "key 'processing.timestamps': expected one of",
    )


# -- epoch precision --------------------------------------------------------------------------


def test_epoch_times_keep_microseconds_and_the_phase_rebuilds(tmp_path, capsys):
    """t_start 1700000000.123456 survives the CSV; the model rebuilt from the file's t_mid,
    f0, A, phase and offset matches the fit's own residual level on the data."""
    traj, _ = harmonic_experiment(duration_s=60.0, seed=5, t0=1700000000.123456, dropout=0.0)
    traj = traj[traj["plate"] == 7]
    write_trajectory(traj, tmp_path / "t.csv")
    assert run_cli(["fit", tmp_path / "t.csv", "--out", tmp_path / "e.csv", "--axes", "z"], capsys)[0] == 0
    text = (tmp_path / "e.csv").read_text()
    assert "1700000000.123456" in text
    e = pd.read_csv(tmp_path / "e.csv").iloc[0]
    back = read_trajectory(tmp_path / "t.csv")
    assert abs(e["t_start"] - back["t"].min()) < 1e-6
    t_mid = 0.5 * (e["t_start"] + e["t_end"])
    model = e["offset_mm"] + e["amplitude_mm"] * np.cos(
        2 * np.pi * e["f0_hz"] * (back["t"].to_numpy() - t_mid) - e["phase_rad"]
    )
    rms = np.sqrt(np.mean((back["z"].to_numpy() - model) ** 2))
    assert rms < 1.05 * e["sigma_residual_mm"]


# -- one bad plate or window never stops the rest ---------------------------------------------


def test_a_plate_without_valid_z_gets_a_status(work, capsys):
    df = pd.read_csv(work / "traj.csv")
    one = pd.DataFrame(
        {"segment": [df["segment"].iloc[0]], "t": [df["t"].iloc[0]], "plate": [42], "z": [np.nan]}
    )
    pd.concat([df, one]).to_csv(work / "t2.csv", index=False)
    assert run_cli(["fit", work / "t2.csv", "--out", work / "e2.csv"], capsys)[0] == 0
    e = pd.read_csv(work / "e2.csv")
    assert set(e.loc[e["plate"] == 42, "status"]) == {"too_few_samples"}
    assert (e.loc[(e["plate"] != 42) & (e["axis"] == "z"), "status"] == "converged").all()
    code, err = run_cli(["diagnose", work / "t2.csv", "--out", work / "d2.json", "--no-figures"], capsys)
    assert code == 0, err
    d = json.loads((work / "d2.json").read_text())
    assert {"plate": 42, "axis": "z", "status": "too_few_samples", "n": 0} in d["left_out"]


def test_an_overflowing_value_is_a_window_status(work, capsys):
    df = pd.read_csv(work / "traj.csv")
    i = df.index[df["plate"] == 5][50]
    df.loc[i, "z"] = 1e308
    df.to_csv(work / "big.csv", index=False)
    assert run_cli(["fit", work / "big.csv", "--out", work / "e3.csv", "--window", "20"], capsys)[0] == 0
    e = pd.read_csv(work / "e3.csv").set_index(["plate", "axis", "window"])
    assert e.loc[(5, "z", 0), "status"] == "value_out_of_range"
    assert e.loc[(5, "z", 1), "status"] == "converged" and e.loc[(7, "z", 0), "status"] == "converged"
    code, err = run_cli(["diagnose", work / "big.csv", "--out", work / "d3.json", "--no-figures"], capsys)
    assert code == 0, err
    left = json.loads((work / "d3.json").read_text())["left_out"]
    assert any(x["plate"] == 5 and x["axis"] == "z" and x["status"] == "value_out_of_range" for x in left)


def test_diagnose_refuses_a_reference_with_no_shared_plate(work, capsys):
    pd.DataFrame({"t": [1.7e9, 1.7e9 + 1], "plate": [99, 99], "z": [0.0, 1.0]}).to_csv(
        work / "other.csv", index=False
    )
    args = ["diagnose", work / "traj.csv", "--out", work / "d.json", "--reference", work / "other.csv"]
    assert_refused(work, capsys, args, "other.csv: no plate of the reference (99)")


# -- files that cannot be read, commands that cannot finish -----------------------------------


def test_simulate_with_a_directory_as_config(tmp_path, capsys):
    (tmp_path / "cfgdir").mkdir()
    assert_refused(
        tmp_path, capsys, ["simulate", tmp_path / "cfgdir", "--out", tmp_path / "o"], "cfgdir: is a directory"
    )


def test_extract_with_a_corrupt_zarr_json(tmp_path, capsys):
    store = tmp_path / "r.zarr"
    store.mkdir()
    (store / "zarr.json").write_text("{garbage")
    assert_refused(
        tmp_path, capsys, ["extract", store, "--out", tmp_path / "t.csv"], "zarr.json: not valid JSON"
    )


def test_extract_refuses_output_in_the_recording_or_a_bad_suffix(tmp_path, capsys):
    store = tmp_path / "r.zarr"
    store.mkdir()
    assert_refused(
        tmp_path, capsys, ["extract", store, "--out", store / "t.csv"], "lies inside the recording"
    )
    assert_refused(
        tmp_path, capsys, ["extract", store, "--out", tmp_path / "t.json"], "expected a name ending"
    )


def test_run_exits_1_when_a_unit_failed(tmp_path, capsys):
    traj, lds = harmonic_experiment(duration_s=30.0, seed=2)
    write_trajectory(traj[traj["plate"].isin([5, 7])], tmp_path / "traj1.csv")
    (tmp_path / "c.toml").write_text(
        '[campaign]\nname = "t"\n[processing]\nwindow_s = 15.0\n'
        '[[recording]]\nday = 1\ncamera = "cam2"\ncycles = 1\ntrajectories = "traj1.csv"\n'
        '[[recording]]\nday = 2\ncamera = "cam2"\ncycles = 2\ntrajectories = "nowhere.csv"\n'
    )
    code, err = run_cli(["run", tmp_path / "c.toml", "--out", tmp_path / "o"], capsys)
    assert code == 1
    assert len(err) == 1 and "1 of 2 units failed (first: day02-cam2" in err[0] and "nowhere.csv" in err[0]
    assert (tmp_path / "o" / "report.md").exists()


def test_a_full_disk_keeps_the_previous_outputs(work, capsys, monkeypatch):
    """ENOSPC while a temporary file is written: exit 1, the output named, nothing replaced."""
    real = Path.write_bytes

    def full(self, data):
        if self.name.startswith(TMP):
            real(self, data[: len(data) // 3])
            raise OSError(errno.ENOSPC, "No space left on device", str(self))
        return real(self, data)

    monkeypatch.setattr(Path, "write_bytes", full)
    assert_refused(
        work,
        capsys,
        ["fit", work / "traj.csv", "--out", work / "EST.csv", "--window", "20"],
        f"{work / 'EST.csv'}: cannot write (No space left on device)",
        code=1,
    )


# -- fuzz: any table content ends in a status or a one-line error -----------------------------

CELLS = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(-(10**20), 10**20),
    st.sampled_from(["", "nan", "abc", "1e308", "-0", "1,5", " 3 ", "True", "2024-01-01"]),
)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(rows=st.lists(st.tuples(CELLS, st.sampled_from([1, 2, 2.5, "x", ""]), CELLS), min_size=0, max_size=40))
def test_fuzzed_tables_end_in_a_status_or_one_line(tmp_path, capsys, rows):
    d = tmp_path / f"f{abs(hash(str(rows))) % 10**9}"
    d.mkdir()
    lines = ["t,plate,z"] + [",".join(str(c) for c in r) for r in rows]
    (d / "t.csv").write_text("\n".join(lines) + "\n")
    before = snapshot(d)
    code, err = run_cli(["fit", d / "t.csv", "--out", d / "e.csv"], capsys)
    assert code in (0, 2), err
    if code == 2:
        assert len(err) == 1 and str(d / "t.csv") in err[0], err
        assert snapshot(d) == before
    else:
        e = pd.read_csv(d / "e.csv")
        assert set(e["status"]) <= set(STATUSES)
    assert no_temporaries(d)


# -- interrupts -------------------------------------------------------------------------------


def _interrupt(args, cwd: Path, delay: float | None, sig=signal.SIGINT):
    """Start the CLI, send ``sig`` after ``delay`` s; returns (exit code, stderr, sent in time)."""
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen(
        [sys.executable, "-m", "jaxdefl.cli", *map(str, args)],
        cwd=cwd,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    if delay is None:  # an uninterrupted run
        _, err = proc.communicate(timeout=600)
        return proc.returncode, err.decode(), False
    time.sleep(delay)
    running = proc.poll() is None
    if running:
        proc.send_signal(sig)
    _, err = proc.communicate(timeout=300)
    return proc.returncode, err.decode(), running


def _restore(work: Path, state: dict[str, bytes], outputs: list[str]) -> None:
    for name in outputs:
        p = work / name
        if name in state:
            p.parent.mkdir(parents=True, exist_ok=True)
            p.write_bytes(state[name])
        elif p.exists():
            p.unlink()


def _whole_and_new(after: dict, ref: dict, name: str) -> bool:
    if name.endswith((".json", ".md")):  # carry the time they were written
        return bool(after.get(name))
    return after.get(name) == ref.get(name)


def _check_interrupt(work: Path, old_args, args, outputs: list[str], delays, sig=signal.SIGINT):
    """``old_args`` make the previous outputs; ``args`` is interrupted after each delay.

    ``delays`` are seconds, each sent ``sig``, or (seconds, signal) pairs: one uninterrupted
    reference run then serves several signals. After every attempt the outputs are all the
    previous ones byte for byte, or all new and whole (equal to an uninterrupted run's); the
    exit code is 128 + signal (or death by the signal itself, before the CLI installed its
    handler, with nothing written); 0 only when the command had already finished."""
    ref_dir = Path(tempfile.mkdtemp(dir=work.parent, prefix=work.name + "-ref-"))
    shutil.copytree(work, ref_dir, dirs_exist_ok=True)
    code, err, _ = _interrupt(args, ref_dir, None)  # never sent: an uninterrupted run
    assert code == 0, err
    ref = snapshot(ref_dir)
    code, err, _ = _interrupt(old_args, work, None)
    assert code == 0, err
    baseline = snapshot(work)
    for delay in delays:
        delay, sig = delay if isinstance(delay, tuple) else (delay, sig)
        expected = 128 + int(sig)
        _restore(work, baseline, outputs)
        code, err, sent = _interrupt(args, work, delay, sig)
        after = snapshot(work)
        assert no_temporaries(work), (delay, args, list(work.rglob(f"{TMP}*")))
        old = [after.get(n) == baseline.get(n) for n in outputs]
        new = [_whole_and_new(after, ref, n) for n in outputs]
        assert all(old) or all(new), (delay, old, new, err)
        if not sent or code == 0:  # finished before the signal
            assert all(new), (delay, sent, code, old, new, err)
            continue
        if code == -int(sig):
            # killed by the signal's default action, outside the command (before the CLI
            # installed its handler, or after it returned): outputs all old or all new (above)
            continue
        assert code == expected, (delay, code, err)
        lines = [x for x in err.splitlines() if x.startswith("jaxdefl: ")]
        assert lines and "interrupted" in lines[-1], err
        if "whole and new" not in lines[-1]:
            assert all(old), (delay, err)


FIT = ["fit", "traj.csv", "--out", "EST.csv", "--reference", "lds.csv"]


def test_sigint_during_fit_never_half_commits(work):
    rng = np.random.default_rng(0)
    _check_interrupt(
        work,
        [*FIT, "--window", "20", "--posterior", "1"],
        [*FIT, "--window", "10", "--posterior", "1"],
        ["EST.csv", "EST.json", "EST_reference.csv", "EST_comparison.csv", "EST_uncertainty.csv"],
        delays=sorted(rng.uniform(0.5, 8.0, 3)),
    )


@pytest.mark.slow
def test_interrupts_at_random_moments_of_every_command(work):
    # SIGINT and SIGTERM take the same handler: each command's random moments alternate between
    # them, against one uninterrupted reference run (two runs of every command per signal before)
    rng = np.random.default_rng(2)

    def moments(lo: float, hi: float, k: int) -> list[tuple[float, int]]:
        sigs = (signal.SIGINT, signal.SIGTERM)
        return [(float(d), sigs[i % 2]) for i, d in enumerate(sorted(rng.uniform(lo, hi, k)))]

    _check_interrupt(
        work,
        [*FIT, "--window", "20", "--posterior", "2"],
        [*FIT, "--window", "10", "--posterior", "2"],
        ["EST.csv", "EST.json", "EST_reference.csv", "EST_comparison.csv", "EST_uncertainty.csv"],
        delays=moments(0.3, 10.0, 3),
    )
    _check_interrupt(
        work,
        ["diagnose", "traj.csv", "--out", "D.json", "--effects", "drift", "--no-figures"],
        ["diagnose", "traj.csv", "--out", "D.json"],
        ["D.json", "D.md"],
        delays=moments(0.3, 12.0, 2),
    )
    # extract: a small simulated recording
    from jaxdefl.simulate import simulate_to_dir

    cfg = Path(__file__).resolve().parents[1] / "configs" / "exp2_tof_3hz.toml"
    simulate_to_dir(cfg, work / "sim", duration_s=20.0, progress=False)
    _check_interrupt(
        work,
        ["extract", "sim/recording.zarr", "--out", "T.csv", "--realtime"],
        ["extract", "sim/recording.zarr", "--out", "T.csv"],
        ["T.csv"],
        delays=moments(0.3, 8.0, 2),
    )
    _check_interrupt(
        work,
        ["simulate", str(cfg), "--out", "sim2", "--duration", "10", "--session", "day1"],
        ["simulate", str(cfg), "--out", "sim2", "--duration", "20", "--session", "day1"],
        ["sim2/truth.csv", "sim2/lds.csv", "sim2/config.json"],
        delays=moments(0.3, 8.0, 2),
    )


@pytest.mark.slow
def test_sigint_during_run_exits_130_and_resumes(tmp_path):
    from test_bulk import make_campaign

    cfg = make_campaign(tmp_path, days=6, duration_s=30.0)
    out = tmp_path / "o"
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen(
        [sys.executable, "-m", "jaxdefl.cli", "run", str(cfg), "--out", str(out)],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    deadline = time.time() + 240
    while time.time() < deadline:
        if len(list(out.glob("units/*/manifest.json"))) >= 2:
            break
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err.decode()
    assert "run the same command again to resume" in err.decode()
    done = {p.parent.name for p in out.glob("units/*/manifest.json")}
    assert 2 <= len(done) < 6
    assert not list(out.rglob(f"{TMP}*"))
    assert main(["run", str(cfg), "--out", str(out)]) == 0
    units = pd.read_csv(out / "units.csv").set_index("unit")
    assert all(units.loc[u, "skipped"] for u in done)


# -- duplicates, windows longer than the record, campaign plates (issue 25 item 4) --------------


@pytest.mark.parametrize("axes", ["z,z", "z,x,z", "y, y"])
def test_a_duplicated_axis_is_refused(work, capsys, axes):
    args = ["fit", work / "traj.csv", "--out", work / "EST.csv", "--axes", axes]
    assert_refused(work, capsys, args, "--axes: names ")


@pytest.mark.parametrize("header", ["t,plate,z,x,z", "t,plate,z,plate", "t,t,plate,z"])
def test_a_duplicated_column_is_refused_naming_file_and_column(work, capsys, header):
    bad = work / "dup.csv"
    names = header.split(",")
    rows = "\n".join(",".join(str(0.05 * i if n == "t" else 1) for n in names) for i in range(20))
    bad.write_text(header + "\n" + rows + "\n")
    twice = next(n for n in names if names.count(n) > 1)
    first, second = [i + 1 for i, n in enumerate(names) if n == twice]
    message = f"dup.csv: column {twice!r} appears twice in the header (columns {first} and {second})"
    assert_refused(work, capsys, ["fit", bad, "--out", work / "EST.csv"], message)


def test_a_window_longer_than_the_record_is_clipped_and_said(work, capsys):
    traj = read_trajectory(work / "traj.csv")
    span = traj["t"].max() - traj["t"].min()
    capsys.readouterr()
    out = work / "long.csv"
    assert main(["fit", str(work / "traj.csv"), "--out", str(out), "--window", "3000", "--axes", "z"]) == 0
    said = capsys.readouterr().err
    assert "--window 3000 s is longer than segment 'day1' (60 s)" in said and "clipped" in said
    est = pd.read_csv(out)
    assert (est["window"] == 0).all()
    dt = np.median(np.diff(np.unique(traj["t"])))
    t0 = traj["t"].min()
    # the window is the record: its bounds and the phase's reference time come from the data
    assert np.allclose(est["t_start"], t0, atol=1e-6)
    assert np.allclose(est["t_end"], t0 + span + dt, atol=1e-6)
    whole = work / "whole.csv"
    assert main(["fit", str(work / "traj.csv"), "--out", str(whole), "--axes", "z"]) == 0
    ref = pd.read_csv(whole)
    # the clipped window fits the same samples as the whole-record fit
    assert (est["n"].to_numpy() == ref["n"].to_numpy()).all()
    assert np.allclose(est["amplitude_mm"], ref["amplitude_mm"], rtol=1e-6)


def _campaign(tmp: Path, tables: Path, processing: str) -> Path:
    shutil.copy(tables / "traj.csv", tmp / "traj.csv")
    (tmp / "campaign.toml").write_text(
        f'[campaign]\nname = "c"\n[processing]\n{processing}\n'
        '[[recording]]\nday = 1\ncamera = "cam"\ncycles = 0\ntrajectories = "traj.csv"\n'
    )
    return tmp / "campaign.toml"


@pytest.mark.parametrize(
    "processing, message",
    [
        ("reference_plate = 42", "key 'processing.reference_plate': plate 42 has no position"),
        ("reference_plate = 0", "key 'processing.reference_plate': plate 0 has no position"),
        (
            "plate_x_mm = [200.0, 450.0, 700.0]\nreference_plate = 3",
            "key 'processing.plate_x_mm': has 3 plate positions, but the recordings have plates 3, 5, 7",
        ),
        (
            "reference_plate = 2",
            "key 'processing.reference_plate': plate 2 is in no recording (plates 3, 5, 7)",
        ),
    ],
)
def test_campaign_plate_keys_are_config_errors_before_any_campaign_output(
    tables, tmp_path, capsys, processing, message
):
    cfg = _campaign(tmp_path, tables, processing)
    out = tmp_path / "out"
    code, err = run_cli(["run", cfg, "--out", out], capsys)
    assert code == 2 and len(err) == 1 and message in err[0], err
    assert "campaign.toml" in err[0]
    # no campaign table, dataset or report: at most the finished units, kept for a rerun
    made = {p.name for p in out.iterdir()} if out.exists() else set()
    assert made <= {"units"}, made


def test_simulated_campaign_checks_plates_against_its_simulation(tmp_path, capsys):
    cfg = tmp_path / "c.toml"
    cfg.write_text(
        "[processing]\nplate_x_mm = [200.0, 450.0]\nreference_plate = 2\n"
        '[simulate]\nconfig = "exp2_tof_3hz"\nduration_s = 5.0\n'
    )
    code, err = run_cli(["run", cfg, "--out", tmp_path / "out"], capsys)
    assert code == 2 and "key 'processing.plate_x_mm': has 2 plate positions" in err[0], err
    assert not (tmp_path / "out").exists()
