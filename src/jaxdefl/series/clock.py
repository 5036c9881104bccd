"""The sample clock behind a series of timestamps: t_k = t0 + k dt with integer frame indices k.

Real devices do not write their clock exactly: a camera's timestamps jitter around its frame
clock, a logger rounds them (a logger writing ``k × 0.0077531 s`` with five significant digits
repeats a stamp once the rounding step exceeds the interval), and frames drop out. `fit_clock`
recovers the clock from such stamps, in row order:

1. A first interval from the spacings: the median of the positive spacings within a factor 1.5
   of their 10th percentile, re-centred a few times (the one-frame spacings, even when most
   frames are lost, but not the smallest spacing, which jitter shrinks).
2. Integer indices from the spacings, k_{i+1} − k_i = max(1, round(Δt_i / dt)) (a repeated stamp
   is the next frame, a gap of m frames is m).
3. A robust line t = t0 + dt k (least squares, then again without the samples beyond 4 robust
   σ's), and corrections where the indices went wrong: the running median of the residuals, in
   frames, rounded, is added to k (a median keeps the step of a misread gap sharp and ignores
   the rounding and jitter of single stamps). Repeated until no index changes.

The result reports the recovered interval, the jitter RMS (the stamps' scatter about the
recovered clock) and the clock drift (the change of the interval over the series, from a
quadratic term, in parts per million).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._numerics import MAD_TO_SIGMA, mad_sigma

__all__ = ["Clock", "SNAP_MAX", "fit_clock", "robust_interval"]

# A series whose stamps scatter less than this fraction of a frame (RMS) about the recovered
# clock is snapped to it for the periodogram's frame grid (the fit always uses the stamps).
SNAP_MAX = 0.25
# Running-median length (samples) of the index corrections: odd, long enough that the median of
# rounding or jitter noise of +-0.65 frame stays well inside +-0.5 frame.
_MEDIAN_LEN = 31
_MAX_ROUNDS = 4
# Stamps whose indices come from their spacings alone, before the line takes over.
_SEED = 32


@dataclass(frozen=True)
class Clock:
    """A recovered sample clock.

    Attributes:
        t0: time of frame 0 in the units of the input (s), relative to the input's first stamp
            when `fit_clock` was given relative times.
        dt: the recovered interval (s).
        k: (sample,) integer frame index of every stamp, strictly increasing, k[0] == 0.
        jitter_rms: RMS of the stamps about t0 + k dt (s).
        drift_ppm: change of the interval from the first to the last frame, in ppm of dt.
    """

    t0: float
    dt: float
    k: np.ndarray
    jitter_rms: float
    drift_ppm: float

    @property
    def t(self) -> np.ndarray:
        """The recovered clock at every stamp: t0 + k dt."""
        return self.t0 + self.k * self.dt

    @property
    def jitter_frames(self) -> float:
        return self.jitter_rms / self.dt if self.dt > 0 else np.inf


def robust_interval(t: np.ndarray, hint: float | None = None) -> float:
    """A first frame interval of the sorted stamps ``t``: the median of the positive spacings
    within a factor 1.5 of their 10th percentile (or of ``hint``, a nominal interval, when given).
    NaN when no spacing is positive."""
    d = np.diff(np.asarray(t, dtype=np.float64))
    pos = d[d > 0]
    if not pos.size:
        return float("nan")
    q = float(hint) if hint is not None else float(np.quantile(pos, 0.1))
    for _ in range(6):  # the 10th percentile sits low in a jittered cluster: re-centre on it
        near = pos[(pos >= q / 1.5) & (pos <= 1.5 * q)]
        if not near.size:
            break
        q_new = float(np.median(near))
        if q_new == q:
            break
        q = q_new
    return q


def _line(k: np.ndarray, t: np.ndarray) -> tuple[float, float, np.ndarray]:
    """t = a + b k by least squares, then again without the stamps beyond 4 robust σ's."""
    keep = np.ones(k.size, bool)
    for _ in range(2):
        kc = k[keep].mean()
        tc = t[keep].mean()
        dk = k[keep] - kc
        den = float(dk @ dk)
        b = float(dk @ (t[keep] - tc)) / den if den > 0 else 0.0
        a = tc - b * kc
        r = t - a - b * k
        s = mad_sigma(r)
        if not s > 0:
            break
        keep = np.abs(r) <= 4 * s
        if keep.sum() < 2:
            keep[:] = True
            break
    return a, b, r


