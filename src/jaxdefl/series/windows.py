"""Cut trajectory tables into padded, masked windows: shape ``(window, sample)``.

Every row of the batch is one (segment, plate, axis, window). Times are stored relative to the
window's mid time ``t_mid = (t_start + t_end) / 2`` (computed in float64 from the window bounds,
not from the data), so epoch timestamps lose nothing and the fit is well conditioned.
Samples on a regular frame clock also get their integer frame index ``k`` (relative to the first
sample of the window), which lets the periodogram use an exact FFT on the masked grid.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from .._errors import ConfigError

__all__ = [
    "Windows",
    "make_windows",
    "windows_like",
    "frame_clock",
    "check_window_plan",
    "STATUS_OK",
    "STATUS_FEW_SAMPLES",
]

STATUS_OK = "converged"
STATUS_FEW_SAMPLES = "too_few_samples"

# A window is on the frame clock when every timestamp is within this fraction of a frame
# interval of t_first + k * dt: then the masked-grid FFT periodogram is exact to that level.
CLOCK_TOLERANCE = 1e-5
MAX_GRID_FILL = 64


@dataclass(frozen=True)
class Windows:
    """A batch of windows, padded to a common number of samples.

    Attributes:
        t: (window, sample) time relative to ``table.t_centre`` (the mid-time of the window's
            own samples, which conditions the fit best) in s; 0 where masked.
        y: (window, sample) values in mm; 0 where masked.
        mask: (window, sample) True where a sample is valid.
        k: (window, sample) frame index relative to the window's first sample; 0 where masked.
        dt: (window,) frame interval in s (median spacing, refined by least squares).
        on_clock: (window,) True when all samples sit on the frame clock (see CLOCK_TOLERANCE).
        table: one row per window: segment, window, t_start, t_end, t_mid (middle of the bounds,
            the reference of reported phases), t_centre, plate, axis, n, status.
    """

    t: np.ndarray
    y: np.ndarray
    mask: np.ndarray
    k: np.ndarray
    dt: np.ndarray
    on_clock: np.ndarray
    table: pd.DataFrame

    def __len__(self) -> int:
        return len(self.table)

    def select(self, rows: np.ndarray) -> Windows:
        """The windows at ``rows`` (integer indices or a boolean mask), as a new batch."""
        rows = np.asarray(rows)
        if rows.dtype == bool:
            rows = np.flatnonzero(rows)
        return Windows(
            self.t[rows],
            self.y[rows],
            self.mask[rows],
            self.k[rows],
            self.dt[rows],
            self.on_clock[rows],
            self.table.iloc[rows].reset_index(drop=True),
        )


def frame_clock(t_rel: np.ndarray) -> tuple[float, np.ndarray, bool]:
    """Frame interval, integer frame indices and on-clock flag for sorted times ``t_rel`` (s).

    The interval starts as the smallest spacing (drop-outs only make gaps of whole frames, and
    with most frames lost even the median spacing spans several frames) and is refined by least
    squares of t on k, so long windows do not accumulate error. A grid with more than
    ``MAX_GRID_FILL`` frames per sample is not treated as a frame clock (the FFT grid would be
    mostly empty; such times take the non-uniform path).
    """
    n = t_rel.size
    if n < 2:
        return np.nan, np.zeros(n, np.int64), False
    d = np.diff(t_rel)
    pos = d[d > 0]
    if pos.size == 0:
        return np.nan, np.zeros(n, np.int64), False
    dt = float(pos.min())
    rel = t_rel - t_rel[0]
    k = np.rint(rel / dt)
    for _ in range(2):
        kk = float(k @ k)
        if kk > 0:
            dt = float(k @ rel) / kk
        k = np.rint(rel / dt)
    on = (
        bool(np.max(np.abs(rel - k * dt)) <= CLOCK_TOLERANCE * dt)
        and bool(np.all(np.diff(k) > 0))
        and k[-1] + 1 <= MAX_GRID_FILL * n
    )
    return dt, k.astype(np.int64), on


def _bounds(t_seg: np.ndarray, window_s: float | None, step_s: float | None) -> list[tuple[float, float]]:
    t0, t1 = float(t_seg.min()), float(t_seg.max())
    if window_s is None:
        return [(t0, t1)]
    d = np.diff(np.unique(t_seg))
    dt = float(np.median(d)) if d.size else 0.0
    span = t1 - t0 + dt
    n = max(1, int(np.floor((span - window_s) / step_s + 1 + 1e-9)))
    return [(t0 + i * step_s, t0 + i * step_s + window_s) for i in range(n)]


def _pack(series: list[tuple], min_samples: int) -> Windows:
    """Pad (meta, t_abs, y[, (dt, k, on_clock)]) tuples into a Windows batch.

    The optional clock triple comes from a clock fitted to the whole series; without it (or
    when it is off the clock) the window's own clock is fitted.
    """
    n_max = max((len(item[1]) for item in series), default=1)
    s = max(n_max, 1)
    b = len(series)
    T = np.zeros((b, s))
    Y = np.zeros((b, s))
    M = np.zeros((b, s), bool)
    K = np.zeros((b, s), np.int64)
    dt = np.full(b, np.nan)
    on = np.zeros(b, bool)
    rows = []
    centre = np.zeros(b)
    for i, (meta, t_abs, y, *clock) in enumerate(series):
        n = t_abs.size
        centre[i] = 0.5 * (t_abs[0] + t_abs[-1]) if n else meta["t_mid"]
        T[i, :n] = t_abs - centre[i]
        Y[i, :n] = y
        M[i, :n] = True
        if clock and clock[0][2] and n:
            dt[i], K[i, :n], on[i] = clock[0][0], clock[0][1] - clock[0][1][0], True
        elif n:
            dt[i], K[i, :n], on[i] = frame_clock(t_abs - t_abs[0])
        rows.append({**meta, "n": n, "status": STATUS_OK if n >= min_samples else STATUS_FEW_SAMPLES})
    cols = ["segment", "window", "t_start", "t_end", "t_mid", "plate", "axis", "n", "status"]
    table = pd.DataFrame(rows, columns=cols)
    table.insert(5, "t_centre", centre)
    return Windows(T, Y, M, K, dt, on, table)


def make_windows(
    df: pd.DataFrame,
    axes: tuple[str, ...] = ("z", "x", "y"),
    window_s: float | None = None,
    step_s: float | None = None,
    min_samples: int = 16,
) -> Windows:
    """Cut a validated trajectory table into windows for every segment, plate and axis.

    Windows start at the first timestamp of their segment (shared by all plates, so windows line
    up across plates) and advance by ``step_s``; only windows that fit inside the segment are
    made (at least one per segment). Without ``window_s`` each segment is one window.

    Args:
        df: canonical table from `jaxdefl.io.validate_trajectory`.
        axes: the axes to window; an axis absent from the table is an error.
        window_s: window length in s, or None for one window per segment.
        step_s: window step in s (default: ``window_s``).
        min_samples: windows with fewer valid samples get status ``too_few_samples``.

    Raises:
        ConfigError: a non-positive window or step, or an axis missing from the table.
    """
    if window_s is not None and not window_s > 0:
        raise ConfigError(f"--window: expected a positive length in s, got {window_s}")
    if step_s is not None and window_s is None:
        raise ConfigError("--step: needs --window")
    if window_s is not None:
        step_s = window_s if step_s is None else step_s
        if not step_s > 0:
            raise ConfigError(f"--step: expected a positive length in s, got {step_s}")
    missing = [a for a in axes if a not in df.columns]
    if missing:
        raise ConfigError(
            f"--axes: the table has no column {', '.join(missing)} (it has {', '.join(df.columns)})"
        )
    series = []
    for seg, g in df.groupby("segment", sort=False):
        bounds = _bounds(g["t"].to_numpy(), window_s, step_s)
        for plate, gp in g.groupby("plate", sort=True):
            t_all = gp["t"].to_numpy()
            # One clock for the whole series (all axes share the timestamps); a window where
            # it does not hold to CLOCK_TOLERANCE gets its own clock fitted in `_pack`.
            dt_all, k_all, _ = frame_clock(t_all - t_all[0])
            resid_ok = np.abs(t_all - t_all[0] - k_all * dt_all) <= CLOCK_TOLERANCE * dt_all
            for axis in axes:
                v = gp[axis].to_numpy()
                ok = np.isfinite(v)
                for w, (a, b) in enumerate(bounds):
                    if window_s is None:
                        lo, hi = 0, t_all.size
                    else:
                        lo, hi = np.searchsorted(t_all, [a, b], side="left")
                    sel = ok[lo:hi]
                    meta = dict(
                        segment=seg,
                        window=w,
                        t_start=a,
                        t_end=b,
                        t_mid=0.5 * (a + b),
                        plate=int(plate),
                        axis=axis,
                    )
                    clock = (dt_all, k_all[lo:hi][sel], bool(resid_ok[lo:hi][sel].all()))
                    series.append((meta, t_all[lo:hi][sel], v[lo:hi][sel], clock))
    return _pack(series, min_samples)


def windows_like(ref: pd.DataFrame, like: pd.DataFrame, min_samples: int = 16) -> Windows:
    """Windows of a reference table (t, plate, z) with the bounds of the z rows of ``like``.

    ``like`` is a windows table (e.g. `Windows.table` of the camera); each z row with a plate the
    reference has becomes one reference window over the same [t_start, t_end) (whole-segment
    windows include t_end). The reference's own segment labels are ignored: time decides.
    """
    series = []
    by_plate = {int(p): g for p, g in ref.groupby("plate")}
    whole = like["window"].max() == 0
    for _, row in like[like["axis"] == "z"].iterrows():
        g = by_plate.get(int(row["plate"]))
        if g is None:
            continue
        t_all = g["t"].to_numpy()
        v = g["z"].to_numpy()
        side = "right" if whole else "left"
        lo = np.searchsorted(t_all, row["t_start"], side="left")
        hi = np.searchsorted(t_all, row["t_end"], side=side)
        ok = np.isfinite(v[lo:hi])
        meta = {c: row[c] for c in ("segment", "window", "t_start", "t_end", "t_mid", "plate", "axis")}
        series.append((meta, t_all[lo:hi][ok], v[lo:hi][ok]))
    if not series:
        raise ConfigError("--reference: no plate of the reference table is in the trajectory table")
    return _pack(series, min_samples)


# Windows shorter than this many frame intervals hold too few samples for a harmonic (4
# parameters) and, cut from a long table, come in numbers that exhaust memory.
MIN_WINDOW_FRAMES = 8
# The padded batch (t, y, mask, k: 8 bytes each, plus the periodogram's and the fit's working
# copies) must fit in this budget; past it the window settings are refused before any work.
MAX_BATCH_BYTES = 4 << 30


def check_window_plan(
    df: pd.DataFrame,
    axes: tuple[str, ...],
    window_s: float | None,
    step_s: float | None,
    source: str = "the table",
) -> None:
    """Refuse window settings that cannot give a fit or would not fit in memory, before any work.

    Raises:
        ConfigError: a window shorter than MIN_WINDOW_FRAMES frame intervals (median spacing of
            the table's timestamps), or a padded batch larger than MAX_BATCH_BYTES.
    """
    if window_s is None:
        return
    step_s = window_s if step_s is None else step_s
    t = df["t"].to_numpy()
    same = (df["plate"].to_numpy()[1:] == df["plate"].to_numpy()[:-1]) & (
        df["segment"].to_numpy()[1:] == df["segment"].to_numpy()[:-1]
    )
    d = np.diff(t)[same]
    d = d[d > 0]
    if not d.size:
        return
    dt = float(np.median(d))
    if window_s < MIN_WINDOW_FRAMES * dt:
        raise ConfigError(
            f"--window {window_s:g}: shorter than {MIN_WINDOW_FRAMES} frame intervals of {source} "
            f"(median spacing {dt:.6g} s); expected at least {MIN_WINDOW_FRAMES * dt:.6g} s"
        )
    n_series = df.groupby(["segment", "plate"], sort=False).ngroups * max(1, len(axes))
    span = float(df.groupby("segment", sort=False)["t"].agg(lambda s: s.max() - s.min()).max())
    n_windows = max(1.0, np.floor((span + dt - window_s) / step_s + 1))
    samples = min(window_s, span + dt) / dt + 1
    need = 8 * 8 * n_series * n_windows * samples
    if need > MAX_BATCH_BYTES:
        raise ConfigError(
            f"--window {window_s:g} --step {step_s:g}: {int(n_series * n_windows):,} windows of "
            f"~{int(samples):,} samples from {source} would need ~{need / 2**30:.0f} GiB; "
            f"expected at most {MAX_BATCH_BYTES / 2**30:.0f} GiB (use a longer --step)"
        )
