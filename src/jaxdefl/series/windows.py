"""Cut trajectory tables into padded, masked windows: shape ``(window, sample)``.

Every row of the batch is one (segment, plate, axis, window). Times are stored relative to the
window's mid time ``t_mid = (t_start + t_end) / 2`` (computed in float64 from the window bounds,
not from the data), so epoch timestamps lose nothing and the fit is well conditioned.
Samples on a frame clock also get their integer frame index ``k`` (relative to the first sample
of the window), which lets the periodogram use an FFT on the masked grid: exact for an exact
clock, on the stamps snapped to the recovered clock when they jitter by a fraction of a frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from .._errors import ConfigError
from .._resources import MEMORY_BUDGET_BYTES
from ..status import Status
from .clock import SNAP_MAX, fit_clock

__all__ = [
    "Windows",
    "make_windows",
    "windows_like",
    "frame_clock",
    "check_window_plan",
]

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
        dt: (window,) frame interval in s (the recovered clock, `jaxdefl.series.clock`).
        on_clock: (window,) True when the samples sit on the frame clock to SNAP_MAX of a frame
            (RMS): the periodogram uses the frame grid (see `frame_clock`).
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


def frame_clock(t_rel: np.ndarray, hint: float | None = None) -> tuple[float, np.ndarray, bool]:
    """Frame interval, integer frame indices and on-clock flag for sorted times ``t_rel`` (s).

    The clock is recovered by `jaxdefl.series.clock.fit_clock` (a robust line t = t0 + k dt
    whose integer indices resolve drop-outs, repeats and jitter; never the smallest spacing,
    which jitter shrinks). The times are on the clock when they scatter about it by at most
    ``SNAP_MAX`` of a frame (RMS): the periodogram then uses the frame grid (exact for an
    exact clock, the stamps snapped to the nearest frame otherwise; the fit always uses the
    stamps). A grid with more than ``MAX_GRID_FILL`` frames per sample is not a frame clock (the
    FFT grid would be mostly empty; such times take the non-uniform path). ``hint`` is a
    nominal interval (1 / frame rate) to start the clock fit from.
    """
    n = t_rel.size
    c = fit_clock(t_rel, hint)
    if not np.isfinite(c.dt):
        return np.nan, np.zeros(n, np.int64), False
    on = c.jitter_frames <= SNAP_MAX and c.k[-1] + 1 <= MAX_GRID_FILL * n
    return c.dt, c.k, bool(on)


def _bounds(t_seg: np.ndarray, window_s: float | None, step_s: float | None) -> list[tuple[float, float]]:
    t0, t1 = float(t_seg.min()), float(t_seg.max())
    if window_s is None:
        return [(t0, t1)]
    # the spacings of the distinct stamps: each plate's run is sorted, so a merge sort is fast
    d = np.diff(np.sort(t_seg, kind="stable"))
    d = d[d > 0]
    dt = float(np.median(d)) if d.size else 0.0
    span = t1 - t0 + dt
    if window_s > span * (1 + 1e-9):  # a window longer than the record is clipped to it
        return [(t0, t0 + span)]
    n = max(1, int(np.floor((span - window_s) / step_s + 1 + 1e-9)))
    return [(t0 + i * step_s, t0 + i * step_s + window_s) for i in range(n)]


@dataclass
class _Block:
    """Windows cut from one series (one segment, plate and axis): index matrices, no copies.

    ``pos`` (window, sample) are positions into ``t``/``y`` of each window's valid samples
    (valid ones first, ``valid`` marks them); ``clock_dt``/``clock_k``/``clock_on`` are the
    series clock as each window sees it (`_window_clocks`), or None to fit each window's own.
    """

    meta: dict
    t: np.ndarray
    y: np.ndarray
    pos: np.ndarray
    valid: np.ndarray
    clock_dt: np.ndarray | None = None
    clock_k: np.ndarray | None = None
    clock_on: np.ndarray | None = None


def _positions(lo: np.ndarray, hi: np.ndarray, ok: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Positions of the ``ok`` samples within [lo, hi) of each window, valid ones first:
    (window, sample) positions (0 where padded) and their mask."""
    idx = np.flatnonzero(ok)
    before = np.concatenate([[0], np.cumsum(ok)])  # valid samples before each position
    first, n = before[lo], before[hi] - before[lo]
    s = max(int(n.max(initial=0)), 1)
    j = np.arange(s)[None, :]
    valid = j < n[:, None]
    pos = idx[np.minimum(first[:, None] + j, max(idx.size - 1, 0))] if idx.size else np.zeros_like(valid, int)
    return np.where(valid, pos, 0), valid


