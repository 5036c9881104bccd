"""Benchmark bulk reprocessing: the eleven-day campaign end to end against the per-window loop.

The campaign of issue 27: days x 30 min at 20 Hz, 13 plates, x/y/z, 3 % drop-outs, 60-s windows
(11 days: 12,870 windows, 5.1 M rows), listed as [[recording]] entries; amplitudes grow with
the load cycles as in the thesis' Table 6.16. ``--lds`` adds the 300-Hz LDS tables under five
plates (the LDS comparison stage; 2.7 M rows a day more).

In the same run:
- `jaxdefl run` in a fresh process (the wall time of the process, imports and JIT compilation
  included), in-process and on dask (``--schedulers``, LocalCluster workers), with each one's
  peak memory (the driver's, and the workers' on dask), and for 2 days against the full length;
- the stage breakdown of the in-process run, summed over the units (from their manifests):
  reading, validation and clock checks, windowing, kernel (periodogram + fit), whole-record fit,
  residual statistics, LDS comparison, writing and manifest, aggregate (zarr, figures, report);
- the loop a user writes today, end to end: pandas reads each table, then per window (and
  per whole record) astropy's LombScargle ('fast') for the start frequency and scipy's
  least_squares ('lm') on [C, D, E, ω], as in `bench_fit.py`. Reading is timed in full, the fits
  on ``--loop-sample`` windows and ``--loop-whole`` whole records per round, scaled to all.
Rounds (``--rounds``) alternate jaxdefl and the loop; the speed-up printed is their median. The
CPU times (jaxdefl's process with all its threads; the loop's, scaled like its wall time) are
printed beside: their ratio depends less on what else the machine runs.

Usage: python experiments/bench_bulk.py [--days 11] [--minutes 30] [--window 60] [--rounds 3]
                                        [--schedulers none,local:2] [--lds]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

CYCLES = [32400, 60050, 92450, 154200, 226400, 280000, 332900, 391000, 486400, 677400, 880286]
AMPS = [2.37, 2.42, 2.43, 2.44, 2.46, 2.465, 2.47, 2.48, 2.48, 2.54, 2.55]
STAGES = [
    ("reading", "reading"),
    ("validation", "validation and clock checks"),
    ("windowing", "windowing"),
    ("kernel", "kernel (periodogram + fit)"),
    ("whole-record fit", "whole-record fit"),
    ("residual", "residual statistics"),
    ("LDS comparison", "LDS comparison"),
    ("writing", "writing and manifest"),
    ("aggregate", "aggregate (zarr, figures, report)"),
]


def make_campaign(root: Path, days: int, minutes: float, window_s: float, lds: bool = False) -> Path:
    from jaxdefl.io import write_trajectory
    from jaxdefl.synthetic import harmonic_experiment

    root.mkdir(parents=True, exist_ok=True)
    lines = [f'[campaign]\nname = "bench-{days}d"\n', f"[processing]\nwindow_s = {window_s}\n"]
    for d in range(1, days + 1):
        traj, ref = harmonic_experiment(
            duration_s=60 * minutes,
            seed=d,
            amplitude_mm=AMPS[(d - 1) % 11],
            t0=1.7e9 + 86400 * d,
            lds_rate_hz=300.0 if lds else 1.0,
        )
        write_trajectory(traj, root / f"traj{d:02d}.csv")
        entry = (
            f'[[recording]]\nday = {d}\ncamera = "cam2"\ncycles = {CYCLES[(d - 1) % 11]}\n'
            f'trajectories = "traj{d:02d}.csv"\n'
        )
        if lds:
            write_trajectory(ref, root / f"lds{d:02d}.csv")
            entry += f'lds = "lds{d:02d}.csv"\n'
        lines.append(entry)
    cfg = root / "campaign.toml"
    cfg.write_text("\n".join(lines))
    return cfg


# The run in a fresh process. On dask the cluster is started here, so that the workers' peak
# memory can be read after the run; the aggregate stage is timed by wrapping `gather`.
_CHILD = """
import json, resource, sys, time
t_start = time.perf_counter()
import jaxdefl.bulk.aggregate as agg
import jaxdefl.bulk.runner as runner
from jaxdefl.bulk import load_campaign, run_campaign
spent = {}
_gather = agg.gather
def gather(*a, **k):
    t = time.perf_counter()
    try:
        return _gather(*a, **k)
    finally:
        spent["aggregate"] = time.perf_counter() - t
