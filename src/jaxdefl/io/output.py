"""Outputs that are whole or absent: every command writes through `Outputs`.

A command plans its outputs first (`Outputs.reserve`: collisions with an input or with another
output are refused before anything is read or computed), then writes each one to a temporary
name in the output's own directory (`Outputs.path`, or the table/JSON/text helpers), and
`Outputs.commit` fsyncs and renames them all into place, with SIGINT and SIGTERM held back for the
few renames so that an interrupt never leaves a set half-committed (and refuses to commit once a
signal arrived, see `jaxdefl._signals`). If anything fails or the
command is interrupted before the commit, `Outputs.discard` removes the temporary files and the
previous outputs stay exactly as they were. Rename is atomic on POSIX, so a reader sees either the
old file or the whole new one, never a truncated one (a full disk fails the write of the
temporary file, not the output).

Tables: the suffix chooses the format (``.csv``, ``.parquet``/``.pq``); CSV times (``t``,
``t_start``, ``t_end``, ``t_update``) are written to the microsecond (``%.6f``: epoch seconds of
1.7e9 keep their microseconds), other floats with ten significant digits; Parquet keeps float64.
"""

from __future__ import annotations

import json
import os
import secrets
import shutil
import signal
from collections.abc import Callable, Iterable
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pandas as pd

from .._errors import ConfigError, Interrupted, JaxdeflError
from .._signals import check_interrupt, note_commit_under_signal

__all__ = [
    "TABLE_SUFFIXES",
    "TIME_COLUMNS",
    "Outputs",
    "atomic_write_bytes",
    "format_table",
    "signals_held",
]

TABLE_SUFFIXES = (".csv", ".parquet", ".pq")
TIME_COLUMNS = ("t", "t_start", "t_end", "t_update")
_TMP_PREFIX = ".jaxdefl-tmp-"


def _same(a: Path, b: Path) -> bool:
    """Whether two paths name the same file (resolved; hard links of an existing file too)."""
    try:
        if a.exists() and b.exists():
            return os.path.samefile(a, b)
    except OSError:
        pass
    return a.resolve() == b.resolve()


@contextmanager
def signals_held():
    """Hold SIGINT and SIGTERM back (delivered when the block ends): a few renames stay together."""
    sigs = {signal.SIGINT, signal.SIGTERM}
    try:
        old = signal.pthread_sigmask(signal.SIG_BLOCK, sigs)
    except (AttributeError, ValueError, OSError):  # not POSIX or not the main thread
        yield
        return
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


