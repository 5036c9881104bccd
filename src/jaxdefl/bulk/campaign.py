"""Campaign configs: many recordings (days x cameras) and the processing options.

```toml
[campaign]
name = "exp2-3hz"

[processing]               # every key optional
window_s = 600.0           # windows within each recording (default: one fit per recording)
step_s = 600.0
axes = ["z", "x", "y"]
fmin_hz = 0.5
fmax_hz = 10.0
oversampling = 5.0
fap_max = 0.01
reference_plate = 7        # the plate of the per-day tables and the fatigue curve
plate_x_mm = [...]         # plate positions along the beam (default: 13 plates at 250 mm)
span_mm = 3400.0           # beam span and load-point distance for the profile fit
load_a_mm = 1200.0
timestamps = "strict"      # or "reclock" / "merge": how the tables' timestamps are read
                           # (`jaxdefl.io.validate_trajectory`; `jaxdefl run --timestamps` overrides)
model = "harmonic"         # signal model, harmonics and lines as `jaxdefl fit` --model,
harmonics = 1              # --harmonics and --lines (default: the thesis' harmonic + offset)
lines = 1

[[recording]]              # one per day and camera
day = 1
camera = "cam2"
cycles = 32400
trajectories = "day01/traj.csv"   # relative to this file
lds = "day01/lds.csv"             # optional reference
```

Instead of ``[[recording]]`` entries, a ``[simulate]`` table makes the recordings with the
simulator (see `jaxdefl.bulk.simulated`).
"""

from __future__ import annotations

import json
import tomllib
from dataclasses import asdict, dataclass, field
from pathlib import Path

from .._configs import not_found_hint, resolve_config
from .._errors import ConfigError
from ..io.trajectory import TIMESTAMP_POLICIES

__all__ = ["Campaign", "Processing", "Recording", "check_plates", "load_campaign"]


@dataclass(frozen=True)
class Processing:
    window_s: float | None = None
    step_s: float | None = None
    axes: tuple[str, ...] = ("z", "x", "y")
    fmin_hz: float | None = None
    fmax_hz: float | None = None
    oversampling: float = 5.0
    fap_max: float = 0.01
    reference_plate: int = 7
    plate_x_mm: tuple[float, ...] = tuple(200.0 + 250.0 * i for i in range(13))
    span_mm: float = 3400.0
    load_a_mm: float = 1200.0
    correct_motion_artefact: bool = False
    timestamps: str = "strict"
    model: str = "harmonic"
    harmonics: int = 1
    lines: int = 1

    def estimation_kwargs(self) -> dict:
        return dict(
            window_s=self.window_s,
            step_s=self.step_s,
            axes=self.axes,
            fmin_hz=self.fmin_hz,
            fmax_hz=self.fmax_hz,
            oversampling=self.oversampling,
            fap_max=self.fap_max,
        )

    def digest_source(self) -> str:
        d = asdict(self)
        if (d["model"], d["harmonics"], d["lines"]) == ("harmonic", 1, 1):
            # the default signal model leaves the digest of configs written before it existed
            del d["model"], d["harmonics"], d["lines"]
        return json.dumps(d, sort_keys=True)


@dataclass(frozen=True)
class Recording:
    day: int
    camera: str
    cycles: int
    trajectories: Path | None = None
    lds: Path | None = None
    simulate: dict | None = None  # simulator arguments when the campaign makes its own data
    failed: str = ""  # why the recording could not be made (simulated campaigns)
    truth: Path | None = None  # true trajectories (simulated campaigns)
    frame_rate_hz: float | None = None  # ToF facts for the motion-artefact correction
    tap_offsets: tuple[float, ...] | None = None

    @property
    def unit_id(self) -> str:
        return f"day{self.day:02d}-{self.camera}"


@dataclass(frozen=True)
class Campaign:
    name: str
    path: Path
    processing: Processing
    recordings: tuple[Recording, ...] = field(default_factory=tuple)
    simulate: dict | None = None


_TOP = {"campaign", "processing", "recording", "simulate"}
_PROC_TYPES = {
    "window_s": (int, float),
    "step_s": (int, float),
    "axes": list,
    "fmin_hz": (int, float),
    "fmax_hz": (int, float),
    "oversampling": (int, float),
    "fap_max": (int, float),
    "reference_plate": int,
    "plate_x_mm": list,
    "span_mm": (int, float),
    "load_a_mm": (int, float),
    "correct_motion_artefact": bool,
    "timestamps": str,
    "model": str,
    "harmonics": int,
    "lines": int,
}
_REC_KEYS = {
    "day": int,
    "camera": str,
    "cycles": int,
    "trajectories": str,
    "lds": str,
    "frame_rate_hz": (int, float),
    "tap_offsets": list,
}


def _err(path: Path, key: str, msg: str) -> ConfigError:
    return ConfigError(f"{path}: key '{key}': {msg}")


