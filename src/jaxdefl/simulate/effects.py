"""Recordings with concealed effects: the generator of the missing-physics benchmark (issue 7).

A recording is the simulator's exact plate-centroid kinematics (`simulate_trajectories`, fatigue
switched off so that the amplitude is constant within the record) at the delivered frame times
(drop-outs included), plus white sensor noise per plate and axis. Zero, one or two *effects* are
injected into the camera trajectories; the LDS reference (300 Hz, 2 µm) sees the beam's motion
only, so it carries the physical modulations of the load (`amplitude_modulation`,
`frequency_modulation`) and none of the camera's artefacts.

Nominal model: y = offset + A cos(ω t_rel − φ) + white noise, per plate and axis. Notation of the
effects' parameters (the contract with ``jaxdefl diagnose``): t_rel = t − first timestamp of the
table, t_mid the middle of the record, ω = 2π f0, φ the plate's motion phase.

=====================  ======================================================================
id                     injection and parameters
=====================  ======================================================================
motion_artefact        the four correlation samples at 0, T/4, T/2, 3T/4 after the frame time:
                       the camera reads the mean of the four positions, i.e. H(ω)·truth
                       (`jaxdefl.fit.motion.motion_artefact_response`); ``tap_spread_s`` = T.
                       Every plate and axis; visible against the LDS only.
timing_error           t_cam = t_true + offset + rate·(t_true − t_first); ``offset_s`` or
                       ``rate_ppm``. Every plate and axis; visible against the LDS only.
harmonic_distortion    z += a cos(k ω t_rel − ψ); ``order`` (k), ``amplitude_mm`` (a).
drift                  z += a exp(−t_rel/τ); ``amplitude_mm`` (signed), ``tau_s``.
level_jump             z += δ for t_rel ≥ t_j; ``t_jump_s``, ``size_mm``.
amplitude_modulation   A(t) = A0 (1 + r (t − t_mid)) (``relative_rate_per_s``) or
                       A0 (1 + m cos(2π f_m t_rel + ψ)) (``depth``, ``freq_hz``); z and x.
frequency_modulation   phase + β sin(2π f_m t_rel + ψ) (``depth_rad``, ``freq_hz``) or
                       f(t) = f0 + d (t − t_mid) (``drift_hz_per_s``); every axis.
extra_periodic         z (and x) += a_p cos(2π f_e t_rel + ψ); ``freq_hz``, ``amplitude_mm``
                       (median over the plates of the z amplitudes a_p).
outliers               a fraction ε of the samples of 1-3 plates get an error N(0, s²) or ±s;
                       ``fraction``, ``scale_mm``.
heteroscedastic_noise  σ_i = σ0 (1 + m u_i), u = cos(ω t_rel − φ − ψ) (kind "phase") or
                       (t − t_mid)/(duration/2) (kind "time"); ``modulation`` (m).
quantization           noise before rounding, as a disparity camera makes it: each z is the mean of
                       P pixel readings o + q round((z_clean + e_i − o)/q), e_i ~ N(0, σ_d²), plus
                       the rest of the series' noise after the rounding, N(0, σ² − σ_d²/P) (none
                       for the default σ_d = σ√P: then the pixels' noise is the whole noise); the
                       unrounded reading has the series' noise σ, not added twice. Its mean is the
                       smoothed staircase `jaxdefl._lattice.smoothed_staircase`; ``step_mm`` (q),
                       ``offset_mm`` (o), ``pixels`` (P, default 1), ``dither_mm`` (σ_d, optional;
                       drawn: P 20-200, σ_d/q 0.12-0.25); structured-light recordings only.
mode_shape             z_p += a sin(nπ x_p/L) cos(2π f t_rel + ψ), x_p the plate's position on the
                       span L; ``mode`` (n = 2 or 3: sign changes across the plates), ``freq_hz``,
                       ``amplitude_mm`` (a, at the antinode), ``phase_rad``.
clipping               z_p = offset_p + min(s (z_p − offset_p), c A_p) s, c 0.3-0.99, on 1-2 plates of the
                       middle of the span (before the noise: the pixels read the bound each with
                       its own noise); ``level`` (c), ``side`` (s = +1 far, −1 near), ``level_mm``.
camera_shake           z += u(t) on every plate alike, u the camera's random low-pass motion
                       (`injection.shake_displacement`); ``rms_mm``, ``corner_hz`` (3-30 mHz).
stiffness_change       a crack at ``t_s``: amplitude × 1/(1 + s), frequency × √(1 + s), phase
                       continuous (`injection`'s motion term; the LDS sees it); ``stiffness_change``
                       (s < 0); every axis.
=====================  ======================================================================

Magnitudes (`draw_effect`): "below the raw noise": the effect's RMS contribution, after removing
what the nominal model absorbs (offset, the harmonic and a small change of its frequency; for the
reference-tied effects only the offset), is 0.1-0.6 σ of the series it touches (log-uniform), and
large enough for statistics: the likelihood signal S = Σ n·rms²/σ² over the affected series is at
least `SIGNAL_MIN`. Whatever the RMS, nothing may show by eye: a drift or jump at most σ, an
amplitude envelope within ±25 %, a phase wobble within 0.5 rad. Noise-structure effects use m in
0.15-0.4; outliers 0.2-1 % of the samples at 4-12 σ. The reference-tied effects use the physical
ranges: the taps spread over 0.4-1 frame period; timestamps late by 2-10 ms; a clock rate of
20-200 ppm (either sign) but as small as the RMS target asks (20-40 ppm for 15-20 minutes: larger
rates put the camera-LDS mismatch far above the raw noise). A quantization step is at most half
the largest plate's peak-to-peak motion (the cap wins over the target); its pixels' noise is
drawn apart from the series' noise: with σ = 1 mm and ≤ 5.2 mm of motion, the default σ_d = σ√P
is ≥ 4.5 mm for P ≥ 20 and washes out every step that fits the motion, while P of 1-2 leaves
readings on the lattice itself (a plate whose motion spans less than a step reads constant).

Each id's draw, its rendering into a recording and the parameters it scores are its vocabulary
module's (`jaxdefl.effects.<id>`: ``draw``, ``bench``, ``scored``; the table above summarises
them): `draw_effect` hands the draw the recording and the sizing (`Draw`), `make_recording` calls
the rendering's hooks stage by stage (`jaxdefl.effects.Bench`). This module spells no id.

Public surface: `EFFECT_IDS`, `RecordingSpec`, `CleanRecording`, `Draw`, `random_spec`, `draw_effect`,
`make_recording`, `make_case`, `primary_parameters`, `effect_strength`, `best_evidence`.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
import pandas as pd

from ..effects import EFFECT_IDS, REGISTRY, ids_where
from .config import SimConfig, config_from_dict
from .injection import make_spec, motion_modulations
from .lds import frame_clock, truth_table
from .writer import simulate_trajectories

__all__ = [
    "Draw",
    "EFFECT_IDS",
    "NEEDS_REFERENCE",
    "STRUCTURED_LIGHT_ONLY",
    "TOF_ONLY",
    "SIGNAL_MIN",
    "RMS_RATIO_RANGE",
    "RecordingSpec",
    "CleanRecording",
    "SESSIONS",
    "random_spec",
    "draw_effect",
    "make_recording",
    "make_case",
    "primary_parameters",
    "effect_strength",
    "best_evidence",
]

# the benchmark's two cameras: which effects need the LDS, and which one camera alone makes
NEEDS_REFERENCE = ids_where(needs_reference=True)
STRUCTURED_LIGHT_ONLY = frozenset(
    e.id for e in REGISTRY.values() if "structured_light" in e.sensors and "tof" not in e.sensors
)
TOF_ONLY = frozenset(
    e.id for e in REGISTRY.values() if "tof" in e.sensors and "structured_light" not in e.sensors
)
SIGNAL_MIN = 200.0  # Σ n rms²/σ² over the affected series (aim: >= ~150, with a margin)
RMS_RATIO_RANGE = (0.1, 0.6)  # effect RMS / raw noise σ of the touched series

# Experiment II's days at 3 Hz: (day, cycles at start, f0 Hz, mid-span amplitude mm) of Table 6.16
# (ToF days, LDS) and Table 6.24 (Kinect days), as in configs/exp2_{tof,kinect}_3hz.toml
SESSIONS = {
    "tof": {
        "day1": (1, 32400, 3.0680, 2.32),
        "day2": (2, 60050, 3.0678, 2.42),
        "day3": (3, 92450, 3.0679, 2.58),
        "day5": (5, 226400, 3.0681, 2.58),
        "day8": (8, 391000, 3.0687, 2.61),
        "day11": (11, 880286, 3.0673, 2.63),
    },
    "structured_light": {
        "day7": (7, 332900, 3.0684, 2.59),
        "day8": (8, 391000, 3.0687, 2.62),
        "day10": (10, 677400, 3.0675, 2.64),
    },
}
_AXES = ("x", "y", "z")
# raw noise σ (mm) per axis: the thesis' Table 6.17 (ToF, 20 Hz: 0.76 mm in z); ToF noise grows with
# the frame rate as the range noise of Table 6.1 (29 MHz: 2.56 -> 3.14 mm from 20 to 30 Hz)
_NOISE_MM = {
    ("tof", 20.0): {"x": 0.30, "y": 0.10, "z": 0.76},
    ("tof", 30.0): {"x": 0.37, "y": 0.12, "z": 0.93},
    ("structured_light", 30.0): {"x": 0.40, "y": 0.15, "z": 1.00},
}


@dataclass(frozen=True)
class RecordingSpec:
    """What the recording looks like (the decoys the nominal model must handle).

    Attributes:
        sensor: ``tof`` (SR4000 config) or ``structured_light`` (Kinect config); the sensor hint.
        frame_rate_hz: camera frame rate (20 or 30).
        duration_s: record length.
        n_plates: 9-13 plates spread over the span (the beam's shape gives them different
            amplitudes).
        dropout_prob: probability of a lost frame.
        reference: whether an LDS table comes with the recording.
        session: a day of `SESSIONS` (loading frequency and amplitude); "": the sensor's first.
        noise_mm: raw noise σ per axis (mm); None: from sensor and frame rate (`_NOISE_MM`).
        plate_noise_spread: per-plate σ factors drawn uniformly in 1 ± this.
        noisy_plate: a plate (1-based) whose noise is ``noisy_factor`` times larger; 0: none.
        frame_common: share of each plate's noise variance common to all plates of a frame (a
            ToF camera's frame-wide range error: the simulator's per-frame error, thesis Tables
            6.2/6.17); 0: independent plates.
        line_of_sight: share of each axis' noise variance that is the plate's range error seen
            along its line of sight (a ToF plate's x, y and z come from the same ranges along
            the same rays: the extracted SR4000 frames give |ρ| 0.9-1.0 between a plate's axes,
            the sign that of the ray's component); 0: independent axes.
    """

    sensor: Literal["tof", "structured_light"] = "tof"
    frame_rate_hz: float = 20.0
    duration_s: float = 900.0
    n_plates: int = 13
    dropout_prob: float = 0.03
    reference: bool = True
    session: str = ""
    noise_mm: tuple[float, float, float] | None = None  # x, y, z
    plate_noise_spread: float = 0.15
    noisy_plate: int = 0
    noisy_factor: float = 1.8
    frame_common: float = 0.0
    line_of_sight: float = 0.0

    def sigma_mm(self) -> dict[str, float]:
        if self.noise_mm is not None:
            return dict(zip(_AXES, self.noise_mm, strict=True))
        key = (self.sensor, float(self.frame_rate_hz))
        if key in _NOISE_MM:
            return dict(_NOISE_MM[key])
        base = _NOISE_MM[(self.sensor, 30.0 if self.sensor == "structured_light" else 20.0)]
        return dict(base)

    @property
    def lds_plates(self) -> tuple[int, ...]:
        """LDS under every other plate away from the supports (3, 5, ... n-2)."""
        return tuple(range(3, self.n_plates - 1, 2)) if self.reference else ()


def sim_config(spec: RecordingSpec) -> SimConfig:
    """The simulator config of a spec: Experiment II's day, fatigue off, plates over the span.

    Self-contained (`config_from_dict`), so that edits to the shipped configs do not move the
    benchmark.
    """
    sessions = SESSIONS[spec.sensor]
    name = spec.session or next(iter(sessions))
    if name not in sessions:
        raise ValueError(f"session: expected one of {', '.join(sessions)} for {spec.sensor}, got {name!r}")
    day, cycles, f0, amp = sessions[name]
    span, x0 = 3400.0, 200.0
    raw = {
        "recording": {
            "segment": name,
            "day": day,
            "duration_s": float(spec.duration_s),
            "start_epoch_s": 1.7e9,
            "cycles_at_start": float(cycles),
        },
        "beam": {"span_mm": span, "load_a_mm": 1200.0},
        "plates": {"count": spec.n_plates, "x0_mm": x0, "spacing_mm": (span - 2 * x0) / (spec.n_plates - 1)},
        "loading": {"frequency_hz": f0, "amplitude_mm": amp, "longitudinal_mm": 0.5, "lateral_mm": 0.05},
        "fatigue": {"law": "none"},
        "camera": {
            "sensor": "sr4000" if spec.sensor == "tof" else "kinect",
            "frame_rate_hz": float(spec.frame_rate_hz),
            "x_mm": 1700.0,
            "y_mm": 400.0,
            "standoff_mm": 1900.0,
            "dropout_prob": float(spec.dropout_prob),
        },
        "lds": {"enabled": True, "plates": list(spec.lds_plates or (3,)), "defective_plate": 0},
    }
    return config_from_dict(raw, source=f"<concealed effects {name}>")


def random_spec(
    rng: np.random.Generator,
    minutes: float | None = None,
    sensor: str | None = None,
    reference: bool | None = None,
) -> RecordingSpec:
    """A recording with random decoys: 9-13 plates, 20/30 Hz, 3-30 % drop-outs, 15-20 minutes
    (or ``minutes``), with or without the LDS, sometimes a plate with a larger noise, and for
    half of the ToF recordings noise shared by the plates of a frame (40-85 % of its variance).

    The frame-common share is drawn from a stream of its own, seeded by the other draws, so that
    this decoy did not move the benchmark's other random draws."""
    if sensor is None:
        sensor = "structured_light" if rng.random() < 0.2 else "tof"
    fs = 30.0 if sensor == "structured_light" else float(rng.choice([20.0, 30.0], p=[0.6, 0.4]))
    duration = 60.0 * (float(rng.uniform(15.0, 20.0)) if minutes is None else float(minutes))
    n_plates = int(rng.integers(9, 14))
    days = list(SESSIONS[sensor])
    spec = RecordingSpec(
        sensor=sensor,  # type: ignore[arg-type]
        frame_rate_hz=fs,
        duration_s=round(duration, 3),
        n_plates=n_plates,
        dropout_prob=round(float(rng.uniform(0.03, 0.30)), 4),
        reference=bool(rng.random() < 0.6) if reference is None else reference,
        session=str(rng.choice(days)),
        noisy_plate=int(rng.integers(1, n_plates + 1)) if rng.random() < 0.4 else 0,
        noisy_factor=round(float(rng.uniform(1.5, 2.0)), 3),
    )
    if sensor == "tof":
        own = np.random.default_rng([n_plates, int(spec.dropout_prob * 1e4), int(spec.duration_s)])
        if own.random() < 0.5:
            spec = dataclasses.replace(spec, frame_common=round(float(own.uniform(0.4, 0.85)), 3))
    return spec


class CleanRecording:
    """The clean kinematics, frame clock, noise levels and LDS of one recording (no effects).

    Built once per (spec, seed) and shared by `draw_effect` (magnitudes relative to its noise)
    and `make_recording`.
    """

    def __init__(self, spec: RecordingSpec, seed: int):
        self.spec, self.seed = spec, int(seed)
        cfg = sim_config(spec)
        self.cfg = cfg
        self.truth, lds = simulate_trajectories(cfg, spec.duration_s, seed)
        _, t = frame_clock(cfg, spec.duration_s, seed)
        self.t = t  # (frame,) epoch s, true acquisition times
        self.t_first, self.t_last = float(t[0]), float(t[-1])
        self.t_mid = 0.5 * (self.t_first + self.t_last)
        self.duration = self.t_last - self.t_first
        ld = cfg.loading
        self.f0 = ld.frequency_hz
        self.omega = 2 * math.pi * ld.frequency_hz
        self.amp0 = ld.amplitude_mm
        zero = dataclasses.replace(ld, amplitude_mm=0.0, mean_mm=0.0, longitudinal_mm=0.0, lateral_mm=0.0)
        one = dataclasses.replace(zero, mean_mm=1.0)
        t1 = t[:1]
        st = truth_table(dataclasses.replace(cfg, loading=zero), t1)
        self.static = st[list(_AXES)].to_numpy()  # (plate, axis)
        self.shape = (
            truth_table(dataclasses.replace(cfg, loading=one), t1)["z"].to_numpy() - self.static[:, 2]
        )
        self.n_plates = spec.n_plates
        # motion phase φ of y = A cos(ω t_rel − φ): sin(ω τ + φ0) with τ = t − t0
        self.phase = float(
            np.mod(math.pi / 2 - ld.phase_rad - self.omega * (self.t_first - cfg.t0_s), 2 * math.pi)
        )
        self.lds = lds if spec.reference else None
        rng = np.random.default_rng([self.seed, 7001])
        sig = spec.sigma_mm()
        fac = 1.0 + spec.plate_noise_spread * rng.uniform(-1.0, 1.0, spec.n_plates)
        if spec.noisy_plate:
            fac[spec.noisy_plate - 1] *= spec.noisy_factor
        self.sigma = np.stack([sig[a] * fac for a in _AXES], axis=1)  # (plate, axis)
        self.eps = rng.standard_normal((t.size, spec.n_plates, 3))  # unit white noise
        if spec.frame_common > 0:  # its own stream: the independent part stays as it was
            common = np.random.default_rng([self.seed, 7002]).standard_normal((t.size, 1, 3))
            c = spec.frame_common
            self.eps = math.sqrt(1.0 - c) * self.eps + math.sqrt(c) * common
        if spec.line_of_sight > 0:  # one range error per plate, along the ray to the plate
            ray = self.ray_signs()
            r = self.eps[..., 2:3]  # the range error: the z draw, its frame-common part included
            own = np.random.default_rng([self.seed, 7003]).standard_normal(self.eps.shape)
            c = spec.line_of_sight
            self.eps = math.sqrt(1.0 - c) * own + math.sqrt(c) * r * ray[None]

    def ray_signs(self) -> np.ndarray:
        """(plate, axis) signs of the ray to each plate relative to its z component (the camera at
        the origin, z along its axis): how a range error moves the plate's x, y and z."""
        ray = np.sign(self.static)
        ray[ray == 0] = 1.0
        return ray * ray[:, 2:3]

    def noise_correlation(self) -> np.ndarray:
        """(3 P, 3 P) correlation of one frame's unit noise ``eps`` over the series (plate, axis),
        flattened plate-major, as drawn: a share ``frame_common`` of each axis' variance common to
        the plates, then a share ``line_of_sight`` of each one the plate's range error (its z draw,
        common part included) times the ray's sign."""
        n, c, los = self.n_plates, self.spec.frame_common, self.spec.line_of_sight
        corr = np.kron(np.ones((n, n)), np.eye(3)) * ((1.0 - c) * np.eye(3 * n) + c)
        if los > 0:
            z = corr[2::3, 2::3]  # (plate, plate) of the z draws
            ray = self.ray_signs().reshape(-1)
            zz = np.kron(z, np.ones((3, 3)))  # each series' range error: its plate's z draw
            corr = (1.0 - los) * np.eye(3 * n) + los * zz * np.outer(ray, ray)
        return corr

    def motion(self, t: np.ndarray, am=None, fm=None) -> np.ndarray:
        """(frame, plate, axis) clean positions at true epoch times t, with the load's AM / FM."""
        ld = self.cfg.loading
        phase = self.omega * (t - self.cfg.t0_s) + ld.phase_rad
        if fm is not None:
            phase = phase + fm(t)
        s = np.sin(phase)
        g = am(t) if am is not None else 1.0
        out = np.empty((t.size, self.n_plates, 3))
        out[..., 0] = self.static[:, 0] + (ld.longitudinal_mm * g * s)[:, None]
        out[..., 1] = self.static[:, 1] + (ld.lateral_mm * s)[:, None]
        out[..., 2] = self.static[:, 2] + self.shape * (ld.mean_mm + self.amp0 * g * s)[:, None]
        return out


# ---------------------------------------------------------------------------------------------
# rendering: effects -> camera table and LDS


def _bench(e: Mapping):
    """How the benchmark renders a drawn effect: its vocabulary entry's (`jaxdefl.effects.Bench`)."""
    return REGISTRY[e["id"]].bench


def _hooked(effects: Sequence[Mapping], hook: str) -> list[tuple[Callable, Mapping]]:
    """(hook, effect) of the effects that have ``hook``, by the entries' ``stage`` (then the
    effects' order)."""
    found = [(getattr(_bench(e), hook), e) for e in effects if getattr(_bench(e), hook) is not None]
    return sorted(found, key=lambda fe: _bench(fe[1]).stage)


def _modulations(base: CleanRecording, effects: Sequence[Mapping]):
    """AM gain g(t) and FM phase Δφ(t) functions of true epoch time (None when absent): the load's
    modulations (``Bench.load``) as the simulator's registry injects them
    (`jaxdefl.simulate.injection`), in rank order."""
    specs = [make_spec(e["id"], load(base, e)) for load, e in _hooked(_by_rank(effects), "load")]
    if not specs:
        return None, None
    gain, shift, _ = motion_modulations(tuple(specs), base.t_first, base.f0)
    return gain, shift


def _by_rank(effects: Sequence[Mapping]) -> list[Mapping]:
    return sorted(effects, key=lambda e: REGISTRY[e["id"]].rank)


def _camera_clean(base: CleanRecording, effects: Sequence[Mapping]) -> tuple[np.ndarray, np.ndarray]:
    """(table times, clean camera positions (frame, plate, axis)) before noise and quantisation:
    the beam's motion (the load's modulations) read over the camera's taps, the table's clock,
    then the camera's additive terms and its saturation (``Bench``)."""
    am, fm = _modulations(base, effects)
    t = base.t
    offsets = [0.0]
    for taps, e in _hooked(effects, "taps"):
        offsets = [a + b for a in offsets for b in taps(base, e)]
    if offsets != [0.0]:
        pos = sum(base.motion(t + d, am, fm) for d in offsets) / float(len(offsets))
    else:
        pos = base.motion(t, am, fm)
    t_tab = t
    for clock, e in _hooked(effects, "clock"):
        t_tab = clock(base, e, t_tab)
    trel = t_tab - t_tab[0]
    for camera, e in _hooked(effects, "camera"):
        camera(base, e, pos, trel)
    return t_tab, pos


def _render(base: CleanRecording, effects: Sequence[Mapping]) -> tuple[np.ndarray, np.ndarray, dict]:
    """(table times, camera positions with noise (frame, plate, axis), realised extras)."""
    t_tab, pos = _camera_clean(base, effects)
    extras: dict[str, Any] = {}
    scale = np.ones_like(base.eps)
    for noise_scale, e in _hooked(effects, "noise_scale"):
        noise_scale(base, e, t_tab, scale)
    noise = base.sigma[None] * scale * base.eps
    for readings, e in _hooked(effects, "readings"):  # the pixels' noise is the series' noise
        readings(base, e, pos, noise, scale)
    pos = pos + noise
    for after_noise, e in _hooked(effects, "after_noise"):
        after_noise(base, e, pos, t_tab, extras)
    return t_tab, pos, extras


def _lds(base: CleanRecording, effects: Sequence[Mapping]) -> pd.DataFrame | None:
    """The LDS table: the beam's motion (with the load's AM / FM) at 300 Hz, 2 µm noise."""
    if base.lds is None:
        return None
    lds = base.lds.copy()
    am, fm = _modulations(base, effects)
    if am is not None or fm is not None:
        t = lds["t"].to_numpy()
        ld = base.cfg.loading
        phase = base.omega * (t - base.cfg.t0_s) + ld.phase_rad
        nominal = base.amp0 * np.sin(phase)
        moved = base.amp0 * (am(t) if am is not None else 1.0) * np.sin(phase + (fm(t) if fm else 0.0))
        shape = base.shape[lds["plate"].to_numpy() - 1]
        lds["z"] = lds["z"].to_numpy() + shape * (moved - nominal)
    lds.attrs = {}
    return lds.reset_index(drop=True)


def _table(base: CleanRecording, t_tab: np.ndarray, pos: np.ndarray) -> pd.DataFrame:
    n, m = pos.shape[:2]
    return pd.DataFrame(
        {
            "segment": base.cfg.recording.segment,
            "t": np.repeat(t_tab, m),
            "plate": np.tile(np.arange(1, m + 1), n),
            "x": pos[..., 0].ravel(),
            "y": pos[..., 1].ravel(),
            "z": pos[..., 2].ravel(),
        }
    )


# ---------------------------------------------------------------------------------------------
# magnitudes: effective RMS and likelihood signal of an effect


def _absorbed(base: CleanRecording, t: np.ndarray, delta: np.ndarray, tied: bool) -> np.ndarray:
    """``delta`` (frame, series) minus what the nominal model absorbs: the offset (tied to a
    reference), else the offset, the harmonic and a frequency change (d/dω of A cos(ω t − φ) is
    −A t sin(ω t − φ), in quadrature with the motion; an amplitude trend t cos(ω t − φ) is not
    absorbed)."""
    if tied:
        return delta - delta.mean(axis=0)
    tc = (t - 0.5 * (t[0] + t[-1])) / max(0.5 * (t[-1] - t[0]), 1e-9)
    arg = base.omega * (t - t[0]) - base.phase
    x = np.stack([np.ones_like(t), np.cos(arg), np.sin(arg), tc * np.sin(arg)], axis=1)
    coef, *_ = np.linalg.lstsq(x, delta, rcond=None)
    return delta - x @ coef


def _effect_delta(base: CleanRecording, e: Mapping) -> tuple[np.ndarray, np.ndarray]:
    """(table times, (frame, plate, axis) the camera's mean reading with the mean-shape effect
    ``e`` less the reading without it); for the reference-tied effects, against the truth at the
    table's own timestamps (what a reference would show)."""
    t_tab, pos = _camera_clean(base, [e])
    clean = base.motion(t_tab) if e["id"] in NEEDS_REFERENCE else _camera_clean(base, [])[1]
    return t_tab, _mean_reading(base, e, pos) - clean


def _gls_evidence(base: CleanRecording, r: np.ndarray) -> float:
    """Σ_t r_tᵀ Σ⁻¹ r_t for the absorbed differences r (frame, plate, axis) under the recording's
    own noise covariance Σ (`CleanRecording.noise_correlation` and σ)."""
    sd = base.sigma.reshape(-1)
    corr = base.noise_correlation()
    flat = r.reshape(r.shape[0], -1) / sd[None, :]
    return float(np.sum(flat * np.linalg.solve(corr, flat.T).T))


def best_evidence(base: CleanRecording, e: Mapping) -> float:
    """The evidence S of an effect for the best possible detector: the known-form likelihood-ratio
    test's noncentrality Σ_t δ_tᵀ Σ⁻¹ δ_t, δ_t the effect in frame t over all series (zero on the
    ones it leaves alone) after what the nominal model absorbs, Σ the noise covariance across
    plates and axes as drawn (frame-common and line-of-sight shares). On independent noise it is
    `effect_strength`'s S; an effect alike on the plates carries less evidence under frame-common
    noise (the common noise looks like it), one on a single plate more (the other plates measure
    the common noise). Noise-structure effects (their own ``Bench.strength``) keep
    `effect_strength`'s S."""
    eid = e["id"]
    spec = base.spec
    if _bench(e).strength is not None or (spec.frame_common <= 0 and spec.line_of_sight <= 0):
        return effect_strength(base, e)[1]
    t_tab, delta = _effect_delta(base, e)
    keep = np.zeros(delta.shape[1:], bool)
    if eid in NEEDS_REFERENCE:  # against the LDS: on its plates, z
        keep[np.asarray(spec.lds_plates, int) - 1, 2] = True
    else:
        idx, axes = _series_mask(e)
        keep[np.ix_(idx, axes)] = True
    delta = np.where(keep[None], delta, 0.0)
    n = delta.shape[0]
    r = _absorbed(base, t_tab, delta.reshape(n, -1), tied=eid in NEEDS_REFERENCE).reshape(delta.shape)
    return _gls_evidence(base, r)


def _mean_reading(base: CleanRecording, e: Mapping, pos: np.ndarray) -> np.ndarray:
    """(frame, plate, axis) the camera's mean reading of the clean positions ``pos``: ``pos``
    itself but where the effect says otherwise (``Bench.mean_reading``: a lattice's deterministic
    part is its staircase smoothed by the pixels' noise, the rest of the rounding is noise)."""
    mean_reading = _bench(e).mean_reading
    return pos if mean_reading is None else mean_reading(base, e, pos)


def _series_mask(e: Mapping) -> tuple[np.ndarray, list[int]]:
    idx = np.asarray(e["plates"], int) - 1
    axes = [_AXES.index(a) for a in e["axes"]]
    return idx, axes


def effect_strength(base: CleanRecording, e: Mapping) -> tuple[float, float]:
    """(pooled RMS ratio r, likelihood signal S) of one effect on the series it touches: of its
    mean reading's difference after what the nominal model absorbs, or its own
    (``Bench.strength``: a noise structure)."""
    eid = e["id"]
    if _bench(e).strength is not None:
        return _bench(e).strength(base, e)
    idx, axes = _series_mask(e)
    n = base.t.size
    sig = base.sigma[np.ix_(idx, axes)]  # (plate, axis)
    if eid in NEEDS_REFERENCE:  # visible against the LDS only: on its plates, z
        idx, axes = np.asarray(base.spec.lds_plates, int) - 1, [2]
        sig = base.sigma[np.ix_(idx, axes)]
    t_tab, delta = _effect_delta(base, e)
    delta = delta[:, idx][:, :, axes].reshape(n, -1)
    rms = np.sqrt(np.mean(_absorbed(base, t_tab, delta, tied=eid in NEEDS_REFERENCE) ** 2, axis=0))
    with np.errstate(divide="ignore", invalid="ignore"):  # a noise-free recording: infinite ratio
        ratio = (rms / sig.ravel()) ** 2
    return float(np.sqrt(np.mean(ratio))), float(n * np.sum(ratio))


# ---------------------------------------------------------------------------------------------
# drawing effects


def _strength_of(evidence: str) -> Callable[[CleanRecording, Mapping], tuple[float, float]]:
    """(RMS ratio, S) with S counted as ``evidence`` says (see `draw_effect`)."""
    if evidence == "white":
        return effect_strength
    return lambda base, e: (effect_strength(base, e)[0], best_evidence(base, e))


def _loguniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(np.exp(rng.uniform(math.log(lo), math.log(hi))))


def _adjacent(rng: np.random.Generator, n_plates: int, k: int) -> list[int]:
    start = int(rng.integers(1, n_plates - k + 2))
    return list(range(start, start + k))


def _fit_magnitude(
    base: CleanRecording,
    e: dict,
    key: str,
    target: float,
    signal_min: float,
    bounds: tuple[float, float] = (0.0, math.inf),
    strength: Callable[[CleanRecording, Mapping], tuple[float, float]] | None = None,
) -> dict:
    """Scale ``parameters[key]`` so that r = target (and S >= signal_min), its magnitude kept
    within ``bounds`` (the bounds win); a few multiplicative secant steps."""
    p = e["parameters"]
    for _ in range(8):
        r, s = (strength or effect_strength)(base, e)
        if r <= 0:
            break
        want = max(target, r * math.sqrt(signal_min / s)) if s > 0 else target
        mag = abs(p[key]) * want / r
        mag = min(max(mag, bounds[0]), bounds[1])
        factor = mag / abs(p[key])
        p[key] = math.copysign(mag, p[key])
        if abs(factor - 1.0) < 1e-3:
            break
    return e


def _extra_frequency(rng: np.random.Generator, f0: float, fs: float) -> float:
    """0.3-8 Hz, >= 0.1 Hz from every k f0 (k = 0..6) and their aliases, below Nyquist."""
    bad = [abs(k * f0 - m * fs) for k in range(7) for m in range(-3, 4)]
    hi = min(8.0, fs / 2 - 0.2)
    for _ in range(1000):
        f = float(rng.uniform(0.3, hi))
        if min(abs(f - b) for b in bad) >= 0.1:
            return round(f, 4)
    raise RuntimeError("no extra frequency found")  # pragma: no cover


def draw_effect(
    effect_id: str,
    base: CleanRecording,
    rng: np.random.Generator,
    target_ratio: float | None = None,
    signal_min: float = SIGNAL_MIN,
    evidence: Literal["white", "best"] = "white",
) -> dict:
    """A fully specified effect with random parameters, plates and a hidden magnitude.

    Args:
        effect_id: one of `EFFECT_IDS`.
        base: the recording it goes into (magnitudes are relative to its noise).
        rng: randomness.
        target_ratio: effect RMS / σ; default log-uniform in `RMS_RATIO_RANGE`.
        signal_min: floor of the likelihood signal S = Σ n rms²/σ².
        evidence: what S counts: ``white`` the series taken as independent (`effect_strength`),
            ``best`` the best possible detector's under the recording's noise covariance
            (`best_evidence`: what a detection curve is drawn against).

    Returns:
        {"id", "kind", "parameters", "plates", "axes", ...}: what `make_recording` injects.
    """
    if effect_id not in EFFECT_IDS:
        raise ValueError(f"effect_id: expected one of {', '.join(EFFECT_IDS)}, got {effect_id!r}")
    if evidence not in ("white", "best"):
        raise ValueError(f"evidence: expected 'white' or 'best', got {evidence!r}")
    target = target_ratio if target_ratio is not None else _loguniform(rng, *RMS_RATIO_RANGE)
    psi = round(float(rng.uniform(0, 2 * math.pi)), 4)
    b = Draw(effect_id, base, rng, target, signal_min, _strength_of(evidence), psi)
    return REGISTRY[effect_id].draw(b)


@dataclass(frozen=True)
class Draw:
    """What an effect's benchmark draw (`jaxdefl.effects.Entry.draw`) gets from `draw_effect`: the
    recording (its noise, duration, f0), the random stream, the RMS target and the likelihood
    floor, a phase ``psi`` drawn for every effect, and the benchmark's sizing."""

    effect_id: str
    base: CleanRecording
    rng: np.random.Generator
    target: float
    signal_min: float
    strength: Callable[[CleanRecording, Mapping], tuple[float, float]]
    psi: float
    axes: tuple[str, ...] = _AXES

    @property
    def spec(self) -> RecordingSpec:
        return self.base.spec

    @property
    def n_plates(self) -> int:
        return self.base.n_plates

    @property
    def everyone(self) -> list[int]:
        return list(range(1, self.base.n_plates + 1))

    def loguniform(self, lo: float, hi: float) -> float:
        return _loguniform(self.rng, lo, hi)

    def adjacent(self, n_plates: int, k: int) -> list[int]:
        return _adjacent(self.rng, n_plates, k)

    def extra_frequency(self) -> float:
        return _extra_frequency(self.rng, self.base.f0, self.spec.frame_rate_hz)

    def sigma_z(self, plates) -> float:
        """The median z noise σ (mm) of ``plates``."""
        return float(np.median(self.base.sigma[np.asarray(plates) - 1, 2]))

    def measure(self, e: Mapping) -> tuple[float, float]:
        """(RMS ratio, likelihood signal S) of ``e`` as the draw counts them."""
        return self.strength(self.base, e)

    def sized(self, e: dict, key: str, bounds: tuple[float, float] = (0.0, math.inf)) -> dict:
        """``e`` with its id and ``parameters[key]`` scaled to the target (`_fit_magnitude`)."""
        e["id"] = self.effect_id
        return _fit_magnitude(self.base, e, key, self.target, self.signal_min, bounds, self.strength)

    def quantization_step(self, e: dict, dither_ratio: float) -> float:
        return _quantization_step(self.base, e, self.target, self.signal_min, dither_ratio, self.strength)

    def clip_level(self, e: dict) -> dict:
        return _clip_level(self.base, e, self.target, self.signal_min, self.strength)


def _quantization_step(
    base: CleanRecording,
    e: dict,
    target: float,
    signal_min: float,
    dither_ratio: float | None = None,
    strength: Callable[[CleanRecording, Mapping], tuple[float, float]] | None = None,
) -> float:
    """The smallest step q (mm) with r >= target and S >= signal_min, at most half the largest
    plate's peak-to-peak motion (a larger step puts the motion on one to three levels: a smooth
    function of the position, i.e. harmonics of f0, with no staircase left to tell it by, whatever
    its RMS); bisection in log q, the pixels' noise ``dither_mm`` kept at
    ``dither_ratio`` × q when given.

    Not `_fit_magnitude`'s r ∝ q: with a fixed pixel noise σ_d (σ√P by default) the staircase's
    RMS is ∝ q exp(−2π²σ_d²/q²) for q ≲ 2σ_d (a log-slope 1 + 4π²σ_d²/q², dozens where
    q ~ σ_d), so a multiplicative secant step overshoots and diverges. Below the cap r and S grow
    with q.
    """
    p = e["parameters"]
    q_max = 0.5 * 2.0 * base.amp0 * float(np.max(np.abs(base.shape[np.asarray(e["plates"], int) - 1])))

    def enough(q: float) -> bool:
        p["step_mm"] = q
        if dither_ratio is not None:
            p["dither_mm"] = dither_ratio * q
        r, s = (strength or effect_strength)(base, e)
        return r >= target and s >= signal_min

    lo = 0.5 * target * float(np.median(base.sigma[:, 2])) * math.sqrt(12.0)  # half the hard staircase's
    while lo > 1e-3 and enough(lo):
        lo *= 0.5
    hi = min(2.0 * lo, q_max)
    while hi < q_max and not enough(hi):
        lo, hi = hi, min(2.0 * hi, q_max)
    if hi == q_max and not enough(hi):
        return q_max  # the cap wins: the effect is smaller than the target
    for _ in range(16):
        mid = math.sqrt(lo * hi)
        if enough(mid):
            hi = mid
        else:
            lo = mid
    return hi


def _clip_level(base: CleanRecording, e: dict, target: float, signal_min: float, strength=None) -> dict:
    """The clip level c (fraction of the amplitude, 0.3-0.99: the peaks of the motion) giving the
    RMS ratio ``target``, lowered until the likelihood signal reaches ``signal_min``; bisection
    (both fall as c rises)."""
    p = e["parameters"]

    def level_for(want: Callable[[float, float], bool]) -> float:
        lo, hi = 0.3, 0.99  # want(lo) holds (the strongest clip), want(hi) may not
        for _ in range(30):
            p["level"] = 0.5 * (lo + hi)
            if want(*(strength or effect_strength)(base, e)):
                lo = p["level"]
            else:
                hi = p["level"]
        return lo

    c = min(level_for(lambda r, s: r >= target), level_for(lambda r, s: s >= signal_min))
    p["level"] = round(c, 4)
    j = e["plates"][0] - 1
    p["level_mm"] = p["side"] * p["level"] * base.amp0 * abs(float(base.shape[j]))
    return e


# ---------------------------------------------------------------------------------------------
# primary parameters (what the benchmark scores)


def primary_parameters(effect: Mapping) -> dict[str, tuple[float, bool]]:
    """{name: (true value, sign matters)} of the parameters the benchmark requires within 25 %."""
    eid, kind, p = effect["id"], effect.get("kind", ""), effect["parameters"]
    entry = REGISTRY.get(eid)
    if entry is None or entry.scored is None:
        raise ValueError(f"unknown effect id {eid!r}")
    names = entry.scored(kind)
    return {k: (float(p[k]), sign) for k, sign in names.items()}


# ---------------------------------------------------------------------------------------------
# public entry points


def _truth_entry(base: CleanRecording, t_tab: np.ndarray, e: Mapping, extras: Mapping) -> dict:
    eid, p = e["id"], dict(e["parameters"])
    t0, t1 = float(t_tab[0]), float(t_tab[-1])
    out: dict[str, Any] = {
        "id": eid,
        "kind": e.get("kind", ""),
        "parameters": {},
        "plates": [int(v) for v in e["plates"]],
        "axes": list(e["axes"]),
        "t_start": t0,
        "t_end": t1,
    }
    truth = _bench(e).truth
    if truth is not None:  # its parameters as realised, its times and bands
        truth(base, e, p, out, t_tab, extras)
    if eid in NEEDS_REFERENCE:
        out["detectable_plates"] = [int(v) for v in base.spec.lds_plates]
    out["parameters"] = {k: (int(v) if isinstance(v, (int, np.integer)) else float(v)) for k, v in p.items()}
    r, s = effect_strength(base, e)
    out["rms_ratio"], out["signal"] = round(r, 4), round(s, 1)
    return out


def make_recording(
    spec: RecordingSpec, effects: Sequence[Mapping], seed: int, base: CleanRecording | None = None
) -> tuple[pd.DataFrame, pd.DataFrame | None, dict]:
    """A recording with the given effects injected.

    Args:
        spec: the recording (decoys).
        effects: fully specified effects (`draw_effect`'s output, or hand-made: ``id``, ``kind``,
            ``parameters``, ``plates``, ``axes``; extra_periodic optionally ``plate_factors``).
        seed: drop-outs, LDS noise, camera noise and outliers; the same seed gives the same noise
            whatever the effects, so a control and an effect case differ by the effect alone.
        base: a `CleanRecording` already built for (spec, seed) (saves the kinematics).

    Returns:
        traj: [segment, t, plate, x, y, z] (mm, epoch s) at the delivered frames.
        lds: [segment, t, plate, z] or None without a reference.
        truth: {"recording": {...}, "effects": [...]} with the labels (kept away from the tables).
    """
    base = base if base is not None else CleanRecording(spec, seed)
    ids = [e["id"] for e in effects]
    if len(set(ids)) != len(ids):
        raise ValueError(f"effects: each id at most once, got {ids}")
    for e in effects:
        if e["id"] not in EFFECT_IDS:
            raise ValueError(f"effects: unknown id {e['id']!r}; expected one of {', '.join(EFFECT_IDS)}")
    t_tab, pos, extras = _render(base, effects)
    traj = _table(base, t_tab, pos)
    lds = _lds(base, effects)
    truth = {
        "recording": {
            "sensor": spec.sensor,
            "frame_rate_hz": spec.frame_rate_hz,
            "duration_s": spec.duration_s,
            "n_plates": spec.n_plates,
            "dropout_prob": spec.dropout_prob,
            "frame_common": spec.frame_common,
            "line_of_sight": spec.line_of_sight,
            "reference": spec.reference,
            "lds_plates": list(spec.lds_plates),
            "session": spec.session,
            "seed": int(seed),
            "f0_hz": base.f0,
            "amplitude_mm": base.amp0,
            "motion_phase_rad": base.phase,
            "noisy_plate": spec.noisy_plate,
            "noise_mm": {a: base.sigma[:, i].round(4).tolist() for i, a in enumerate(_AXES)},
            "t_first": float(t_tab[0]),
            "t_last": float(t_tab[-1]),
            "n_frames": int(t_tab.size),
        },
        "effects": [_truth_entry(base, t_tab, e, extras) for e in effects],
    }
    return traj, lds, truth


def make_case(
    seed: int,
    effect_ids: Sequence[str] = (),
    minutes: float | None = None,
    sensor: str | None = None,
) -> tuple[pd.DataFrame, pd.DataFrame | None, dict]:
    """A random recording (decoys from `random_spec`) with ``effect_ids`` drawn and injected.

    Effects that need the reference force an LDS; quantization forces a structured-light recording,
    the motion artefact a ToF one.
    """
    rng = np.random.default_rng([int(seed), 7000])
    ids = list(effect_ids)
    if any(i in STRUCTURED_LIGHT_ONLY for i in ids) and any(i in TOF_ONLY for i in ids):
        raise ValueError(f"effect_ids: {ids} need both a ToF and a structured-light camera")
    if any(i in STRUCTURED_LIGHT_ONLY for i in ids):
        sensor = "structured_light"
    if any(i in TOF_ONLY for i in ids):
        sensor = "tof"
    reference = True if any(i in NEEDS_REFERENCE for i in ids) else None
    spec = random_spec(rng, minutes=minutes, sensor=sensor, reference=reference)
    base = CleanRecording(spec, seed)
    effects = [draw_effect(i, base, rng) for i in ids]
    return make_recording(spec, effects, seed, base=base)
