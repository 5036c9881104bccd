"""Estimates unchanged by the speed work of issue 27: the windowed and whole-record estimates
of a small fixed dataset agree to 1e-6 σ with those saved from the code before it
(``tests/data/fit_reference.npz``, written by ``experiments/make_fit_reference.py`` on 1f08985)."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location(
    "make_fit_reference", ROOT / "experiments" / "make_fit_reference.py"
)
ref_script = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(ref_script)

# (estimate, its σ) pairs compared in units of σ
SIGMA_OF = {
    "f0_hz": "sigma_f0_hz",
    "amplitude_mm": "sigma_amplitude_mm",
    "offset_mm": "sigma_residual_mm",
}


@pytest.fixture(scope="module")
def now():
    return ref_script.reference_estimates(ref_script.reference_dataset())


@pytest.fixture(scope="module")
def saved():
    return dict(np.load(ROOT / "tests" / "data" / "fit_reference.npz"))


@pytest.mark.parametrize("name", ["windows", "whole"])
def test_estimates_unchanged_to_1e6_sigma(now, saved, name):
    tab = now[name]
    assert list(tab["status"]) == list(saved[f"{name}/status"])
    assert list(tab["axis"]) == list(saved[f"{name}/axis"])
    ok = tab["status"].to_numpy() == "converged"
    assert ok.sum() > 0.8 * ok.size
    for col, scol in SIGMA_OF.items():
        d = np.abs(tab[col].to_numpy()[ok] - saved[f"{name}/{col}"][ok]) / saved[f"{name}/{scol}"][ok]
        assert d.max() < 1e-6, (col, d.max())
    # the σ's themselves, the phase and the residual statistics, relative
    for col in (
        "sigma_f0_hz",
        "sigma_amplitude_mm",
        "sigma_f0_white_hz",
        "sigma_amplitude_white_mm",
        "sigma_residual_mm",
        "r2",
    ):
        np.testing.assert_allclose(
            tab[col].to_numpy()[ok], saved[f"{name}/{col}"][ok], rtol=1e-6, err_msg=col
        )
    dphi = np.angle(np.exp(1j * (tab["phase_rad"].to_numpy()[ok] - saved[f"{name}/phase_rad"][ok])))
    amp, sa = saved[f"{name}/amplitude_mm"][ok], saved[f"{name}/sigma_amplitude_mm"][ok]
    assert np.max(np.abs(dphi) * amp / sa) < 1e-6  # the phase's σ is σ_A / A
    np.testing.assert_allclose(
        tab["whiteness_p"].to_numpy()[ok], saved[f"{name}/whiteness_p"][ok], rtol=1e-5, atol=1e-12
    )
    for col in ("t_start", "t_end", "plate", "n"):
        np.testing.assert_array_equal(tab[col].to_numpy(dtype=float), saved[f"{name}/{col}"], err_msg=col)