def load_campaign(path: Path | str) -> Campaign:
    """Read and validate a campaign TOML.

    Raises:
        ConfigError: unreadable TOML, unknown keys, wrong types, missing or duplicate
            recordings, non-positive windows (one line naming the file and key).
    """
    path = resolve_config(path)
    if not path.is_file():
        raise ConfigError(f"{path}: campaign file not found{not_found_hint()}")
    try:
        raw = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as err:
        raise ConfigError(f"{path}: not valid TOML ({err})") from None
    for key in raw:
        if key not in _TOP:
            raise _err(path, key, f"unknown key; expected one of {', '.join(sorted(_TOP))}")
    name = str(raw.get("campaign", {}).get("name", path.stem))
    for key in raw.get("campaign", {}):
        if key != "name":
            raise _err(path, f"campaign.{key}", "unknown key; expected name")
    proc_raw = dict(raw.get("processing", {}))
    for key, val in proc_raw.items():
        if key not in _PROC_TYPES:
            raise _err(path, f"processing.{key}", f"unknown key; expected one of {', '.join(_PROC_TYPES)}")
        if not isinstance(val, _PROC_TYPES[key]) or (isinstance(val, bool) and _PROC_TYPES[key] is not bool):
            raise _err(path, f"processing.{key}", f"expected {_type_name(_PROC_TYPES[key])}, got {val!r}")
    for key in ("window_s", "step_s", "oversampling", "span_mm", "fap_max"):
        if key in proc_raw and not proc_raw[key] > 0:
            raise _err(path, f"processing.{key}", f"expected a positive number, got {proc_raw[key]!r}")
    if "axes" in proc_raw:
        bad = [a for a in proc_raw["axes"] if a not in ("z", "x", "y")]
        if bad or not proc_raw["axes"]:
            raise _err(path, "processing.axes", f"expected a list of z, x, y; got {proc_raw['axes']!r}")
        proc_raw["axes"] = tuple(proc_raw["axes"])
    if "timestamps" in proc_raw and proc_raw["timestamps"] not in TIMESTAMP_POLICIES:
        raise _err(
            path,
            "processing.timestamps",
            f"expected one of {', '.join(TIMESTAMP_POLICIES)}, got {proc_raw['timestamps']!r}",
        )
    if {"model", "harmonics", "lines"} & set(proc_raw):
        from ..fit import signal_model

        try:
            signal_model(
                proc_raw.get("model", "harmonic"), proc_raw.get("harmonics", 1), proc_raw.get("lines", 1)
            )
        except ConfigError as err:  # the message names the fit flag: name the key instead
            msg = str(err)
            for key in ("model", "harmonics", "lines"):
                msg = msg.replace(f"--{key}", f"processing.{key}")
            raise ConfigError(f"{path}: {msg}") from None
    if "plate_x_mm" in proc_raw:
        proc_raw["plate_x_mm"] = tuple(float(v) for v in proc_raw["plate_x_mm"])
    proc = Processing(
        **{
            k: (float(v) if isinstance(v, int) and _PROC_TYPES[k] == (int, float) else v)
            for k, v in proc_raw.items()
        }
    )
    recs = []
    entries = raw.get("recording", [])
    if not isinstance(entries, list):
        raise _err(path, "recording", "expected an array of tables ([[recording]])")
    for i, rec in enumerate(entries):
        where = f"recording[{i}]"
        for key, val in rec.items():
            if key not in _REC_KEYS:
                raise _err(path, f"{where}.{key}", f"unknown key; expected one of {', '.join(_REC_KEYS)}")
            if not isinstance(val, _REC_KEYS[key]) or isinstance(val, bool):
                raise _err(path, f"{where}.{key}", f"expected {_type_name(_REC_KEYS[key])}, got {val!r}")
        for key in ("day", "camera", "trajectories"):
            if key not in rec:
                raise _err(path, f"{where}.{key}", "missing")
        if rec.get("cycles", 0) < 0:
            raise _err(path, f"{where}.cycles", f"expected a count >= 0, got {rec['cycles']}")
        recs.append(
            Recording(
                day=rec["day"],
                camera=rec["camera"],
                cycles=rec.get("cycles", 0),
                trajectories=(path.parent / rec["trajectories"]),
                lds=(path.parent / rec["lds"]) if "lds" in rec else None,
                frame_rate_hz=float(rec["frame_rate_hz"]) if "frame_rate_hz" in rec else None,
                tap_offsets=tuple(float(v) for v in rec["tap_offsets"]) if "tap_offsets" in rec else None,
            )
        )
    seen = set()
    for r in recs:
        if r.unit_id in seen:
            raise _err(path, "recording", f"day {r.day} camera {r.camera!r} appears twice")
        seen.add(r.unit_id)
    sim = raw.get("simulate")
    if sim is not None and recs:
        raise _err(
            path,
            "simulate",
            "a campaign either lists [[recording]] entries or simulates them, not both",
        )
    if sim is None and not recs:
        raise _err(path, "recording", "no recordings: add [[recording]] entries or a [simulate] table")
    _check_reference_plate(path, proc, len(proc.plate_x_mm))
    if sim is not None:
        from ..simulate import load_config

        recs = _simulated_recordings(sim, path)
        cfg = recs[0].simulate
        check_plates(path, proc, range(1, len(load_config(cfg["config"], cfg["session"]).plate_x_mm()) + 1))
    return Campaign(name=name, path=path, processing=proc, recordings=tuple(recs), simulate=sim)


