"""The vectorised windowing (`jaxdefl.series.make_windows`, `windows_like`) against a slow,
readable reference that cuts and clocks one window at a time (the implementation before issue
27's speed work): the same samples, masks, frame indices, clocks and table, bit for bit (the
frame interval to the last bits)."""

import importlib.util
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from jaxdefl.io import validate_trajectory
from jaxdefl.series import frame_clock, make_windows, windows_like
from jaxdefl.series.clock import SNAP_MAX, fit_clock
from jaxdefl.series.windows import EXACT, MAX_GRID_FILL, Windows, _bounds
from jaxdefl.status import Status

ROOT = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location("mfr", ROOT / "experiments" / "make_fit_reference.py")
mfr = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(mfr)


def _slow_window_clock(dt, k, r):
    if r.size < 2 or not np.isfinite(dt):
        return dt, k, False
    kc = k - k.mean()
    den = float(kc @ kc)
    slope = float(kc @ r) / den if den > 0 else 0.0
    left = r - r.mean() - slope * kc
    if float(np.max(np.abs(left))) <= EXACT * dt:
        return dt + slope, k, True
    return dt, k, bool(np.std(r) <= SNAP_MAX * dt)


def _slow_pack(series, min_samples):
    s = max(max((len(item[1]) for item in series), default=1), 1)
    b = len(series)
    T, Y = np.zeros((b, s)), np.zeros((b, s))
    M, K = np.zeros((b, s), bool), np.zeros((b, s), np.int64)
    dt, on, centre, rows = np.full(b, np.nan), np.zeros(b, bool), np.zeros(b), []
    for i, (meta, t_abs, y, *clock) in enumerate(series):
        n = t_abs.size
        centre[i] = 0.5 * (t_abs[0] + t_abs[-1]) if n else meta["t_mid"]
        T[i, :n], Y[i, :n], M[i, :n] = t_abs - centre[i], y, True
        if clock and clock[0][2] and n and clock[0][1][-1] - clock[0][1][0] + 1 <= MAX_GRID_FILL * n:
            dt[i], K[i, :n], on[i] = clock[0][0], clock[0][1] - clock[0][1][0], True
        elif n:
            dt[i], K[i, :n], on[i] = frame_clock(t_abs - t_abs[0])
        ok = Status.CONVERGED if n >= min_samples else Status.TOO_FEW_SAMPLES
        rows.append({**meta, "n": n, "status": ok})
    cols = ["segment", "window", "t_start", "t_end", "t_mid", "plate", "axis", "n", "status"]
    table = pd.DataFrame(rows, columns=cols)
    table.insert(5, "t_centre", centre)
    return Windows(T, Y, M, K, dt, on, table)


def slow_make_windows(df, axes, window_s=None, step_s=None, min_samples=16):
    """One window at a time: cut, drop missing values, clock, pad."""
    step_s = window_s if step_s is None else step_s
    series = []
    for seg, g in df.groupby("segment", sort=False):
        bounds = _bounds(g["t"].to_numpy(), window_s, step_s)
        for plate, gp in g.groupby("plate", sort=True):
            t_all = gp["t"].to_numpy()
            clk = fit_clock(t_all - t_all[0])
            resid = t_all - t_all[0] - clk.t if np.isfinite(clk.dt) else np.full(t_all.size, np.nan)
            for axis in axes:
                v = gp[axis].to_numpy()
                for w, (a, b) in enumerate(bounds):
                    lo, hi = (0, t_all.size) if window_s is None else np.searchsorted(t_all, [a, b])
                    sel = np.isfinite(v[lo:hi])
                    meta = dict(segment=seg, window=w, t_start=a, t_end=b, t_mid=0.5 * (a + b))
                    meta |= dict(plate=int(plate), axis=axis)
                    clock = _slow_window_clock(clk.dt, clk.k[lo:hi][sel], resid[lo:hi][sel])
                    series.append((meta, t_all[lo:hi][sel], v[lo:hi][sel], clock))
    return _slow_pack(series, min_samples)


def slow_windows_like(ref, like, min_samples=16):
    series = []
    by_plate = {int(p): g for p, g in ref.groupby("plate")}
    whole = like["window"].max() == 0
    for _, row in like[like["axis"] == "z"].iterrows():
        g = by_plate.get(int(row["plate"]))
        if g is None:
            continue
        t_all, v = g["t"].to_numpy(), g["z"].to_numpy()
        lo = np.searchsorted(t_all, row["t_start"], side="left")
        hi = np.searchsorted(t_all, row["t_end"], side="right" if whole else "left")
        ok = np.isfinite(v[lo:hi])
        meta = {c: row[c] for c in ("segment", "window", "t_start", "t_end", "t_mid", "plate", "axis")}
        series.append((meta, t_all[lo:hi][ok], v[lo:hi][ok]))
    return _slow_pack(series, min_samples)


def assert_same(a: Windows, b: Windows):
    for name in ("t", "y", "mask", "k", "on_clock"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    # a window's own exact clock comes from sums reduced in another order: to the last bits
    np.testing.assert_allclose(a.dt, b.dt, rtol=1e-14, atol=0)
    pd.testing.assert_frame_equal(a.table, b.table)


@pytest.fixture(scope="module")
def tables():
    """Drop-outs, missing values on some axes, a logger restart, one jittered plate, 2 segments."""
    rng = np.random.default_rng(3)
    df = mfr.reference_dataset(minutes=2)
    df.loc[rng.random(len(df)) < 0.01, "x"] = np.nan
    df.loc[df.index[:300], "y"] = np.nan
    restart = df.copy()
    restart["t"] += np.where(restart["t"] > restart["t"].min() + 70, 0.013, 0.0)
    jitter = df.copy()
    on3 = (jitter["plate"] == 3).to_numpy()
    jitter.loc[on3, "t"] = np.sort(jitter["t"][on3] + rng.normal(0, 0.015, on3.sum()))  # off its clock
    two = df.copy()
    two["segment"] = np.where(two["t"] > two["t"].min() + 50, "b", "a")
    return [validate_trajectory(d) for d in (df, restart, jitter, two)]


@pytest.mark.parametrize("window_s, step_s", [(None, None), (30.0, None), (20.0, 7.0), (3.0, None)])
def test_make_windows_equals_the_window_by_window_reference(tables, window_s, step_s):
    for df in tables:
        got = make_windows(df, axes=("z", "x", "y"), window_s=window_s, step_s=step_s)
        assert_same(got, slow_make_windows(df, ("z", "x", "y"), window_s, step_s))


def test_shared_clocks_change_nothing(tables):
    clocks = {}
    make_windows(tables[1], window_s=None, clocks=clocks)
    assert_same(make_windows(tables[1], window_s=30.0, clocks=clocks), make_windows(tables[1], window_s=30.0))


@pytest.mark.parametrize("window_s", [None, 30.0])
def test_windows_like_equals_the_reference(tables, window_s):
    df = tables[0]
    like = make_windows(df, axes=("z", "x"), window_s=window_s).table
    ref = df[df["plate"] != 5][["t", "plate", "z", "segment"]]
    assert_same(windows_like(ref, like), slow_windows_like(ref, like))
