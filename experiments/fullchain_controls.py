"""Full-chain controls: how often `diagnose` and `reconcile` name physics that is not there.

For each seed and each shipped config, a recording is simulated with NO effect (`jaxdefl
simulate CONFIG --duration D --seed S`), extracted (`jaxdefl extract`), then

(a) diagnosed as a user would: `jaxdefl diagnose TRAJ --config CONFIG --reference lds.csv`, and
(b) reconciled against its own config: `jaxdefl reconcile recording.zarr --config CONFIG
    --reference lds.csv`.

Every named effect is a false name (the recording holds only the config's nominal physics);
unnamed terms are located structure, not names, and are counted apart. Prints a table per record
and the totals per id. Records run in parallel (``--workers``), each through the CLI.

Usage: python experiments/fullchain_controls.py --seeds 1 2 [--configs exp2_tof_1hz ...]
       [--duration 180] [--workers 2] [--out DIR] [--skip-reconcile] [--twins 4] [--src OTHER/src]
       [--report-only]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from collections import Counter
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = ("exp2_tof_1hz", "exp2_tof_3hz", "exp2_kinect_1hz", "exp2_kinect_3hz")


SRC = ROOT / "src"
TWINS = 4


def _cli(*args: str, log: Path) -> None:
    env = dict(os.environ, PYTHONPATH=str(SRC), OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")
    cmd = [sys.executable, "-m", "jaxdefl", *args]
    with log.open("a") as fh:
        fh.write("$ " + " ".join(cmd) + "\n")
        fh.flush()
        done = subprocess.run(cmd, env=env, stdout=fh, stderr=subprocess.STDOUT, cwd=ROOT)
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(args[:2])} failed (exit {done.returncode}); see {log}")


def _twins_flag() -> tuple[str, ...]:
    """``--twins N`` for this tree's CLI; a baseline tree (``--src``) may not know the flag."""
    return () if SRC != ROOT / "src" else ("--twins", str(TWINS))


def _names(effects: list[dict]) -> list[str]:
    """One name per id and plates/axes reported (the count of false names)."""
    return [e["id"] for e in effects]


def _default_session(cfg: str) -> tuple[str, ...]:
    """``--session NAME`` of the session `diagnose --config` and `reconcile` take by default (the
    config's ``recording.session`` or its first); () for a config without sessions. Without it,
    `simulate` writes every session of a multi-session config to its own folder."""
    import tomllib

    raw = tomllib.loads(Path(cfg).read_text())
    names = [str(s.get("name", i + 1)) for i, s in enumerate(raw.get("session", []))]
    picked = raw.get("recording", {}).get("session") or (names[0] if names else None)
    return ("--session", picked) if picked else ()


def run_record(config: str, seed: int, duration: float, out: Path, do_reconcile: bool) -> dict:
    """Simulate, extract, diagnose and reconcile one control; the names each step gave."""
    rec = out / f"{config}_s{seed}"
    rec.mkdir(parents=True, exist_ok=True)
    log = rec / "log.txt"
    cfg = str(ROOT / "configs" / f"{config}.toml")
    t0 = time.perf_counter()
    row = dict(config=config, seed=seed, duration_s=duration)
    try:
        sim = rec / "sim"
        if not (sim / "lds.csv").exists():
            _cli(
                "simulate", cfg, "--out", str(sim), "--duration", str(duration), "--seed", str(seed),
                *_default_session(cfg), log=log,
            )  # fmt: skip
        traj = rec / "traj.csv"
        if not traj.exists():
            _cli("extract", str(sim / "recording.zarr"), "--out", str(traj), log=log)
        diag = rec / "DIAG.json"
        if not diag.exists():
            _cli(
                "diagnose", str(traj), "--config", cfg, "--reference", str(sim / "lds.csv"),
                "--out", str(diag), "--no-figures", *_twins_flag(), log=log,
            )  # fmt: skip
        d = json.loads(diag.read_text())
        row["diagnose"] = _names(d["effects"])
        row["diagnose_detail"] = [
            f"{e['id']}[{','.join(map(str, e.get('plates', [])))}{''.join(e.get('axes', []))}]"
            for e in d["effects"]
        ]
        row["diagnose_unnamed"] = [u.get("kind", "?") for u in d.get("unnamed", [])]
        row["diagnose_nominal"] = [e["id"] for e in d.get("nominal_physics", [])]
        row["diagnose_s"] = d.get("seconds")
        if do_reconcile:
            rdir = rec / "reconcile"
            if not (rdir / "reconcile.json").exists():
                _cli(
                    "reconcile", str(sim / "recording.zarr"), "--config", cfg,
                    "--reference", str(sim / "lds.csv"), "--out", str(rdir), "--seed", str(seed),
                    *_twins_flag(), log=log,
                )  # fmt: skip
            r = json.loads((rdir / "reconcile.json").read_text())
            row["reconcile"] = _names(r["effects"])
            row["reconcile_detail"] = [
                f"{e['id']}[{','.join(map(str, e.get('plates', [])))}{''.join(e.get('axes', []))}]"
                for e in r["effects"]
            ]
            row["reconcile_outside"] = [
                lv["metric"] for lv in r["levels"] if lv.get("verdict") in ("still apart", "reconciled")
            ]
    except Exception as err:  # one failed record never stops the others
        row["error"] = str(err)
    row["seconds"] = time.perf_counter() - t0
    (rec / "row.json").write_text(json.dumps(row, indent=1))
    return row


