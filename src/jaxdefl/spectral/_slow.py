"""A slow, readable Lomb normalised periodogram (thesis eq. 5.25-5.28) to test fast ones against."""

from __future__ import annotations

import numpy as np

__all__ = ["lomb_slow"]


def lomb_slow(t: np.ndarray, y: np.ndarray, freq_hz: np.ndarray) -> np.ndarray:
    """P_N(f) by direct sums, one frequency at a time. Returns (freq,)."""
    t = np.asarray(t, np.float64)
    h = np.asarray(y, np.float64)
    h = h - h.mean()  # (5.25)
    var = np.sum(h**2) / (h.size - 1)  # (5.26)
    out = np.empty(len(freq_hz))
    for i, f in enumerate(freq_hz):
        w = 2 * np.pi * f
        tau = np.arctan2(np.sum(np.sin(2 * w * t)), np.sum(np.cos(2 * w * t))) / (2 * w)  # (5.28)
        c = np.cos(w * (t - tau))
        s = np.sin(w * (t - tau))
        cc, ss = np.sum(c**2), np.sum(s**2)
        term_c = np.sum(h * c) ** 2 / cc
        term_s = np.sum(h * s) ** 2 / ss if ss > 1e-12 * h.size else 0.0
        out[i] = (term_c + term_s) / (2 * var)  # (5.27)
    return out
