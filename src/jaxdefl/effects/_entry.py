"""What one effect module declares (`Entry`), the pieces its injection and translation share
(`Param`, `Motion`, `Report`, the scheduled-effect helpers) and the parameter checks."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .._sensors import SENSORS

__all__ = [
    "Bench",
    "FRAME_LEVELS",
    "LEVELS",
    "PHASE",
    "SENSORS",
    "WHEN",
    "Entry",
    "Motion",
    "Param",
    "Reading",
    "Report",
    "active",
    "all_of",
    "bench_load",
    "bench_plates",
    "check_when",
    "elapsed",
    "modulation_params",
    "non_negative",
    "positive",
    "relative",
    "spec_values",
]

LEVELS = ("range", "timestamps", "motion", "plate", "measurement", "sampling")
FRAME_LEVELS = ("range", "timestamps", "motion", "sampling")  # what rendered frames can show


@dataclass(frozen=True)
class Param:
    """One parameter of an effect: its name, unit (or meaning), default (None: required, unless
    ``optional``: then left out of the spec, and the injection says what stands for it) and, for
    a word parameter, its choices; ``plate``: a plate number 1..n."""

    name: str
    unit: str
    default: float | str | None = None
    choices: tuple[str, ...] = ()
    plate: bool = False
    optional: bool = False


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
    # x moving by φ(x / L) q(τ) (`jaxdefl.simulate.injection.mode_displacement`)
    modes: list[tuple[Callable[[np.ndarray], np.ndarray], np.ndarray]] = field(default_factory=list)


@dataclass
class Reading:
    """What the measurement-level effects act on, in place: a camera's plate centroids before
    their noise and the noise drawn for them (the reading is ``xyz + noise``).

    Attributes:
        t_rel: (frame,) s since the first frame.
        xyz: (frame, plate, 3) mm, the centroids (x, y, z) before the noise.
        noise: (frame, plate, 3) mm, the noise drawn for them.
        plates: (plate,) the 1-based plate numbers of the columns.
        sigma: the noise's standard deviation (mm), broadcastable to ``noise``; None: not known.
        arg: (frame, plate) rad, each plate's motion angle (0 at the peak of its z, growing with
            time: z = mean + A cos(arg)); None: not known.
        seed: the simulation's seed (the effects' own draws).
    """

    t_rel: np.ndarray
    xyz: np.ndarray
    noise: np.ndarray
    plates: np.ndarray
    sigma: np.ndarray | None = None
    arg: np.ndarray | None = None
    seed: int = 0

    def columns(self, plates: tuple[int, ...]) -> np.ndarray:
        """The columns of ``plates`` (all of them for none) that the reading holds."""
        if not plates:
            return np.arange(self.plates.size)
        return np.flatnonzero(np.isin(self.plates, plates))

    def noise_sigma(self, col: int, axis: int) -> np.ndarray | None:
        """(frame,) the noise's standard deviation of one column and axis, or None."""
        if self.sigma is None:
            return None
        return np.broadcast_to(np.asarray(self.sigma, np.float64), self.noise.shape)[:, col, axis]


