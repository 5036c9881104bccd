"""Reliability under concurrent commands, damaged stores, killed runs and hostile sizes.

- One command per output: a second one on the same --out exits 2 naming the holder, or waits
  with --wait; a killed holder's lock is stale and taken over; two `run`s started at random
  moments on one campaign folder never leave a partial results.zarr.
- A Zarr recording with a missing or truncated chunk, or without an array the reader needs, is
  an error naming the array and the frames, never fill values.
- A resume removes the temporary files of killed commands.
- Every flag or key that sizes work is bounded by an estimate made before the work: simulate
  durations and chunks (memory and disk), fit --oversampling (memory).
- Echoed input is cut: a CSV padded with zero bytes gives a short message.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from jaxdefl._errors import MESSAGE_CHARS, ParameterError, echo, one_line
from jaxdefl._resources import MEMORY_BUDGET_BYTES
from jaxdefl.cli import main
from jaxdefl.io import write_trajectory
from jaxdefl.io.lock import OutputLocked, lock_path, output_lock
from jaxdefl.io.recording import open_recording

ROOT = Path(__file__).resolve().parents[1]
TOF = ROOT / "configs" / "exp2_tof_3hz.toml"
TMP = ".jaxdefl-tmp-"
PY = [sys.executable, "-m", "jaxdefl.cli"]


def run_cli(args, capsys) -> tuple[int, list[str]]:
    capsys.readouterr()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        code = main([str(a) for a in args])
    text = capsys.readouterr().err
    assert "Traceback" not in text, text
    return code, [line for line in text.splitlines() if line.startswith("jaxdefl: ")]


def files(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def table(tmp_path_factory):
    from conftest import harmonic_table

    d = tmp_path_factory.mktemp("rel")
    write_trajectory(harmonic_table(n_plates=2, duration_s=60.0), d / "traj.csv")
    return d / "traj.csv"


@pytest.fixture
def work(table, tmp_path):
    shutil.copy(table, tmp_path / "traj.csv")
    return tmp_path


def _spawn_holder(out: Path, hold_s: float) -> subprocess.Popen:
    """A process that takes OUT's lock, says so on stdout and holds it for ``hold_s`` s."""
    code = (
        "import sys, time\n"
        "from jaxdefl.io.lock import output_lock\n"
        f"with output_lock({str(out)!r}, command='jaxdefl holder'):\n"
        "    print('held', flush=True)\n"
        f"    time.sleep({hold_s})\n"
        "print('released', flush=True)\n"
    )
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "held"
    return proc


# -- locks ------------------------------------------------------------------------------------


def test_a_second_command_on_a_held_output_exits_2_naming_the_holder(work, capsys):
    out = work / "EST.csv"
    with output_lock(out, command="jaxdefl fit"):
        before = files(work)
        code, err = run_cli(["fit", work / "traj.csv", "--out", out], capsys)
        assert code == 2 and len(err) == 1, err
        assert f"pid {os.getpid()}" in err[0] and "jaxdefl fit" in err[0] and "since" in err[0], err[0]
        assert "--wait" in err[0]
        assert files(work) == before  # nothing written, the holder's lock untouched
    assert not lock_path(out).exists()  # released
    assert run_cli(["fit", work / "traj.csv", "--out", out], capsys)[0] == 0
    assert not lock_path(out).exists()


def test_a_companion_shares_its_outputs_lock(work):
    """``EST.csv`` and ``EST.json`` (fit's sidecar, also a diagnose --out) are one lock."""
    assert lock_path(work / "EST.csv") == lock_path(work / "EST.json")
    with output_lock(work / "EST.csv"), pytest.raises(OutputLocked, match="in use by"):
        with output_lock(work / "EST.json"):
            pass
    with output_lock(work / "A.csv"), output_lock(work / "B.csv"):  # other outputs: no conflict
        pass


def test_wait_waits_for_the_holder(work, capsys):
    out = work / "EST.csv"
    holder = _spawn_holder(out, 1.5)
    try:
        code, err = run_cli(["fit", work / "traj.csv", "--out", out, "--wait"], capsys)
        assert holder.stdout.readline().strip() == "released"  # the fit waited for it
    finally:
        holder.kill()
        holder.wait()
    assert code == 0, err
    assert any("waiting for" in e and "jaxdefl holder" in e for e in err), err
    assert (work / "EST.csv").exists()


