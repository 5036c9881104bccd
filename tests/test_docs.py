"""The documentation: the output contracts' JSON Schemas hold for real outputs of the commands,
the schemas' vocabularies are the code's, the docs site builds strict, and the README stays a
front page whose links land in the site."""

from __future__ import annotations

import json
import math
import os
import re
import subprocess
import sys
from importlib import resources
from pathlib import Path

import jsonschema
import numpy as np
import pandas as pd
import pytest
from conftest import harmonic_table

from jaxdefl._effect_ids import EFFECT_IDS
from jaxdefl.cli import main
from jaxdefl.fit import ESTIMATE_COLUMNS, STATUSES
from jaxdefl.reconcile.clock import CLOCK_METRICS
from jaxdefl.reconcile.frames import FRAME_METRICS
from jaxdefl.reconcile.metrics import METRICS
from jaxdefl.status import Status

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(__file__).parent / "data"


def _schema(name: str) -> dict:
    """A schema as the installed package ships it."""
    text = resources.files("jaxdefl").joinpath("schemas", f"{name}.schema.json").read_text()
    schema = json.loads(text)
    jsonschema.Draft202012Validator.check_schema(schema)
    return schema


def _errors(schema: dict, instance) -> list[str]:
    v = jsonschema.Draft202012Validator(schema)
    return [f"{'/'.join(map(str, e.absolute_path))}: {e.message}" for e in v.iter_errors(instance)]


def _rows(path: Path) -> list[dict]:
    """An estimates table's rows as a reader sees them: empty cells are null."""
    df = pd.read_csv(path, dtype={"segment": str})
    return [
        {k: None if isinstance(v, float) and math.isnan(v) else v for k, v in r.items()}
        for r in df.to_dict("records")
    ]


# ---------------------------------------------------------------------------------------------
# the schemas' vocabularies are the code's


def test_schema_vocabularies_are_the_codes():
    est, diag, rec = _schema("est"), _schema("diag"), _schema("reconcile")
    assert est["required"] == list(ESTIMATE_COLUMNS)
    assert est["properties"]["status"]["enum"] == [s for s in STATUSES if s != Status.ABSENT]
    assert diag["$defs"]["effect_id"]["enum"] == list(EFFECT_IDS)
    levels = rec["properties"]["levels"]["items"]["properties"]
    assert levels["metric"]["enum"] == [*METRICS, *FRAME_METRICS, *CLOCK_METRICS]
    assert set(levels["level"]["enum"]) == {*METRICS.values(), "frames", "clock"}


def test_a_row_outside_the_contract_is_refused():
    """The EST schema can fail: an unknown column, a wrong status, a missing column."""
    schema = _schema("est")
    row = {c: 0.0 for c in ESTIMATE_COLUMNS} | {
        "segment": "day1",
        "window": 0,
        "plate": 3,
        "axis": "z",
        "n": 600,
        "status": "converged",
    }
    assert _errors(schema, row) == []
    assert _errors(schema, row | {"amplitude_3_mm": 0.1, "f0_2_hz": None}) == []
    assert _errors(schema, row | {"kappa": 1.0})
    assert _errors(schema, row | {"status": "fine"})
    assert _errors(schema, {k: v for k, v in row.items() if k != "sigma_f0_hz"})


# ---------------------------------------------------------------------------------------------
# real outputs


def _fit_rows(tmp_path: Path, name: str, args: list[str]) -> list[dict]:
    """EST.csv of a 2-plate, 2-axis table whose plate 2 has no valid x (too_few_samples)."""
    traj = tmp_path / "traj.csv"
    if not traj.exists():
        df = harmonic_table(n_plates=2, duration_s=40.0, axes=("z", "x"), seed=3)
        df.loc[df["plate"] == 2, "x"] = np.nan
        df.to_csv(traj, index=False)
    out = tmp_path / f"{name}.csv"
    assert main(["fit", str(traj), "--out", str(out), *args]) == 0
    rows = _rows(out)
    schema = _schema("est")
    assert rows and all(_errors(schema, r) == [] for r in rows), (name, _errors(schema, rows[0]))
    assert {r["status"] for r in rows} == {"converged", "too_few_samples"}, name
    return rows


def test_an_estimates_table_follows_the_est_schema(tmp_path):
    rows = _fit_rows(tmp_path, "default", ["--window", "20"])
    assert list(rows[0]) == list(ESTIMATE_COLUMNS)


@pytest.mark.slow
def test_estimates_tables_of_the_other_signal_models_follow_the_est_schema(tmp_path):
    cols = set(_fit_rows(tmp_path, "harmonics", ["--harmonics", "3"])[0])
    assert {"sigma_phase_rad", "amplitude_2_mm", "sigma_phase_3_rad"} <= cols
    cols = set(_fit_rows(tmp_path, "lines_damped", ["--lines", "2", "--model", "damped"])[0])
    assert {"f0_2_hz", "peak_fap_2", "damping_ratio_2", "natural_frequency_hz"} <= cols


