"""Effects the simulator can inject, at the level where their physics acts (``[[effect]]`` tables).

One entry per effect id of the diagnosis vocabulary that the simulator renders, with the same
parameters (and units) that ``jaxdefl diagnose`` fits, so that a diagnosed effect can be simulated
as it was reported (``jaxdefl reconcile`` writes them into ``reconciled.toml``). ``t_rel`` is the
time since the start of the recording (the first frame).

=====================  ==========  ========================================================
id                     acts on     parameters (units)
=====================  ==========  ========================================================
drift                  range       amplitude_mm (at t_rel = 0, signed), tau_s: every pixel
                                   (or the listed plates' pixels) reads a·exp(−t_rel/τ)
                                   farther: a camera warming up
level_jump             range       t_jump_s, size_mm: a range offset from t_jump_s on
outliers               range       fraction, scale_mm: that fraction of the frames read the
                                   listed plates (default: all) N(0, scale²) off
timing_error           timestamps  offset_s, rate_ppm: stamps = t + offset + rate·t_rel
amplitude_modulation   motion      relative_rate_per_s and t_ref_s (A·(1 + r (t_rel − t_ref)))
                                   or depth, freq_hz, phase_rad (A·(1 + m cos(2π f_m t_rel + ψ)))
frequency_modulation   motion      drift_hz_per_s and t_ref_s (f0 + d (t_rel − t_ref)) or
                                   depth_rad, freq_hz, phase_rad (phase + β sin(2π f_m t_rel + ψ))
extra_periodic         motion      freq_hz, amplitude_mm (mid-span), phase_rad: a second
                                   motion of the beam in its deflection shape
harmonic_distortion    motion      order (k), amplitude_mm (mid-span), phase_rad: the load's
                                   k-th harmonic, a cos(k θ(t) − ψ) with θ the load's phase
=====================  ==========  ========================================================

``plates`` (1-based) restricts a range effect to those plates' pixels (default: the whole image).
Motion effects move the beam (and so the LDS); range and timestamp effects are the camera's.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from .._errors import ConfigError

__all__ = [
    "INJECTABLE",
    "EffectSpec",
    "make_spec",
    "parse_effects",
    "motion_modulations",
    "range_offset",
    "stamp_times",
]

# id -> (level, required parameters, optional parameters with defaults)
_KINDS: dict[str, tuple[str, tuple[str, ...], dict[str, float]]] = {
    "drift": ("range", ("amplitude_mm", "tau_s"), {}),
    "level_jump": ("range", ("t_jump_s", "size_mm"), {}),
    "outliers": ("range", ("fraction", "scale_mm"), {}),
    "timing_error": ("timestamps", (), {"offset_s": 0.0, "rate_ppm": 0.0}),
    "amplitude_modulation": (
        "motion",
        (),
        {"relative_rate_per_s": 0.0, "t_ref_s": 0.0, "depth": 0.0, "freq_hz": 0.0, "phase_rad": 0.0},
    ),
    "frequency_modulation": (
        "motion",
        (),
        {"drift_hz_per_s": 0.0, "t_ref_s": 0.0, "depth_rad": 0.0, "freq_hz": 0.0, "phase_rad": 0.0},
    ),
    "extra_periodic": ("motion", ("freq_hz", "amplitude_mm"), {"phase_rad": 0.0}),
    "harmonic_distortion": ("motion", ("order", "amplitude_mm"), {"phase_rad": 0.0}),
}
INJECTABLE = tuple(_KINDS)


@dataclass(frozen=True)
class EffectSpec:
    """One ``[[effect]]`` table: the id, its parameters (floats) and the plates it touches."""

    id: str
    parameters: tuple[tuple[str, float], ...] = ()  # (name, value) pairs: the spec stays hashable
    plates: tuple[int, ...] = ()

    @property
    def level(self) -> str:
        return _KINDS[self.id][0]

    def p(self, name: str) -> float:
        return float(dict(self.parameters)[name])

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {"id": self.id, **{k: float(v) for k, v in self.parameters}}
        if self.plates:
            d["plates"] = list(self.plates)
        return d


def parse_effects(src: str, tables: Any, n_plates: int) -> tuple[EffectSpec, ...]:
    """Validate the ``[[effect]]`` array of a config; one-line `ConfigError` naming the key."""
    if not isinstance(tables, list) or not all(isinstance(e, dict) for e in tables):
        raise ConfigError(f"{src}: key 'effect': expected an array of tables [[effect]], got {tables!r}")
    out = []
    for i, raw in enumerate(tables):
        key = f"effect[{i + 1}]"
        eid = raw.get("id")
        if eid not in _KINDS:
            raise ConfigError(
                f"{src}: key '{key}.id': expected one of {', '.join(INJECTABLE)} (effects the simulator "
                f"can inject), got {eid!r}"
            )
        _, required, optional = _KINDS[eid]
        params: dict[str, float] = dict(optional)
        plates: tuple[int, ...] = ()
        for name, value in raw.items():
            if name == "id":
                continue
            if name == "plates":
                if not isinstance(value, list) or not all(
                    isinstance(v, int) and not isinstance(v, bool) and 1 <= v <= n_plates for v in value
                ):
                    raise ConfigError(
                        f"{src}: key '{key}.plates': expected a list of plate numbers 1..{n_plates}, "
                        f"got {value!r}"
                    )
                plates = tuple(sorted(set(value)))
                continue
            if name not in required and name not in optional:
                names = ", ".join((*required, *optional, "plates"))
                raise ConfigError(
                    f"{src}: key '{key}.{name}': unknown parameter of {eid}; expected one of {names}"
                )
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ConfigError(f"{src}: key '{key}.{name}': expected a number, got {value!r}")
            params[name] = float(value)
        missing = [n for n in required if n not in params]
        if missing:
            raise ConfigError(f"{src}: key '{key}': {eid} needs {', '.join(missing)}")
        out.append(make_spec(eid, params, plates, src, key))
    return tuple(out)


def make_spec(
    eid: str,
    params: dict[str, float],
    plates: tuple[int, ...] = (),
    src: str = "<effect>",
    key: str = "effect",
) -> EffectSpec:
    """A checked spec: the optional parameters filled with their defaults."""
    _, required, optional = _KINDS[eid]
    full = {**optional, **{k: float(v) for k, v in params.items()}}
    missing = [n for n in required if n not in full]
    if missing:
        raise ConfigError(f"{src}: key '{key}': {eid} needs {', '.join(missing)}")
    spec = EffectSpec(eid, tuple(full.items()), tuple(plates))
    _check(src, key, spec)
    return spec


def _check(src: str, key: str, e: EffectSpec) -> None:
    def bad(name: str, expected: str):
        return ConfigError(f"{src}: key '{key}.{name}': expected {expected}, got {e.p(name):g}")

    if e.id == "drift" and not e.p("tau_s") > 0:
        raise bad("tau_s", "a time constant > 0 s")
    if e.id == "level_jump" and not e.p("t_jump_s") >= 0:
        raise bad("t_jump_s", "a time >= 0 s")
    if e.id == "outliers":
        if not 0 < e.p("fraction") < 1:
            raise bad("fraction", "a fraction of the frames in (0, 1)")
        if not e.p("scale_mm") > 0:
            raise bad("scale_mm", "a scale > 0 mm")
    if e.id == "harmonic_distortion" and not (e.p("order") >= 2 and e.p("order") == round(e.p("order"))):
        raise bad("order", "an integer >= 2")
    if e.id == "amplitude_modulation" and abs(e.p("depth")) >= 1:
        raise bad("depth", "a modulation depth |m| < 1")
    if e.id in ("extra_periodic",) and not e.p("freq_hz") > 0:
        raise bad("freq_hz", "a frequency > 0 Hz")


def _of(effects, level: str):
    return [e for e in effects if e.level == level]


def motion_modulations(
    effects, t0_s: float
) -> tuple[Callable | None, Callable | None, list[tuple[Callable, float]]]:
    """(gain g(t), phase shift Δφ(t), additive terms) of the motion effects, functions of epoch
    time; an additive term is (f(t, θ) -> mid-span mm, 0) with θ the load's phase."""
    gain = shift = None
    extra: list[Callable] = []
    for e in _of(effects, "motion"):
        if e.id == "amplitude_modulation":
            names = ("relative_rate_per_s", "t_ref_s", "depth", "freq_hz", "phase_rad")
            r, tr, m, fm, psi = (e.p(k) for k in names)

            def gain(t, r=r, tr=tr, m=m, fm=fm, psi=psi, prev=gain):
                g = 1.0 + r * (t - t0_s - tr) + m * np.cos(2 * math.pi * fm * (t - t0_s) + psi)
                return g if prev is None else g * prev(t)
        elif e.id == "frequency_modulation":
            names = ("drift_hz_per_s", "t_ref_s", "depth_rad", "freq_hz", "phase_rad")
            d, tr, beta, fm, psi = (e.p(k) for k in names)

            def shift(t, d=d, tr=tr, beta=beta, fm=fm, psi=psi, prev=shift):
                u = t - t0_s - tr
                s = math.pi * d * u**2 + beta * np.sin(2 * math.pi * fm * (t - t0_s) + psi)
                return s if prev is None else s + prev(t)
        elif e.id == "extra_periodic":
            f, a, psi = e.p("freq_hz"), e.p("amplitude_mm"), e.p("phase_rad")
            extra.append(lambda t, theta, f=f, a=a, psi=psi: a * np.cos(2 * math.pi * f * (t - t0_s) + psi))
        elif e.id == "harmonic_distortion":
            k, a, psi = int(e.p("order")), e.p("amplitude_mm"), e.p("phase_rad")
            extra.append(lambda t, theta, k=k, a=a, psi=psi: a * np.cos(k * theta - psi))
    return gain, shift, extra


