"""Uncertainty stage: posterior checks of the linearised σ's, coverage studies, honesty flags."""

from ._posterior import (
    A_MAX_FACTOR, PARAMS, PosteriorSummary, chain_diagnostics, harmonic_log_posterior,
    sample_posteriors, stretch_sample,
)

__all__ = [
    "A_MAX_FACTOR", "PARAMS", "PosteriorSummary", "chain_diagnostics", "harmonic_log_posterior",
    "sample_posteriors", "stretch_sample",
]
