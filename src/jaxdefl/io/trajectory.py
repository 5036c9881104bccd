"""Trajectory and reference tables: read, validate, write (DESIGN.md contract).

A trajectory table has columns ``t`` (s), ``plate`` (integer), ``z`` (mm) and optionally ``x``,
``y`` (mm) and ``segment`` (a day or session label). A reference (LDS) table has ``t``, ``plate``,
``z``. Headers may carry a unit, ``z_m``, ``z [cm]`` or ``t_ms``; values are converted to seconds
and millimetres. NaN (or an empty cell) means a missing sample.

Duplicate policy: loggers write the same row twice. Rows that repeat ``(segment, plate, t)``
with identical values are dropped (an exact duplicate carries no information); a repeated
timestamp with different values is an error, as is a timestamp that goes backwards.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pandas as pd

from .._errors import InputError

__all__ = ["load_table", "read_trajectory", "read_reference", "write_trajectory", "validate_trajectory"]

_LENGTH_MM = {"mm": 1.0, "m": 1000.0, "cm": 10.0, "um": 1e-3, "µm": 1e-3, "micron": 1e-3}
_TIME_S = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "µs": 1e-6}
_VALUE_COLUMNS = ("t", "x", "y", "z")
_HEADER = re.compile(r"^\s*([A-Za-z]+)\s*(?:[_ ]\s*\[?\s*([^\]\s]+)\s*\]?|\[\s*([^\]\s]+)\s*\])?\s*$")


def _parse_header(name: str, path: Path) -> tuple[str, float]:
    """Split a header like ``z``, ``z_mm`` or ``z [m]`` into (base name, factor to s or mm)."""
    m = _HEADER.match(str(name))
    if not m:
        return str(name), 1.0
    base = m.group(1)
    unit = m.group(2) or m.group(3)
    if base not in _VALUE_COLUMNS or unit is None:
        return (base if unit is None else str(name)), 1.0
    table = _TIME_S if base == "t" else _LENGTH_MM
    if unit not in table:
        expected = ", ".join(table)
        raise InputError(f"{path}: column {name!r} has unknown unit {unit!r}; expected one of {expected}")
    return base, table[unit]


def load_table(path: Path) -> pd.DataFrame:
    """A CSV or Parquet table as read, not yet validated (`validate_trajectory` does that)."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: file not found")
    suffix = path.suffix.lower()
    try:
        if suffix in (".parquet", ".pq"):
            return pd.read_parquet(path)
        if suffix in (".csv", ".txt", ".gz"):
            return pd.read_csv(path, comment="#")
    except (ValueError, OSError, pd.errors.ParserError) as err:
        first = str(err).splitlines()[0] if str(err) else type(err).__name__
        raise InputError(f"{path}: cannot be read as a table ({first})") from None
    raise InputError(f"{path}: unknown table format {suffix!r}; expected .csv or .parquet")


def _to_numeric(df: pd.DataFrame, col: str, path: Path) -> np.ndarray:
    raw = df[col]
    if raw.dtype == object or pd.api.types.is_string_dtype(raw):
        stripped = raw.astype("string").str.strip()
        blank = stripped.isna() | (stripped == "") | stripped.str.lower().isin(["nan", "na"])
        num = pd.to_numeric(stripped.where(~blank, None), errors="coerce")
        bad = num.isna() & ~blank
        if bad.any():
            i = int(np.flatnonzero(bad.to_numpy())[0])
            raise InputError(f"{path}: row {i + 2} column {col!r}: expected a number, got {raw.iloc[i]!r}")
        return num.to_numpy(dtype=np.float64)
    return pd.to_numeric(raw, errors="coerce").to_numpy(dtype=np.float64)


