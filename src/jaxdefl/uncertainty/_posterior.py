"""Posterior of the harmonic model per window, sampled with emcee.

Parameters θ = [C, D, E, ω, log σ] of y = E + C cos ωt + D sin ωt + noise of standard deviation
σ, t from the window's mid time (thesis 5.29), and with the AR(1) likelihood also z = atanh ρ.
Priors (weakly informative, all proper or improper-flat):

- amplitude and phase uniform: p(C, D) ∝ 1 / hypot(C, D) for A < ``A_MAX_FACTOR`` × the
  data's range; this prior does not pull the amplitude up at low SNR as a flat (C, D) prior would
  (a flat prior on (C, D) is p(A) ∝ A);
- E flat; ω uniform on (0, ω_Nyquist) of the window's frame clock;
- log σ flat (Jeffreys p(σ) ∝ 1/σ); ρ uniform on (-1, 1).

Likelihoods (``NOISE_MODELS``): ``white``, independent Gaussian noise; ``ar1``, a stationary
Gaussian AR(1) on the frame clock, exact across drop-outs: a sample d frames after the previous
valid one is N(ρ^d r_prev, σ²(1 - ρ^{2d})), the first N(0, σ²) (σ the marginal σ). The
log-probability is a pure JAX function of one θ and one window's data, vmapped over the walkers
that `emcee.EnsembleSampler` (``vectorize=True``) hands it, one window at a time.
"""

from __future__ import annotations

import logging
import threading
from dataclasses import dataclass
from functools import partial
from typing import Literal

import emcee
import jax
import jax.numpy as jnp
import numpy as np

from .._errors import ConfigError
from .._jax import float64
from .._signals import check_interrupt
from .._sincos import sincos
from ..fit import Estimates, frame_positions

__all__ = [
    "PARAMS", "A_MAX_FACTOR", "NOISE_MODELS", "PosteriorSummary", "ar1_log_posterior",
    "harmonic_log_posterior", "sample_posteriors", "chain_diagnostics",
]

PARAMS = ("C", "D", "E", "omega", "log_sigma", "atanh_rho")
RHO_MAX = 0.999
A_MAX_FACTOR = 10.0
# A chain is trusted when the kept steps span at least TAU_TOL autocorrelation times (emcee
# asks 50 τ for a precise τ itself; 20 τ gives means and σ's to a few per cent), the
# effective sample count is at least N_EFF_MIN and the acceptance fraction is in range.
TAU_TOL = 20.0
N_EFF_MIN = 500.0
ACCEPTANCE_RANGE = (0.15, 0.8)
logging.getLogger("emcee.autocorr").setLevel(logging.ERROR)  # we report τ/N ourselves


def harmonic_log_posterior(theta, t, y, w, g, omega_max, a_max):
    """Log-posterior (up to a constant) of θ = [C, D, E, ω, log σ] for one window, white noise.

    Args:
        theta: (param,) parameters; E is relative to the data's weighted mean of ``y``.
        t, y, w: (sample,) times from the window's mid time, values centred on their mean, and
            0/1 mask weights; g: (sample,) frame index (unused here, see `ar1_log_posterior`).
        omega_max: upper bound of the uniform ω prior (rad/s); a_max: of the amplitude prior.
    Returns:
        scalar log-probability, -inf outside the prior's support.
    """
    c, d, e, om, ls = theta[0], theta[1], theta[2], theta[3], theta[4]
    sn, cs = sincos(om * t)
    r = y - (c * cs + d * sn + e)
    n = jnp.sum(w)
    loglike = -n * ls - 0.5 * jnp.sum(w * r * r) * jnp.exp(-2.0 * ls)
    return _with_prior(loglike, c, d, om, omega_max, a_max)


def ar1_log_posterior(theta, t, y, w, g, omega_max, a_max):
    """Log-posterior of θ = [C, D, E, ω, log σ, atanh ρ] for one window, AR(1) noise.

    The noise is a stationary AR(1) of marginal σ and lag-1 correlation ρ on the frame clock;
    ``g`` (sample,) holds each sample's frame index (valid samples first), so a drop-out of
    d - 1 frames makes the next sample N(ρ^d r_prev, σ² (1 - ρ^{2d})). Other arguments as
    `harmonic_log_posterior`.
    """
    c, d, e, om, ls, z = theta[0], theta[1], theta[2], theta[3], theta[4], theta[5]
    rho = jnp.tanh(z)
    sn, cs = sincos(om * t)
    r = y - (c * cs + d * sn + e)
    first = jnp.arange(t.size) == 0
    gap = jnp.maximum(g - jnp.concatenate([g[:1], g[:-1]]), 1.0)
    r_prev = jnp.concatenate([jnp.zeros(1, r.dtype), r[:-1]])
    odd = jnp.mod(gap, 2.0) == 1.0
    rho_d = jnp.where(odd & (rho < 0), -1.0, 1.0) * jnp.exp(gap * jnp.log(jnp.abs(rho) + 1e-300))
    rho_d = jnp.where(first, 0.0, rho_d)
    innov = 1.0 - rho_d**2
    e_i = r - rho_d * r_prev
    var = jnp.exp(2.0 * ls) * innov
    loglike = -0.5 * jnp.sum(w * (e_i * e_i / var + jnp.log(var)))
    log_jac = jnp.log1p(-rho * rho)  # ρ uniform on (-1, 1), sampled as z = atanh ρ
    inside = jnp.abs(rho) < RHO_MAX
    return jnp.where(inside, _with_prior(loglike, c, d, om, omega_max, a_max) + log_jac, -jnp.inf)


