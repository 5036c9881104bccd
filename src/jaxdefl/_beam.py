"""The beam's static deflection shape: one function for the simulator, the synthetic tables and
the reports (any length unit, the same for all three arguments)."""

from __future__ import annotations

import numpy as np

__all__ = ["beam_shape"]


def beam_shape(x, span: float, a: float):
    """Elastic deflection of a simply supported beam under two symmetric point loads, peak 1.

    Loads at ``a`` from each support (span L): w(x) ∝ x (3 L a - 3 a² - x²) for x <= a and
    a (3 L x - 3 x² - a²) between the loads; zero outside the supports. ``x``, ``span`` and
    ``a`` in one unit (mm or m).
    """
    x = np.asarray(x, float)
    xs = np.minimum(x, span - x)
    outer = xs * (3 * span * a - 3 * a**2 - xs**2)
    inner = a * (3 * span * xs - 3 * xs**2 - a**2)
    d = np.where(xs <= a, outer, inner)
    mid = a * (3 * span * span / 2 - 3 * span**2 / 4 - a**2)
    return np.where((x >= 0) & (x <= span), d / mid, 0.0)
