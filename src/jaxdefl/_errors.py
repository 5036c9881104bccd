"""Errors that reach the user as one line (and an exit code) instead of a traceback."""

from __future__ import annotations

__all__ = ["JaxdeflError", "ConfigError", "InputError"]


class JaxdeflError(Exception):
    """Base class: a failure that is explained by its message alone. Exit code 1."""

    exit_code = 1


class ConfigError(JaxdeflError):
    """A bad configuration file, key or command-line argument. Exit code 2."""

    exit_code = 2


class InputError(JaxdeflError):
    """An input file that does not follow its contract (names file, row, column). Exit code 2."""

    exit_code = 2
