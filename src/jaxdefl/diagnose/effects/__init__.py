"""The library of candidate effects: one module per effect, each exporting ``EFFECT``."""

from __future__ import annotations

import importlib

from ..._effect_ids import EFFECT_IDS
from .._base import Effect

__all__ = ["EFFECT_IDS", "load_effects"]


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
