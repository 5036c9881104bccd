"""Camera side or structure side: each finding of a multi-camera recording, tested per camera on
the plates the cameras share.

A registered trajectory (`jaxdefl register`: every camera's plates in the beam's frame, on one
clock, a ``camera`` column) is diagnosed camera by camera. What one camera sees and another
looking at the same plate does not is on the first camera's side (warm-up, shake, its clock,
multipath); what every camera sees on a shared plate is the structure (a crack, the load). The
test of a finding (effect id ``e`` named in camera ``c``) is the diagnosis, restricted to ``e``, of
each camera's shared plates alone:

- ``structure``: ``e`` is named on the shared plates by ``c`` and by every other camera there,
  with parameters that agree within `DISAGREE` combined σ's, and the beam can make it
  (`Detector.can_be_structural`);
- ``measurement``: every camera there names it, but only a measurement makes it (outliers, a
  noise level, a clock, a lattice): the cameras' common physics, not the beam;
- ``camera``: by ``c`` alone, while every other camera had the power to see it (its residual
  on the shared plates is at most `NOISIER` times ``c``'s);
- ``undecided``: ``c``'s own shared plates do not show it, no other camera sees them, another
  camera is too noisy, or the cameras disagree among themselves or on its size. The reason is said.

One effect on one side is one finding, whatever axes and cameras report it.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np
import pandas as pd

from .._errors import InputError
from ..settings import DiagnoseSettings
from ._search import run_diagnosis
from .detectors import load_detectors

__all__ = ["NOISIER", "Attribution", "Finding", "attribute", "on_frame_clock"]

# Two cameras' reports of a structural effect on the same plates agree within this many
# combined σ's in every parameter they both give.
DISAGREE = 4.0
# Another camera had the power to see a finding when its residual on the shared plates is at
# most this many times the finding camera's (a 1.5-fold noise costs 2.25 in Δχ² of a term).
NOISIER = 1.5


@dataclass
class CameraTest:
    """One camera's diagnosis of one effect id on the shared plates."""

    named: bool
    delta_bic: float | None
    rms_mm: float
    plates: list[int]
    parameters: dict = field(default_factory=dict)  # of its strongest report, as DIAG.json has them

    def to_json(self) -> dict:
        return {
            "named": self.named,
            "delta_bic": self.delta_bic,
            "rms_mm": _finite(self.rms_mm),
            "plates": self.plates,
            "parameters": self.parameters,
        }


@dataclass
class Finding:
    """An effect id named by ``cameras`` (the cameras whose whole diagnosis named it), and where
    it sits."""

    id: str
    cameras: list[str]
    plates: dict[str, list[int]]
    attribution: str  # "camera", "structure", "measurement" or "undecided"
    side: str | None  # the camera a camera-side finding belongs to
    reason: str
    tests: dict[str, CameraTest] = field(default_factory=dict)

    def to_json(self) -> dict:
        return {
            "id": self.id,
            "cameras": self.cameras,
            "plates": self.plates,
            "attribution": self.attribution,
            "camera": self.side,
            "reason": self.reason,
            "tests": {c: t.to_json() for c, t in self.tests.items()},
        }


@dataclass
class Attribution:
    cameras: dict[str, dict]  # camera -> plates, effects named, rms before/after
    shared_plates: list[int]
    findings: list[Finding]
    seconds: float

    def to_json(self) -> dict:
        return {
            "cameras": self.cameras,
            "shared_plates": self.shared_plates,
            "findings": [f.to_json() for f in self.findings],
            "seconds": self.seconds,
        }


def _cameras(df: pd.DataFrame, column: str, source: str) -> dict[str, pd.DataFrame]:
    if column not in df.columns:
        raise InputError(
            f"{source}: has no {column!r} column; expected a registered trajectory "
            "(`jaxdefl register` OUT/trajectory.csv) with one camera per row"
        )
    names = [str(c) for c in pd.unique(df[column].astype(str))]
    if len(names) < 2:
        raise InputError(f"{source}: column {column!r} names {len(names)} camera; expected at least 2")
    out = {}
    for c in names:
        part = df[df[column].astype(str) == c].drop(columns=[column]).copy()
        part["segment"] = c  # one camera is one record
        out[c] = part.reset_index(drop=True)
    return out


