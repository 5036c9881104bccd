"""Benchmark the estimation engine on workload W against the peers, in the same run.

W: 13 plates x 3 axes = 39 series, 60 windows of 60 s at 20 Hz with 3 % random frame drop-outs
(2340 windows, ~3000 frequencies each at 5x oversampling).

Peers:
- the per-window loop a user would write today: astropy LombScargle (method 'fast') for the
  start frequency, then scipy.optimize.least_squares ('lm') on [C, D, E, omega];
- nifty-ls's batched periodogram alone (the 39 series of a window share their timestamps).

Usage: python experiments/bench_fit.py [--windows-per-series 60] [--loop-sample 300] [--rounds 3] [--cache]
                                      [--jitter-ms 5]
``--jitter-ms`` adds W with jittered frame times against W on the perfect clock (same signal and
noise draws): time ratio, periodogram path, missing-frame fraction and agreement of the estimates.
The astropy + scipy loop is timed on --loop-sample windows per round and scaled to all of W;
rounds alternate jaxdefl, the loop and nifty-ls. The persistent JIT cache is off unless --cache,
so the first call shows the real compile time.

Measured (`python experiments/bench_fit.py --loop-sample 300 --rounds 3`, 2 cores, quiet machine
at load 0.1-2.6, 2026-11-23 13:48-14:13 UTC), five runs:

    run  steady (best of 3)  compile   rounds: speed-up vs loop   median
    1    0.621 s             4.09 s    38.6x, 32.5x, 36.8x        36.8x
    2    0.574 s             -         39.6x, 33.5x, 35.2x        35.2x
    3    0.632 s             5.59 s    32.0x, 31.6x, 34.5x        32.0x   (runs 3-5: after the
    4    0.687 s             5.31 s    29.2x, 30.0x, 34.3x        30.0x    scaling-noise fix)
    5    0.667 s             -         33.7x, 34.0x, 29.3x        33.7x

Median over the 15 rounds 33.7x; nifty-ls periodogram alone / jaxdefl 2.1-3.3.
Per round jaxdefl took 0.58-0.75 s, the loop (scaled) 19.2-25.7 s, nifty-ls 1.56-2.10 s. What
took it from ~29x to ~36x: Gauss-Newton in groups of 64 windows under `lax.map` (the loop state
stays in L2; 1.5x less CPU for the fit) and one Gauss-Newton step from the linear fit's own sines
and cosines (2 optimistix evaluations per window instead of 3).

Jitter (`python experiments/bench_fit.py --loop-sample 100 --rounds 3 --jitter-ms 5`, 2026-11-25
09:09-09:16 UTC, machine shared at load 8-13): W with 5 ms RMS of frame-time jitter against W on
the perfect clock, same draws: estimation 1.10x the perfect clock's time (median of rounds 1.10,
1.03, 1.29), windowing 2.33 s vs 1.77 s; all 2340 windows on the batched frame grid, none on the
non-uniform path; missing frames median 0.0292 (perfect clock 0.0292, true drop-out rate 3 %);
estimates differ from the perfect clock's by a median 0.07 σ (f0 and A).
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np
import pandas as pd


def make_workload(
    n_windows: int, seed: int = 0, fs: float = 20.0, dropout: float = 0.03, jitter_s: float = 0.0
):
    """W; with ``jitter_s`` the frames are taken (and stamped) at times that jitter by that RMS
    about the frame clock, shared by the plates of a frame; the signal and noise draws are the
    same as without."""
    rng = np.random.default_rng(seed)
    n = int(round(n_windows * 60 * fs))
    t = 1.7e9 + np.arange(n) / fs
    t = t[rng.random(n) > dropout]  # a dropped frame is lost for every plate
    if jitter_s:
        t = t + np.random.default_rng(seed + 1000).normal(0.0, jitter_s, t.size)
    rows = []
    for plate in range(1, 14):
        shape = np.sin(np.pi * plate / 14)
        f0 = 3.0672
        ph = rng.uniform(0, 2 * np.pi)
        z = 2.4 * shape * np.cos(2 * np.pi * f0 * (t - t[0]) + ph) + 0.76 * rng.standard_normal(t.size)
        x = 0.5 * np.cos(2 * np.pi * f0 * (t - t[0]) + ph) + 0.5 * rng.standard_normal(t.size)
        y = 0.05 * np.cos(2 * np.pi * f0 * (t - t[0]) + ph) + 0.017 * rng.standard_normal(t.size)
        rows.append(pd.DataFrame(dict(t=t, plate=plate, x=x, y=y, z=z)))
    return pd.concat(rows, ignore_index=True)


def run_jaxdefl(df):
    from jaxdefl.fit import estimate_windows
    from jaxdefl.io import validate_trajectory
    from jaxdefl.series import make_windows

    t0 = time.perf_counter()
    w = make_windows(validate_trajectory(df), window_s=60.0)
    t_win = time.perf_counter() - t0
    t0 = time.perf_counter()
    est = estimate_windows(w)
    t_first = time.perf_counter() - t0
    t_steady = np.inf
    for _ in range(3):  # steady state: the best of three runs
        t0 = time.perf_counter()
        est = estimate_windows(w)
        t_steady = min(t_steady, time.perf_counter() - t0)
    return w, est, t_win, t_first, t_steady


def run_loop(w, rows):
    from astropy.timeseries import LombScargle
    from scipy.optimize import least_squares

    out = []
    t0 = time.perf_counter()
    for r in rows:
        m = w.mask[r]
        t, y = w.t[r, m], w.y[r, m]
        T = t[-1] - t[0]
        freq = np.arange(1, 3001) / (5 * T)
        freq = freq[freq <= 10.0]
        ls = LombScargle(t, y, fit_mean=False, center_data=True, normalization="standard")
        p = ls.power(freq, method="fast")
        f = freq[np.argmax(p)]
        om = 2 * np.pi * f
        g = np.stack([np.cos(om * t), np.sin(om * t), np.ones_like(t)], 1)
        c, d, e = np.linalg.lstsq(g, y, rcond=None)[0]

        def res(p, t=t, y=y):
            return y - (p[0] * np.cos(p[3] * t) + p[1] * np.sin(p[3] * t) + p[2])

        # As a user writes it: default tolerances, finite-difference Jacobian.
        sol = least_squares(res, [c, d, e, om], method="lm")
        out.append(sol.x)
    return time.perf_counter() - t0, np.array(out)


def run_nifty(w):
    import nifty_ls

    tab = w.table
    t0 = time.perf_counter()
    for _, g in tab.groupby(["segment", "window"]).groups.items():
        g = np.asarray(g)
        m = w.mask[g[0]]
        t = w.t[g[0], m]
        ys = w.y[g][:, m] if all(w.mask[i].sum() == m.sum() for i in g) else None
        if ys is None:
            continue
        T = t[-1] - t[0]
        nifty_ls.lombscargle(
            t,
            ys,
            fmin=1 / (5 * T),
            fmax=10.0,
            Nf=3000,
            fit_mean=False,
            center_data=True,
            normalization="standard",
        )
    return time.perf_counter() - t0


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--windows-per-series", type=int, default=60)
    ap.add_argument("--loop-sample", type=int, default=300, help="windows of the loop per round")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--cache", action="store_true", help="keep jaxdefl's persistent JIT cache on")
    ap.add_argument(
        "--jitter-ms",
        type=float,
        default=0.0,
        help="also time W with this frame-time jitter (RMS) vs the perfect clock",
    )
    args = ap.parse_args()
    if not args.cache:  # the first call then shows the real compile time
        os.environ["JAXDEFL_CACHE_DIR"] = ""
    import jax

    from jaxdefl.fit import estimate_windows

    df = make_workload(args.windows_per_series)
    w, est, t_win, t_first, t_steady = run_jaxdefl(df)
    nwin = len(w)
    st = est.table["status"].value_counts().to_dict()
    compile_s = t_first - t_steady
    print(
        f"workload W: {nwin} windows ({w.t.shape[1]} samples max), jax {jax.__version__}, "
        f"devices {jax.devices()}"
    )
    print(f"statuses: {st}")
    print(f"windowing (pandas -> padded arrays):       {t_win:8.3f} s")
    print(f"jaxdefl periodogram + fit, first call:     {t_first:8.3f} s (compile ~{compile_s:.2f} s)")
    print(f"jaxdefl periodogram + fit, steady (best of 3): {t_steady:8.3f} s {nwin / t_steady:5.0f} w/s")

    # Rounds alternate the peers, so that a change of the machine's load hits both alike; each
    # round's loop runs on a fresh random sample of windows, scaled to all of W.
    rng = np.random.default_rng(1)
    ratios, df_rel, da_rel = [], 0.0, 0.0
    for k in range(args.rounds):
        t0 = time.perf_counter()
        est = estimate_windows(w)
        t_us = time.perf_counter() - t0
        sample = rng.choice(nwin, size=min(args.loop_sample, nwin), replace=False)
        t_loop_s, params = run_loop(w, sample)
        t_loop = t_loop_s * nwin / sample.size
        t_nifty = run_nifty(w)
        ratios.append(t_loop / t_us)
        print(
            f"round {k + 1}: jaxdefl {t_us:6.3f} s | astropy+scipy loop {t_loop:7.2f} s "
            f"(scaled from {sample.size}) | nifty-ls periodogram alone {t_nifty:6.3f} s | "
            f"speed-up {t_loop / t_us:5.1f}x | nifty-ls/jaxdefl {t_nifty / t_us:5.2f}"
        )
        f_ref = params[:, 3] / (2 * np.pi)
        a_ref = np.hypot(params[:, 0], params[:, 1])
        fit = est.fit
        df_rel = max(df_rel, np.nanmax(np.abs(fit.f0_hz[sample] - f_ref) / fit.sigma_f0_hz[sample]))
        da = np.abs(fit.amplitude_mm[sample] - a_ref) / fit.sigma_amplitude_mm[sample]
        da_rel = max(da_rel, np.nanmax(da))
    print(
        f"speed-up vs astropy+scipy loop: median {np.median(ratios):6.1f}x (rounds: "
        + ", ".join(f"{r:.1f}" for r in ratios)
        + ")"
    )
    print(f"max |Δf0|/σ_f0 vs loop: {df_rel:.3g}; max |ΔA|/σ_A vs loop: {da_rel:.3g}")
    if args.jitter_ms:
        jitter_comparison(args, w)


def jitter_comparison(args, w_perfect):
    """W with jittered frame times against W on the perfect clock, in the same run: windowing
    and steady-state estimation times (rounds alternate), the periodogram path taken, the
    missing-frame fraction of the honesty flags and the estimates' agreement."""
    from jaxdefl.fit import estimate_windows
    from jaxdefl.io import validate_trajectory
    from jaxdefl.series import make_windows
    from jaxdefl.uncertainty import honesty_features

    df_j = make_workload(args.windows_per_series, jitter_s=args.jitter_ms / 1000.0)
    df_p = make_workload(args.windows_per_series)
    t0 = time.perf_counter()
    w_j = make_windows(validate_trajectory(df_j), window_s=60.0)
    t_win_j = time.perf_counter() - t0
    t0 = time.perf_counter()
    w_p = make_windows(validate_trajectory(df_p), window_s=60.0)
    t_win_p = time.perf_counter() - t0
    est_j = estimate_windows(w_j)  # compile whatever shapes are new
    ratios = []
    for k in range(args.rounds):
        t0 = time.perf_counter()
        est_p = estimate_windows(w_p)
        t_p = time.perf_counter() - t0
        t0 = time.perf_counter()
        est_j = estimate_windows(w_j)
        t_j = time.perf_counter() - t0
        ratios.append(t_j / t_p)
        print(
            f"jitter round {k + 1}: perfect clock {t_p:6.3f} s | {args.jitter_ms:g} ms jitter "
            f"{t_j:6.3f} s | ratio {t_j / t_p:5.2f}"
        )
    methods = dict(zip(*np.unique(est_j.periodogram.method, return_counts=True), strict=True))
    miss_j = honesty_features(est_j)["missing"].to_numpy()
    miss_p = honesty_features(est_p)["missing"].to_numpy()
    ok = (est_j.table["status"] == "converged") & (est_p.table["status"] == "converged")
    d_f = np.abs(est_j.fit.f0_hz - est_p.fit.f0_hz)[ok] / est_p.fit.sigma_f0_hz[ok]
    d_a = np.abs(est_j.fit.amplitude_mm - est_p.fit.amplitude_mm)[ok] / est_p.fit.sigma_amplitude_mm[ok]
    print(
        f"jitter {args.jitter_ms:g} ms RMS at 20 Hz: time ratio jitter/perfect median "
        f"{np.median(ratios):.2f} "
        f"(rounds: {', '.join(f'{r:.2f}' for r in ratios)}); windowing {t_win_j:.2f} s vs {t_win_p:.2f} s"
    )
    print(
        f"  periodogram paths {methods}; on the frame grid {int(w_j.on_clock.sum())}/{len(w_j)}; "
        f"missing frames median {np.median(miss_j):.4f} (perfect clock {np.median(miss_p):.4f}, "
        f"max {miss_j.max():.4f})"
    )
    print(
        f"  converged {int(ok.sum())}/{len(ok)}; jitter vs perfect clock: "
        f"median |Δf0|/σ {np.median(d_f):.3f}, "
        f"median |ΔA|/σ {np.median(d_a):.3f}"
    )


if __name__ == "__main__":
    main()
