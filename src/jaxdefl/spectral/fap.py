"""False-alarm probability of a Lomb periodogram peak and significance levels (Press et al. 1992).

Under the null hypothesis (white Gaussian noise) the normalised power P_N at one frequency is
exponentially distributed, P(P_N > z) = exp(-z). Searching M independent frequencies gives
FAP(z) = 1 - (1 - exp(-z))**M. For a window of span T searched from fmin to fmax,
M = 2 T (fmax - fmin), which is about N when the search runs to the Nyquist frequency
(Press et al.'s rule of thumb).
"""

from __future__ import annotations

import numpy as np

__all__ = ["THESIS_ALPHAS", "false_alarm_probability", "n_independent", "significance_level"]

# The significance levels plotted in the thesis (section 5.3.1).
THESIS_ALPHAS = (0.001, 0.005, 0.01, 0.05, 0.1, 0.5)


def n_independent(span_s, fmin_hz, fmax_hz):
    """Number of independent frequencies M = 2 T (fmax - fmin), at least 1."""
    return np.maximum(1.0, 2.0 * np.asarray(span_s) * (np.asarray(fmax_hz) - np.asarray(fmin_hz)))


def false_alarm_probability(power, m_indep):
    """FAP = 1 - (1 - exp(-z))**M of a peak of normalised power z among M frequencies."""
    z = np.asarray(power, dtype=np.float64)
    m = np.asarray(m_indep, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        return -np.expm1(m * np.log1p(-np.exp(-z)))


def significance_level(alpha, m_indep):
    """The power z with FAP(z) = alpha: z = -ln(1 - (1 - alpha)**(1/M))."""
    a = np.asarray(alpha, dtype=np.float64)
    m = np.asarray(m_indep, dtype=np.float64)
    return -np.log(-np.expm1(np.log1p(-a) / m))
