"""Benchmark bulk reprocessing: a scaled 11-day campaign end to end.

Days x 10 min at 20 Hz, 13 plates, 3 axes, 3 % drop-outs, LDS under five plates; amplitudes
grow with the load cycles as in the thesis' Table 6.16. Runs `jaxdefl run` in-process and with
1 and 2 dask workers (LocalCluster) in the same session, and the in-process run for 2 and 11
days in fresh processes to compare peak memory against campaign length.

Usage: python experiments/bench_bulk.py [--days 11] [--minutes 10] [--window 60]
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

CYCLES = [32400, 60050, 92450, 154200, 226400, 280000, 332900, 391000, 486400, 677400, 880286]
AMPS = [2.37, 2.42, 2.43, 2.44, 2.46, 2.465, 2.47, 2.48, 2.48, 2.54, 2.55]


def make_campaign(root: Path, days: int, minutes: float, window_s: float) -> Path:
    from jaxdefl.io import write_trajectory
    from jaxdefl.synthetic import harmonic_experiment

    lines = [f'[campaign]\nname = "bench-{days}d"\n', f"[processing]\nwindow_s = {window_s}\n"]
    for d in range(1, days + 1):
        traj, lds = harmonic_experiment(
            duration_s=60 * minutes, seed=d, amplitude_mm=AMPS[(d - 1) % 11], t0=1.7e9 + 86400 * d
        )
        write_trajectory(traj, root / f"traj{d:02d}.csv")
        write_trajectory(lds, root / f"lds{d:02d}.csv")
        lines.append(
            f'[[recording]]\nday = {d}\ncamera = "cam2"\ncycles = {CYCLES[(d - 1) % 11]}\n'
            f'trajectories = "traj{d:02d}.csv"\nlds = "lds{d:02d}.csv"\n'
        )
    cfg = root / "campaign.toml"
    cfg.write_text("\n".join(lines))
    return cfg


_CHILD = """
import resource, sys, time, json
from jaxdefl.bulk import load_campaign, run_campaign
t = time.perf_counter()
units = run_campaign(load_campaign(sys.argv[1]), sys.argv[2], scheduler=sys.argv[3], progress=False)
print(json.dumps({"seconds": time.perf_counter() - t, "ok": int((units["status"] == "ok").sum()),
                  "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""


def run(cfg: Path, out: Path, scheduler: str) -> dict:
    if out.exists():
        shutil.rmtree(out)
    res = subprocess.run(
        [sys.executable, "-c", _CHILD, str(cfg), str(out), scheduler],
        capture_output=True,
        text=True,
        check=True,
    )
    return json.loads(res.stdout.strip().splitlines()[-1])


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--days", type=int, default=11)
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--window", type=float, default=60.0)
    ap.add_argument("--schedulers", default="none,local:1,local:2", help="comma list; 'none' is required")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        (tmp / "full").mkdir()
        (tmp / "short").mkdir()
        t0 = time.perf_counter()
        cfg = make_campaign(tmp / "full", args.days, args.minutes, args.window)
        short = make_campaign(tmp / "short", 2, args.minutes, args.window)
        print(
            f"campaign: {args.days} days x {args.minutes:g} min at 20 Hz, 13 plates, windows of "
            f"{args.window:g} s (made in {time.perf_counter() - t0:.1f} s)"
        )
        windows = args.days * 13 * 3 * int(60 * args.minutes // args.window)
        rows = {}
        scheds = ["none"] + [x for x in args.schedulers.split(",") if x and x != "none"]
        for sched in scheds:
            r = run(cfg, tmp / f"out-{sched.replace(':', '')}", sched)
            rows[sched] = r
            print(
                f"scheduler {sched:8s}: {r['seconds']:7.1f} s, {args.days / r['seconds'] * 60:6.2f} days/min, "
                f"{windows / r['seconds']:8.0f} windows/s, units ok {r['ok']}/{args.days}, "
                f"driver peak RSS {r['peak_rss_mb']:.0f} MB"
            )
        base = rows["none"]["seconds"]
        for sched in scheds[1:]:
            print(
                f"speed-up {sched}: {base / rows[sched]['seconds']:.2f}x "
                "(cluster start-up and per-worker JIT compilation included)"
            )
        r2 = run(short, tmp / "out-short", "none")
        print(
            f"peak RSS in-process: 2 days {r2['peak_rss_mb']:.0f} MB, {args.days} days "
            f"{rows['none']['peak_rss_mb']:.0f} MB (ratio {rows['none']['peak_rss_mb'] / r2['peak_rss_mb']:.2f})"
        )


if __name__ == "__main__":
    main()
