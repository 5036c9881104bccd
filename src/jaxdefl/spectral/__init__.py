"""Spectral stage: batched Lomb normalised periodograms and false-alarm probabilities."""

from ._slow import lomb_slow
from .fap import THESIS_ALPHAS, false_alarm_probability, n_independent, significance_level
from .lomb import METHODS, Periodogram, lomb_direct, lomb_from_sums, lomb_grid, lomb_peaks

__all__ = [
    "METHODS",
    "THESIS_ALPHAS",
    "Periodogram",
    "false_alarm_probability",
    "lomb_direct",
    "lomb_from_sums",
    "lomb_grid",
    "lomb_peaks",
    "lomb_slow",
    "n_independent",
    "significance_level",
]
