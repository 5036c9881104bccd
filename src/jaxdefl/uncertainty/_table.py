"""Posterior checks of chosen windows as a table beside the linearised σ's (``fit --posterior N``)."""

from __future__ import annotations

import numpy as np
import pandas as pd

from .._errors import ConfigError
from ..fit import Estimates
from ._posterior import sample_posteriors

__all__ = ["POSTERIOR_COLUMNS", "choose_windows", "posterior_table"]

POSTERIOR_COLUMNS = [
    "segment", "window", "plate", "axis", "amplitude_post_mm", "sigma_amplitude_post_mm",
    "amplitude_lo95_mm", "amplitude_hi95_mm", "f0_post_hz", "sigma_f0_post_hz", "f0_lo95_hz",
    "f0_hi95_hz", "sigma_amplitude_lin_mm", "sigma_f0_lin_hz", "sigma_ratio_amplitude", "tau_max",
    "acceptance", "n_effective", "converged_chain",
]


def choose_windows(estimates: Estimates, n_windows: int, seed: int = 0) -> np.ndarray:
    """A seeded random sample of ``n_windows`` converged windows, in table order.

    A random sample rather than the first N so that every plate and axis (the low-SNR lateral
    axis above all) has its chance of being checked; all converged windows when there are fewer.

    Raises:
        ConfigError: ``n_windows`` below 1.
    """
    if not (isinstance(n_windows, int | np.integer) and n_windows >= 1):
        raise ConfigError(f"--posterior: expected a positive number of windows, got {n_windows}")
    ok = np.flatnonzero(estimates.table["status"].to_numpy() == "converged")
    if ok.size <= n_windows:
        return ok
    return np.sort(np.random.default_rng(seed).choice(ok, n_windows, replace=False))


def posterior_table(
    estimates: Estimates, n_windows: int, seed: int = 0, n_walkers: int = 32, n_steps: int = 2000
) -> pd.DataFrame:
    """emcee posterior of A and f0 for ``n_windows`` converged windows, beside the linearised σ's.

    Windows are a seeded random sample of the converged ones (`choose_windows`); each gets an
    `emcee.EnsembleSampler` of ``n_walkers`` walkers and ``n_steps`` steps (the first quarter is
    burn-in) over [C, D, E, ω, log σ] with the priors of `harmonic_log_posterior`. Intervals are
    the 2.5 and 97.5 % posterior quantiles; ``sigma_ratio_amplitude`` is posterior σ_A over
    linearised σ_A (thesis 5.44); ``converged_chain`` follows `chain_diagnostics`.

    Returns:
        one row per checked window, columns ``POSTERIOR_COLUMNS`` (empty if none converged).
    Raises:
        ConfigError: bad ``n_windows``, ``n_walkers`` or ``n_steps``.
    """
    rows = choose_windows(estimates, n_windows, seed)
    if rows.size == 0:
        return pd.DataFrame(columns=POSTERIOR_COLUMNS)
    p = sample_posteriors(estimates, rows, seed=seed, n_walkers=n_walkers, n_steps=n_steps, sampler="emcee")
    tab = estimates.table.iloc[rows]
    sa_lin = estimates.fit.sigma_amplitude_mm[rows]
    out = pd.DataFrame({
        "segment": tab["segment"].to_numpy(), "window": tab["window"].to_numpy(),
        "plate": tab["plate"].to_numpy(), "axis": tab["axis"].to_numpy(),
        "amplitude_post_mm": p.amplitude_mm, "sigma_amplitude_post_mm": p.sigma_amplitude_mm,
        "amplitude_lo95_mm": p.amplitude_q[:, 0], "amplitude_hi95_mm": p.amplitude_q[:, 3],
        "f0_post_hz": p.f0_hz, "sigma_f0_post_hz": p.sigma_f0_hz,
        "f0_lo95_hz": p.f0_q[:, 0], "f0_hi95_hz": p.f0_q[:, 3],
        "sigma_amplitude_lin_mm": sa_lin, "sigma_f0_lin_hz": estimates.fit.sigma_f0_hz[rows],
        "sigma_ratio_amplitude": p.sigma_amplitude_mm / sa_lin,
        "tau_max": p.tau_max, "acceptance": p.acceptance, "n_effective": p.n_effective,
        "converged_chain": p.converged_chain,
    })
    return out[POSTERIOR_COLUMNS]
