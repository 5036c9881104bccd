"""SIGINT and SIGTERM: the command stops at once, or at the next safe point, and never commits.

The CLI installs `on_signal` for the length of a command. It records the signal and raises
`Interrupted` where the interpreter happens to be. That raise can be lost: Python drops
exceptions raised in garbage-collection callbacks and ``__del__`` methods (JAX runs one on
every collection). The record cannot be lost, so the places that make work permanent look at it
first: `jaxdefl.io.output.Outputs.commit` refuses to commit, the bulk runner stops before its next
unit, and the CLI never exits 0 once a signal arrived.
"""

from __future__ import annotations

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


def committed_under_signal() -> bool:
    return bool(_committed)


def _on_signal(signum, frame) -> None:
    _received.append(signum)
    # later signals are ignored so that the clean-up of the first one runs to its end
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    raise Interrupted(signum)


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
