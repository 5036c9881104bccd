"""Uncertainty stage: posterior checks of the linearised σ's, coverage studies, honesty flags."""

from ._coverage import (
    NOISES,
    Z68,
    Z95,
    case_coverage,
    debiased_amplitude,
    noise_series,
    rice_interval,
    simulate_case,
    window_scores,
)
from ._figures import plot_coverage, plot_posterior_vs_linearised
from ._flags import (
    CYCLES_MIN,
    DROPOUT_MAX,
    R2_MIN,
    SNR_MIN,
    WHITENESS_P_MIN,
    honesty_features,
    honesty_flags,
)
from ._posterior import (
    A_MAX_FACTOR,
    NOISE_MODELS,
    PARAMS,
    PosteriorSummary,
    ar1_log_posterior,
    chain_diagnostics,
    harmonic_log_posterior,
    sample_posteriors,
)
from ._table import (
    POSTERIOR_COLUMNS,
    UNCERTAINTY_COLUMNS,
    choose_windows,
    posterior_table,
    uncertainty_table,
)

__all__ = [
    "A_MAX_FACTOR", "CYCLES_MIN", "DROPOUT_MAX", "NOISES", "NOISE_MODELS", "PARAMS",
    "POSTERIOR_COLUMNS", "PosteriorSummary", "R2_MIN", "SNR_MIN", "UNCERTAINTY_COLUMNS",
    "WHITENESS_P_MIN", "Z68", "Z95", "ar1_log_posterior", "case_coverage", "chain_diagnostics",
    "choose_windows", "debiased_amplitude", "harmonic_log_posterior", "honesty_features",
    "honesty_flags", "noise_series", "plot_coverage", "plot_posterior_vs_linearised",
    "posterior_table", "rice_interval", "sample_posteriors", "simulate_case", "uncertainty_table",
    "window_scores",
]
