"""Reports never contradict their own tables (issue 25.14): the diagnosis report (OUT.md of
`jaxdefl diagnose`) and the reconcile report (report.md) over several real results: nothing
found, unnamed terms only, named + unnamed, a white-noise failure with nothing modelled.

The checks read the rendered markdown back, as a user would: the summary sentence against the
sections and tables below it, parsed independently of the code that wrote them.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

import numpy as np
import pytest

from jaxdefl.diagnose import ALPHA, diagnose
from jaxdefl.reconcile.engine import Reconciliation
from jaxdefl.report.diagnosis import diagnosis_markdown
from jaxdefl.report.reconcile import reconcile_markdown

sys.path.insert(0, str(Path(__file__).parent))
from test_diagnose import record  # noqa: E402
from test_diagnose_unnamed import damper  # noqa: E402


def _trend_and_line(seed: int = 12):
    """A 1.37-Hz line of 0.3 mm on three plates, plus a 0.54-mm trend with a 0.3-mm step at 60 s."""
    traj = record(minutes=2, plates=3, seed=seed, line=(1.37, 0.3))
    t = traj["t"] - traj["t"].min()
    traj["z"] += 0.54 * t / 120.0 + 0.3 * (t > 60.0)
    return traj


CASES = {
    # nothing there, nothing found
    "nothing": lambda: diagnose(record(minutes=2, plates=3, seed=11)),
    # a named line only
    "named": lambda: diagnose(record(minutes=2, plates=3, seed=12, line=(1.37, 0.3))),
    # the vocabulary cannot name a trend with a step: unnamed only (the report once said
    # "No effect located: consistent with the nominal model" above it)
    "unnamed": lambda: diagnose(_trend_and_line(), effects=("timing_error",)),
    "named+unnamed": lambda: diagnose(_trend_and_line(), effects=("extra_periodic",)),
    # unnamed envelope and a residual test still failing
    "unnamed+unexplained": lambda: diagnose(damper(1)[0]),
    # nothing modelled at all while the nominal residuals are far from white
    "white-noise failure": lambda: diagnose(_trend_and_line(), effects=("timing_error",), open_world=False),
}


@pytest.fixture(scope="module")
def diagnoses():
    return {name: make() for name, make in CASES.items()}


def _parse_diagnosis(md: str) -> dict:
    lines = md.splitlines()
    summary = next(line for line in lines if line.startswith("**"))
    p = {m[1]: float(m[2]) for m in re.finditer(r"^\| (nominal|final) \| .* \| ([^|]+) \|$", md, re.M)}
    sections = re.split(r"^## ", md, flags=re.M)

    def bullets(title: str) -> list[str]:
        sec = next((s for s in sections if s.startswith(title)), "")
        return [line for line in sec.splitlines() if line.startswith("- ")]

    return {
        "summary": summary,
        "named": re.findall(r"^## \d+\. `(\w+)`", md, re.M),
        "unnamed": [re.match(r"- `(\w+)`", b)[1] for b in bullets("Structure outside the vocabulary")],
        "unexplained": bullets("Unexplained structure"),
        "advice": bullets("What to do next"),
        "p": p,
    }


def _check_diagnosis(md: str) -> dict:
    r = _parse_diagnosis(md)
    s, named, unnamed = r["summary"], r["named"], r["unnamed"]
    clean = not named and not unnamed and not r["unexplained"] and r["p"]["nominal"] >= ALPHA
    assert ("consistent with the nominal model" in s) == clean, s
    if named:
        assert f"**{len(named)} effect" in s and all(f"`{e}`" in s for e in named), s
    else:
        assert "No effect located" in s or "No named effect" in s, s
    if unnamed:
        assert f"{len(unnamed)} unnamed term" in s and all(k in s for k in unnamed), s
    else:
        assert "unnamed" not in s, s
    if r["unexplained"]:
        assert "Unexplained structure" in s, s
    if r["p"]["final"] < ALPHA and not r["unexplained"] and not clean:
        assert "not white" in s, s
    if r["p"]["final"] >= ALPHA:
        assert "still not white" not in s, s
    if not clean:  # every finding gets advice and the command to run next
        commands = [a for a in r["advice"] if re.search(r"`jaxdefl \w+ [^`]+`", a)]
        wanted = len(unnamed) + bool(named) + bool(r["unexplained"] or (not named and not unnamed))
        assert len(commands) >= wanted, (s, r["advice"])
        assert "What to do next" in s
    # the method paragraph states the search's rule, not the old ΔBIC-only one
    assert "likelihood-ratio" in md and "when the Bayesian information criterion improves" not in md
    return r


@pytest.mark.parametrize("case", list(CASES))
def test_the_diagnosis_summary_never_contradicts_its_tables(diagnoses, case):
    d = diagnoses[case]
    r = _check_diagnosis(diagnosis_markdown(d, []))
    # the cases are what they say they are (so every branch of the summary is exercised)
    kinds = {
        "nothing": (False, False, True),
        "named": (True, False, None),
        "unnamed": (False, True, None),
        "named+unnamed": (True, True, None),
        "unnamed+unexplained": (False, True, None),
        "white-noise failure": (False, False, False),
    }[case]
    assert bool(r["named"]) == kinds[0] and bool(r["unnamed"]) == kinds[1], r
    if kinds[2] is not None:
        assert (r["p"]["nominal"] >= ALPHA) == kinds[2], r["p"]
    if case == "unnamed+unexplained":
        assert r["unexplained"]


def test_a_trend_with_a_step_is_never_called_consistent_with_the_nominal_model(diagnoses):
    md = diagnosis_markdown(diagnoses["unnamed"], [])
    assert "No effect located" not in md and "No named effect" in md
    (trend,) = [a for a in _parse_diagnosis(md)["advice"] if a.startswith("- `trend`")]
    assert "--reference" in trend  # no reference given: one tells the camera from the structure


# -- reconcile -------------------------------------------------------------------------------


def _row(metric, before, after, null, level="trajectories"):
    return dict(level=level, metric=metric, before=before, after=after, null_95=null)


def _effect(eid):
    return dict(
        id=eid,
        parameters={"amplitude_mm": 0.3},
        plates=[1, 2],
        axes=["z"],
        delta_bic=-50.0,
        simulated=True,
        injected=None,
        note="",
        explanation="",
    )


def _rec(rows, effects, diag):
    return Reconciliation(levels=rows, effects=effects, specs=(), diagnosis=diag, f0_hz=3.0)


def _reconcile_cases(diagnoses):
    apart = [
        _row("noise_mm", 0.5, 0.5, 0.1),
        _row("slow_mm", 2.0, 1.5, 0.3),
        _row("envelope", 0.2, 0.05, 0.1),
    ]
    agree = [_row("noise_mm", 0.05, 0.05, 0.1), _row("slow_mm", 2.0, 0.2, 0.3)]
    return {
        # four metrics apart, nothing named (the report once said "None: the diagnosis found
        # nothing" and gave no advice)
        "apart, nothing named": _rec(
            apart + [_row("outlier_rate", 0.4, 0.4, 0.1)], [], diagnoses["white-noise failure"]
        ),
        "apart, unnamed only": _rec(apart, [], diagnoses["unnamed"]),
        "apart, named + unnamed": _rec(apart, [_effect("extra_periodic")], diagnoses["named+unnamed"]),
        "reconciled": _rec(agree, [_effect("extra_periodic")], diagnoses["named"]),
        "agreed already": _rec(agree[:1], [], diagnoses["nothing"]),
    }


def _check_reconcile(md: str):
    summary = next(line for line in md.splitlines() if line.startswith("**"))
    verdicts = ("agreed already", "reconciled", "still apart", "not measured")
    table = [
        r for r in re.findall(r"^\| (\w+) \| (\w+) \| .* \| ([a-z ]+) \|$", md, re.M) if r[2] in verdicts
    ]
    assert table
    apart = [m for _, m, v in table if v == "still apart"]
    fixed = [m for _, m, v in table if v == "reconciled"]
    advice = md.split("## What to do next", 1)[1].split("\n\n")[1].splitlines()
    assert summary.startswith("**Still apart**") == bool(apart), summary
    for m in apart:
        assert m in summary, (m, summary)
        assert any(a.startswith(f"- `{m}`") and re.search(r"`jaxdefl \w+ [^`]+`", a) for a in advice), advice
    for m in {m for _, m, _ in table} - set(apart) - set(fixed):
        assert m not in summary, (m, summary)
    if not apart:
        assert summary.startswith("**Reconciled**") == bool(fixed), summary
    named = re.findall(r"^- \*\*(\w+)\*\*", md, re.M)
    unnamed = re.findall(r"^- unnamed `(\w+)`", md, re.M)
    assert all(f"`{e}`" in summary for e in named)
    assert (f"{len(unnamed)} unnamed term" in summary) == bool(unnamed), summary
    assert "found nothing" not in md
    if not named and apart:
        assert "named no effect" in summary
    return apart, unnamed


@pytest.mark.parametrize(
    "case",
    ["apart, nothing named", "apart, unnamed only", "apart, named + unnamed", "reconciled", "agreed already"],
)
def test_the_reconcile_summary_never_contradicts_its_table(diagnoses, case):
    rec = _reconcile_cases(diagnoses)[case]
    d = {"config": "reconciled.toml", "unexplained": rec.diagnosis["unexplained"]}
    md = reconcile_markdown(rec, d, [], "rec.csv", "exp.toml", "rec_out")
    apart, unnamed = _check_reconcile(md)
    expect_apart = {r["metric"] for r in rec.levels if rec.verdict(r) == "still apart"}
    assert set(apart) == expect_apart
    assert bool(unnamed) == bool(rec.diagnosis["unnamed"])
    # unexplained structure is written as sentences, not as raw dicts
    assert "{'test'" not in md
    assert "likelihood-ratio" in md


def test_every_metric_has_advice_and_a_command():
    from jaxdefl.reconcile.metrics import METRICS
    from jaxdefl.report.reconcile import _ADVICE, _MEANING

    assert set(METRICS) <= set(_ADVICE) and set(_MEANING) <= set(_ADVICE)
    assert all(cmd.startswith("jaxdefl ") for _, cmd in _ADVICE.values())
    assert np.all([len(s) > 40 for s, _ in _ADVICE.values()])


def test_reconcile_advice_runs_on_what_each_command_reads(diagnoses):
    """diagnose and fit read trajectory tables: for a frame recording the advice extracts it
    first; reconcile reads the frames themselves. An effect named on several series is listed
    once, with its count."""
    rows = [_row("slow_mm", 2.0, 1.5, 0.3), _row("envelope", 0.2, 0.15, 0.1, "estimates")]
    rows.append(_row("noise_mm", 0.5, 0.5, 0.1))
    rec = _rec(rows, [_effect("drift"), _effect("drift"), _effect("outliers")], diagnoses["unnamed"])
    d = {"config": "reconciled.toml", "unexplained": []}
    md = reconcile_markdown(rec, d, [], "sim/recording.zarr", "exp.toml", "rec_out")
    commands = re.findall(r"`(jaxdefl \w+ [^`]+)`", md)
    assert not [c for c in commands if c.split()[1] in ("diagnose", "fit") and ".zarr" in c], commands
    assert "jaxdefl extract sim/recording.zarr --out recording_trajectories.csv" in commands
    assert (
        "jaxdefl diagnose recording_trajectories.csv --reference LDS.csv --out recording_diag.json"
        in commands
    )
    assert "jaxdefl reconcile sim/recording.zarr --config rec_out/reconciled.toml --out rec_out_2" in commands
    summary = next(line for line in md.splitlines() if line.startswith("**"))
    assert "(`drift` ×2, `outliers`)" in summary
    # a table needs no extraction
    md = reconcile_markdown(rec, d, [], "traj.csv", "exp.toml", "rec_out")
    assert "jaxdefl extract" not in md and "`jaxdefl fit traj.csv --window 30 --out traj_30s.csv`" in md
