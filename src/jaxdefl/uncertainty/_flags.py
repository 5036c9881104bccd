"""Flags for windows whose linearised σ's (thesis 5.43-5.45) are known to be dishonest.

Thresholds come from the Monte Carlo study ``experiments/coverage.py`` (white noise, 20 Hz frame
clock, f0 near 3 Hz, windows of 1-30 s, random drop-outs 3-60 %, A/σ from 3.3 down to 0.12),
binning every fitted window by the feature below and asking where the 95 % linearised
interval of A or f0 covers the truth less than 93 % of the time:

- ``low_snr``: Â / σ_A below ``SNR_MIN``. Â is biased upward by about σ_A² / Â and its
  distribution is Rice, not normal; ω̂ can sit on a noise peak. Trust the Rice interval
  (`rice_interval`) for A, or the posterior (`posterior_table`), not Â ± 1.96 σ_A.
- ``few_cycles``: f̂0 × window span below ``CYCLES_MIN`` cycles: the offset and the harmonic are
  not orthogonal over the window and ω is poorly constrained; trust the posterior.
- ``heavy_dropouts``: more than ``DROPOUT_MAX`` of the frame clock's frames missing. Random
  drop-outs alone did not break coverage in the study (the covariance uses the samples that are
  there); the flag marks windows where so little of the clock is left that gaps of whole cycles
  are likely in real recordings, so check them with the posterior.

Several reasons are joined with ``+``; windows without a converged fit are ``not_fitted``.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from ..fit import Estimates

__all__ = ["SNR_MIN", "CYCLES_MIN", "DROPOUT_MAX", "honesty_features", "honesty_flags"]

SNR_MIN = 10.0
CYCLES_MIN = 5.0
DROPOUT_MAX = 0.5


def honesty_features(estimates: Estimates) -> pd.DataFrame:
    """Per window: ``snr`` = Â/σ_A, ``cycles`` = f̂0 × span, ``missing`` = fraction of frames lost.

    The span is last minus first valid time plus one frame interval; the missing fraction is
    1 - n / (span / dt) on the window's frame clock (NaN where the window has no clock).
    """
    w = estimates.windows
    f = estimates.fit
    n = w.mask.sum(axis=1)
    lo = np.where(w.mask, w.t, np.inf).min(axis=1)
    hi = np.where(w.mask, w.t, -np.inf).max(axis=1)
    dt = np.asarray(w.dt, float)
    span = np.where(n > 1, hi - lo + np.nan_to_num(dt), np.nan)
    with np.errstate(invalid="ignore", divide="ignore"):
        frames = np.rint(span / dt)
        missing = np.clip(1.0 - n / frames, 0.0, 1.0)
        snr = f.amplitude_mm / f.sigma_amplitude_mm
    return pd.DataFrame({"snr": snr, "cycles": f.f0_hz * span, "missing": missing, "n": n})


def honesty_flags(estimates: Estimates) -> np.ndarray:
    """'ok' or the reasons (``low_snr``, ``few_cycles``, ``heavy_dropouts``, joined by '+') per window.

    Returns:
        (window,) array of str; ``not_fitted`` where the fit did not converge.
    """
    feat = honesty_features(estimates)
    reasons = [
        ("low_snr", ~(feat["snr"].to_numpy() >= SNR_MIN)),
        ("few_cycles", ~(feat["cycles"].to_numpy() >= CYCLES_MIN)),
        ("heavy_dropouts", feat["missing"].to_numpy() > DROPOUT_MAX),
    ]
    out = []
    fitted = estimates.fit.converged & (estimates.table["status"].to_numpy() == "converged")
    for i in range(len(feat)):
        if not fitted[i]:
            out.append("not_fitted")
            continue
        why = [name for name, bad in reasons if bad[i]]
        out.append("+".join(why) if why else "ok")
    return np.array(out, dtype=object).astype(str)
