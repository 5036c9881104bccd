"""Are the concealed benchmark's recordings the same under two source trees, bit for bit?

A refactoring of the benchmark's rendering (issue 24: each id's rendering moved into its
vocabulary module) must not change a single number of `make_case`. This runs the same cases
under ``--before`` (a ``src`` directory, e.g. a checkout of main) and ``--after`` (default: this
checkout's ``src``) in fresh processes and compares with numpy equality:

- `make_case(seed, [id])` for every detectable id and the control (no effect), ``--seeds``;
- combinations of several ids in one case (the stage order of the rendering);
- `draw_effect(..., evidence="best")` on noise with frame-common and line-of-sight shares, with
  `best_evidence` and `effect_strength` of each draw (the sizing paths).

The camera table (t, x, y, z), the LDS (t, z) and the truth JSON (key order included) must be
equal. Prints the count of cases and those that differ; exit 1 when any does.

Usage: python experiments/concealed_identity.py --before /path/to/old/src [--after src]
                                                [--seeds 1,2,3] [--minutes 2]
"""

from __future__ import annotations

import argparse
import os
import pickle
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

COMBOS = [
    ("drift", "mode_shape"),
    ("amplitude_modulation", "frequency_modulation"),
    ("stiffness_change", "amplitude_modulation", "frequency_modulation"),
    ("extra_periodic", "clipping", "harmonic_distortion"),
    ("heteroscedastic_noise", "quantization"),
    ("motion_artefact", "timing_error"),
    ("outliers", "level_jump", "camera_shake", "drift"),
]


def snapshot(out: str, seeds: list[int], minutes: float) -> None:
    """The cases under the source tree this process imports, pickled to ``out``."""
    import json

    from jaxdefl.effects import EFFECT_IDS
    from jaxdefl.simulate.effects import (
        CleanRecording,
        RecordingSpec,
        best_evidence,
        draw_effect,
        effect_strength,
        make_case,
        make_recording,
    )

    def row(traj, lds, extra):
        return (
            traj[["t", "x", "y", "z"]].to_numpy(),
            None if lds is None else lds[["t", "z"]].to_numpy(),
            json.dumps(extra, default=str),
        )

    cases = {}
    for seed in seeds:
        for ids in [(), *((e,) for e in EFFECT_IDS), *COMBOS]:
            traj, lds, truth = make_case(seed, list(ids), minutes=minutes)
            cases[(seed, ids)] = row(traj, lds, truth)
    for sensor, rate in (("tof", 20.0), ("structured_light", 30.0)):
        spec = RecordingSpec(
            sensor=sensor,
            frame_rate_hz=rate,
            duration_s=60.0 * minutes,
            n_plates=9,
            frame_common=0.4,
            line_of_sight=0.6,
        )
        base = CleanRecording(spec, 8)
        for eid in EFFECT_IDS:
            try:
                e = draw_effect(eid, base, np.random.default_rng([8, 1]), evidence="best")
            except ValueError:  # an id of the other camera
                continue
            traj, lds, truth = make_recording(spec, [e], 8, base=base)
            cases[(sensor, eid)] = row(traj, lds, [truth, best_evidence(base, e), effect_strength(base, e)])
    with open(out, "wb") as fh:
        pickle.dump(cases, fh)


def _run(src: Path, out: Path, seeds: str, minutes: float) -> dict:
    env = dict(os.environ, PYTHONPATH=str(src))
    cmd = [sys.executable, __file__, "--snapshot", str(out), "--seeds", seeds, "--minutes", str(minutes)]
    subprocess.run(cmd, env=env, check=True)
    with open(out, "rb") as fh:
        return pickle.load(fh)


def _same(a, b) -> bool:
    (t1, l1, j1), (t2, l2, j2) = a, b
    lds = (l1 is None and l2 is None) or (
        l1 is not None and l2 is not None and np.array_equal(l1, l2, equal_nan=True)
    )
    return np.array_equal(t1, t2, equal_nan=True) and lds and j1 == j2


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--before", type=Path, help="the source tree to compare against (a src directory)")
    ap.add_argument("--after", type=Path, default=Path(__file__).resolve().parents[1] / "src")
    ap.add_argument("--seeds", default="1,2,3")
    ap.add_argument("--minutes", type=float, default=2.0)
    ap.add_argument("--snapshot", help=argparse.SUPPRESS)
    args = ap.parse_args()
    seeds = [int(s) for s in args.seeds.split(",")]
    if args.snapshot:
        snapshot(args.snapshot, seeds, args.minutes)
        return 0
    if args.before is None:
        ap.error("--before: the src directory to compare against is required")
    with tempfile.TemporaryDirectory() as tmp:
        before = _run(args.before, Path(tmp) / "before.pkl", args.seeds, args.minutes)
        after = _run(args.after, Path(tmp) / "after.pkl", args.seeds, args.minutes)
    if before.keys() != after.keys():
        print(f"the cases differ: {sorted(set(before) ^ set(after), key=str)}")
        return 1
    differ = [k for k in before if not _same(before[k], after[k])]
    print(f"{len(before)} cases compared, bit-identical: {len(before) - len(differ)}; differ: {differ}")
    return 1 if differ else 0


if __name__ == "__main__":
    sys.exit(main())
