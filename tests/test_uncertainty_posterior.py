import emcee
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxdefl import ConfigError
from jaxdefl.fit import estimate_windows
from jaxdefl.io import validate_trajectory
from jaxdefl.series import make_windows
from jaxdefl.uncertainty import (
    POSTERIOR_COLUMNS,
    chain_diagnostics,
    plot_posterior_vs_linearised,
    posterior_table,
    sample_posteriors,
    simulate_case,
)

OMEGA = 2 * np.pi * 3.0672
SIGMA = 0.76


def _linear_gaussian_lp(theta, t, y):
    """Known-frequency harmonic, known σ, flat priors: a Gaussian posterior in [C, D, E]."""
    r = y - (theta[0] * jnp.cos(OMEGA * t) + theta[1] * jnp.sin(OMEGA * t) + theta[2])
    return -0.5 * jnp.sum(r * r) / SIGMA**2


def _analytic(t, y):
    g = np.stack([np.cos(OMEGA * t), np.sin(OMEGA * t), np.ones_like(t)], 1)
    cov = SIGMA**2 * np.linalg.inv(g.T @ g)
    return np.linalg.solve(g.T @ g, g.T @ y), cov


@pytest.fixture(scope="module")
def linear_case():
    rng = np.random.default_rng(5)
    t = np.sort(rng.uniform(-2.0, 2.0, 60))  # irregular, short: correlated C, D, E
    y = 0.8 * np.cos(OMEGA * t + 0.4) + 0.3 + SIGMA * rng.standard_normal(t.size)
    mean, cov = _analytic(t, y)
    x0 = mean + 0.1 * rng.standard_normal((32, 3)) @ np.linalg.cholesky(cov).T
    return t, y, mean, cov, x0


def _check_gaussian(samples, mean, cov):
    sd = np.sqrt(np.diag(cov))
    got_cov = np.cov(samples.T)
    got_sd = np.sqrt(np.diag(got_cov))
    np.testing.assert_array_less(np.abs(samples.mean(0) - mean) / sd, 0.05)
    np.testing.assert_allclose(got_sd, sd, rtol=0.05)
    corr = cov / np.outer(sd, sd)
    np.testing.assert_allclose(got_cov / np.outer(got_sd, got_sd), corr, atol=0.05)


def test_emcee_with_jax_log_prob_matches_analytic_gaussian_posterior(linear_case):
    t, y, mean, cov, x0 = linear_case
    lp = jax.jit(jax.vmap(lambda th: _linear_gaussian_lp(th, jnp.asarray(t), jnp.asarray(y))))
    s = emcee.EnsembleSampler(32, 3, lambda x: np.asarray(lp(jnp.asarray(x))), vectorize=True)
    s.random_state = np.random.RandomState(1).get_state()
    s.run_mcmc(x0, 4000, progress=False)
    kept = s.get_chain(discard=1000)
    diag = chain_diagnostics(kept, float(np.mean(s.acceptance_fraction)))
    assert diag["converged_chain"], diag
    _check_gaussian(kept.reshape(-1, 3), mean, cov)


@pytest.fixture(scope="module")
def thesis_estimates():
    from conftest import harmonic_table

    df = validate_trajectory(harmonic_table(n_plates=3, duration_s=20.0, amp=2.5, sigma=0.75, seed=4))
    return estimate_windows(make_windows(df, axes=("z",)))


def test_posterior_table_at_thesis_snr_agrees_with_linearised(thesis_estimates, tmp_path):
    tab = posterior_table(thesis_estimates, n_windows=2, seed=3)
    assert list(tab.columns) == POSTERIOR_COLUMNS
    assert len(tab) == 2
    assert tab["converged_chain"].all()
    assert (tab["noise_model"] == "ar1").all() and (tab["rho_post"].abs() < 0.1).all()
    # White noise: the AR(1) posterior finds ρ near 0 and agrees with the white-noise σ's; the
    # default σ's (spectral density near f0, estimated from ~100 periodogram ordinates) differ
    # from those by their own estimation noise (~7 %).
    est = thesis_estimates.table.set_index(["plate"]).loc[tab["plate"]]
    white_a = est["sigma_amplitude_white_mm"].to_numpy()
    white_f = est["sigma_f0_white_hz"].to_numpy()
    np.testing.assert_allclose(tab["sigma_amplitude_post_mm"] / white_a, 1.0, atol=0.1)
    np.testing.assert_allclose(tab["sigma_f0_post_hz"] / white_f, 1.0, atol=0.1)
    np.testing.assert_allclose(tab["sigma_ratio_amplitude"], 1.0, atol=0.25)
    assert (tab["amplitude_lo95_mm"].to_numpy() < est["amplitude_mm"].to_numpy()).all()
    assert (tab["amplitude_hi95_mm"].to_numpy() > est["amplitude_mm"].to_numpy()).all()
    assert ((tab["acceptance"] > 0.3) & (tab["acceptance"] < 0.7)).all()
    assert (tab["n_effective"] > 500).all()
    path = plot_posterior_vs_linearised(tab, tmp_path / "post.png")
    assert path.stat().st_size > 1000


