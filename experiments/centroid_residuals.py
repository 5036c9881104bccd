"""Plate-centroid residual sigma of simulated ToF recordings against the thesis' tables.

For every setting of Table 6.2 (Experiment I, 1 Hz), Table 6.7 (3 Hz) and Experiment II's Day 1
(Tables 6.12, 6.17): render the session's frames (`configs/exp1.toml`: 500 frames, as the thesis;
Experiment II: ``--duration`` seconds), take the plate centroids with the simulator's reference
extraction (`simulate.measured_centroids`), fit them with the engine (`jaxdefl fit`'s
`estimate_table`, one window) and print sigma_residual_mm of plate 7 and the median plate next to
the thesis' value.

    python experiments/centroid_residuals.py [--out FILE.csv] [--duration 60] [--quick]

``--quick`` runs the 20 Hz settings only.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import pandas as pd

from jaxdefl.fit import estimate_table
from jaxdefl.io import read_trajectory, write_trajectory
from jaxdefl.simulate import load_config, measured_centroids, render_frames
from jaxdefl.simulate.tof import TABLE_6_2_MM, TABLE_6_7_MM, TABLE_6_12_RESIDUAL_MM, TABLE_6_17_RESIDUAL_MM

CONFIGS = Path(__file__).parents[1] / "configs"


def residuals(config: str, session: str, duration_s: float | None, seed: int = 5) -> pd.Series:
    cfg = load_config(CONFIGS / config, session)
    t, frames, _, _ = render_frames(cfg, duration_s=duration_s, seed=seed)
    df = measured_centroids(cfg, t, frames)
    df = df[df.plate.isin(cfg.camera.plates)]
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "traj.csv"
        write_trajectory(df, path)
        est = estimate_table(read_trajectory(path), axes=("z",)).table
    est = est[est.status == "converged"]
    return est.set_index("plate").sigma_residual_mm, len(t)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--duration", type=float, default=60.0, help="Experiment II seconds")
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args(argv)
    cases = []
    for table, name, hz in ((TABLE_6_2_MM, "6.2", "1hz"), (TABLE_6_7_MM, "6.7", "3hz")):
        for cam, row in table.items():
            for fs, want in row.items():
                if args.quick and fs != 20.0:
                    continue
                cases.append((f"Table {name}", "exp1.toml", f"{cam}_{fs:.0f}fps_{hz}", None, want))
    cases.append(("Table 6.12", "exp2_tof_1hz.toml", "day1", args.duration, TABLE_6_12_RESIDUAL_MM["day1"]))
    cases.append(("Table 6.17", "exp2_tof_3hz.toml", "day1", args.duration, TABLE_6_17_RESIDUAL_MM["day1"]))
    rows = []
    for table, config, session, duration, want in cases:
        t0 = time.perf_counter()
        res, n = residuals(config, session, duration)
        row = dict(
            table=table,
            session=f"{config.removesuffix('.toml')}:{session}",
            frames=n,
            thesis_mm=want,
            plate7_mm=round(float(res.loc[7]), 3),
            median_mm=round(float(res.median()), 3),
            ratio_plate7=round(float(res.loc[7]) / want, 3),
            seconds=round(time.perf_counter() - t0, 1),
        )
        rows.append(row)
        print(" ".join(f"{k}={v}" for k, v in row.items()), flush=True)
    df = pd.DataFrame(rows)
    print(df.to_string(index=False))
    if args.out:
        df.to_csv(args.out, index=False)
    return 0


if __name__ == "__main__":
    sys.exit(main())
