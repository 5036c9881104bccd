"""The concealed-effect benchmark of ``jaxdefl diagnose`` (issue 7).

    python experiments/concealed_effects.py [--out DIR] [--cases N] [--controls N] [--minutes M]
                                            [--seed S] [--workers K] [--held-out ID]
                                            [--ar1-controls SHARE]

Generates recordings with the simulator (`jaxdefl.simulate.effects`): every effect several times
alone, random pairs of effects, and effect-free controls, with decoys the nominal model handles
(3-30 % drop-outs, 9-13 plates of different amplitudes, a plate with a larger noise, 20 and
30 Hz, 15-20 minutes, with and without an LDS, and on half of the ToF recordings noise shared by
the plates of a frame, 40-85 % of its variance). The labels stay here: the diagnosing call gets the
tables and the hints a user has (``sensor``, ``frame_rate_hz``) and nothing else. Then scores:

- confusion matrix: rows the injected id ("none" for a control), columns the reported ids ("none"
  when an injected effect is not reported and nothing else is). A reported id that matches no
  injected effect counts in the row of every effect of the case.
- detection: the injected id reported with at least half of its plates right (for the effects
  seen only against the reference, half of the LDS plates also counts).
- false positives: controls with any reported effect.
- location: plates Jaccard of the detected effects (for the effects seen only against the
  reference, the better of the Jaccard against all plates and against the LDS plates); level
  jumps: the jump-time error.
- parameter recovery: |estimate − truth| / |truth| of each primary parameter
  (`jaxdefl.simulate.effects.primary_parameters`), within 25 % counts as recovered.
- quality: share of reported effects with ΔBIC < −10 and rms_after < rms_before.
- seconds per recording (the diagnose call only).
- controls flagged: controls with any reported effect *or unnamed term* (the open world's
  generic terms count as a flag). ``--ar1-controls SHARE`` (default 0.5) gives that share of the
  controls AR(1) noise on top of the white noise, ρ drawn in 0.3-0.8, σ twice the recording's
  white σ (so most of the noise is coloured); half of the ToF recordings carry frame-common noise.
- held-out mode (``--held-out ID``): every effect case is ID alone, and the diagnosis runs with ID
  removed from its registry (``effects=`` all other ids). Scored: the injected effect *modelled
  as unnamed* — an ``unnamed`` term with ΔBIC < −10 on at least half of its plates — with no
  vocabulary name claimed (no named effect reported).

Writes DIR/cases.csv (one row per case and injected effect; one row per control), DIR/confusion.csv,
DIR/summary.md and DIR/results/case_NNN.json (plan, truth, DIAG dict, seconds, error: saved as each
case ends, so that a stopped run resumes where it stopped, and ``--rescore`` scores them again),
and prints the summary.
"""

from __future__ import annotations

import argparse
import importlib
import json
import math
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from scipy.signal import lfilter

from jaxdefl.simulate.effects import EFFECT_IDS, make_case, primary_parameters

TARGETS = {"detected": 0.90, "false_positive": 0.05, "quality": 1.0, "recovered": 1.0}
RECOVERY_TOL = 0.25
DELTA_BIC_MAX = -10.0
INCOMPATIBLE = {
    frozenset({"motion_artefact", "timing_error"}),  # nearly the same signature against the LDS
    frozenset({"motion_artefact", "quantization"}),  # a ToF and a structured-light property
}
DIAGNOSE = "jaxdefl.diagnose:diagnose"


# ---------------------------------------------------------------------------------------------
# the plan


def plan_cases(
    n_cases: int, n_controls: int, seed: int, held_out: str | None = None, ar1_controls: float = 0.0
) -> list[dict]:
    """Cases: the first ceil(3N/4) are single effects, round-robin over `EFFECT_IDS` (so every effect
    appears several times alone), the rest random compatible pairs; then the controls. With
    ``held_out`` every effect case is that effect alone (and carries ``held_out``); a share
    ``ar1_controls`` of the controls gets AR(1) noise (``ar1_rho`` in 0.3-0.8)."""
    rng = np.random.default_rng([seed, 1])
    n_single = n_cases if held_out else min(n_cases, math.ceil(0.75 * n_cases))
    plan = []
    for i in range(n_single):
        eid = held_out or EFFECT_IDS[i % len(EFFECT_IDS)]
        plan.append({"kind": "single", "effects": [eid]})
    while len(plan) < n_cases:
        pair = sorted(rng.choice(EFFECT_IDS, size=2, replace=False).tolist())
        if frozenset(pair) not in INCOMPATIBLE:
            plan.append({"kind": "pair", "effects": pair})
    n_ar1 = int(round(ar1_controls * n_controls))
    rho_rng = np.random.default_rng([seed, 2])
    for j in range(n_controls):
        c: dict[str, Any] = {"kind": "control", "effects": []}
        if j < n_ar1:
            c["ar1_rho"] = round(float(rho_rng.uniform(0.3, 0.8)), 3)
        plan.append(c)
    for i, p in enumerate(plan):
        p["case"] = i
        p["seed"] = int(seed) * 100_000 + i
        if held_out:
            p["held_out"] = held_out
    return plan


