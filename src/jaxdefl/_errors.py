"""Errors that reach the user as one line (and an exit code) instead of a traceback."""

from __future__ import annotations

__all__ = ["JaxdeflError", "ConfigError", "InputError", "Interrupted", "ParameterError"]


class JaxdeflError(Exception):
    """Base class: a failure that is explained by its message alone. Exit code 1."""

    exit_code = 1


class ConfigError(JaxdeflError):
    """A bad configuration file, key or command-line argument. Exit code 2."""

    exit_code = 2


class ParameterError(ConfigError):
    """A setting out of its domain, named by its parameter: ``window_s: expected ...``.

    ``problem`` may name other parameters as ``{name}``. A command line shows its flags instead
    (`renamed`: ``--window: expected ...``), a library caller sees the parameter names.
    """

    def __init__(self, params: str | tuple[str, ...], problem: str):
        self.params = (params,) if isinstance(params, str) else tuple(params)
        self.problem = problem
        super().__init__(self._text({}))

    def _text(self, names: dict[str, str]) -> str:
        params = "/".join(names.get(p, p) for p in self.params)
        return f"{params}: {self.problem.format_map(_Names(names))}"

    def renamed(self, names: dict[str, str]) -> ConfigError:
        """The same error with the parameters called by ``names`` (e.g. their flags)."""
        return ConfigError(self._text(names))


class _Names(dict):
    """``{name}`` placeholders: a parameter without another name keeps its own."""

    def __missing__(self, key: str) -> str:
        return key


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
