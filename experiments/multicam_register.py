"""Registration of the two-camera Experiment I against the simulator's truth, over seeds.

For each seed: `jaxdefl simulate configs/exp1_two_cameras.toml` (both cameras), `jaxdefl
extract` of each camera, `jaxdefl register` with the LDS; prints per camera the pose errors
(mrad, mm) and their ratio to the stated σ, the clock offset error (ms) and its ratio to σ, and
plate 7's amplitude from the two cameras with their combined σ. Also the wall time of
registration against extraction (the peer in the same run).

    PYTHONPATH=src python experiments/multicam_register.py --seeds 2 3 4 5 6 --duration 25
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

from jaxdefl.cli import main
from jaxdefl.report.multicam import fit_beam_shape

CONFIG = Path(__file__).parents[1] / "configs" / "exp1_two_cameras.toml"


def run(seed: int, duration: float, work: Path) -> list[dict]:
    out = work / f"s{seed}"
    assert (
        main(["simulate", str(CONFIG), "--out", str(out), "--seed", str(seed), "--duration", str(duration)])
        == 0
    )
    t = time.perf_counter()
    for cam in ("cam3", "cam4"):
        assert main(["extract", str(out / f"{cam}.zarr"), "--out", str(out / f"{cam}_traj.csv")]) == 0
    t_extract = time.perf_counter() - t
    t = time.perf_counter()
    args = ["register", str(out / "cam3.zarr"), str(out / "cam4.zarr")]
    args += ["--trajectory", str(out / "cam3_traj.csv"), "--trajectory", str(out / "cam4_traj.csv")]
    args += ["--config", str(CONFIG), "--lds", str(out / "lds.csv"), "--out", str(out / "reg")]
    assert main(args) == 0
    t_register = time.perf_counter() - t
    truth = {p["camera"]: p for p in json.loads((out / "cameras.json").read_text())}
    t0 = json.loads((out / "reg" / "registration.json").read_text())["reference"]["t0_s"]
    poses = pd.read_csv(out / "reg" / "poses.csv")
    clocks = pd.read_csv(out / "reg" / "clocks.csv").set_index("camera")
    common = pd.read_csv(out / "reg" / "common.csv").set_index("plate")
    prof = pd.read_csv(out / "reg" / "profile.csv")
    p7 = prof[(prof["plate"] == 7) & prof["source"].isin(["cam3", "cam4"])]
    cams = prof[prof["source"].isin(["cam3", "cam4"])]
    midspan = fit_beam_shape(cams["x_mm"], cams["amplitude_mm"], cams["sigma_amplitude_mm"], 3400.0, 1200.0)
    rows = []
    for cam, tr in truth.items():
        want = [np.radians(tr[k]) * 1e3 for k in ("roll_deg", "pitch_deg", "yaw_deg")] + tr["origin_mm"]
        got = poses[poses["camera"] == cam]
        err = got["value"].to_numpy() - np.array(want)
        rows.append(
            dict(
                seed=seed,
                camera=cam,
                max_angle_err_mrad=np.abs(err[:3]).max(),
                max_pos_err_mm=np.abs(err[3:]).max(),
                max_pull=np.abs(err / got["sigma"].to_numpy()).max(),
                pulls=np.round(err / got["sigma"].to_numpy(), 2).tolist(),
                clock_err_ms=clocks.loc[cam, "offset_ms"] - tr["clock_offset_ms"],
                clock_sigma_ms=clocks.loc[cam, "sigma_offset_ms"],
                # the clock's error mid-recording, where the data pin it
                mid_err_ms=clocks.loc[cam, "offset_mid_ms"]
                - (tr["clock_offset_ms"] + tr["clock_drift_ppm"] * 1e-3 * (clocks.loc[cam, "t_mid_s"] - t0)),
                mid_sigma_ms=clocks.loc[cam, "sigma_offset_mid_ms"],
                rate_err_ppm=clocks.loc[cam, "rate_ppm"] - tr["clock_drift_ppm"],
                rate_sigma_ppm=clocks.loc[cam, "sigma_rate_ppm"],
                p7_A_mm=float(p7.loc[p7["source"] == cam, "amplitude_mm"].iloc[0]),
                p7_sigma_mm=float(p7.loc[p7["source"] == cam, "sigma_amplitude_mm"].iloc[0]),
                p7_p_amplitude=float(common.loc[7, "p_amplitude"]),
                # the elastic shape through both cameras' plates against the configured 3.85 mm
                midspan_err_mm=midspan[0] - 3.85,
                midspan_sigma_mm=midspan[1],
                t_extract_s=t_extract,
                t_register_s=t_register,
            )
        )
    return rows


def main_() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, nargs="+", default=[2, 3, 4, 5, 6])
    ap.add_argument("--duration", type=float, default=25.0)
    a = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as d:
        for s in a.seeds:
            rows += run(s, a.duration, Path(d))
    df = pd.DataFrame(rows)
    pd.set_option("display.width", 250)
    print(df.drop(columns=["pulls"]).round(3).to_string(index=False))
    pulls = np.concatenate(df["pulls"].to_list())
    print(
        f"pose: max angle error {df['max_angle_err_mrad'].max():.3f} mrad, max position error "
        f"{df['max_pos_err_mm'].max():.3f} mm; |pull| < 2 for {np.mean(np.abs(pulls) < 2):.0%} "
        f"of {len(pulls)}"
    )
    print(
        f"clock: max |offset error| {df['clock_err_ms'].abs().max():.3f} ms; "
        f"|err|/σ < 2 for {np.mean(np.abs(df['clock_err_ms'] / df['clock_sigma_ms']) < 2):.0%}"
    )
    print(
        f"clock mid-recording: max |error| {df['mid_err_ms'].abs().max():.3f} ms; "
        f"|err|/σ < 2 for {np.mean(np.abs(df['mid_err_ms'] / df['mid_sigma_ms']) < 2):.0%}"
    )
    print(f"plate 7 amplitude consistent (p >= 0.01) in {np.mean(df['p7_p_amplitude'] >= 0.01):.0%} of seeds")
    print(f"registration / extraction wall time: {df['t_register_s'].sum() / df['t_extract_s'].sum():.2f}")


if __name__ == "__main__":
    main_()
