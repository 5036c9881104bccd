"""Simulation configs: TOML tables -> frozen dataclasses, validated at the boundary.

A config describes one recording session. Optional ``[[session]]`` entries (a ``name`` plus
partial tables such as ``loading = {frequency_hz = 3.0680}``) are merged over the base tables;
``recording.session`` (or the ``session`` argument of `load_config`) picks one, default the first.

Coordinates: world X along the beam from the left support, Y lateral from the beam axis (plates on
the +Y side), Z downward from the beam top surface; the camera looks straight down (nadir) from
(camera.x_mm, camera.y_mm, -camera.standoff_mm). Trajectories are written in the camera frame
(X along the image columns = along the beam, Y along the rows, Z = depth, growing downward), so a
downward deflection is a positive z change; the LDS report the same deflection, downward positive.
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .._configs import not_found_hint, resolve_config
from .._errors import ConfigError
from .injection import EffectSpec, parse_effects
from .schedule import CHANGE_IDS, parse_changes

__all__ = [
    "SimConfig",
    "RecordingConfig",
    "BeamConfig",
    "PlatesConfig",
    "SceneConfig",
    "LoadingConfig",
    "FatigueConfig",
    "CameraConfig",
    "LDSConfig",
    "load_config",
    "config_from_dict",
    "list_sessions",
    "SENSOR_MAX_FRAME_RATE_HZ",
    "SPEED_OF_LIGHT_M_S",
]

SPEED_OF_LIGHT_M_S = 299_792_458.0
SENSOR_MAX_FRAME_RATE_HZ = {"sr4000": 54.0, "kinect": 30.0}
_SENSOR_DEFAULTS = {
    # width, height, field of view (deg) of Table 4.1 (SR4000-0040001, the USB Cam 2) and 4.2
    "sr4000": dict(width=176, height=144, fov_deg=(43.6, 34.6)),
    "kinect": dict(width=640, height=480, fov_deg=(57.0, 43.0)),
}


@dataclass(frozen=True)
class RecordingConfig:
    segment: str = "day1"
    day: int = 1
    duration_s: float = 60.0
    seed: int = 0
    start_epoch_s: float = 1.7e9  # plus (day - 1) days
    cycles_at_start: float = 32400.0
    chunk_frames: int = 200
    session: str = ""


@dataclass(frozen=True)
class BeamConfig:
    span_mm: float = 3400.0  # between supports
    overhang_mm: float = 100.0
    load_a_mm: float = 1200.0  # distance of each load point from its support
    width_mm: float = 150.0
    height_mm: float = 300.0
    reflectivity: float = 0.8  # painted white


@dataclass(frozen=True)
class PlatesConfig:
    count: int = 13
    x0_mm: float = 200.0
    spacing_mm: float = 250.0
    length_mm: float = 220.0
    width_mm: float = 50.0
    # Plates are bonded to the beam's side at its bottom (thesis 4.1, 6.2.1: "attached to the
    # bottom side"), sticking out horizontally; the depth classification of 5.1.1 keeps what lies
    # between the beam top (second threshold) and the floor (first): the plates are deeper than the
    # top surface. Their top face sits this far below the beam top (beam height less a thin plate).
    depth_below_top_mm: float = 295.0
    reflectivity: float = 0.9  # white-washed aluminium


@dataclass(frozen=True)
class SceneConfig:
    floor_below_top_mm: float = 800.0
    floor_reflectivity: float = 0.05  # black paper
    target_reflectivity: float = 0.9  # white circular targets
    target_radius_mm: float = 30.0
    target_spacing_mm: float = 400.0
    occluders: bool = True  # spreader beam and actuator


@dataclass(frozen=True)
class LoadingConfig:
    frequency_hz: float = 3.0680
    amplitude_mm: float = 2.32  # mid-span (plate 7) amplitude at the start of the recording
    mean_mm: float = 0.0  # mean deflection about which the beam oscillates
    phase_rad: float = 0.0
    longitudinal_mm: float = 0.5  # in-phase rigid motion along the beam
    lateral_mm: float = 0.05


@dataclass(frozen=True)
class FatigueConfig:
    """Amplitude growth with load cycles N: A(N) = amplitude_mm * F(N) / F(N_start)."""

    law: str = "log"  # "log" (a + b ln N), "linear" (a + b N) or "none"
    cycles: tuple[float, float] = (32400.0, 880286.0)  # Table 6.16 (LDS)
    amplitude_mm: tuple[float, float] = (2.32, 2.63)


@dataclass(frozen=True)
class CameraConfig:
    sensor: str = "sr4000"
    name: str = "cam2"
    frame_rate_hz: float = 20.0
    modulation_mhz: float = 29.0
    width: int = 0  # 0: the sensor's default
    height: int = 0
    fov_deg: tuple[float, float] = (0.0, 0.0)
    x_mm: float = 1700.0
    y_mm: float = 400.0
    standoff_mm: float = 1900.0  # camera to beam top surface
    # orientation: the camera frame is the world frame turned by R = Rz(yaw) Ry(pitch) Rx(roll)
    # (`jaxdefl.simulate.scene.camera_rotation`); all zero: looking straight down
    roll_deg: float = 0.0
    pitch_deg: float = 0.0
    yaw_deg: float = 0.0
    # the camera's own clock: it stamps a frame taken at true time t with
    # t0 + clock_offset_ms / 1000 + (1 + clock_drift_ppm 1e-6) (t - t0)
    clock_offset_ms: float = 0.0
    clock_drift_ppm: float = 0.0
    plates: tuple[int, ...] = ()  # plates that must be in view (validated)
    tap_offsets: tuple[float, float, float, float] = (0.0, 0.25, 0.5, 0.75)  # x frame period
    integration_time_ms: float = 0.0  # 0: from the frame rate (Section 4.3.2)
    noise_scale: float = 1.0
    # ToF: per-frame range error correlated across pixels (a modulation-phase offset common to the
    # frame plus a smooth part across the image), sized so that a plate centroid's residual about
    # the true motion matches the thesis (Tables 6.2/6.7 for cam3/cam4, 6.12/6.17 for cam2)
    calibration: str = ""  # cam2, cam3 or cam4; "": camera.name if it is one of them, else cam2
    centroid_residual_mm: float = -1.0  # -1: from the calibration unit's table; 0: no such error
    correlated_spatial_fraction: float = 0.1  # share of its variance in a per-frame tilt
    dropout_prob: float = 0.03
    scattering: float = 0.003
    supersample: int = 4
    timestamp_jitter_ms: float = 0.0
    # structured light
    baseline_mm: float = 75.0
    depth_resolution_mm_at_2m: float = 3.0  # Table 4.2
    disparity_noise_px: float = 0.1
    frame_noise_mm: float = 0.4
    session_shift_mm: float = 17.0  # Table 6.21
    jumps_per_minute: float = 1.0
    jump_mm: float = 3.0


@dataclass(frozen=True)
class LDSConfig:
    enabled: bool = True
    rate_hz: float = 300.0
    noise_um: float = 2.0
    plates: tuple[int, ...] = (3, 5, 7, 9, 11)
    defective_plate: int = 0  # 0: none; the thesis' plate 9
    defect_gain: float = 0.6
    defect_noise_um: float = 40.0


@dataclass(frozen=True)
class SimConfig:
    recording: RecordingConfig = field(default_factory=RecordingConfig)
    beam: BeamConfig = field(default_factory=BeamConfig)
    plates: PlatesConfig = field(default_factory=PlatesConfig)
    scene: SceneConfig = field(default_factory=SceneConfig)
    loading: LoadingConfig = field(default_factory=LoadingConfig)
    fatigue: FatigueConfig = field(default_factory=FatigueConfig)
    camera: CameraConfig = field(default_factory=CameraConfig)
    lds: LDSConfig = field(default_factory=LDSConfig)
    # [[effect]] tables, then [[change]] tables (their scheduled spelling): one registry,
    # `jaxdefl.simulate.injection`
    effects: tuple[EffectSpec, ...] = ()
    source: str = "<config>"
    # several cameras at once ([[camera]] tables): `camera` is the first; `for_camera` gives the
    # config of one of them. Empty for a single [camera] table.
    cameras: tuple[CameraConfig, ...] = ()
    # per effect: the name of the one camera it is scoped to (key ``camera`` of its table), or ""
    effect_cameras: tuple[str, ...] = ()

    def to_dict(self) -> dict:
        """The effective config as TOML-shaped tables: `config_from_dict` reads it back (every
        effect as an ``[[effect]]`` table, ``[[change]]`` ones included)."""
        d = dataclasses.asdict(
            self, dict_factory=lambda kv: {k: list(v) if isinstance(v, tuple) else v for k, v in kv}
        )
        for key in ("source", "effects", "cameras", "effect_cameras"):
            d.pop(key)
        if self.cameras:
            d["camera"] = [d_cam for d_cam in (_as_table(c) for c in self.cameras)]
        if self.effects:
            d["effect"] = [e.to_dict() for e in self.effects]
            for table, cam in zip(d["effect"], self._scopes(), strict=True):
                if cam:
                    table["camera"] = cam
        return d

    def _scopes(self) -> tuple[str, ...]:
        # a config whose effects were replaced (dataclasses.replace(cfg, effects=...)) without
        # their scopes has every effect on every camera
        if len(self.effect_cameras) == len(self.effects):
            return self.effect_cameras
        return ("",) * len(self.effects)

    @property
    def camera_names(self) -> tuple[str, ...]:
        """The names of the cameras, in config order (one for a single [camera] table)."""
        return tuple(c.name for c in self.cameras) or (self.camera.name,)

    def for_camera(self, name: str) -> SimConfig:
        """The single-camera config of camera ``name``: its camera, the effects scoped to it and
        the unscoped ones."""
        if not self.cameras:
            return self
        cam = next(c for c in self.cameras if c.name == name)
        effects = tuple(e for e, c in zip(self.effects, self._scopes(), strict=True) if c in ("", name))
        return dataclasses.replace(self, camera=cam, cameras=(), effects=effects, effect_cameras=())

    @property
    def changes(self) -> tuple[EffectSpec, ...]:
        """The scheduled effects (the ids a ``[[change]]`` table spells: stiffness_change,
        debond, sensor_fault), in config order."""
        return tuple(e for e in self.effects if e.id in CHANGE_IDS.values())

    @property
    def t0_s(self) -> float:
        return self.recording.start_epoch_s + (self.recording.day - 1) * 86400.0

    def plate_x_mm(self) -> list[float]:
        return [self.plates.x0_mm + i * self.plates.spacing_mm for i in range(self.plates.count)]


def _as_table(obj: Any) -> dict:
    return dataclasses.asdict(
        obj, dict_factory=lambda kv: {k: list(v) if isinstance(v, tuple) else v for k, v in kv}
    )


_SECTIONS = {
    f.name: f.type
    for f in dataclasses.fields(SimConfig)
    if f.name not in ("source", "effects", "cameras", "effect_cameras")
}
_CLASSES = {
    "recording": RecordingConfig,
    "beam": BeamConfig,
    "plates": PlatesConfig,
    "scene": SceneConfig,
    "loading": LoadingConfig,
    "fatigue": FatigueConfig,
    "camera": CameraConfig,
    "lds": LDSConfig,
}


def _err(src: str, key: str, expected: str, got: Any) -> ConfigError:
    return ConfigError(f"{src}: key {key!r}: expected {expected}, got {got!r}")


def _coerce(src: str, key: str, default: Any, value: Any) -> Any:
    """Convert a TOML value to the type of the dataclass default."""
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise _err(src, key, "true or false", value)
        return value
    if isinstance(default, int):
        if isinstance(value, bool) or not isinstance(value, int):
            raise _err(src, key, "an integer", value)
        return value
    if isinstance(default, float):
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise _err(src, key, "a number", value)
        return float(value)
    if isinstance(default, str):
        if not isinstance(value, str):
            raise _err(src, key, "a string", value)
        return value
    if isinstance(default, tuple):
        if not isinstance(value, list):
            raise _err(src, key, "a list", value)
        kind = type(default[0]) if default else int
        if default and len(value) != len(default) and len(default) in (2, 4) and kind is float:
            raise _err(src, key, f"a list of {len(default)} numbers", value)
        out = []
        for v in value:
            if kind is float and isinstance(v, (int, float)) and not isinstance(v, bool):
                out.append(float(v))
            elif kind is int and isinstance(v, int) and not isinstance(v, bool):
                out.append(v)
            else:
                raise _err(src, key, f"a list of {'numbers' if kind is float else 'integers'}", value)
        return tuple(out)
    raise AssertionError(key)


def _section(src: str, name: str, table: Any, prefix: str = "", label: str = "") -> Any:
    cls = _CLASSES[name]
    label = label or prefix + name
    if not isinstance(table, dict):
        raise _err(src, label, "a table", table)
    defaults = cls()
    names = [f.name for f in dataclasses.fields(cls)]
    kwargs = {}
    for key, value in table.items():
        if key not in names:
            raise ConfigError(f"{src}: unknown key {label + '.' + key!r}; expected one of {', '.join(names)}")
        kwargs[key] = _coerce(src, label + "." + key, getattr(defaults, key), value)
    return cls(**kwargs)


def _complete_camera(src: str, cam: CameraConfig, table: dict, label: str = "camera") -> CameraConfig:
    """The sensor's defaults for what ``table`` leaves out (size, field of view, Kinect rate)."""
    sensor = cam.sensor
    if sensor not in _SENSOR_DEFAULTS:
        raise _err(src, label + ".sensor", "one of " + ", ".join(_SENSOR_DEFAULTS), sensor)
    d = _SENSOR_DEFAULTS[sensor]
    cam = dataclasses.replace(
        cam,
        width=cam.width or d["width"],
        height=cam.height or d["height"],
        fov_deg=cam.fov_deg if cam.fov_deg[0] > 0 else d["fov_deg"],
    )
    if sensor == "kinect" and "frame_rate_hz" not in table:
        cam = dataclasses.replace(cam, frame_rate_hz=30.0)
    return cam