def test_the_lock_of_a_killed_process_is_stale_and_taken_over(work, capsys):
    out = work / "sim"
    holder = _spawn_holder(out, 60)
    holder.send_signal(signal.SIGKILL)  # no cleanup: the lock file stays with its pid
    holder.wait()
    assert lock_path(out).exists()
    assert json.loads(lock_path(out).read_text())["pid"] == holder.pid
    with output_lock(out, command="jaxdefl next") as path:
        assert json.loads(path.read_text())["command"] == "jaxdefl next"
    assert not lock_path(out).exists()
    # a leftover lock file naming a pid that is gone (no flock held) is taken over, and said
    est = work / "EST.csv"
    lock_path(est).write_text(json.dumps({"pid": holder.pid, "host": os.uname().nodename}))
    code, err = run_cli(["fit", work / "traj.csv", "--out", est], capsys)
    assert code == 0 and any(f"cleared the stale lock of jaxdefl (pid {holder.pid}" in e for e in err), err
    assert est.exists() and not lock_path(est).exists()


def test_a_refused_lock_leaves_no_folder(tmp_path):
    out = tmp_path / "a" / "b" / "EST.csv"
    with output_lock(out):
        assert lock_path(out).parent == (tmp_path / "a" / "b").resolve()
    assert not (tmp_path / "a").exists()  # made for the lock only, removed with it


@pytest.mark.slow
def test_concurrent_runs_at_random_moments_never_leave_a_partial_store(tmp_path):
    """Two `run`s on one folder, the second started 0-3 s after the first: one exits 2 naming
    the other (or, with --wait, the waiting one finishes); results.zarr always has every
    variable."""
    import xarray as xr
    from test_bulk import make_campaign

    cfg = make_campaign(tmp_path, days=2, duration_s=30.0)
    ref = tmp_path / "ref"
    assert subprocess.run([*PY, "run", cfg, "--out", ref], capture_output=True).returncode == 0
    with xr.open_zarr(ref / "results.zarr") as ds:
        want = set(ds.data_vars)
    rng = np.random.default_rng(25)
    for trial, wait in enumerate((False, False, True)):
        out = tmp_path / f"o{trial}"
        first = subprocess.Popen([*PY, "run", cfg, "--out", out], stderr=subprocess.PIPE, text=True)
        time.sleep(rng.uniform(0.0, 3.0))
        second = subprocess.Popen(
            [*PY, "run", cfg, "--out", out, *(["--wait"] if wait else [])], stderr=subprocess.PIPE, text=True
        )
        codes = [p.wait(timeout=600) for p in (first, second)]
        errs = [p.stderr.read() for p in (first, second)]
        if wait:
            # the one that waits always finishes; the first, which does not wait, is refused
            # only if it took longer to start than the second took to take the lock (under load)
            assert codes[1] == 0, errs
            assert codes[0] == 0 or (codes[0] == 2 and "in use by jaxdefl run (pid" in errs[0]), errs
        else:
            assert sorted(codes) == [0, 2], errs
            refused = errs[codes.index(2)]
            assert "in use by jaxdefl run (pid" in refused, refused
        with xr.open_zarr(out / "results.zarr") as ds:
            assert set(ds.data_vars) == want
        assert not list(out.rglob(f"{TMP}*")) and not list(out.rglob(".*.zarr.tmp"))
        assert not lock_path(out).exists()


# -- resume: the temporaries of killed commands ------------------------------------------------


def test_a_resumed_run_removes_the_temporaries_of_killed_units(tmp_path, capsys):
    from test_bulk import make_campaign

    cfg = make_campaign(tmp_path, days=1, duration_s=30.0)
    out = tmp_path / "o"
    assert run_cli(["run", cfg, "--out", out], capsys)[0] == 0
    unit = next(out.glob("units/*"))
    planted = [
        unit / f"{TMP}0123abcd-whole.csv",
        out / f"{TMP}0123abcd-report.md",
        out / ".results.zarr.tmp" / "zarr.json",
        out / f"{TMP}demo-x" / "simulation" / "recording.zarr" / "c" / "0",
    ]
    for p in planted:
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_bytes(b"\0" * 1000)
    assert run_cli(["run", cfg, "--out", out], capsys)[0] == 0
    assert not list(out.rglob(f"{TMP}*")) and not (out / ".results.zarr.tmp").exists()
    units = pd.read_csv(out / "units.csv")
    assert units["skipped"].all()  # finished units are kept


