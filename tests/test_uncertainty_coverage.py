import numpy as np
import pytest

from jaxdefl.uncertainty import (
    Z95,
    case_coverage,
    debiased_amplitude,
    rice_interval,
    sample_posteriors,
    simulate_case,
)


def _rice_draws(a, s, n, seed):
    rng = np.random.default_rng(seed)
    return np.hypot(a + s * rng.standard_normal(n), s * rng.standard_normal(n))


@pytest.mark.parametrize("a_over_s", [0.0, 0.5, 1.0, 2.0, 5.0])
def test_rice_interval_covers_at_any_snr(a_over_s):
    a_hat = _rice_draws(a_over_s, 1.0, 4000, seed=int(10 * a_over_s))
    for level in (0.68, 0.95):
        lo, hi = rice_interval(a_hat, np.ones_like(a_hat), level=level)
        cover = np.mean((lo <= a_over_s) & (a_over_s <= hi))
        # Central Neyman belt: exact coverage, more where the lower end is clamped at A = 0.
        assert level - 0.02 <= cover <= (1 + level) / 2 + 0.02, (level, cover)
    if a_over_s >= 5:
        assert cover == pytest.approx(0.95, abs=0.015)


def test_debiased_amplitude_removes_the_upward_bias():
    """With ω fitted, E[Â] ≈ A + σ_A²/A; at A/σ_A about 5 the debiased estimator removes most of it."""
    est, truth = simulate_case(0.375, 0.75, 10.0, 0.03, 400, seed=3)
    r = case_coverage(est, truth)
    assert 4 < r["snr_window"] < 6
    assert r["bias_a_rel"] > 0.02
    assert abs(r["bias_a_debiased_rel"]) < r["bias_a_rel"] / 2
    a_hat = _rice_draws(2.0, 1.0, 20000, seed=3)
    assert np.mean(a_hat**2 - 2.0) == pytest.approx(4.0, rel=0.03)  # E[Â²] = A² + 2σ² at known ω
    assert np.all(debiased_amplitude(a_hat, 1.0) <= a_hat)


def test_thesis_snr_linearised_and_posterior_agree_and_cover():
    """Fast version of the study's thesis-SNR case (10 s windows, 400 fits, 6 emcee posteriors).

    White noise: the default σ's (spectral density near f0) and the white ones both cover at
    93-97 % (binomial σ 1.1 % at 400 windows); the posterior (white likelihood) σ's agree with
    the white σ's window by window. Posterior coverage is the slow test's and the study's.
    """
    est, truth = simulate_case(2.5, 0.75, 10.0, 0.03, 400, seed=11)
    ok = np.flatnonzero(est.fit.converged)[:6]
    post = sample_posteriors(est, ok, noise="white", n_walkers=24, n_steps=2000, seed=2)
    r = case_coverage(est, truth, post)
    assert r["fitted"] == 1.0
    for k in ("lin_a_95", "lin_f0_95", "white_a_95", "white_f0_95"):
        assert 0.93 <= r[k] <= 0.97, (k, r)
    assert abs(r["bias_a_sigma"]) < 0.2
    ratio = post.sigma_amplitude_mm / est.table["sigma_amplitude_white_mm"].to_numpy()[ok]
    assert np.all(np.abs(ratio - 1) < 0.1), ratio
    ratio_f = post.sigma_f0_hz / est.table["sigma_f0_white_hz"].to_numpy()[ok]
    assert np.all(np.abs(ratio_f - 1) < 0.1), ratio_f
    assert post.converged_chain.all()


def test_coloured_noise_default_sigmas_cover_and_white_ones_do_not():
    """AR(1) ρ 0.6 at 1 Hz loading, thesis SNR (A 2.5 mm, σ 0.75 mm), 30-s windows, 600 windows
    (a seed not used while tuning). The binomial σ of a 95 % coverage over 600 windows is 0.9 %:
    the default intervals must cover within 0.95 ± 0.027 (3σ); the white-noise ones cover ~0.75
    (issue 13's figure)."""
    est, truth = simulate_case(2.5, 0.75, 30.0, 0.03, 600, seed=2024, noise="ar1", rho=0.6,
                               f0_range_hz=(0.95, 1.05), band_hz=(0.6, 1.4))
    r = case_coverage(est, truth)
    assert r["fitted"] == 1.0
    for k in ("lin_a_95", "lin_f0_95"):
        assert abs(r[k] - 0.95) <= 0.027, (k, r)
    assert r["white_a_95"] < 0.85 and r["white_f0_95"] < 0.85, r


def test_low_snr_amplitude_linearised_under_covers_and_rice_helps():
    """A/σ = 0.12 in 10 s windows (A/σ_A about 1.2): Â is biased up by > 100 % and Â ± 1.96 σ_A
    covers about 63 %; the Rice interval takes the bias into account and covers far more."""
    est, truth = simulate_case(0.09, 0.75, 10.0, 0.03, 400, seed=7)
    r = case_coverage(est, truth)
    assert r["snr_window"] < 2
    assert r["bias_a_rel"] > 1.0
    assert r["bias_a_debiased_rel"] < r["bias_a_rel"] - 0.2
    assert r["lin_a_95"] < 0.7
    assert r["rice_a_95"] > r["lin_a_95"] + 0.1


@pytest.mark.slow
def test_low_snr_posterior_restores_coverage():
    """A/σ = 0.67 in 3 s windows (A/σ_A about 3.7): the linearised f0 interval covers about 84 %,
    the emcee posterior's (wider and non-Gaussian: it spreads over the side peaks of ω) about 95 %,
    on the same 60 windows (binomial σ 2.8 %: at least 0.88). Its chains fail the convergence
    diagnostics: a multi-modal ω posterior is itself the sign that σ_f0 cannot be trusted."""
    est, truth = simulate_case(0.5, 0.75, 3.0, 0.03, 60, seed=7)
    ok = np.flatnonzero(est.fit.converged)
    post = sample_posteriors(est, ok, noise="white", n_walkers=16, n_steps=1200, seed=2, chunk=64)
    r = case_coverage(est, truth, post)
    assert r["n_post"] > 55
    assert r["lin_f0_95_on_post"] < 0.9
    assert r["post_f0_95"] >= 0.88 and r["post_f0_95"] > r["lin_f0_95_on_post"] + 0.05
    assert r["post_a_95"] >= r["lin_a_95_on_post"]
    assert r["ratio_sigma_f0"] > 2


@pytest.mark.slow
def test_ar1_posterior_covers_under_coloured_noise():
    """AR(1) ρ 0.6 at 1 Hz, 10-s windows: the emcee posterior with the AR(1) likelihood covers A
    and f0 (40 windows, binomial σ 3.4 %: at least 0.85), the white σ's do not."""
    est, truth = simulate_case(2.5, 0.75, 10.0, 0.03, 40, seed=21, noise="ar1", rho=0.6,
                               f0_range_hz=(0.95, 1.05), band_hz=(0.6, 1.4))
    ok = np.flatnonzero(est.fit.converged)
    post = sample_posteriors(est, ok, noise="ar1", n_walkers=16, n_steps=1000, seed=5, chunk=40)
    r = case_coverage(est, truth, post)
    assert r["post_a_95"] >= 0.85 and r["post_f0_95"] >= 0.85, r
    assert r["rho_post"] == pytest.approx(0.6, abs=0.1)
    assert r["white_a_95"] < 0.85


def test_z95():
    assert Z95 == pytest.approx(1.959964, abs=1e-6)
