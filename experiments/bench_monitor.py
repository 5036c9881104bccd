"""Latency and sustained speed of `jaxdefl monitor` (13 plates × 3 axes, 30 Hz), next to the batch
fit of the same data, in the same run.

    PYTHONPATH=src python experiments/bench_monitor.py [--duration 300] [--rate 30] [--window 60]

Data: the live simulated camera (`jaxdefl.simulate.camera_blocks`, Experiment II at 3 Hz, the
camera at --rate) for --duration s. Measured:

- per-frame latency: frame arrival → updated estimates (`Monitor.feed` of one frame: the tracker
  update, the block sums and, at block ends, the change detector), median / 99th percentile / max,
  against the 5 ms budget, in wall time and in the thread's CPU time (on a shared machine the wall
  time includes waiting for a core);
- sustained speed: frames per second of wall time through `Monitor.feed` over the whole record,
  as a multiple of real time (--rate frames/s);
- the batch peer: `jaxdefl.fit` of the whole record at once (one fit per plate and axis) and of
  one --window-s window — what refitting a moving window at every frame would cost per frame
  (it is how a batch tool would have to give per-frame estimates).

BLAS runs single-threaded for both (the monitor's matrices are small; threads only add latency).
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np
from threadpoolctl import threadpool_limits

from jaxdefl.monitor import Layout, Monitor, fit_span
from jaxdefl.simulate import camera_blocks, config_from_dict


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--duration", type=float, default=300.0)
    ap.add_argument("--rate", type=float, default=30.0)
    ap.add_argument("--window", type=float, default=60.0)
    ap.add_argument("--seed", type=int, default=3)
    a = ap.parse_args()
    cfg = config_from_dict({"camera": {"frame_rate_hz": a.rate}, "fatigue": {"law": "none"}}, "bench")
    parts = list(camera_blocks(cfg, a.duration, a.seed, block_frames=600))
    t = np.concatenate([p[0] for p in parts])
    Y = np.concatenate([p[1][..., [2, 0, 1]].reshape(len(p[0]), -1) for p in parts])
    lay = Layout(tuple(range(1, 14)), ("z", "x", "y"))
    print(
        f"data: {len(t)} frames, {lay.n} series, {a.duration:g} s at {a.rate:g} Hz; "
        f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores"
    )
    with threadpool_limits(1, user_api="blas"):
        mon = Monitor(lay)
        n0 = int(np.searchsorted(t, t[0] + 10.5))
        c0 = time.perf_counter()
        mon.feed(t[:n0], Y[:n0])  # buffering and the start fit (JIT compile included)
        start_s = time.perf_counter() - c0
        lat = np.empty(len(t) - n0)
        cpu = np.empty(len(t) - n0)
        w0 = time.perf_counter()
        for k in range(n0, len(t)):
            c, p = time.perf_counter(), time.thread_time()
            mon.feed(t[k : k + 1], Y[k : k + 1])
            lat[k - n0] = time.perf_counter() - c
            cpu[k - n0] = time.thread_time() - p
        wall = time.perf_counter() - w0
        # batch peers
        fit_span(t, Y, lay)  # compile for this shape
        c = time.perf_counter()
        fit_span(t, Y, lay)
        batch_all = time.perf_counter() - c
        nw = int(a.window * a.rate)
        fit_span(t[:nw], Y[:nw], lay)
        c = time.perf_counter()
        reps = 3
        for r in range(reps):
            s = r * nw // 4
            fit_span(t[s : s + nw], Y[s : s + nw], lay)
        batch_win = (time.perf_counter() - c) / reps
    fps = len(lat) / wall
    ms = 1e3 * lat
    print(f"monitor start (buffer + batch fit of the first 10 s, JIT compile included): {start_s:.2f} s")
    print(
        f"per-frame latency: median {np.median(ms):.3f} ms, p99 {np.percentile(ms, 99):.3f} ms, "
        f"max {ms.max():.2f} ms; {100 * np.mean(ms > 5):.2f} % of frames over the 5-ms budget "
        f"(median {5 / np.median(ms):.1f}x under it)"
    )
    mc = 1e3 * cpu
    print(
        f"per-frame CPU time (this thread only: without the waits for a core the other jobs hold): "
        f"median {np.median(mc):.3f} ms, p99 {np.percentile(mc, 99):.3f} ms, max {mc.max():.2f} ms; "
        f"{100 * np.mean(mc > 5):.2f} % over 5 ms"
    )
    print(f"sustained: {fps:.0f} frames/s = {fps / a.rate:.1f}x real time at {a.rate:g} Hz")
    print(
        f"batch fit of the whole {a.duration:g} s (warm): {batch_all:.3f} s = "
        f"{1e3 * batch_all / len(t):.3f} ms per frame of data; monitor / batch time "
        f"{wall / batch_all:.2f}"
    )
    print(
        f"batch refit of a {a.window:g}-s window (warm): {1e3 * batch_win:.1f} ms; per-frame update by "
        f"refitting = {batch_win / np.median(lat):.0f}x the monitor's median latency"
    )


if __name__ == "__main__":
    main()
