"""What the simulator and the extraction make of the sensor, measured on a short clip.

The trajectory-level simulation (`Twin`) must carry what the *frame* simulator would put into
trajectories, or every recording differs from it for reasons the user's simulation already
knows. Two facts are measured by running the frame simulator and the extraction on a short clip
of the configured experiment (same seed, so the noise cancels in differences):

- ``frame_common``: per axis, the correlation of the plates' residuals within a frame (the ToF
  camera's frame-wide range error, thesis Tables 6.2/6.17);
- ``gain``: per plate and axis, how far the extracted centroid moves when every pixel's range
  reads 1 mm farther (the transfer of a range effect such as a warm-up into trajectories; the
  extraction's depth classification and 3D geometry set it, not 1).

and, on a longer clip of the configured experiment as it is (``outlier_seconds``):

- ``outliers``: per plate and axis, the samples the extraction puts far from the motion (beyond
  `metrics.OUTLIER_SIGMAS` noise σ's of the residual, as `outlier_rate` counts them: a ToF
  camera's mixed-pixel frames on the plate under it) — their sizes in σ's and the samples
  searched, so that the twin renders them at the rate and size the chain makes them.

and two of the config: each plate's position along the span (``plate_xi``, x / L), where the
beam's other bending modes (`mode_shape`) move it; and a structured-light camera's level jumps
(``jumps_per_minute``, ``jump_mm``: the whole depth image steps, Poisson in time, each size
N(0, jump_mm)), which the twin renders as the frame simulator does, through the range gains.
The clips are rendered without those jumps (they are the twin's to draw, not noise or outliers
of the extraction: a 3-mm step would make every later sample of a clip an "outlier").
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from .._numerics import harmonic_design, wls
from ..effects import level_jump
from ..simulate.config import SimConfig
from ..simulate.injection import make_spec
from .metrics import frame_common_correlation, outlier_sizes, series_residuals

__all__ = ["SensorCalibration", "calibrate"]


@dataclass
class SensorCalibration:
    frame_common: dict[str, float]  # axis -> mean pairwise correlation (`frame_common_correlation`)
    gain: dict[tuple[int, str], float]  # (plate, axis) -> d centroid / d range (mm/mm)
    seconds: float
    frame_common_se: float = 0.0  # its standard error from the clip's length (Fisher z)
    plate_xi: dict[int, float] = dataclasses.field(default_factory=dict)  # plate -> x / span
    # (plate, axis) -> (samples searched, the outliers' signed sizes in noise σ's)
    outliers: dict[tuple[int, str], tuple[int, tuple[float, ...]]] = dataclasses.field(default_factory=dict)
    # a structured-light camera's level jumps (0: none): per minute, and their RMS size in mm
    jumps_per_minute: float = 0.0
    jump_mm: float = 0.0

    def gain_of(self, plate: int, axis: str) -> float:
        return self.gain.get((int(plate), axis), 1.0 if axis == "z" else 0.0)


def _extract(cfg: SimConfig, seconds: float, seed: int) -> pd.DataFrame:
    from ..frames import extract_recording
    from ..io.recording import Recording
    from ..simulate import render_frames

    t, frames, amp, facts = render_frames(cfg, seconds, seed)
    intr = {k: float(facts[k]) for k in ("fx", "fy", "cx", "cy")}

    def read(s, e):
        return t[s:e], frames[s:e], amp[s:e]

    rec = Recording(
        path=Path("<calibration clip>"),
        kind=facts["frame_kind"],
        n_frames=len(t),
        height=frames.shape[1],
        width=frames.shape[2],
        intrinsics=intr,
        segment=str(facts["segment"]),
        attrs=facts,
        plate_x_mm=np.asarray(facts["plate_x_mm"], float),
        camera_x_mm=float(facts["camera_x_mm"]),
        _read=read,
    )
    return extract_recording(rec, realtime=False, progress=False)


def _frame_common(df: pd.DataFrame, f0_hz: float) -> dict[str, tuple[float, int]]:
    """Per axis: the simulator's frame-common correlation (`frame_common_correlation`) and the frames."""
    out = {}
    omega = 2 * math.pi * f0_hz
    for axis in ("z", "x", "y"):
        wide = df.pivot_table(index="t", columns="plate", values=axis).dropna()
        if wide.shape[0] < 20 or wide.shape[1] < 3:
            continue
        t = wide.index.to_numpy() - wide.index[0]
        y = wide.to_numpy()
        rho = frame_common_correlation(y - wls(harmonic_design(omega * t), y, cov=False)[2])
        if np.isfinite(rho):
            out[axis] = (float(np.clip(rho, 0.0, 0.99)), int(wide.shape[0]))
    return out


def _outliers(df: pd.DataFrame, f0_hz: float) -> dict[tuple[int, str], tuple[int, tuple[float, ...]]]:
    """Per series of an extracted clip: (samples, the outliers' sizes in σ's, `outlier_sizes`)."""
    return {
        key: (int(r.size), tuple(float(u) for u in outlier_sizes(r, noise)))
        for key, (_, r, noise) in series_residuals(df, f0_hz).items()
    }


def calibrate(
    cfg: SimConfig, seconds: float = 10.0, seed: int = 0, outlier_seconds: float = 60.0
) -> SensorCalibration:
    """Simulate and extract a ``seconds`` clip twice (ranges as configured, and 1 mm farther),
    and an ``outlier_seconds`` clip of the configured experiment (0: none) for its outliers."""
    jumps = (cfg.camera.jumps_per_minute, cfg.camera.jump_mm) if cfg.camera.sensor == "kinect" else (0.0, 0.0)
    if jumps[0] > 0:  # the twin draws them itself (`Twin.simulate`)
        cfg = dataclasses.replace(cfg, camera=dataclasses.replace(cfg.camera, jumps_per_minute=0.0))
    clean = dataclasses.replace(cfg, effects=())
    shifted = dataclasses.replace(
        cfg, effects=(make_spec(level_jump.ENTRY.id, {"t_jump_s": 0.0, "size_mm": 1.0}),)
    )
    a = _extract(clean, seconds, seed)
    b = _extract(shifted, seconds, seed)
    m = a.merge(b, on=["t", "plate"], suffixes=("", "_1"))
    gain = {}
    for plate, g in m.groupby("plate"):
        for axis in ("z", "x", "y"):
            d = (g[f"{axis}_1"] - g[axis]).to_numpy()
            d = d[np.isfinite(d)]
            if d.size:
                gain[(int(plate), axis)] = float(np.median(d))
    fc = _frame_common(a, cfg.loading.frequency_hz)
    # the clip is short: its correlations carry an error the null band must allow for
    se = [(1 - r * r) / math.sqrt(max(n - 4, 1)) for r, n in fc.values()]
    outliers = {}
    if outlier_seconds > 0:
        long = a if outlier_seconds <= seconds else _extract(clean, outlier_seconds, seed + 1)
        outliers = _outliers(long, cfg.loading.frequency_hz)
    return SensorCalibration(
        {k: r for k, (r, _) in fc.items()},
        gain,
        seconds,
        float(np.sqrt(np.mean(np.square(se)))) if se else 0.0,
        {i + 1: float(x) / cfg.beam.span_mm for i, x in enumerate(cfg.plate_x_mm())},
        outliers,
        *jumps,
    )