def test_a_file_output_removes_only_its_own_temporaries(work, capsys):
    mine = [work / f"{TMP}0123abcd-EST.csv", work / f"{TMP}0123abcd-EST_reference.csv"]
    others = [work / f"{TMP}0123abcd-OTHER.csv", work / f"{TMP}0123abcd-EST2.csv"]
    for p in mine + others:
        p.write_text("partial")
    assert run_cli(["fit", work / "traj.csv", "--out", work / "EST.csv"], capsys)[0] == 0
    assert not any(p.exists() for p in mine)
    assert all(p.exists() for p in others)  # another command's, under another lock


def test_the_sweep_spares_a_folder_where_another_command_writes(tmp_path):
    out = tmp_path / "o"
    (out / "sub").mkdir(parents=True)
    dead = [out / f"{TMP}0123abcd-x.csv", out / ".results.zarr.tmp", out / ".notes.tmp"]
    alive = out / "sub" / f"{TMP}0123abcd-EST.csv"
    holder = _spawn_holder(out / "sub" / "EST.csv", 60)  # a fit writing into OUT/sub now
    for p in [*dead, alive]:
        p.write_text("x")
    try:
        with output_lock(out):
            pass
    finally:
        holder.kill()
        holder.wait()
    assert [p.exists() for p in dead] == [False, False, True]  # a user's own .tmp file is kept
    assert alive.exists()