def add_ar1_noise(traj: pd.DataFrame, truth: Mapping, rho: float, seed: int) -> pd.DataFrame:
    """AR(1) noise of coefficient ``rho`` on every plate and axis, its marginal σ twice the
    recording's white σ of that plate and axis, on the frame clock (drop-outs skip frames)."""
    rng = np.random.default_rng([int(seed), 9001])
    rec = truth["recording"]
    dt = 1.0 / float(rec["frame_rate_hz"])
    k = np.rint((traj["t"].to_numpy() - float(rec["t_first"])) / dt).astype(np.int64)
    n_frames = int(k.max()) + 1
    out = traj.copy()
    plates = traj["plate"].to_numpy()
    for axis in ("x", "y", "z"):
        sig = np.asarray(rec["noise_mm"][axis], float)
        for p in np.unique(plates):
            a = lfilter([1.0], [1.0, -rho], rng.standard_normal(n_frames) * math.sqrt(1 - rho * rho))
            rows = plates == p
            out.loc[rows, axis] = traj.loc[rows, axis].to_numpy() + 2.0 * sig[int(p) - 1] * a[k[rows]]
    return out


# ---------------------------------------------------------------------------------------------
# running


def _resolve(diagnose: str | Callable) -> Callable:
    if callable(diagnose):
        return diagnose
    module, name = diagnose.split(":")
    return getattr(importlib.import_module(module), name)


def _blind_call(
    diagnose: Callable,
    traj: pd.DataFrame,
    lds: pd.DataFrame | None,
    hints: Mapping,
    held_out: str | None = None,
    alpha: float | None = None,
) -> dict:
    """The diagnosing call: the tables and a user's hints, nothing from the truth (with a held-out
    effect, the registry without it)."""
    extra: dict = {"effects": tuple(e for e in EFFECT_IDS if e != held_out)} if held_out else {}
    if alpha is not None:  # the family-wise level of the named effects (`diagnose --alpha`)
        extra["alpha"] = alpha
    return diagnose(
        traj,
        reference=lds,
        sensor=hints["sensor"],
        frame_rate_hz=hints["frame_rate_hz"],
        modulation_mhz=None,
        **extra,
    )


def run_case(plan: Mapping, minutes: float | None, diagnose: str | Callable = DIAGNOSE) -> dict:
    """Generate one case, run the blind diagnosis, return {plan, truth, diag, seconds, error}."""
    traj, lds, truth = make_case(plan["seed"], plan["effects"], minutes=minutes)
    if plan.get("ar1_rho"):
        traj = add_ar1_noise(traj, truth, float(plan["ar1_rho"]), plan["seed"])
        truth["recording"]["ar1_rho"] = float(plan["ar1_rho"])
    rec = truth["recording"]
    hints = {"sensor": rec["sensor"], "frame_rate_hz": rec["frame_rate_hz"]}
    fn = _resolve(diagnose)
    t0 = time.perf_counter()
    try:
        diag, error = _blind_call(fn, traj, lds, hints, plan.get("held_out")), ""
    except Exception as err:  # a failure is a result of the benchmark, not its end
        diag, error = None, f"{type(err).__name__}: {err}"
    seconds = time.perf_counter() - t0
    return {"plan": dict(plan), "truth": truth, "diag": _jsonable(diag), "seconds": seconds, "error": error}


def _jsonable(obj: Any) -> Any:
    if isinstance(obj, Mapping):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _jsonable(obj.tolist())
    if isinstance(obj, (np.floating, float)):
        return float(obj)
    if isinstance(obj, (np.integer, int)) and not isinstance(obj, bool):
        return int(obj)
    return obj