def _camera_tables(src: str, tables: list) -> tuple[CameraConfig, ...]:
    """``[[camera]]`` tables -> cameras with unique names."""
    if not tables or not all(isinstance(t, dict) for t in tables):
        raise _err(src, "camera", "a [camera] table or an array of tables [[camera]]", tables)
    cams = []
    for i, table in enumerate(tables):
        label = f"camera[{i + 1}]"
        if "name" not in table:
            raise ConfigError(f"{src}: key {label + '.name'!r}: expected a camera name, got nothing")
        cam = _section(src, "camera", table, label=label)
        cams.append(_complete_camera(src, cam, table, label))
    names = [c.name for c in cams]
    for i, name in enumerate(names):
        if not name or name in names[:i] or not name.replace("_", "").replace("-", "").isalnum():
            raise _err(
                src,
                f"camera[{i + 1}].name",
                "a unique name of letters, digits, - and _ (it names the camera's files)",
                name,
            )
    return tuple(cams)


def _effect_scopes(src: str, tables: Any, names: tuple[str, ...]) -> tuple[list, list[str]]:
    """Strip each [[effect]] table's ``camera`` key: (tables without it, the camera or "")."""
    if not isinstance(tables, list):
        return tables, []
    stripped, scopes = [], []
    for i, t in enumerate(tables):
        if isinstance(t, dict) and "camera" in t:
            t = dict(t)
            cam = t.pop("camera")
            if cam not in names:
                raise _err(src, f"effect[{i + 1}].camera", f"one of the cameras {', '.join(names)}", cam)
            scopes.append(cam)
        else:
            scopes.append("")
        stripped.append(t)
    return stripped, scopes


