"""The package as a user installs it: a wheel built from the checkout, installed on its own into
a fresh directory, runs the demo from another directory (configs come as package data)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SKIP = shutil.ignore_patterns(
    ".venv", ".git", "__pycache__", "*.egg-info", "build", "demo_out", "out", ".*cache"
)


def _wheel(tmp: Path) -> Path:
    src = tmp / "src-copy"
    shutil.copytree(REPO, src, symlinks=True, ignore=SKIP)
    dist = tmp / "dist"
    subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "wheel",
            "-q",
            "--no-deps",
            "--no-build-isolation",
            "-w",
            str(dist),
            str(src),
        ],
        check=True,
        capture_output=True,
    )
    (whl,) = dist.glob("jaxdefl-*.whl")
    return whl


@pytest.mark.slow
def test_wheel_installs_and_runs_the_demo_elsewhere(tmp_path):
    whl = _wheel(tmp_path)
    names = zipfile.ZipFile(whl).namelist()
    shipped = sorted(p.name for p in (REPO / "src" / "jaxdefl" / "configs").glob("*.toml"))
    assert shipped and all(f"jaxdefl/configs/{n}" in names for n in shipped)

    target = tmp_path / "site"
    subprocess.run(
        [sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--target", str(target), str(whl)],
        check=True,
        capture_output=True,
    )
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    # the installed copy first on the path: the checkout's editable install must not be used
    env = {**os.environ, "PYTHONPATH": str(target)}
    where = subprocess.run(
        [sys.executable, "-c", "import jaxdefl; print(jaxdefl.__file__)"],
        cwd=elsewhere,
        env=env,
        capture_output=True,
        text=True,
        check=True,
    ).stdout.strip()
    assert Path(where).is_relative_to(target), where

    # a shipped config by name, and the demo, from a directory without configs/
    sim = subprocess.run(
        [sys.executable, "-m", "jaxdefl", "simulate", "exp1", "--out", "sim", "--duration", "2"],
        cwd=elsewhere,
        env=env,
        capture_output=True,
        text=True,
    )
    assert sim.returncode == 0, sim.stderr
    # exp1 holds Experiment I's 16 sessions: each in its own folder
    assert (elsewhere / "sim" / "cam3_10fps_1hz" / "truth.csv").is_file()
    demo = subprocess.run(
        [sys.executable, "-m", "jaxdefl", "demo", "--duration", "12", "--out", "demo"],
        cwd=elsewhere,
        env=env,
        capture_output=True,
        text=True,
    )
    assert demo.returncode == 0, demo.stderr
    assert (elsewhere / "demo" / "summary.md").is_file() and (
        elsewhere / "demo" / "trajectories.csv"
    ).is_file()