def _fsync_path(path: Path) -> None:
    files = [p for p in path.rglob("*") if p.is_file()] if path.is_dir() else [path]
    for f in files:
        fd = os.open(f, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def _fsync_dir(path: Path) -> None:
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        try:
            path.unlink()
        except FileNotFoundError:
            pass


def format_table(df: pd.DataFrame, float_format: str = "%.10g") -> str:
    """CSV text of a table: time columns to the microsecond, other floats with ``float_format``."""
    df = df.copy()
    for c in TIME_COLUMNS:
        if c in df.columns and pd.api.types.is_float_dtype(df[c]):
            a = df[c].to_numpy(np.float64)
            s = np.char.mod("%.6f", a).astype(object)
            s[~np.isfinite(a)] = ""
            df[c] = s
    return df.to_csv(index=False, float_format=float_format)


class Outputs:
    """A set of output files (and directories) committed together, or not at all.

    Args:
        inputs: paths the command reads; no output may be one of them.

    Use as a context manager: the set is committed when the block ends without an exception and
    discarded (temporary files removed, previous outputs untouched) when it raises, including on
    KeyboardInterrupt and the CLI's signal exceptions.
    """

    def __init__(self, inputs: Iterable[Path | str | None] = ()):
        self.inputs = [Path(p) for p in inputs if p is not None]
        self._planned: dict[Path, str] = {}
        self._staged: dict[Path, Path] = {}
        self._token = secrets.token_hex(4)
        self._made: list[Path] = []  # directories made for the outputs: removed if left empty

    # -- planning ---------------------------------------------------------------------------

    def reserve(self, path: Path | str, what: str, suffixes: tuple[str, ...] | None = None) -> Path:
        """Plan an output: refuse a bad suffix, an input path or another output's path.

        Args:
            path: where the output goes.
            what: how the user names it in messages (``--out``, ``the settings sidecar``).
            suffixes: the suffixes allowed (lower case), None for any.
        Raises:
            ConfigError: the suffix is not allowed, the path is an input, an existing directory,
                or another output of the same command.
        """
        path = Path(path)
        if suffixes is not None and path.suffix.lower() not in suffixes:
            got = path.suffix or "no suffix"
            raise ConfigError(f"{what} {path}: expected a name ending in {' or '.join(suffixes)}, got {got}")
        for p in self.inputs:
            if _same(path, p):
                raise ConfigError(f"{what} {path}: is an input of this command; choose another name")
        for p, other in self._planned.items():
            if _same(path, p):
                raise ConfigError(f"{what} {path}: is also where {other} goes; choose another name")
        if path.is_dir() and not (suffixes is None and path.suffix.lower() == ".zarr"):
            raise ConfigError(f"{what} {path}: is an existing directory; expected a file name")
        self._planned[path] = what
        return path

    def planned(self) -> list[Path]:
        return list(self._planned)

    # -- writing ----------------------------------------------------------------------------

    def path(self, final: Path | str) -> Path:
        """The temporary path to write ``final`` to (same directory and suffix); renamed at commit."""
        final = Path(final)
        if final not in self._planned:
            self.reserve(final, str(final))
        if final in self._staged:
            return self._staged[final]
        self._made += [d for d in reversed([final.parent, *final.parent.parents]) if not d.exists()]
        final.parent.mkdir(parents=True, exist_ok=True)
        tmp = final.parent / f"{_TMP_PREFIX}{self._token}-{final.name}"
        self._staged[final] = tmp
        return tmp

    def stage(self, final: Path | str, write: Callable[[Path], object]) -> Path:
        """Any writer that takes a path: ``write(tmp)`` fills the temporary path.

        Raises:
            JaxdeflError: the write failed (a full disk, no permission), naming ``final``.
        """
        check_interrupt()
        final = Path(final)
        tmp = self.path(final)
        try:
            write(tmp)
        except OSError as err:
            _remove(tmp)
            raise JaxdeflError(f"{final}: cannot write ({err.strerror or err})") from None
        return final

    def adopt(self, final: Path | str, tmp: Path | str) -> Path:
        """Take over a file or directory already written at ``tmp`` (same file system as
        ``final``, e.g. a staging directory beside it): renamed to ``final`` at commit."""
        final = Path(final)
        if final not in self._planned:
            self.reserve(final, str(final))
        self._staged[final] = Path(tmp)
        return final

    def bytes(self, final: Path | str, data: bytes) -> Path:
        return self.stage(final, lambda tmp: tmp.write_bytes(data))

    def text(self, final: Path | str, text: str) -> Path:
        return self.bytes(final, text.encode())

    def json(self, final: Path | str, obj) -> Path:
        return self.text(final, json.dumps(obj, indent=2, default=str) + "\n")

    def table(self, final: Path | str, df: pd.DataFrame, float_format: str = "%.10g") -> Path:
        """A table, CSV or Parquet by the suffix (Parquet keeps float64 as is)."""
        final = Path(final)
        if final.suffix.lower() in (".parquet", ".pq"):
            return self.stage(final, lambda tmp: df.to_parquet(tmp, index=False))
        return self.text(final, format_table(df, float_format))

    def figure(self, final: Path | str, fig, **kw) -> Path:
        """A matplotlib figure (format from the final suffix)."""
        final = Path(final)
        fmt = final.suffix.lstrip(".") or "png"
        return self.stage(final, lambda tmp: fig.savefig(tmp, format=fmt, **kw))

    # -- committing -------------------------------------------------------------------------

    def commit(self) -> list[Path]:
        """fsync every staged output, then rename them all into place with signals held."""
        try:
            check_interrupt()  # never commit once a signal arrived
        except Interrupted:
            self.discard()
            raise
        staged = list(self._staged.items())
        try:
            for _, tmp in staged:
                _fsync_path(tmp)
        except OSError as err:
            self.discard()
            raise JaxdeflError(f"{err.filename or tmp}: cannot write ({err.strerror or err})") from None
        old: list[Path] = []
        with signals_held():
            try:
                for final, tmp in staged:
                    if tmp.is_dir() and final.exists():
                        # a directory cannot replace another in one rename: move the old one aside
                        aside = final.parent / f"{_TMP_PREFIX}{self._token}-old-{final.name}"
                        os.replace(final, aside)
                        old.append(aside)
                    os.replace(tmp, final)
                for d in {f.parent for f, _ in staged}:
                    _fsync_dir(d)
                self._staged.clear()
                self._made.clear()
            finally:
                for p in old:
                    _remove(p)
            note_commit_under_signal()
        return [f for f, _ in staged]

    def discard(self) -> None:
        """Remove every temporary file; the previous outputs are left as they were."""
        for tmp in self._staged.values():
            _remove(tmp)
        self._staged.clear()
        for d in reversed(self._made):  # a refused or failed command leaves no empty folder
            try:
                d.rmdir()
            except OSError:
                pass
        self._made.clear()

    def __enter__(self) -> Outputs:
        return self

    def __exit__(self, exc_type, exc, tb) -> bool:
        if exc_type is None:
            self.commit()
        else:
            self.discard()
        return False


def atomic_write_bytes(path: Path | str, data: bytes) -> None:
    """Write one file so that readers see the old file or the whole new one."""
    with Outputs() as outs:
        outs.bytes(path, data)
