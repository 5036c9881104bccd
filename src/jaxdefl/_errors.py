"""Errors that reach the user as one line (and an exit code) instead of a traceback."""

from __future__ import annotations

__all__ = [
    "JaxdeflError",
    "ConfigError",
    "InputError",
    "Interrupted",
    "ParameterError",
    "MESSAGE_CHARS",
    "echo",
    "one_line",
]

# An error message is one line of at most this many characters, whatever the input held.
MESSAGE_CHARS = 600


def echo(value, limit: int = 60) -> str:
    """``repr(value)`` of input echoed in a message, cut to ``limit`` characters: a cell padded
    with a million zero bytes is shown by its start and its length."""
    text = repr(value.item() if hasattr(value, "item") and callable(value.item) else value)
    if len(text) <= limit:
        return text
    n = len(value) if isinstance(value, str | bytes) else len(text)
    return f"{text[: limit - 3]}... ({n:,} characters)"


def one_line(message: str, limit: int = MESSAGE_CHARS) -> str:
    """A message as one line of at most ``limit`` characters (control characters escaped)."""
    text = str(message)
    if len(text) > 4 * limit:
        text = text[: 4 * limit]  # before escaping: a message of gigabytes is never copied whole
        cut = True
    else:
        cut = False
    text = "".join(c if c.isprintable() else repr(c)[1:-1] for c in " ".join(text.splitlines()))
    if cut or len(text) > limit:
        return f"{text[: limit - 40]}... (message cut at {limit} characters)"
    return text


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