def test_diagnoses_follow_the_diag_schema(tmp_path):
    """A named effect, a series left out and what cannot be told (synthetic plates with an LDS),
    and an unnamed term (the real friction-damper record's ramped envelope)."""
    df = harmonic_table(n_plates=3, duration_s=40.0, sigma=0.3, seed=5, phase=0.4)
    t_rel = df["t"] - df["t"].min()
    df.loc[(df["plate"] == 2) & (t_rel > 22.0), "z"] += 1.5  # a level jump on plate 2
    df = pd.concat([df, df[df["plate"] == 1].assign(plate=4, z=np.nan)], ignore_index=True)
    lds = harmonic_table(n_plates=3, duration_s=40.0, fs=300.0, sigma=0.002, dropout=0.0, seed=6, phase=0.4)
    lds = lds[lds["plate"] == 1]
    traj, ref = tmp_path / "traj.csv", tmp_path / "lds.csv"
    df.to_csv(traj, index=False)
    lds.to_csv(ref, index=False)
    schema = _schema("diag")

    out = tmp_path / "diag.json"
    assert main(["diagnose", str(traj), "--out", str(out), "--reference", str(ref), "--no-figures"]) == 0
    d = json.loads(out.read_text())
    assert _errors(schema, d) == []
    assert "level_jump" in [e["id"] for e in d["effects"]], d["effects"]
    assert d["left_out"] and d["left_out"][0]["plate"] == 4
    assert d["cannot_tell"] and d["input"]["reference_plates"] == [1]

    out = tmp_path / "brfd.json"
    assert main(["diagnose", str(DATA / "brfd_sine_2hz.csv"), "--out", str(out), "--no-figures"]) == 0
    d = json.loads(out.read_text())
    assert _errors(schema, d) == []
    assert [u["kind"] for u in d["unnamed"]] == ["envelope"], d["unnamed"]

    broken = {**d, "effects": [{"id": "gremlins"}]}
    assert _errors(schema, broken)


@pytest.mark.slow
def test_a_reconciliation_follows_the_reconcile_schema(tmp_path):
    df = harmonic_table(n_plates=3, duration_s=40.0, sigma=0.3, seed=7, axes=("z", "x"))
    t_rel = df["t"] - df["t"].min()
    df.loc[t_rel > 22.0, "z"] += 1.5  # every plate's reading jumps: a range offset
    traj = tmp_path / "traj.csv"
    df.to_csv(traj, index=False)
    out = tmp_path / "rec"
    args = ["reconcile", str(traj), "--config", "exp2_tof_3hz", "--out", str(out), "--null-sims", "5"]
    assert main(args) == 0
    d = json.loads((out / "reconcile.json").read_text())
    assert _errors(_schema("reconcile"), d) == []
    assert {r["metric"] for r in d["levels"]} == {*METRICS, *CLOCK_METRICS}
    assert any(e["simulated"] and e["injected"]["id"] == e["id"] for e in d["effects"]), d["effects"]


# ---------------------------------------------------------------------------------------------
# the site and the front page


def test_docs_site_builds_strict(tmp_path):
    """Broken links, anchors, references or a generated page that fails stop the build."""
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1", "PYTHONPATH": str(ROOT / "src")}
    r = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path / "site")],
        cwd=ROOT,
        capture_output=True,
        text=True,
        env=env,
    )
    assert r.returncode == 0, r.stderr[-3000:]
    cli = (tmp_path / "site" / "reference" / "cli" / "index.html").read_text()
    for command in ("fit", "diagnose", "reconcile", "monitor", "run", "simulate", "extract", "demo"):
        assert f'id="{command}"' in cli, command
    assert "--posterior-noise" in cli
    effects = (tmp_path / "site" / "reference" / "effects" / "index.html").read_text()
    for eid in EFFECT_IDS:
        assert f"<code>{eid}</code>" in effects, eid


def test_readme_is_a_front_page_whose_links_resolve():
    text = (ROOT / "README.md").read_text()
    assert len(text.splitlines()) <= 150
    assert "./dev demo" in text and "./dev test" in text
    links = re.findall(r"\]\(([^)#]+)(?:#[^)]*)?\)", text)
    local = [link for link in links if not re.match(r"[a-z]+://", link)]
    assert local, "the README links into the docs"
    for link in local:
        assert (ROOT / link).exists(), link


_CALL = re.compile(r"\s*(?:\S+=\S+\s+)?jaxdefl\s+(?:--debug\s+)?([a-z]+)")
_FLAG = re.compile(r"(?<![\w-])--[a-z][a-z-]*")


def _documented_calls():
    """(file, command, flags) of every `jaxdefl COMMAND ...` line in the README's and the docs'
    bash blocks (continuation lines of a usage block included)."""
    files = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
    for path in files:
        for block in re.findall(r"```bash\n(.*?)```", path.read_text(), flags=re.S):
            command = None
            for line in block.splitlines():
                code = line.split("#", 1)[0]
                if m := _CALL.match(code):
                    command = m.group(1)
                elif not line.startswith(" "):
                    command = None
                if command is None:
                    continue
                for segment in code.split("&&"):  # `jaxdefl simulate ... && jaxdefl reconcile ...`
                    if (m := _CALL.match(segment)) and m.group(1) != command:
                        continue
                    yield path.relative_to(ROOT), command, _FLAG.findall(segment)


def test_documented_commands_and_flags_exist():
    import typer

    from jaxdefl.cli import app

    commands = typer.main.get_command(app).commands
    calls = list(_documented_calls())
    assert len(calls) > 20
    for path, command, flags in calls:
        assert command in commands, (path, command)
        known = {o for p in commands[command].params for o in (*p.opts, *p.secondary_opts)}
        unknown = set(flags) - known - {"--debug", "--help"}
        assert not unknown, (str(path), command, sorted(unknown))
