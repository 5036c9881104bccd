"""Benchmark the streamed ToF simulation: frames per second and peak resident memory.

    python experiments/bench_simulate.py --duration 3600 [--config configs/exp2_tof_3hz.toml]

Simulates a recording of the given duration to a temporary directory (deleted unless --keep),
then prints frames, wall time, frames/s, the size written and the peak RSS of the process.
"""

from __future__ import annotations

import argparse
import resource
import shutil
import tempfile
import time
from pathlib import Path

from jaxdefl.simulate import simulate_to_dir


def _du(path: Path) -> int:
    return sum(f.stat().st_size for f in path.rglob("*") if f.is_file())


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=600.0, help="simulated seconds (3600 = 1 hour)")
    ap.add_argument(
        "--config", type=Path, default=Path(__file__).parents[1] / "configs" / "exp2_tof_3hz.toml"
    )
    ap.add_argument("--out", type=Path, default=None, help="output directory (default: a temporary one)")
    ap.add_argument("--keep", action="store_true", help="keep the output")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)

    out = args.out or Path(tempfile.mkdtemp(prefix="jaxdefl-bench-"))
    t0 = time.perf_counter()
    simulate_to_dir(args.config, out, duration_s=args.duration, seed=args.seed, progress=False)
    wall = time.perf_counter() - t0
    import zarr

    n = int(zarr.open_group(str(out / "recording.zarr"), mode="r").attrs["n_frames"])
    size = _du(out)
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # Linux: KiB
    print(f"config         {args.config}")
    print(f"duration       {args.duration:g} s simulated")
    print(f"frames         {n}")
    print(f"wall time      {wall:.1f} s")
    print(f"frames/s       {n / wall:.1f}")
    print(f"written        {size / 1e9:.2f} GB ({out})")
    print(f"peak RSS       {peak_mb:.0f} MB")
    if not args.keep and args.out is None:
        shutil.rmtree(out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
