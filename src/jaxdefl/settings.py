"""The settings of a command, frozen and validated whole before any input is read.

A setting out of its domain raises `jaxdefl.ParameterError` naming the parameter
(``window_s: expected a positive length in s, got -1``); the command line maps the parameter
names to its flags (`FIT_FLAGS`: ``--window: ...``).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field, replace
from typing import Any, Literal

from ._errors import ConfigError, ParameterError
from ._sensors import SENSORS
from .effects import EFFECT_IDS

__all__ = [
    "ALPHA_NAMED",
    "DIAGNOSE_FLAGS",
    "DiagnoseSettings",
    "FIT_FLAGS",
    "FitSettings",
    "EXTRACT_FLAGS",
    "ExtractSettings",
    "MONITOR_FLAGS",
    "MonitorSettings",
    "RECONCILE_FLAGS",
    "ReconcileSettings",
    "RUN_FLAGS",
    "RunSettings",
    "SENSORS",
    "SIMULATE_FLAGS",
    "SimulateSettings",
    "MAX_HARMONICS",
    "MAX_LINES",
    "MODEL_KINDS",
    "MONITOR_METHODS",
    "SignalModel",
    "TIMESTAMP_POLICIES",
    "check_scheduler",
    "check_timestamp_policy",
    "resolve_device",
    "signal_model",
]

# The family-wise false-alarm rate of a record's named effects (the default of
# `DiagnoseSettings.alpha`, `jaxdefl diagnose --alpha`). 0.01, not 0.05: the noise model is never
# exactly right (coloured, frame-common, heavy-tailed extraction noise), so the realised rate on
# full-chain controls runs above the nominal one (2 false names in 20 records at 0.05), and a
# false name costs a reader more than a miss. The price: a line scanned over 100 frequencies
# (χ²₂) needs S = 36.9 for 90 % power instead of 32.8 (+12.5 % in evidence, +6 % in amplitude).
ALPHA_NAMED = 0.01

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
# parameter -> flag of `jaxdefl diagnose`
DIAGNOSE_FLAGS = {
    "sensor": "--sensor",
    "frame_rate_hz": "--frame-rate",
    "modulation_mhz": "--modulation-mhz",
    "segment": "--segment",
    "effects": "--effects",
    "alpha": "--alpha",
    "timestamps": "--timestamps",
}
# parameter -> flag of `jaxdefl reconcile`
RECONCILE_FLAGS = {
    "session": "--session",
    "segment": "--segment",
    "n_null": "--null-sims",
    "seed": "--seed",
    "timestamps": "--timestamps",
}
# parameter -> flag of `jaxdefl extract`
EXTRACT_FLAGS = {
    "realtime": "--realtime",
    "chunk_frames": "--chunk-frames",
    "device": "--device",
    "timestamps": "--timestamps",
}
# parameter -> flag of `jaxdefl simulate`
SIMULATE_FLAGS = {
    "duration_s": "--duration",
    "seed": "--seed",
    "session": "--session",
    "live": "--live",
    "speed": "--speed",
}
# parameter -> flag of `jaxdefl run`
RUN_FLAGS = {"scheduler": "--scheduler", "timestamps": "--timestamps"}
# parameter -> flag of `jaxdefl monitor`
MONITOR_FLAGS = {
    "replay": "--replay",
    "speed": "--speed",
    "until_s": "--until",
    "duration_s": "--duration",
    "method": "--method",
    "alarms_per_day": "--alarms-per-day",
    "block_s": "--block",
    "snapshot_s": "--snapshot",
    "idle_s": "--idle",
    "seed": "--seed",
    "timestamps": "--timestamps",
}
# --------------------------------------------------------------------------------------------
# the vocabularies the settings check (the stages import them from here)

TIMESTAMP_POLICIES = ("strict", "reclock", "merge")
MONITOR_METHODS = ("ekf", "rls")  # `jaxdefl.monitor.estimator.METHODS` implements each

ModelKind = Literal["harmonic", "damped"]
MODEL_KINDS = ("harmonic", "damped")
MAX_HARMONICS = 20
MAX_LINES = 8


@dataclass(frozen=True)
class SignalModel:
    """Which model `jaxdefl fit` fits (hashable: it is a static argument of the jitted kernels).

    Attributes:
        kind: "harmonic" (undamped sinusoids) or "damped" (each line decays exponentially).
        harmonics: K, components at f0, 2 f0, ..., K f0 (undamped only).
        lines: N, independent frequencies.
    """

    kind: ModelKind = "harmonic"
    harmonics: int = 1
    lines: int = 1

    @property
    def is_default(self) -> bool:
        """The thesis model (one harmonic + offset): fitted by `fit_harmonics`."""
        return self.kind == "harmonic" and self.harmonics == 1 and self.lines == 1

    @property
    def damped(self) -> bool:
        return self.kind == "damped"

    @property
    def n_components(self) -> int:
        return self.harmonics * self.lines

    @property
    def n_params(self) -> int:
        return 2 * self.n_components + 1 + self.lines * (2 if self.damped else 1)

    def line_of(self, j: int) -> int:
        """The frequency (line) that component ``j`` oscillates at."""
        return 0 if self.harmonics > 1 else j

    def multiplier(self, j: int) -> int:
        """Component ``j`` oscillates at ``multiplier(j)`` times its line's frequency."""
        return j + 1 if self.harmonics > 1 else 1

    @property
    def offset_index(self) -> int:
        return 2 * self.n_components

    def omega_index(self, line: int) -> int:
        return 2 * self.n_components + 1 + line

    def decay_index(self, line: int) -> int:
        return 2 * self.n_components + 1 + self.lines + line


