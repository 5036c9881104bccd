"""What the range effects share: the columns (pixels off the plates, plate p's) they act on."""

from __future__ import annotations

import numpy as np

__all__ = ["columns"]


def columns(e, n_plates: int, off_plates: bool) -> np.ndarray:
    """The range columns of effect ``e``: its plates, else every plate (and, ``off_plates``, the
    pixels off the plates, column 0)."""
    if e.plates:
        return np.asarray(e.plates)
    return np.arange(0 if off_plates else 1, n_plates + 1)
