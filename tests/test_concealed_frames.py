"""The evidence of `experiments/concealed_frames.py` (the x axis of its detection curve).

S_cov must be the known-form test's noncentrality under noise correlated across plates: checked
against the value computed with the TRUE covariance, and against the independent-plates sum when
the noise is independent. A common effect under frame-common noise carries much less evidence
than the plates-as-independent sum says; an effect in the beam's shape (sign changes across the
plates) keeps most of it."""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def bench():
    sys.path.insert(0, str(ROOT / "experiments"))
    spec = importlib.util.spec_from_file_location(
        "concealed_frames", ROOT / "experiments" / "concealed_frames.py"
    )
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _tables(rng, n_plates, n_frames, rho, footprint):
    """Control and effect tables sharing the noise; noise equicorrelated (ρ) across the plates' z
    (x, y independent), σ = 1 mm; ``footprint(t) -> (frames, plates)`` added to z."""
    t = np.arange(n_frames) / 20.0
    common = rng.standard_normal((n_frames, 1))
    z = math.sqrt(rho) * common + math.sqrt(1 - rho) * rng.standard_normal((n_frames, n_plates))
    xy = rng.standard_normal((2, n_frames, n_plates))
    plates = np.arange(1, n_plates + 1)

    def table(zz):
        return pd.DataFrame(
            {
                "t": np.repeat(t, n_plates),
                "plate": np.tile(plates, n_frames),
                "x": xy[0].ravel(),
                "y": xy[1].ravel(),
                "z": zz.ravel(),
            }
        )

    d = footprint(t)
    return table(z), table(z + d), d


def _projected(bench, d):
    t = np.arange(d.shape[0]) / 20.0
    X = bench._design(t)
    return d - X @ np.linalg.lstsq(X, d, rcond=None)[0]


@pytest.mark.parametrize("rho", [0.0, 0.8])
def test_evidence_is_the_known_form_noncentrality(bench, rho):
    rng = np.random.default_rng(11)
    n_p, n = 6, 4000
    shape = np.sin(np.pi * np.arange(1, n_p + 1) / (n_p + 1))
    common = lambda t: 0.05 * np.exp(-t / 60.0)[:, None] * np.ones(n_p)  # noqa: E731 (a warm-up)
    for footprint in (common, lambda t: 0.05 * np.cos(2 * np.pi * 1.3 * t)[:, None] * shape):
        control, effect, d = _tables(rng, n_p, n, rho, footprint)
        s_indep, s_cov = bench.evidence(effect, control)
        r = _projected(bench, d)
        cov = (1 - rho) * np.eye(n_p) + rho  # the true covariance of z across the plates
        truth = float(np.einsum("ti,ij,tj->", r, np.linalg.inv(cov), r))
        assert s_cov == pytest.approx(truth, rel=0.1)
        assert s_indep == pytest.approx(float(np.sum(r**2)), rel=0.1)
        if rho == 0.0:
            assert s_cov == pytest.approx(s_indep, rel=0.1)
    # under frame-common noise the common warm-up is worth far less than the independent sum
    control, effect, d = _tables(rng, n_p, n, 0.8, common)
    s_indep, s_cov = bench.evidence(effect, control)
    assert s_cov < 0.3 * s_indep


def test_a_growth_keeps_its_evidence_and_a_frequency_change_has_none():
    """`reconcile_frames.growth_evidence`: an amplitude growing linearly in phase with the motion
    is not what the nominal fit absorbs (its frequency change is the quadrature t-term), so its S
    is Σ Δ² / σ² of the growth less its mean; a change of the frequency alone carries none."""
    sys.path.insert(0, str(ROOT / "experiments"))
    spec = importlib.util.spec_from_file_location(
        "reconcile_frames", ROOT / "experiments" / "reconcile_frames.py"
    )
    rf = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(rf)
    f0 = 3.068
    rng = np.random.default_rng(4)
    n, plates = 2400, np.arange(1, 6)
    t = np.arange(n) / 20.0
    tc = t - t.mean()
    arg = 2 * math.pi * f0 * t + 0.7

    def table(extra):
        rows = []
        for p in plates:
            z = 2.0 * np.sin(arg) + extra(p) + rng.standard_normal(n)
            rows.append(
                pd.DataFrame(
                    {"t": t, "plate": p, "x": rng.standard_normal(n), "y": rng.standard_normal(n), "z": z}
                )
            )
        return pd.concat(rows, ignore_index=True)

    control = table(lambda p: 0.0)
    base = control.copy()
    growth = 0.2 * tc / np.ptp(tc)  # 10 % of 2 mm over the record
    grown = base.assign(
        z=base.z + growth[np.tile(np.arange(n), len(plates))] * np.tile(np.sin(arg), len(plates))
    )
    expect = len(plates) * float(np.sum((growth * np.sin(arg)) ** 2))
    s, s_cov = rf.growth_evidence(grown, control)
    assert s == pytest.approx(expect, rel=0.1) and s_cov == pytest.approx(expect, rel=0.15)
    chirp = base.assign(z=base.z + np.tile(growth * np.cos(arg), len(plates)))  # as large, in quadrature
    assert max(rf.growth_evidence(chirp, control)) < 0.02 * expect
