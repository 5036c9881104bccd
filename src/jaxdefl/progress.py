"""The commands' console, progress and closing lines (on stderr).

On a terminal (stdout and stderr both TTYs) progress is a transient rich bar or spinner. Off it
(a pipe, a log file, a batch job) it is plain lines on stderr, at most one every `PLAIN_EVERY_S`
seconds and at least that often while a step runs: a long step is never silent, a log is never
flooded, and no control characters are written. Every command ends with one ``jaxdefl CMD:
wrote ...`` line (`wrote`).
"""

from __future__ import annotations

import sys
import threading
import time
from contextlib import contextmanager

from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)

__all__ = ["PLAIN_EVERY_S", "NoProgress", "console", "interactive", "progress_bar", "status", "wrote"]

# soft_wrap: a long line is never broken at 80 columns in a log (a terminal wraps it itself)
console = Console(stderr=True, soft_wrap=True)
PLAIN_EVERY_S = 5.0  # seconds between plain progress lines off a terminal


def interactive() -> bool:
    """Live bars only when both stdout and stderr are terminals (a piped stdout means a log)."""
    try:
        return sys.stdout.isatty() and sys.stderr.isatty()
    except (AttributeError, ValueError):  # a closed or replaced stream
        return False


def _say(line: str) -> None:
    print(line, file=sys.stderr, flush=True)


def _duration(s: float) -> str:
    return f"{s:.0f} s" if s < 120 else f"{s / 60:.1f} min"


class PlainProgress:
    """`rich.progress.Progress`'s add_task/advance/update as plain lines on stderr: every
    ``every_s`` seconds, each unfinished task's description, done/total, time elapsed and left."""

    def __init__(self, every_s: float | None = None):
        self.every_s = PLAIN_EVERY_S if every_s is None else every_s
        self.tasks: dict[int, dict] = {}
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def __enter__(self) -> PlainProgress:
        self._thread = threading.Thread(target=self._loop, name="jaxdefl-progress", daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *exc) -> bool:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        return False

    def add_task(self, description: str, total: float | None = None, **_) -> int:
        with self._lock:
            k = len(self.tasks)
            self.tasks[k] = dict(description=description, total=total, completed=0.0, t0=time.monotonic())
        return k

    def advance(self, task: int, advance: float = 1) -> None:
        with self._lock:
            self.tasks[task]["completed"] += advance

    def update(self, task: int, *, description=None, total=None, completed=None, advance=None, **_) -> None:
        with self._lock:
            t = self.tasks[task]
            for key, v in (("description", description), ("total", total), ("completed", completed)):
                if v is not None:
                    t[key] = v
            if advance is not None:
                t["completed"] += advance

    def line(self, t: dict) -> str:
        elapsed = time.monotonic() - t["t0"]
        total, done = t["total"], t["completed"]
        if not total:
            return f"{t['description']} ({_duration(elapsed)})"
        text = (
            f"{t['description']}: {done:.0f}/{total:.0f} ({100 * done / total:.0f} %), {_duration(elapsed)}"
        )
        if 0 < done < total:
            text += f", about {_duration(elapsed * (total - done) / done)} left"
        return text

    def _loop(self) -> None:
        while not self._stop.wait(self.every_s):
            with self._lock:
                lines = [
                    self.line(t) for t in self.tasks.values() if not t["total"] or t["completed"] < t["total"]
                ]
            for line in lines:
                _say(line)


class NoProgress:
    """A progress bar that shows nothing (progress disabled)."""

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False

    def add_task(self, *a, **k):
        return 0

    def advance(self, *a, **k):
        pass

    def update(self, *a, **k):
        pass


def progress_bar(enabled: bool = True):
    """A progress display with `rich.progress.Progress`'s add_task/advance/update: a transient
    rich bar (description, done/total, time elapsed and left) on a terminal, `PlainProgress`
    lines off it, nothing when not ``enabled``."""
    if not enabled:
        return NoProgress()
    if not interactive():
        return PlainProgress()
    return Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        console=console,
        transient=True,
    )


class _Status:
    def __init__(self, update):
        self.update = update


@contextmanager
def status(message: str):
    """A step without a count: a rich spinner on a terminal; off it, the message at once and
    again (with the time taken) every `PLAIN_EVERY_S` seconds while the step runs. Yields an
    object whose ``update(message)`` names the current sub-step."""
    if interactive():
        with console.status(message) as s:
            yield _Status(lambda m: s.update(m))
        return
    _say(message)
    with PlainProgress() as bar:
        task = bar.add_task(message)

        def update(m: str) -> None:
            if m != bar.tasks[task]["description"]:
                _say(m)
                bar.update(task, description=m)

        yield _Status(update)


def wrote(command: str, *paths, detail: str = "") -> None:
    """The closing line of a command: ``jaxdefl CMD: wrote PATH, PATH (detail)``, on stderr."""
    where = ", ".join(str(p) for p in paths)
    console.print(
        f"jaxdefl {command}: wrote {where}" + (f" ({detail})" if detail else ""),
        markup=False,
        highlight=False,
        soft_wrap=True,
    )
