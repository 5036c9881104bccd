"""Monte Carlo coverage of the linearised and posterior intervals of A and f0 (one case at a time).

A case is (amplitude, noise σ and kind, window length, drop-out rate, frame rate, stamp jitter):
``simulate_case`` makes
independent windows of harmonic motion with known truth (random f0 near 3 Hz and phase), runs the
estimation engine on them, and ``case_coverage`` scores the intervals of the converged windows:

- linearised: Â ± z σ_A and f̂0 ± z σ_f0 with the table's default σ's (thesis 5.43-5.45 scaled to
  the residual's spectral density near f0), and with the white-noise σ's; z = 0.994 / 1.960 for
  68 / 95 %;
- Rice: the Neyman interval for A from Â ~ Rice(A, σ_A) (`rice_interval`), which knows that the
  amplitude of a noisy sinusoid is biased upward, E[Â²] = A² + 2σ_A²;
- posterior: the 16-84 % and 2.5-97.5 % quantiles of `sample_posteriors` (emcee).

Coverage is over converged windows only: at low SNR many windows have no significant peak,
and the ones that pass the false-alarm test are selected for upward noise (reported as
``detected``).
"""

from __future__ import annotations

import numpy as np
import pandas as pd
from scipy import stats

from ..fit import Estimates, estimate_windows
from ..io import validate_trajectory
from ..series import make_windows
from ..status import Status
from ._posterior import PosteriorSummary

__all__ = [
    "NOISES", "Z68", "Z95", "noise_series", "simulate_case", "case_coverage", "window_scores",
    "rice_interval", "debiased_amplitude",
]

Z68 = float(stats.norm.ppf(0.84))
Z95 = float(stats.norm.ppf(0.975))


NOISES = ("white", "ar1", "frame_common", "one_over_f")
# Plates that share a camera frame in the ``frame_common`` noise (the thesis' 13 plates).
FRAME_PLATES = 13


def simulate_case(
    amplitude_mm: float, sigma_mm: float, window_s: float, dropout: float, n_windows: int,
    seed: int = 0, fs_hz: float = 20.0, f0_range_hz=(2.9, 3.1), fap_max: float = 1.0,
    band_hz: tuple[float, float] | None = (2.0, 4.0), burst_frames: float = 1.0,
    noise: str = "white", rho: float = 0.6, jitter_s: float = 0.0,
) -> tuple[Estimates, dict]:
    """Estimates of ``n_windows`` independent simulated windows and their truth (f0_hz, amplitude_mm).

    Each window is its own plate of a one-segment table on an epoch clock (t0 = 1.7e9 s); frames
    drop out independently with probability ``dropout``, or, with ``burst_frames`` > 1, in
    bursts of that mean length (a two-state Markov chain with the same drop-out fraction). By
    default every window is fitted
    (``fap_max`` 1: no detection cut, so coverage is not conditioned on a noise-selected peak)
    with the periodogram searched in ``band_hz`` around the known loading frequency.

    Noise of standard deviation ``sigma_mm`` (see `noise_series`): ``white``; ``ar1`` with
    lag-1 correlation ``rho`` at the frame interval; ``frame_common``: half the variance shared
    by the ``FRAME_PLATES`` plates of a frame and slow (AR(1), ρ 0.95, a thermal drift of the
    camera's range), half white per plate; ``one_over_f``: density ∝ 1/f. ``jitter_s``: the
    frames are taken on the clock but stamped with that much Gaussian jitter (the fit sees the
    stamps).
    """
    if noise not in NOISES:
        raise ValueError(f"noise: expected one of {', '.join(NOISES)}, got {noise!r}")
    rng = np.random.default_rng(seed)
    n = int(round(window_s * fs_hz))
    t = np.arange(n) / fs_hz
    f0 = rng.uniform(*f0_range_hz, n_windows)
    ph = rng.uniform(0, 2 * np.pi, n_windows)
    keep = _keep_mask(rng, n_windows, n, dropout, burst_frames)
    keep[:, 0] = keep[:, -1] = True  # every window spans its full length
    y = amplitude_mm * np.cos(2 * np.pi * f0[:, None] * t + ph[:, None])
    y = y + sigma_mm * noise_series(rng, n_windows, n, noise, rho)
    stamps = np.broadcast_to(t + 1.7e9, (n_windows, n))
    if jitter_s > 0:
        stamps = stamps + jitter_s * rng.standard_normal((n_windows, n))
        stamps = np.sort(stamps, axis=1)  # a stamp never runs backwards
    plate = np.repeat(np.arange(n_windows), n).reshape(n_windows, n)
    df = pd.DataFrame({"t": stamps[keep], "plate": plate[keep], "z": 5.0 + y[keep]})
    fmin, fmax = (None, None) if band_hz is None else band_hz
    est = estimate_windows(make_windows(validate_trajectory(df), axes=("z",)), fmin_hz=fmin,
                           fmax_hz=fmax, fap_max=fap_max)
    return est, {"f0_hz": f0, "amplitude_mm": np.full(n_windows, float(amplitude_mm))}