def _merge(base: dict, over: dict) -> dict:
    out = {k: dict(v) if isinstance(v, dict) else v for k, v in base.items()}
    for k, v in over.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = {**out[k], **v}
        else:
            out[k] = v
    return out


def list_sessions(raw: dict) -> list[str]:
    """Names of the ``[[session]]`` entries of a raw config table."""
    return [str(s.get("name", i + 1)) for i, s in enumerate(raw.get("session", []))]


def config_from_dict(raw: dict, source: str = "<config>", session: str | None = None) -> SimConfig:
    """Validate a raw (TOML-shaped) dict and return the effective `SimConfig`.

    Raises:
        ConfigError: unknown keys, wrong types, impossible values (see `validate`).
    """
    raw = dict(raw)
    sessions = raw.pop("session", [])
    effect_tables = raw.pop("effect", [])
    raw_changes = raw.pop("change", [])
    if not isinstance(sessions, list) or not all(isinstance(s, dict) for s in sessions):
        raise _err(source, "session", "an array of tables [[session]]", sessions)
    for key in raw:
        if key not in _SECTIONS:
            raise ConfigError(
                f"{source}: unknown key {key!r}; expected one of "
                f"{', '.join(list(_SECTIONS) + ['session', 'effect', 'change'])}"
            )
    wanted = session if session is not None else raw.get("recording", {}).get("session", "") or None
    if sessions:
        names = [str(s.get("name", "")) for s in sessions]
        if wanted is None:
            chosen = sessions[0]
        elif wanted in names:
            chosen = sessions[names.index(wanted)]
        else:
            raise _err(source, "recording.session", f"one of {', '.join(names)}", wanted)
        chosen = dict(chosen)
        name = str(chosen.pop("name", ""))
        for key, val in chosen.items():
            if key not in _SECTIONS:
                raise ConfigError(
                    f"{source}: unknown key {'session[' + name + '].' + key!r}; "
                    f"expected one of name, {', '.join(_SECTIONS)}"
                )
            if not isinstance(val, dict):
                raise _err(source, f"session[{name}].{key}", "a table", val)
        raw = _merge(raw, chosen)
        raw.setdefault("recording", {})
        raw["recording"] = {**raw["recording"], "session": name}
        raw["recording"].setdefault("segment", name)
    elif wanted:
        raise _err(source, "recording.session", "no session (the file has no [[session]] entries)", wanted)
    camera_tables = raw.pop("camera") if isinstance(raw.get("camera"), list) else None
    if camera_tables is not None and sessions:
        raise ConfigError(
            f"{source}: key 'camera': expected one [camera] table with [[session]] entries, got "
            f"{len(camera_tables)} [[camera]] tables (several cameras record one session)"
        )
    parts = {name: _section(source, name, raw.get(name, {})) for name in _SECTIONS}
    cameras: tuple[CameraConfig, ...] = ()
    if camera_tables is not None:
        cameras = _camera_tables(source, camera_tables)
        parts["camera"] = cameras[0]
    else:
        parts["camera"] = _complete_camera(source, parts["camera"], raw.get("camera", {}))
    names = tuple(c.name for c in cameras)
    effect_tables, scopes = _effect_scopes(source, effect_tables, names)
    effects = parse_effects(source, effect_tables, parts["plates"].count)
    effects += parse_changes(source, raw_changes, parts["plates"].count)
    scoped = tuple(scopes) + ("",) * (len(effects) - len(scopes)) if any(scopes) else ()
    for i, (e, cam) in enumerate(zip(effects, scoped or ("",) * len(effects), strict=True)):
        if cam and e.level not in ("range", "timestamps"):
            raise _err(
                source,
                f"effect[{i + 1}].camera",
                f"no camera for {e.id} (it moves the structure; only range and timestamps effects "
                "are one camera's)",
                cam,
            )
    cfg = SimConfig(**parts, effects=effects, source=source, cameras=cameras, effect_cameras=scoped)
    for name in cfg.camera_names:
        validate(cfg.for_camera(name), f"camera[{names.index(name) + 1}]" if cameras else "camera")
    return cfg


