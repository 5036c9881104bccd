"""The simulator's injection machinery: an ``[[effect]]`` table -> a checked `EffectSpec`, and the
specs injected level by level.

The effects themselves (their meaning, parameters with units, levels and injections) are the
vocabulary's (`jaxdefl.effects`: one module per id, listed in the docs' effects reference); here
`REGISTRY` holds those the simulator injects (`jaxdefl.effects.INJECTABLE`). The simulator config
spells an effect as an ``[[effect]]`` table (``id`` + parameters); the ``[[change]]`` tables of
`jaxdefl monitor` (`jaxdefl.simulate.schedule`) are another spelling of the same entries
(``kind = "stiffness"`` is the crack's id), parsed into the same `EffectSpec`. The diagnosis' ids
carry the parameters (and units) that ``jaxdefl diagnose`` fits, so that a diagnosed effect can be
simulated as it was reported (each entry's ``from_diagnosis``; ``jaxdefl reconcile`` writes them
into ``reconciled.toml``). ``t_rel`` is the time since the start of the recording (the first
frame).

``plates`` (1-based) restricts a range effect to those plates' pixels (default: the whole image),
and a measurement effect that takes them to those plates' centroids.
A scheduled effect (``t_s``) acts from ``t_s`` to the end, or for ``duration_s`` when > 0.
Levels: ``range`` and ``timestamps`` are the camera's (frames), ``motion`` moves the beam (so
the LDS, the trajectories and the frames), ``plate`` one plate's motion (trajectories, LDS),
``sampling`` the instants a camera's reading averages the true positions over (`sampled`:
frames, each of a ToF camera's taps; the live camera; reconcile's twin) and ``measurement`` a
camera's centroids and their noise (`measurement_faults`: where trajectories are measured
without frames, the live camera and reconcile's twin).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from .._errors import ConfigError
from ..effects import FRAME_LEVELS, INJECTABLE, LEVELS, Entry, Motion, Param, Reading
from ..effects import REGISTRY as VOCABULARY
from ..effects._entry import active, elapsed
from ..effects.camera_shake import displacement as shake_displacement

__all__ = [
    "INJECTABLE",
    "LEVELS",
    "FRAME_LEVELS",
    "REGISTRY",
    "EffectSpec",
    "Entry",
    "Motion",
    "Param",
    "make_spec",
    "parse_effects",
    "parse_table",
    "motion_terms",
    "shake_displacement",
    "motion_modulations",
    "range_offset",
    "stamp_times",
    "plate_motion",
    "measurement_faults",
    "sampling_offsets",
    "sampled",
    "mode_displacement",
    "active",
    "elapsed",
]

REGISTRY: dict[str, Entry] = {eid: VOCABULARY[eid] for eid in INJECTABLE}


@dataclass(frozen=True)
class EffectSpec:
    """One effect of a config: the id, its parameters and the plates it touches.

    Parameters are (name, value) pairs (the spec stays hashable): floats, a plate number as an
    int, a word (``fault``) as a str; they also read as attributes (``spec.f0_change``)."""

    id: str
    parameters: tuple[tuple[str, Any], ...] = ()
    plates: tuple[int, ...] = ()

    @property
    def level(self) -> str:
        return REGISTRY[self.id].level

    def p(self, name: str) -> Any:
        v = dict(self.parameters)[name]
        return v if isinstance(v, (str, int)) else float(v)

    def __getattr__(self, name: str) -> Any:
        if name.startswith("__"):
            raise AttributeError(name)
        params = dict(object.__getattribute__(self, "parameters"))
        if name in params:
            return params[name]
        raise AttributeError(f"{type(self).__name__} {self.id!r} has no parameter {name!r}")

    def to_dict(self) -> dict[str, Any]:
        """The ``[[effect]]`` table this spec is read from (`parse_effects` reads it back)."""
        d: dict[str, Any] = {"id": self.id, **dict(self.parameters)}
        if self.plates:
            d["plates"] = list(self.plates)
        return d


# ---------------------------------------------------------------------------------------------
# parsing and validation


def parse_effects(
    src: str,
    tables: Any,
    n_plates: int,
    name: str = "effect",
    id_key: str = "id",
    ids: dict[str, str] | None = None,
    first: int = 1,
) -> tuple[EffectSpec, ...]:
    """Validate an array of ``[[name]]`` tables (``[[effect]]`` by default) into specs; one-line
    `ConfigError` naming the key (``name[i]``, counted from ``first``). ``ids`` maps the values
    of ``id_key`` to registry ids (a spelling: `jaxdefl.simulate.schedule`'s ``[[change]]``)."""
    if not isinstance(tables, list) or not all(isinstance(e, dict) for e in tables):
        raise ConfigError(f"{src}: key '{name}': expected an array of tables [[{name}]], got {tables!r}")
    ids = ids if ids is not None else {i: i for i in INJECTABLE}
    out = []
    for i, raw in enumerate(tables):
        key = f"{name}[{i + first}]"
        value = raw.get(id_key)
        if value not in ids:
            what = " (effects the simulator can inject)" if name == "effect" else ""
            raise ConfigError(
                f"{src}: key '{key}.{id_key}': expected one of {', '.join(ids)}{what}, got {value!r}"
            )
        params = {k: v for k, v in raw.items() if k != id_key}
        out.append(parse_table(src, key, ids[value], params, n_plates))
    return tuple(out)


def parse_table(src: str, key: str, eid: str, raw: dict, n_plates: int) -> EffectSpec:
    """One table's parameters (everything but its id) -> a checked `EffectSpec`; errors name
    ``key`` (``effect[1]``, ``change[0]``)."""
    entry = REGISTRY[eid]
    params: dict[str, Any] = {}
    plates: tuple[int, ...] = ()
    for name, value in raw.items():
        if name == "plates" and entry.takes_plates:
            if not isinstance(value, list) or not all(_is_plate(v, n_plates) for v in value):
                raise ConfigError(
                    f"{src}: key '{key}.plates': expected a list of plate numbers 1..{n_plates}, "
                    f"got {value!r}"
                )
            plates = tuple(sorted(set(value)))
            continue
        p = entry.param(name)
        if p is None:
            names = ", ".join([q.name for q in entry.params] + (["plates"] if entry.takes_plates else []))
            raise ConfigError(
                f"{src}: unknown key '{key}.{name}': not a parameter of {eid}; expected one of {names}"
            )
        if p.plate:
            if not _is_plate(value, n_plates):
                raise ConfigError(
                    f"{src}: key '{key}.{name}': expected a plate number in 1..{n_plates}, got {value!r}"
                )
        elif p.choices:
            if value not in p.choices:
                raise ConfigError(
                    f"{src}: key '{key}.{name}': expected one of {', '.join(p.choices)}, got {value!r}"
                )
        elif isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise ConfigError(f"{src}: key '{key}.{name}': expected a number, got {value!r}")
        params[name] = value
    return make_spec(eid, params, plates, src, key)


def _is_plate(v: Any, n_plates: int) -> bool:
    return isinstance(v, int) and not isinstance(v, bool) and 1 <= v <= n_plates


def make_spec(
    eid: str,
    params: dict[str, Any],
    plates: tuple[int, ...] = (),
    src: str = "<effect>",
    key: str = "effect",
) -> EffectSpec:
    """A checked spec: the defaults filled in (derived ones by the entry's ``resolve``)."""
    entry = REGISTRY[eid]

    def bad(name: str, expected: str, value: Any = None):
        v = spec.p(name) if value is None else value
        shown = f"{v:g}" if isinstance(v, float) else repr(v)
        return ConfigError(f"{src}: key '{key}.{name}': expected {expected}, got {shown}")

    full = {p.name: p.default for p in entry.params if p.default is not None}
    for k, v in params.items():
        p = entry.param(k)
        full[k] = v if p is not None and (p.plate or p.choices) else float(v)
    if entry.resolve:
        full = entry.resolve(full, bad)
    missing = [p for p in entry.params if p.default is None and not p.optional and p.name not in full]
    if missing:
        p = missing[0]
        raise ConfigError(f"{src}: key '{key}.{p.name}': {eid} needs {p.name} ({p.unit})")
    spec = EffectSpec(
        eid, tuple((p.name, full[p.name]) for p in entry.params if p.name in full), tuple(plates)
    )
    if entry.check:
        entry.check(spec, bad)
    return spec


# ---------------------------------------------------------------------------------------------
# injection, level by level


def _of(effects, level: str):
    return [e for e in effects if e.level == level]


def motion_terms(effects, tau_s: np.ndarray, f0_hz: float) -> Motion:
    """The motion effects' terms at ``tau_s`` (s since the first frame), composed in order."""
    m = Motion(np.asarray(tau_s, np.float64), float(f0_hz))
    for e in _of(effects, "motion"):
        REGISTRY[e.id].inject(e, m)
    return m


def motion_modulations(
    effects, t0_s: float, f0_hz: float = 0.0
) -> tuple[Callable | None, Callable | None, list[Callable]]:
    """(gain g(t), phase shift Δφ(t), additive terms f(t, θ) -> mid-span mm) of the motion
    effects as functions of epoch time, for a model that has no load cycles of its own (the
    reconciliation's twin): a stiffness change's amplitude is in the gain, its phase in the shift
    (``f0_hz``: the load's frequency it scales). None where no effect acts."""
    motion = _of(effects, "motion")
    if not motion:
        return None, None, []

    def at(t):
        return motion_terms(motion, np.asarray(t, np.float64) - t0_s, f0_hz)

    def gain(t):
        m = at(t)
        return m.gain * m.amplitude

    def shift(t):
        m = at(t)
        return m.shift + m.load_phase

    def additive(e):
        return lambda t, theta: motion_terms((e,), np.asarray(t, np.float64) - t0_s, f0_hz).extra[0](theta)

    extra = [additive(e) for e in motion if motion_terms((e,), np.zeros(1), f0_hz).extra]
    return gain, shift, extra


def mode_displacement(effects, tau_s: np.ndarray, xi: np.ndarray) -> np.ndarray | None:
    """(frame, plate) mm the bending modes (`mode_shape`) move plates at ``xi`` = x / span, at
    ``tau_s`` (s since the first frame); None when no mode acts."""
    m = motion_terms(effects, tau_s, 0.0)  # only a bending mode adds to ``modes``
    if not m.modes:
        return None
    return sum(q[:, None] * shape(xi)[None, :] for shape, q in m.modes)


def range_offset(effects, t_s: np.ndarray, t0_s: float, n_plates: int, seed: int) -> np.ndarray:
    """(frame, plates + 1) range offsets (mm): column 0 for pixels off the plates, column p for
    plate p's pixels. Outliers hit (frame, plate) pairs independently, at random but reproducibly
    (a hash of the seed, the frame's time and the plate)."""
    t_s = np.asarray(t_s, np.float64)
    off = np.zeros((t_s.size, n_plates + 1))
    trel = t_s - t0_s
    for e in _of(effects, "range"):
        cols, d = REGISTRY[e.id].inject(e, trel, n_plates, seed)
        off[:, cols] += d
    return off


def stamp_times(effects, t_s: np.ndarray, t0_s: float) -> np.ndarray:
    """The timestamps the camera writes for true frame times ``t_s`` (timing errors)."""
    out = np.asarray(t_s, np.float64).copy()
    for e in _of(effects, "timestamps"):
        out = out + REGISTRY[e.id].inject(e, np.asarray(t_s) - t0_s)
    return out


def plate_motion(effects, t_rel: np.ndarray, motion, dx, dy, rest) -> None:
    """One plate's own motion (debonding) on the (frame, plate) motions, in place."""
    for e in _of(effects, "plate"):
        REGISTRY[e.id].inject(e, np.asarray(t_rel, np.float64), motion, dx, dy, rest)


def measurement_faults(
    effects,
    t_rel: np.ndarray,
    xyz,
    noise,
    *,
    plates=None,
    sigma=None,
    arg=None,
    seed: int = 0,
) -> None:
    """The measurement effects (a noise level with the motion, a lattice, sensor faults) on a
    camera's (frame, plate, 3) centroids before noise and their noise draw, in place (the
    reading is ``xyz + noise``), in their entries' ``order``: see `jaxdefl.effects.Reading`
    (``plates``: the columns' plate numbers, default 1..n; ``sigma``: the noise's standard
    deviation; ``arg``: (frame, plate) each plate's motion angle, 0 at the peak of its z)."""
    acting = sorted(_of(effects, "measurement"), key=lambda e: REGISTRY[e.id].order)
    if not acting:
        return
    cols = np.arange(1, np.shape(xyz)[1] + 1) if plates is None else np.asarray(plates, int)
    r = Reading(np.asarray(t_rel, np.float64), xyz, noise, cols, sigma, arg, int(seed))
    for e in acting:
        REGISTRY[e.id].inject(e, r)


def sampling_offsets(effects, t_rel: np.ndarray) -> np.ndarray | None:
    """(frame, k) s: the instants after each frame's time whose true positions a camera's
    reading averages (every sum of one instant of each sampling effect), or None when none
    acts."""
    t_rel = np.asarray(t_rel, np.float64)
    out = None
    for e in _of(effects, "sampling"):
        d = np.asarray(REGISTRY[e.id].inject(e, t_rel), np.float64)
        d = np.broadcast_to(d, (t_rel.size, d.shape[-1]))
        out = d if out is None else (out[:, :, None] + d[:, None, :]).reshape(t_rel.size, -1)
    return out


def sampled(effects, t_s: np.ndarray, t0_s: float, positions: Callable[[np.ndarray], np.ndarray]):
    """``positions(t_s)`` (frame first) as a camera reads them: the mean over the sampling
    effects' instants after each frame's time (`sampling_offsets`); ``positions(t_s)`` itself
    when none acts."""
    t_s = np.asarray(t_s, np.float64)
    offs = sampling_offsets(effects, t_s - t0_s)
    if offs is None:
        return positions(t_s)
    return sum(positions(t_s + offs[:, k]) for k in range(offs.shape[1])) / offs.shape[1]