def _running_median(u: np.ndarray, ends: str = "nearest") -> np.ndarray:
    """Running median of ``_MEDIAN_LEN`` samples. ``ends="nearest"`` extends each end by its
    last sample (a monotone sequence comes back unchanged); ``ends="median"`` by the median of
    its own half window (the last sample's noise then does not decide the ends)."""
    from scipy.ndimage import median_filter

    h = _MEDIAN_LEN // 2
    if u.size <= _MEDIAN_LEN:
        return np.full(u.size, np.median(u))
    if ends == "nearest":
        return median_filter(u, size=_MEDIAN_LEN, mode="nearest")
    padded = np.concatenate([np.full(h, np.median(u[: h + 1])), u, np.full(h, np.median(u[-h - 1 :]))])
    return median_filter(padded, size=_MEDIAN_LEN, mode="nearest")[h:-h]


def _assign(t: np.ndarray, a: float, b: float) -> np.ndarray:
    """Frame indices of the stamps ``t`` on the line t = a + b k, strictly increasing.

    x = (t − a)/b − i is the number of frames skipped before stamp i plus its noise in frames:
    its running median, rounded, ignores the scatter of single stamps (jitter, a logger's
    rounding step even above the interval) and keeps steps sharp (a monotone sequence is its
    own running median, so heavy drop-outs stay exact where the scatter is small).
    """
    idx = np.arange(t.size)
    x = (t - a) / b - idx
    smooth = _running_median(x)
    g = np.rint(smooth)
    h = _MEDIAN_LEN // 2
    if x.size > 2 * _MEDIAN_LEN:
        # within half a window of an end the running median is the end sample's own value; where
        # the stamps scatter by a quarter frame or more, take the ends' half-window median instead
        dev = np.abs(x - smooth)
        padded = None
        for end in (slice(0, h), slice(-h, None)):
            near = dev[:_MEDIAN_LEN] if end.start == 0 else dev[-_MEDIAN_LEN:]
            if MAD_TO_SIGMA * float(np.median(near)) >= 0.25:
                padded = np.rint(_running_median(x, ends="median")) if padded is None else padded
                g[end] = padded[end]
    return idx + np.maximum.accumulate(g)


def _coherent_interval(t: np.ndarray, dt0: float) -> tuple[float, float]:
    """Interval and phase of the clock from the stamps' coherence: the frequency ν near 1/dt0
    where |Σ exp(2πi ν t)| peaks. Drop-outs do not move the peak and jitter only lowers it, so
    this finds the interval where spacings are too noisy to count frames one by one. The
    stamps are binned at dt0/8 for an FFT over the whole span, then the peak is refined by
    direct sums. Returns (dt, t0) with t0 the time of a frame nearest t[0]."""
    h = dt0 / 8
    span = float(t[-1] - t[0])
    m = int(span / h) + 1
    if m > 1 << 25:  # a very long series: the first part fixes the interval well enough
        t = t[: int(t.size * (1 << 25) / m)]
        m = int((t[-1] - t[0]) / h) + 1
    hist = np.bincount(((t - t[0]) / h).astype(np.int64), minlength=m).astype(np.float64)
    from scipy.fft import next_fast_len, rfft

    n_fft = next_fast_len(2 * m, real=True)
    spec = np.abs(rfft(hist, n=n_fft))
    nu = np.arange(spec.size) / (n_fft * h)
    band = (nu >= 0.8 / dt0) & (nu <= 1.25 / dt0)
    if not band.any():
        return dt0, float(t[0])
    nu0 = float(nu[band][np.argmax(spec[band])])
    tr = t - t[0]
    step = 1.0 / (n_fft * h)
    for _ in range(3):  # zoom: 9 direct sums around the peak, then a third of the step
        grid = nu0 + step * np.linspace(-1, 1, 9)
        c = np.abs(np.exp(2j * np.pi * grid[:, None] * tr[None, :]).sum(axis=1))
        nu0 = float(grid[np.argmax(c)])
        step /= 3
    phase = np.angle(np.exp(2j * np.pi * nu0 * tr).sum()) / (2 * np.pi)
    return 1.0 / nu0, float(t[0] + phase / nu0)