def signal_model(kind: str = "harmonic", harmonics: int = 1, lines: int = 1) -> SignalModel:
    """A `SignalModel` from the `fit` flags ``--model``, ``--harmonics`` and ``--lines``.

    Raises:
        ConfigError: an unknown model, a count out of range, or flags that do not combine.
    """
    if kind not in MODEL_KINDS:
        raise ConfigError(f"--model: expected one of {', '.join(MODEL_KINDS)}, got {kind!r}")
    for flag, v, top in (("--harmonics", harmonics, MAX_HARMONICS), ("--lines", lines, MAX_LINES)):
        if isinstance(v, bool) or int(v) != v or not 1 <= v <= top:
            raise ConfigError(f"{flag}: expected a whole number from 1 to {top}, got {v}")
    if harmonics > 1 and lines > 1:
        raise ConfigError(
            f"--harmonics {harmonics} with --lines {lines}: expected one of them (harmonics of one f0, "
            "or independent lines), not both"
        )
    if kind == "damped" and harmonics > 1:
        raise ConfigError(
            f"--harmonics {harmonics} with --model damped: the damped model has no harmonics "
            "(use --lines N for several modes)"
        )
    return SignalModel(kind, int(harmonics), int(lines))


def check_timestamp_policy(policy: str) -> str:
    """The policy, or a ConfigError naming --timestamps and the choices."""
    if policy not in TIMESTAMP_POLICIES:
        raise ConfigError(f"--timestamps: expected one of {', '.join(TIMESTAMP_POLICIES)}, got {policy!r}")
    return policy


# a dask scheduler's address: [protocol://]host:port
_ADDRESS = re.compile(r"^(?:(?:tcp|tls|ucx|ws|wss)://)?(?:\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9._-]+):(\d{1,5})$")


def check_scheduler(scheduler: str) -> str:
    """The scheduler: none, local, local:N (N >= 1 workers) or an address ``[tcp://]host:port``;
    else a `ParameterError`."""
    s = scheduler.strip()
    kind, colon, n = s.partition(":")
    local = kind == "local" and (not colon or (n.isdigit() and int(n) >= 1))
    address = _ADDRESS.match(s)
    if not (s == "none" or local or (address and 1 <= int(address.group(1)) <= 65535)):
        raise ParameterError(
            "scheduler",
            "expected none, local, local:N with N >= 1 workers or a scheduler address host:port "
            f"(e.g. tcp://10.0.0.5:8786), got {scheduler!r}",
        )
    return s


AXES = ("z", "x", "y")


def _names(v: tuple[str, ...] | str) -> tuple[str, ...]:
    """A comma list (``"z,x"``) or a sequence of names as a tuple, blanks dropped."""
    return tuple(a.strip() for a in (v.split(",") if isinstance(v, str) else v) if a.strip())


