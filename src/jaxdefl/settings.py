"""The settings of a command, frozen and validated whole before any input is read.

A setting out of its domain raises `jaxdefl.ParameterError` naming the parameter
(``window_s: expected a positive length in s, got -1``); the command line maps the parameter
names to its flags (`FIT_FLAGS`: ``--window: ...``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from ._errors import ParameterError

__all__ = ["FIT_FLAGS", "FitSettings"]

# parameter -> flag of `jaxdefl fit`
FIT_FLAGS = {
    "window_s": "--window",
    "step_s": "--step",
    "axes": "--axes",
    "fmin_hz": "--fmin",
    "fmax_hz": "--fmax",
    "oversampling": "--oversampling",
    "fap_max": "--fap-max",
    "posterior": "--posterior",
    "timestamps": "--timestamps",
    "posterior_noise": "--posterior-noise",
    "model": "--model",
    "harmonics": "--harmonics",
    "lines": "--lines",
}
AXES = ("z", "x", "y")


def _got(v) -> str:
    """A value as the user gave it, safe inside a `ParameterError` problem (braces escaped)."""
    text = f"{v:g}" if isinstance(v, float) else repr(v) if isinstance(v, str) else str(v)
    return text.replace("{", "{{").replace("}", "}}")


@dataclass(frozen=True)
class FitSettings:
    """Everything `jaxdefl fit` does besides its input and output paths.

    ``axes`` may be given as a comma list (``"z,x"``); None fits z, x, y as present. ``spec``
    is the signal model the settings name (`jaxdefl.fit.signal_model`).
    """

    window_s: float | None = None
    step_s: float | None = None
    axes: tuple[str, ...] | str | None = None
    fmin_hz: float | None = None
    fmax_hz: float | None = None
    oversampling: float = 5.0
    fap_max: float = 0.01
    posterior: int | None = None
    timestamps: str = "strict"
    posterior_noise: str = "ar1"
    model: str = "harmonic"
    harmonics: int = 1
    lines: int = 1
    spec: Any = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        def bad(name: str, expected: str):
            return ParameterError(name, f"expected {expected}, got {_got(getattr(self, name))}")

        for name in ("window_s", "step_s", "fmin_hz", "fmax_hz", "oversampling", "fap_max"):
            v = getattr(self, name)
            if v is not None and not math.isfinite(v):
                raise bad(name, "a finite number")
        if self.window_s is not None and not self.window_s > 0:
            raise bad("window_s", "a positive length in s")
        if self.step_s is not None and self.window_s is None:
            raise ParameterError("step_s", "needs {window_s}")
        if self.step_s is not None and not self.step_s > 0:
            raise bad("step_s", "a positive length in s")
        if self.fmin_hz is not None and self.fmin_hz < 0:
            raise bad("fmin_hz", "a frequency >= 0 Hz")
        if self.fmax_hz is not None and not self.fmax_hz > 0:
            raise bad("fmax_hz", "a positive frequency in Hz")
        if self.fmin_hz is not None and self.fmax_hz is not None and not self.fmin_hz < self.fmax_hz:
            raise ParameterError(
                ("fmin_hz", "fmax_hz"),
                f"expected fmin < fmax, got {_got(self.fmin_hz)} and {_got(self.fmax_hz)}",
            )
        if not self.oversampling >= 1:
            raise bad("oversampling", "a factor >= 1")
        if not 0 < self.fap_max <= 1:
            raise bad("fap_max", "a probability in (0, 1]")
        if self.posterior is not None and self.posterior < 0:
            raise bad("posterior", "a number of windows >= 0")
        if self.posterior_noise not in ("ar1", "white"):
            raise bad("posterior_noise", "ar1 or white")
        if self.axes is not None:
            given = self.axes
            axes = tuple(a.strip() for a in (given.split(",") if isinstance(given, str) else given))
            axes = tuple(a for a in axes if a)
            if not axes or any(a not in AXES for a in axes):
                raise ParameterError("axes", f"expected a comma list of z, x, y; got {_got(given)}")
            object.__setattr__(self, "axes", axes)
        from .fit import signal_model
        from .io import check_timestamp_policy

        check_timestamp_policy(self.timestamps)
        # signal models other than the thesis' (the posterior check knows only the default model)
        spec = signal_model(self.model, self.harmonics, self.lines)
        if self.posterior is not None and not spec.is_default:
            raise ParameterError(
                "posterior",
                "checks the σ's of the default model only; drop it, or drop {model}/{harmonics}/{lines}",
            )
        object.__setattr__(self, "spec", spec)
