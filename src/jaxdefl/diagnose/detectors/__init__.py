"""The detectors: one module per diagnosable id of the vocabulary
(`jaxdefl.effects.EFFECT_IDS`), each exporting ``EFFECT``."""

from __future__ import annotations

import importlib

from ...effects import EFFECT_IDS
from .._base import Detector

__all__ = ["EFFECT_IDS", "load_detectors"]


def load_detectors() -> dict[str, Detector]:
    """{id: its detector}, in the order of `EFFECT_IDS`."""
    return {name: importlib.import_module(f"{__name__}.{name}").EFFECT for name in EFFECT_IDS}
