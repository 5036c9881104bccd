import ast

import jax
import numpy as np
import pandas as pd
import pytest

jax.config.update("jax_enable_x64", True)


def harmonic_table(
    n_plates=1,
    duration_s=60.0,
    fs=20.0,
    f0=3.0672,
    amp=2.4,
    sigma=0.76,
    dropout=0.03,
    t0=1.7e9,
    seed=0,
    axes=("z",),
    phase=None,
):
    """A trajectory table of harmonic motion with white noise and frame drop-outs."""
    rng = np.random.default_rng(seed)
    n = int(round(duration_s * fs))
    t = t0 + np.arange(n) / fs
    t = t[rng.random(n) >= dropout]
    frames = []
    for plate in range(1, n_plates + 1):
        ph = rng.uniform(0, 2 * np.pi) if phase is None else phase
        cols = {"t": t, "plate": plate}
        for a in axes:
            cols[a] = 5.0 + amp * np.cos(2 * np.pi * f0 * (t - t0) + ph) + sigma * rng.standard_normal(t.size)
        frames.append(pd.DataFrame(cols))
    return pd.concat(frames, ignore_index=True)


@pytest.fixture
def make_table():
    return harmonic_table


def docstring_ids(tree: ast.AST) -> set[int]:
    """``id()`` of every docstring constant in a parsed module (literal checks skip them)."""
    return {
        id(n.body[0].value)
        for n in ast.walk(tree)
        if isinstance(n, (ast.Module, ast.FunctionDef, ast.ClassDef, ast.AsyncFunctionDef))
        and n.body
        and isinstance(n.body[0], ast.Expr)
        and isinstance(n.body[0].value, ast.Constant)
    }


def pytest_collection_modifyitems(config, items):
    """Modules with slow tests run first, each module's tests kept together and in order.

    pytest-xdist hands the workers consecutive tests in collection order and the last ones in
    small batches: with the slow modules at the end (alphabetical order put the coverage and
    reconcile tests there), one worker ran a minute-long test while the other sat idle. Fast
    modules last fill both workers to the end. The order is deterministic (xdist's workers must
    collect alike) and changes only where tests run, not what they check.
    """
    slow = {item.nodeid.split("::")[0] for item in items if item.get_closest_marker("slow")}
    items.sort(key=lambda item: item.nodeid.split("::")[0] not in slow)  # stable: order kept within
