"""The library of candidate effects: one detector module per diagnosable id of the vocabulary
(`jaxdefl.effects.EFFECT_IDS`), each exporting ``EFFECT``."""

from __future__ import annotations

import importlib

from ...effects import EFFECT_IDS
from .._base import Detector

__all__ = ["EFFECT_IDS", "load_effects"]


def load_effects() -> dict[str, Detector]:
    """{id: effect} of the library, in the order of `EFFECT_IDS`."""
    return {name: importlib.import_module(f"{__name__}.{name}").EFFECT for name in EFFECT_IDS}
