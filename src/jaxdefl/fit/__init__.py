"""Fit stage: vectorised, jitted Gauss-Newton harmonic fits with covariance (thesis 5.3)."""

from .estimate import ESTIMATE_COLUMNS, STATUSES, Estimates, estimate_windows
from .harmonic import N_PARAMS, HarmonicFit, fit_harmonic, fit_harmonics
from .models import MODEL_KINDS, ModelFit, SignalModel, fit_model, model_values, signal_model
from .reference import COMPARISON_COLUMNS, compare_with_reference, fit_reference
from .residual_noise import (
    WHITENESS_P_MIN,
    ResidualNoise,
    frame_positions,
    harmonic_residual,
    residual_noise,
)
from .table import estimate_table, windows_for

__all__ = [
    "COMPARISON_COLUMNS",
    "ESTIMATE_COLUMNS",
    "N_PARAMS",
    "STATUSES",
    "Estimates",
    "HarmonicFit",
    "MODEL_KINDS",
    "ModelFit",
    "SignalModel",
    "compare_with_reference",
    "estimate_table",
    "estimate_windows",
    "fit_harmonic",
    "fit_harmonics",
    "fit_model",
    "fit_reference",
    "model_values",
    "signal_model",
    "windows_for",
    "ResidualNoise",
    "WHITENESS_P_MIN",
    "frame_positions",
    "harmonic_residual",
    "residual_noise",
]
