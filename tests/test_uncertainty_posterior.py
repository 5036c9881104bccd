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
    stretch_sample,
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


def test_jax_stretch_matches_analytic_gaussian_posterior(linear_case):
    t, y, mean, cov, x0 = linear_case
    data = (jnp.asarray(t[None]), jnp.asarray(y[None]))
    chain, acc = stretch_sample(_linear_gaussian_lp, jnp.asarray(x0[None]), data,
                                jax.random.PRNGKey(0), 4000)
    kept = np.asarray(chain)[1000:, 0]
    diag = chain_diagnostics(kept, float(np.mean(acc)))
    assert diag["converged_chain"], diag
    _check_gaussian(kept.reshape(-1, 3), mean, cov)


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
    np.testing.assert_allclose(tab["sigma_ratio_amplitude"], 1.0, atol=0.1)
    np.testing.assert_allclose(tab["sigma_f0_post_hz"] / tab["sigma_f0_lin_hz"], 1.0, atol=0.1)
    est = thesis_estimates.table.set_index(["plate"]).loc[tab["plate"]]
    assert (tab["amplitude_lo95_mm"].to_numpy() < est["amplitude_mm"].to_numpy()).all()
    assert (tab["amplitude_hi95_mm"].to_numpy() > est["amplitude_mm"].to_numpy()).all()
    assert ((tab["acceptance"] > 0.3) & (tab["acceptance"] < 0.7)).all()
    assert (tab["n_effective"] > 500).all()
    path = plot_posterior_vs_linearised(tab, tmp_path / "post.png")
    assert path.stat().st_size > 1000


def test_samplers_agree(thesis_estimates):
    a = sample_posteriors(thesis_estimates, np.array([1]), n_steps=2000, sampler="emcee", seed=1)
    b = sample_posteriors(thesis_estimates, np.array([1]), n_steps=2000, sampler="jax", seed=1)
    for x, y in ((a.sigma_amplitude_mm, b.sigma_amplitude_mm), (a.sigma_f0_hz, b.sigma_f0_hz)):
        np.testing.assert_allclose(x, y, rtol=0.1)
    assert abs(a.amplitude_mm[0] - b.amplitude_mm[0]) < 0.1 * a.sigma_amplitude_mm[0]


def test_posterior_table_takes_all_converged_windows_when_asked_for_more(thesis_estimates):
    tab = posterior_table(thesis_estimates, n_windows=10, n_walkers=12, n_steps=400)
    assert sorted(tab["plate"]) == [1, 2, 3]


def test_bad_arguments(thesis_estimates):
    with pytest.raises(ConfigError, match="--posterior: expected a positive number of windows, got 0"):
        posterior_table(thesis_estimates, n_windows=0)
    with pytest.raises(ConfigError, match="n_walkers: expected an even number >= 12"):
        sample_posteriors(thesis_estimates, np.array([0]), n_walkers=7)
    with pytest.raises(ConfigError, match=r"n_steps: expected at least 200 \(burn-in 100 \+ 100\), got 150"):
        sample_posteriors(thesis_estimates, np.array([0]), n_steps=150, discard=100)
    with pytest.raises(ConfigError, match="sampler: expected one of emcee, jax, got 'stan'"):
        sample_posteriors(thesis_estimates, np.array([0]), sampler="stan")
    df = validate_trajectory(__import__("conftest").harmonic_table(duration_s=20.0, amp=0.0, seed=1))
    est = estimate_windows(make_windows(df, axes=("z",)))
    with pytest.raises(ConfigError, match="rows: window 0 has no converged fit"):
        sample_posteriors(est, np.array([0]))