def noise_series(
    rng: np.random.Generator, b: int, n: int, kind: str = "white", rho: float = 0.6
) -> np.ndarray:
    """(b, n) unit-variance noise of the kinds of `simulate_case`, stationary from the first sample."""
    if kind == "white":
        return rng.standard_normal((b, n))
    if kind == "ar1":
        return _ar1(rng, b, n, rho)
    if kind == "frame_common":
        groups = -(-b // FRAME_PLATES)
        common = np.repeat(_ar1(rng, groups, n, 0.95), FRAME_PLATES, axis=0)[:b]
        return np.sqrt(0.5) * common + np.sqrt(0.5) * rng.standard_normal((b, n))
    # 1/f: white noise shaped in the frequency domain over 4 window lengths (the lowest
    # frequencies then vary from window to window, as they do in a long record), one window kept.
    m = 4 * n
    f = np.fft.rfftfreq(m)
    gain = np.where(f > 0, 1.0 / np.sqrt(np.maximum(f, 1e-12)), 0.0)
    x = np.fft.irfft(np.fft.rfft(rng.standard_normal((b, m)), axis=1) * gain, n=m, axis=1)[:, :n]
    two_sided = gain[0] ** 2 + 2 * np.sum(gain[1:-1] ** 2) + gain[-1] ** 2  # m even
    return x / np.sqrt(two_sided / m)  # Parseval: the variance of x per unit white variance


def _ar1(rng, b: int, n: int, rho: float) -> np.ndarray:
    from scipy.signal import lfilter

    e = rng.standard_normal((b, n)) * np.sqrt(1 - rho**2)
    e[:, 0] = rng.standard_normal(b)  # stationary start
    return lfilter([1.0], [1.0, -rho], e, axis=1)


def _keep_mask(rng, b: int, n: int, dropout: float, burst: float) -> np.ndarray:
    if burst <= 1.0 or dropout <= 0:
        return rng.random((b, n)) >= dropout
    p_exit = 1.0 / burst
    p_enter = min(1.0, dropout / (1.0 - dropout) * p_exit)  # stationary drop fraction = dropout
    keep = np.empty((b, n), bool)
    state = rng.random(b) >= dropout
    u = rng.random((b, n))
    for i in range(n):
        keep[:, i] = state
        state = np.where(state, u[:, i] >= p_enter, u[:, i] < p_exit)
    return keep


def rice_interval(a_hat, sigma_a, level: float = 0.95, iters: int = 60):
    """Central Neyman interval for A from an observed amplitude Â ~ Rice(A, σ_A).

    The lower end solves P(Â' <= Â | A) = (1 + level)/2 (0 when even A = 0 is that extreme),
    the upper end P(Â' <= Â | A) = (1 - level)/2, by bisection (the CDF falls as A grows).
    """
    a_hat = np.asarray(a_hat, float)
    s = np.asarray(sigma_a, float)
    x = a_hat / s

    def solve(p):
        lo = np.zeros_like(x)
        hi = x + 12.0
        for _ in range(iters):
            mid = 0.5 * (lo + hi)
            above = stats.rice.cdf(x, mid) > p  # A = mid too small
            lo = np.where(above, mid, lo)
            hi = np.where(above, hi, mid)
        return 0.5 * (lo + hi)

    p_hi, p_lo = 0.5 * (1 + level), 0.5 * (1 - level)
    low = np.where(stats.rice.cdf(x, 1e-12) <= p_hi, 0.0, solve(p_hi))
    return low * s, solve(p_lo) * s


def debiased_amplitude(a_hat, sigma_a):
    """sqrt(max(Â² - 2σ_A², 0)), Â with its first-order upward bias removed.

    With ω fitted as well, E[Â] ≈ A + σ_A²/A: σ_A²/(2A) from the noise in quadrature with the
    signal (Rice), as much again from maximising the fit over ω. In the study the remaining
    bias is within ±2 % for A/σ_A >= 5 (raw Â: up to +5 %); at A/σ_A 2.5-3 it halves the bias
    (+33 % -> +20 %, +22 % -> +10 %) but fitting the highest noise peak still dominates. (At known ω the
    right correction would be Â² - σ_A²; see ``experiments/coverage.py``.)
    """
    a_hat = np.asarray(a_hat, float)
    return np.sqrt(np.maximum(a_hat**2 - 2 * np.asarray(sigma_a, float) ** 2, 0.0))


def _cover(lo, hi, truth) -> float:
    return float(np.mean((lo <= truth) & (truth <= hi))) if len(truth) else np.nan


def case_coverage(est: Estimates, truth: dict, post: PosteriorSummary | None = None) -> dict:
    """Coverage of 68 / 95 % intervals, bias and σ ratios over the converged windows of a case.

    ``lin_*``: the estimates table's default σ's (honest under coloured noise); ``white_*``: the
    white-noise σ's (thesis 5.42-5.45, ``sigma_*_white``); ``post_*``: the posterior's quantiles.
    """
    ok = np.flatnonzero(est.table["status"].to_numpy() == Status.CONVERGED)
    tab = est.table
    a, sa = tab["amplitude_mm"].to_numpy()[ok], tab["sigma_amplitude_mm"].to_numpy()[ok]
    fr, sf = tab["f0_hz"].to_numpy()[ok], tab["sigma_f0_hz"].to_numpy()[ok]
    sa_w, sf_w = tab["sigma_amplitude_white_mm"].to_numpy()[ok], tab["sigma_f0_white_hz"].to_numpy()[ok]
    at, ft = truth["amplitude_mm"][ok], truth["f0_hz"][ok]
    out = dict(
        n_windows=len(est.table), fitted=ok.size / max(len(est.table), 1),
        detected=float(np.mean(est.table["peak_fap"].to_numpy() <= 0.01)),
        snr_window=float(np.median(at / sa)) if ok.size else np.nan,
        bias_a_rel=float(np.mean(a / at - 1)) if ok.size else np.nan,
        bias_a_sigma=float(np.mean((a - at) / sa)) if ok.size else np.nan,
        bias_a_debiased_rel=float(np.mean(debiased_amplitude(a, sa) / at - 1)) if ok.size else np.nan,
    )
    for lab, z in (("68", Z68), ("95", Z95)):
        out[f"lin_a_{lab}"] = _cover(a - z * sa, a + z * sa, at)
        out[f"lin_f0_{lab}"] = _cover(fr - z * sf, fr + z * sf, ft)
        out[f"white_a_{lab}"] = _cover(a - z * sa_w, a + z * sa_w, at)
        out[f"white_f0_{lab}"] = _cover(fr - z * sf_w, fr + z * sf_w, ft)
        lo, hi = rice_interval(a, sa, level=0.68 if lab == "68" else 0.95)
        out[f"rice_a_{lab}"] = _cover(lo, hi, at)
    if post is not None:
        sel = np.searchsorted(ok, post.rows)
        at_p, ft_p = truth["amplitude_mm"][post.rows], truth["f0_hz"][post.rows]
        out["n_post"] = post.rows.size
        out["post_a_68"] = _cover(post.amplitude_q[:, 1], post.amplitude_q[:, 2], at_p)
        out["post_a_95"] = _cover(post.amplitude_q[:, 0], post.amplitude_q[:, 3], at_p)
        out["post_f0_68"] = _cover(post.f0_q[:, 1], post.f0_q[:, 2], ft_p)
        out["post_f0_95"] = _cover(post.f0_q[:, 0], post.f0_q[:, 3], ft_p)
        out["lin_a_95_on_post"] = _cover(a[sel] - Z95 * sa[sel], a[sel] + Z95 * sa[sel], at_p)
        out["lin_f0_95_on_post"] = _cover(fr[sel] - Z95 * sf[sel], fr[sel] + Z95 * sf[sel], ft_p)
        out["ratio_sigma_a"] = float(np.median(post.sigma_amplitude_mm / sa[sel]))
        out["ratio_sigma_f0"] = float(np.median(post.sigma_f0_hz / sf[sel]))
        out["bias_a_post_rel"] = float(np.mean(post.amplitude_mm / at_p - 1))
        out["chains_ok"] = float(np.mean(post.converged_chain))
        out["rho_post"] = float(np.mean(post.rho))
    return out


def window_scores(est: Estimates, truth: dict) -> pd.DataFrame:
    """Per converged window: the honesty features of `honesty_features` and whether each
    linearised 95 % interval covers the truth (for choosing flag thresholds)."""
    from ._flags import honesty_features

    ok = np.flatnonzero(est.table["status"].to_numpy() == Status.CONVERGED)
    feat = honesty_features(est).iloc[ok].reset_index(drop=True)
    tab = est.table.iloc[ok]
    a, sa = tab["amplitude_mm"].to_numpy(), tab["sigma_amplitude_mm"].to_numpy()
    feat["z_a"] = (a - truth["amplitude_mm"][ok]) / sa
    feat["z_f0"] = (tab["f0_hz"].to_numpy() - truth["f0_hz"][ok]) / tab["sigma_f0_hz"].to_numpy()
    lo, hi = rice_interval(a, sa)
    feat["rice_a_95"] = (lo <= truth["amplitude_mm"][ok]) & (truth["amplitude_mm"][ok] <= hi)
    feat["lin_a_95"] = np.abs(feat["z_a"]) < Z95
    feat["lin_f0_95"] = np.abs(feat["z_f0"]) < Z95
    return feat