def _pack(blocks: list[_Block], min_samples: int) -> Windows:
    """Pad the windows of ``blocks`` into a Windows batch.

    A window takes its block's clock when that is on the frame clock and the grid is at most
    MAX_GRID_FILL frames per sample; otherwise (or without a clock) its own clock is fitted
    (`frame_clock`).
    """
    sizes = [b.pos.shape[0] for b in blocks]
    b_all = sum(sizes)
    s = max((int(b.valid.sum(axis=1).max(initial=0)) for b in blocks), default=1) or 1
    T = np.zeros((b_all, s))
    Y = np.zeros((b_all, s))
    M = np.zeros((b_all, s), bool)
    K = np.zeros((b_all, s), np.int64)
    dt = np.full(b_all, np.nan)
    on = np.zeros(b_all, bool)
    centre = np.zeros(b_all)
    n_all = np.zeros(b_all, np.int64)
    r0 = 0
    for blk, size in zip(blocks, sizes, strict=True):
        rows = slice(r0, r0 + size)
        r0 += size
        w = min(blk.pos.shape[1], s)
        pos, valid = blk.pos[:, :w], blk.valid[:, :w]
        n = valid.sum(axis=1)
        last = pos[np.arange(size), np.maximum(n - 1, 0)]
        t_abs = blk.t[pos]
        c = np.where(n > 0, 0.5 * (blk.t[pos[:, 0]] + blk.t[last]), blk.meta["t_mid"])
        T[rows, :w] = np.where(valid, t_abs - c[:, None], 0.0)
        Y[rows, :w] = np.where(valid, blk.y[pos], 0.0)
        M[rows, :w] = valid
        centre[rows], n_all[rows] = c, n
        if blk.clock_on is not None:
            k = blk.clock_k[:, :w]
            fill = k[np.arange(size), np.maximum(n - 1, 0)] - k[:, 0] + 1 <= MAX_GRID_FILL * n
            take = blk.clock_on & (n > 0) & fill
            K[rows, :w] = np.where(valid & take[:, None], k - k[:, :1], 0)
            dt[rows] = np.where(take, blk.clock_dt, np.nan)
            on[rows] = take
        # A window off its series clock (or without one) fits its own.
        for i in np.flatnonzero(~on[rows] & (n > 0)):
            r = rows.start + i
            tw = t_abs[i, : n[i]]
            dt[r], K[r, : n[i]], on[r] = frame_clock(tw - tw[0])
    meta = {
        k: np.concatenate([np.broadcast_to(b.meta[k], sz) for b, sz in zip(blocks, sizes, strict=True)])
        if blocks
        else np.zeros(0)
        for k in ("segment", "window", "t_start", "t_end", "t_mid", "plate", "axis")
    }
    status = np.where(n_all >= min_samples, Status.CONVERGED, Status.TOO_FEW_SAMPLES).astype(object)
    table = pd.DataFrame(
        {
            "segment": meta["segment"].tolist(),
            "window": meta["window"].astype(np.int64),
            "t_start": meta["t_start"].astype(np.float64),
            "t_end": meta["t_end"].astype(np.float64),
            "t_mid": meta["t_mid"].astype(np.float64),
            "t_centre": centre,
            "plate": meta["plate"].astype(np.int64),
            "axis": meta["axis"].tolist(),
            "n": n_all,
            "status": [Status(x) for x in status],
        }
    )
    return Windows(T, Y, M, K, dt, on, table)


# A window whose stamps lie on a line in k to this fraction of a frame is on an exact clock.
EXACT = 1e-5


