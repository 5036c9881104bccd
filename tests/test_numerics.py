"""The shared numerics (`jaxdefl._numerics`) against independent references: scipy's least
squares and median absolute deviation, and the thesis' harmonic model."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import linalg, stats

from jaxdefl._numerics import difference_sigma, harmonic_design, mad_sigma, wls


def _problem(seed: int = 0, n: int = 400):
    rng = np.random.default_rng(seed)
    t = np.sort(rng.uniform(0.0, 60.0, n))
    cols = np.concatenate([harmonic_design(2 * np.pi * 3.07 * t), (t - 30.0)[:, None] / 30.0], axis=1)
    w = rng.uniform(0.5, 2.0, n)
    w[rng.random(n) < 0.05] = 0.0  # skipped samples
    beta = np.array([1.5, 2.0, -0.7, 0.3])
    r = cols @ beta + rng.standard_normal(n) / np.sqrt(np.where(w > 0, w, 1.0))
    return cols, r, w


def test_wls_is_scipy_least_squares_on_the_whitened_problem():
    cols, r, w = _problem()
    beta, cov, fitted = wls(cols, r, w)
    sw = np.sqrt(w)
    ref, res, _, _ = linalg.lstsq(cols * sw[:, None], r * sw)
    np.testing.assert_allclose(beta, ref, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(fitted, cols @ ref, rtol=1e-10, atol=1e-12)
    # covariance: σ̂² (GᵀWG)⁻¹, σ̂² over the samples used less the parameters
    dof = int((w > 0).sum()) - cols.shape[1]
    s2 = float(res) / dof
    np.testing.assert_allclose(cov, s2 * np.linalg.inv((cols * w[:, None]).T @ cols), rtol=1e-9)


def test_wls_with_several_right_hand_sides_is_one_fit_per_column():
    cols, r, w = _problem(1)
    rs = np.stack([r, 2.0 * r[::-1], r - 5.0], axis=1)
    beta, cov, fitted = wls(cols, rs, w)
    for j in range(rs.shape[1]):
        b, c, f = wls(cols, rs[:, j], w)
        np.testing.assert_allclose(beta[:, j], b, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(cov[j], c, rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(fitted[:, j], f, rtol=1e-12, atol=1e-12)
    assert wls(cols, r, w, cov=False)[1] is None


def test_unweighted_wls_recovers_the_harmonic_model_exactly():
    t = np.linspace(0.0, 10.0, 201)
    phase = 2 * np.pi * 2.5 * (t - 5.0)
    y = 4.0 + 1.2 * np.cos(phase) - 0.4 * np.sin(phase)
    beta = wls(harmonic_design(phase), y, cov=False)[0]
    np.testing.assert_allclose(beta, [4.0, 1.2, -0.4], atol=1e-12)


def test_harmonic_design_columns():
    phase = np.array([0.0, np.pi / 2, np.pi])
    np.testing.assert_allclose(harmonic_design(phase), [[1, 1, 0], [1, 0, 1], [1, -1, 0]], atol=1e-15)
    np.testing.assert_allclose(harmonic_design(phase, offset=False), harmonic_design(phase)[:, 1:])


def test_mad_sigma_is_scipys_normal_scaled_mad():
    rng = np.random.default_rng(2)
    x = rng.standard_normal((500, 3)) * [1.0, 2.0, 0.5] + 7.0
    ref = stats.median_abs_deviation(x, axis=0, scale="normal")
    np.testing.assert_allclose(mad_sigma(x, axis=0), ref, rtol=1e-4)  # 1.4826 vs 1/Φ⁻¹(¾)
    for j in range(3):
        assert mad_sigma(x[:, j]) == pytest.approx(float(mad_sigma(x, axis=0)[j]), rel=1e-15)


def test_difference_sigma_ignores_slow_structure_and_gaps():
    rng = np.random.default_rng(3)
    k = np.arange(20000)
    k = k[rng.random(k.size) > 0.1]  # dropped frames
    r = 0.8 * rng.standard_normal(k.size) + 50.0 * np.sin(2 * np.pi * k / 20000) + 3.0 * (k > 9000)
    assert difference_sigma(r, k) == pytest.approx(0.8, rel=0.03)
    assert difference_sigma(np.array([1.0])) == 0.0
