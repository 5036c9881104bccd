"""SIGINT and SIGTERM: the command stops at its next safe point, and never commits after one.

The CLI installs the handler for the length of a command. The handler only records the signal:
raising from a signal handler lands wherever the interpreter happens to be, and there it is
either lost (Python drops exceptions raised in garbage-collection callbacks and ``__del__``;
JAX runs one on every collection) or fatal (inside a C++ callback of XLA, an exception aborts
the process). Long loops call `check_interrupt` between their steps (fit blocks, diagnosis
rounds, frame chunks, bulk units), `jaxdefl.io.output.Outputs` calls it before every write and
before its commit, and the CLI never exits 0 once a signal arrived. A second signal is an
insistence: the default action ends the process at once (temporary files may stay behind under
their hidden names; outputs are never partial, since only a commit renames them into place).
"""

from __future__ import annotations

import os
import signal
import threading
from contextlib import contextmanager

from ._errors import Interrupted

__all__ = [
    "check_interrupt",
    "committed_under_signal",
    "handle_signals",
    "note_commit_under_signal",
    "received",
]

_received: list[int] = []
_committed: list[bool] = []


def received() -> int | None:
    """The first signal received while `handle_signals` was active, else None."""
    return _received[0] if _received else None


def check_interrupt() -> None:
    """Raise `Interrupted` if a signal was received (a safe point of a long command)."""
    if _received:
        raise Interrupted(_received[0])


def note_commit_under_signal() -> None:
    """Called by a commit while signals are held: a signal pending now arrived during the
    commit, so the command's outputs are whole and new (the message says so)."""
    try:
        pending = signal.sigpending()
    except (AttributeError, OSError):
        return
    if pending & {signal.SIGINT, signal.SIGTERM}:
        _committed.append(True)


def note_finished() -> None:
    """The command returned having written its outputs: a signal still pending now came after
    they were committed, so they are whole and new (the message says so)."""
    _committed.append(True)


def committed_under_signal() -> bool:
    return bool(_committed)


def _on_signal(signum, frame) -> None:
    if _received:  # the second one: end now, by the signal's default action
        signal.signal(signum, signal.SIG_DFL)
        os.kill(os.getpid(), signum)
        return
    _received.append(signum)


@contextmanager
def handle_signals():
    """Turn SIGINT/SIGTERM into `Interrupted` for the block (main thread only), then restore."""
    _received.clear()
    _committed.clear()
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    for s in previous:
        signal.signal(s, _on_signal)
    try:
        yield
    finally:
        for s, h in previous.items():
            signal.signal(s, h)
