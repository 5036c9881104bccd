"""Progress and closing lines (issue 25.16): off a terminal every command shows plain progress
lines on stderr (no live bars, no control characters, at most one per `PLAIN_EVERY_S` and at
least that often while a step runs) and ends with one ``jaxdefl CMD: wrote ...`` line; a config
with several sessions makes every one of them, each in its own folder."""

from __future__ import annotations

import re
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from jaxdefl import progress
from jaxdefl.cli import main
from jaxdefl.io import write_trajectory
from jaxdefl.synthetic import harmonic_experiment

CONTROL = re.compile(r"[\r\x1b]")


def _wrote(err: str, command: str) -> list[str]:
    """The paths of the command's closing line; the line must be the last one of its kind."""
    lines = [x for x in err.splitlines() if x.startswith(f"jaxdefl {command}: wrote ")]
    assert len(lines) == 1, err
    assert not CONTROL.search(err), repr(err[-500:])
    head = lines[0].removeprefix(f"jaxdefl {command}: wrote ")
    return [p.strip() for p in re.sub(r" \(.*\)$", "", head).split(", ")]


def test_plain_progress_lines_are_paced_and_plain(monkeypatch, capsys):
    monkeypatch.setattr(progress, "PLAIN_EVERY_S", 0.2)
    assert not progress.interactive()  # pytest captures both streams
    t0 = time.monotonic()
    with progress.progress_bar() as bar:
        task = bar.add_task("rendering", total=10)
        for _ in range(10):
            time.sleep(0.1)
            bar.advance(task)
    elapsed = time.monotonic() - t0
    err = capsys.readouterr().err
    lines = err.splitlines()
    # a line every 0.2 s while it ran, never more often, each one saying how far it is
    assert 2 <= len(lines) <= elapsed / 0.2 + 1, lines
    for line in lines:
        m = re.fullmatch(r"rendering: (\d+)/10 \((\d+) %\), \d+ s(, about \d+ s left)?", line)
        assert m and int(m[2]) == 10 * int(m[1]), line
    assert not CONTROL.search(err)
    # a step that ends sooner than the interval says nothing
    with progress.progress_bar() as bar:
        bar.advance(bar.add_task("quick", total=3), 3)
    assert capsys.readouterr().err == ""


def test_a_status_says_its_step_at_once_and_while_it_runs(monkeypatch, capsys):
    monkeypatch.setattr(progress, "PLAIN_EVERY_S", 0.15)
    with progress.status("diagnosing ...") as step:
        time.sleep(0.4)
        step.update("refitting ...")
        time.sleep(0.05)
    lines = capsys.readouterr().err.splitlines()
    assert lines[0] == "diagnosing ..." and "refitting ..." in lines
    assert any(re.fullmatch(r"diagnosing \.\.\. \(\d+ s\)", x) for x in lines)  # the heartbeat


@pytest.fixture
def tables(tmp_path):
    traj, lds = harmonic_experiment(duration_s=40, seed=3)
    write_trajectory(traj[traj["plate"].isin([3, 7])], tmp_path / "traj.csv")
    write_trajectory(lds, tmp_path / "lds.csv")
    return tmp_path


def test_fit_and_diagnose_end_with_what_they_wrote(tables, capsys):
    out = tables / "est.csv"
    assert (
        main(["fit", str(tables / "traj.csv"), "--out", str(out), "--reference", str(tables / "lds.csv")])
        == 0
    )
    paths = _wrote(capsys.readouterr().err, "fit")
    assert paths[0] == str(out) and all(Path(p).is_file() for p in paths)
    assert any(p.endswith("_comparison.csv") for p in paths)
    diag = tables / "d.json"
    assert main(["diagnose", str(tables / "traj.csv"), "--out", str(diag), "--effects", "drift"]) == 0
    err = capsys.readouterr().err
    paths = _wrote(err, "diagnose")
    assert str(diag) in paths and str(diag.with_suffix(".md")) in paths
    assert all(Path(p).is_file() for p in paths)
    assert err.splitlines()[0].startswith("jaxdefl diagnose: ")  # the step is named at once


def _two_session_config(tmp: Path) -> Path:
    cfg = tmp / "two.toml"
    cfg.write_text(
        "[recording]\nduration_s = 1.0\n[camera]\nframe_rate_hz = 10.0\n"
        '[[session]]\nname = "a"\n[[session]]\nname = "b"\nloading = { amplitude_mm = 3.0 }\n'
    )
    return cfg


def test_simulate_makes_every_session_and_extract_says_what_it_wrote(tmp_path, capsys):
    cfg = _two_session_config(tmp_path)
    out = tmp_path / "sim"
    assert main(["simulate", str(cfg), "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "has 2 sessions (a, b)" in err and "--session NAME" in err
    assert _wrote(err, "simulate") == [str(out / "a"), str(out / "b")]
    truth = {s: pd.read_csv(out / s / "truth.csv") for s in "ab"}
    for s in "ab":
        assert (out / s / "recording.zarr").is_dir() and (out / s / "config.json").is_file()
    # the sessions differ as their tables say: b loads harder
    swing = {s: truth[s].groupby("plate")["z"].agg(np.ptp).max() for s in "ab"}
    assert swing["b"] > swing["a"]
    assert not (out / "truth.csv").exists()
    # one session picked: the single-session layout, in DIR itself, saying which one it made
    one = tmp_path / "one"
    assert main(["simulate", str(cfg), "--out", str(one), "--session", "b"]) == 0
    paths = _wrote(capsys.readouterr().err, "simulate")
    assert str(one / "truth.csv") in paths and all(Path(p).exists() for p in paths)
    np.testing.assert_array_equal(pd.read_csv(one / "truth.csv")["z"], truth["b"]["z"])
    table = tmp_path / "t.csv"
    assert main(["extract", str(one / "recording.zarr"), "--out", str(table)]) == 0
    # the table and the camera facts beside it (TRAJ.camera.json)
    assert _wrote(capsys.readouterr().err, "extract") == [str(table), str(tmp_path / "t.camera.json")]
    assert len(pd.read_csv(table)) > 0


def test_monitor_and_run_end_with_what_they_wrote(tmp_path, capsys):
    import sys

    sys.path.insert(0, str(Path(__file__).parent))
    from test_bulk import make_campaign

    cfg = make_campaign(tmp_path, days=2)
    out = tmp_path / "camp"
    assert main(["run", str(cfg), "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert err.splitlines()[0].startswith("jaxdefl run: campaign t: 2 recording(s)")
    paths = _wrote(err, "run")
    assert str(out / "report.md") in paths and all(Path(p).exists() for p in paths)
    traj = tmp_path / "traj1.csv"
    mon = tmp_path / "mon"
    assert main(["monitor", "--replay", str(traj), "--out", str(mon), "--speed", "0"]) == 0
    paths = _wrote(capsys.readouterr().err, "monitor")
    assert str(mon / "events.jsonl") in paths and all(Path(p).exists() for p in paths)


def test_on_a_terminal_progress_is_a_live_rich_bar(monkeypatch):
    from rich.progress import Progress

    monkeypatch.setattr(progress, "interactive", lambda: True)
    assert isinstance(progress.progress_bar(), Progress)
    assert isinstance(progress.progress_bar(enabled=False), progress.NoProgress)
    monkeypatch.setattr(progress, "interactive", lambda: False)
    assert isinstance(progress.progress_bar(), progress.PlainProgress)