agg.gather = gather
sched = sys.argv[3]
workers_mb = []
cluster = None
if sched.startswith("local"):
    from dask.distributed import Client, LocalCluster
    n = int(sched.partition(":")[2] or 2)
    cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None,
                           silence_logs=40)
    sched = cluster.scheduler_address
t = time.perf_counter()
units = run_campaign(load_campaign(sys.argv[1]), sys.argv[2], scheduler=sched, progress=False)
run_s = time.perf_counter() - t
if cluster is not None:
    with Client(cluster) as c:
        got = c.run(lambda: resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)
        workers_mb = sorted(got.values())
    cluster.close()
print(json.dumps({"run_s": run_s, "in_process_s": time.perf_counter() - t_start,
                  "ok": int((units["status"] == "ok").sum()), "aggregate_s": spent.get("aggregate", 0.0),
                  "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                  "workers_peak_rss_mb": workers_mb}))
"""


def run(cfg: Path, out: Path, scheduler: str, cache: str) -> dict:
    """`jaxdefl run` in a fresh process: its wall time from the parent, python start included.
    ``cache`` is the persistent JIT cache directory ("" for none)."""
    if out.exists():
        shutil.rmtree(out)
    env = {**os.environ, "JAXDEFL_CACHE_DIR": cache}
    cpu0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    res = subprocess.run(
        [sys.executable, "-c", _CHILD, str(cfg), str(out), scheduler],
        capture_output=True,
        text=True,
        env=env,
    )
    wall = time.perf_counter() - t0
    cpu1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    if res.returncode:
        raise SystemExit(f"jaxdefl run failed ({scheduler}):\n{res.stderr[-3000:]}")
    r = json.loads(res.stdout.strip().splitlines()[-1])
    r["wall_s"] = wall
    r["cpu_s"] = (cpu1.ru_utime - cpu0.ru_utime) + (cpu1.ru_stime - cpu0.ru_stime)  # all threads
    stages: dict[str, float] = {}
    for man in sorted((out / "units").glob("*/manifest.json")):
        for k, v in json.loads(man.read_text()).get("stage_seconds", {}).items():
            stages[k] = stages.get(k, 0.0) + v
    stages["aggregate"] = r["aggregate_s"]
    r["stages"] = stages
    return r


def _loop_fit(t: np.ndarray, y: np.ndarray, n_freq: int | None) -> np.ndarray:
    """The per-window fit a user writes: astropy for the start, scipy's 'lm' for the optimum."""
    from astropy.timeseries import LombScargle
    from scipy.optimize import least_squares

    span = t[-1] - t[0]
    df = 1 / (5 * span)
    freq = np.arange(1, int(10.0 / df) + 1) * df if n_freq is None else np.arange(1, n_freq + 1) * df
    freq = freq[freq <= 10.0]
    ls = LombScargle(t, y, fit_mean=False, center_data=True, normalization="standard")
    f = freq[np.argmax(ls.power(freq, method="fast"))]
    om = 2 * np.pi * f
    t = t - 0.5 * (t[0] + t[-1])
    g = np.stack([np.cos(om * t), np.sin(om * t), np.ones_like(t)], 1)
    c, d, e = np.linalg.lstsq(g, y, rcond=None)[0]

    def res(p):
        return y - (p[0] * np.cos(p[3] * t) + p[1] * np.sin(p[3] * t) + p[2])

    return least_squares(res, [c, d, e, om], method="lm").x


def run_loop(cfg_dir: Path, days: int, window_s: float, rng, n_windows: int, n_whole: int) -> dict:
    """The loop end to end: every table read by pandas (timed in full); the window and whole-
    record fits timed on random samples and scaled to the campaign."""
    import pandas as pd

    t0, c0 = time.perf_counter(), time.process_time()
    tables = [pd.read_csv(cfg_dir / f"traj{d:02d}.csv") for d in range(1, days + 1)]
    t_read, c_read = time.perf_counter() - t0, time.process_time() - c0
    series = []  # (t, y, window bounds) of every day, plate and axis
    for tab in tables:
        t_first = tab["t"].min()  # windows start together on every plate, as jaxdefl's do
        n_win = int((tab["t"].max() - t_first + 0.05 - window_s) // window_s + 1)
        for _, g in tab.groupby("plate"):
            t = g["t"].to_numpy()
            for axis in ("z", "x", "y"):
                series.append((t, g[axis].to_numpy(), t_first, n_win))
    all_windows = [(i, k) for i, s in enumerate(series) for k in range(s[3])]
    pick = rng.choice(len(all_windows), size=min(n_windows, len(all_windows)), replace=False)
    t0, c0 = time.perf_counter(), time.process_time()
    for j in pick:
        i, k = all_windows[j]
        t, y, t_first, _ = series[i]
        lo, hi = np.searchsorted(t, [t_first + k * window_s, t_first + (k + 1) * window_s])
        _loop_fit(t[lo:hi], y[lo:hi], 3000)
    t_win = (time.perf_counter() - t0) * len(all_windows) / pick.size
    c_win = (time.process_time() - c0) * len(all_windows) / pick.size
    whole = rng.choice(len(series), size=min(n_whole, len(series)), replace=False)
    t0, c0 = time.perf_counter(), time.process_time()
    for i in whole:
        _loop_fit(series[i][0], series[i][1], None)
    t_whole = (time.perf_counter() - t0) * len(series) / whole.size
    c_whole = (time.process_time() - c0) * len(series) / whole.size
    return {
        "read_s": t_read,
        "windows_s": t_win,
        "whole_s": t_whole,
        "n_windows": len(all_windows),
        "cpu_s": c_read + c_win + c_whole,
    }


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--days", type=int, default=11)
    ap.add_argument("--minutes", type=float, default=30.0)
    ap.add_argument("--window", type=float, default=60.0)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--loop-sample", type=int, default=300, help="loop windows per round")
    ap.add_argument("--loop-whole", type=int, default=4, help="loop whole-record fits per round")
    ap.add_argument("--lds", action="store_true", help="add 300-Hz LDS tables (LDS comparison)")
    ap.add_argument("--schedulers", default="none,local:2", help="comma list; 'none' is required")
    ap.add_argument(
        "--no-cache",
        action="store_true",
        help="no persistent JIT cache (every run compiles); by default a fresh cache directory is "
        "filled by round 1 (cold) and used by the later rounds, as a user's second run would",
    )
    args = ap.parse_args()
    print(f"load: {os.getloadavg()[0]:.1f} {os.getloadavg()[1]:.1f} {os.getloadavg()[2]:.1f} (1/5/15 min)")
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        t0 = time.perf_counter()
        cfg = make_campaign(tmp / "full", args.days, args.minutes, args.window, args.lds)
        short = make_campaign(tmp / "short", 2, args.minutes, args.window, args.lds)
        n_rows = args.days * 13 * int(round(60 * args.minutes * 20) * 0.97)
        print(
            f"campaign: {args.days} days x {args.minutes:g} min at 20 Hz, 13 plates, x/y/z, windows of "
            f"{args.window:g} s, ~{n_rows / 1e6:.1f} M rows{' + LDS at 300 Hz' if args.lds else ''} "
            f"(made in {time.perf_counter() - t0:.1f} s)"
        )
        cache = "" if args.no_cache else str(tmp / "jit-cache")
        rng = np.random.default_rng(27)
        ratios, runs, cpu_ratios = [], [], []
        for k in range(args.rounds):
            r = run(cfg, tmp / "out-none", "none", cache)
            lp = run_loop(tmp / "full", args.days, args.window, rng, args.loop_sample, args.loop_whole)
            loop_s = lp["read_s"] + lp["windows_s"] + lp["whole_s"]
            ratios.append(loop_s / r["wall_s"])
            cpu_ratios.append(lp["cpu_s"] / r["cpu_s"])
            runs.append(r)
            cold = " (cold JIT cache)" if k == 0 and cache else ""
            print(
                f"round {k + 1}{cold}: jaxdefl run {r['wall_s']:6.1f} s (fresh process; "
                f"{r['ok']}/{args.days} units "
                f"ok, peak RSS {r['peak_rss_mb']:.0f} MB) | loop {loop_s:6.1f} s (read {lp['read_s']:.1f}, "
                f"{lp['n_windows']} windows {lp['windows_s']:.1f}, whole records {lp['whole_s']:.1f}) | "
                f"speed-up {loop_s / r['wall_s']:5.1f}x "
                f"(windows alone {lp['windows_s'] / r['wall_s']:.1f}x) | "
                f"CPU time jaxdefl {r['cpu_s']:.1f} s (all threads), loop {lp['cpu_s']:.1f} s: "
                f"{cpu_ratios[-1]:.1f}x | load {os.getloadavg()[0]:.1f}"
            )
        print(
            f"speed-up of jaxdefl run over the loop: median {np.median(ratios):.1f}x "
            f"(rounds: {', '.join(f'{x:.1f}' for x in ratios)}); CPU-time ratio median "
            f"{np.median(cpu_ratios):.1f}x (rounds: {', '.join(f'{x:.1f}' for x in cpu_ratios)}; less "
            "sensitive to the machine's load: jaxdefl's CPU time counts all its threads)"
        )
        best = runs[int(np.argsort([r["wall_s"] for r in runs])[len(runs) // 2])]  # the median run
        print(
            f"stages of the median in-process run ({best['wall_s']:.1f} s in all; python start, "
            f"imports and JIT compilation {best['wall_s'] - best['run_s']:.1f} s outside the run "
            f"and inside the first unit's stages):"
        )
        total = sum(best["stages"].values())
        for key, label in STAGES:
            v = best["stages"].get(key, 0.0)
            print(f"  {label:36s} {v:7.2f} s  {100 * v / max(total, 1e-9):5.1f} %")
        print(
            f"  {'sum of stages':36s} {total:7.2f} s (thread time: two units run at once); "
            f"run_campaign {best['run_s']:.2f} s"
        )
        rows = {"none": best}
        for sched in [x for x in args.schedulers.split(",") if x and x != "none"]:
            r = run(cfg, tmp / f"out-{sched.replace(':', '')}", sched, cache)
            rows[sched] = r
            print(
                f"scheduler {sched}: {r['wall_s']:.1f} s fresh process, units ok {r['ok']}/{args.days}, "
                f"peak RSS driver {r['peak_rss_mb']:.0f} MB, workers "
                + ", ".join(f"{m:.0f}" for m in r["workers_peak_rss_mb"])
                + " MB (cluster start-up and per-worker JIT compilation included)"
            )
        r2 = run(short, tmp / "out-short", "none", cache)
        print(
            f"peak RSS in-process: 2 days {r2['peak_rss_mb']:.0f} MB, {args.days} days "
            f"{best['peak_rss_mb']:.0f} MB (ratio {best['peak_rss_mb'] / r2['peak_rss_mb']:.2f})"
        )
        for sched in rows:
            if sched != "none":
                r2d = run(short, tmp / "out-short", sched, cache)
                print(
                    f"peak RSS on {sched}: 2 days max worker {max(r2d['workers_peak_rss_mb']):.0f} MB, "
                    f"{args.days} days max worker {max(rows[sched]['workers_peak_rss_mb']):.0f} MB"
                )
    print(f"load at the end: {os.getloadavg()[0]:.1f} {os.getloadavg()[1]:.1f} {os.getloadavg()[2]:.1f}")


if __name__ == "__main__":
    main()