def run_benchmark(
    plan: Sequence[Mapping],
    minutes: float | None = None,
    workers: int = 1,
    diagnose: str | Callable = DIAGNOSE,
    log: Callable[[str], None] | None = print,
    out: Path | None = None,
) -> list[dict]:
    """Every case of the plan (in ``workers`` processes when > 1; ``diagnose`` must then be a
    "module:function" name). With ``out``, each case is saved as it ends (DIR/results/) and a
    case already saved there for the same seed, effects and length is not run again (resume)."""
    done: dict[int, dict] = {}
    if out is not None:
        (out / "results").mkdir(parents=True, exist_ok=True)
        for r in load_results(out):
            p = r["plan"]
            if r.get("minutes") == minutes:
                done[p["case"]] = r

    def finish(r: dict) -> dict:
        r["minutes"] = minutes
        if out is not None:
            path = out / "results" / f"case_{r['plan']['case']:03d}.json"
            path.write_text(json.dumps(r, indent=1, default=str))
        if log is not None:
            ids = ",".join(r["plan"]["effects"]) or "control"
            rep = ",".join(e.get("id", "?") for e in (r["diag"] or {}).get("effects", [])) or "-"
            err = f"  ERROR {r['error'][:80]}" if r["error"] else ""
            log(f"case {r['plan']['case']:3d} {ids:45s} -> {rep:45s} {r['seconds']:6.1f} s{err}")
        return r

    def same(p: Mapping) -> bool:
        r = done.get(p["case"])
        return r is not None and r["plan"]["seed"] == p["seed"] and r["plan"]["effects"] == list(p["effects"])

    todo = [p for p in plan if not same(p)]
    results = {p["case"]: done[p["case"]] for p in plan if same(p)}
    if log is not None and results:
        log(f"resuming: {len(results)} cases already in {out}")
    if workers <= 1:
        for p in todo:
            results[p["case"]] = finish(run_case(p, minutes, diagnose))
    else:
        if callable(diagnose):
            raise ValueError("diagnose: with workers > 1 give a 'module:function' name")
        import multiprocessing as mp

        with ProcessPoolExecutor(workers, mp_context=mp.get_context("spawn")) as pool:
            futures = [pool.submit(run_case, p, minutes, diagnose) for p in todo]
            for f in futures:
                r = finish(f.result())
                results[r["plan"]["case"]] = r
    return [results[p["case"]] for p in plan]


# ---------------------------------------------------------------------------------------------
# scoring


def _value(par: Any) -> float:
    if isinstance(par, Mapping):
        par = par.get("value", float("nan"))
    try:
        return float(par)
    except (TypeError, ValueError):
        return float("nan")


def relative_error(estimate: float, truth: float, sign_matters: bool = True) -> float:
    """|estimate − truth| / |truth| (on magnitudes when the sign is a phase convention)."""
    if not sign_matters:
        estimate, truth = abs(estimate), abs(truth)
    if not math.isfinite(estimate) or truth == 0:
        return float("nan")
    return abs(estimate - truth) / abs(truth)


def _jaccard(a: set, b: set) -> float:
    return len(a & b) / len(a | b) if b else 0.0


def score_effect(injected: Mapping, reported: Sequence[Mapping], t_first: float) -> dict:
    """Detection, location and parameter recovery of one injected effect among the reports."""
    same = [r for r in reported if r.get("id") == injected["id"]]
    true = set(int(p) for p in injected["plates"])
    det = set(int(p) for p in injected.get("detectable_plates") or [])
    rep = set(int(p) for r in same for p in (r.get("plates") or []))
    named = bool(same)
    hits = len(rep & true)
    located = named and (hits >= len(true) / 2 or (bool(det) and len(rep & det) >= len(det) / 2))
    out: dict[str, Any] = {
        "named": named,
        "located": located,
        "detected": named and located,
        "jaccard": max(_jaccard(rep, true), _jaccard(rep, det)) if named else float("nan"),
        "jump_error_s": float("nan"),
    }
    # the report that overlaps the true plates most gives the parameters
    best = max(same, key=lambda r: len(set(r.get("plates") or []) & true), default=None)
    errors = {}
    for name, (value, sign) in primary_parameters(injected).items():
        est = _value((best or {}).get("parameters", {}).get(name, float("nan")))
        errors[name] = relative_error(est, value, sign)
    if injected["id"] == "level_jump" and best is not None:
        pars = best.get("parameters", {})
        est = _value(pars["t_jump_s"]) if "t_jump_s" in pars else _value(best.get("t_start")) - t_first
        out["jump_error_s"] = abs(est - float(injected["parameters"]["t_jump_s"]))
    out["param_errors"] = errors
    out["recovered"] = named and all(math.isfinite(v) and v <= RECOVERY_TOL for v in errors.values())
    return out


