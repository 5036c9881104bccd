"""Time `jaxdefl diagnose` on the issue's largest recording against the plain fit, in one run.

    python experiments/bench_diagnose.py [--minutes 60] [--rate 30] [--plates 13] [--effect drift]

Recording: the simulator's plates (`jaxdefl.simulate.effects.make_case`: 13 plates, x/y/z,
drop-outs, LDS reference), 60 minutes at 30 Hz by default, with one concealed effect (or
``--effect none``). Peer in the same run: the nominal estimation alone (`estimate_windows`, one
window per plate and axis, what `jaxdefl fit` does) — the diagnosis' cost is reported as a ratio
to it. Both are run twice: the first call includes JIT compilation (the persistent cache makes
later processes faster), the second is the steady state. Prints seconds per stage: context
(validation, nominal fits), screening per effect, refinement, residual tests.

The stages run under the same one-thread BLAS limit as `run_diagnosis`. The load average is
printed at the start and the end: the cores are shared, compare against the peer of the same run.

Measured (2 cores shared with other jobs, 2026-11-23): see the closing note of issue 7.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=60.0)
    ap.add_argument("--rate", type=float, default=30.0)
    ap.add_argument("--plates", type=int, default=13)
    ap.add_argument("--effect", default="drift", help="an effect id, or none")
    ap.add_argument("--seed", type=int, default=3)
    args = ap.parse_args()
    print("load average (1, 5, 15 min): {:.2f} {:.2f} {:.2f}".format(*os.getloadavg()))

    from threadpoolctl import threadpool_limits

    from jaxdefl.diagnose import build_context, load_detectors, run_diagnosis
    from jaxdefl.fit import estimate_windows
    from jaxdefl.io import validate_trajectory
    from jaxdefl.series import make_windows
    from jaxdefl.settings import DiagnoseSettings
    from jaxdefl.simulate.effects import CleanRecording, RecordingSpec, draw_effect, make_recording

    effects = () if args.effect == "none" else (args.effect,)
    spec = RecordingSpec(
        sensor="tof",
        frame_rate_hz=args.rate,
        duration_s=args.minutes * 60,
        n_plates=args.plates,
    )
    t = time.perf_counter()
    base = CleanRecording(spec, args.seed)
    rng = np.random.default_rng(args.seed)
    drawn = [draw_effect(e, base, rng) for e in effects]
    traj, lds, truth = make_recording(spec, drawn, seed=args.seed, base=base)
    print(
        f"recording: {args.minutes:g} min at {args.rate:g} Hz, {args.plates} plates, "
        f"{len(traj)} rows, effect {args.effect} ({time.perf_counter() - t:.1f} s to simulate)"
    )

    settings = DiagnoseSettings(sensor="tof", frame_rate_hz=args.rate)
    for run in ("first (with compile)", "steady"):
        t = time.perf_counter()
        df = validate_trajectory(traj)
        est = estimate_windows(make_windows(df, window_s=None))
        t_fit = time.perf_counter() - t
        t = time.perf_counter()
        diag = run_diagnosis(traj, lds, settings)
        t_diag = time.perf_counter() - t
        found = ", ".join(a.proposal.effect for a in diag.accepted) or "none"
        print(
            f"{run:>22}: fit alone {t_fit:6.1f} s | diagnose {t_diag:6.1f} s "
            f"(ratio {t_diag / t_fit:5.1f}x) | located: {found} | "
            f"{int((est.table['status'] == 'converged').sum())} series fitted | {len(diag.rounds)} rounds"
        )

    # stages of the steady state, under run_diagnosis' BLAS limit
    with threadpool_limits(limits=1, user_api="blas"):
        t = time.perf_counter()
        ctx, states, _ = build_context(traj, lds, settings)
        print(f"  context (validation, nominal and reference fits): {time.perf_counter() - t:.2f} s")
        for eid, eff in load_detectors().items():
            if eff.cannot_tell(ctx):
                continue
            t = time.perf_counter()
            props = eff.propose(ctx, states)
            t_p = time.perf_counter() - t
            t = time.perf_counter()
            for p in props:
                if p.refine is not None:
                    p.refine()
            print(f"  {eid:>22}: screen {t_p:5.2f} s, refine {time.perf_counter() - t:5.2f} s")
        from jaxdefl.diagnose._whiteness import residual_tests

        t = time.perf_counter()
        for i, st in enumerate(states):
            residual_tests(ctx, i, st)
        print(f"  residual tests: {time.perf_counter() - t:.2f} s; samples {sum(s.n for s in ctx.series)}")
    print(f"  truth: {[e['id'] for e in truth['effects']] if isinstance(truth, dict) else truth}")
    print("load average (1, 5, 15 min): {:.2f} {:.2f} {:.2f}".format(*os.getloadavg()))


if __name__ == "__main__":
    main()
