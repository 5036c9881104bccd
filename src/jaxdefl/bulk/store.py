"""Unit outputs that survive a SIGKILL: atomic files and manifests written last.

A unit writes its outputs into ``DIR/units/<unit id>/`` through temporary files renamed into
place (rename is atomic on POSIX), then writes ``manifest.json`` the same way. A unit is
finished exactly when its manifest exists, names the same input digests, config hash and
package version, and every output it lists still has the recorded size and digest (for a
directory output such as a Zarr store: the same number of files and bytes, since hashing
gigabytes of frames on every rerun would cost more than it protects). Anything
else (no manifest, a stale one, a missing or altered output) is recomputed; a half-written file
is never read because it only ever exists under a temporary name.
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
import time
import traceback
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pandas as pd

from .. import __version__
from .._errors import JaxdeflError
from ..io.output import atomic_write_bytes
from ..status import UnitStatus

__all__ = [
    "atomic_write_bytes",
    "atomic_write_text",
    "csv_text",
    "digest_path",
    "digest_text",
    "is_finished",
    "read_manifest",
    "run_unit",
    "write_manifest",
]

MANIFEST = "manifest.json"


def digest_text(text: str) -> str:
    """sha256 of a string (config hashes)."""
    return hashlib.sha256(text.encode()).hexdigest()


def digest_path(path: Path) -> str:
    """sha256 of a file's bytes, or of a directory's files (names and bytes, sorted)."""
    path = Path(path)
    h = hashlib.sha256()
    files = sorted(p for p in path.rglob("*") if p.is_file()) if path.is_dir() else [path]
    for f in files:
        if path.is_dir():
            h.update(str(f.relative_to(path)).encode())
        with open(f, "rb") as fh:
            for block in iter(lambda: fh.read(1 << 20), b""):
                h.update(block)
    return h.hexdigest()


def atomic_write_text(path: Path, text: str) -> None:
    atomic_write_bytes(path, text.encode())


def csv_text(df: pd.DataFrame, float_format: str = "%.10g") -> str:
    """The text of ``df.to_csv(index=False, float_format=float_format)``, made column by column.

    pandas formats every cell through Python calls of its own (a unit's windows table took ~0.1 s,
    holding the GIL that the other unit's thread waits for); here a column is one list of strings
    and Python's csv writer (which pandas uses too) joins them: the same text (the test compares
    it with pandas') in a few times less time. Tables with columns of other dtypes than numpy's
    float, int, bool, object and pandas' strings go to pandas itself.
    """
    cols = []
    for name in df.columns:
        col = df[name]
        dtype = col.dtype
        if isinstance(dtype, pd.StringDtype):  # pandas' strings: as objects, missing as ""
            values, kind = col.to_numpy(dtype=object, na_value=None), "O"
        elif isinstance(dtype, np.dtype) and dtype.kind in "fiubO":
            values, kind = col.to_numpy(), dtype.kind
        else:
            return df.to_csv(index=False, float_format=float_format)
        if kind == "f":
            text = [float_format % v for v in values.tolist()]
            for i in np.flatnonzero(np.isnan(values)).tolist():
                text[i] = ""
        elif kind == "O":
            text = values.tolist()
            for i in np.flatnonzero(pd.isna(values)).tolist():
                text[i] = ""
        else:
            text = [str(v) for v in values.tolist()]
        cols.append(text)
    if not cols:
        return df.to_csv(index=False, float_format=float_format)
    buf = io.StringIO()
    out = csv.writer(buf, lineterminator="\n")
    out.writerow([str(c) for c in df.columns])
    out.writerows(zip(*cols, strict=True))
    return buf.getvalue()


def _signature(path: Path) -> dict:
    if path.is_dir():
        files = [f for f in path.rglob("*") if f.is_file()]
        return {"files": len(files), "bytes": sum(f.stat().st_size for f in files)}
    return {"sha256": digest_path(path), "bytes": path.stat().st_size}


def write_manifest(
    unit_dir: Path,
    unit_id: str,
    inputs: dict,
    config_hash: str,
    outputs: list[str],
    status: str,
    reason: str = "",
    seconds: float = 0.0,
    extra: dict | None = None,
) -> dict:
    """Record a finished unit; call after its outputs are in place. Returns the manifest."""
    unit_dir = Path(unit_dir)
    man = {
        "unit": unit_id,
        "inputs": inputs,
        "config_hash": config_hash,
        "version": __version__,
        "outputs": {name: _signature(unit_dir / name) for name in outputs},
        "status": status,
        "reason": reason,
        "seconds": round(seconds, 3),
        **(extra or {}),
    }
    atomic_write_text(unit_dir / MANIFEST, json.dumps(man, indent=1, sort_keys=True))
    return man


def read_manifest(unit_dir: Path) -> dict | None:
    try:
        return json.loads((Path(unit_dir) / MANIFEST).read_text())
    except (OSError, ValueError):
        return None


def is_finished(unit_dir: Path, inputs: dict, config_hash: str) -> dict | None:
    """The manifest of a finished, fresh unit, else None."""
    man = read_manifest(unit_dir)
    if man is None or man.get("inputs") != inputs or man.get("config_hash") != config_hash:
        return None
    if man.get("version") != __version__:
        return None
    for name, meta in man.get("outputs", {}).items():
        p = Path(unit_dir) / name
        if not p.exists():
            return None
        if "files" in meta or p.is_dir():
            if _signature(p) != meta:
                return None
        elif p.stat().st_size != meta["bytes"] or digest_path(p) != meta["sha256"]:
            return None
    return man


def run_unit(
    unit_dir: Path,
    unit_id: str,
    inputs: dict,
    config_hash: str,
    work: Callable[[Path], list[str]],
    extra: dict | None = None,
) -> dict:
    """Run one resumable unit: skip it when finished and fresh, else ``work(unit_dir)``.

    ``work`` writes its outputs atomically into ``unit_dir`` and returns their names. A failure
    is recorded in the manifest with its reason (the message of a ``JaxdeflError``, else the
    unit id and the exception's last line) and never raised: one bad unit never stops a
    campaign. Returns the manifest (with ``"skipped": True`` when nothing was recomputed).
    """
    unit_dir = Path(unit_dir)
    done = is_finished(unit_dir, inputs, config_hash)
    if done is not None:
        return {**done, "skipped": True}
    unit_dir.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    try:
        status, reason, names = UnitStatus.OK, "", list(work(unit_dir))
    except JaxdeflError as err:
        status, reason, names = UnitStatus.FAILED, str(err), []
    except Exception as err:
        last = traceback.format_exception_only(type(err), err)[-1].strip()
        status, reason, names = UnitStatus.FAILED, f"{unit_id}: {last}", []
    seconds = time.perf_counter() - t0
    extra = {**(extra or {}), "computed_at": time.time()}
    return write_manifest(unit_dir, unit_id, inputs, config_hash, names, status, reason, seconds, extra)