def _check_axes(settings) -> None:
    """``settings.axes`` as a tuple of z, x, y (None: the axes present), or a `ParameterError`."""
    if settings.axes is not None:
        axes = _names(settings.axes)
        if not axes or any(a not in AXES for a in axes):
            raise ParameterError("axes", f"expected a comma list of z, x, y; got {_got(settings.axes)}")
        if len(set(axes)) < len(axes):
            twice = next(a for a in axes if axes.count(a) > 1)
            raise ParameterError(
                "axes", f"names {twice} twice in {_got(settings.axes)}; expected each axis once"
            )
        object.__setattr__(settings, "axes", axes)


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
        _check_axes(self)
        check_timestamp_policy(self.timestamps)
        # signal models other than the thesis' (the posterior check knows only the default model)
        spec = signal_model(self.model, self.harmonics, self.lines)
        if self.posterior is not None and not spec.is_default:
            raise ParameterError(
                "posterior",
                "checks the σ's of the default model only; drop it, or drop {model}/{harmonics}/{lines}",
            )
        object.__setattr__(self, "spec", spec)


def _check_positive(settings, names: tuple[str, ...], expected: str) -> None:
    """Each of ``names`` None or a finite number > 0, or a `ParameterError` naming it."""
    for name in names:
        v = getattr(settings, name)
        if v is not None and not (math.isfinite(v) and v > 0):
            raise ParameterError(name, f"expected {expected}, got {_got(v)}")


@dataclass(frozen=True)
class DiagnoseSettings:
    """What `jaxdefl diagnose` (`jaxdefl.diagnose.run_diagnosis`) knows of the camera and searches.

    ``sensor``, ``frame_rate_hz``, ``modulation_mhz``, ``tap_offsets`` (four fractions of the
    frame period): what the user knows of the camera (None: unknown; the frame rate then comes
    from the timestamps). ``depth_step_mm_at_2m``, ``jumps_per_minute``, ``jump_mm``: a
    structured-light camera's configured depth lattice (its step at 2 m; it grows as z²) and
    level jumps (their rate and RMS size), its nominal physics (`jaxdefl.diagnose._sensor_nominal`).
    ``segment``: the segment to diagnose when the table has several.
    ``effects``: restrict the library to these ids (a comma list or a tuple; None: all).
    ``alpha``: the family-wise false-alarm level of the named effects (a record of the nominal
    model gets any effect named with at most this probability; split over the effects and their
    scans). ``axes``: the axes diagnosed (None: z, x, y as present). ``timestamps``: the policy the
    tables are read with (`jaxdefl.io.validate_trajectory`). ``open_world``: search what the
    named effects leave with generic terms (`jaxdefl.diagnose.unnamed`).
    """

    sensor: str | None = None
    frame_rate_hz: float | None = None
    modulation_mhz: float | None = None
    tap_offsets: tuple[float, ...] | None = None
    depth_step_mm_at_2m: float | None = None
    jumps_per_minute: float | None = None
    jump_mm: float | None = None
    segment: str | None = None
    effects: tuple[str, ...] | str | None = None
    alpha: float = ALPHA_NAMED
    axes: tuple[str, ...] | str | None = None
    timestamps: str = "strict"
    open_world: bool = True

    def __post_init__(self):
        if self.sensor is not None and self.sensor not in SENSORS:
            raise ParameterError("sensor", f"expected one of {', '.join(SENSORS)}, got {_got(self.sensor)}")
        _check_positive(self, ("frame_rate_hz",), "a positive rate in Hz")
        _check_positive(self, ("modulation_mhz",), "a positive frequency in MHz")
        _check_positive(self, ("depth_step_mm_at_2m", "jump_mm"), "a positive size in mm")
        if self.jumps_per_minute is not None and not (
            math.isfinite(self.jumps_per_minute) and self.jumps_per_minute >= 0
        ):
            raise ParameterError(
                "jumps_per_minute", f"expected a rate >= 0 per minute, got {_got(self.jumps_per_minute)}"
            )
        if self.tap_offsets is not None:
            taps = tuple(float(o) for o in self.tap_offsets)
            if len(taps) != 4 or not all(0.0 <= o < 1.0 for o in taps):
                raise ParameterError(
                    "tap_offsets", f"expected 4 fractions of the frame period in [0, 1), got {list(taps)}"
                )
            object.__setattr__(self, "tap_offsets", taps)
        if self.effects is not None:
            effects = _names(self.effects)
            unknown = [e for e in effects if e not in EFFECT_IDS]
            if unknown or not effects:
                raise ParameterError(
                    "effects",
                    f"unknown effect {_got(unknown[0] if unknown else self.effects)} "
                    f"(expected one of {', '.join(EFFECT_IDS)})",
                )
            object.__setattr__(self, "effects", effects)
        if not (isinstance(self.alpha, int | float) and 0.0 < float(self.alpha) < 0.5):
            raise ParameterError("alpha", f"expected a false-alarm level in (0, 0.5), got {_got(self.alpha)}")
        _check_axes(self)
        check_timestamp_policy(self.timestamps)

    def with_camera(self, facts: dict) -> DiagnoseSettings:
        """These settings with the camera ``facts`` (a simulation config's) where they say nothing."""
        given = {k: v for k, v in facts.items() if getattr(self, k) is None}
        return replace(self, **given) if given else self