@dataclass(frozen=True)
class Report:
    """A diagnosed effect (an entry of DIAG.json's ``effects``) as an entry's ``from_diagnosis``
    reads it: the fitted values ``p`` (name -> value), ``detail``, ``kind``, ``plates``, the
    record's ``duration_s``, whether it was seen on at least half of the plates (``whole``: a
    camera effect) and the range-to-centroid ``calibration`` (or None)."""

    p: dict[str, Any]
    detail: dict[str, Any]
    kind: str | None
    plates: tuple[int, ...]
    duration_s: float
    whole: bool = False
    calibration: Any = None

    @classmethod
    def of(cls, e: dict, duration_s: float, calibration=None, n_plates: int = 0) -> Report:
        """The report of one DIAG.json effect entry (parameters as ``{"value": ...}`` or bare)."""
        p = {k: (v.get("value") if isinstance(v, dict) else v) for k, v in e.get("parameters", {}).items()}
        detail = e.get("detail") or {}
        plates = tuple(int(x) for x in e.get("plates", ()))
        whole = n_plates > 0 and len(plates) * 2 >= n_plates
        return cls(
            p, detail, p.get("kind") or detail.get("kind"), plates, float(duration_s), whole, calibration
        )

    def per_range(self, sizes: dict, value: float) -> float:
        """A trajectory-level size as the range size that makes it: the median over the effect's
        series ({"4z": size, ...}) of size / gain, where the range-to-centroid gain is large
        enough to tell; ``value`` without a calibration or per-series sizes."""
        if self.calibration is None or not sizes:
            return value
        ratios = []
        for key, size in sizes.items():
            plate, axis = int(key[:-1]), key[-1]
            g = self.calibration.gain_of(plate, axis)
            if abs(g) >= 0.5:
                ratios.append(float(size) / g)
        return float(np.median(ratios)) if ratios else value


@dataclass(frozen=True)
class Bench:
    """How the concealed benchmark (`jaxdefl.simulate.effects`) renders one drawn effect ``e`` (a
    dict: id, kind, parameters, plates, axes) into a recording ``base`` (its `CleanRecording`:
    the clean motion ``base.motion``, noise ``base.sigma`` and ``base.eps``, the beam's shape and
    statics, f0, phase, seed). Every hook is optional and acts at its stage, in this order:

    - ``load(base, e) -> params``: the load's modulation it is, as the registry's parameters
      (`jaxdefl.simulate.injection.motion_modulations`: the beam moves, the LDS sees it);
    - ``taps(base, e) -> offsets``: s after each frame's time; the camera reads the mean of the
      positions at them;
    - ``clock(base, e, t) -> t_tab``: the table's stamps for true frame times ``t``;
    - ``camera(base, e, pos, trel)``: on the clean camera positions (frame, plate, axis) in
      place, by ``stage`` (then the effects' order: a saturation last);
    - ``noise_scale(base, e, t_tab, scale)``: the noise's scale (frame, plate, axis) in place;
    - ``readings(base, e, pos, noise, scale)``: the clean positions and their noise, in place,
      as the camera reads them (a lattice);
    - ``after_noise(base, e, pos, t_tab, extras)``: on the noisy positions in place, what it
      drew in ``extras`` (outliers);
    - ``mean_reading(base, e, pos) -> pos``: the camera's mean reading of clean positions where
      it is not they themselves (a lattice smoothed by its noise);
    - ``strength(base, e) -> (r, S)``: its RMS ratio and likelihood signal where they are not
      those of its mean reading's difference (a noise structure);
    - ``truth(base, e, p, out, t_tab, extras)``: its truth entry (its parameters ``p``, its
      times and bands in ``out``) in place.
    """

    stage: int = 0
    load: Callable | None = None
    taps: Callable | None = None
    clock: Callable | None = None
    camera: Callable | None = None
    noise_scale: Callable | None = None
    readings: Callable | None = None
    after_noise: Callable | None = None
    mean_reading: Callable | None = None
    strength: Callable | None = None
    truth: Callable | None = None


def bench_plates(e) -> np.ndarray:
    """The 0-based plate indices of a drawn effect (the benchmark's ``plates`` are 1-based)."""
    return np.asarray(e.get("plates", []), int) - 1


def bench_load(base, e) -> dict:
    """A load modulation's registry parameters from its draw: a linear kind about the record's
    middle (``t_ref_s``, s since the first frame)."""
    params = {k: float(v) for k, v in e["parameters"].items()}
    if e["kind"] == "linear":
        params["t_ref_s"] = base.t_mid - base.t_first
    return params


@dataclass(frozen=True)
class _Values:
    """Parameters read as a spec's (``p(name)``)."""

    values: dict

    def p(self, name: str) -> Any:
        return self.values[name]