def fit_clock(t: np.ndarray, hint: float | None = None) -> Clock:
    """Recover the sample clock of the stamps ``t`` (s, in row order, non-decreasing).

    Two ways, the one whose stamps sit closer to their clock wins: counting frames from the
    spacings (the line is fitted on the first ``_SEED`` stamps, whose indices come from their
    spacings, then takes in twice as many stamps at a time, indices from `_assign`), which
    holds for a logger's rounding however coarse; and the stamps' coherence
    (`_coherent_interval`), which holds for jitter of up to a few tenths of a frame however
    many frames drop out. The first alone is used when it leaves less than 0.05 frame RMS.

    Args:
        t: (sample,) timestamps; subtract a large epoch first for full precision.
        hint: a nominal interval (e.g. 1 / --frame-rate) to start from instead of the spacings.

    Returns:
        The clock; for fewer than two stamps or no positive spacing, dt is NaN.
    """
    t = np.asarray(t, dtype=np.float64)
    n = t.size
    if n < 2:
        return Clock(float(t[0]) if n else 0.0, float("nan"), np.zeros(n, np.int64), 0.0, 0.0)
    dt = robust_interval(t, hint)
    if not np.isfinite(dt) or dt <= 0:
        return Clock(float(t[0]), float("nan"), np.zeros(n, np.int64), 0.0, 0.0)
    m = min(n, _SEED)
    d = np.diff(t[:m])
    k = np.concatenate([[0.0], np.cumsum(np.maximum(1.0, np.rint(d / dt)))])
    a, b, _ = _line(k, t[:m])
    while m < n and b > 0:
        m = min(n, 2 * m)
        k = _assign(t[:m], a, b)
        a, b, _ = _line(k, t[:m])
    best = _settle(t, k, a, b)
    if not best.jitter_frames < 0.05 and n >= 8:
        dt_c, a_c = _coherent_interval(t, dt)
        other = _settle(t, _assign(t, a_c, dt_c), a_c, dt_c)
        if other.jitter_rms < best.jitter_rms:
            best = other
    return best


def _settle(t: np.ndarray, k: np.ndarray, a: float, b: float) -> Clock:
    """Refit the line and reassign the indices until they stop changing; the clock's report."""
    n = t.size
    for _ in range(_MAX_ROUNDS):
        if not b > 0:
            break
        a, b, _ = _line(k, t)
        k_new = _assign(t, a, b)
        if np.array_equal(k_new, k):
            break
        k = k_new
    a, b, _ = _line(k, t)
    a, b = a + b * k[0], b
    k = k - k[0]
    r = t - a - b * k
    drift = 0.0
    if n >= 8 and k[-1] > 0 and b > 0:
        c2 = np.polyfit(k / k[-1], r, 2)[0]  # r ≈ c2 x² + ...: the interval changes by 2 c2 / k_last
        drift = float(2 * c2 / k[-1] / b * 1e6)
    return Clock(float(a), float(b), k.astype(np.int64), float(np.sqrt(np.mean(r**2))), drift)
