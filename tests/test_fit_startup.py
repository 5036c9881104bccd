"""What a fresh `jaxdefl fit` process pays before its work: kernels traced once per machine (a
later process loads the traced kernel instead of tracing it again, and computes exactly what the
plain jitted kernel computes), and only the libraries the command needs."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src"

# One process: the periodogram's mask kernel on a fixed batch, through `persistent_jit` and
# through the plain `jax.jit` of the same function (in the float64 scope `persistent_jit` runs
# its kernels in); prints whether they agree bit for bit and whether `jax.export.export` (the
# trace) was called.
SCRIPT = """
import sys
import numpy as np
import jax.export
traced = []
real = jax.export.export
jax.export.export = lambda *a, **k: (traced.append(1), real(*a, **k))[1]
from jaxdefl._jax import float64
from jaxdefl.spectral import lomb
rng = np.random.default_rng(0)
masks = (rng.random((4, 40)) > 0.2).astype(np.float64)
kw = dict(n_fft=int(sys.argv[1]), j_lo=1, j_hi=20)
a = np.asarray(lomb._mask_terms(masks, **kw))
with float64():
    b = np.asarray(lomb._mask_terms.jitted(masks, **kw))
print(np.array_equal(a, b), len(traced))
"""


def _run(cache: Path | None, n_fft: int) -> tuple[bool, int]:
    """(agrees with the plain jit, traces) of one fresh process; ``cache`` None: no cache."""
    env = {**os.environ, "JAXDEFL_CACHE_DIR": str(cache or ""), "PYTHONPATH": str(SRC)}
    out = subprocess.run(
        [sys.executable, "-c", SCRIPT, str(n_fft)], env=env, capture_output=True, text=True, check=True
    ).stdout.split()
    return out[0] == "True", int(out[1])


def test_a_traced_kernel_is_loaded_by_a_later_process(tmp_path):
    cache = tmp_path / "jit"
    assert _run(cache, 200) == (True, 1)  # traced, kept
    kept = sorted((cache / "traced").iterdir())
    assert len(kept) == 1 and kept[0].name.startswith("jaxdefl.spectral.lomb._mask_terms-")
    assert _run(cache, 200) == (True, 0)  # loaded, not traced, same numbers
    # a damaged file is traced again and replaced
    kept[0].write_bytes(b"not a kernel")
    assert _run(cache, 200) == (True, 1)
    assert kept[0].read_bytes() != b"not a kernel"


def test_the_key_holds_the_static_arguments_and_no_cache_means_plain_jit(tmp_path):
    cache = tmp_path / "jit"
    assert _run(cache, 200) == (True, 1)
    assert _run(cache, 256) == (True, 1)  # another static argument: its own trace
    assert len(list((cache / "traced").iterdir())) == 2
    assert _run(None, 200) == (True, 0)  # JAXDEFL_CACHE_DIR="": the plain jit, nothing kept


FIT = """
import sys
from jaxdefl.cli import main
code = main(["fit", sys.argv[1], "--out", sys.argv[2], "--window", "20"])
heavy = ("torch", "kornia", "matplotlib", "scipy.stats", "emcee", "dask", "zarr")
print(code, *[m for m in heavy if m in sys.modules])
"""


def test_fit_imports_only_what_it_needs(tmp_path):
    """`jaxdefl fit` (no --posterior) loads no frame, figure, posterior or campaign library."""
    from jaxdefl.synthetic import harmonic_experiment

    traj, _ = harmonic_experiment(duration_s=40, seed=3)
    traj.to_parquet(tmp_path / "traj.parquet")
    env = {**os.environ, "PYTHONPATH": str(SRC)}
    out = subprocess.run(
        [sys.executable, "-c", FIT, str(tmp_path / "traj.parquet"), str(tmp_path / "est.parquet")],
        env=env,
        capture_output=True,
        text=True,
        check=True,
    ).stdout.split()
    assert out == ["0"], out
    assert (tmp_path / "est.parquet").is_file()