# Null simulations of `reconcile`: each costs a simulated record and its diagnosis scores; past
# this, the band's percentiles gain nothing and the command would run for days.
MAX_NULL_SIMS = 1000


@dataclass(frozen=True)
class ReconcileSettings:
    """Everything `jaxdefl reconcile` (`jaxdefl.reconcile.reconcile`) does besides its paths.

    ``session``, ``segment``: the config's session and the recording's segment (None: the
    first). ``n_null`` simulations make the null band (at least 5 for a 95 % band), ``n_sims``
    the before/after comparisons, from ``seed``. ``timestamps``: the policy the recording is
    read with. ``diagnosis``: what the diagnosis of the recording knows of the camera.
    """

    session: str | None = None
    segment: str | None = None
    n_null: int = 20
    n_sims: int = 4
    seed: int = 0
    timestamps: str = "strict"
    diagnosis: DiagnoseSettings = field(default_factory=DiagnoseSettings)

    def __post_init__(self):
        if not 5 <= self.n_null <= MAX_NULL_SIMS:
            raise ParameterError(
                "n_null",
                f"expected at least 5 simulations for a 95 % band and at most {MAX_NULL_SIMS} "
                f"(each is a whole simulated record), got {self.n_null}",
            )
        if self.n_sims < 1:
            raise ParameterError("n_sims", f"expected at least 1 simulation, got {self.n_sims}")
        if self.seed < 0:
            raise ParameterError("seed", f"expected a seed >= 0, got {self.seed}")
        check_timestamp_policy(self.timestamps)


def _check_seed(settings) -> None:
    if settings.seed is not None and settings.seed < 0:
        raise ParameterError("seed", f"expected a seed >= 0, got {settings.seed}")


def resolve_device(device: str | None) -> str:
    """The torch device of the extraction: ``cpu``, ``cuda`` or ``cuda:N``; None: CUDA if available.

    Raises:
        ParameterError: an unknown device, or CUDA asked for where there is none.
    """
    import torch  # only for a device: the settings module stays light

    if device is None or device == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    name = str(device).strip().lower()
    if name == "cpu":
        return name
    if name == "cuda" or (name.startswith("cuda:") and name[5:].isdigit()):
        if not torch.cuda.is_available():
            raise ParameterError(
                "device", f"{device}: CUDA is not available (torch {torch.__version__}); use cpu"
            )
        index = int(name[5:]) if ":" in name else 0
        if index >= torch.cuda.device_count():
            raise ParameterError(
                "device", f"{device}: this machine has {torch.cuda.device_count()} CUDA device(s)"
            )
        return name
    raise ParameterError("device", f"expected cpu, cuda or cuda:N, got {device!r}")


