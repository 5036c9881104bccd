"""Changes scheduled in a simulation config: ``[[change]]`` tables (for `jaxdefl monitor`).

Each change starts at ``t_s`` seconds after the start of the recording and lasts to its end
(or for ``duration_s`` when that is > 0):

=============  ===========================================================================
kind           keys and effect
=============  ===========================================================================
stiffness      ``stiffness_change`` (relative, −0.01 = 1 % of the stiffness lost): the beam's
               natural scaling k ∝ f0² and, under load control, deflection ∝ 1/k give
               f0 × √(1 + s) and every plate's amplitude × 1/(1 + s); ``f0_change`` and
               ``amplitude_change`` (relative) override either. Seen by every plate, the LDS
               and rendered frames (phase continuous).
debond         ``plate``, ``amplitude_change`` (relative, default −0.5): the plate no longer
               follows the beam fully; its motion about rest scales. Trajectories only.
sensor_fault   ``plate``, ``fault``: ``lost`` (no samples), ``jump`` (z steps by ``size``
               mm, default 1.0) or ``noise`` (its noise × ``size``, default 3.0). The live
               camera's measurements only (`jaxdefl.simulate.live`).
=============  ===========================================================================
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from .._errors import ConfigError

__all__ = ["Change", "CHANGE_KINDS", "SENSOR_FAULTS", "parse_changes", "frequency_phase", "amplitude_factor"]

CHANGE_KINDS = ("stiffness", "debond", "sensor_fault")
SENSOR_FAULTS = ("lost", "jump", "noise")
_KEYS = {
    "stiffness": ("kind", "t_s", "duration_s", "stiffness_change", "f0_change", "amplitude_change"),
    "debond": ("kind", "t_s", "duration_s", "plate", "amplitude_change"),
    "sensor_fault": ("kind", "t_s", "duration_s", "plate", "fault", "size"),
}


@dataclass(frozen=True)
class Change:
    """One scheduled change (see the module doc); times relative to the recording start."""

    kind: str
    t_s: float
    duration_s: float = 0.0  # 0: to the end of the recording
    plate: int = 0
    f0_change: float = 0.0
    amplitude_change: float = 0.0
    fault: str = ""
    size: float = 0.0

    def to_table(self) -> dict[str, Any]:
        """The ``[[change]]`` table this change is read from (`parse_changes` reads it back)."""
        keys = {"stiffness": ("f0_change", "amplitude_change"), "debond": ("plate", "amplitude_change")}
        own = keys.get(self.kind, ("plate", "fault", "size"))
        return {"kind": self.kind, "t_s": self.t_s, "duration_s": self.duration_s} | {
            k: getattr(self, k) for k in own
        }

    def active(self, tau_s: np.ndarray) -> np.ndarray:
        """Whether the change acts at times ``tau_s`` (s after the recording start)."""
        tau_s = np.asarray(tau_s, np.float64)
        on = tau_s >= self.t_s
        if self.duration_s > 0:
            on &= tau_s < self.t_s + self.duration_s
        return on

    def elapsed(self, tau_s: np.ndarray) -> np.ndarray:
        """Time spent under the change up to ``tau_s`` (0 before it)."""
        tau_s = np.asarray(tau_s, np.float64)
        end = self.t_s + self.duration_s if self.duration_s > 0 else np.inf
        return np.clip(np.minimum(tau_s, end) - self.t_s, 0.0, None)


def _number(src: str, key: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ConfigError(f"{src}: key {key!r}: expected a number, got {value!r}")
    return float(value)


def parse_changes(src: str, raw: Any, n_plates: int) -> tuple[Change, ...]:
    """Validate the ``[[change]]`` array of tables of a config.

    Raises:
        ConfigError: not an array of tables, an unknown kind or key, a bad value (named).
    """
    if not isinstance(raw, list) or not all(isinstance(c, dict) for c in raw):
        raise ConfigError(f"{src}: key 'change': expected an array of tables [[change]], got {raw!r}")
    out = []
    for i, c in enumerate(raw):
        where = f"change[{i}]"
        kind = c.get("kind")
        if kind not in CHANGE_KINDS:
            raise ConfigError(
                f"{src}: key '{where}.kind': expected one of {', '.join(CHANGE_KINDS)}, got {kind!r}"
            )
        for key in c:
            if key not in _KEYS[kind]:
                raise ConfigError(
                    f"{src}: unknown key '{where}.{key}' for kind {kind}; "
                    f"expected one of {', '.join(_KEYS[kind])}"
                )
        if "t_s" not in c:
            raise ConfigError(
                f"{src}: key '{where}.t_s': expected the start time in s after the recording start"
            )
        t_s = _number(src, f"{where}.t_s", c["t_s"])
        dur = _number(src, f"{where}.duration_s", c.get("duration_s", 0.0))
        if t_s < 0 or dur < 0:
            raise ConfigError(
                f"{src}: key '{where}.t_s': expected times >= 0 s, got t_s={t_s:g}, duration_s={dur:g}"
            )
        kw: dict[str, Any] = dict(kind=kind, t_s=t_s, duration_s=dur)
        if kind != "stiffness":
            plate = c.get("plate")
            if isinstance(plate, bool) or not isinstance(plate, int) or not 1 <= plate <= n_plates:
                raise ConfigError(
                    f"{src}: key '{where}.plate': expected a plate number in 1..{n_plates}, got {plate!r}"
                )
            kw["plate"] = plate
        if kind == "stiffness":
            s = _number(src, f"{where}.stiffness_change", c.get("stiffness_change", 0.0))
            if not -1.0 < s:
                raise ConfigError(
                    f"{src}: key '{where}.stiffness_change': expected a relative change > -1, got {s:g}"
                )
            kw["f0_change"] = _number(src, f"{where}.f0_change", c.get("f0_change", math.sqrt(1.0 + s) - 1.0))
            kw["amplitude_change"] = _number(
                src, f"{where}.amplitude_change", c.get("amplitude_change", 1.0 / (1.0 + s) - 1.0)
            )
            if kw["f0_change"] <= -1.0:
                raise ConfigError(
                    f"{src}: key '{where}.f0_change': expected a relative change > -1, "
                    f"got {kw['f0_change']:g}"
                )
        elif kind == "debond":
            kw["amplitude_change"] = _number(
                src, f"{where}.amplitude_change", c.get("amplitude_change", -0.5)
            )
        else:
            fault = c.get("fault")
            if fault not in SENSOR_FAULTS:
                raise ConfigError(
                    f"{src}: key '{where}.fault': expected one of {', '.join(SENSOR_FAULTS)}, got {fault!r}"
                )
            kw["fault"] = fault
            kw["size"] = _number(
                src, f"{where}.size", c.get("size", {"lost": 0.0, "jump": 1.0, "noise": 3.0}[fault])
            )
            if fault == "noise" and kw["size"] < 0:
                raise ConfigError(
                    f"{src}: key '{where}.size': expected a noise factor >= 0, got {kw['size']:g}"
                )
        if kw.get("amplitude_change", 0.0) <= -1.0:
            raise ConfigError(
                f"{src}: key '{where}.amplitude_change': expected a relative change > -1, "
                f"got {kw['amplitude_change']:g}"
            )
        out.append(Change(**kw))
    return tuple(out)


def frequency_phase(changes: tuple[Change, ...], f0_hz: float, tau_s: np.ndarray) -> np.ndarray:
    """Loading phase 2π ∫ f dt (rad) at ``tau_s`` with the stiffness changes (continuous)."""
    tau_s = np.asarray(tau_s, np.float64)
    phase = 2 * np.pi * f0_hz * tau_s
    for c in changes:
        if c.kind == "stiffness" and c.f0_change:
            phase = phase + 2 * np.pi * f0_hz * c.f0_change * c.elapsed(tau_s)
    return phase


def amplitude_factor(changes: tuple[Change, ...], tau_s: np.ndarray, plate: int = 0) -> np.ndarray:
    """Factor on the motion at ``tau_s``: ``plate`` 0, the beam's (stiffness changes); a plate
    number (1-based), that plate's own (debonding) on top of the beam's."""
    tau_s = np.asarray(tau_s, np.float64)
    out = np.ones_like(tau_s)
    for c in changes:
        if (c.kind == "stiffness" and plate == 0) or (c.kind == "debond" and c.plate == plate and plate > 0):
            out = out * np.where(c.active(tau_s), 1.0 + c.amplitude_change, 1.0)
    return out