def spec_values(entry: Entry, params: dict) -> _Values:
    """``params`` with the entry's defaults filled in, numbers as floats, read as a spec's
    (``.p(name)``): a drawn effect's parameters for the entry's own functions."""
    full = {p.name: p.default for p in entry.params if p.default is not None}
    for k, v in params.items():
        q = entry.param(k)
        full[k] = v if q is not None and (q.plate or q.choices) else float(v)
    return _Values(full)


@dataclass(frozen=True)
class Entry:
    """One effect id of the vocabulary (`jaxdefl.effects.REGISTRY`).

    Attributes:
        id: the DIAG.json / ``[[effect]]`` id (the module's name).
        meaning: the physics it stands for (one line).
        rank: its place in the vocabulary: the diagnosis proposes candidates in this order, and
            the simulator lists its effects by level, then rank.
        sensors: the sensor kinds (`SENSORS`) that can produce it.
        structural: the beam itself can make it (its motion or its shape change), not only a
            measurement (a noise structure, a clock, a camera's motion or bound).
        needs_reference: it can only be told against an LDS reference.
        detectable: ``jaxdefl diagnose`` names it (its detector is
            ``jaxdefl.diagnose.detectors.<id>``).
        record_kinds: the kinds of record (`jaxdefl.diagnose.record_kind.KINDS`) in which the
            diagnosis searches it, None for every kind: an effect defined against one steady
            loading harmonic cannot be told from the motion of a record of another kind.
        level, params, inject, check, resolve: its injection (None: the simulator does not
            inject it). ``inject`` acts at ``level``:

            - range: ``inject(e, t_rel, n_plates, seed) -> (columns, (frame, column) mm)``,
              column 0 the pixels off the plates, p plate p's;
            - timestamps: ``inject(e, t_rel) -> (frame,) s`` added to the written stamps;
            - motion: ``inject(e, m: Motion)`` composes its terms into ``m``;
            - plate: ``inject(e, t_rel, motion, dx, dy, rest)`` scales (frame, plate) motions in
              place;
            - measurement: ``inject(e, r: Reading)`` on a camera's centroids and their noise, in
              place (after the range effects, before the reading is ``xyz + noise``), in the
              order of ``order``;
            - sampling: ``inject(e, t_rel) -> (k,) or (frame, k) s``: the instants after each
              frame's time whose true positions the camera's reading averages.

            ``check(e, bad)`` raises ``bad(name, expected)`` for an impossible value;
            ``resolve(params, bad)`` fills defaults derived from other parameters
            (``bad(name, expected, value)``).
        from_diagnosis: ``from_diagnosis(report: Report) -> (parameters, plates)``: the
            ``[[effect]]`` table that simulates a diagnosed effect as it was reported.
        plated: whether a ``plates`` list restricts it to those plates (None: for the range level).
        order: within its level, the order in which the effects act (then the config's order): a
            reading is rounded after its noise has been shaped.
        locator: (parameter, resolution): what tells two injections of the id apart (a jump's
            time, a line's frequency), for reports of one effect seen on several axes.
        example: the parameters of a valid ``[[effect]]`` table, large enough to be diagnosed on
            a few minutes of an 11-plate ToF record (the conformance suite injects it).
        draw: ``draw(b) -> effect`` the concealed benchmark's random draw of a detectable id
            (`jaxdefl.simulate.effects.draw_effect`; ``b`` a `jaxdefl.simulate.effects.Draw`:
            the recording, the random stream, the size target and the benchmark's sizing).
        scored: ``scored(kind) -> {name: sign matters}``: the parameters the benchmark requires
            within 25 % of their true values, by the drawn kind
            (`jaxdefl.simulate.effects.primary_parameters`).
        bench: how the concealed benchmark renders its draw (`Bench`).
        footprint: the shapes the effect leaves on a record's residual that other ids can leave
            too (a warm-up and a level jump: a slow change of the mean; a crack and a drift of the
            loading frequency: a change of the frequency). Ids sharing one are rivals: the
            diagnosis fits each rival of a named effect to the same residual and reports the
            ΔBIC margin (`jaxdefl.diagnose` RIVAL_MARGIN), so that a name the record cannot tell
            from another is said to be so.
    """

    id: str
    meaning: str
    rank: int
    sensors: tuple[str, ...] = SENSORS
    structural: bool = True
    needs_reference: bool = False
    detectable: bool = True
    record_kinds: tuple[str, ...] | None = None
    level: str | None = None
    params: tuple[Param, ...] = ()
    inject: Callable | None = None
    check: Callable | None = None
    resolve: Callable | None = None
    from_diagnosis: Callable[[Report], tuple[dict, tuple[int, ...]]] | None = None
    plated: bool | None = None
    order: int = 0
    locator: tuple[str, float] | None = None
    example: dict[str, Any] = field(default_factory=dict)
    draw: Callable[[Any], dict] | None = None
    scored: Callable[[str], dict[str, bool]] | None = None
    bench: Bench = field(default_factory=Bench)
    footprint: tuple[str, ...] = ()

    @property
    def injectable(self) -> bool:
        return self.inject is not None

    @property
    def takes_plates(self) -> bool:
        """Whether an ``[[effect]]`` table of it may list ``plates``."""
        return self.level == "range" if self.plated is None else self.plated

    def param(self, name: str) -> Param | None:
        return next((p for p in self.params if p.name == name), None)


