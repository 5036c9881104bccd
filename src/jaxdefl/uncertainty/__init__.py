"""Uncertainty stage: posterior checks of the linearised σ's, coverage studies, honesty flags."""

from ._coverage import (
    Z68,
    Z95,
    case_coverage,
    debiased_amplitude,
    rice_interval,
    simulate_case,
    window_scores,
)
from ._figures import plot_coverage, plot_posterior_vs_linearised
from ._flags import CYCLES_MIN, DROPOUT_MAX, SNR_MIN, honesty_features, honesty_flags
from ._posterior import (
    A_MAX_FACTOR,
    PARAMS,
    PosteriorSummary,
    chain_diagnostics,
    harmonic_log_posterior,
    sample_posteriors,
    stretch_sample,
)
from ._table import POSTERIOR_COLUMNS, choose_windows, posterior_table

__all__ = [
    "A_MAX_FACTOR", "CYCLES_MIN", "DROPOUT_MAX", "PARAMS", "POSTERIOR_COLUMNS", "SNR_MIN", "Z68",
    "Z95", "PosteriorSummary", "case_coverage", "chain_diagnostics", "choose_windows",
    "debiased_amplitude", "harmonic_log_posterior", "honesty_features", "honesty_flags",
    "plot_coverage", "plot_posterior_vs_linearised", "posterior_table", "rice_interval",
    "sample_posteriors", "simulate_case", "stretch_sample", "window_scores",
]