def load_config(path: Path | str, session: str | None = None) -> SimConfig:
    """Read a simulation config (TOML), merge the chosen session and validate it.

    Raises:
        ConfigError: missing or unparsable file, unknown keys, impossible values.
    """
    path = resolve_config(path)
    if not path.exists():
        raise ConfigError(f"{path}: file not found; expected a simulation config (TOML){not_found_hint()}")
    if not path.is_file():
        raise ConfigError(f"{path}: is a directory; expected a simulation config file (TOML)")
    try:
        raw = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as err:
        raise ConfigError(f"{path}: not valid TOML ({err})") from None
    except (OSError, UnicodeDecodeError) as err:
        raise ConfigError(f"{path}: cannot be read as a TOML text file ({type(err).__name__})") from None
    return config_from_dict(raw, str(path), session)


def validate(cfg: SimConfig, camera_key: str = "camera") -> None:
    """Physical and geometric checks; one-line `ConfigError` naming file and key (the camera's
    keys under ``camera_key``: ``camera`` or ``camera[2]``)."""
    src, cam = cfg.source, cfg.camera

    def _err(src: str, key: str, expected: str, got: Any) -> ConfigError:
        if key.startswith("camera."):
            key = camera_key + key[len("camera") :]
        return ConfigError(f"{src}: key {key!r}: expected {expected}, got {got!r}")

    rec = cfg.recording
    if not rec.duration_s > 0:
        raise _err(src, "recording.duration_s", "a duration > 0 s", rec.duration_s)
    if rec.chunk_frames < 1:
        raise _err(src, "recording.chunk_frames", "an integer >= 1", rec.chunk_frames)
    fmax = SENSOR_MAX_FRAME_RATE_HZ[cam.sensor]
    if not 0 < cam.frame_rate_hz <= fmax:
        raise ConfigError(
            f"{src}: key '{camera_key}.frame_rate_hz': expected <= {fmax:g} Hz for the "
            f"{'SR4000' if cam.sensor == 'sr4000' else 'Kinect'} (and > 0), got {cam.frame_rate_hz:g}"
        )
    if cam.sensor == "sr4000" and not 5.0 <= cam.modulation_mhz <= 60.0:
        raise _err(src, "camera.modulation_mhz", "a modulation frequency in 5-60 MHz", cam.modulation_mhz)
    if len(cam.tap_offsets) != 4 or not all(0.0 <= o < 1.0 for o in cam.tap_offsets):
        raise _err(
            src, "camera.tap_offsets", "4 fractions of the frame period in [0, 1)", list(cam.tap_offsets)
        )
    if not 0.0 <= cam.dropout_prob < 1.0:
        raise _err(src, "camera.dropout_prob", "a probability in [0, 1)", cam.dropout_prob)
    if cam.calibration not in ("", "cam2", "cam3", "cam4"):
        raise _err(src, "camera.calibration", "one of cam2, cam3, cam4 (or empty)", cam.calibration)
    if cam.centroid_residual_mm < 0 and cam.centroid_residual_mm != -1.0:
        raise _err(
            src,
            "camera.centroid_residual_mm",
            "a value >= 0 mm (or -1: calibrated)",
            cam.centroid_residual_mm,
        )
    if not 0.0 <= cam.correlated_spatial_fraction <= 1.0:
        raise _err(
            src, "camera.correlated_spatial_fraction", "a fraction in [0, 1]", cam.correlated_spatial_fraction
        )
    if cam.noise_scale < 0:
        raise _err(src, "camera.noise_scale", "a value >= 0", cam.noise_scale)
    if cam.supersample < 1:
        raise _err(src, "camera.supersample", "an integer >= 1", cam.supersample)
    for key in ("roll_deg", "pitch_deg", "yaw_deg"):
        angle = getattr(cam, key)
        if cam.sensor != "sr4000" and angle != 0.0:
            raise _err(src, "camera." + key, "0 for a Kinect (only ToF cameras turn)", angle)
        if not abs(angle) <= 20.0:
            raise _err(src, "camera." + key, "an angle within +-20 deg of looking straight down", angle)
    if not abs(cam.clock_drift_ppm) <= 1000.0:
        raise _err(src, "camera.clock_drift_ppm", "a clock rate error within +-1000 ppm", cam.clock_drift_ppm)
    if cfg.loading.frequency_hz <= 0:
        raise _err(src, "loading.frequency_hz", "a frequency > 0 Hz", cfg.loading.frequency_hz)
    if cfg.fatigue.law not in ("log", "linear", "none"):
        raise _err(src, "fatigue.law", "one of log, linear, none", cfg.fatigue.law)
    if cfg.fatigue.law != "none" and min(cfg.fatigue.cycles) <= 0:
        raise _err(src, "fatigue.cycles", "two cycle counts > 0", list(cfg.fatigue.cycles))
    if cfg.lds.rate_hz <= 0:
        raise _err(src, "lds.rate_hz", "a rate > 0 Hz", cfg.lds.rate_hz)
    if not -cfg.camera.standoff_mm < cfg.plates.depth_below_top_mm < cfg.scene.floor_below_top_mm:
        raise _err(
            src,
            "plates.depth_below_top_mm",
            f"a depth between the camera and the floor ({cfg.scene.floor_below_top_mm:g} mm below the top)",
            cfg.plates.depth_below_top_mm,
        )
    n = cfg.plates.count
    for key, plates in (("lds.plates", cfg.lds.plates), ("camera.plates", cam.plates)):
        bad = [p for p in plates if not 1 <= p <= n]
        if bad:
            raise _err(src, key, f"plate numbers in 1..{n}", bad[0])
    if cfg.lds.defective_plate and cfg.lds.defective_plate not in cfg.lds.plates:
        raise _err(
            src,
            "lds.defective_plate",
            f"0 or one of lds.plates {list(cfg.lds.plates)}",
            cfg.lds.defective_plate,
        )
    # impossible geometry: a plate the camera must see lies (partly) outside the field of view
    from .scene import plate_image_bounds  # scene depends on config only for its types

    for p in cam.plates:
        u0, u1, v0, v1 = plate_image_bounds(cfg, p)
        if u0 < 0 or v0 < 0 or u1 > cam.width or v1 > cam.height:
            raise ConfigError(
                f"{src}: key '{camera_key}.plates': expected plates inside the {cam.width}x{cam.height} "
                f"field of view, got plate {p} at columns {u0:.0f}..{u1:.0f}, rows {v0:.0f}..{v1:.0f}"
            )