# ---------------------------------------------------------------------------------------------
# scheduled effects: from t_s, to the end or for duration_s


def active(e, t_rel: np.ndarray) -> np.ndarray:
    """Whether a scheduled effect acts at ``t_rel``."""
    t_rel = np.asarray(t_rel, np.float64)
    on = t_rel >= e.p("t_s")
    if e.p("duration_s") > 0:
        on &= t_rel < e.p("t_s") + e.p("duration_s")
    return on


def elapsed(e, t_rel: np.ndarray) -> np.ndarray:
    """Time spent under a scheduled effect up to ``t_rel`` (0 before it)."""
    t_rel = np.asarray(t_rel, np.float64)
    end = e.p("t_s") + e.p("duration_s") if e.p("duration_s") > 0 else np.inf
    return np.clip(np.minimum(t_rel, end) - e.p("t_s"), 0.0, None)


# a periodic modulation (of the amplitude or the frequency) completes at least this many cycles in
# a record: fewer is a trend of the envelope, not a periodic one. The detectors' band starts at
# MODULATION_MIN_CYCLES / duration (`jaxdefl.diagnose.detectors._modulation.modulation_band`) and
# the benchmark draws no slower one.
MODULATION_MIN_CYCLES = 2.0

WHEN = (Param("t_s", "s after the recording start"), Param("duration_s", "s (0: to the end)", 0.0))
PHASE = Param("phase_rad", "rad", 0.0)


def modulation_params(rate: str, rate_unit: str, depth: str, depth_unit: str) -> tuple[Param, ...]:
    """A modulation's parameters: linear about t_ref_s, or sinusoidal (all default 0)."""
    names = (
        (rate, rate_unit),
        ("t_ref_s", "s"),
        (depth, depth_unit),
        ("freq_hz", "Hz"),
        ("phase_rad", "rad"),
    )
    return tuple(Param(n, u, 0.0) for n, u in names)


# ---------------------------------------------------------------------------------------------
# parameter checks: check(e, bad) raises bad(name, expected)


def check_when(e, bad):
    if not e.p("t_s") >= 0:
        raise bad("t_s", "a time >= 0 s")
    if not e.p("duration_s") >= 0:
        raise bad("duration_s", "a duration >= 0 s")


def relative(name: str):
    def check(e, bad):
        if not e.p(name) > -1.0:
            raise bad(name, "a relative change > -1")

    return check


def positive(name: str, expected: str):
    def check(e, bad):
        if not e.p(name) > 0:
            raise bad(name, expected)

    return check


def non_negative(name: str, expected: str):
    def check(e, bad):
        if not e.p(name) >= 0:
            raise bad(name, expected)

    return check


def all_of(*fns):
    def check(e, bad):
        for f in fns:
            f(e, bad)

    return check
