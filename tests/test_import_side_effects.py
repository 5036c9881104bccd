"""Importing jaxdefl changes nothing in the JAX process, and the library computes in float64 all
the same (`jaxdefl._jax`): float64 is a scope around each library call, the compilation cache is
made at the first kernel call, and the command line sets both up for its whole process.

Every check runs in a fresh interpreter (tests/conftest.py turns float64 on for this one), with
``$JAXDEFL_CACHE_DIR`` at a path that does not exist yet.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from conftest import harmonic_table

SRC = Path(__file__).resolve().parents[1] / "src"


def _run(script: str, cache: Path, *args: str) -> dict:
    """The JSON line a fresh interpreter prints last, with ``cache`` as $JAXDEFL_CACHE_DIR."""
    env = {**os.environ, "PYTHONPATH": str(SRC), "JAXDEFL_CACHE_DIR": str(cache)}
    env.pop("JAX_ENABLE_X64", None)
    out = subprocess.run([sys.executable, "-c", script, *args], env=env, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr[-3000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


IMPORTS = """
import importlib, json, os, pkgutil
import jaxdefl, jaxdefl.fit, jaxdefl.diagnose, jaxdefl.simulate, jaxdefl.spectral
import jaxdefl.uncertainty, jaxdefl.cli
# and every other module (``python -m jaxdefl`` would run the command)
names = [m.name for m in pkgutil.walk_packages(jaxdefl.__path__, "jaxdefl.") if m.name != "jaxdefl.__main__"]
for name in names:
    importlib.import_module(name)
import jax
print(json.dumps(dict(
    modules=len(names),
    x64=jax.config.jax_enable_x64,
    compilation_cache=jax.config.jax_compilation_cache_dir,
    cache=os.path.exists(os.environ["JAXDEFL_CACHE_DIR"]),
)))
"""


def test_importing_changes_nothing_in_jax(tmp_path):
    got = _run(IMPORTS, tmp_path / "cache")
    assert got["modules"] > 50  # the walk found the package's modules
    assert got == {**got, "x64": False, "compilation_cache": None, "cache": False}


# Mode "off": the library alone, float64 never turned on for the process. Mode "cli": the `fit`
# command first (it sets float64 and the cache up for its process), then the same library call.
FIT = """
import json, os, sys
import pandas as pd
import jax
from jaxdefl.fit import estimate_windows
from jaxdefl.io import validate_trajectory
from jaxdefl.series import make_windows
table, mode = sys.argv[1], sys.argv[2]
cache = os.environ["JAXDEFL_CACHE_DIR"]
traced = os.path.join(cache, "traced")
before = os.path.exists(cache)
if mode == "cli":
    from jaxdefl.cli import main
    assert main(["fit", table, "--out", table + ".est.parquet", "--window", "20"]) == 0
w = make_windows(validate_trajectory(pd.read_parquet(table)), axes=("z",), window_s=20.0)
est = estimate_windows(w).table
print(json.dumps(dict(
    f0=est["f0_hz"].tolist(),
    amplitude=est["amplitude_mm"].tolist(),
    sigma_f0=est["sigma_f0_hz"].tolist(),
    x64=jax.config.jax_enable_x64,
    cache_before=before,
    cache_after=os.path.exists(cache),
    traced=len(os.listdir(traced)) if os.path.isdir(traced) else 0,
    compilation_cache=jax.config.jax_compilation_cache_dir,
)))
"""


@pytest.fixture(scope="module")
def fits(tmp_path_factory):
    """{mode: (cache dir, printed results)} of the harmonic table with epoch-second times."""
    root = tmp_path_factory.mktemp("fit")
    table = root / "traj.parquet"
    harmonic_table(duration_s=60.0, t0=1.7e9, seed=3).to_parquet(table)
    return {mode: (root / mode, _run(FIT, root / mode, str(table), mode)) for mode in ("off", "cli")}


def test_the_fit_computes_in_float64_without_the_global_flag(fits):
    off, cli = fits["off"][1], fits["cli"][1]
    assert cli["x64"] is True  # the command line turns float64 on for its process
    assert off["x64"] is False  # the library's scope did not leak into the process
    assert len(off["f0"]) == 3 and np.all(np.isfinite(off["f0"]))
    assert off["f0"] == pytest.approx([3.0672] * 3, rel=1e-3)
    # float32 anywhere on the way moves f0 by ~1e-8 and A by ~1e-7 (relative)
    for k in ("f0", "amplitude", "sigma_f0"):
        np.testing.assert_allclose(off[k], cli[k], rtol=1e-9, atol=0, err_msg=k)


def test_the_cache_is_made_at_the_first_kernel_call(fits):
    cache, off = fits["off"]
    assert off["cache_before"] is False  # importing the fit stage made nothing
    assert off["cache_after"] is True and off["traced"] > 0  # the kernels were kept there
    assert off["compilation_cache"] == str(cache)


DIAGNOSE = """
import json, sys
import pandas as pd
import jax
table, mode = sys.argv[1], sys.argv[2]
if mode == "setup":
    from jaxdefl._jax import setup
    setup()
from jaxdefl.diagnose import diagnose
d = diagnose(pd.read_parquet(table), effects=("extra_periodic",), open_world=False)
found = [[e["id"], e["plates"], e["delta_bic"], e["parameters"]["freq_hz"]["value"]] for e in d["effects"]]
print(json.dumps(dict(
    effects=found,
    bic=[d["nominal"]["bic"], d["final"]["bic"]],
    x64=jax.config.jax_enable_x64,
)))
"""


def _line_on_one_plate() -> pd.DataFrame:
    """Three plates on the epoch clock, 10 min; a 0.3 mm line at 1.37 Hz on plate 1 alone (its
    per-plate proposal is refined by the diagnosis' nonlinear solver, `_varpro.fit_shared`)."""
    rng = np.random.default_rng(12)
    t = np.arange(12000) / 20.0
    t = t[rng.random(t.size) >= 0.03]
    rows = []
    for p in (1, 2, 3):
        z = 1900 + 2.4 * np.cos(2 * math.pi * 3.0672 * t + 0.7 * p) + 0.76 * rng.standard_normal(t.size)
        if p == 1:
            z = z + 0.3 * np.cos(2 * math.pi * 1.37 * t + 0.4)
        rows.append(pd.DataFrame({"t": 1.7e9 + t, "plate": p, "z": z}))
    return pd.concat(rows, ignore_index=True)


def test_the_diagnosis_computes_in_float64_without_the_global_flag(tmp_path):
    table = tmp_path / "traj.parquet"
    _line_on_one_plate().to_parquet(table)
    off, ref = (_run(DIAGNOSE, tmp_path / mode, str(table), mode) for mode in ("off", "setup"))
    assert ref["x64"] is True and off["x64"] is False
    assert [e[:2] for e in off["effects"]] == [["extra_periodic", [1]]]
    assert [e[:2] for e in off["effects"]] == [e[:2] for e in ref["effects"]]
    # float32 in the solver moves ΔBIC by ~1e-6 and the line's frequency by ~1e-7 (relative)
    np.testing.assert_allclose(
        [e[2:] for e in off["effects"]] + [off["bic"]],
        [e[2:] for e in ref["effects"]] + [ref["bic"]],
        rtol=1e-9,
    )
