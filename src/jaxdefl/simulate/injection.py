"""The registry of effects the simulator injects, each at the level where its physics acts.

One entry (`Injection`) per effect id: its physical meaning, its parameters with their units
(`Param`), its validation and its injection. The simulator config spells an effect as an
``[[effect]]`` table (``id`` + parameters); the ``[[change]]`` tables of `jaxdefl monitor`
(`jaxdefl.simulate.schedule`) are another spelling of the same entries (``kind = "stiffness"``
is ``id = "stiffness_change"``), parsed into the same `EffectSpec`. The diagnosis' ids carry the
parameters (and units) that ``jaxdefl diagnose`` fits, so that a diagnosed effect can be simulated
as it was reported (``jaxdefl reconcile`` writes them into ``reconciled.toml``). ``t_rel`` is the
time since the start of the recording (the first frame).

=====================  ===========  ======================================================
id                     level        parameters (units)
=====================  ===========  ======================================================
drift                  range        amplitude_mm (at t_rel = 0, signed), tau_s: every pixel
                                    (or the listed plates' pixels) reads a·exp(−t_rel/τ)
                                    farther: a camera warming up
level_jump             range        t_jump_s, size_mm: a range offset from t_jump_s on
camera_shake           range        rms_mm, corner_hz (a random low-pass motion, seeded by the
                                    simulation's seed) and/or amplitude_mm, freq_hz, phase_rad
                                    (a sway): the camera moves along its optical axis, so every
                                    pixel (plates, floor targets, beam top) reads the same
                                    displacement
outliers               range        fraction, scale_mm: that fraction of the frames read the
                                    listed plates (default: all) N(0, scale²) off
timing_error           timestamps   offset_s, rate_ppm: stamps = t + offset + rate·t_rel
amplitude_modulation   motion       relative_rate_per_s and t_ref_s (A·(1 + r (t_rel − t_ref)))
                                    or depth, freq_hz, phase_rad (A·(1 + m cos(2π f_m t_rel + ψ)))
frequency_modulation   motion       drift_hz_per_s and t_ref_s (f0 + d (t_rel − t_ref)) or
                                    depth_rad, freq_hz, phase_rad (phase + β sin(2π f_m t_rel + ψ))
extra_periodic         motion       freq_hz, amplitude_mm (mid-span), phase_rad: a second
                                    motion of the beam in its deflection shape
harmonic_distortion    motion       order (k), amplitude_mm (mid-span), phase_rad: the load's
                                    k-th harmonic, a cos(k θ(t) − ψ) with θ the load's phase
mode_shape             motion       mode (n), freq_hz, amplitude_mm (at the antinode),
                                    phase_rad: the beam's n-th bending mode of a simply
                                    supported span, a sin(nπ x/L) cos(2π f t_rel + ψ) at a plate
                                    at x (LDS, trajectories, the plates' pixels in frames)
stiffness_change       motion       t_s, duration_s, stiffness_change (relative, −0.01 = 1 %
                                    lost), f0_change, amplitude_change (relative; default from
                                    stiffness_change: f0 × √(1 + s), amplitude × 1/(1 + s)):
                                    a crack; the load's phase stays continuous
debond                 plate        t_s, duration_s, plate, amplitude_change (relative, default
                                    −0.5): the plate's motion about rest scales (trajectories)
clipping               plate        plate, level_mm (signed: + far side, − near side): the
                                    plate's reading saturates at level_mm from its rest
                                    position (trajectories; one table per plate)
sensor_fault           measurement  t_s, duration_s, plate, fault (lost, jump, noise), size (mm
                                    of the z jump, default 1; noise factor, default 3): the live
                                    camera's centroids of that plate (`jaxdefl.simulate.live`)
=====================  ===========  ======================================================

``plates`` (1-based) restricts a range effect to those plates' pixels (default: the whole image).
A scheduled effect (``t_s``) acts from ``t_s`` to the end, or for ``duration_s`` when > 0.
Levels: ``range`` and ``timestamps`` are the camera's (frames), ``motion`` moves the beam (so
the LDS, the trajectories and the frames), ``plate`` one plate's motion (trajectories, LDS),
``measurement`` the live camera's centroids only. Adding an effect = its entry + its test.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .._errors import ConfigError

__all__ = [
    "INJECTABLE",
    "LEVELS",
    "FRAME_LEVELS",
    "REGISTRY",
    "EffectSpec",
    "Injection",
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
    "mode_displacement",
    "active",
    "elapsed",
]

LEVELS = ("range", "timestamps", "motion", "plate", "measurement")
FRAME_LEVELS = ("range", "timestamps", "motion")  # what rendered frames can show


@dataclass(frozen=True)
class Param:
    """One parameter of an effect: its name, unit (or meaning), default (None: required) and,
    for a word parameter, its choices; ``plate``: a plate number 1..n."""

    name: str
    unit: str
    default: float | str | None = None
    choices: tuple[str, ...] = ()
    plate: bool = False


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


@dataclass
class Motion:
    """The beam's motion terms at times ``tau`` (s since the first frame), composed by the motion
    effects: deflection = mean + A(cycles)·amplitude·gain·sin(θ + shift) + Σ extra(θ), with
    θ = 2π f0 τ + load_phase + φ0 and cycles counted on the load's phase; the longitudinal motion
    takes the gain (not the amplitude factor of a stiffness change, which is the deflection's)."""

    tau: np.ndarray
    f0_hz: float
    load_phase: Any = 0.0  # rad added to the load's phase (counted in load cycles)
    amplitude: Any = 1.0  # factor on the mid-span amplitude
    gain: Any = 1.0  # factor on the response (deflection and longitudinal)
    shift: Any = 0.0  # rad added to the response's phase (not counted in cycles)
    extra: list[Callable[[np.ndarray], np.ndarray]] = field(default_factory=list)  # mm at mid-span
    # other bending modes: (shape φ(x / L), displacement q(τ) mm at the antinode), each plate at
    # x moving by φ(x / L) q(τ) (`mode_displacement`)
    modes: list[tuple[Callable[[np.ndarray], np.ndarray], np.ndarray]] = field(default_factory=list)


@dataclass(frozen=True)
class Injection:
    """A registry entry. ``inject`` acts at ``level``:

    - range: ``inject(e, t_rel, n_plates, seed) -> (columns, (frame, column) mm)``, column 0 the
      pixels off the plates, p plate p's;
    - timestamps: ``inject(e, t_rel) -> (frame,) s`` added to the written stamps;
    - motion: ``inject(e, m: Motion)`` composes its terms into ``m``;
    - plate: ``inject(e, t_rel, motion, dx, dy, rest)`` scales (frame, plate) motions in place;
    - measurement: ``inject(e, t_rel, xyz, noise)`` on (frame, plate, 3) centroids in place.

    ``check(e, bad)`` raises ``bad(name, expected)`` for an impossible value; ``resolve(params,
    bad)`` fills defaults derived from other parameters (``bad(name, expected, value)``).
    """

    id: str
    level: str
    params: tuple[Param, ...]
    meaning: str
    inject: Callable
    check: Callable | None = None
    resolve: Callable | None = None

    def param(self, name: str) -> Param | None:
        return next((p for p in self.params if p.name == name), None)


# ---------------------------------------------------------------------------------------------
# scheduled effects: from t_s, to the end or for duration_s


def active(e: EffectSpec, t_rel: np.ndarray) -> np.ndarray:
    """Whether a scheduled effect acts at ``t_rel``."""
    t_rel = np.asarray(t_rel, np.float64)
    on = t_rel >= e.p("t_s")
    if e.p("duration_s") > 0:
        on &= t_rel < e.p("t_s") + e.p("duration_s")
    return on


def elapsed(e: EffectSpec, t_rel: np.ndarray) -> np.ndarray:
    """Time spent under a scheduled effect up to ``t_rel`` (0 before it)."""
    t_rel = np.asarray(t_rel, np.float64)
    end = e.p("t_s") + e.p("duration_s") if e.p("duration_s") > 0 else np.inf
    return np.clip(np.minimum(t_rel, end) - e.p("t_s"), 0.0, None)


_WHEN = (Param("t_s", "s after the recording start"), Param("duration_s", "s (0: to the end)", 0.0))


def _check_when(e, bad):
    if not e.p("t_s") >= 0:
        raise bad("t_s", "a time >= 0 s")
    if not e.p("duration_s") >= 0:
        raise bad("duration_s", "a duration >= 0 s")


def _relative(e, bad, name):
    if not e.p(name) > -1.0:
        raise bad(name, "a relative change > -1")


# ---------------------------------------------------------------------------------------------
# range: the camera's ranges


def _drift(e, trel, n_plates, seed):
    return _columns(e, n_plates, off_plates=True), (e.p("amplitude_mm") * np.exp(-trel / e.p("tau_s")))[
        :, None
    ]


def _level_jump(e, trel, n_plates, seed):
    return _columns(e, n_plates, off_plates=True), (e.p("size_mm") * (trel >= e.p("t_jump_s")))[:, None]


# the camera's random low-pass motion: a sum of sinusoids (spectral representation of a
# first-order low-pass process, S(f) ∝ 1/(1 + (f/f_c)²) on [f_c/20, 10 f_c]), so that its value at
# a time does not depend on how the frames are chunked
_SHAKE_LINES = 64


def shake_displacement(e: EffectSpec, t_rel: np.ndarray, seed: int) -> np.ndarray:
    """(frame,) mm the camera moved along its optical axis at ``t_rel`` (`camera_shake`): the random
    low-pass motion of RMS ``rms_mm`` and corner ``corner_hz`` (deterministic for a seed) plus
    the sway ``amplitude_mm`` cos(2π ``freq_hz`` t_rel + ``phase_rad``)."""
    t_rel = np.asarray(t_rel, np.float64)
    out = e.p("amplitude_mm") * np.cos(2 * math.pi * e.p("freq_hz") * t_rel + e.p("phase_rad"))
    rms, fc = e.p("rms_mm"), e.p("corner_hz")
    if rms > 0 and fc > 0:
        rng = np.random.default_rng([int(seed) & 0xFFFFFFFF, 0x5A4B])
        edges = np.geomspace(fc / 20.0, 10.0 * fc, _SHAKE_LINES + 1)
        f = edges[:-1] * np.exp(rng.uniform(0, 1, _SHAKE_LINES) * np.log(edges[1:] / edges[:-1]))
        power = np.diff(np.arctan(edges / fc))  # ∫ S df over each band
        amp = np.sqrt(2.0 * power / power.sum()) * rng.rayleigh(1.0 / math.sqrt(2.0), _SHAKE_LINES)
        amp *= rms / math.sqrt(0.5 * float(np.sum(amp**2)))  # the realised RMS is rms_mm
        ph = rng.uniform(0, 2 * math.pi, _SHAKE_LINES)
        out = out + np.cos(2 * math.pi * t_rel[:, None] * f[None, :] + ph[None, :]) @ amp
    return out


def _camera_shake(e, trel, n_plates, seed):
    """Every pixel: the camera moves, so the plates and the static scene move together."""
    return np.arange(0, n_plates + 1), shake_displacement(e, trel, seed)[:, None]


def _outliers(e, trel, n_plates, seed):
    """Each (frame, plate) drawn from a hash of its time: chunking moves nothing."""
    cols = _columns(e, n_plates, off_plates=False)
    keys = np.round(trel * 1e6).astype(np.int64).astype(np.uint64)[:, None]
    salt = np.uint64((int(seed) * 0x9E3779B97F4A7C15) & 0xFFFFFFFFFFFFFFFF)
    keys = keys ^ (cols.astype(np.uint64)[None, :] << np.uint64(40)) ^ salt
    hit = _uniform(keys) < e.p("fraction")
    u1, u2 = _uniform(keys ^ np.uint64(0x5851F42D)), _uniform(keys ^ np.uint64(0x14057B7E))
    normal = np.sqrt(-2.0 * np.log1p(-u1)) * np.cos(2 * math.pi * u2)
    return cols, np.where(hit, e.p("scale_mm") * normal, 0.0)


def _columns(e: EffectSpec, n_plates: int, off_plates: bool) -> np.ndarray:
    if e.plates:
        return np.asarray(e.plates)
    return np.arange(0 if off_plates else 1, n_plates + 1)


def _uniform(keys: np.ndarray) -> np.ndarray:
    """Uniform [0, 1) numbers from uint64 keys (splitmix64): a counter-based random stream."""
    with np.errstate(over="ignore"):
        z = keys + np.uint64(0x9E3779B97F4A7C15)
        z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
        z = z ^ (z >> np.uint64(31))
    return (z >> np.uint64(11)).astype(np.float64) * 2.0**-53


# ---------------------------------------------------------------------------------------------
# timestamps


def _timing_error(e, trel):
    return e.p("offset_s") + e.p("rate_ppm") * 1e-6 * trel


# ---------------------------------------------------------------------------------------------
# motion: the beam's


def _amplitude_modulation(e, m: Motion):
    r, tr, d, fm, psi = (e.p(k) for k in ("relative_rate_per_s", "t_ref_s", "depth", "freq_hz", "phase_rad"))
    m.gain = m.gain * (1.0 + r * (m.tau - tr) + d * np.cos(2 * math.pi * fm * m.tau + psi))


def _frequency_modulation(e, m: Motion):
    d, tr, beta, fm, psi = (
        e.p(k) for k in ("drift_hz_per_s", "t_ref_s", "depth_rad", "freq_hz", "phase_rad")
    )
    m.shift = m.shift + math.pi * d * (m.tau - tr) ** 2 + beta * np.sin(2 * math.pi * fm * m.tau + psi)


def _extra_periodic(e, m: Motion):
    f, a, psi, tau = e.p("freq_hz"), e.p("amplitude_mm"), e.p("phase_rad"), m.tau
    m.extra.append(lambda theta: a * np.cos(2 * math.pi * f * tau + psi))


def _harmonic_distortion(e, m: Motion):
    k, a, psi = int(e.p("order")), e.p("amplitude_mm"), e.p("phase_rad")
    m.extra.append(lambda theta: a * np.cos(k * theta - psi))


def _mode_shape(e, m: Motion):
    """The n-th bending mode of a simply supported span: shape sin(nπ x/L), antisymmetric for
    even n (zero at mid-span, so the LDS at mid-span and the load's own shape do not see n = 2)."""
    n, f, a, psi = int(e.p("mode")), e.p("freq_hz"), e.p("amplitude_mm"), e.p("phase_rad")
    m.modes.append(
        (lambda xi: np.sin(n * math.pi * np.asarray(xi, float)), a * np.cos(2 * math.pi * f * m.tau + psi))
    )


def _stiffness_change(e, m: Motion):
    """k ∝ f0² and, under load control, deflection ∝ 1/k: phase continuous at the change."""
    if e.p("f0_change"):
        m.load_phase = m.load_phase + 2 * np.pi * m.f0_hz * e.p("f0_change") * elapsed(e, m.tau)
    m.amplitude = m.amplitude * np.where(active(e, m.tau), 1.0 + e.p("amplitude_change"), 1.0)


def _stiffness_defaults(p: dict, bad) -> dict:
    """f0_change and amplitude_change from stiffness_change s (which is not kept)."""
    s = p.pop("stiffness_change", 0.0)
    if not s > -1:
        raise bad("stiffness_change", "a relative change > -1", s)
    p.setdefault("f0_change", math.sqrt(1.0 + s) - 1.0)
    p.setdefault("amplitude_change", 1.0 / (1.0 + s) - 1.0)
    return p


# ---------------------------------------------------------------------------------------------
# plate and measurement: one plate's motion, the live camera's centroids


def _debond(e, trel, motion, dx, dy, rest):
    f = np.where(active(e, trel), 1.0 + e.p("amplitude_change"), 1.0)
    j = e.p("plate") - 1
    motion[:, j] = f * (motion[:, j] - rest[j]) + rest[j]
    dx[:, j] *= f
    dy[:, j] *= f


def _clipping(e, trel, motion, dx, dy, rest):
    """The camera's reading of the plate saturates (the plate leaves the depth band, the pixels
    read the band's bound): its deflection from rest is clamped at ``level_mm`` on that side."""
    j, lv = e.p("plate") - 1, e.p("level_mm")
    d = motion[:, j] - rest[j]
    motion[:, j] = rest[j] + (np.minimum(d, lv) if lv > 0 else np.maximum(d, lv))


def _sensor_fault(e, trel, xyz, noise):
    on = active(e, trel)
    j = e.p("plate") - 1
    if e.p("fault") == "noise":
        noise[on, j, :] *= e.p("size")
    elif e.p("fault") == "jump":
        xyz[on, j, 2] += e.p("size")
    else:
        xyz[on, j, :] = np.nan


def _fault_defaults(p: dict, bad) -> dict:
    p.setdefault("size", {"lost": 0.0, "jump": 1.0, "noise": 3.0}.get(p.get("fault"), 0.0))
    return p


def _positive(name: str, expected: str):
    def check(e, bad):
        if not e.p(name) > 0:
            raise bad(name, expected)

    return check


def _non_negative(name: str, expected: str):
    def check(e, bad):
        if not e.p(name) >= 0:
            raise bad(name, expected)

    return check


def _checks(*fns):
    def check(e, bad):
        for f in fns:
            f(e, bad)

    return check


def _outlier_check(e, bad):
    if not 0 < e.p("fraction") < 1:
        raise bad("fraction", "a fraction of the frames in (0, 1)")
    _positive("scale_mm", "a scale > 0 mm")(e, bad)


def _shake_check(e, bad):
    for name in ("rms_mm", "corner_hz", "freq_hz"):
        if not e.p(name) >= 0:
            raise bad(name, "a value >= 0")
    if e.p("rms_mm") > 0 and not e.p("corner_hz") > 0:
        raise bad("corner_hz", "a corner frequency > 0 Hz for a random motion (rms_mm > 0)")


def _order_check(e, bad):
    if not (e.p("order") >= 2 and e.p("order") == round(e.p("order"))):
        raise bad("order", "an integer >= 2")


def _mode_check(e, bad):
    if not (e.p("mode") >= 1 and e.p("mode") == round(e.p("mode"))):
        raise bad("mode", "an integer >= 1")
    _positive("freq_hz", "a frequency > 0 Hz")(e, bad)


def _clip_check(e, bad):
    if e.p("level_mm") == 0:
        raise bad("level_mm", "a level != 0 mm (+ far side, − near side)")


def _depth_check(e, bad):
    if abs(e.p("depth")) >= 1:
        raise bad("depth", "a modulation depth |m| < 1")


def _stiffness_check(e, bad):
    _check_when(e, bad)
    _relative(e, bad, "f0_change")
    _relative(e, bad, "amplitude_change")


def _fault_check(e, bad):
    _check_when(e, bad)
    if e.p("fault") == "noise" and e.p("size") < 0:
        raise bad("size", "a noise factor >= 0")


_PHASE = Param("phase_rad", "rad", 0.0)


def _modulation(rate: str, rate_unit: str, depth: str, depth_unit: str) -> tuple[Param, ...]:
    """A modulation's parameters: linear about t_ref_s, or sinusoidal (all default 0)."""
    names = (
        (rate, rate_unit),
        ("t_ref_s", "s"),
        (depth, depth_unit),
        ("freq_hz", "Hz"),
        ("phase_rad", "rad"),
    )
    return tuple(Param(n, u, 0.0) for n, u in names)


_ENTRIES = (
    Injection(
        "drift",
        "range",
        (Param("amplitude_mm", "mm at t_rel = 0, signed"), Param("tau_s", "s")),
        "a camera warming up: every pixel reads a·exp(−t_rel/τ) farther",
        _drift,
        _positive("tau_s", "a time constant > 0 s"),
    ),
    Injection(
        "level_jump",
        "range",
        (Param("t_jump_s", "s"), Param("size_mm", "mm")),
        "a range offset from t_jump_s on",
        _level_jump,
        _non_negative("t_jump_s", "a time >= 0 s"),
    ),
    Injection(
        "camera_shake",
        "range",
        (
            Param("rms_mm", "mm (random low-pass motion)", 0.0),
            Param("corner_hz", "Hz (its corner frequency)", 0.0),
            Param("amplitude_mm", "mm (sway)", 0.0),
            Param("freq_hz", "Hz (sway)", 0.0),
            _PHASE,
        ),
        "the camera moves along its optical axis: every pixel reads the same displacement",
        _camera_shake,
        _shake_check,
    ),
    Injection(
        "outliers",
        "range",
        (Param("fraction", "of the frames"), Param("scale_mm", "mm")),
        "that fraction of the frames read the plates N(0, scale²) off",
        _outliers,
        _outlier_check,
    ),
    Injection(
        "timing_error",
        "timestamps",
        (Param("offset_s", "s", 0.0), Param("rate_ppm", "ppm", 0.0)),
        "the camera's clock: stamps = t + offset + rate·t_rel",
        _timing_error,
    ),
    Injection(
        "amplitude_modulation",
        "motion",
        _modulation("relative_rate_per_s", "1/s", "depth", "relative"),
        "the load's amplitude A·(1 + r (t_rel − t_ref) + m cos(2π f_m t_rel + ψ))",
        _amplitude_modulation,
        _depth_check,
    ),
    Injection(
        "frequency_modulation",
        "motion",
        _modulation("drift_hz_per_s", "Hz/s", "depth_rad", "rad"),
        "the load's phase + π d (t_rel − t_ref)² + β sin(2π f_m t_rel + ψ)",
        _frequency_modulation,
    ),
    Injection(
        "extra_periodic",
        "motion",
        (Param("freq_hz", "Hz"), Param("amplitude_mm", "mm at mid-span"), _PHASE),
        "a second motion of the beam in its deflection shape",
        _extra_periodic,
        _positive("freq_hz", "a frequency > 0 Hz"),
    ),
    Injection(
        "harmonic_distortion",
        "motion",
        (Param("order", "k"), Param("amplitude_mm", "mm at mid-span"), _PHASE),
        "the load's k-th harmonic a cos(k θ − ψ)",
        _harmonic_distortion,
        _order_check,
    ),
    Injection(
        "mode_shape",
        "motion",
        (Param("mode", "n"), Param("freq_hz", "Hz"), Param("amplitude_mm", "mm at the antinode"), _PHASE),
        "the beam's n-th bending mode a sin(nπ x/L) cos(2π f t + ψ)",
        _mode_shape,
        _mode_check,
    ),
    Injection(
        "stiffness_change",
        "motion",
        (
            *_WHEN,
            Param("stiffness_change", "relative", 0.0),
            Param("f0_change", "relative"),
            Param("amplitude_change", "relative"),
        ),
        "a crack: f0 × (1 + f0_change), the deflection amplitude × (1 + amplitude_change)",
        _stiffness_change,
        _stiffness_check,
        _stiffness_defaults,
    ),
    Injection(
        "debond",
        "plate",
        (*_WHEN, Param("plate", "plate number", plate=True), Param("amplitude_change", "relative", -0.5)),
        "a plate no longer following the beam fully: its motion about rest scales",
        _debond,
        _checks(_check_when, lambda e, bad: _relative(e, bad, "amplitude_change")),
    ),
    Injection(
        "clipping",
        "plate",
        (Param("plate", "plate number", plate=True), Param("level_mm", "mm from rest, signed")),
        "a plate's reading saturating at level_mm from its rest position (the depth band's bound)",
        _clipping,
        _clip_check,
    ),
    Injection(
        "sensor_fault",
        "measurement",
        (
            *_WHEN,
            Param("plate", "plate number", plate=True),
            Param("fault", "kind", choices=("lost", "jump", "noise")),
            Param("size", "mm or factor"),
        ),
        "a plate's centroids lost, jumping by size mm in z, or noisier by a factor size",
        _sensor_fault,
        _fault_check,
        _fault_defaults,
    ),
)
REGISTRY: dict[str, Injection] = {e.id: e for e in _ENTRIES}
INJECTABLE = tuple(REGISTRY)


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
        if name == "plates" and entry.level == "range":
            if not isinstance(value, list) or not all(_is_plate(v, n_plates) for v in value):
                raise ConfigError(
                    f"{src}: key '{key}.plates': expected a list of plate numbers 1..{n_plates}, "
                    f"got {value!r}"
                )
            plates = tuple(sorted(set(value)))
            continue
        p = entry.param(name)
        if p is None:
            names = ", ".join([q.name for q in entry.params] + (["plates"] if entry.level == "range" else []))
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
    missing = [p for p in entry.params if p.default is None and p.name not in full]
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
    m = Motion(np.asarray(tau_s, np.float64), 0.0)
    for e in _of(effects, "motion"):
        if e.id == "mode_shape":
            REGISTRY[e.id].inject(e, m)
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


def measurement_faults(effects, t_rel: np.ndarray, xyz, noise) -> None:
    """Sensor faults on the live camera's (frame, plate, 3) centroids and noise, in place."""
    for e in _of(effects, "measurement"):
        REGISTRY[e.id].inject(e, np.asarray(t_rel, np.float64), xyz, noise)
