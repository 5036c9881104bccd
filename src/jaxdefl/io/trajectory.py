"""Trajectory and reference tables: read, validate, write (DESIGN.md contract).

A trajectory table has columns ``t`` (s), ``plate`` (integer), ``z`` (mm) and optionally ``x``,
``y`` (mm) and ``segment`` (a day or session label). A reference (LDS) table has ``t``, ``plate``,
``z``. Headers may carry a unit, ``z_m``, ``z [cm]`` or ``t_ms``; values are converted to seconds
and millimetres. NaN (or an empty cell) means a missing sample.

Units: a header without a unit is read as s and mm, but values implausible for those are an
error that names the likely unit (epoch milliseconds, microseconds or nanoseconds in ``t``;
metres for a sub-millimetre motion or micrometres in ``z``) and how to say so (``t_ms``, ``z_m``,
... or ``t_s``, ``z_mm`` to confirm); a header with a unit is never second-guessed. Datetime
columns (Parquet datetime64, with or without a time zone; ISO 8601 strings in a CSV) are read as
float seconds since the epoch (UTC), microseconds kept. True/false columns are refused.

Timestamp policy (``timestamps``; `TIMESTAMP_POLICIES`):

- ``strict`` (default): rows that repeat ``(segment, plate, t)`` with identical values are
  dropped (loggers write the same row twice); a repeated timestamp with different values is an
  error, as is a timestamp that goes backwards. The error names the policy that would read the
  file.
- ``merge``: rows that share ``(segment, plate, t)`` are true duplicates, averaged (NaN-aware).
- ``reclock``: the stamps are a device's rounded or jittered writing of a sample clock: every
  row is a sample, in row order, and its time is replaced by the clock recovered per segment and
  plate (`jaxdefl.series.clock.fit_clock`); the recovered interval, jitter RMS and drift are in
  the returned table's ``attrs["timestamps"]``. A plate's rows that step back by more than a
  frame interval are not in sample order (a shuffled or re-sorted file): they are sorted by t
  first, and the report says so (``series_sorted``).
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pandas as pd

from .._errors import InputError, echo
from .._numerics import mad_sigma
from ..settings import TIMESTAMP_POLICIES, check_timestamp_policy

__all__ = [
    "TIMESTAMP_POLICIES",
    "load_table",
    "read_trajectory",
    "read_reference",
    "write_trajectory",
    "validate_trajectory",
    "check_timestamp_policy",
    "timestamp_note",
    "layout_note",
]

_LENGTH_MM = {"mm": 1.0, "m": 1000.0, "cm": 10.0, "um": 1e-3, "µm": 1e-3, "micron": 1e-3}
_TIME_S = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "µs": 1e-6, "ns": 1e-9}
# Unit plausibility of headers without a unit (see `_check_plausible`).
_EPOCH_S_MAX = 1e11  # seconds: the year 5138; beyond, epoch ms, µs or ns
_METRES_MEDIAN_MIN = 0.5  # a range camera sees from 0.5 m on; a series centred lower is ambiguous
_METRES_ABS_MAX = 10.0  # |z| below this everywhere ...
_METRES_SPREAD_MAX = 0.02  # ... and every plate's robust σ below this: metres, not mm
_MICROMETRES_MEDIAN_MIN = 1e5  # median |z| beyond 100 m: micrometres, not mm
# what each policy reads that the others refuse, for the hint of a refusal
_READS = {
    "reclock": "--timestamps reclock (a rounded or jittered logger clock)",
    "merge": "--timestamps merge (true duplicates)",
}


def _hint(given: str) -> str:
    """The policies other than ``given`` that would read a table with repeated timestamps."""
    other = [text for policy, text in _READS.items() if policy != given]
    return "rerun with " + " or ".join(other)


def _plain(v) -> str:
    """A cell as the user wrote it: numpy scalars as plain numbers, strings quoted."""
    return echo(v)


_VALUE_COLUMNS = ("t", "x", "y", "z")
_HEADER = re.compile(r"^\s*([A-Za-z]+)\s*(?:[_ ]\s*\[?\s*([^\]\s]+)\s*\]?|\[\s*([^\]\s]+)\s*\])?\s*$")


def _parse_header(name: str, path: Path) -> tuple[str, float, bool]:
    """Split a header like ``z``, ``z_mm`` or ``z [m]`` into (base name, factor to s or mm,
    whether a unit was given)."""
    m = _HEADER.match(str(name))
    if not m:
        return str(name), 1.0, False
    base = m.group(1)
    unit = m.group(2) or m.group(3)
    if base not in _VALUE_COLUMNS or unit is None:
        return (base if unit is None else str(name)), 1.0, False
    table = _TIME_S if base == "t" else _LENGTH_MM
    if unit not in table:
        expected = ", ".join(table)
        raise InputError(f"{path}: column {name!r} has unknown unit {unit!r}; expected one of {expected}")
    return base, table[unit], True


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
            fast = _read_numeric_csv(path)
            return _unique_columns(pd.read_csv(path, comment="#"), path) if fast is None else fast
    except (ValueError, OSError, pd.errors.ParserError) as err:
        first = str(err).splitlines()[0] if str(err) else type(err).__name__
        raise InputError(f"{path}: cannot be read as a table ({first})") from None
    raise InputError(f"{path}: unknown table format {suffix!r}; expected .csv or .parquet")


def _unique_columns(df: pd.DataFrame, path: Path) -> pd.DataFrame:
    """The table, or an InputError naming a column its header has twice (pandas reads the
    second ``z`` as ``z.1``, which would silently leave it unused)."""
    names = [str(c) for c in df.columns]
    for i, name in enumerate(names):
        m = re.fullmatch(r"(.+)\.(\d+)", name)
        if m and m.group(1) in names[:i]:
            first = names.index(m.group(1))
            raise InputError(
                f"{path}: column {m.group(1)!r} appears twice in the header (columns {first + 1} and "
                f"{i + 1}); expected each column once"
            )
    return df


def _read_numeric_csv(path: Path) -> pd.DataFrame | None:
    """A plain CSV (no comment lines, distinct column names, numeric columns but a text
    ``segment``) read by pyarrow's multithreaded reader: no per-row Python, a few times faster
    than pandas' parser on millions of rows. Anything else gives None, and pandas' reader (whose
    behaviour the messages of `validate_trajectory` are written for) reads the file instead."""
    import pyarrow as pa
    import pyarrow.csv as pacsv

    if path.suffix.lower() != ".csv":
        return None
    data = path.read_bytes()
    if b"#" in data or b'"' in data:
        return None
    try:
        tab = pacsv.read_csv(pa.py_buffer(data))
    except (pa.ArrowInvalid, ValueError):
        return None
    names = tab.column_names
    if len(set(names)) != len(names) or tab.num_rows == 0:
        return None
    for name, typ in zip(names, tab.schema.types, strict=True):
        if not (pa.types.is_integer(typ) or pa.types.is_floating(typ)) and not (
            name == "segment" and pa.types.is_string(typ)
        ):
            return None
    return tab.to_pandas()


def _row_offset(path: Path) -> int:
    """Row number of the first data row in messages: CSV counts file lines (header = line 1),
    Parquet counts data rows from 1."""
    return 1 if path.suffix.lower() in (".parquet", ".pq") else 2


def _epoch_seconds(ns: np.ndarray, nat: np.ndarray) -> np.ndarray:
    """Integer nanoseconds since the epoch as float seconds (whole seconds and the fraction
    apart, so microseconds survive at 1.7e9 s); NaN where ``nat``."""
    sec = (ns // 10**9).astype(np.float64) + (ns % 10**9).astype(np.float64) * 1e-9
    return np.where(nat, np.nan, sec)


def _datetime_seconds(raw: pd.Series) -> np.ndarray:
    """A datetime64 column (naive = UTC, or with a time zone) or a timedelta64 column as float
    seconds since the epoch (or of the duration)."""
    if isinstance(raw.dtype, pd.DatetimeTZDtype):
        raw = raw.dt.tz_convert("UTC").dt.tz_localize(None)
    if pd.api.types.is_timedelta64_dtype(raw):
        vals = raw.astype("timedelta64[ns]").to_numpy()
    else:
        vals = raw.astype("datetime64[ns]").to_numpy()
    return _epoch_seconds(vals.view(np.int64), np.isnat(vals))


def _iso_seconds(stripped: pd.Series, blank: pd.Series) -> np.ndarray | None:
    """ISO 8601 date-time strings (a CSV's ``t`` written by a logger) as float seconds since the
    epoch, UTC unless the string has an offset; None unless every non-blank cell is one."""
    cells = stripped.where(~blank, None)
    first = cells.dropna()
    if first.empty or not first.iloc[0][:4].isdigit() or "-" not in first.iloc[0]:
        return None
    try:
        parsed = pd.to_datetime(cells, format="ISO8601", utc=True)
    except (ValueError, TypeError, OverflowError):
        return None
    return _datetime_seconds(parsed)


def _to_numeric(df: pd.DataFrame, col: str, path: Path, name: str | None = None) -> np.ndarray:
    """Column ``col`` (t, plate, x, y or z: what its values must be) as float64; messages
    call it ``name`` (default: ``col``), as the file does."""
    raw = df[col]
    off = _row_offset(path)
    shown = col if name is None else name
    if pd.api.types.is_bool_dtype(raw):
        raise InputError(
            f"{path}: column {shown!r} holds true/false values; expected "
            + ("times in s" if col == "t" else "plate numbers" if col == "plate" else "numbers in mm")
        )
    if pd.api.types.is_datetime64_any_dtype(raw) or pd.api.types.is_timedelta64_dtype(raw):
        if col != "t":
            raise InputError(f"{path}: column {shown!r} holds dates or durations; expected numbers")
        return _datetime_seconds(raw)
    if raw.dtype == object or pd.api.types.is_string_dtype(raw):
        stripped = raw.astype("string").str.strip()
        blank = stripped.isna() | (stripped == "") | stripped.str.lower().isin(["nan", "na"])
        num = pd.to_numeric(stripped.where(~blank, None), errors="coerce")
        bad = num.isna() & ~blank
        if bad.any():
            if col == "t" and (iso := _iso_seconds(stripped, blank)) is not None:
                return iso
            i = int(np.flatnonzero(bad.to_numpy())[0])
            raise InputError(
                f"{path}: row {i + off} column {shown!r}: expected a number, got {_plain(raw.iloc[i])}"
            )
        return num.to_numpy(dtype=np.float64)
    return pd.to_numeric(raw, errors="coerce").to_numpy(dtype=np.float64)


def _check_plausible(path: Path, col: str, v: np.ndarray, plate: np.ndarray) -> None:
    """Refuse values of a unitless column that are implausible in s or mm (see the module)."""
    fin = np.isfinite(v)
    if not fin.any():
        return
    a = np.abs(v[fin])
    if col == "t":
        top = float(a.max())
        if top > _EPOCH_S_MAX:
            unit, name = (
                ("milliseconds", "t_ms")
                if top < 1e14
                else ("microseconds", "t_us")
                if top < 1e17
                else ("nanoseconds", "t_ns")
            )
            raise InputError(
                f"{path}: column 't' has no unit and values up to {top:.4g}, implausible as seconds "
                f"(after the year 5000): epoch {unit}? rename the column {name} to read them so, "
                "or t_s to confirm seconds"
            )
        return
    if col != "z":
        return
    if float(np.median(a)) > _MICROMETRES_MEDIAN_MIN:
        raise InputError(
            f"{path}: column 'z' has no unit and a median |z| of {float(np.median(a)):.4g}, "
            "implausible in mm (beyond 100 m): micrometres? rename the column z_um to read them so, "
            "or z_mm to confirm millimetres"
        )
    if float(a.max()) >= _METRES_ABS_MAX or float(np.median(a)) < _METRES_MEDIAN_MIN:
        # (values centred near 0 with a tiny motion may be a micrometre-level record in mm:
        # ambiguous, so read as written; a metre-sized level with a tiny motion is not)
        return
    ser = pd.Series(v[fin]).groupby(plate[fin])
    counts = ser.size()
    spread = ser.agg(mad_sigma)[counts >= 8]
    if spread.size and float(spread.max()) > 0 and float(spread.max()) < _METRES_SPREAD_MAX:
        raise InputError(
            f"{path}: column 'z' has no unit, every |z| is below {_METRES_ABS_MAX:g} and no plate "
            f"moves by more than {float(spread.max()):.2g} (robust σ): metres, not mm? rename the "
            "column z_m to read metres, or z_mm to confirm millimetres"
        )


def validate_trajectory(
    df: pd.DataFrame,
    path: Path | str = "<table>",
    required: tuple[str, ...] = ("t", "plate", "z"),
    timestamps: str = "strict",
) -> pd.DataFrame:
    """Check a raw table against the contract and return it in canonical form.

    Returns a DataFrame with columns ``segment`` (str), ``plate`` (int64), ``t`` (float64, s) and
    the present of ``z``, ``x``, ``y`` (float64, mm), sorted by segment, plate and t, with exact
    duplicate rows removed (``strict``), duplicates averaged (``merge``) or the times replaced
    by the recovered sample clock (``reclock``; see the module). Row numbers in messages are
    file lines for CSV (header = line 1) and data rows from 1 for Parquet. With ``reclock`` or
    ``merge``, ``attrs["timestamps"]`` reports what was done.

    Raises:
        InputError: missing columns, non-numeric or true/false values, unknown or implausible
            units, missing or non-integer plate numbers, timestamps repeated with other values
            or going backwards (``strict``).
        ConfigError: an unknown timestamp policy.
    """
    check_timestamp_policy(timestamps)
    path = Path(str(path))
    off = _row_offset(path)
    layout = None
    if "plate" in required and "plate" not in {_parse_header(c, path)[0] for c in df.columns}:
        df, layout = _long_from_wide(df, path)
    renamed: dict[str, str] = {}
    factors: dict[str, float] = {}
    explicit: dict[str, bool] = {}
    for col in df.columns:
        base, factor, has_unit = _parse_header(col, path)
        if base in renamed.values():
            raise InputError(f"{path}: column {base!r} appears twice (as {col!r})")
        renamed[col] = base
        factors[base] = factor
        explicit[base] = has_unit
    df = df.rename(columns=renamed)
    missing = [c for c in required if c not in df.columns]
    if missing:
        got = ", ".join(map(str, df.columns))
        if "plate" in missing:
            layouts = _layouts(plateless="z" in df.columns)
            raise InputError(f"{path}: missing column(s) {', '.join(missing)} (got {got}); {layouts}")
        raise InputError(
            f"{path}: missing column(s) {', '.join(missing)}; "
            f"expected t, plate, z (optional x, y, segment), got {got}"
        )
    if len(df) == 0:
        raise InputError(f"{path}: the table has no rows")
    out = pd.DataFrame(index=pd.RangeIndex(len(df)))
    out["segment"] = df["segment"].astype(str).str.strip() if "segment" in df else "0"
    dated = pd.api.types.is_datetime64_any_dtype(df["t"])
    t = _to_numeric(df, "t", path) * factors["t"]
    if np.isnan(t).any():
        i = int(np.flatnonzero(np.isnan(t))[0])
        raise InputError(f"{path}: row {i + off} column 't': expected a time in s, got an empty cell")
    plate = _to_numeric(df, "plate", path)
    if np.isnan(plate).any() or np.any(plate != np.round(plate)):
        i = int(np.flatnonzero(np.isnan(plate) | (plate != np.round(plate)))[0])
        raise InputError(
            f"{path}: row {i + off} column 'plate': expected an integer plate number, "
            f"got {_plain(df['plate'].iloc[i])}"
        )
    out["plate"] = plate.astype(np.int64)
    out["t"] = t
    axes = [a for a in ("z", "x", "y") if a in df.columns]
    for a in axes:
        out[a] = _to_numeric(df, a, path) * factors[a]
    if not explicit["t"] and not dated:
        _check_plausible(path, "t", t, out["plate"].to_numpy())
    if "z" in axes and not explicit["z"]:
        _check_plausible(path, "z", out["z"].to_numpy(), out["plate"].to_numpy())
    out["_row"] = df["_line"].to_numpy() if "_line" in df else np.arange(len(df)) + off

    out = out.sort_values(["segment", "plate", "_row"], kind="stable").reset_index(drop=True)
    report = None
    if timestamps == "reclock":
        out, report = _reclock(out, path)
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
        fwd = dt[same_series & (dt > 0)]
        small = fwd.size > 0 and -dt[j] < float(np.median(fwd))  # neighbours swapped by jitter?
        raise InputError(
            f"{path}: row {out['_row'].iat[j + 1]}: t must increase within plate "
            f"{out['plate'].iat[j + 1]}, got t={_plain(out['t'].iat[j + 1])} after "
            f"t={_plain(out['t'].iat[j])} (row {out['_row'].iat[j]})"
            + (
                "; if a jittered clock swapped neighbours, rerun with --timestamps reclock"
                if small and timestamps != "reclock"
                else ""
            )
        )
    rep = same_series & (dt == 0)
    if rep.any() and timestamps == "merge":
        out, report = _merge(out, axes)
    elif rep.any():
        vals = out[axes].to_numpy()
        same_vals = np.all((vals[1:] == vals[:-1]) | (np.isnan(vals[1:]) & np.isnan(vals[:-1])), axis=1)
        conflict = rep & ~same_vals
        if conflict.any():
            j = int(np.flatnonzero(conflict)[0])
            raise InputError(
                f"{path}: row {out['_row'].iat[j + 1]}: plate {out['plate'].iat[j + 1]} repeats "
                f"t={_plain(out['t'].iat[j + 1])} of row {out['_row'].iat[j]} with different values "
                f"({int(conflict.sum())} such rows); {_hint(timestamps)}"
            )
        out = out.drop(index=np.flatnonzero(rep) + 1).reset_index(drop=True)
    # A plate without one valid sample stays: its windows get the status too_few_samples, and
    # the other plates are fitted (one bad plate never stops the rest).
    out = out.drop(columns="_row")
    if report is not None:
        out.attrs["timestamps"] = report
    if layout is not None:
        out.attrs["layout"] = layout
    return out


# -- wide logger tables: a time column and one column per channel -------------------------------


def _layouts(time: str | None = None, unit: str | None = None, plateless: bool = False) -> str:
    """The two layouts a table may have and a one-line conversion to the long one: of a wide
    table with the time column ``time`` (in ``unit``; channels numbered 1.. in column order),
    or of a long table without plate numbers (``plateless``: one plate)."""
    layouts = (
        "expected a long table (t, plate, z; optional x, y, segment) or a wide logger table (a time "
        "column such as t, time_ms or 'Time (s)', then one column per plate numbered like LDS1, LDS2)"
    )
    if plateless:
        return f"{layouts}; for one plate: pd.read_csv(f).assign(plate=1).to_csv(g, index=False)"
    time = time or "t"
    long = "t" if unit is None else f"t_{unit}"
    rename = "" if time == long else f".rename(columns={{{time!r}: {long!r}}})"
    return (
        f"{layouts}; to convert (plates 1.. in column order): pd.read_csv(f){rename}.melt(id_vars="
        f"{long!r}, var_name='plate', value_name='z').assign(plate=lambda d: pd.factorize(d.plate)[0]"
        " + 1).to_csv(g, index=False)"
    )


_UNIT = r"(?:[_ ]\s*[\[(]?\s*(?P<unit>[^\])\s]+)\s*[\])]?|\s*[\[(]\s*(?P<unit2>[^\])\s]+)\s*[\])])"
_TIME_HEADER = re.compile(rf"^\s*(?:t|time|timestamp)\s*{_UNIT}?\s*$", re.IGNORECASE)
_CHANNEL_HEADER = re.compile(rf"^\s*(?P<label>.*?)\s*(?P<number>\d+)\s*{_UNIT}?\s*$")


def _unit_of(m: re.Match, table: dict[str, float], path: Path, name: str) -> tuple[float, bool]:
    unit = m.group("unit") or m.group("unit2")
    if unit is None:
        return 1.0, False
    if unit not in table:
        raise InputError(
            f"{path}: column {name!r} has unknown unit {unit!r}; expected one of {', '.join(table)}"
        )
    return table[unit], True


def _long_from_wide(df: pd.DataFrame, path: Path) -> tuple[pd.DataFrame, dict]:
    """A wide logger table (a time column, one column per channel: ``time_ms, LDS1, LDS2``) as
    a long table ``t, plate, z`` (+ segment) with its file lines kept in ``_line``, and the
    mapping of its columns (``attrs["layout"]``). The plate of a channel is its header's
    trailing number; a unit may follow (``LDS1_mm``, ``LDS1 [m]``). Any other table without a
    ``plate`` column is left for `validate_trajectory` to refuse, naming both layouts."""
    names = [str(c) for c in df.columns]
    times = [c for c in names if _TIME_HEADER.match(c)]
    rest = [c for c in names if c not in times and c.strip().lower() != "segment"]
    unit = None
    if len(times) == 1:
        m = _TIME_HEADER.match(times[0])
        unit = m.group("unit") or m.group("unit2")
    if len(times) != 1 or not rest:
        if len(times) > 1:
            raise InputError(
                f"{path}: no 'plate' column and several time columns ({', '.join(times)}); {_layouts()}"
            )
        return df, None
    if any(_parse_header(c, path)[0] in _VALUE_COLUMNS for c in rest):
        return df, None  # a long table without its plate column: refused as such
    channels = {c: _CHANNEL_HEADER.match(c) for c in rest}
    unnumbered = [c for c, m in channels.items() if m is None or m.group("label").startswith("Unnamed")]
    if unnumbered:
        raise InputError(
            f"{path}: no 'plate' column, and the column(s) {', '.join(map(repr, unnumbered))} beside "
            f"{times[0]!r} carry no plate number; {_layouts(times[0], unit)}"
        )
    labels = {re.sub(r"[\s_-]+$", "", m.group("label")).lower() for m in channels.values()}
    plates = {c: int(m.group("number")) for c, m in channels.items()}
    if len(labels) > 1 or len(set(plates.values())) < len(plates):
        raise InputError(
            f"{path}: no 'plate' column, and the channel columns {', '.join(map(repr, rest))} do not "
            f"name one sensor's plates once each; {_layouts(times[0], unit)}"
        )
    off = _row_offset(path)
    t_factor, t_unit = _unit_of(_TIME_HEADER.match(times[0]), _TIME_S, path, times[0])
    raw_t = df[times[0]]
    t = _to_numeric(df.rename(columns={times[0]: "t"}), "t", path, name=times[0])
    if np.isnan(t).any():
        i = int(np.flatnonzero(np.isnan(t))[0])
        raise InputError(f"{path}: row {i + off} column {times[0]!r}: expected a time, got an empty cell")
    # dates (datetime64, ISO strings) are seconds since the epoch already: no unit applies
    dated = pd.api.types.is_datetime64_any_dtype(raw_t) or bool(
        (pd.to_numeric(raw_t, errors="coerce").isna() & raw_t.notna()).any()
    )
    explicit = []
    z = []
    for c, m in channels.items():
        factor, has_unit = _unit_of(m, _LENGTH_MM, path, c)
        explicit.append(has_unit)
        z.append(_to_numeric(df.rename(columns={c: "z"}), "z", path, name=c) * factor)
    n, k = len(df), len(rest)
    long = pd.DataFrame(
        {
            # a unit in the headers is kept, so that the long table's checks never second-guess it
            ("t_s" if t_unit or dated else "t"): np.tile(t if dated else t * t_factor, k),
            "plate": np.repeat(list(plates.values()), n),
            ("z_mm" if all(explicit) else "z"): np.concatenate(z),
            "_line": np.tile(np.arange(n) + off, k),
        }
    )
    seg = next((c for c in names if c.strip().lower() == "segment"), None)
    if seg is not None:
        long.insert(0, "segment", np.tile(df[seg].to_numpy(), k))
    layout = {"layout": "wide", "time": times[0], "channels": plates}
    return long, layout


def layout_note(layout: dict | None, path: Path | str = "") -> str | None:
    """One line for stderr naming how a wide table's columns were read (None for a long table)."""
    if not layout:
        return None
    chans = ", ".join(f"{c} -> plate {p}" for c, p in list(layout["channels"].items())[:8])
    more = " ..." if len(layout["channels"]) > 8 else ""
    return f"{path}: a wide table: {layout['time']} -> t; {chans}{more} (z)"


def _merge(out: pd.DataFrame, axes: list[str]) -> tuple[pd.DataFrame, dict]:
    """Average the rows that share (segment, plate, t) (NaN-aware: a missing value does not
    count); the first row's number is kept for messages."""
    n0 = len(out)
    agg = {a: "mean" for a in axes}
    agg["_row"] = "first"
    merged = out.groupby(["segment", "plate", "t"], sort=False, as_index=False).agg(agg)
    merged = merged[["segment", "plate", "t", *axes, "_row"]].reset_index(drop=True)
    return merged, {"policy": "merge", "rows_merged": int(n0 - len(merged)), "rows": int(len(merged))}


def _reclock(out: pd.DataFrame, path: Path) -> tuple[pd.DataFrame, dict]:
    """Replace t by the clock recovered per (segment, plate), rows in file order (see
    `jaxdefl.series.clock.fit_clock`); a step back of more than a recovered interval is an error."""
    from ..series.clock import fit_clock

    seg = pd.factorize(out["segment"])[0]
    plate = out["plate"].to_numpy()
    cut = np.flatnonzero((seg[1:] != seg[:-1]) | (plate[1:] != plate[:-1])) + 1
    bounds = np.concatenate([[0], cut, [len(out)]])
    out, n_sorted = _sample_order(out, bounds)
    t = out["t"].to_numpy().copy()
    per_segment: dict[str, list] = {}
    for lo, hi in zip(bounds[:-1], bounds[1:], strict=True):
        ts = t[lo:hi]
        if hi - lo < 3:
            continue
        c = fit_clock(ts - ts[0])
        if not np.isfinite(c.dt):
            continue
        d = np.diff(ts)
        if (d < -c.dt).any():
            j = lo + 1 + int(np.flatnonzero(d < -c.dt)[0])
            raise InputError(
                f"{path}: row {out['_row'].iat[j]}: t goes back by more than the recovered frame "
                f"interval ({c.dt:.6g} s) within plate {out['plate'].iat[j]}: the rows are not in "
                "sample order, which --timestamps reclock needs"
            )
        t[lo:hi] = ts[0] + c.t
        per_segment.setdefault(str(out["segment"].iat[lo]), []).append(c)
    out = out.assign(t=t)
    segments = []
    for name, clocks in per_segment.items():
        segments.append(
            {
                "segment": name,
                "series": len(clocks),
                "interval_s": float(np.median([c.dt for c in clocks])),
                "jitter_rms_s": float(np.sqrt(np.mean([c.jitter_rms**2 for c in clocks]))),
                "drift_ppm": float(np.median([c.drift_ppm for c in clocks])),
            }
        )
    return out, {"policy": "reclock", "segments": segments, "series_sorted": n_sorted}


def _sample_order(out: pd.DataFrame, bounds: np.ndarray) -> tuple[pd.DataFrame, int]:
    """The rows of every (segment, plate) series in sample order, and how many series were
    sorted. Rows in file order are the samples' order (a jittered stamp may fall behind its
    predecessor by less than a frame interval); a series whose stamps go back by more than
    its median frame interval was written out of order (shuffled, or plates interleaved
    out of order) and is sorted by t, stably."""
    t = out["t"].to_numpy()
    order = np.arange(t.size)
    n_sorted = 0
    for lo, hi in zip(bounds[:-1], bounds[1:], strict=True):
        d = np.diff(t[lo:hi])
        if not (d < 0).any():
            continue
        steps = np.diff(np.sort(t[lo:hi]))
        steps = steps[steps > 0]
        interval = float(np.median(steps)) if steps.size else 0.0
        if (d < -interval).any():
            order[lo:hi] = lo + np.argsort(t[lo:hi], kind="stable")
            n_sorted += 1
    if n_sorted:
        out = out.iloc[order].reset_index(drop=True)
    return out, n_sorted


def timestamp_note(report: dict | None) -> str | None:
    """One line for stderr about what a timestamp policy did (None for strict)."""
    if not report:
        return None
    if report["policy"] == "merge":
        return f"timestamps merged: {report['rows_merged']} duplicate rows averaged"
    segs = report["segments"]
    if not segs:
        return "timestamps reclocked: no series long enough"
    iv = np.median([s["interval_s"] for s in segs])
    jit = float(np.sqrt(np.mean([s["jitter_rms_s"] ** 2 for s in segs])))
    drift = np.median([s["drift_ppm"] for s in segs])
    n_sorted = report.get("series_sorted", 0)
    return (
        f"timestamps reclocked: interval {iv:.9g} s, jitter RMS {jit:.3g} s "
        f"({jit / iv:.2f} frame), drift {drift:+.3g} ppm "
        f"({sum(s['series'] for s in segs)} series in {len(segs)} segment(s))"
        + (
            f"; the rows of {n_sorted} series were out of sample order and were sorted by t "
            "within their plate"
            if n_sorted
            else ""
        )
    )


def read_trajectory(path: Path | str, timestamps: str = "strict") -> pd.DataFrame:
    """Read and validate a trajectory table (CSV or Parquet); see `validate_trajectory`."""
    path = Path(path)
    return validate_trajectory(load_table(path), path, timestamps=timestamps)


def read_reference(path: Path | str, timestamps: str = "strict") -> pd.DataFrame:
    """Read and validate a reference (LDS) table: ``t``, ``plate``, ``z`` (+ optional segment)."""
    path = Path(path)
    return validate_trajectory(load_table(path), path, timestamps=timestamps)


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
