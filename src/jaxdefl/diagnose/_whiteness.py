"""Residual tests: is what the model leaves white Gaussian noise, and if not, where not?

Five tests per series, each with a p-value under "the residual is white Gaussian noise with
the model's σ profile", and a location:

- ``spectrum``: the largest power of the normalised residual periodogram (Exp(1) per frequency);
  p = 1 − (1 − e^{−z})^M over the M frequencies scanned (Press et al.). Located in a band.
- ``mean_shift``: the largest excursion of the standardised cumulative sum (a Brownian bridge:
  Kolmogorov's distribution). Drifts, jumps, slow modulations. Located at a time.
- ``variance_shift``: the same on z² − 1: noise that changes with time. Located at a time.
- ``tails``: excess kurtosis against √(24/n): outliers, mixtures.
- ``variance_vs_phase``: z² regressed on the cosine and sine of the motion phase (χ², 2 dof):
  noise that depends on where the plate is in its cycle.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import special, stats

from .._numerics import harmonic_design, wls
from ._base import Context, State, masked_periodogram

__all__ = ["TESTS", "residual_tests", "series_whiteness_p"]

TESTS = ("spectrum", "mean_shift", "variance_shift", "tails", "variance_vs_phase")


def _standardised(ctx: Context, i: int, st: State) -> tuple[np.ndarray, np.ndarray]:
    s = ctx.series[i]
    inl = st.inlier
    z = (s.y - st.mean)[inl] / st.scale[inl]
    sd = float(np.sqrt(np.mean((z - z.mean()) ** 2))) or 1.0
    return (z - z.mean()) / sd, s.t[inl]


def residual_tests(ctx: Context, i: int, st: State) -> dict[str, dict]:
    """{test: {"p": p-value, "t": time (s since t0) or None, "band_hz": [lo, hi] or None}}."""
    z, t = _standardised(ctx, i, st)
    n = z.size
    out = {}
    # spectrum on the frame clock (outliers zeroed like gaps)
    full = np.zeros(ctx.series[i].n)
    full[st.inlier] = z
    freq, power = masked_periodogram(ctx, i, full)
    j = int(np.argmax(power))
    m = power.size
    p = 1.0 if power[j] <= 0 else -math.expm1(m * math.log1p(-math.exp(-power[j])))
    df = freq[1] - freq[0] if freq.size > 1 else 1.0 / max(ctx.duration_s, 1e-9)
    out["spectrum"] = {"p": p, "t": None, "band_hz": [freq[j] - df, freq[j] + df]}
    # cumulative sums
    for name, u in (("mean_shift", z), ("variance_shift", z * z - 1.0)):
        u = u - u.mean()
        sd = float(np.std(u)) or 1.0
        c = np.cumsum(u) / (sd * math.sqrt(n))
        k = int(np.argmax(np.abs(c)))
        out[name] = {"p": float(special.kolmogorov(abs(c[k]))), "t": float(t[k]), "band_hz": None}
    kurt = float(np.mean(z**4) - 3.0)
    out["tails"] = {"p": float(stats.norm.sf(kurt / math.sqrt(24.0 / n))), "t": None, "band_hz": None}
    arg = ctx.nominal[i].argument(t)
    g = harmonic_design(arg, offset=False)
    u = z * z - 1.0
    beta = wls(g, u, cov=False)[0]
    chi2 = float(np.sum((g @ beta) ** 2) / max(np.var(u), 1e-300))
    f0 = ctx.nominal[i].f0_hz
    out["variance_vs_phase"] = {"p": float(stats.chi2.sf(chi2, 2)), "t": None, "band_hz": [f0, f0]}
    return out


def series_whiteness_p(tests: dict[str, dict]) -> float:
    """Bonferroni over the tests of one series."""
    return min(1.0, len(tests) * min(v["p"] for v in tests.values()))