def on_frame_clock(part: pd.DataFrame) -> tuple[pd.DataFrame, float]:
    """One camera's rows with every plate on the camera's frame clock, and the spread (s) of the
    plates' offsets taken out.

    A registered trajectory gives each plate the instant its measurement stands for: a four-tap
    ToF camera samples each plate with its own delay (12.5-25 ms at 20 frames/s), so the plates'
    stamps no longer coincide. For a diagnosis the offset of a plate is a constant phase of its
    series, which the nominal model holds; the rows go back onto one clock (the most complete
    plate's, fitted as t0 + k dt, shifted by the plates' mean offset) so that the frames are
    shared again. A table whose plates share their stamps (within 1 µs) is returned unchanged.
    """
    t = part["t"].to_numpy(np.float64)
    plate = part["plate"].to_numpy()
    ref = int(part["plate"].value_counts().idxmax())
    base = np.sort(t[plate == ref])
    if base.size < 3:
        return part, 0.0
    k = np.round((base - base[0]) / np.median(np.diff(base)))
    dt, t0 = np.polyfit(k, base, 1)
    frames = (t - t0) / dt
    frac = frames - np.round(frames)
    offsets = pd.Series(frac).groupby(plate).median()
    off = offsets.reindex(plate).to_numpy()
    spread = float((offsets.max() - offsets.min()) * dt)
    if spread < 1e-6:  # shared stamps, to their rounding
        return part, 0.0
    out = part.copy()
    out["t"] = t0 + (np.round(frames - off) + float(offsets.mean())) * dt
    return out, spread


def _test(df: pd.DataFrame, plates: list[int], eid: str, reference, settings: DiagnoseSettings) -> CameraTest:
    """The diagnosis of ``df``'s ``plates`` alone with the library restricted to ``eid``."""
    part = df[df["plate"].isin(plates)]
    try:
        d = run_diagnosis(part, reference, replace(settings, effects=(eid,), segment=None)).to_json()
    except InputError:  # e.g. no periodic motion on these plates: nothing can be tested
        return CameraTest(False, None, math.nan, plates)
    hits = sorted((e for e in d["effects"] if e["id"] == eid), key=lambda e: e["delta_bic"])
    return CameraTest(
        bool(hits),
        hits[0]["delta_bic"] if hits else None,
        float(d["final"]["rms_mm"]),
        plates,
        hits[0]["parameters"] if hits else {},
    )


def _disagreement(a: dict, b: dict) -> tuple[str, float] | None:
    """The parameter two reports of one effect differ most in, in combined σ's (None: no
    parameter with a value and a σ in both)."""
    worst = None
    for k, va in a.items():
        vb = b.get(k)
        if not (isinstance(va, dict) and isinstance(vb, dict)):
            continue
        x, y, sx, sy = va.get("value"), vb.get("value"), va.get("sigma"), vb.get("sigma")
        if not all(isinstance(v, (int, float)) and math.isfinite(v) for v in (x, y, sx, sy)):
            continue
        if sx <= 0 or sy <= 0:
            continue
        z = abs(x - y) / math.hypot(sx, sy)
        if worst is None or z > worst[1]:
            worst = (k, z)
    return worst


def attribute(
    traj: pd.DataFrame,
    reference: pd.DataFrame | None = None,
    settings: DiagnoseSettings | None = None,
    *,
    column: str = "camera",
    source: str = "<table>",
    on_camera=None,
    per_camera: dict[str, DiagnoseSettings] | None = None,
    nulls: dict[str, Callable[[dict, float], dict]] | None = None,
) -> Attribution:
    """Diagnose every camera of a registered trajectory, then attribute each finding.

    Args:
        traj: a trajectory table with a ``column`` naming each row's camera (``jaxdefl register``
            writes one), all cameras in one frame and on one clock.
        reference: an LDS table on that clock, or None.
        settings: the diagnosis' settings (effects searched, timestamps, axes); per camera.
        on_camera: optional callback(camera) as each camera's diagnosis starts.
        per_camera: a camera's own settings (its sensor facts), in place of ``settings``.
        nulls: per camera, (DIAG.json, seconds) -> DIAG.json with what the camera's simulated
            twins find by themselves moved to ``nominal_physics`` (`reconcile.chain`): those
            are the camera's own physics, never findings.
    """
    import time

    start = time.perf_counter()
    settings = settings if settings is not None else DiagnoseSettings()
    per = _cameras(traj, column, source)
    spread = {}
    for c in per:
        per[c], spread[c] = on_frame_clock(per[c])
    seen = {c: sorted(int(p) for p in pd.unique(d["plate"])) for c, d in per.items()}
    counts = pd.Series([p for ps in seen.values() for p in ps]).value_counts()
    shared = sorted(int(p) for p in counts[counts >= 2].index)
    own = {c: (per_camera or {}).get(c, settings) for c in per}
    diag: dict[str, dict] = {}
    for c, d in per.items():
        if on_camera is not None:
            on_camera(c)
        found = run_diagnosis(d, reference, replace(own[c], segment=None), source=f"{source} [{c}]")
        diag[c] = found.to_json()
        if nulls is not None and c in nulls:
            diag[c] = nulls[c](diag[c], float(d["t"].max() - d["t"].min()))
    cameras = {
        c: {
            "plates": seen[c],
            "effects": [e["id"] for e in diag[c]["effects"]],
            "rms_nominal_mm": diag[c]["nominal"]["rms_mm"],
            "rms_final_mm": diag[c]["final"]["rms_mm"],
            # within the camera's twins: its own physics, not findings (with a config's twins)
            "nominal_physics": [e["id"] for e in diag[c].get("nominal_physics", [])],
            # the plates' sampling offsets put back on the camera's frame clock (`on_frame_clock`)
            "plate_offsets_ms": 1e3 * spread[c],
        }
        for c in per
    }
    tests: dict[tuple[str, str], CameraTest] = {}

    def test(c: str, eid: str) -> CameraTest:
        if (c, eid) not in tests:
            tests[c, eid] = _test(per[c], [p for p in seen[c] if p in shared], eid, reference, own[c])
        return tests[c, eid]

    library = load_detectors()
    findings: list[Finding] = []
    for c in per:
        for e in diag[c]["effects"]:
            f = _attribute_one(c, e, per, seen, shared, test, library)
            # one finding per effect and side: its axes, and the cameras that all show it
            same = next(
                (g for g in findings if (g.id, g.attribution, g.side) == (f.id, f.attribution, f.side)),
                None,
            )
            if same is not None:
                if c not in same.cameras:
                    same.cameras.append(c)
                same.plates[c] = sorted(set(same.plates.get(c, [])) | set(e["plates"]))
                continue
            findings.append(f)
    return Attribution(cameras, shared, findings, time.perf_counter() - start)