def unnamed_located(injected: Mapping, unnamed: Sequence[Mapping]) -> bool:
    """An unnamed term with ΔBIC < −10 on at least half of the injected effect's plates (or of
    its detectable plates, for the effects seen only against the reference)."""
    true = set(int(p) for p in injected["plates"])
    det = set(int(p) for p in injected.get("detectable_plates") or [])
    for u in unnamed:
        try:
            strong = float(u["delta_bic"]) < DELTA_BIC_MAX
        except (KeyError, TypeError, ValueError):
            continue
        rep = set(int(p) for p in u.get("plates") or [])
        if strong and (len(rep & true) >= len(true) / 2 or (det and len(rep & det) >= len(det) / 2)):
            return True
    return False


def good_report(r: Mapping) -> bool:
    """ΔBIC < −10 and a lower RMS after than before."""
    try:
        return float(r["delta_bic"]) < DELTA_BIC_MAX and float(r["rms_after_mm"]) < float(r["rms_before_mm"])
    except (KeyError, TypeError, ValueError):
        return False


def score(results: Sequence[Mapping]) -> tuple[pd.DataFrame, pd.DataFrame, dict]:
    """(cases table, confusion matrix, summary figures) of the benchmark results."""
    rows = []
    labels = ["none", *EFFECT_IDS]
    conf = pd.DataFrame(0, index=labels, columns=labels, dtype=int)
    reports_total = reports_good = 0
    for res in results:
        plan, truth, diag = res["plan"], res["truth"], res["diag"] or {}
        rec = truth["recording"]
        reported = list(diag.get("effects", []) or [])
        unnamed = list(diag.get("unnamed", []) or [])
        rep_ids = sorted({str(r.get("id")) for r in reported})
        reports_total += len(reported)
        reports_good += sum(good_report(r) for r in reported)
        injected = truth["effects"]
        inj_ids = {e["id"] for e in injected}
        extras = [i for i in rep_ids if i not in inj_ids]
        common = {
            "case": plan["case"],
            "kind": plan["kind"],
            "seed": plan["seed"],
            "sensor": rec["sensor"],
            "frame_rate_hz": rec["frame_rate_hz"],
            "minutes": round(rec["duration_s"] / 60.0, 2),
            "n_plates": rec["n_plates"],
            "dropout_prob": rec["dropout_prob"],
            "frame_common": rec.get("frame_common", 0.0),
            "ar1_rho": rec.get("ar1_rho", 0.0),
            "n_unnamed": len(unnamed),
            "reference": rec["reference"],
            "reported_ids": ";".join(rep_ids),
            "extra_ids": ";".join(extras),
            "n_reported": len(reported),
            "n_good_reports": sum(good_report(r) for r in reported),
            "n_unexplained": len(diag.get("unexplained", []) or []),
            "cannot_tell": ";".join(str(c.get("id")) for c in diag.get("cannot_tell", []) or []),
            "seconds": round(float(res["seconds"]), 3),
            "error": res.get("error", ""),
        }
        if not injected:
            for x in extras:
                conf.loc["none", x] += 1
            if not extras:
                conf.loc["none", "none"] += 1
            rows.append(common | {"injected": "none", "any_reported": bool(reported) or bool(unnamed)})
            continue
        for e in injected:
            s = score_effect(e, reported, rec["t_first"])
            if s["named"]:
                conf.loc[e["id"], e["id"]] += 1
            for x in extras:
                conf.loc[e["id"], x] += 1
            if not s["named"] and not extras:
                conf.loc[e["id"], "none"] += 1
            rows.append(
                common
                | {
                    "injected": e["id"],
                    "effect_kind": e.get("kind", ""),
                    "true_plates": ";".join(map(str, e["plates"])),
                    "rms_ratio": e.get("rms_ratio"),
                    "signal": e.get("signal"),
                    "named": s["named"],
                    "located": s["located"],
                    "detected": s["detected"],
                    "jaccard": s["jaccard"],
                    "jump_error_s": s["jump_error_s"],
                    "recovered": s["recovered"],
                    "param_errors": json.dumps({k: round(v, 4) for k, v in s["param_errors"].items()}),
                    "max_param_error": max(s["param_errors"].values(), default=float("nan")),
                    "any_reported": bool(reported),
                    "unnamed_located": unnamed_located(e, unnamed),
                    "held_out_modelled": bool(plan.get("held_out"))
                    and unnamed_located(e, unnamed)
                    and not reported,
                }
            )
    cases = pd.DataFrame(rows)
    summary = _summary(cases, reports_total, reports_good)
    return cases, conf, summary


