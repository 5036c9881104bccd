"""Flags for windows whose linearised σ's (thesis 5.43-5.45) are known to be dishonest.

Thresholds come from the Monte Carlo study ``experiments/coverage.py`` (white noise, 20 Hz frame
clock, f0 near 3 Hz, windows of 1-30 s, random drop-outs 3-60 %, A/σ from 3.3 down to 0.12,
500 windows a case, 30,428 fitted windows pooled), asking where the 95 % linearised interval
of A or f0 covers the truth less than 93 % of the time:

- ``low_snr``: Â / σ_A below ``SNR_MIN`` = 7. Pooled by Â/σ_A, linearised 95 % coverage of
  (A, f0) was (0.94, 0.94) for 7-10, (0.90, 0.91) for 5-7, (0.79, 0.74) for 4-5, (0.70, 0.36) for
  3-4 and (0.86, 0.28) for 2-3: Â is biased upward (+8 % at A/σ_A = 4.3, +33 % at 2.5) and ω̂
  sits on noise peaks. Trust the posterior (`posterior_table`) for f0, and the posterior or
  the Rice interval (`rice_interval`) for A, not Â ± 1.96 σ_A.
- ``few_cycles``: f̂0 × window span below ``CYCLES_MIN`` = 8 cycles. At Â/σ_A >= 10, 3-cycle
  windows (1 s, 20 samples) covered (0.92, 0.88), 9-cycle windows (0.935, 0.933), 30 and more
  cycles 0.94-0.95. Few cycles and few samples go together here (n - 4 = 16 degrees of freedom
  alone make a normal 95 % interval cover 93 %).
- ``heavy_dropouts``: more than ``DROPOUT_MAX`` = 70 % of the frame clock's frames missing.
  Random drop-outs did not break coverage in the study at Â/σ_A >= 10: (0.952, 0.940) at
  50-60 % missing, (0.944, 0.943) at 60-70 % (the covariance uses the samples that are there,
  and the lost SNR shows in Â/σ_A); drop-outs in bursts of 1 s (3 cycles) at 30-60 % neither
  (0.938-0.954 at Â/σ_A >= 10). Beyond 70 % the study has no data, so the flag marks windows
  outside the validated range. (An earlier engine took the median spacing as
  the frame interval, which spans several frames once most are lost, and lost the 3 Hz peak at
  80-85 % drop-outs; a later one took the smallest spacing, which 5 ms of jitter on a 20 Hz
  clock shrinks to half a frame, declaring half the frames missing. Windows now count frames on
  the recovered clock, `jaxdefl.series.clock`, tested at 70 and 85 % drop-outs and with jitter.)
Two more come from the residual (`jaxdefl.fit.residual_noise`: ``r2`` and ``whiteness_p`` of
the estimates table):

- ``coloured_noise``: the residual fails the Ljung-Box whiteness test (``whiteness_p`` below
  ``WHITENESS_P_MIN`` = 1e-3) while the harmonic explains at least ``R2_MIN`` = 0.5 of the
  window's variance. The default σ's use the residual's spectral density near f0 and stay
  honest (95 % coverage 0.929-0.963 under white, AR(1) ρ 0.3-0.9, frame-common and 1/f noise
  and 5 ms stamp jitter at the thesis' SNR, 1 and 3 Hz: ``experiments/coverage.py --section
  coloured``); the white-noise σ's (``sigma_*_white``) do not (0.71-0.76 at 1 Hz, AR(1) ρ 0.6).
  Informative: the trust stays with the default σ's.
- ``inadequate_model``: the residual is not white and the harmonic explains less than half of
  the variance: the window is not one harmonic in noise (a broadband record, a free vibration,
  several modes). No interval of the harmonic model is to be trusted there. Filtered random
  noise (no harmonic) gave ``whiteness_p`` < 1e-40 and ``r2`` 0.003-0.3 in 30-s windows and
  whole records (up to 0.78 below 0.2 Hz, where few_cycles fires too); harmonics at the thesis'
  SNR give ``r2`` 0.84-0.87 under any of the noises above, and the thesis' simulated days
  (configs ``exp2_tof_{1,3}hz``, day 1, every plate and axis) 0.69-0.82.
Several reasons are joined with ``+``; windows without a converged fit are ``not_fitted``.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from ..fit import WHITENESS_P_MIN, Estimates
from ..status import Status

__all__ = [
    "SNR_MIN", "CYCLES_MIN", "DROPOUT_MAX", "R2_MIN", "WHITENESS_P_MIN", "honesty_features",
    "honesty_flags",
]

SNR_MIN = 7.0
CYCLES_MIN = 8.0
DROPOUT_MAX = 0.7
R2_MIN = 0.5


def honesty_features(estimates: Estimates) -> pd.DataFrame:
    """Per window: ``snr`` = Â/σ_A (the table's default σ_A), ``cycles`` = f̂0 × span, ``missing`` =
    fraction of frames lost, and the table's ``r2`` and ``whiteness_p``.

    The span is last minus first valid time plus one frame interval; the missing fraction is
    1 - n / frames, with the frames counted on the window's recovered clock (`Windows.k`, from
    `jaxdefl.series.clock`: a robust clock fit, so jitter does not shrink the interval and
    heavy drop-outs do not stretch it).
    """
    w = estimates.windows
    f = estimates.fit
    n = w.mask.sum(axis=1)
    lo = np.where(w.mask, w.t, np.inf).min(axis=1)
    hi = np.where(w.mask, w.t, -np.inf).max(axis=1)
    dt = np.where(np.isfinite(w.dt) & (w.dt > 0), w.dt, np.nan)
    span = np.where(n > 1, hi - lo + np.nan_to_num(dt), np.nan)
    k_lo = np.where(w.mask, w.k, np.iinfo(np.int64).max).min(axis=1)
    k_hi = np.where(w.mask, w.k, np.iinfo(np.int64).min).max(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        frames = np.where(n > 1, (k_hi - k_lo + 1).astype(np.float64), np.nan)
        missing = np.clip(1.0 - n / frames, 0.0, 1.0)
        snr = f.amplitude_mm / estimates.table["sigma_amplitude_mm"].to_numpy()
    tab = estimates.table
    return pd.DataFrame({
        "snr": snr, "cycles": f.f0_hz * span, "missing": missing, "n": n,
        "r2": tab["r2"].to_numpy(), "whiteness_p": tab["whiteness_p"].to_numpy(),
    })


def honesty_flags(estimates: Estimates) -> np.ndarray:
    """'ok' or the reasons (``low_snr``, ``few_cycles``, ``heavy_dropouts``, ``coloured_noise``,
    ``inadequate_model``, joined by '+') per window.

    Returns:
        (window,) array of str; ``not_fitted`` where the fit did not converge.
    """
    feat = honesty_features(estimates)
    reasons = [
        ("low_snr", ~(feat["snr"].to_numpy() >= SNR_MIN)),
        ("few_cycles", ~(feat["cycles"].to_numpy() >= CYCLES_MIN)),
        ("heavy_dropouts", feat["missing"].to_numpy() > DROPOUT_MAX),
    ]
    structured = feat["whiteness_p"].to_numpy() < WHITENESS_P_MIN
    explains = feat["r2"].to_numpy() >= R2_MIN
    reasons += [("coloured_noise", structured & explains), ("inadequate_model", structured & ~explains)]
    out = []
    fitted = estimates.fit.converged & (estimates.table["status"].to_numpy() == Status.CONVERGED)
    for i in range(len(feat)):
        if not fitted[i]:
            out.append("not_fitted")
            continue
        why = [name for name, bad in reasons if bad[i]]
        out.append("+".join(why) if why else "ok")
    return np.array(out, dtype=object).astype(str)
