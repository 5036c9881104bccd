"""The library of candidate effects: one module per effect, each exporting ``EFFECT``."""

from __future__ import annotations

import importlib

from .._base import Effect

__all__ = ["EFFECT_IDS", "load_effects"]

EFFECT_IDS = (
    "motion_artefact",
    "harmonic_distortion",
    "drift",
    "level_jump",
    "amplitude_modulation",
    "frequency_modulation",
    "timing_error",
    "extra_periodic",
    "outliers",
    "heteroscedastic_noise",
    "quantization",
)


def load_effects() -> dict[str, Effect]:
    """{id: effect} of the library, in the order of `EFFECT_IDS`."""
    out = {}
    for name in EFFECT_IDS:
        try:
            mod = importlib.import_module(f"{__name__}.{name}")
        except ModuleNotFoundError as e:  # during development: a module not written yet
            if e.name != f"{__name__}.{name}":
                raise
            continue
        out[name] = mod.EFFECT
    return out