def _summary(cases: pd.DataFrame, reports_total: int, reports_good: int) -> dict:
    eff = cases[cases.injected != "none"] if len(cases) else cases
    ctl = cases[cases.injected == "none"] if len(cases) else cases
    mean = lambda s: float(s.astype(float).mean()) if len(s) else float("nan")  # noqa: E731
    detected = eff[eff.detected.astype(bool)] if len(eff) else eff
    out = {
        "n_cases": int(cases.case.nunique()) if len(cases) else 0,
        "n_effects": len(eff),
        "n_controls": len(ctl),
        "detected": mean(eff.detected) if len(eff) else float("nan"),
        "named": mean(eff.named) if len(eff) else float("nan"),
        "false_positive": mean(ctl.any_reported) if len(ctl) else float("nan"),
        "spurious_in_effect_cases": mean(eff.extra_ids.astype(str).str.len() > 0)
        if len(eff)
        else float("nan"),
        "jaccard": mean(detected.jaccard) if len(detected) else float("nan"),
        "jump_error_s_median": _nanmedian(eff.jump_error_s) if len(eff) else float("nan"),
        "recovered": mean(eff.recovered) if len(eff) else float("nan"),
        "recovered_of_detected": mean(detected.recovered) if len(detected) else float("nan"),
        "reports": reports_total,
        "quality": reports_good / reports_total if reports_total else float("nan"),
        "seconds_mean": float(cases.drop_duplicates("case").seconds.mean()) if len(cases) else float("nan"),
        "seconds_max": float(cases.drop_duplicates("case").seconds.max()) if len(cases) else float("nan"),
        "held_out_modelled": mean(eff.held_out_modelled)
        if len(eff) and "held_out_modelled" in eff
        else float("nan"),
        "false_positive_ar1": mean(ctl[ctl.ar1_rho > 0].any_reported)
        if len(ctl) and "ar1_rho" in ctl
        else float("nan"),
        "errors": int((cases.drop_duplicates("case").error.astype(str).str.len() > 0).sum())
        if len(cases)
        else 0,
    }
    out["targets"] = {
        "detected >= 90 %": bool(out["detected"] >= TARGETS["detected"]),
        "false positives <= 5 %": bool(out["false_positive"] <= TARGETS["false_positive"]),
        "every report dBIC < -10 and lower RMS": bool(reports_total == 0 or reports_good == reports_total),
        "parameters within 25 %": bool(out["recovered_of_detected"] >= TARGETS["recovered"]),
    }
    return out


def _nanmedian(s: pd.Series) -> float:
    v = s.astype(float).dropna()
    return float(v.median()) if len(v) else float("nan")


def per_effect_table(cases: pd.DataFrame) -> pd.DataFrame:
    eff = cases[cases.injected != "none"]
    if not len(eff):
        return pd.DataFrame()
    g = eff.groupby("injected")
    return pd.DataFrame(
        {
            "n": g.size(),
            "named": g.named.mean(),
            "detected": g.detected.mean(),
            "jaccard": g.jaccard.mean(),
            "recovered": g.recovered.mean(),
            "median_param_error": g.max_param_error.median(),
            "median_rms_ratio": g.rms_ratio.median(),
        }
    ).round(3)