def prewarm(configs, duration: float, twins: int, workers: int) -> None:
    """Simulate, extract and diagnose each config's twins (`jaxdefl.reconcile.chain`) once, as
    `diagnose --config` and `reconcile` will ask for them (same settings, so the same cache)."""
    sys.path.insert(0, str(SRC))
    from jaxdefl.pipeline import _camera_facts
    from jaxdefl.reconcile.chain import chain_null
    from jaxdefl.settings import DiagnoseSettings

    for c in configs:
        cfg = ROOT / "configs" / f"{c}.toml"
        settings = DiagnoseSettings().with_camera(_camera_facts(cfg))
        chain_null(cfg, settings, clip_s=min(60.0, duration), k=twins, with_reference=True, workers=workers)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", required=True)
    ap.add_argument("--configs", nargs="+", default=list(CONFIGS), choices=CONFIGS)
    ap.add_argument("--duration", type=float, default=180.0, help="recording length, s")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", type=Path, default=None, help="work directory (kept; reruns resume)")
    ap.add_argument("--skip-reconcile", action="store_true")
    ap.add_argument("--twins", type=int, default=4, help="twins of the config (the CLI's --twins)")
    ap.add_argument("--report-only", action="store_true", help="print the records of --out finished so far")
    ap.add_argument("--src", type=Path, default=None, help="the jaxdefl source tree to run (a baseline)")
    args = ap.parse_args()
    global SRC, TWINS
    SRC = args.src if args.src is not None else SRC
    TWINS = args.twins
    out = args.out or Path(tempfile.mkdtemp(prefix="fullchain_"))
    jobs = [(c, s) for s in args.seeds for c in args.configs]
    print(f"{len(jobs)} records ({args.duration:g} s each) -> {out}", flush=True)
    t0 = time.perf_counter()
    if (
        args.twins > 0 and SRC == ROOT / "src" and not args.report_only
    ):  # the twins of each config once, before the records share them
        os.environ.setdefault("JAXDEFL_CACHE", str(out / "cache"))
        prewarm(args.configs, args.duration, args.twins, args.workers)
        print(f"twins ready ({time.perf_counter() - t0:.0f} s)", flush=True)
    if args.report_only:  # the records finished so far (a run stopped early)
        rows = [json.loads(p.read_text()) for c, s in jobs if (p := out / f"{c}_s{s}" / "row.json").exists()]
    else:
        with ThreadPoolExecutor(args.workers) as pool:
            rows = list(
                pool.map(lambda j: run_record(j[0], j[1], args.duration, out, not args.skip_reconcile), jobs)
            )
    totals = {"diagnose": Counter(), "reconcile": Counter()}
    flagged = Counter()
    print(f"\n{'record':24s} {'diagnose: false names':50s} reconcile: false names")
    for r in rows:
        name = f"{r['config']} s{r['seed']}"
        if "error" in r:
            print(f"{name:24s} ERROR {r['error']}")
            continue
        for step in totals:
            totals[step].update(r.get(step, []))
            flagged[step] += bool(r.get(step))
        rd = ", ".join(r.get("reconcile_detail", [])) or "-"
        print(f"{name:24s} {', '.join(r['diagnose_detail']) or '-':50s} {rd}")
        if r.get("diagnose_nominal"):
            print(f"{'':24s}   nominal physics (within the twins): {', '.join(r['diagnose_nominal'])}")
        if r.get("diagnose_unnamed"):
            print(f"{'':24s}   unnamed (not names): {', '.join(r['diagnose_unnamed'])}")
        if r.get("reconcile_outside"):
            print(f"{'':24s}   reconcile metrics outside the null band: {', '.join(r['reconcile_outside'])}")
    n = sum("error" not in r for r in rows)
    for step, c in totals.items():
        if step == "reconcile" and args.skip_reconcile:
            continue
        per_id = ", ".join(f"{k} {v}" for k, v in c.most_common()) or "none"
        print(
            f"{step}: {sum(c.values())} false names in {n} records "
            f"({flagged[step]} records with any); per id: {per_id}"
        )
    print(f"{time.perf_counter() - t0:.0f} s wall")


if __name__ == "__main__":
    main()