@pytest.mark.slow
def test_a_sigkilled_run_resumes_without_its_temporaries(tmp_path):
    from test_bulk import make_campaign

    cfg = make_campaign(tmp_path, days=4, duration_s=30.0)
    out = tmp_path / "o"
    proc = subprocess.Popen([*PY, "run", cfg, "--out", out], stderr=subprocess.DEVNULL)
    deadline = time.time() + 300
    while time.time() < deadline and not list(out.glob("units/*/manifest.json")):
        time.sleep(0.05)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    (out / "units" / "day09-cam2").mkdir(parents=True, exist_ok=True)
    (out / "units" / "day09-cam2" / f"{TMP}0123abcd-windows.csv").write_bytes(b"x" * 10_000)
    done = subprocess.run([*PY, "run", cfg, "--out", out], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert not list(out.rglob(f"{TMP}*"))
    assert not lock_path(out).exists()


# -- Zarr integrity ---------------------------------------------------------------------------


@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    """A 10-s ToF recording in chunks of 50 frames (4 chunks of range and amplitude)."""
    from jaxdefl.simulate import simulate_to_dir

    d = tmp_path_factory.mktemp("sim")
    text = TOF.read_text()
    assert "chunk_frames = 200" in text
    (d / "c.toml").write_text(text.replace("chunk_frames = 200", "chunk_frames = 50"))
    simulate_to_dir(d / "c.toml", d / "sim", duration_s=10.0, progress=False)
    return d


@pytest.fixture
def damaged(sim, tmp_path):
    shutil.copytree(sim / "sim", tmp_path / "sim")
    shutil.copy(sim / "c.toml", tmp_path / "c.toml")
    return tmp_path


def _chunk(store: Path, name: str, i: int) -> Path:
    p = store / name / "c" / str(i) / "0" / "0"
    assert p.is_file(), sorted(str(q) for q in (store / name).rglob("*"))
    return p


def _frames_of_chunk(store: Path, i: int) -> str:
    import zarr

    a = zarr.open_group(str(store), mode="r")["range"]
    c = a.chunks[0]
    return f"frames {i * c}..{min(a.shape[0], (i + 1) * c) - 1}"


@pytest.mark.parametrize("command", ["extract", "reconcile"])
def test_a_deleted_chunk_is_an_error_naming_array_and_frames(damaged, capsys, command):
    store = damaged / "sim" / "recording.zarr"
    _chunk(store, "range", 2).unlink()
    frames = _frames_of_chunk(store, 2)
    args = {
        "extract": ["extract", store, "--out", damaged / "t.csv"],
        "reconcile": ["reconcile", store, "--config", damaged / "c.toml", "--out", damaged / "r"],
    }[command]
    code, err = run_cli(args, capsys)
    assert code == 2 and len(err) == 1, err
    assert "array 'range'" in err[0] and frames in err[0] and "missing" in err[0], err[0]
    assert not (damaged / "t.csv").exists() and not (damaged / "r").exists()


def test_a_truncated_chunk_names_its_own_frames(damaged, capsys):
    store = damaged / "sim" / "recording.zarr"
    p = _chunk(store, "amplitude", 3)
    p.write_bytes(p.read_bytes()[:100])
    code, err = run_cli(["extract", store, "--out", damaged / "t.csv", "--chunk-frames", "64"], capsys)
    assert code == 2 and len(err) == 1, err
    # the batch of frames 192.. spans chunk 3 (150..199): the chunk is named, not the batch
    assert "array 'amplitude'" in err[0] and _frames_of_chunk(store, 3) in err[0], err[0]
    assert "truncated or corrupt" in err[0]


def test_a_missing_array_is_named(damaged, capsys):
    store = damaged / "sim" / "recording.zarr"
    shutil.rmtree(store / "amplitude")
    code, err = run_cli(["extract", store, "--out", damaged / "t.csv"], capsys)
    assert code == 2 and "missing array 'amplitude'" in err[0] and "geometry" not in err[0], err
    shutil.rmtree(store / "timestamps")
    code, err = run_cli(["extract", store, "--out", damaged / "t.csv"], capsys)
    assert code == 2 and "missing array 'timestamps'" in err[0], err


@pytest.mark.parametrize("zarr_format", [2, 3])
def test_every_stored_chunk_is_checked_in_both_formats(tmp_path, zarr_format):
    """A hand-made depth store: whole, it reads back exactly; each missing chunk of each array
    is named (never NaN frames), in Zarr v2 and v3 layouts."""
    import zarr

    rng = np.random.default_rng(0)
    depth = rng.uniform(900, 1100, (23, 6, 8)).astype(np.float32)
    t = 1.7e9 + np.arange(23) / 20.0
    store = tmp_path / "d.zarr"
    g = zarr.open_group(str(store), mode="w", zarr_format=zarr_format)
    g.attrs.update(fx=100.0, fy=100.0, cx=4.0, cy=3.0)
    g.create_array("depth", shape=depth.shape, chunks=(5, 6, 8), dtype="float32")[:] = depth
    g.create_array("timestamps", shape=t.shape, chunks=(10,), dtype="float64")[:] = t
    rec = open_recording(store)
    got = np.concatenate([c.frames for c in rec.chunks(7)])
    np.testing.assert_array_equal(got, depth)
    for name, a in (("depth", g["depth"]), ("timestamps", g["timestamps"])):
        for i in range(-(-a.shape[0] // a.chunks[0])):
            key = store / name / a.metadata.encode_chunk_key((i,) + (0,) * (a.ndim - 1))
            saved = key.read_bytes()
            key.unlink()
            lo, hi = i * a.chunks[0], min(a.shape[0], (i + 1) * a.chunks[0]) - 1
            with pytest.raises(
                Exception, match=rf"array '{name}': the chunk of frames {lo}\.\.{hi} is missing"
            ):
                open_recording(store)
            key.write_bytes(saved)
    assert open_recording(store).n_frames == 23


# -- sizes ------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "duration, message",
    [
        ("0", "--duration: expected a duration > 0 s, got 0"),
        ("-3", "--duration: expected a duration > 0 s, got -3"),
        ("1e9", "--duration 1e+09: 20,000,000,000 frames of 176x144 would need"),
        ("5e6", "--duration 5e+06: 100,000,000 frames of 176x144 would need"),
    ],
)
def test_simulate_durations_out_of_reach_are_refused(tmp_path, capsys, duration, message):
    code, err = run_cli(["simulate", TOF, "--out", tmp_path / "o" / "sim", "--duration", duration], capsys)
    assert code == 2 and len(err) == 1 and message in err[0], err
    assert not (tmp_path / "o").exists()  # no empty folder left


def test_simulate_chunk_frames_and_disk_are_bounded(tmp_path, capsys, monkeypatch):
    cfg = tmp_path / "c.toml"
    cfg.write_text(TOF.read_text().replace("chunk_frames = 200", "chunk_frames = 100000000"))
    code, err = run_cli(["simulate", cfg, "--out", tmp_path / "o"], capsys)
    assert code == 2 and "key 'recording.chunk_frames' 100,000,000" in err[0], err
    assert "frames per chunk" in err[0] and not (tmp_path / "o").exists()
    # the disk: 30 s of 176x144 frames (~12 MiB before compression) on a nearly full disk
    import jaxdefl._resources as res

    free = shutil.disk_usage(tmp_path)._replace(free=1 << 20)
    monkeypatch.setattr(res.shutil, "disk_usage", lambda p: free)
    code, err = run_cli(["simulate", TOF, "--out", tmp_path / "o", "--duration", "30"], capsys)
    assert code == 2 and "--duration 30: 600 frames of 176x144" in err[0] and "1.0 MiB free" in err[0], err
    assert not (tmp_path / "o").exists()


def test_fit_oversampling_is_bounded_by_its_memory(work, capsys):
    before = files(work)
    t0 = time.perf_counter()
    code, err = run_cli(["fit", work / "traj.csv", "--out", work / "E.csv", "--oversampling", "1e6"], capsys)
    assert code == 2 and len(err) == 1 and err[0].startswith("jaxdefl: error: --oversampling: 1e+06 gives"), (
        err
    )
    assert "GiB" in err[0] and "an oversampling <=" in err[0]
    assert files(work) == before
    assert time.perf_counter() - t0 < 120  # refused before the periodogram, not after swapping


def test_the_periodogram_bound_covers_both_methods():
    """The grid (frame clock) and the non-uniform path refuse before allocating; a bound that
    passes is what the periodogram then uses."""
    from jaxdefl.series import make_windows
    from jaxdefl.spectral import lomb_peaks

    rng = np.random.default_rng(1)
    n = 2000
    t_grid = np.arange(n) / 20.0
    t_any = np.sort(rng.uniform(0, 100, n))
    for t in (t_grid, t_any):
        df = pd.DataFrame({"segment": "s", "t": t, "plate": 1, "z": np.sin(2 * np.pi * 3 * t)})
        w = make_windows(df, axes=("z",))
        with pytest.raises(ParameterError, match=r"oversampling: 1e\+07 gives [\d,]+ frequencies"):
            lomb_peaks(w, oversampling=1e7)
        p = lomb_peaks(w, oversampling=20)
        assert abs(p.freq_hz[0] - 3.0) < 1e-3


@pytest.mark.slow
def test_an_allowed_oversampling_stays_within_its_budget(work):
    """The largest oversampling the bound allows on this file is run; its peak RSS stays
    within the budget (plus the interpreter and its libraries, < 1.5 GiB)."""
    out = work / "E.csv"
    msg = subprocess.run(
        [*PY, "fit", work / "traj.csv", "--out", out, "--oversampling", "1e9"], capture_output=True, text=True
    ).stderr
    most = int(msg.split("an oversampling <= ")[1].split(" ")[0].replace(",", ""))
    code = (
        "import sys\nfrom jaxdefl.cli import main\n"
        f"rc = main(['fit', {str(work / 'traj.csv')!r}, '--out', {str(out)!r}, '--oversampling', '{most}'])\n"
        # the process's own peak (VmHWM): ru_maxrss keeps, across exec, the peak of the forked
        # parent (a pytest worker of several GiB), which is what CI measured twice
        "hwm = next(int(x.split()[1]) for x in open('/proc/self/status') if x.startswith('VmHWM'))\n"
        "print(rc, hwm * 1024)\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    rc, peak = done.stdout.split()[-2:]
    assert rc == "0", done.stderr
    assert int(peak) < MEMORY_BUDGET_BYTES + (3 << 29), (most, int(peak) / 2**30)


def test_out_of_memory_advice_names_the_commands_own_flags(tmp_path, capsys, monkeypatch):
    import jaxdefl.simulate as simulate

    def oom(*a, **k):
        raise MemoryError

    monkeypatch.setattr(simulate, "simulate_to_dir", oom)
    code, err = run_cli(["simulate", TOF, "--out", tmp_path / "o"], capsys)
    assert code == 1 and "--duration" in err[0] and "--step" not in err[0] and "--window" not in err[0], err


# -- echoed input -----------------------------------------------------------------------------


def test_a_csv_padded_with_zero_bytes_gives_a_short_message(work, capsys):
    p = work / "traj.csv"
    p.write_bytes(p.read_bytes().rstrip(b"\n") + b"\0" * 2_000_000)
    code, err = run_cli(["fit", p, "--out", work / "E.csv"], capsys)
    assert code == 2 and len(err) == 1, err
    assert len(err[0]) < 300 and "column 'z'" in err[0] and "2,000,0" in err[0], err[0]


def test_echo_and_one_line_bound_any_text():
    assert echo("4.5") == "'4.5'" and echo(np.float64(2.5)) == "2.5"
    cut = echo("7" + "\0" * 10**6)
    assert len(cut) < 100 and cut.endswith("(1,000,001 characters)")
    line = one_line("a\nb\x00" + "x" * 10**7)
    assert len(line) <= MESSAGE_CHARS and "\n" not in line and "\x00" not in line
    assert line.startswith("a b\\x00") and line.endswith(f"(message cut at {MESSAGE_CHARS} characters)")
    assert one_line("short") == "short"


# -- diagnose on long records -----------------------------------------------------------------


def test_diagnose_says_its_phases_and_refuses_more_memory_than_available(work, capsys, monkeypatch):
    import jaxdefl._resources as res

    args = ["diagnose", work / "traj.csv", "--out", work / "d.json", "--effects", "drift", "--no-figures"]
    monkeypatch.setattr(res, "available_memory", lambda: 1 << 20)
    code, err = run_cli(args, capsys)
    assert code == 2 and len(err) == 1, err
    assert "diagnosing 2,3" in err[0] and "1.0 MiB are available" in err[0] and "--segment" in err[0], err
    assert not (work / "d.json").exists()
    monkeypatch.setattr(res, "available_memory", lambda: None)
    capsys.readouterr()
    assert main([str(a) for a in args]) == 0
    text = capsys.readouterr().err  # not a terminal: each long phase says it starts
    assert "jaxdefl diagnose: reading" in text and "against the nominal model" in text


def test_extract_chunk_frames_is_bounded_by_its_memory(sim, capsys, monkeypatch):
    """A batch is min(--chunk-frames, frames) frames: refused when its estimate passes the
    budget (here lowered to 100 MiB so that the 200 frames of the test recording pass it)."""
    import jaxdefl._resources as res

    monkeypatch.setattr(res, "MEMORY_BUDGET_BYTES", 100 << 20)
    store = sim / "sim" / "recording.zarr"
    out = sim / "t.csv"
    code, err = run_cli(["extract", store, "--out", out, "--chunk-frames", "1000000"], capsys)
    assert code == 2 and len(err) == 1, err
    n = open_recording(store).n_frames
    assert f"--chunk-frames: batches of {n} frames of 176x144 would need" in err[0], err[0]
    most = (100 << 20) // (24 * 176 * 144)
    assert f"at most {most:,} frames per batch), got 1,000,000" in err[0] and not out.exists()


@pytest.mark.parametrize("zarr_format", [2, 3])
def test_a_short_uncompressed_chunk_is_named(tmp_path, zarr_format):
    """Without a codec to fail, a short chunk file is still an error naming its frames."""
    import zarr

    store = tmp_path / "u.zarr"
    g = zarr.open_group(str(store), mode="w", zarr_format=zarr_format)
    g.attrs.update(fx=100.0, fy=100.0, cx=4.0, cy=3.0)
    d = g.create_array("depth", shape=(20, 6, 8), chunks=(5, 6, 8), dtype="float32", compressors=None)
    d[:] = np.ones((20, 6, 8), np.float32)
    g.create_array("timestamps", shape=(20,), chunks=(20,), dtype="float64", compressors=None)[:] = np.arange(
        20.0
    )
    with open(store / "depth" / d.metadata.encode_chunk_key((2, 0, 0)), "r+b") as f:
        f.truncate(100)
    rec = open_recording(store)
    with pytest.raises(Exception, match=r"array 'depth': the chunk of frames 10\.\.14 cannot be read"):
        list(rec.chunks(7))  # the batch 7..13 meets the short chunk 10..14


def test_reconcile_null_sims_are_bounded(work, capsys):
    args = ["reconcile", work / "traj.csv", "--config", TOF, "--out", work / "r", "--null-sims", "1000000000"]
    code, err = run_cli(args, capsys)
    assert code == 2 and len(err) == 1 and "--null-sims: expected at least 5" in err[0], err
    assert "at most 1000" in err[0] and "got 1000000000" in err[0] and not (work / "r").exists()
