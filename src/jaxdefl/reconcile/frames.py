"""The frames level: the recording's pixels against the frame simulator's, on a short clip.

Where the trajectories agree with the simulation but the camera does not (a noisier sensor, a
modulation frequency or integration time other than configured, pixels that saturate or drop
out), the difference is in the pixels. A clip of the recording (its first `CLIP_S` seconds) is
compared with clips the frame simulator renders from the same config (`render_frames`):

===============  =========================================================================
metric           statistic per amplitude bin (distance: RMS over the bins of log ratios)
===============  =========================================================================
range_noise      the median over the bin's pixels of each pixel's short-term range noise:
                 its range over the clip less a line in time and the loading harmonic at f0
                 (moving plates keep only their noise), then σ of the first differences
                 (MAD, or the plain deviation where the ranges sit on a lattice) / √2 — the
                 ToF noise against amplitude of the thesis (section 3.2), or a Kinect's depth
                 noise against its IR image
valid_share      the share of the bin's range samples that are valid (finite and > 0):
                 saturation, low amplitude, drop-outs
===============  =========================================================================

The bins are the deciles of the simulated clip's per-pixel median amplitude (the range's when a
recording has no amplitude image), so that both sides are binned alike; a bin needs
`MIN_PIXELS` pixels on both sides. The null band comes from clips of other seeds compared with
the nominal clip, their log ratios pooled over clips and bins into a χ² band (`pooled_null_95`);
*after* compares the recording with a clip rendered
with the reconciled ``[[effect]]`` tables.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from .._numerics import harmonic_design, mad_sigma, wls
from .metrics import FAMILY_Q

__all__ = [
    "CLIP_S",
    "FRAME_METRICS",
    "FrameStats",
    "clip_stats",
    "frame_levels",
    "frame_stats",
    "log_ratios",
    "pooled_null_95",
]

CLIP_S = 4.0
N_BINS = 10
MIN_PIXELS = 20
FRAME_METRICS = ("range_noise", "valid_share")


@dataclass
class FrameStats:
    """Per amplitude bin: median short-term range noise (mm), valid share, pixel count."""

    edges: np.ndarray
    range_noise: np.ndarray
    valid_share: np.ndarray
    pixels: np.ndarray


def _pixel_noise(t: np.ndarray, r: np.ndarray, f0_hz: float) -> np.ndarray:
    """(pixel,) short-term noise of each column of ``r`` (frame, pixel), NaN where a pixel is
    ever invalid or the clip is too short."""
    n = r.shape[0]
    if n < 8:
        return np.full(r.shape[1], np.nan)
    tt = t - t[0]
    w = 2 * math.pi * f0_hz * tt
    a = np.concatenate([harmonic_design(w), tt[:, None]], axis=1)
    ok = np.all(np.isfinite(r) & (r > 0), axis=0)
    x = np.where(ok[None, :], r, 0.0).astype(np.float64)
    res = x - wls(a, x, cov=False)[2]
    d = np.diff(res, axis=0)
    mad = mad_sigma(d, axis=0)
    lattice = mad <= 1e-9 * np.maximum(np.abs(x).max(axis=0), 1.0)
    sd = np.where(lattice, d.std(axis=0), mad) / math.sqrt(2.0)
    return np.where(ok, sd, np.nan)


def frame_stats(
    t: np.ndarray,
    frames: np.ndarray,
    amplitude: np.ndarray | None,
    f0_hz: float,
    edges: np.ndarray | None = None,
) -> FrameStats:
    """The clip's statistics per bin of the pixels' median amplitude (``edges``: None for the
    deciles of this clip's, as the nominal clip sets them)."""
    n = frames.shape[0]
    r = frames.reshape(n, -1).astype(np.float64)
    key_src = amplitude if amplitude is not None else frames
    key = np.nanmedian(np.where(np.isfinite(key_src), key_src, np.nan).reshape(n, -1), axis=0)
    if edges is None:
        edges = np.nanquantile(key, np.linspace(0.0, 1.0, N_BINS + 1))
        edges[0], edges[-1] = -np.inf, np.inf
    b = np.clip(np.searchsorted(edges, key, side="right") - 1, 0, len(edges) - 2)
    b = np.where(np.isfinite(key), b, -1)
    sd = _pixel_noise(np.asarray(t, np.float64), r, f0_hz)
    valid = np.mean(np.isfinite(r) & (r > 0), axis=0)
    m = len(edges) - 1
    noise, share, count = np.full(m, np.nan), np.full(m, np.nan), np.zeros(m, int)
    for k in range(m):
        sel = b == k
        count[k] = int(sel.sum())
        if count[k] < MIN_PIXELS:
            continue
        share[k] = float(valid[sel].mean())
        s = sd[sel]
        s = s[np.isfinite(s)]
        if s.size >= MIN_PIXELS:
            noise[k] = float(np.median(s))
    return FrameStats(np.asarray(edges, float), noise, share, count)


def distance(a: FrameStats, b: FrameStats, metric: str) -> float:
    """RMS over the bins both sides measure of log(a / b) of one metric."""
    r = log_ratios(a, b, metric)
    r = r[np.isfinite(r)]
    return float(np.sqrt(np.mean(r**2))) if r.size else float("nan")


def log_ratios(a: FrameStats, b: FrameStats, metric: str) -> np.ndarray:
    """(bin,) log(a / b) of one metric, NaN where a side does not measure the bin."""
    x, y = getattr(a, metric), getattr(b, metric)
    ok = np.isfinite(x) & np.isfinite(y) & (x > 0) & (y > 0)
    return np.where(ok, np.log(np.where(ok, x, 1.0) / np.where(ok, y, 1.0)), np.nan)


def pooled_null_95(null_ratios: list[np.ndarray], q: float = 0.95) -> float:
    """The 95th percentile of `distance` under the null from a few clips: the clips' log ratios
    pooled over clips and bins give their variance s² from k = n·m values (each bin's log ratio
    ≈ N(0, σ²), the bins alike: deciles of pixels), and a new clip's distance² over m bins is
    σ² χ²_m / m, so distance² / s² is F(m, k) and the band s·√F₀.₉₅(m, k) — a 95th percentile
    of the next distance, where the empirical one of 4 clips is about an 80th (``q``: another
    percentile, s·√F_q(m, k)). NaN without two finite ratios."""
    from scipy import stats

    r = np.concatenate([np.asarray(x, float).ravel() for x in null_ratios]) if null_ratios else np.zeros(0)
    r = r[np.isfinite(r)]
    if r.size < 2:
        return float("nan")
    m = max(1, round(r.size / max(len(null_ratios), 1)))  # bins a distance averages over
    s2 = float(np.mean(r * r))
    return float(math.sqrt(s2 * stats.f.ppf(q, m, r.size)))


def clip_stats(cfg, seed: int, f0_hz: float, edges: np.ndarray | None, specs=(), seconds: float = CLIP_S):
    """Render ``seconds`` of the config (with ``specs`` as its ``[[effect]]`` tables) and reduce it."""
    from ..simulate import render_frames

    cfg = dataclasses.replace(cfg, effects=tuple(specs))
    t, fr, amp, _ = render_frames(cfg, seconds, seed)
    return frame_stats(t, fr, amp, f0_hz, edges)


def read_clip(recording, seconds: float = CLIP_S):
    """(t, frames, amplitude | None) of a frame recording's first ``seconds``."""
    t0 = None
    parts_t, parts_f, parts_a = [], [], []
    for ch in recording.chunks():
        t0 = ch.t[0] if t0 is None else t0
        keep = ch.t - t0 <= seconds
        parts_t.append(ch.t[keep])
        parts_f.append(ch.frames[keep])
        parts_a.append(None if ch.amplitude is None else ch.amplitude[keep])
        if not keep.all():
            break
    amp = None if any(a is None for a in parts_a) else np.concatenate(parts_a)
    return np.concatenate(parts_t), np.concatenate(parts_f), amp


def frame_levels(recording, cfg, f0_hz: float, specs=(), seed: int = 0, n_null: int = 4) -> list[dict]:
    """The frames level's rows of ``reconcile.json``: {level, metric, before, after, null_95,
    null_family}."""
    t, fr, amp = read_clip(recording)
    seconds = float(min(CLIP_S, t[-1] - t[0]))
    nominal = clip_stats(cfg, seed + 1, f0_hz, None, seconds=seconds)
    rec = frame_stats(t, fr, amp, f0_hz, nominal.edges)
    fixed = clip_stats(cfg, seed + 1, f0_hz, nominal.edges, specs, seconds) if specs else nominal
    null = [clip_stats(cfg, seed + 2000 + j, f0_hz, nominal.edges, seconds=seconds) for j in range(n_null)]
    rows = []
    for metric in FRAME_METRICS:
        ratios = [log_ratios(s, nominal, metric) for s in null]
        band = pooled_null_95(ratios)
        rows.append(
            dict(
                level="frames",
                metric=metric,
                before=distance(rec, nominal, metric),
                after=distance(rec, fixed, metric),
                null_95=band,
                null_family=pooled_null_95(ratios, FAMILY_Q),
                null_method="pooled_chi2",
                recording=[None if not np.isfinite(v) else float(v) for v in getattr(rec, metric)],
                simulation=[None if not np.isfinite(v) else float(v) for v in getattr(nominal, metric)],
            )
        )
    return rows
