"""One writer per output: a lock beside every output file or directory.

A command that writes OUT (a file, or a directory such as a campaign folder) holds
``.<OUT stem>.jaxdefl-lock`` in OUT's directory for as long as it runs. The lock is an
``flock`` on that file, so the kernel releases it when its holder dies, even by SIGKILL: a lock
file left behind by a killed process is stale by construction, and the next command takes it
over (and says so). The file holds its holder's pid, host, start time and command, which a
refused command names. A second command on the same OUT is refused (`OutputLocked`, exit 2) or,
with ``wait``, polls until the holder is done (SIGINT/SIGTERM still stop it).

While the lock is held nobody else writes OUT, so the temporary files left in it by a killed
command (`Outputs` writes ``.jaxdefl-tmp-*``, the campaign store ``.results.zarr.tmp``) are
garbage and `output_lock` removes them (`remove_temporaries`): a resumed campaign never keeps
the gigabytes of a killed unit.
"""

from __future__ import annotations

import datetime as _dt
import errno
import json
import os
import re
import shutil
import socket
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from .._errors import ConfigError
from .._signals import check_interrupt

__all__ = ["LOCK_SUFFIX", "OutputLocked", "lock_path", "output_lock", "remove_temporaries"]

LOCK_SUFFIX = ".jaxdefl-lock"
_TMP_PREFIX = ".jaxdefl-tmp-"  # `jaxdefl.io.output.Outputs`' temporary names
# companions a file output writes beside itself (``fit``: OUT_reference.csv, ...)
_COMPANION_TAGS = ("reference", "comparison", "uncertainty", "posterior")


class OutputLocked(ConfigError):
    """Another command holds the output's lock. Exit code 2."""


def lock_path(out: Path | str) -> Path:
    """The lock file of an output: ``.<stem>.jaxdefl-lock`` beside it (its real location:
    a symlinked directory and the path it points to share one lock; ``EST.csv`` and its
    companion ``EST.json`` too)."""
    out = Path(os.path.realpath(Path(out)))
    return out.parent / f".{out.stem or out.name}{LOCK_SUFFIX}"


def _holder_text(info: dict | None) -> str:
    if not info:
        return "another process"
    started = info.get("started")
    when = f", since {started}" if started else ""
    return f"{info.get('command', 'jaxdefl')} (pid {info.get('pid', '?')} on {info.get('host', '?')}{when})"


def _read_holder(path: Path) -> dict | None:
    for _ in range(20):  # the holder writes its line right after it takes the lock
        try:
            text = path.read_text()
        except OSError:
            return None
        if text.strip():
            try:
                info = json.loads(text)
            except ValueError:
                return None
            return info if isinstance(info, dict) else None
        time.sleep(0.01)
    return None


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _try_lock(path: Path) -> int | None:
    """The fd of ``path`` locked by this process, or None when another process holds it."""
    import fcntl

    while True:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            return None
        except OSError as err:
            if err.errno in (errno.ENOLCK, errno.EOPNOTSUPP, errno.ENOSYS):  # no locks on this file system
                return fd
            os.close(fd)
            raise
        # the file may have been removed (released) between open and flock: lock the new one
        try:
            same = os.stat(path).st_ino == os.fstat(fd).st_ino
        except FileNotFoundError:
            same = False
        if same:
            return fd
        os.close(fd)


def _held(path: Path) -> bool:
    """Whether another process holds the lock ``path`` now."""
    import fcntl

    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except BlockingIOError:
        return True
    except OSError:
        return False
    finally:
        os.close(fd)  # closing drops the probe's own shared lock
    return False


def remove_temporaries(out: Path | str) -> list[Path]:
    """Remove the temporary files of killed commands from OUT (call only while holding OUT's
    lock). A directory output: every ``.jaxdefl-tmp-*`` and ``.*.zarr.tmp`` inside it, except
    in a folder where another command holds a lock now (``jaxdefl fit --out OUT/sub/EST.csv``
    while OUT's lock is held); a file output: the ``.jaxdefl-tmp-*`` names of OUT and its
    companions beside it. Returns them."""
    out = Path(out)
    found: list[Path] = []
    if out.is_dir():
        for d, dirs, names in os.walk(out):
            if any(n.endswith(LOCK_SUFFIX) and _held(Path(d) / n) for n in names):
                dirs.clear()  # another command writes here now: its temporaries are alive
                continue
            for n in dirs + names:
                if n.startswith(_TMP_PREFIX) or (n.startswith(".") and n.endswith(".zarr.tmp")):
                    found.append(Path(d) / n)
            dirs[:] = [n for n in dirs if not n.startswith(_TMP_PREFIX)]
    elif out.parent.is_dir():
        stem = re.escape(out.stem)
        pat = re.compile(
            rf"{re.escape(_TMP_PREFIX)}[0-9a-f]{{8}}-(old-)?{stem}(\.[^.]+|_({'|'.join(_COMPANION_TAGS)})\.[^.]+)$"
        )
        found = [p for p in out.parent.iterdir() if pat.match(p.name)]
    removed = []
    for p in sorted(found, key=lambda q: len(q.parts)):
        if not os.path.lexists(p):  # inside a directory removed before
            continue
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p, ignore_errors=True)
        else:
            p.unlink(missing_ok=True)
        removed.append(p)
    return removed


@contextmanager
def output_lock(
    out: Path | str, command: str = "jaxdefl", wait: bool = False, poll_s: float = 0.2, what: str = "--out"
) -> Iterator[Path]:
    """Hold OUT's lock for the block, then remove it; remove killed commands' temporaries first.

    Args:
        out: the output file or directory. command: how the holder is named to others.
        wait: poll until the holder is done instead of refusing. what: how OUT is named.
    Raises:
        OutputLocked: another process holds the lock (and ``wait`` is false).
    """
    out = Path(out)
    path = lock_path(out)
    created = []
    for d in reversed([path.parent, *path.parent.parents]):  # directories made only for the lock
        if not d.exists():
            created.append(d)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd = None
    try:
        waited = False
        while (fd := _try_lock(path)) is None:
            holder = _read_holder(path)
            if not wait:
                raise OutputLocked(
                    f"{what} {out}: in use by {_holder_text(holder)}; "
                    "wait for it to finish or rerun with --wait"
                )
            if not waited:
                print(f"jaxdefl: waiting for {out}: in use by {_holder_text(holder)}", file=sys.stderr)
                waited = True
            check_interrupt()
            time.sleep(poll_s)
        check_interrupt()
        stale = _read_holder(path)
        if stale and stale.get("host") == socket.gethostname() and not _pid_alive(int(stale.get("pid", 0))):
            print(f"jaxdefl: {out}: cleared the stale lock of {_holder_text(stale)}", file=sys.stderr)
        info = {
            "pid": os.getpid(),
            "host": socket.gethostname(),
            "started": _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%d %H:%M:%S UTC"),
            "command": command,
        }
        os.ftruncate(fd, 0)
        os.pwrite(fd, (json.dumps(info) + "\n").encode(), 0)
        remove_temporaries(out)
        yield path
    finally:
        if fd is not None:
            try:
                path.unlink()  # before the unlock: a waiter that opened it retries (`_try_lock`)
            except FileNotFoundError:
                pass
            os.close(fd)
        for d in reversed(created):
            try:
                d.rmdir()  # only if still empty
            except OSError:
                break
