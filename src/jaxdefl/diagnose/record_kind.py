"""What kind of record this is, recognised before anything is named (issue 23, Build item 4).

The vocabulary of `effects` is written against the thesis' nominal model: one steady loading
harmonic per plate and axis. A record of another kind leaves its own motion in that model's
residual, and whichever named terms absorb part of it pass their tests: a shaker's second forcing
line folded onto 2 f0 becomes `harmonic_distortion`, a forcing step a "crack", a free decay's
large first cycles `outliers`. So the kind is recognised first, from the spectrum and the
envelope of the record's strongest series, and the nominal model follows it:

- ``forced_harmonic``: one loading line carries the motion (the thesis' record): nominal model
  unchanged, the whole vocabulary searched.
- ``multi_tone``: several lines that are not harmonics of one another each carry a share of the
  motion (a shaker driven by a multi-tone signal). The nominal model holds every forcing line
  (`jaxdefl.fit` with ``--lines N``: frequencies refined, amplitudes per series); the effects
  defined against one loading harmonic cannot be told apart from the forcing, and a change of
  the lines' amplitudes is located (`forcing_change`): a forcing step moves every line's
  amplitude by one factor with its frequency kept, a stiffness loss moves the frequencies (of a
  free response) or each line's amplitude and phase by its own factor (a forced response); where
  the record cannot tell the two apart the report says so.
- ``free_decay``: the motion dies away (an impact, a release): the nominal model is damped modes
  (`jaxdefl.fit` ``--model damped --lines N``, N by BIC: frequency, damping ratio and the
  amplitude of each mode on every series).
- ``broadband``: no few lines carry the motion (random excitation): no loading harmonic, so
  nothing defined against one is named.
- ``quasi_static``: the motion is slower than two cycles over the record (a slowly loaded
  specimen, a staircase of positions): the load path itself is the motion; it is located (its
  steps and ramps), not named.

The kind is judged on the motion, not on whatever holds the variance. A slow level path may
dominate a vibration record without being its motion: a structured-light camera's level jumps
(about one a minute, 3 mm, Fig. 6.64) and session wander outweigh a 2.5-mm loading harmonic over
a few minutes. So when the slow part holds most of the variance, the level path is taken out
first (`level_path`: its steps by binary segmentation, its slow wander below SLOW_CYCLES) and the
record is a vibration record, judged on what remains, when a line many cycles over the record
(FORCED_CYCLES) carries most of that remainder (FORCED_SHARE); otherwise the path is the motion
and the record is quasi-static. A staircase of positions leaves noise (or the path's own shape,
a line of a few cycles) once its steps are out; a loaded beam seen by a jumping camera leaves its
loading line.

Every threshold below is a share of the record's variance or a ratio of amplitudes, so a kind is
recognised the same way in millimetres, volts or g.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .._numerics import difference_sigma
from ..effects import EFFECT_IDS, REGISTRY
from ._base import Context, State

__all__ = [
    "RecordKind",
    "recognise",
    "kind_nominal",
    "HARMONIC_LOCKED",
    "KINDS",
    "value_lattice",
    "binary_steps",
    "level_path",
]

KINDS = ("forced_harmonic", "multi_tone", "free_decay", "broadband", "quasi_static")
# Effects defined against one steady loading harmonic: under another kind of record they
# cannot be told from the record's own motion (`cannot_tell`). Each effect says where it is
# searched (`jaxdefl.effects` ``Entry.record_kinds``; a damped-mode model leaves its largest
# misfit where the motion is largest, which a mixture would read as outliers).
HARMONIC_LOCKED = tuple(e for e in EFFECT_IDS if REGISTRY[e].record_kinds == ("forced_harmonic",))
# what remains searched, per kind (None: everything)
SEARCHED = {
    kind: None
    if kind == "forced_harmonic"
    else tuple(e for e in EFFECT_IDS if REGISTRY[e].record_kinds is None or kind in REGISTRY[e].record_kinds)
    for kind in KINDS
}
LINE_SHARE = 0.03  # a line carries at least this share of the record's variance
# multi-tone: a second line, not a harmonic of the strongest, carries this share (an extra
# vibration or a second mode under the noise is an effect's business, not the forcing's)
TONE_SHARE = 0.15
LINES_MAX = 6
SIDEBAND_CYCLES = 3.0  # a peak this close (in 1/T) to a line is that line's envelope
SLOW_CYCLES = 2.5  # below this many cycles over the record, motion is the load path
SLOW_SHARE = 0.6  # quasi-static: the slow part holds this share of the variance
LINES_SHARE_MIN = 0.5  # broadband: the strongest lines hold less than this share
# ... and the rest is not white measurement noise: the top tenth of its smoothed spectrum holds
# this share of its power (white noise: ~0.15; a randomly excited resonance: most of it)
COLOURED_SHARE = 0.4
DECAY_RATIO = 2.5  # free decay: the strongest line's amplitude falls this much over the record
ONSET_RATIO = 1.2  # and its envelope's largest value is in the first fifth of the record
# A vibration under a dominant level path: once the path is out, a line of at least this many
# cycles over the record (a forcing, not the path's own shape) carries this share of what is left
FORCED_CYCLES = 10.0
FORCED_SHARE = 0.5
# the level path's steps: a split pays when it removes this many log n noise variances (BIC with
# a margin: a step has a time and a size), at most PATH_STEPS_MAX of them
STEP_PENALTY = 3.0
PATH_STEPS_MAX = 60


@dataclass
class RecordKind:
    """The recognised kind and the numbers it was recognised from (DIAG.json ``record``)."""

    kind: str
    lines_hz: list[float] = field(default_factory=list)
    line_shares: list[float] = field(default_factory=list)
    slow_share: float = 0.0
    decay_ratio: float = 1.0
    modes: list[dict] = field(default_factory=list)
    forcing_change: dict | None = None
    resolution: dict | None = None
    level_path: dict | None = None
    statement: str = ""

    def to_json(self) -> dict:
        return {
            "kind": self.kind,
            "lines_hz": self.lines_hz,
            "line_shares": self.line_shares,
            "slow_share": self.slow_share,
            "decay_ratio": self.decay_ratio,
            "modes": self.modes,
            "forcing_change": self.forcing_change,
            "resolution": self.resolution,
            "level_path": self.level_path,
            "statement": self.statement,
        }


def value_lattice(y: np.ndarray) -> float | None:
    """The step q of the lattice the values sit on, read from their spacing, or None.

    The spacings of the distinct values are multiples of q when the values are on a lattice
    (an ADC's step, a table's written decimals, a disparity camera's depth steps): q is the
    smallest spacing that the others are whole multiples of (within 2 % of q, for decimals
    written from binary floats), checked on every spacing. Values averaged over many rounded
    pixels (a plate's centroid) are not on a lattice: None.
    """
    y = np.asarray(y, float)
    y = y[np.isfinite(y)]
    scale = float(np.max(np.abs(y))) if y.size else 0.0
    # values equal but for their last binary digits (a decimal written from a product) are one
    u = np.unique(np.round(y / scale, 10) * scale) if scale > 0 else np.unique(y)
    if u.size < 8:
        return None
    d = np.diff(u)
    d = d[d > 0]
    q = float(np.min(d))
    if q <= 0 or not math.isfinite(q):
        return None
    # the smallest spacing may be a rounding artefact of a decimal written from a binary
    # float (1.22070e-3 and 1.22071e-3): take the median of the spacings within 2 % of it
    q = float(np.median(d[d < 1.02 * q]))
    # an ADC's step is not exactly uniform (its calibration's rounding): the spacings of
    # neighbouring values are checked, where the error of a multiple stays small
    k = d[d < 20.5 * q] / q
    if k.size < 0.5 * d.size or np.mean(np.abs(k - np.rint(k)) < 0.1) < 0.9:
        return None
    return q


def _grid(t: np.ndarray, y: np.ndarray, dt: float) -> np.ndarray:
    """The series on its frame grid (gaps linearly filled): for spectra and envelopes only."""
    k = np.rint((t - t[0]) / dt).astype(np.int64)
    g = np.full(int(k[-1]) + 1, np.nan)
    g[k] = y
    bad = np.isnan(g)
    if bad.any():
        idx = np.arange(g.size)
        g[bad] = np.interp(idx[bad], idx[~bad], g[~bad])
    return g


def _lines(g: np.ndarray, dt: float, n_max: int = LINES_MAX) -> tuple[list[float], list[float]]:
    """Lines found one at a time at the residual periodogram's peak (zero-padded FFT, linear
    least squares at the peak), with the share of the variance each removes."""
    n = g.size
    t = np.arange(n) * dt
    r = g - g.mean()
    var0 = float(np.mean(r**2)) or 1e-300
    m = 1 << int(math.ceil(math.log2(4 * n)))
    freq = np.fft.rfftfreq(m, dt)
    lo = max(1, int(math.ceil(SLOW_CYCLES / (n * dt) * m * dt)))  # lines faster than the load path
    out_f, out_s = [], []
    blocked: list[tuple[int, int]] = []
    while len(out_f) < n_max:
        p = np.abs(np.fft.rfft(r, m)) ** 2
        p[:lo] = 0.0
        for a, b in blocked:
            p[a : b + 1] = 0.0
        j = int(np.argmax(p))
        if j <= 0 or j >= p.size - 1:
            break
        f = float(freq[j])
        if any(abs(f - g) < SIDEBAND_CYCLES / (n * dt) for g in out_f):
            # a sideband of a line already found: its envelope (a ramp, a decay), not a tone
            lo_j, hi_j = np.searchsorted(freq, [f - 0.5 / (n * dt), f + 0.5 / (n * dt)])
            blocked.append((lo_j, hi_j))
            if len(blocked) > 4 * n_max:
                break
            continue
        cols = np.stack([np.cos(2 * np.pi * f * t), np.sin(2 * np.pi * f * t), np.ones(n)], axis=1)
        beta = np.linalg.lstsq(cols, r, rcond=None)[0]
        r1 = r - cols @ beta
        share = (float(np.mean(r**2)) - float(np.mean(r1**2))) / var0
        if share < LINE_SHARE:
            break
        out_f.append(f)
        out_s.append(share)
        r = r1
    return out_f, out_s


def _harmonic_of(f: float, base: float, fs: float, tol_hz: float) -> bool:
    """f is k·base for some k = 2..8, folded about the Nyquist frequency (an alias)."""
    for k in range(2, 9):
        a = (k * base) % fs
        a = min(a, fs - a)
        if abs(a - f) < tol_hz:
            return True
    return False


def _envelope(g: np.ndarray, dt: float, f: float, parts: int = 10) -> np.ndarray:
    """Amplitude of the line at f in ``parts`` consecutive pieces of the record (demodulated)."""
    n = g.size
    t = np.arange(n) * dt
    z = (g - g.mean()) * np.exp(-2j * np.pi * f * t)
    edges = np.linspace(0, n, parts + 1).astype(int)
    return np.array([2 * abs(np.mean(z[a:b])) for a, b in zip(edges[:-1], edges[1:], strict=True)])


def _slow_share(g: np.ndarray, dt: float) -> float:
    """Share of the variance below SLOW_CYCLES cycles over the record (a load path)."""
    r = g - g.mean()
    var = float(np.sum(r**2)) or 1e-300
    c = np.fft.rfft(r)
    cut = int(math.floor(SLOW_CYCLES)) + 1
    low = float(np.sum(np.abs(c[1:cut]) ** 2) * 2 / r.size)
    return min(1.0, low / var)


def _coloured(g: np.ndarray, lines: list[float], dt: float, block: int = 16) -> float:
    """Share of the power of what the lines leave in the top tenth of its spectrum smoothed over
    ``block`` bins: ~0.1-0.15 for white noise, near 1 for a randomly excited resonance."""
    n = g.size
    t = np.arange(n) * dt
    r = g - g.mean()
    if lines:
        cols = [np.ones(n)] + [f(2 * np.pi * fr * t) for fr in lines for f in (np.cos, np.sin)]
        a = np.stack(cols, axis=1)
        r = r - a @ np.linalg.lstsq(a, r, rcond=None)[0]
    p = np.abs(np.fft.rfft(r))[1:] ** 2
    m = p.size // block
    if m < 10:
        return 0.0
    b = p[: m * block].reshape(m, block).mean(axis=1)
    top = np.sort(b)[::-1][: max(1, m // 10)]
    return float(top.sum() / max(b.sum(), 1e-300))


def binary_steps(r: np.ndarray, max_steps: int = PATH_STEPS_MAX) -> tuple[np.ndarray, list[int]]:
    """Piecewise-constant levels of r by binary segmentation: the split that most reduces the
    sum of squares, while it removes more than STEP_PENALTY · log n noise variances (σ from the
    first differences: 1.4826 MAD / √2). (levels, the cuts: index of the first sample after
    each step, increasing)."""
    n = r.size
    d = np.diff(r)
    sig = difference_sigma(r)
    if sig <= 0:  # values on a coarse lattice: the differences' RMS
        sig = float(np.std(d)) / math.sqrt(2) if d.size else 0.0
    pen = STEP_PENALTY * math.log(max(n, 2)) * max(sig, 1e-300) ** 2
    cuts = [0, n]
    while len(cuts) - 2 < max_steps:
        best = (0.0, -1)
        for a, b in zip(cuts[:-1], cuts[1:], strict=True):
            if b - a < 4:
                continue
            c = np.cumsum(r[a:b])
            m = b - a
            k = np.arange(1, m)
            left = c[:-1]
            gain = left**2 / k + (c[-1] - left) ** 2 / (m - k) - c[-1] ** 2 / m
            j = int(np.argmax(gain))
            if gain[j] > best[0]:
                best = (float(gain[j]), a + j + 1)
        if best[0] < pen:
            break
        cuts = sorted([*cuts, best[1]])
    levels = np.empty(n)
    for a, b in zip(cuts[:-1], cuts[1:], strict=True):
        levels[a:b] = r[a:b].mean()
    return levels, cuts[1:-1]


def _slow_part(r: np.ndarray) -> np.ndarray:
    """The part of r below SLOW_CYCLES cycles over the record (its mean kept)."""
    c = np.fft.rfft(r - r.mean())
    c[int(math.floor(SLOW_CYCLES)) + 1 :] = 0.0
    return np.fft.irfft(c, r.size) + r.mean()


def level_path(g: np.ndarray, dt: float, f_hz: float, iterations: int = 3) -> tuple[np.ndarray, int]:
    """The slow level path under a line at ``f_hz``: steps (`_steps`) plus the wander below
    SLOW_CYCLES, fitted alternately with the line (the line out before the steps are found, the
    steps out before the line is fitted). (path on the grid, its number of steps)."""
    n = g.size
    t = np.arange(n) * dt
    a = np.stack([np.cos(2 * np.pi * f_hz * t), np.sin(2 * np.pi * f_hz * t), np.ones(n)], axis=1)
    path = np.zeros(n)
    n_steps = 0
    for _ in range(iterations):
        beta = np.linalg.lstsq(a, g - path, rcond=None)[0]
        r = g - a[:, :2] @ beta[:2]
        levels, cuts = binary_steps(r)
        n_steps = len(cuts)
        path = levels + _slow_part(r - levels)
    return path, n_steps


def _motion_under_path(g: np.ndarray, dt: float, lines: list[float]):
    """A vibration under a dominant level path: (motion, path facts) when, with the path out,
    a line of at least FORCED_CYCLES cycles carries FORCED_SHARE of what is left; else None."""
    duration = g.size * dt
    # the strongest line of many cycles (the path's own steps make lines of a few)
    fast = [f for f in lines if f * duration >= FORCED_CYCLES]
    if not fast:
        return None
    f = fast[0]
    path, n_steps = level_path(g, dt, f)
    motion = g - path
    motion = motion - motion.mean()
    t = np.arange(g.size) * dt
    f = _peak_near(t, motion, f)  # the screening's grid refined on the motion (the nominal's hint)
    a = np.stack([np.cos(2 * np.pi * f * t), np.sin(2 * np.pi * f * t)], axis=1)
    fit = a @ np.linalg.lstsq(a, motion, rcond=None)[0]
    var = float(np.mean(motion**2)) or 1e-300
    share = 1.0 - float(np.mean((motion - fit) ** 2)) / var
    if share < FORCED_SHARE:
        return None
    total = float(np.var(g)) or 1e-300
    facts = {
        "steps": int(n_steps),
        "share": float(min(1.0, np.var(path) / total)),
        "line_hz": f,
        "line_share_after": share,
    }
    return motion, facts


def _decays(g: np.ndarray, dt: float, lines) -> tuple[float, bool]:
    """(start-to-end ratio of the strongest line's envelope, whether it is a free decay: the
    envelope falls DECAY_RATIO-fold from its start, without rising again)."""
    env = _envelope(g, dt, lines[0]) if lines else np.ones(2)
    ratio = float(env[0] / max(env[-1], 1e-300))
    first = int(np.argmax(env))
    falls = bool(np.all(np.diff(env[first:]) < 0.25 * env[first:-1] + 0.02 * env[first]))
    return ratio, bool(lines) and ratio >= DECAY_RATIO and first <= 1 and falls


def recognise(series: list[tuple[np.ndarray, np.ndarray]], dt: float) -> RecordKind:
    """The record's kind from its series ((t, y) pairs; t in s), judged on the series with the
    largest variance (the plate that moves most carries the record's kind), on its motion: a
    dominant level path under a clear line is taken out first (`_motion_under_path`)."""
    best = max(series, key=lambda s: float(np.var(s[1])))
    g = _grid(best[0], best[1], dt)
    fs = 1.0 / dt
    slow = _slow_share(g, dt)
    lines, shares = _lines(g, dt)
    rk = RecordKind("forced_harmonic", lines_hz=lines, line_shares=shares, slow_share=slow)
    duration = g.size * dt
    # a path that holds most of the variance (quasi-static) or leaves the lines a minor share
    # (its steps' spectrum reads as broadband) is taken out first when a clear line rides on it
    # (a free decay's spread lines leave them a minor share too: a decay of the record as it is
    # comes first, and nothing is taken out of it)
    decays = _decays(g, dt, lines)[1]
    path_first = not decays and (slow >= SLOW_SHARE or sum(shares) < LINES_SHARE_MIN)
    under = _motion_under_path(g, dt, lines) if path_first else None
    if under is not None:
        # judged on the motion: the path's variance is the sensor's or the set-up's, not the kind's
        g, rk.level_path = under
        lines, shares = _lines(g, dt)
        rk.lines_hz, rk.line_shares = lines, shares
    elif slow >= SLOW_SHARE:
        rk.kind = "quasi_static"
        rk.statement = (
            f"a quasi-static record: {slow:.0%} of the variance is slower than {SLOW_CYCLES:g} cycles "
            f"over the {duration:.3g}-s record (a load path, not a vibration); the load path is "
            "located, nothing defined against a loading harmonic is named"
        )
        return rk
    rk.decay_ratio, decays = _decays(g, dt, lines)
    if decays:
        rk.kind = "free_decay"
        rk.statement = (
            f"a free decay: the {lines[0]:.4g}-Hz motion falls {rk.decay_ratio:.3g}-fold over the "
            "record from its start (an impact or a release); the nominal model is damped modes"
        )
        return rk
    if (not lines or sum(shares) < LINES_SHARE_MIN) and _coloured(g, lines, dt) >= COLOURED_SHARE:
        rk.kind = "broadband"
        rk.statement = (
            f"a broadband record: its {len(lines)} strongest lines hold {sum(shares):.0%} of the "
            "variance (random excitation, no loading harmonic); nothing defined against one is named"
        )
        return rk
    if not lines:  # no line stands out and what is left is white: no motion the kinds describe
        rk.statement = "no spectral line stands out of the noise"
        return rk
    tol = 2.0 / duration
    forcing = [
        f
        for f, sh in zip(lines[1:], shares[1:], strict=True)
        if not _harmonic_of(f, lines[0], fs, tol) and sh >= TONE_SHARE
    ]
    if forcing:
        rk.kind = "multi_tone"
        rk.statement = (
            f"multi-tone forcing: {len(lines)} lines at {', '.join(f'{f:.4g}' for f in lines)} Hz "
            f"carry {sum(shares):.0%} of the variance ({len(forcing) + 1} of them strong and not "
            "harmonics of the strongest); the nominal model holds them all"
        )
        return rk
    rk.statement = (
        f"a forced harmonic record: the {lines[0]:.4g}-Hz line carries {shares[0]:.0%} of the variance"
    )
    if rk.level_path is not None:
        lp = rk.level_path
        rk.statement += (
            f" once a level path is taken out (its {lp['steps']} steps and slow wander held "
            f"{lp['share']:.0%} of the record's variance, {slow:.0%} of it slower than "
            f"{SLOW_CYCLES:g} cycles: judged on the motion, the record is a vibration, not a load path)"
        )
    return rk


# --------------------------------------------------------------------------------------------
# the nominal model of each kind


def _fit_lines(t: np.ndarray, y: np.ndarray, freqs: list[float], decays: list[float] | None = None):
    """Linear least squares of sinusoids (optionally decaying from t = 0) plus an offset at
    fixed frequencies: (fitted values, per-line complex amplitudes)."""
    cols = [np.ones_like(t)]
    for j, f in enumerate(freqs):
        e = np.exp(-decays[j] * t) if decays is not None else 1.0
        cols += [np.cos(2 * np.pi * f * t) * e, np.sin(2 * np.pi * f * t) * e]
    a = np.stack(cols, axis=1)
    beta = np.linalg.lstsq(a, y, rcond=None)[0]
    amps = [complex(beta[1 + 2 * j], -beta[2 + 2 * j]) for j in range(len(freqs))]
    return a @ beta, amps


def _model_fit(ctx: Context, i: int, n_lines: int, damped: bool):
    """`jaxdefl.fit`'s model (``--lines N``, ``--model damped``) on series i, one window over
    the record: (values at the series' times, frequencies Hz, decay rates /s, converged)."""
    import pandas as pd

    from ..fit import estimate_windows
    from ..fit.models import model_values, signal_model
    from ..series import make_windows

    s = ctx.series[i]
    df = pd.DataFrame({"segment": "0", "t": s.t, "plate": s.plate, "z": s.y})
    w = make_windows(df, axes=("z",), window_s=None)
    spec = signal_model("damped" if damped else "harmonic", 1, n_lines)
    est = estimate_windows(w, model=spec, workers=1)
    f = est.fit
    if not bool(np.asarray(f.converged)[0]):
        return None
    p = np.asarray(f.model_params)[0]
    vals = model_values(spec, p[None, :], w.t[:1], np.asarray(f.origin_s)[:1])[0]
    m = w.mask[0]
    out = np.full(s.n, np.nan)
    out[: int(m.sum())] = vals[m]
    if not np.all(np.isfinite(out)):
        return None
    om = [float(p[spec.omega_index(j)]) / (2 * np.pi) for j in range(n_lines)]
    lam = [float(p[spec.decay_index(j)]) for j in range(n_lines)] if damped else [0.0] * n_lines
    return out, om, lam


def _bic(y: np.ndarray, fitted: np.ndarray, k: int) -> float:
    n = y.size
    rss = max(float(np.sum((y - fitted) ** 2)), 1e-300)
    return n * math.log(rss / n) + k * math.log(n)


def kind_nominal(ctx: Context, states: list[State], rk: RecordKind) -> tuple[list[State], list[str]]:
    """The nominal states of the recognised kind (the thesis' harmonic for a forced harmonic
    record) and notes on what was fitted."""
    notes: list[str] = []
    if rk.kind == "forced_harmonic":
        return states, notes
    new = list(states)
    if rk.kind == "multi_tone":
        freqs = _refined_lines(ctx, states, rk)
        rk.lines_hz = freqs
        rk.forcing_change = forcing_change(ctx, freqs)
        # a located change of the lines' amplitudes is the forcing's (or the response's): the
        # nominal model holds the lines' amplitudes before and after it, so that no named effect
        # takes the change for a crack, a jump or a modulation
        tc = None if rk.forcing_change is None else rk.forcing_change["t_s"] - ctx.t0
        k = 1 + 3 * len(freqs)
        for i, s in enumerate(ctx.series):
            if tc is None:
                fitted, _ = _fit_lines(s.t, s.y, freqs)
            else:
                a = s.t < tc
                fitted = np.empty(s.n)
                fitted[a] = _fit_lines(s.t[a], s.y[a], freqs)[0]
                fitted[~a] = _fit_lines(s.t[~a], s.y[~a], freqs)[0]
                k = 3 + 5 * len(freqs)
            new[i] = states[i].with_(mean=fitted, n_params=k)
        notes.append(
            "nominal model: the forcing lines at "
            + ", ".join(f"{f:.5g}" for f in freqs)
            + " Hz (jaxdefl fit --lines), amplitudes per series"
            + ("" if tc is None else f", before and after the change at t = {rk.forcing_change['t_s']:.4g} s")
        )
        return new, notes
    if rk.kind == "free_decay":
        modes = []
        for i, s in enumerate(ctx.series):
            best = None
            for n_lines in (1, 2, 3):
                r = _model_fit(ctx, i, n_lines, damped=True)
                if r is None:
                    continue
                b = _bic(s.y, r[0], 1 + 4 * n_lines)
                if best is None or b < best[0] - 10.0:
                    best = (b, n_lines, r)
            if best is None:
                notes.append(f"plate {s.plate} {s.axis}: the damped model did not converge; harmonic kept")
                continue
            _, n_lines, (vals, om, lam) = best
            new[i] = states[i].with_(mean=vals, n_params=1 + 4 * n_lines)
            for f, la in zip(om, lam, strict=True):
                wn = math.hypot(2 * math.pi * f, la)
                _, amps = _fit_lines(s.t, s.y, [f], [la])
                modes.append(
                    {
                        "plate": s.plate,
                        "axis": s.axis,
                        "freq_hz": f,
                        "decay_per_s": la,
                        "damping_ratio": la / wn if wn > 0 else None,
                        "amplitude_at_start": abs(amps[0]),
                    }
                )
        rk.modes = sorted(modes, key=lambda m: -m["amplitude_at_start"])
        notes.append(
            "nominal model: damped modes (jaxdefl fit --model damped --lines N, N by BIC) at "
            + ", ".join(f"{m['freq_hz']:.4g} Hz (ζ {m['damping_ratio']:.3g})" for m in rk.modes)
        )
        return new, notes
    # broadband, quasi-static: the motion itself (a smooth of the record) is the nominal mean
    for i, s in enumerate(ctx.series):
        new[i] = states[i].with_(mean=load_path(s.t, s.y), n_params=states[i].n_params)
    if rk.kind == "quasi_static":
        rk.modes = []
        steps = located_steps(ctx)
        rk.forcing_change = {"load_steps": steps}
        notes.append(
            f"nominal model: the load path (a running median of the record); {len(steps)} steps of it located"
        )
    return new, notes


def _refined_lines(ctx: Context, states: list[State], rk: RecordKind) -> list[float]:
    """The forcing lines' frequencies refined by `jaxdefl.fit` (``--lines N``) on the series
    that moves most; the screening's frequencies where that fit fails."""
    i = int(np.argmax([float(np.var(s.y)) for s in ctx.series]))
    r = _model_fit(ctx, i, len(rk.lines_hz), damped=False)
    if r is None:
        return list(rk.lines_hz)
    om = r[1]
    # keep the fit's frequency only where it stayed near the screened line
    out = []
    for f in rk.lines_hz:
        j = int(np.argmin([abs(g - f) for g in om]))
        out.append(om[j] if abs(om[j] - f) < 2.0 / max(ctx.duration_s, 1e-9) else f)
    return out


def load_path(t: np.ndarray, y: np.ndarray, width: int = 15) -> np.ndarray:
    """A running median of the record (odd ``width`` samples): the load path of a slowly loaded
    or randomly excited record, steps kept sharp."""
    from scipy.ndimage import median_filter

    return median_filter(np.asarray(y, float), size=min(width, max(3, (y.size // 2) * 2 - 1)), mode="nearest")


def located_steps(ctx: Context, max_steps: int = 40) -> list[dict]:
    """Steps of the load path (binary segmentation of the running median's levels): time and
    size of each step larger than 5 σ of the noise, on the series that moves most."""
    i = int(np.argmax([float(np.var(s.y)) for s in ctx.series]))
    s = ctx.series[i]
    lp = load_path(s.t, s.y)
    sig = max(float(np.std(s.y - lp)), 1e-300)
    d = np.diff(lp)
    out = []
    j = 0
    while j < d.size and len(out) < max_steps:
        if abs(d[j]) > 0:
            k = j
            # one movement: same-sign changes with pauses of at most two samples between them
            while True:
                nxt = [m for m in range(k + 1, min(k + 4, d.size)) if np.sign(d[m]) == np.sign(d[j])]
                if not nxt or any(np.sign(d[m]) == -np.sign(d[j]) for m in range(k + 1, nxt[0])):
                    break
                k = nxt[0]
            size = float(lp[k + 1] - lp[j])
            if abs(size) > 5 * sig:
                out.append(
                    {"t_start": float(ctx.t0 + s.t[j]), "t_end": float(ctx.t0 + s.t[k + 1]), "size": size}
                )
            j = k + 1
        else:
            j += 1
    return out


def forcing_change(ctx: Context, freqs: list[float]) -> dict | None:
    """A change of the forcing lines' amplitudes, located and told from a change of the
    structure where the record allows.

    The record is split at the time that best separates two sets of line amplitudes (every
    tenth of the record from 0.2 to 0.8 tried; the amplitudes fitted per part). A forcing step
    moves every line by one factor with its frequency and phase kept; a stiffness change of a
    forced response moves each line's amplitude and phase by its own factor (the frequency
    response moves under the lines), and of a free response the frequencies. Returned: the split
    time, each line's amplitude ratio and phase change and frequency in each part, and the
    verdict."""
    i = int(np.argmax([float(np.var(s.y)) for s in ctx.series]))
    s = ctx.series[i]
    t, y = s.t, s.y
    base, _ = _fit_lines(t, y, freqs)
    rss0 = float(np.sum((y - base) ** 2))
    best = None
    for frac in np.linspace(0.2, 0.8, 25):
        tc = t[0] + frac * (t[-1] - t[0])
        a, b = t < tc, t >= tc
        fa, amp_a = _fit_lines(t[a], y[a], freqs)
        fb, amp_b = _fit_lines(t[b], y[b], freqs)
        rss = float(np.sum((y[a] - fa) ** 2) + np.sum((y[b] - fb) ** 2))
        if best is None or rss < best[0]:
            best = (rss, tc, amp_a, amp_b)
    rss, tc, amp_a, amp_b = best
    n = y.size
    k_extra = 1 + 2 * len(freqs)
    lr = n * math.log(max(rss0, 1e-300) / max(rss, 1e-300))
    if lr < k_extra * math.log(n) + 10.0:  # BIC: no change worth its parameters
        return None
    ratios = [abs(b) / max(abs(a), 1e-300) for a, b in zip(amp_a, amp_b, strict=True)]
    dphase = [float(np.angle(b / a)) if abs(a) > 0 else 0.0 for a, b in zip(amp_a, amp_b, strict=True)]
    # the lines' own frequencies before and after (a stiffness change of a free response moves them)
    pre = [_peak_near(t[t < tc], y[t < tc], f) for f in freqs]
    post = [_peak_near(t[t >= tc], y[t >= tc], f) for f in freqs]
    strong = [j for j, a in enumerate(amp_a) if abs(a) > 0.1 * max(abs(x) for x in amp_a)]
    r_strong = np.array([ratios[j] for j in strong])
    spread = float(np.std(np.log(r_strong))) if r_strong.size > 1 else math.nan
    dph = max(abs(dphase[j]) for j in strong) if strong else 0.0
    freq_kept = all(abs(b - a) < 2.0 / max(t[-1] - t[0], 1e-9) for a, b in zip(pre, post, strict=True))
    if freq_kept and r_strong.size > 1 and spread < 0.1:
        verdict = (
            "a change of the forcing: every strong line's amplitude moved by about the same factor "
            f"({np.exp(np.mean(np.log(r_strong))):.3g}) with its frequency kept"
        )
        cause = "forcing"
        if dph > 0.3:
            verdict += "; the lines' phases moved too, which a pure forcing step would not do"
            cause = "cannot_tell"
    elif freq_kept:
        verdict = (
            "the lines' amplitudes changed by different factors with their frequencies kept: a change "
            "of the forcing's spectrum or of the structure's response under it; the record cannot "
            "tell the two apart without the force"
        )
        cause = "cannot_tell"
    else:
        verdict = "the lines' frequencies moved: the structure changed, not only the forcing"
        cause = "structure"
    return {
        "t_s": float(ctx.t0 + tc),
        "lines_hz": freqs,
        "amplitude_ratio": ratios,
        "phase_change_rad": dphase,
        "freq_before_hz": pre,
        "freq_after_hz": post,
        "ratio_spread_log": spread,
        "cause": cause,
        "verdict": verdict,
        "series": s.key,
    }


def _peak_near(t: np.ndarray, y: np.ndarray, f: float) -> float:
    """The periodogram's peak within ±2/T of f (zero-padded FFT, parabolic interpolation)."""
    if t.size < 16:
        return f
    dt = float(np.median(np.diff(t)))
    g = _grid(t, y, dt)
    g = g - g.mean()
    m = 1 << int(math.ceil(math.log2(8 * g.size)))
    p = np.abs(np.fft.rfft(g, m)) ** 2
    freq = np.fft.rfftfreq(m, dt)
    span = 2.0 / (g.size * dt)
    sel = np.flatnonzero(np.abs(freq - f) <= span)
    if sel.size < 3:
        return f
    j = sel[int(np.argmax(p[sel]))]
    if 0 < j < p.size - 1:
        a, b, c = np.log(p[j - 1 : j + 2] + 1e-300)
        den = a - 2 * b + c
        off = 0.5 * (a - c) / den if den < 0 else 0.0
        return float(freq[j] + off * (freq[1] - freq[0]))
    return float(freq[j])
