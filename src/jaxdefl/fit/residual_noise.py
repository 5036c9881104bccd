"""What the residual of a fit says about the model and the noise, for every window at once.

Per window, from the residual r = y - model on the window's frame clock (drop-outs are gaps):

- ``r2``: the fraction of the window's variance the model explains, 1 - Σr² / Σ(y - ȳ)².
- ``whiteness_p``: Ljung-Box test of the residual at the sample spacing (lags 1..H,
  H = min(20, n/5)): Q = n (n + 2) Σ ρ̂_h² / n_h with n_h the pairs at lag h (n - h without
  drop-outs, where Q is Ljung & Box's statistic), p = P(χ²_H > Q).
- ``kappa``: the residual's spectral density at f0 over its average density (1 for white
  noise). The least-squares estimates of A, f0 and phase have the variance white noise of the
  density at f0 would give them (Whittle 1952; Hannan 1973), so their σ's honest under coloured
  noise are the white-noise σ's times √kappa.

kappa is a smoothed periodogram of the residual in a band around f0, prewhitened (Andrews &
Monahan 1992): the band's periodogram ordinates are divided by the AR(1) spectrum fitted to the
residual's lag-1 correlation, averaged, and multiplied back by that spectrum at f0. Dividing
flattens the steep spectra of slow noise (AR(1), 1/f, drift) so the band's average is not pulled
up by its low-frequency side; averaging over the band keeps what AR(1) does not describe. The
ordinates within 2/T of f0 are left out (the fit removed the residual's power there). The band
holds about 2·max(30, √n) independent ordinates (σ's within ~7 % under white noise at
n = 600, 2.6 % at n = 35,000) and reaches at most f0/2 either side. A window too short for 16
independent ordinates (a few cycles) takes the AR(2) spectrum at f0 when its residual fails the
whiteness test, else κ = 1. With drop-outs the AR(1)
shape is that of the masked series, (1 - p) h(f) + p for a missing fraction p. All windows are
done at once with FFTs of the zero-filled frame grid (numpy), in chunks.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.fft
from scipy import special

from .._shapes import pow2_at_least
from ..series import Windows
from ..series.rows import unique_rows

__all__ = [
    "BAND_MIN_ORDINATES",
    "LJUNG_BOX_MAX_LAG",
    "WHITENESS_P_MIN",
    "ResidualNoise",
    "frame_positions",
    "harmonic_residual",
    "residual_noise",
]

LJUNG_BOX_MAX_LAG = 20
BAND_MIN_ORDINATES = 30  # half-band in Fourier bins (1/T): at least this, or √n when larger
BAND_MAX_FRACTION = 0.5  # of f0, either side
BAND_MIN_INDEPENDENT = 16  # fewer: no band estimate (σ's within ~12 % from 16 ordinates)
WHITENESS_P_MIN = 1e-3  # Ljung-Box p below which a short window's residual counts as coloured
PHI_MAX = 0.97  # prewhitening coefficient bound (Andrews & Monahan 1992)
_CHUNK_CELLS = 1 << 22


@dataclass(frozen=True)
class ResidualNoise:
    """Model adequacy and noise colour per window (NaN where no fit).

    Attributes (all (window,)):
        r2: variance fraction explained by the model.
        whiteness_p: Ljung-Box p-value of the residual; lags: the H used.
        kappa: residual spectral density at f0 over its mean (variance inflation of the σ's);
            (window, line) when `residual_noise` was given a frequency per line.
        phi: lag-1 autocorrelation of the residual (the prewhitening AR(1) coefficient).
    """

    r2: np.ndarray
    whiteness_p: np.ndarray
    lags: np.ndarray
    kappa: np.ndarray
    phi: np.ndarray


def frame_positions(w: Windows, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Frame index of every sample of the windows at ``rows`` (window, sample) and their sample
    spacing (window,): the frame clock where a window is on one, else the order of the samples
    (valid samples come first in a row)."""
    m = w.mask[rows]
    order = np.cumsum(m, axis=1) - 1
    k = np.where(m, w.k[rows], 0)
    increasing = np.all((np.diff(k, axis=1) > 0) | ~m[:, 1:], axis=1)
    use_k = w.on_clock[rows] & increasing
    g = np.where(use_k[:, None], k, np.where(m, order, 0))
    n = m.sum(axis=1)
    span = np.where(m, w.t[rows], -np.inf).max(axis=1) - np.where(m, w.t[rows], np.inf).min(axis=1)
    dt = np.where(use_k, w.dt[rows], span / np.maximum(n - 1, 1))
    return g, dt


def harmonic_residual(w: Windows, params: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
    """y - (C cos ωt + D sin ωt + E) of every window (or of those at ``rows``), (window, sample);
    ``params`` (window, param) as `HarmonicFit.params` (NaN rows give NaN)."""
    t, y = (w.t, w.y) if rows is None else (w.t[rows], w.y[rows])
    c, d, e, om = (params[:, i, None] if rows is None else params[rows, i, None] for i in range(4))
    ph = om * t
    return y - (c * np.cos(ph) + d * np.sin(ph) + e)


def residual_noise(
    w: Windows, residual: np.ndarray, f0_hz: np.ndarray, rows: np.ndarray | None = None
) -> ResidualNoise:
    """r2, Ljung-Box p, prewhitened spectral density ratio at f0 and lag-1 correlation per window.

    Args:
        w: the windows that were fitted.
        residual: (window, sample) data minus model (anything where masked).
        f0_hz: (window,) the model's frequency; the band of ``kappa`` is centred on it. Or
            (window, line) for a model of several lines: ``kappa`` is then (window, line), the
            density at each line (one FFT of the residual serves them all).
        rows: windows to assess (default: those with a finite f0 and more than 8 samples).
    Returns:
        ResidualNoise with NaN for the windows not assessed.
    """
    b = len(w)
    f0_hz = np.asarray(f0_hz, float)
    one_line = f0_hz.ndim == 1
    f0_hz = f0_hz.reshape(b, -1)  # (window, line)
    n_all = w.mask.sum(axis=1)
    if rows is None:
        finite = np.all(np.isfinite(np.where(w.mask, residual, 0)), axis=1)
        rows = np.flatnonzero(np.isfinite(f0_hz[:, 0]) & (n_all > 8) & finite)
    rows = np.asarray(rows, np.int64)
    out = {k: np.full(b, np.nan) for k in ("r2", "whiteness_p", "lags", "phi")}
    out["kappa"] = np.full(f0_hz.shape, np.nan)
    if one_line:
        out["kappa"] = out["kappa"][:, 0]
    if rows.size == 0:
        return ResidualNoise(**out)
    g_all, dt_all = frame_positions(w, rows)
    frames = g_all.max(axis=1) + 1
    # Windows that need the same FFT length go together, in chunks of bounded size.
    lengths = np.array([pow2_at_least(int(f) + LJUNG_BOX_MAX_LAG + 1) for f in frames])
    for m_len in np.unique(lengths):
        same = np.flatnonzero(lengths == m_len)
        size = max(1, _CHUNK_CELLS // int(m_len))
        for c0 in range(0, same.size, size):
            sel = same[c0 : c0 + size]
            with np.errstate(invalid="ignore", divide="ignore"):  # a window it cannot assess is NaN
                part = _chunk(w, residual, f0_hz, rows[sel], g_all[sel], dt_all[sel], frames[sel], int(m_len))
            for k, v in part.items():
                out[k][rows[sel]] = v[:, 0] if (k == "kappa" and one_line) else v
    return ResidualNoise(**out)


def _chunk(w, residual, f0_hz, rows, g, dt, frames, m_len) -> dict:
    m = w.mask[rows]
    n = m.sum(axis=1).astype(float)
    y = np.where(m, w.y[rows], 0.0)
    r = np.where(m, residual[rows], 0.0)
    ybar = y.sum(axis=1) / n
    ss_y = np.sum(np.where(m, y - ybar[:, None], 0.0) ** 2, axis=1)
    rbar = r.sum(axis=1) / n
    rc = np.where(m, r - rbar[:, None], 0.0)
    ss_r = np.sum(rc**2, axis=1)
    r2 = 1.0 - np.sum(r**2, axis=1) / ss_y

    # Frame indices are distinct within a window; masked samples all go to the last cell, which
    # no frame reaches (the grid is longer than the frames plus the lags) and which ends zero.
    bi = np.arange(rows.size)[:, None]
    cell = np.where(m, g, m_len - 1)
    grid = np.zeros((rows.size, m_len))
    present = np.zeros((rows.size, m_len), bool)
    grid[bi, cell] = rc
    present[bi, cell] = m
    n_lag = np.minimum(LJUNG_BOX_MAX_LAG, np.maximum(1, n // 5)).astype(int)
    # Lag products on the frame grid (a missing frame is a zero), Σ r_k r_{k+h} and the pairs,
    # from the power spectra: the grid is longer than the frames plus the lags, so the circular
    # autocorrelation is the plain one; its first lags are one matrix product with cosines.
    # The pairs depend on the frames present only: the axes of a plate, and the plates where
    # drop-outs hit whole frames, share them, so each distinct frame grid is transformed once.
    fr_all = scipy.fft.rfft(grid, axis=1)
    frame_sets, inverse = unique_rows(np.packbits(present, axis=1))
    fm = scipy.fft.rfft(np.unpackbits(frame_sets, axis=1, count=m_len).astype(np.float64), axis=1)
    j = np.arange(fr_all.shape[1])
    weight = np.where((j == 0) | (2 * j == m_len), 1.0, 2.0) / m_len
    cosines = weight[:, None] * np.cos(2 * np.pi * np.outer(j, np.arange(LJUNG_BOX_MAX_LAG + 1)) / m_len)
    acov = (fr_all.real**2 + fr_all.imag**2) @ cosines
    pairs = np.rint((fm.real**2 + fm.imag**2) @ cosines)[inverse.ravel()]

    # Ljung-Box with the pairs each lag actually has (drop-outs remove some).
    h = np.arange(1, LJUNG_BOX_MAX_LAG + 1)
    with np.errstate(invalid="ignore", divide="ignore"):
        rho = acov[:, 1:] / ss_r[:, None]
        terms = np.where((h[None, :] <= n_lag[:, None]) & (pairs[:, 1:] > 0), rho**2 / pairs[:, 1:], 0.0)
    q = n * (n + 2) * terms.sum(axis=1)
    p_white = special.chdtrc(n_lag, q)  # χ² survival (scipy.stats would cost 1 s of import)

    # Prewhitened band average of the periodogram around f0: AR(2) by Yule-Walker from the
    # autocorrelations at lags 1 and 2 (each lag's products over its own pairs).
    with np.errstate(invalid="ignore", divide="ignore"):
        rho1, rho2 = ((acov[:, h] / pairs[:, h]) / (ss_r / n) for h in (1, 2))
    rho1 = np.where(np.isfinite(rho1), np.clip(rho1, -PHI_MAX, PHI_MAX), 0.0)
    rho2 = np.where(np.isfinite(rho2), np.clip(rho2, -PHI_MAX, PHI_MAX), 0.0)
    phi2 = (rho2 - rho1**2) / (1 - rho1**2)
    phi1 = rho1 * (1 - phi2)
    stationary = (np.abs(phi2) < PHI_MAX) & (phi1 + phi2 < PHI_MAX) & (phi2 - phi1 < PHI_MAX)
    phi1 = np.where(stationary, phi1, rho1)  # else AR(1)
    phi2 = np.where(stationary, phi2, 0.0)
    missing = np.clip(1.0 - n / frames, 0.0, 1.0)
    span = frames * dt
    f0 = f0_hz[rows]
    # AR(2) variance per unit innovation variance: the mean of its density over (0, fs/2).
    gamma0 = (1 - phi2) / ((1 + phi2) * ((1 - phi2) ** 2 - phi1**2))

    def shape(f):  # unit-variance AR(2) spectrum of the masked series, fs S(f) / γ0
        c1 = np.cos(2 * np.pi * f * dt[:, None])
        c2 = 2 * c1**2 - 1
        p1, p2 = phi1[:, None], phi2[:, None]
        den = 1 + p1**2 + p2**2 - 2 * p1 * (1 - p2) * c1 - 2 * p2 * c2
        return (1 - missing[:, None]) / (den * gamma0[:, None]) + missing[:, None]

    nyq = 0.5 / dt[:, None]
    kappa = np.empty(f0.shape)
    for j in range(f0.shape[1]):  # each line's band (one for the thesis model)
        fj = f0[:, j]
        half = np.minimum(np.maximum(BAND_MIN_ORDINATES, np.sqrt(n)) / span, BAND_MAX_FRACTION * fj)
        # Only the bins of each window's own band are transformed into powers (a window whose
        # f0 lies far from the others' does not widen everyone's).
        lo_bin, hi_bin = (fj - half) * m_len * dt, (fj + half) * m_len * dt
        finite = np.isfinite(lo_bin) & np.isfinite(hi_bin)
        top = m_len // 2
        lo = np.clip(np.floor(np.where(finite, lo_bin, 1.0)), 1, top).astype(np.int64)
        hi = np.clip(np.ceil(np.where(finite, hi_bin, 0.0)) + 1, lo, top + 1).astype(np.int64)
        idx = lo[:, None] + np.arange(max(1, int((hi - lo).max())))[None, :]
        inside = idx < hi[:, None]
        idx = np.minimum(idx, top)
        fr = np.take_along_axis(fr_all, idx, axis=1)
        freq = idx / (m_len * dt[:, None])
        dist = np.abs(freq - fj[:, None])
        band = inside & (dist >= 2.0 / span[:, None]) & (dist <= half[:, None]) & (freq < nyq)
        power = (fr.real**2 + fr.imag**2) / n[:, None]
        with np.errstate(invalid="ignore", divide="ignore"):
            flat = np.where(band, power / shape(freq), 0.0).sum(axis=1) / band.sum(axis=1)
            kj = shape(fj[:, None])[:, 0] * flat / (ss_r / n)
        # A band of fewer than BAND_MIN_INDEPENDENT independent ordinates (a window of a few
        # cycles, 2 T half - 4 of them) would make the σ's noisier than white ones: there, the
        # AR(2) spectrum at f0 when the residual's colour is significant, else white (κ = 1).
        independent = 2 * half * span - 4
        short = np.where(p_white < WHITENESS_P_MIN, shape(fj[:, None])[:, 0], 1.0)
        kappa[:, j] = np.where(independent >= BAND_MIN_INDEPENDENT, kj, short)
    return dict(r2=r2, whiteness_p=p_white, lags=n_lag.astype(float), kappa=kappa, phi=rho1)