def validate_trajectory(
    df: pd.DataFrame, path: Path | str = "<table>", required: tuple[str, ...] = ("t", "plate", "z")
) -> pd.DataFrame:
    """Check a raw table against the contract and return it in canonical form.

    Returns a DataFrame with columns ``segment`` (str), ``plate`` (int64), ``t`` (float64, s) and
    the present of ``z``, ``x``, ``y`` (float64, mm), sorted by segment, plate and t, with exact
    duplicate rows removed. Row numbers in messages are file lines (header = line 1).

    Raises:
        InputError: missing columns, non-numeric values, unknown units, missing or non-integer
            plate numbers, timestamps repeated with other values or going backwards.
    """
    path = Path(str(path))
    renamed: dict[str, str] = {}
    factors: dict[str, float] = {}
    for col in df.columns:
        base, factor = _parse_header(col, path)
        if base in renamed.values():
            raise InputError(f"{path}: column {base!r} appears twice (as {col!r})")
        renamed[col] = base
        factors[base] = factor
    df = df.rename(columns=renamed)
    missing = [c for c in required if c not in df.columns]
    if missing:
        raise InputError(
            f"{path}: missing column(s) {', '.join(missing)}; "
            f"expected t, plate, z (optional x, y, segment), got {', '.join(map(str, df.columns))}"
        )
    if len(df) == 0:
        raise InputError(f"{path}: the table has no rows")
    out = pd.DataFrame(index=pd.RangeIndex(len(df)))
    out["segment"] = df["segment"].astype(str).str.strip() if "segment" in df else "0"
    t = _to_numeric(df, "t", path) * factors["t"]
    if np.isnan(t).any():
        i = int(np.flatnonzero(np.isnan(t))[0])
        raise InputError(f"{path}: row {i + 2} column 't': expected a time in s, got an empty cell")
    plate = _to_numeric(df, "plate", path)
    if np.isnan(plate).any() or np.any(plate != np.round(plate)):
        i = int(np.flatnonzero(np.isnan(plate) | (plate != np.round(plate)))[0])
        raise InputError(
            f"{path}: row {i + 2} column 'plate': expected an integer plate number, "
            f"got {df['plate'].iloc[i]!r}"
        )
    out["plate"] = plate.astype(np.int64)
    out["t"] = t
    axes = [a for a in ("z", "x", "y") if a in df.columns]
    for a in axes:
        out[a] = _to_numeric(df, a, path) * factors[a]
    out["_row"] = np.arange(len(df)) + 2

    out = out.sort_values(["segment", "plate", "_row"], kind="stable").reset_index(drop=True)
    # segments compared as codes: the labels as Python strings cost seconds on an LDS table
    # (a missing label, code -1, equals nothing, as NaN does)
    seg = pd.factorize(out["segment"])[0]
    same_series = (
        (seg[1:] == seg[:-1]) & (seg[1:] >= 0) & (out["plate"].to_numpy()[1:] == out["plate"].to_numpy()[:-1])
    )
    dt = np.diff(out["t"].to_numpy())
    back = same_series & (dt < 0)
    if back.any():
        j = int(np.flatnonzero(back)[0])
        raise InputError(
            f"{path}: row {out['_row'].iat[j + 1]}: t must increase within plate "
            f"{out['plate'].iat[j + 1]}, got t={float(out['t'].iat[j + 1])!r} after "
            f"t={float(out['t'].iat[j])!r} (row {out['_row'].iat[j]})"
        )
    rep = same_series & (dt == 0)
    if rep.any():
        vals = out[axes].to_numpy()
        same_vals = np.all((vals[1:] == vals[:-1]) | (np.isnan(vals[1:]) & np.isnan(vals[:-1])), axis=1)
        conflict = rep & ~same_vals
        if conflict.any():
            j = int(np.flatnonzero(conflict)[0])
            raise InputError(
                f"{path}: row {out['_row'].iat[j + 1]}: plate {out['plate'].iat[j + 1]} repeats "
                f"t={float(out['t'].iat[j + 1])!r} of row {out['_row'].iat[j]} with different values"
            )
        out = out.drop(index=np.flatnonzero(rep) + 1).reset_index(drop=True)
    # A plate without one valid sample stays: its windows get the status too_few_samples, and
    # the other plates are fitted (one bad plate never stops the rest).
    return out.drop(columns="_row")


def read_trajectory(path: Path | str) -> pd.DataFrame:
    """Read and validate a trajectory table (CSV or Parquet); see `validate_trajectory`."""
    path = Path(path)
    return validate_trajectory(load_table(path), path)


def read_reference(path: Path | str) -> pd.DataFrame:
    """Read and validate a reference (LDS) table: ``t``, ``plate``, ``z`` (+ optional segment)."""
    path = Path(path)
    return validate_trajectory(load_table(path), path)


def write_trajectory(df: pd.DataFrame, path: Path | str, outs=None) -> None:
    """Write a trajectory table atomically, CSV or Parquet by the suffix; CSV keeps t to the
    microsecond and lengths to the nanometre (``%.6f``). With ``outs`` (an
    `jaxdefl.io.output.Outputs`) the table is only staged, to be committed with the others."""
    from .output import Outputs

    cols = [c for c in ("segment", "t", "plate", "x", "y", "z") if c in df.columns]
    if outs is not None:
        outs.table(path, df[cols], float_format="%.6f")
        return
    with Outputs() as own:
        own.table(path, df[cols], float_format="%.6f")
