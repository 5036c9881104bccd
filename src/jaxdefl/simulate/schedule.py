"""``[[change]]`` tables: the scheduled spelling of registry effects (for `jaxdefl monitor`).

A ``[[change]]`` table is an ``[[effect]]`` table of `jaxdefl.simulate.injection`'s registry
with ``kind`` for ``id``; it parses into the same `EffectSpec` (and `SimConfig.to_dict` writes it
back as ``[[effect]]``). Each change starts at ``t_s`` seconds after the start of the recording
and lasts to its end (or for ``duration_s`` when that is > 0):

=============  ================  ========================================================
kind           effect id         keys and effect
=============  ================  ========================================================
stiffness      stiffness_change  ``stiffness_change`` (relative, −0.01 = 1 % of the
                                 stiffness lost): the beam's natural scaling k ∝ f0² and,
                                 under load control, deflection ∝ 1/k give f0 × √(1 + s)
                                 and every plate's amplitude × 1/(1 + s); ``f0_change`` and
                                 ``amplitude_change`` (relative) override either. Seen by
                                 every plate, the LDS and rendered frames (phase continuous).
debond         debond            ``plate``, ``amplitude_change`` (relative, default −0.5):
                                 the plate no longer follows the beam fully; its motion
                                 about rest scales. Trajectories only.
sensor_fault   sensor_fault      ``plate``, ``fault``: ``lost`` (no samples), ``jump`` (z
                                 steps by ``size`` mm, default 1.0) or ``noise`` (its noise
                                 × ``size``, default 3.0). The live camera's measurements
                                 only (`jaxdefl.simulate.live`).
=============  ================  ========================================================
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..effects import debond, sensor_fault, stiffness_change
from .injection import EffectSpec, motion_terms, parse_effects

__all__ = [
    "CHANGE_KINDS",
    "CHANGE_IDS",
    "SENSOR_FAULTS",
    "parse_changes",
    "frequency_phase",
    "amplitude_factor",
]

# a [[change]]'s kind -> its id: a crack is spelled "stiffness", the others by their ids
CHANGE_IDS = {"stiffness": stiffness_change.ENTRY.id} | {
    e.id: e.id for e in (debond.ENTRY, sensor_fault.ENTRY)
}
CHANGE_KINDS = tuple(CHANGE_IDS)
SENSOR_FAULTS = sensor_fault.ENTRY.param("fault").choices


def parse_changes(src: str, raw: Any, n_plates: int) -> tuple[EffectSpec, ...]:
    """Validate the ``[[change]]`` array of tables of a config: the registry's specs.

    Raises:
        ConfigError: not an array of tables, an unknown kind or key, a bad value (named).
    """
    return parse_effects(src, raw, n_plates, name="change", id_key="kind", ids=CHANGE_IDS, first=0)


def frequency_phase(changes: tuple[EffectSpec, ...], f0_hz: float, tau_s: np.ndarray) -> np.ndarray:
    """Loading phase 2π ∫ f dt (rad) at ``tau_s`` with the stiffness changes (continuous)."""
    tau_s = np.asarray(tau_s, np.float64)
    return 2 * np.pi * f0_hz * tau_s + motion_terms(changes, tau_s, f0_hz).load_phase


def amplitude_factor(changes: tuple[EffectSpec, ...], tau_s: np.ndarray) -> np.ndarray:
    """Factor of the stiffness changes on the beam's deflection amplitude at ``tau_s``."""
    tau_s = np.asarray(tau_s, np.float64)
    return np.ones_like(tau_s) * motion_terms(changes, tau_s, 0.0).amplitude