def _attribute_one(c, e, per, seen, shared, test, library) -> Finding:
    eid = e["id"]
    mine = [p for p in seen[c] if p in shared]
    others = [o for o in per if o != c and any(p in seen[o] for p in mine)]
    f = Finding(eid, [c], {c: e["plates"]}, "undecided", None, "")
    if not others:
        f.reason = f"no other camera sees a plate {c} sees"
        return f
    own = test(c, eid)
    f.tests[c] = own
    for o in others:
        f.tests[o] = test(o, eid)
    shared_txt = ", ".join(str(p) for p in mine)
    if not own.named:
        f.reason = f"{c}'s shared plates ({shared_txt}) alone do not show it: it cannot be compared"
        return f
    named = [o for o in others if f.tests[o].named]
    if len(named) == len(others):
        everyone = ", ".join([c, *named])
        effect = library.get(eid)
        if effect is not None and not effect.can_be_structural():
            f.attribution = "measurement"
            f.reason = (
                f"every camera on plates {shared_txt} shows it ({everyone}), and only a measurement "
                "makes it: the cameras' common physics (their kind, their processing), not the beam"
            )
            return f
        for o in named:
            worst = _disagreement(own.parameters, f.tests[o].parameters)
            if worst is not None and worst[1] > DISAGREE:
                f.reason = (
                    f"every camera on plates {shared_txt} shows it ({everyone}), but its {worst[0]} "
                    f"differs between {c} and {o} by {worst[1]:.1f} combined σ: a beam's effect "
                    "would be the same in both"
                )
                return f
        f.attribution = "structure"
        f.reason = f"every camera on plates {shared_txt} shows it alike: {everyone}"
        return f
    if named:
        silent = ", ".join(o for o in others if o not in named)
        f.reason = f"on plates {shared_txt}, {', '.join(named)} show it and {silent} do not"
        return f
    noisy = [o for o in others if not (f.tests[o].rms_mm <= NOISIER * own.rms_mm)]
    if noisy:
        f.reason = (
            f"not seen by {', '.join(noisy)} on plates {shared_txt}, whose residual is more than "
            f"{NOISIER:g}× {c}'s: a miss there is possible"
        )
        return f
    f.attribution, f.side = "camera", c
    quiet = ", ".join(others)
    f.reason = f"{c} shows it on plates {shared_txt} and {quiet}, as precise there, do not: on {c}'s side"
    return f


def attribution_table(a: Attribution) -> list[tuple[str, ...]]:
    """Rows (effect, cameras, attribution, reason) for a terminal or Markdown table."""
    rows = []
    for f in a.findings:
        side = f"camera ({f.side})" if f.attribution == "camera" else f.attribution
        rows.append((f.id, ", ".join(f.cameras), side, f.reason))
    return rows


def _finite(x: float) -> float | None:
    return None if x is None or not np.isfinite(x) else float(x)
