"""Posterior checks of chosen windows as a table beside the linearised σ's (``fit --posterior N``)."""

from __future__ import annotations

import numpy as np
import pandas as pd

from .._errors import ConfigError
from ..fit import Estimates
from ..status import Status
from ._coverage import debiased_amplitude, rice_interval
from ._flags import honesty_features, honesty_flags
from ._posterior import sample_posteriors

__all__ = [
    "POSTERIOR_COLUMNS", "UNCERTAINTY_COLUMNS", "choose_windows", "posterior_table", "uncertainty_table",
]

UNCERTAINTY_COLUMNS = [
    "segment", "window", "plate", "axis", "snr", "cycles", "missing", "r2", "whiteness_p", "flag",
    "trust_amplitude", "trust_f0", "amplitude_debiased_mm", "amplitude_rice_lo95_mm",
    "amplitude_rice_hi95_mm",
]


def uncertainty_table(estimates: Estimates) -> pd.DataFrame:
    """Honesty flags of every window and which interval of A and of f0 to trust.

    Trust values: ``linearised`` (Â ± 1.96 σ_A and f̂0 ± 1.96 σ_f0 with the table's default σ's,
    honest under coloured noise: also for windows flagged only ``coloured_noise``);
    ``posterior`` (few cycles, heavy drop-outs, or f0 at low SNR: `posterior_table`);
    ``rice_or_posterior`` (A at low SNR: the Rice interval, in this table, or the posterior);
    ``inadequate_model`` (the window is not one harmonic in noise: no interval of this model);
    ``none`` (not fitted). Columns ``UNCERTAINTY_COLUMNS``.
    """
    tab = estimates.table
    feat = honesty_features(estimates)
    flags = honesty_flags(estimates)
    amp, sig = tab["amplitude_mm"].to_numpy(), tab["sigma_amplitude_mm"].to_numpy()
    lo, hi = rice_interval(amp, sig)
    reasons = [set(f.split("+")) for f in flags]
    low = np.array(["low_snr" in r for r in reasons])
    shaky = np.array([bool(r & {"low_snr", "few_cycles", "heavy_dropouts"}) for r in reasons])
    bad_model = np.array(["inadequate_model" in r for r in reasons])
    trust_a = np.where(low, "rice_or_posterior", np.where(shaky, "posterior", "linearised")).astype(object)
    trust_f = np.where(shaky, "posterior", "linearised").astype(object)
    for trust in (trust_a, trust_f):
        trust[bad_model] = "inadequate_model"
        trust[flags == "not_fitted"] = "none"
    unc = tab[["segment", "window", "plate", "axis"]].assign(
        snr=feat["snr"].to_numpy(), cycles=feat["cycles"].to_numpy(),
        missing=feat["missing"].to_numpy(), r2=feat["r2"].to_numpy(),
        whiteness_p=feat["whiteness_p"].to_numpy(), flag=flags, trust_amplitude=trust_a,
        trust_f0=trust_f, amplitude_debiased_mm=debiased_amplitude(amp, sig),
        amplitude_rice_lo95_mm=lo, amplitude_rice_hi95_mm=hi,
    )
    return unc[UNCERTAINTY_COLUMNS].reset_index(drop=True)

POSTERIOR_COLUMNS = [
    "segment", "window", "plate", "axis", "amplitude_post_mm", "sigma_amplitude_post_mm",
    "amplitude_lo95_mm", "amplitude_hi95_mm", "f0_post_hz", "sigma_f0_post_hz", "f0_lo95_hz",
    "f0_hi95_hz", "sigma_amplitude_lin_mm", "sigma_f0_lin_hz", "sigma_ratio_amplitude",
    "noise_model", "rho_post", "tau_max", "acceptance", "n_effective", "converged_chain",
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
    ok = np.flatnonzero(estimates.table["status"].to_numpy() == Status.CONVERGED)
    if ok.size <= n_windows:
        return ok
    return np.sort(np.random.default_rng(seed).choice(ok, n_windows, replace=False))


def posterior_table(
    estimates: Estimates, n_windows: int, seed: int = 0, n_walkers: int = 32, n_steps: int = 2000,
    noise: str = "ar1",
) -> pd.DataFrame:
    """emcee posterior of A and f0 for ``n_windows`` converged windows, beside the linearised σ's.

    Windows are a seeded random sample of the converged ones (`choose_windows`); each gets an
    `emcee.EnsembleSampler` of ``n_walkers`` walkers and ``n_steps`` steps (the first quarter is
    burn-in) over [C, D, E, ω, log σ] (and atanh ρ with the ``ar1`` likelihood, the default:
    white noise is its ρ = 0) with the priors of `harmonic_log_posterior`. Intervals are
    the 2.5 and 97.5 % posterior quantiles; ``sigma_*_lin`` are the estimates table's default
    σ's (linearised, scaled to the residual's density near f0); ``sigma_ratio_amplitude`` is
    posterior σ_A over that σ_A; ``rho_post`` the posterior mean of ρ; ``converged_chain``
    follows `chain_diagnostics`.

    Returns:
        one row per checked window, columns ``POSTERIOR_COLUMNS`` (empty if none converged).
    Raises:
        ConfigError: bad ``n_windows``, ``n_walkers`` or ``n_steps``.
    """
    rows = choose_windows(estimates, n_windows, seed)
    if rows.size == 0:
        return pd.DataFrame(columns=POSTERIOR_COLUMNS)
    p = sample_posteriors(estimates, rows, seed=seed, n_walkers=n_walkers, n_steps=n_steps, noise=noise)
    tab = estimates.table.iloc[rows]
    sa_lin = tab["sigma_amplitude_mm"].to_numpy()
    out = pd.DataFrame({
        "segment": tab["segment"].to_numpy(), "window": tab["window"].to_numpy(),
        "plate": tab["plate"].to_numpy(), "axis": tab["axis"].to_numpy(),
        "amplitude_post_mm": p.amplitude_mm, "sigma_amplitude_post_mm": p.sigma_amplitude_mm,
        "amplitude_lo95_mm": p.amplitude_q[:, 0], "amplitude_hi95_mm": p.amplitude_q[:, 3],
        "f0_post_hz": p.f0_hz, "sigma_f0_post_hz": p.sigma_f0_hz,
        "f0_lo95_hz": p.f0_q[:, 0], "f0_hi95_hz": p.f0_q[:, 3],
        "sigma_amplitude_lin_mm": sa_lin, "sigma_f0_lin_hz": tab["sigma_f0_hz"].to_numpy(),
        "sigma_ratio_amplitude": p.sigma_amplitude_mm / sa_lin, "noise_model": noise, "rho_post": p.rho,
        "tau_max": p.tau_max, "acceptance": p.acceptance, "n_effective": p.n_effective,
        "converged_chain": p.converged_chain,
    })
    return out[POSTERIOR_COLUMNS]