_SIM_KEYS = {
    "config": str,
    "sessions": list,
    "duration_s": (int, float),
    "seed": int,
    "realtime": bool,
    "unit_frames": int,
}


def _simulated_recordings(sim: dict, path: Path) -> list[Recording]:
    """One `Recording` per session of the ``[simulate]`` table (files are made by the run)."""
    import tomllib

    from ..simulate import load_config
    from ..simulate.config import list_sessions

    for key, val in sim.items():
        if key not in _SIM_KEYS:
            raise ConfigError(
                f"{path}: key 'simulate.{key}': unknown key; expected one of {', '.join(_SIM_KEYS)}"
            )
        if not isinstance(val, _SIM_KEYS[key]) or (isinstance(val, bool) and _SIM_KEYS[key] is not bool):
            raise ConfigError(f"{path}: key 'simulate.{key}': expected {_SIM_KEYS[key]!s}, got {val!r}")
    if "config" not in sim:
        raise ConfigError(f"{path}: key 'simulate.config': missing (the simulation config to record)")
    # a path relative to the campaign file wins; else the name of a shipped config
    cfg_path = resolve_config(sim["config"], relative_to=path.parent).resolve()
    if not cfg_path.is_file():
        raise ConfigError(f"{path}: key 'simulate.config': file not found: {cfg_path}{not_found_hint()}")
    if sim.get("duration_s", 600.0) <= 0:
        raise ConfigError(
            f"{path}: key 'simulate.duration_s': expected a positive duration, got {sim['duration_s']}"
        )
    if sim.get("unit_frames", 2000) < 1:
        raise ConfigError(f"{path}: key 'simulate.unit_frames': expected >= 1, got {sim['unit_frames']}")
    known = list_sessions(tomllib.loads(cfg_path.read_text())) or [None]
    sessions = sim.get("sessions", known)
    recs = []
    for name in sessions:
        if name not in known:
            raise ConfigError(
                f"{path}: key 'simulate.sessions': {name!r} is not a session of {cfg_path.name} "
                f"({', '.join(map(str, known))})"
            )
        scfg = load_config(cfg_path, name)
        spec = dict(
            config=str(cfg_path),
            session=name,
            duration_s=float(sim.get("duration_s", 600.0)),
            seed=sim.get("seed"),
            realtime=bool(sim.get("realtime", False)),
            unit_frames=int(sim.get("unit_frames", 2000)),
        )
        recs.append(
            Recording(
                day=scfg.recording.day,
                camera=scfg.camera.name,
                cycles=int(scfg.recording.cycles_at_start),
                simulate=spec,
            )
        )
    return recs


def _check_reference_plate(path: Path, proc: Processing, n_plates: int) -> None:
    if not 1 <= proc.reference_plate <= n_plates:
        raise _err(
            path,
            "processing.reference_plate",
            f"plate {proc.reference_plate} has no position in processing.plate_x_mm "
            f"(expected a plate 1..{len(proc.plate_x_mm)})",
        )


def check_plates(path: Path, proc: Processing, plates) -> None:
    """A `ConfigError` naming the key when ``proc.plate_x_mm`` has no position for one of the
    recordings' ``plates`` or ``proc.reference_plate`` is not one of them (before the campaign's
    tables and report are written)."""
    plates = sorted(int(p) for p in plates)
    if not plates:
        return
    if plates[-1] > len(proc.plate_x_mm) or plates[0] < 1:
        raise _err(
            path,
            "processing.plate_x_mm",
            f"has {len(proc.plate_x_mm)} plate positions, but the recordings have plates "
            f"{_plate_list(plates)}; expected a position (mm) for each plate 1..{plates[-1]}",
        )
    if proc.reference_plate not in plates:
        raise _err(
            path,
            "processing.reference_plate",
            f"plate {proc.reference_plate} is in no recording (plates {_plate_list(plates)})",
        )


def _plate_list(plates: list[int]) -> str:
    return ", ".join(map(str, plates[:12])) + (" ..." if len(plates) > 12 else "")


def _type_name(t) -> str:
    if isinstance(t, tuple):
        return "a number"
    return {int: "an integer", str: "a string", list: "a list", float: "a number", bool: "true or false"}[t]
