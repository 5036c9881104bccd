"""Errors that reach the user as one line (and an exit code) instead of a traceback."""

from __future__ import annotations

__all__ = ["JaxdeflError", "ConfigError", "InputError", "Interrupted"]


class JaxdeflError(Exception):
    """Base class: a failure that is explained by its message alone. Exit code 1."""

    exit_code = 1


class ConfigError(JaxdeflError):
    """A bad configuration file, key or command-line argument. Exit code 2."""

    exit_code = 2


class InputError(JaxdeflError):
    """An input file that does not follow its contract (names file, row, column). Exit code 2."""

    exit_code = 2


class Interrupted(BaseException):  # noqa: N818 - it is the event, not an error
    """SIGINT or SIGTERM arrived: the command stops, its temporary files are removed.

    A BaseException, like KeyboardInterrupt, so that no ``except Exception`` on the way up
    mistakes it for a failure to be reported (or swallowed) as a status.
    """

    def __init__(self, signum: int):
        import signal

        super().__init__(signal.Signals(signum).name)
        self.signum = signum
        self.exit_code = 128 + signum
