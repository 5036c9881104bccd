"""Which recursive estimator for `jaxdefl monitor`: the extended Kalman filter with slow process
noise against recursive least squares with forgetting, on the same simulated record.

    PYTHONPATH=src python experiments/monitor_estimators.py [--rate 20] [--seed 2]
                                                            [--figure monitor_estimators.png]

Record: the live simulated camera (Experiment II, 3 Hz, SR4000-class ToF at --rate, calibrated
centroid noise, 70 % of it shared by the plates of a frame, 3 % drop-outs), 900 s, fatigue off;
at 300 s the frequency drops by 0.1 % (below what the alarms need: a drift the tracker must
follow), at 600 s every amplitude rises by 2 %. Estimators (`jaxdefl.monitor.estimator`, both
started from the same batch fit of the first 10 s):

- ``ekf``: random walks on f0 (2e-5 Hz/√s), the amplitudes (5e-4 /√s) and offsets (2e-3 mm/√s);
- ``rls 60 s`` and ``rls 20 s``: exponential forgetting with those time constants.

Printed per estimator: on the stationary part (120–300 s) the RMS error of f0 and of plate 7's z
amplitude against the truth, their mean reported σ and the share of frames whose error is within
1 σ (with a memory of minutes one record is nearly one draw: not a calibration test, which the
tests make on many blocks and seeds); after each step, the time until the error stays below 1/e of
the step; the mean update time per frame.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from threadpoolctl import threadpool_limits

from jaxdefl.monitor import Layout, TrackerSettings, fit_span, initial_state
from jaxdefl.simulate import camera_blocks, config_from_dict


def settle(t, err, t_step, step):
    """Seconds after ``t_step`` until |err| stays below |step|/e."""
    after = t >= t_step
    bad = after & (np.abs(err) > abs(step) / np.e)
    if not bad.any():
        return 0.0
    return float(t[bad][-1] - t_step)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--rate", type=float, default=20.0)
    ap.add_argument("--seed", type=int, default=2)
    ap.add_argument("--figure", default="monitor_estimators.png")
    a = ap.parse_args()
    f0, df, da = 3.0680, -0.001, 0.02
    cfg = config_from_dict(
        {
            "camera": {"frame_rate_hz": a.rate},
            "fatigue": {"law": "none"},
            "change": [
                {"kind": "stiffness", "t_s": 300.0, "f0_change": df, "amplitude_change": 0.0},
                {"kind": "stiffness", "t_s": 600.0, "f0_change": 0.0, "amplitude_change": da},
            ],
        },
        "study",
    )
    parts = list(camera_blocks(cfg, 900.0, a.seed, block_frames=1200))
    t = np.concatenate([p[0] for p in parts])
    Y = np.concatenate([p[1][..., [2, 0, 1]].reshape(len(p[0]), -1) for p in parts])
    lay = Layout(tuple(range(1, 14)), ("z", "x", "y"))
    tau = t - cfg.t0_s
    f_true = np.where(tau >= 300, f0 * (1 + df), f0)
    a_true = cfg.loading.amplitude_mm * np.where(tau >= 600, 1 + da, 1.0)  # plate 7: shape 1
    n0 = int(np.searchsorted(t, t[0] + 10.0))
    start = fit_span(t[:n0], Y[:n0], lay)
    j7 = 6 * 3  # plate 7, z
    methods = {
        "ekf": TrackerSettings(method="ekf"),
        "rls 60 s": TrackerSettings(method="rls", memory_s=60.0),
        "rls 20 s": TrackerSettings(method="rls", memory_s=20.0),
    }
    out = {}
    with threadpool_limits(1, user_api="blas"):
        for name, st in methods.items():
            tr = initial_state(t[:n0], Y[:n0], start, st)
            m = len(t) - n0
            fe, fs, ae, as_ = (np.empty(m) for _ in range(4))
            c0 = time.perf_counter()
            for k in range(n0, len(t)):
                tr.update(t[k], Y[k])
                e = tr.estimates()
                i = k - n0
                fe[i], fs[i] = e["f0_hz"][0] - f_true[k], e["sigma_f0_hz"][0]
                ae[i], as_[i] = e["amplitude_mm"][j7] - a_true[k], e["sigma_amplitude_mm"][j7]
            per_frame = (time.perf_counter() - c0) / m
            out[name] = (fe, fs, ae, as_, per_frame)
    tt = tau[n0:]
    stat = (tt >= 120) & (tt < 300)
    print(f"record: {len(t)} frames at {a.rate:g} Hz, 39 series; seed {a.seed}")
    print(
        f"{'estimator':10s} {'f0 RMS err':>11s} {'mean σ_f0':>10s} {'|e|<σ':>6s} {'A7 RMS err':>11s} "
        f"{'mean σ_A':>9s} {'|e|<σ':>6s} {'f0 step':>8s} {'A step':>7s} {'ms/frame':>9s}"
    )
    for name, (fe, fs, ae, as_, pf) in out.items():
        s_f = settle(tt, fe, 300.0, df * f0)
        s_a = settle(tt, ae, 600.0, da * cfg.loading.amplitude_mm)
        print(
            f"{name:10s} {np.sqrt(np.mean(fe[stat] ** 2)):11.2e} {np.mean(fs[stat]):10.2e} "
            f"{np.mean(np.abs(fe[stat]) < fs[stat]):6.2f} {np.sqrt(np.mean(ae[stat] ** 2)):11.4f} "
            f"{np.mean(as_[stat]):9.4f} {np.mean(np.abs(ae[stat]) < as_[stat]):6.2f} "
            f"{s_f:7.0f}s {s_a:6.0f}s {1e3 * pf:9.3f}"
        )
    if a.figure:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
        for name, (fe, fs, ae, as_, _) in out.items():
            (ln,) = ax1.plot(tt, 1e3 * fe, lw=0.8, label=name)
            ax1.fill_between(tt, -1e3 * fs, 1e3 * fs, color=ln.get_color(), alpha=0.15)
            ax2.plot(tt, ae, lw=0.8, color=ln.get_color(), label=name)
            ax2.fill_between(tt, -as_, as_, color=ln.get_color(), alpha=0.15)
        ax1.set_ylabel("f0 error (mHz), ±σ bands")
        ax2.set_ylabel("plate 7 A_z error (mm), ±σ")
        ax2.set_xlabel("time (s): f0 −0.1 % at 300 s, amplitudes +2 % at 600 s")
        ax1.legend()
        fig.tight_layout()
        fig.savefig(a.figure, dpi=90)
        print(f"figure: {a.figure}")


if __name__ == "__main__":
    main()