def test_ar1_likelihood_widens_the_posterior_as_the_coloured_sigmas_do():
    """AR(1) ρ 0.6 at 1 Hz: the white-noise σ's are ~0.6 of the truth (coverage ~0.75). The AR(1)
    posterior finds ρ, and its σ's agree with the default (coloured) σ's; the white-likelihood
    posterior agrees with the white σ's (so it under-covers alike)."""
    est, _ = simulate_case(2.5, 0.75, 30.0, 0.03, 2, seed=8, noise="ar1", rho=0.6,
                           f0_range_hz=(0.95, 1.05), band_hz=(0.6, 1.4))
    rows = np.arange(2)
    ar1 = sample_posteriors(est, rows, noise="ar1", n_steps=1000, seed=1)
    white = sample_posteriors(est, rows, noise="white", n_steps=1000, seed=1)
    tab = est.table
    np.testing.assert_allclose(ar1.rho, 0.6, atol=0.1)
    np.testing.assert_allclose(ar1.sigma_amplitude_mm / tab["sigma_amplitude_mm"], 1.0, atol=0.2)
    np.testing.assert_allclose(ar1.sigma_f0_hz / tab["sigma_f0_hz"], 1.0, atol=0.2)
    np.testing.assert_allclose(white.sigma_amplitude_mm / tab["sigma_amplitude_white_mm"], 1.0, atol=0.1)
    assert np.all(ar1.sigma_amplitude_mm > 1.4 * white.sigma_amplitude_mm)


def test_windows_stepping_together_give_each_window_its_own_emcee_chain(thesis_estimates):
    """Pooling the evaluations of several windows' samplers changes no chain: the posterior of a
    window is the same whether it is sampled alone or beside others."""
    rows = np.array([0, 1, 2])
    alone = sample_posteriors(thesis_estimates, rows, n_walkers=12, n_steps=300, seed=4, chunk=1)
    together = sample_posteriors(thesis_estimates, rows, n_walkers=12, n_steps=300, seed=4, chunk=3)
    np.testing.assert_allclose(alone.amplitude_q, together.amplitude_q, rtol=1e-9)
    np.testing.assert_allclose(alone.f0_q, together.f0_q, rtol=1e-9)
    np.testing.assert_array_equal(alone.acceptance, together.acceptance)


def test_posterior_table_takes_all_converged_windows_when_asked_for_more(thesis_estimates):
    tab = posterior_table(thesis_estimates, n_windows=10, n_walkers=12, n_steps=400, noise="white")
    assert sorted(tab["plate"]) == [1, 2, 3]


def test_bad_arguments(thesis_estimates):
    with pytest.raises(ConfigError, match="--posterior: expected a positive number of windows, got 0"):
        posterior_table(thesis_estimates, n_windows=0)
    with pytest.raises(ConfigError, match="n_walkers: expected an even number >= 12"):
        sample_posteriors(thesis_estimates, np.array([0]), n_walkers=7)
    with pytest.raises(ConfigError, match="n_walkers: expected an even number >= 14"):
        sample_posteriors(thesis_estimates, np.array([0]), n_walkers=12, noise="ar1")
    with pytest.raises(ConfigError, match=r"n_steps: expected at least 200 \(burn-in 100 \+ 100\), got 150"):
        sample_posteriors(thesis_estimates, np.array([0]), n_steps=150, discard=100)
    with pytest.raises(ConfigError, match="noise: expected one of white, ar1, got 'pink'"):
        sample_posteriors(thesis_estimates, np.array([0]), noise="pink")
    df = validate_trajectory(__import__("conftest").harmonic_table(duration_s=20.0, amp=0.0, seed=1))
    est = estimate_windows(make_windows(df, axes=("z",)))
    with pytest.raises(ConfigError, match="rows: window 0 has no converged fit"):
        sample_posteriors(est, np.array([0]))