def _with_prior(loglike, c, d, om, omega_max, a_max):
    amp = jnp.hypot(c, d)
    inside = (om > 0) & (om < omega_max) & (amp < a_max) & (amp > 0) & jnp.isfinite(loglike)
    return jnp.where(inside, loglike - jnp.log(amp), -jnp.inf)


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
        rho: posterior mean of the AR(1) correlation (NaN with the white likelihood).
        tau_max, acceptance, n_effective, converged_chain: diagnostics (see `chain_diagnostics`).
    """

    rows: np.ndarray
    amplitude_mm: np.ndarray
    sigma_amplitude_mm: np.ndarray
    amplitude_q: np.ndarray
    f0_hz: np.ndarray
    sigma_f0_hz: np.ndarray
    f0_q: np.ndarray
    rho: np.ndarray
    tau_max: np.ndarray
    acceptance: np.ndarray
    n_effective: np.ndarray
    converged_chain: np.ndarray


QUANTILES = (2.5, 16.0, 84.0, 97.5)
NoiseModel = Literal["white", "ar1"]
NOISE_MODELS = {"white": harmonic_log_posterior, "ar1": ar1_log_posterior}


def _window_data(est: Estimates, rows: np.ndarray, noise: NoiseModel):
    """Centred (t, y, w, g), ω_max, A_max and the start point and spread of every window at ``rows``.

    The start is the Gauss-Newton fit with its covariance scaled to the table's default σ's
    (honest under coloured noise) and, for AR(1), ρ at the residual's lag-1 correlation.
    """
    w = est.windows
    m = w.mask[rows]
    t = np.where(m, w.t[rows], 0.0)
    wt = m.astype(np.float64)
    g = frame_positions(w, rows)[0].astype(np.float64)
    ybar = np.sum(wt * w.y[rows], 1) / np.sum(wt, 1)
    y = np.where(m, w.y[rows] - ybar[:, None], 0.0)
    rng = np.where(m, y, -np.inf).max(1) - np.where(m, y, np.inf).min(1)
    dt = np.where(np.isfinite(w.dt[rows]) & (w.dt[rows] > 0), w.dt[rows], np.nan)
    om_max = np.pi / dt
    p = est.fit.params[rows].copy()
    p[:, 2] -= ybar
    n = m.sum(1)
    inflate = (est.table["sigma_amplitude_mm"].to_numpy()[rows] / est.fit.sigma_amplitude_mm[rows]) ** 2
    inflate = np.where(np.isfinite(inflate), inflate, 1.0)
    dim = 5 if noise == "white" else 6
    theta0 = np.concatenate([p, np.log(est.fit.sigma_residual_mm[rows])[:, None]], 1)
    cov = np.zeros((rows.size, dim, dim))
    cov[:, :4, :4] = est.fit.cov[rows] * inflate[:, None, None]
    cov[:, 4, 4] = 1.0 / (2.0 * np.maximum(n - 4, 1))
    if noise == "ar1":
        phi = est.noise.phi[rows] if est.noise is not None else np.zeros(rows.size)
        phi = np.clip(np.nan_to_num(phi), -0.95, 0.95)
        theta0 = np.concatenate([theta0, np.arctanh(phi)[:, None]], 1)
        cov[:, 5, 5] = 1.0 / np.maximum(n, 1)
    return (t, y, wt, g, om_max, A_MAX_FACTOR * rng), theta0, cov


def _initial_ball(rng: np.random.Generator, theta0, cov, n_walkers: int):
    """Walkers drawn from N(θ̂, Σ̂) (the linearised posterior)."""
    b, d = theta0.shape
    chol = np.linalg.cholesky(cov + 1e-30 * np.eye(d))
    return theta0[:, None, :] + np.einsum("bij,bwj->bwi", chol, rng.standard_normal((b, n_walkers, d)))


def sample_posteriors(
    est: Estimates,
    rows: np.ndarray,
    seed: int = 0,
    n_walkers: int = 32,
    n_steps: int = 2000,
    discard: int | None = None,
    noise: NoiseModel = "white",
    chunk: int = 32,
) -> PosteriorSummary:
    """Sample the posterior of the windows at ``rows`` (converged fits) with emcee; summarise A and f0.

    One `emcee.EnsembleSampler` (stretch move, ``vectorize=True``) per window, its
    log-probability the JAX function of ``noise`` (`NOISE_MODELS`) vmapped over the walkers;
    ``chunk`` windows' samplers step together (see `_run_emcee`).
    Walkers start from the linearised posterior N(θ̂, Σ̂) of the Gauss-Newton fit; the first
    ``discard`` steps (default a quarter) are burn-in. The chains explore the mode the fit found;
    a second, distant ω mode (a wrong periodogram peak) is not searched for.

    Raises:
        ConfigError: bad walker/step counts, an unknown noise model, or a row that did not converge.
    """
    rows = np.asarray(rows, dtype=np.int64)
    if noise not in NOISE_MODELS:
        raise ConfigError(f"noise: expected one of {', '.join(NOISE_MODELS)}, got {noise!r}")
    dim = 5 if noise == "white" else 6
    if n_walkers < 2 * dim + 2 or n_walkers % 2:
        raise ConfigError(
            f"n_walkers: expected an even number >= {2 * dim + 2} (2 x {dim} parameters + 2), "
            f"got {n_walkers}")
    discard = n_steps // 4 if discard is None else discard
    if n_steps - discard < 100:
        raise ConfigError(
            f"n_steps: expected at least {discard + 100} (burn-in {discard} + 100), got {n_steps}")
    bad = rows[~est.fit.converged[rows]]
    if bad.size:
        status = est.table["status"].iloc[bad[0]]
        raise ConfigError(f"rows: window {int(bad[0])} has no converged fit (status {status})")
    data, theta0, cov = _window_data(est, rows, noise)
    rng = np.random.default_rng(seed)
    x0 = _initial_ball(rng, theta0, cov, n_walkers)
    seeds = rng.integers(2**31, size=rows.size)  # one per window: chunking changes nothing
    out = {k: [] for k in ("a", "f", "rho", "tau", "acc", "neff", "ok")}
    for c0 in range(0, rows.size, chunk):
        check_interrupt()
        sl = slice(c0, c0 + chunk)
        chains, accs = _run_emcee(NOISE_MODELS[noise], tuple(d[sl] for d in data), x0[sl], seeds[sl], n_steps)
        for chain, acc in zip(chains, accs, strict=True):
            kept = chain[discard:]
            diag = chain_diagnostics(kept, acc)
            out["a"].append(np.hypot(kept[..., 0], kept[..., 1]).ravel())
            out["f"].append(kept[..., 3].ravel() / (2 * np.pi))
            out["rho"].append(float(np.mean(np.tanh(kept[..., 5]))) if dim == 6 else np.nan)
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
        rho=np.array(out["rho"]), tau_max=np.array(out["tau"]), acceptance=np.array(out["acc"]),
        n_effective=np.array(out["neff"]), converged_chain=np.array(out["ok"], dtype=bool),
    )


@float64()
def _run_emcee(log_prob, data, x0, seeds, n_steps):
    """One `emcee.EnsembleSampler` per window, all stepping together, one JAX call per round.

    Each sampler runs in its own thread; its vectorised log-probability leaves the walkers to
    evaluate at a barrier, and the barrier's action evaluates every window's walkers in one
    jitted call (vmapped over windows and walkers) while the samplers wait. The samplers are
    emcee's, unchanged (moves, random states, bookkeeping): only the evaluations are pooled, so
    a window's chain is the one emcee gives it alone (tested). Samplers always evaluate the same
    number of walkers at the same round (all of them at the start, half at each half-step).
    """
    b, n_walkers, dim = x0.shape
    batch = tuple(jnp.asarray(d) for d in data)
    asked: list = [None] * b
    answers: list = [None] * b

    @float64()  # the barrier's action runs on a sampler's thread: a scope of its own
    def evaluate():
        lp = _eval_windows(log_prob, jnp.asarray(np.stack(asked)), batch)
        answers[:] = list(np.asarray(lp))

    barrier = threading.Barrier(b, action=evaluate)
    results: list = [None] * b
    errors: list = []

    def run(i):
        def lp(x):
            asked[i] = x
            barrier.wait()
            return answers[i]

        try:
            s = emcee.EnsembleSampler(n_walkers, dim, lp, vectorize=True)
            s.random_state = np.random.RandomState(int(seeds[i])).get_state()
            s.run_mcmc(x0[i], n_steps, progress=False)
            results[i] = (s.get_chain(), float(np.mean(s.acceptance_fraction)))
        except threading.BrokenBarrierError:
            pass
        except BaseException as exc:  # noqa: BLE001 - handed to the caller below
            errors.append(exc)
            barrier.abort()

    threads = [threading.Thread(target=run, args=(i,), daemon=True) for i in range(b)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    if errors:
        raise errors[0]
    return [r[0] for r in results], [r[1] for r in results]


@partial(jax.jit, static_argnames=("log_prob",))
def _eval_windows(log_prob, x, data):
    """log_prob of x (window, walker, param) with each window's own data row."""
    return jax.vmap(lambda xw, *row: jax.vmap(lambda th: log_prob(th, *row))(xw))(x, *data)
