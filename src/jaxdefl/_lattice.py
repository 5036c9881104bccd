"""Rounding to a lattice after Gaussian noise: the mean reading of a quantising sensor.

A disparity camera rounds each pixel's noisy reading to its lattice, o + q·round((z + e − o)/q)
with e ~ N(0, σ_d²) (σ_d the noise before rounding, the "dither"). The mean of many such readings
(a plate's centroid) follows the dither-smoothed staircase

    m(h) = o + q·E[round((h − o)/q + (σ_d/q)·Z)],  Z ~ N(0, 1),

which is the hard staircase for σ_d = 0 and tends to h as σ_d grows: the sawtooth m(h) − h has the
Fourier series −q Σ_k (−1)^(k+1) exp(−2π²k²σ_d²/q²) sin(2πk x)/(πk), x = (h − o)/q, so its first
harmonic falls as exp(−2π²σ_d²/q²). Used by the simulator's quantization effect
(`quantised_readings`: the concealed benchmark's `jaxdefl.simulate.effects` and the registry's
`jaxdefl.effects.quantization`) and by the diagnosis' model term
(`jaxdefl.diagnose.detectors.quantization`).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.special import ndtr

__all__ = ["dithered_round", "dithered_round_var", "quantised_readings", "smoothed_staircase"]

S_HARD = 1e-3  # below: the hard round (the smoothing is < Φ(−500) away from a step's edge)
S_SMOOTH = 2.0  # above: x itself (the first harmonic is exp(−2π²·4) ≈ 6e-35 of q/π)


def _checked(x, s: float) -> np.ndarray:
    if not s >= 0:
        raise ValueError(f"s: expected a noise level >= 0, got {s}")
    return np.asarray(x, dtype=float)


def dithered_round(x: np.ndarray, s: float) -> np.ndarray:
    """E[round(x + s Z)], Z ~ N(0, 1), elementwise: exact to ~1e-15 (a finite sum of Φ).

    With n0 = round(x) and r = x − n0, round(x + sZ) − n0 counts the half-integers n0 + k − ½ the
    reading passed upwards minus those n0 − k + ½ it passed downwards, so
    E = n0 + Σ_{k=1..K} [Φ((r − k + ½)/s) − Φ((−r − k + ½)/s)], K = ⌈9 s⌉ + 1 (later terms are
    below Φ(−9)).

    Args:
        x: positions in lattice units (any shape).
        s: the noise's standard deviation in lattice units (>= 0).

    Returns:
        The expected rounded value, shaped like x.
    """
    x = _checked(x, s)
    if s < S_HARD:
        return np.round(x)
    if s > S_SMOOTH:
        return x.copy()
    n0 = np.round(x)
    r = x - n0
    out = n0.copy()
    for k in range(1, math.ceil(9.0 * s) + 2):
        out += ndtr((r - k + 0.5) / s) - ndtr((-r - k + 0.5) / s)
    return out


def dithered_round_var(x: np.ndarray, s: float) -> np.ndarray:
    """Var[round(x + s Z)], Z ~ N(0, 1), elementwise: the spread of one rounded reading.

    With k = round(x + sZ) − n0 (n0 = round(x), r = x − n0), E[k²] = Σ_{j>=1} (2j − 1) [P(k >= j)
    + P(k <= −j)] = Σ_j (2j − 1) [Φ((r − j + ½)/s) + Φ((−r − j + ½)/s)], and Var = E[k²] − E[k]².
    0 for s below `S_HARD` (the hard round), s² + 1/12 above `S_SMOOTH` (Sheppard).
    """
    x = _checked(x, s)
    if s < S_HARD:
        return np.zeros_like(x)
    if s > S_SMOOTH:
        return np.full_like(x, s * s + 1.0 / 12.0)
    r = x - np.round(x)
    m1 = np.zeros_like(x)
    m2 = np.zeros_like(x)
    for j in range(1, math.ceil(9.0 * s) + 2):
        up, down = ndtr((r - j + 0.5) / s), ndtr((-r - j + 0.5) / s)
        m1 += up - down
        m2 += (2 * j - 1) * (up + down)
    return m2 - m1 * m1


def smoothed_staircase(h: np.ndarray, q: float, o: float, dither: float) -> np.ndarray:
    """o + q·E[round((h − o)/q + (dither/q) Z)]: the mean reading at true value h (same units).

    Args:
        h: true values (any shape).
        q: the lattice step (> 0).
        o: a lattice level.
        dither: the noise's standard deviation before rounding (>= 0, units of h).
    """
    return q * dithered_round((np.asarray(h, dtype=float) - o) / q, dither / q) + o


def quantised_readings(
    z_clean: np.ndarray,
    noise: np.ndarray,
    sig_f: np.ndarray,
    eps: np.ndarray,
    q: float,
    o: float,
    n_px: int,
    dither: float,
    rng: np.random.Generator,
) -> np.ndarray:
    """(frame,) the readings of a quantising sensor: the mean of P pixel readings
    o + q·round((z_clean + e_i − o)/q), the pixels' noise e_i ~ N(0, σ_d²) before the rounding,
    plus the rest of the reading's noise after it (none when σ_d = σ_f √P).

    ``noise`` = σ_f ε is the reading's noise as drawn without the rounding (σ_f ``sig_f``, the
    frame's level, ε ``eps``). It is split into independent parts before and after the rounding,
    with ρ = σ_d²/(P σ_f²) (at most 1): the pixels' mean m = √ρ σ_f (√ρ ε + √(1 − ρ) u) and the
    rest σ_f ε − m (uncorrelated with m: both variances add to σ_f²); then e_i = m + σ_d (g_i − ḡ),
    u and g_i iid N(0, 1) from ``rng``, has exactly the law of P iid N(0, σ_d²) with mean m. So
    the unrounded reading has the noise as drawn, and a reading with and without the rounding
    differ by the rounding alone.

    Args:
        z_clean: (frame,) the values before noise (mm).
        noise, sig_f, eps: (frame,) the noise drawn, its standard deviation and its unit draw.
        q, o: the lattice's step (> 0) and a level (mm).
        n_px: P, the readings averaged (>= 1).
        dither: σ_d, a pixel's noise before the rounding (mm, >= 0).
        rng: the stream of u and g.
    """
    if n_px < 1:
        raise ValueError(f"pixels: expected a count >= 1, got {n_px}")
    u = rng.standard_normal(z_clean.size)
    g = rng.standard_normal((z_clean.size, n_px))
    g -= g.mean(axis=1, keepdims=True)
    with np.errstate(divide="ignore", invalid="ignore"):
        rho = np.where(sig_f > 0, np.minimum(dither**2 / (n_px * sig_f**2), 1.0), 1.0)
    m = np.sqrt(rho) * sig_f * (np.sqrt(rho) * eps + np.sqrt(1.0 - rho) * u)
    e_px = m[:, None] + dither * g
    readings = np.mean(q * np.round((z_clean[:, None] + e_px - o) / q) + o, axis=1)
    return readings + (noise - m)