def _window_clocks(dt: float, k: np.ndarray, r: np.ndarray, valid: np.ndarray):
    """The series clock as seen by each window: (interval, indices, on the grid), (window,) each.

    ``k`` and ``r`` (window, sample) are the windows' frame indices and residuals about the
    series clock (``valid`` marks the samples). A line through the residuals (a logger restart
    shifts the clock, a rate change tilts it) makes an exact clock of the window's own when what
    is left is below EXACT of a frame; else the window is snapped to the series clock when its
    stamps scatter by at most SNAP_MAX of a frame, and fits its own clock otherwise."""
    n = valid.sum(axis=1)
    size = np.maximum(n, 1)
    kf = np.where(valid, k, 0).astype(np.float64)
    rv = np.where(valid, r, 0.0)
    kc = np.where(valid, kf - kf.sum(axis=1, keepdims=True) / size[:, None], 0.0)
    den = np.einsum("ij,ij->i", kc, kc)
    with np.errstate(invalid="ignore", divide="ignore"):
        slope = np.where(den > 0, np.einsum("ij,ij->i", kc, rv) / np.where(den > 0, den, 1.0), 0.0)
    rc = np.where(valid, rv - rv.sum(axis=1, keepdims=True) / size[:, None], 0.0)
    left = np.abs(np.where(valid, rc - slope[:, None] * kc, 0.0)).max(axis=1, initial=0.0)
    std = np.sqrt(np.einsum("ij,ij->i", rc, rc) / size)
    usable = (n >= 2) & bool(np.isfinite(dt))
    exact = usable & (left <= EXACT * dt)
    dt_w = np.where(exact, dt + slope, dt)
    return dt_w, np.where(valid, k, 0), usable & (exact | (std <= SNAP_MAX * dt))


def _series_rows(df: pd.DataFrame):
    """Row numbers of every segment (in order of appearance) and, within it, of every plate
    (in increasing order), each in table order: ``df.groupby("segment", sort=False)`` then
    ``groupby("plate")`` as (segment, rows, [(plate, rows), ...]), without a frame per group."""
    codes, segments = pd.factorize(df["segment"], sort=False)  # missing: -1, left out
    plate = df["plate"].to_numpy()
    for i, seg in enumerate(segments):
        rows = np.flatnonzero(codes == i)
        p = plate[rows]
        keep = ~pd.isna(p)
        rows, p = rows[keep], p[keep]
        order = np.argsort(p, kind="stable")
        values, starts = np.unique(p[order], return_index=True)
        parts = np.split(rows[order], starts[1:])
        yield seg, rows, list(zip(values.tolist(), parts, strict=True))


