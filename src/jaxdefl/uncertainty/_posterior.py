"""Posterior of the harmonic model per window, sampled with the affine-invariant stretch move.

Parameters θ = [C, D, E, ω, log σ] of y = E + C cos ωt + D sin ωt + N(0, σ²), t from the
window's mid time (thesis 5.29). Priors (weakly informative, all proper or improper-flat):

- amplitude and phase uniform: p(C, D) ∝ 1 / hypot(C, D) for A < ``A_MAX_FACTOR`` × the
  data's range; this prior does not pull the amplitude up at low SNR as a flat (C, D) prior would
  (a flat prior on (C, D) is p(A) ∝ A);
- E flat; ω uniform on (0, ω_Nyquist) of the window's frame clock;
- log σ flat (Jeffreys p(σ) ∝ 1/σ).

The log-probability is a pure JAX function of one θ and one window's (t, y, w), vmapped over
walkers (and over windows by the batched sampler). Two samplers run the same move (Goodman &
Weare 2010, as `emcee.moves.StretchMove`): ``"emcee"`` drives `emcee.EnsembleSampler` one window
at a time with the JAX log-probability vectorised over walkers, ``"jax"`` runs the move for many
windows at once inside `jax.lax.scan` (the coverage study uses it; tests check that both agree
with each other and with an analytic posterior).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from functools import partial
from typing import Literal

import emcee
import jax
import jax.numpy as jnp
import numpy as np

from .. import _jax  # noqa: F401
from .._errors import ConfigError
from .._signals import check_interrupt
from .._sincos import sincos
from ..fit import Estimates

__all__ = [
    "PARAMS", "A_MAX_FACTOR", "PosteriorSummary", "harmonic_log_posterior", "sample_posteriors",
    "stretch_sample", "chain_diagnostics",
]

PARAMS = ("C", "D", "E", "omega", "log_sigma")
A_MAX_FACTOR = 10.0
# A chain is trusted when the kept steps span at least TAU_TOL autocorrelation times (emcee
# asks 50 τ for a precise τ itself; 20 τ gives means and σ's to a few per cent), the
# effective sample count is at least N_EFF_MIN and the acceptance fraction is in range.
TAU_TOL = 20.0
N_EFF_MIN = 500.0
ACCEPTANCE_RANGE = (0.15, 0.8)
logging.getLogger("emcee.autocorr").setLevel(logging.ERROR)  # we report τ/N ourselves


def harmonic_log_posterior(theta, t, y, w, omega_max, a_max):
    """Log-posterior (up to a constant) of θ = [C, D, E, ω, log σ] for one window.

    Args:
        theta: (param,) parameters; E is relative to the data's weighted mean of ``y``.
        t, y, w: (sample,) times from the window's mid time, values centred on their mean, and
            0/1 mask weights.
        omega_max: upper bound of the uniform ω prior (rad/s); a_max: of the amplitude prior.
    Returns:
        scalar log-probability, -inf outside the prior's support.
    """
    c, d, e, om, ls = theta[0], theta[1], theta[2], theta[3], theta[4]
    sn, cs = sincos(om * t)
    r = y - (c * cs + d * sn + e)
    n = jnp.sum(w)
    loglike = -n * ls - 0.5 * jnp.sum(w * r * r) * jnp.exp(-2.0 * ls)
    amp = jnp.hypot(c, d)
    inside = (om > 0) & (om < omega_max) & (amp < a_max) & (amp > 0) & jnp.isfinite(loglike)
    return jnp.where(inside, loglike - jnp.log(amp), -jnp.inf)


@partial(jax.jit, static_argnames=("log_prob",))
def _eval_walkers(log_prob, x, data):
    return jax.vmap(lambda th: log_prob(th, *data))(x)


@partial(jax.jit, static_argnames=("log_prob", "n_steps", "a"))
def stretch_sample(log_prob, x0, data, key, n_steps: int, a: float = 2.0):
    """Run the stretch move for a batch of independent problems (one per window) at once.

    Args:
        log_prob: ``log_prob(theta, *data_row) -> scalar`` for one walker of one window.
        x0: (window, walker, param) start positions (an even number of walkers).
        data: tuple of arrays with a leading window axis, passed row-wise to ``log_prob``.
        key: a `jax.random` key; n_steps: steps; a: the stretch scale (emcee's default 2).
    Returns:
        chain (step, window, walker, param) and accepted (step, window, walker) booleans.
    """
    b, n_w, dim = x0.shape
    half = n_w // 2
    lp_one = jax.vmap(lambda th, *row: log_prob(th, *row), in_axes=(0,) + (None,) * len(data))
    lp_all = jax.vmap(lp_one)

    def half_step(x, lp, key, first):
        s, c = (x[:, :half], x[:, half:]) if first else (x[:, half:], x[:, :half])
        lps = lp[:, :half] if first else lp[:, half:]
        k1, k2, k3 = jax.random.split(key, 3)
        z = ((a - 1.0) * jax.random.uniform(k1, (b, half)) + 1.0) ** 2 / a
        j = jax.random.randint(k2, (b, half), 0, n_w - half)
        cj = jnp.take_along_axis(c, j[..., None], axis=1)
        prop = cj - (cj - s) * z[..., None]
        lpp = lp_all(prop, *data)
        log_r = (dim - 1.0) * jnp.log(z) + lpp - lps
        acc = jnp.log(jax.random.uniform(k3, (b, half))) < log_r
        s_new = jnp.where(acc[..., None], prop, s)
        lp_new = jnp.where(acc, lpp, lps)
        if first:
            return jnp.concatenate([s_new, c], 1), jnp.concatenate([lp_new, lp[:, half:]], 1), acc
        return jnp.concatenate([c, s_new], 1), jnp.concatenate([lp[:, :half], lp_new], 1), acc

    def step(carry, key):
        x, lp = carry
        k1, k2 = jax.random.split(key)
        x, lp, acc1 = half_step(x, lp, k1, True)
        x, lp, acc2 = half_step(x, lp, k2, False)
        return (x, lp), (x, jnp.concatenate([acc1, acc2], 1))

    lp0 = lp_all(x0, *data)
    _, (chain, acc) = jax.lax.scan(step, (x0, lp0), jax.random.split(key, n_steps))
    return chain, acc


def chain_diagnostics(chain: np.ndarray, accepted_fraction: float) -> dict:
    """τ_max, effective sample count and a verdict for one window's chain (step, walker, param).

    τ is emcee's integrated autocorrelation time (`emcee.autocorr.integrated_time`, quiet) of every
    parameter, estimated on the kept steps; the chain is trusted when it is at least
    ``TAU_TOL`` τ_max long, holds ``N_EFF_MIN`` effective samples and the acceptance fraction lies
    in ``ACCEPTANCE_RANGE``.
    """
    tau = emcee.autocorr.integrated_time(chain, quiet=True)
    tau_max = float(np.max(tau))
    n_steps, n_walkers = chain.shape[:2]
    n_eff = n_steps * n_walkers / tau_max
    ok = (np.isfinite(tau_max) and n_steps >= TAU_TOL * tau_max and n_eff >= N_EFF_MIN
          and ACCEPTANCE_RANGE[0] <= accepted_fraction <= ACCEPTANCE_RANGE[1])
    return dict(tau_max=tau_max, n_effective=n_eff, converged_chain=bool(ok))


@dataclass(frozen=True)
class PosteriorSummary:
    """Posterior summaries of A and f0 for a set of windows (all arrays (window,)).

    Attributes:
        rows: indices of the windows in the `Estimates` they came from.
        amplitude_mm, f0_hz: posterior means; sigma_*: posterior standard deviations;
        amplitude_q, f0_q: (window, 4) quantiles at 2.5, 16, 84, 97.5 % (68 % and 95 % intervals).
        tau_max, acceptance, n_effective, converged_chain: diagnostics (see `chain_diagnostics`).
    """

    rows: np.ndarray
    amplitude_mm: np.ndarray
    sigma_amplitude_mm: np.ndarray
    amplitude_q: np.ndarray
    f0_hz: np.ndarray
    sigma_f0_hz: np.ndarray
    f0_q: np.ndarray
    tau_max: np.ndarray
    acceptance: np.ndarray
    n_effective: np.ndarray
    converged_chain: np.ndarray


QUANTILES = (2.5, 16.0, 84.0, 97.5)
Sampler = Literal["emcee", "jax"]


def _window_data(est: Estimates, rows: np.ndarray):
    """Centred (t, y, w), ω_max, A_max and the start point of every window at ``rows``."""
    w = est.windows
    m = w.mask[rows]
    t = np.where(m, w.t[rows], 0.0)
    wt = m.astype(np.float64)
    ybar = np.sum(wt * w.y[rows], 1) / np.sum(wt, 1)
    y = np.where(m, w.y[rows] - ybar[:, None], 0.0)
    rng = np.where(m, y, -np.inf).max(1) - np.where(m, y, np.inf).min(1)
    dt = np.where(np.isfinite(w.dt[rows]) & (w.dt[rows] > 0), w.dt[rows], np.nan)
    om_max = np.pi / dt
    p = est.fit.params[rows].copy()
    p[:, 2] -= ybar
    theta0 = np.concatenate([p, np.log(est.fit.sigma_residual_mm[rows])[:, None]], 1)
    cov = np.zeros((rows.size, 5, 5))
    cov[:, :4, :4] = est.fit.cov[rows]
    cov[:, 4, 4] = 1.0 / (2.0 * np.maximum(m.sum(1) - 4, 1))
    return (t, y, wt, om_max, A_MAX_FACTOR * rng), theta0, cov


def _initial_ball(rng: np.random.Generator, theta0, cov, n_walkers: int):
    """Walkers drawn from N(θ̂, Σ̂) (the linearised posterior), kept inside the prior support."""
    b, d = theta0.shape
    chol = np.linalg.cholesky(cov + 1e-30 * np.eye(d))
    x = theta0[:, None, :] + np.einsum("bij,bwj->bwi", chol, rng.standard_normal((b, n_walkers, d)))
    return x


def sample_posteriors(
    est: Estimates,
    rows: np.ndarray,
    seed: int = 0,
    n_walkers: int = 32,
    n_steps: int = 2000,
    discard: int | None = None,
    sampler: Sampler = "emcee",
    chunk: int = 32,
) -> PosteriorSummary:
    """Sample the posterior of the windows at ``rows`` (converged fits) and summarise A and f0.

    Walkers start from the linearised posterior N(θ̂, Σ̂) of the Gauss-Newton fit; the first
    ``discard`` steps (default a quarter) are burn-in. The chains explore the mode the fit found;
    a second, distant ω mode (a wrong periodogram peak) is not searched for.

    Raises:
        ConfigError: bad walker/step counts, an unknown sampler, or a row that did not converge.
    """
    rows = np.asarray(rows, dtype=np.int64)
    if n_walkers < 12 or n_walkers % 2:
        raise ConfigError(
            f"n_walkers: expected an even number >= 12 (2 x 5 parameters + 2), got {n_walkers}")
    discard = n_steps // 4 if discard is None else discard
    if n_steps - discard < 100:
        raise ConfigError(
            f"n_steps: expected at least {discard + 100} (burn-in {discard} + 100), got {n_steps}")
    if sampler not in _SAMPLERS:
        raise ConfigError(f"sampler: expected one of {', '.join(_SAMPLERS)}, got {sampler!r}")
    bad = rows[~est.fit.converged[rows]]
    if bad.size:
        status = est.table["status"].iloc[bad[0]]
        raise ConfigError(f"rows: window {int(bad[0])} has no converged fit (status {status})")
    data, theta0, cov = _window_data(est, rows)
    rng = np.random.default_rng(seed)
    x0 = _initial_ball(rng, theta0, cov, n_walkers)
    out = {k: [] for k in ("a", "f", "tau", "acc", "neff", "ok")}
    for c0 in range(0, rows.size, chunk):
        check_interrupt()
        sl = slice(c0, c0 + chunk)
        chains, accs = _SAMPLERS[sampler](tuple(d[sl] for d in data), x0[sl], rng, n_steps)
        for chain, acc in zip(chains, accs, strict=True):
            kept = chain[discard:]
            diag = chain_diagnostics(kept, acc)
            out["a"].append(np.hypot(kept[..., 0], kept[..., 1]).ravel())
            out["f"].append(kept[..., 3].ravel() / (2 * np.pi))
            out["tau"].append(diag["tau_max"])
            out["acc"].append(acc)
            out["neff"].append(diag["n_effective"])
            out["ok"].append(diag["converged_chain"])
    a = out["a"]
    f = out["f"]
    return PosteriorSummary(
        rows=rows,
        amplitude_mm=np.array([v.mean() for v in a]), sigma_amplitude_mm=np.array([v.std(ddof=1) for v in a]),
        amplitude_q=np.array([np.percentile(v, QUANTILES) for v in a]).reshape(-1, 4),
        f0_hz=np.array([v.mean() for v in f]), sigma_f0_hz=np.array([v.std(ddof=1) for v in f]),
        f0_q=np.array([np.percentile(v, QUANTILES) for v in f]).reshape(-1, 4),
        tau_max=np.array(out["tau"]), acceptance=np.array(out["acc"]),
        n_effective=np.array(out["neff"]), converged_chain=np.array(out["ok"], dtype=bool),
    )


def _run_emcee(data, x0, rng, n_steps):
    """One `emcee.EnsembleSampler` per window; the log-probability is vectorised over walkers."""
    chains, accs = [], []
    for i in range(x0.shape[0]):
        row = tuple(jnp.asarray(d[i]) for d in data)

        def lp(x, row=row):
            return np.asarray(_eval_walkers(harmonic_log_posterior, jnp.asarray(x), row))

        s = emcee.EnsembleSampler(x0.shape[1], x0.shape[2], lp, vectorize=True)
        s.random_state = np.random.RandomState(int(rng.integers(2**31))).get_state()
        s.run_mcmc(x0[i], n_steps, progress=False)
        chains.append(s.get_chain())
        accs.append(float(np.mean(s.acceptance_fraction)))
    return chains, accs


def _run_jax(data, x0, rng, n_steps):
    """All windows of the chunk in one `stretch_sample` call (padded to a power of two)."""
    b = x0.shape[0]
    size = 1 << max(0, int(np.ceil(np.log2(b))))
    pad = np.concatenate([np.arange(b), np.zeros(size - b, np.int64)])
    key = jax.random.PRNGKey(int(rng.integers(2**31)))
    chain, acc = stretch_sample(harmonic_log_posterior, jnp.asarray(x0[pad]),
                                tuple(jnp.asarray(np.asarray(d)[pad]) for d in data), key, n_steps)
    chain = np.asarray(chain)[:, :b].transpose(1, 0, 2, 3)
    acc = np.asarray(acc)[:, :b].mean(axis=(0, 2))
    return list(chain), list(acc)


_SAMPLERS = {"emcee": _run_emcee, "jax": _run_jax}