@dataclass(frozen=True)
class ExtractSettings:
    """Everything `jaxdefl extract` (`jaxdefl.frames.extract_to_table`) does besides its paths.

    ``realtime``: track the plates detected once instead of detecting them in every frame.
    ``chunk_frames``: frames per batch. ``device``: the torch device (cpu, cuda, cuda:N; None:
    CUDA if there is one), resolved when the settings are made. ``timestamps``: strict or
    reclock (frame recordings have no duplicate rows to merge).
    """

    realtime: bool = False
    chunk_frames: int = 256
    device: str | None = None
    timestamps: str = "strict"

    def __post_init__(self):
        if self.chunk_frames < 1:
            raise ParameterError("chunk_frames", f"expected an integer >= 1, got {self.chunk_frames}")
        if self.timestamps not in ("strict", "reclock"):
            raise ParameterError(
                "timestamps", f"expected strict or reclock for frames, got {_got(self.timestamps)}"
            )
        object.__setattr__(self, "device", resolve_device(self.device))


@dataclass(frozen=True)
class SimulateSettings:
    """Everything `jaxdefl simulate` does besides its config and output directory.

    ``duration_s`` and ``seed`` override the config's (None: the config's); ``session``: a
    ``[[session]]`` of the config (None: the first); ``live`` appends measured centroids as
    they come, ``speed`` times real time.
    """

    duration_s: float | None = None
    seed: int | None = None
    session: str | None = None
    live: bool = False
    speed: float = 1.0

    def __post_init__(self):
        d = self.duration_s
        if d is not None and not (math.isfinite(d) and d > 0):
            raise ParameterError("duration_s", f"expected a duration > 0 s, got {_got(d)}")
        _check_seed(self)
        _check_positive(self, ("speed",), "a factor > 0")


@dataclass(frozen=True)
class RunSettings:
    """Everything `jaxdefl run` does besides its campaign config and output directory.

    ``scheduler``: none (in-process), local or local:N (a dask LocalCluster of N workers) or a
    scheduler's address. ``timestamps`` overrides the campaign's ``processing.timestamps``.
    """

    scheduler: str = "none"
    timestamps: str | None = None

    def __post_init__(self):
        check_scheduler(self.scheduler)
        if self.timestamps is not None:
            check_timestamp_policy(self.timestamps)


@dataclass(frozen=True)
class MonitorSettings:
    """Everything `jaxdefl monitor` (`jaxdefl.monitor.run.run_monitor`) does besides its paths.

    ``replay``: replay the source as if live. ``speed``: times real time for a replayed or
    simulated source (0: as fast as it goes). ``until_s`` s of data, ``duration_s`` s of wall
    clock: when to stop (None: at the end). ``method``: the recursive estimator (ekf or rls).
    ``alarms_per_day``: false alarms allowed per day of data, ``block_s`` the change-detection
    block, ``snapshot_s`` s of data between estimate snapshots, ``idle_s`` s without data that
    end a followed source. ``seed``: a simulated camera's seed. ``timestamps``: the policy of a
    replayed table (a followed or simulated source is read strictly, as it arrives).
    """

    replay: bool = False
    speed: float = 1.0
    until_s: float | None = None
    duration_s: float | None = None
    method: str = "ekf"
    alarms_per_day: float = 1.0
    block_s: float = 5.0
    snapshot_s: float = 10.0
    idle_s: float = 10.0
    seed: int | None = None
    timestamps: str = "strict"

    def __post_init__(self):
        if not (math.isfinite(self.speed) and self.speed >= 0):
            raise ParameterError(
                "speed", f"expected a factor >= 0 (0: as fast as it goes), got {_got(self.speed)}"
            )
        _check_positive(self, ("until_s", "duration_s", "block_s", "snapshot_s", "idle_s"), "a time > 0 s")
        _check_positive(self, ("alarms_per_day",), "a rate > 0 per day")
        _check_seed(self)
        if self.method not in MONITOR_METHODS:
            raise ParameterError(
                "method", f"expected one of {', '.join(MONITOR_METHODS)}, got {_got(self.method)}"
            )
        check_timestamp_policy(self.timestamps)
        if self.timestamps != "strict" and not self.replay:
            raise ParameterError(
                "timestamps",
                f"{self.timestamps} applies to {{replay}} of a table; a followed or simulated source "
                "is read as it arrives (strict)",
            )
