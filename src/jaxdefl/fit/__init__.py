"""Fit stage: vectorised, jitted Gauss-Newton harmonic fits with covariance (thesis 5.3)."""

from .estimate import ESTIMATE_COLUMNS, STATUSES, Estimates, estimate_windows
from .harmonic import N_PARAMS, HarmonicFit, fit_harmonic, fit_harmonics

__all__ = [
    "ESTIMATE_COLUMNS",
    "N_PARAMS",
    "STATUSES",
    "Estimates",
    "HarmonicFit",
    "estimate_windows",
    "fit_harmonic",
    "fit_harmonics",
]