def range_offset(effects, t_s: np.ndarray, t0_s: float, n_plates: int, seed: int) -> np.ndarray:
    """(frame, plates + 1) range offsets (mm): column 0 for pixels off the plates, column p for
    plate p's pixels. Outliers hit (frame, plate) pairs independently, at random but reproducibly
    (a hash of the seed, the frame's time and the plate)."""
    t_s = np.asarray(t_s, np.float64)
    off = np.zeros((t_s.size, n_plates + 1))
    trel = t_s - t0_s
    for e in _of(effects, "range"):
        cols = np.arange(n_plates + 1) if not e.plates else np.asarray(e.plates)
        if e.id == "drift":
            d = e.p("amplitude_mm") * np.exp(-trel / e.p("tau_s"))
        elif e.id == "level_jump":
            d = e.p("size_mm") * (trel >= e.p("t_jump_s"))
        else:  # outliers: each (frame, plate) drawn from a hash of its time: chunking moves nothing
            cols = np.arange(1, n_plates + 1) if not e.plates else np.asarray(e.plates)
            keys = np.round(trel * 1e6).astype(np.int64).astype(np.uint64)[:, None]
            salt = np.uint64((int(seed) * 0x9E3779B97F4A7C15) & 0xFFFFFFFFFFFFFFFF)
            keys = keys ^ (cols.astype(np.uint64)[None, :] << np.uint64(40)) ^ salt
            hit = _uniform(keys) < e.p("fraction")
            u1, u2 = _uniform(keys ^ np.uint64(0x5851F42D)), _uniform(keys ^ np.uint64(0x14057B7E))
            normal = np.sqrt(-2.0 * np.log1p(-u1)) * np.cos(2 * math.pi * u2)
            off[:, cols] += np.where(hit, e.p("scale_mm") * normal, 0.0)
            continue
        off[:, cols] += d[:, None]
    return off


def _uniform(keys: np.ndarray) -> np.ndarray:
    """Uniform [0, 1) numbers from uint64 keys (splitmix64): a counter-based random stream."""
    with np.errstate(over="ignore"):
        z = keys + np.uint64(0x9E3779B97F4A7C15)
        z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
        z = z ^ (z >> np.uint64(31))
    return (z >> np.uint64(11)).astype(np.float64) * 2.0**-53


def stamp_times(effects, t_s: np.ndarray, t0_s: float) -> np.ndarray:
    """The timestamps the camera writes for true frame times ``t_s`` (timing errors)."""
    out = np.asarray(t_s, np.float64).copy()
    for e in _of(effects, "timestamps"):
        out = out + e.p("offset_s") + e.p("rate_ppm") * 1e-6 * (np.asarray(t_s) - t0_s)
    return out