def summary_markdown(cases: pd.DataFrame, conf: pd.DataFrame, summary: Mapping, args: Mapping) -> str:
    pct = lambda v: "n/a" if not math.isfinite(v) else f"{100 * v:.1f} %"  # noqa: E731
    s = summary
    lines = [
        "# Concealed-effect benchmark of `jaxdefl diagnose`",
        "",
        "Run: " + " ".join(f"--{k} {v}" for k, v in args.items()),
        "",
        f"{s['n_cases']} recordings: {s['n_effects']} injected effects, {s['n_controls']} controls; "
        f"{s['errors']} diagnose failures.",
        "",
        "| figure | value | target |",
        "|---|---|---|",
        f"| injected effects named and located | {pct(s['detected'])} | >= 90 % |",
        f"| injected effects named (any plates) | {pct(s['named'])} | |",
        f"| controls with any reported effect or unnamed term | {pct(s['false_positive'])} | <= 5 % |",
        f"| of them AR(1) controls (ρ 0.3-0.8) | {pct(s['false_positive_ar1'])} | <= 5 % |",
        f"| held-out effect modelled as unnamed, no name | {pct(s['held_out_modelled'])} | >= 80 % |",
        f"| effect cases with a spurious extra id | {pct(s['spurious_in_effect_cases'])} | |",
        f"| plates Jaccard (detected) | {s['jaccard']:.3f} | |",
        f"| level-jump time error, median | {s['jump_error_s_median']:.2f} s | |",
        f"| parameters within 25 % (of detected) | {pct(s['recovered_of_detected'])} | 100 % |",
        f"| parameters within 25 % (of injected) | {pct(s['recovered'])} | |",
        f"| reports with dBIC < -10 and lower RMS | {pct(s['quality'])} of {s['reports']} | 100 % |",
        f"| seconds per recording (mean / max) | {s['seconds_mean']:.1f} / {s['seconds_max']:.1f} | < 60 |",
        "",
        "Targets: " + "; ".join(f"{k}: {'PASS' if v else 'FAIL'}" for k, v in s["targets"].items()),
        "",
        "## Per effect",
        "",
        _md(per_effect_table(cases)),
        "",
        "## Confusion matrix (rows injected, columns reported)",
        "",
        _md(conf.loc[(conf.sum(axis=1) > 0), (conf.sum(axis=0) > 0)]),
        "",
    ]
    return "\n".join(lines)


def _md(df: pd.DataFrame) -> str:
    if not len(df):
        return "(none)"
    cols = [df.index.name or ""] + [str(c) for c in df.columns]
    out = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for idx, row in df.iterrows():
        out.append(
            "| "
            + " | ".join([str(idx)] + [f"{v:.3g}" if isinstance(v, float) else str(v) for v in row])
            + " |"
        )
    return "\n".join(out)


def write_outputs(
    out: Path, results: Sequence[Mapping], args: Mapping
) -> tuple[pd.DataFrame, pd.DataFrame, dict, str]:
    """Score and write DIR/cases.csv, DIR/confusion.csv, DIR/summary.md and DIR/results/*.json."""
    cases, conf, summary = score(results)
    (out / "results").mkdir(parents=True, exist_ok=True)
    for r in results:
        path = out / "results" / f"case_{r['plan']['case']:03d}.json"
        path.write_text(json.dumps(dict(r), indent=1, default=str))
    cases.to_csv(out / "cases.csv", index=False)
    conf.to_csv(out / "confusion.csv", index_label="injected")
    md = summary_markdown(cases, conf, summary, args)
    (out / "summary.md").write_text(md)
    return cases, conf, summary, md


def load_results(out: Path) -> list[dict]:
    """The per-case results saved in DIR/results/ ({plan, truth, diag, seconds, error, minutes})."""
    return [json.loads(p.read_text()) for p in sorted((out / "results").glob("case_*.json"))]


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("concealed_out"), help="output folder")
    ap.add_argument("--cases", type=int, default=44, help="effect cases (3/4 single effects, 1/4 pairs)")
    ap.add_argument("--controls", type=int, default=20, help="effect-free controls")
    ap.add_argument("--minutes", type=float, default=None, help="record length (default 15-20 min, random)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--workers", type=int, default=1, help="processes")
    ap.add_argument("--diagnose", default=DIAGNOSE, help="module:function of the diagnosis")
    ap.add_argument("--rescore", action="store_true", help="score DIR/results again, no run")
    ap.add_argument("--held-out", default=None, help="an effect id removed from the registry for the run")
    ap.add_argument("--ar1-controls", type=float, default=0.5, help="share of controls with AR(1) noise")
    args = ap.parse_args(argv)
    if args.held_out is not None and args.held_out not in EFFECT_IDS:
        print(f"concealed_effects: --held-out: expected one of {', '.join(EFFECT_IDS)}", file=sys.stderr)
        return 2
    if args.cases < 0 or args.controls < 0 or args.workers < 1:
        print("concealed_effects: --cases and --controls must be >= 0, --workers >= 1", file=sys.stderr)
        return 2
    shown = {k: v for k, v in vars(args).items() if k not in ("diagnose", "rescore") and v is not None}
    if args.rescore:
        results = load_results(args.out)
        shown = {"out": args.out, "rescore": "(scored again from DIR/results)"}
    else:
        plan = plan_cases(args.cases, args.controls, args.seed, args.held_out, args.ar1_controls)
        results = run_benchmark(plan, args.minutes, args.workers, args.diagnose, out=args.out)
    *_, md = write_outputs(args.out, results, shown)
    print(md)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