def make_windows(
    df: pd.DataFrame,
    axes: tuple[str, ...] = ("z", "x", "y"),
    window_s: float | None = None,
    step_s: float | None = None,
    min_samples: int = 16,
    clocks: dict | None = None,
) -> Windows:
    """Cut a validated trajectory table into windows for every segment, plate and axis.

    Windows start at the first timestamp of their segment (shared by all plates, so windows line
    up across plates) and advance by ``step_s``; only windows that fit inside the segment are
    made (at least one per segment). A window longer than its segment is clipped to the segment
    (`check_window_plan` says so). Without ``window_s`` each segment is one window.

    Args:
        df: canonical table from `jaxdefl.io.validate_trajectory`.
        axes: the axes to window; an axis absent from the table is an error.
        window_s: window length in s, or None for one window per segment.
        step_s: window step in s (default: ``window_s``).
        min_samples: windows with fewer valid samples get status ``too_few_samples``.
        clocks: a dict shared by calls on the same table (say the whole record and its
            windows): each series' frame clock is fitted once and kept there.

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
    blocks = []
    last = (None, None)  # plates of a frame share their stamps: one clock fit for them all
    columns = {c: df[c].to_numpy() for c in ("t", *axes)}
    for seg, seg_rows, plates in _series_rows(df):
        bounds = np.array(_bounds(columns["t"][seg_rows], window_s, step_s))
        a, b = bounds[:, 0], bounds[:, 1]
        for plate, rows in plates:
            t_all = columns["t"][rows]
            # One clock for the whole series (all axes share the timestamps). A window takes
            # it when its stamps scatter about it (a constant offset aside: a logger restart
            # keeps its own exact grid) by at most SNAP_MAX of a frame; else its own clock is
            # fitted in `_pack`.
            known = None if clocks is None else clocks.get((seg, int(plate)))
            if known is not None and np.array_equal(known[0], t_all):
                clk = known[1]
            elif last[0] is not None and np.array_equal(last[0], t_all):
                clk = last[1]
            else:
                clk = fit_clock(t_all - t_all[0])
            last = (t_all, clk)
            if clocks is not None:
                clocks[(seg, int(plate))] = last
            resid = t_all - t_all[0] - clk.t if np.isfinite(clk.dt) else np.full(t_all.size, np.nan)
            if window_s is None:
                lo, hi = np.zeros(1, np.int64), np.full(1, t_all.size)
            else:
                lo, hi = np.searchsorted(t_all, a, side="left"), np.searchsorted(t_all, b, side="left")
            meta = dict(
                segment=seg,
                window=np.arange(a.size),
                t_start=a,
                t_end=b,
                t_mid=0.5 * (a + b),
                plate=int(plate),
            )
            shared = None  # the windows' clocks where no value is missing, shared by the axes
            for axis in axes:
                v = columns[axis][rows]
                ok = np.isfinite(v)
                pos, valid = _positions(lo, hi, ok)
                if ok.all() and shared is not None:
                    clock = shared
                else:
                    clock = _window_clocks(clk.dt, clk.k[pos], resid[pos], valid)
                    shared = clock if ok.all() else shared
                blocks.append(_Block({**meta, "axis": axis}, t_all, v, pos, valid, *clock))
    return _pack(blocks, min_samples)


def windows_like(ref: pd.DataFrame, like: pd.DataFrame, min_samples: int = 16) -> Windows:
    """Windows of a reference table (t, plate, z) with the bounds of the z rows of ``like``.

    ``like`` is a windows table (e.g. `Windows.table` of the camera); each z row with a plate the
    reference has becomes one reference window over the same [t_start, t_end) (whole-segment
    windows include t_end). The reference's own segment labels are ignored: time decides.
    """
    blocks = []
    by_plate = {int(p): g for p, g in ref.groupby("plate")}
    whole = like["window"].max() == 0
    z = like[like["axis"] == "z"]
    # one block per run of rows of the same plate, in the order of ``like``
    plates = z["plate"].to_numpy().astype(np.int64)
    starts = np.flatnonzero(np.concatenate([[True], plates[1:] != plates[:-1]]))
    for r0, r1 in zip(starts, np.append(starts[1:], plates.size), strict=True):
        g = by_plate.get(int(plates[r0]))
        if g is None:
            continue
        rows = z.iloc[r0:r1]
        t_all = g["t"].to_numpy()
        v = g["z"].to_numpy()
        lo = np.searchsorted(t_all, rows["t_start"].to_numpy(), side="left")
        hi = np.searchsorted(t_all, rows["t_end"].to_numpy(), side="right" if whole else "left")
        pos, valid = _positions(lo, hi, np.isfinite(v))
        meta = {
            c: rows[c].to_numpy() for c in ("segment", "window", "t_start", "t_end", "t_mid", "plate", "axis")
        }
        blocks.append(_Block(meta, t_all, v, pos, valid))
    if not blocks:
        raise ConfigError("--reference: no plate of the reference table is in the trajectory table")
    return _pack(blocks, min_samples)


# Windows shorter than this many frame intervals hold too few samples for a harmonic (4
# parameters) and, cut from a long table, come in numbers that exhaust memory.
MIN_WINDOW_FRAMES = 8
# The padded batch (t, y, mask, k: 8 bytes each, plus the periodogram's and the fit's working
# copies) must fit in this budget; past it the window settings are refused before any work.
MAX_BATCH_BYTES = MEMORY_BUDGET_BYTES


def check_window_plan(
    df: pd.DataFrame,
    axes: tuple[str, ...],
    window_s: float | None,
    step_s: float | None,
    source: str = "the table",
) -> str | None:
    """Refuse window settings that cannot give a fit or would not fit in memory, before any work.

    Returns:
        A note for the user when the window is longer than a segment (that segment's window is
        clipped to it, see `make_windows`), else None.

    Raises:
        ConfigError: a window shorter than MIN_WINDOW_FRAMES frame intervals (median spacing of
            the table's timestamps), or a padded batch larger than MAX_BATCH_BYTES.
    """
    if window_s is None:
        return None
    step_s = window_s if step_s is None else step_s
    t = df["t"].to_numpy()
    same = (df["plate"].to_numpy()[1:] == df["plate"].to_numpy()[:-1]) & (
        df["segment"].to_numpy()[1:] == df["segment"].to_numpy()[:-1]
    )
    d = np.diff(t)[same]
    d = d[d > 0]
    if not d.size:
        return None
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
    spans = df.groupby("segment", sort=False)["t"].agg(lambda s: s.max() - s.min()) + dt
    short = spans[window_s > spans * (1 + 1e-9)]
    if short.empty:
        return None
    which = (
        f"segment {short.index[0]!r} ({short.iloc[0]:.6g} s)"
        if len(short) == 1
        else f"{len(short)} of {len(spans)} segments (the shortest {short.min():.6g} s)"
    )
    return f"--window {window_s:g} s is longer than {which} of {source}: clipped to the record"
