"""In-process harmonic trajectories for the demo and benchmarks (no frames, no camera physics).

The full sensor simulator lives in `jaxdefl.simulate`; this is the quick stand-in that the thesis'
harmonic model (5.29) plus white noise and frame drop-outs describes: 13 plates on a simply
supported beam under two-point loading, vertical deflection with the elastic shape, small in-phase
longitudinal and lateral motion, and LDS references under plates 3, 5, 7, 9, 11.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from ._beam import beam_shape

__all__ = ["beam_shape", "harmonic_experiment"]

SPAN_M = 3.4
PLATE_X_M = 0.2 + 0.25 * np.arange(13)  # 13 plates at 250 mm along the beam
LOAD_A_M = 1.2  # distance of each load point from its support


def harmonic_experiment(
    duration_s: float = 600.0,
    seed: int = 1,
    frame_rate_hz: float = 20.0,
    f0_hz: float = 3.0672,
    amplitude_mm: float = 2.37,
    sigma_mm=(0.9, 0.3, 0.76),
    motion_mm=(0.5, 0.05),
    dropout: float = 0.03,
    t0: float = 1.7e9,
    lds_plates=(3, 5, 7, 9, 11),
    lds_rate_hz: float = 300.0,
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Camera trajectories (t, plate, x, y, z) and LDS reference (t, plate, z) in s and mm."""
    rng = np.random.default_rng(seed)
    n = int(round(duration_s * frame_rate_hz))
    t = t0 + np.arange(n) / frame_rate_hz
    t = t[rng.random(n) >= dropout]  # a dropped frame is lost for every plate
    phase = rng.uniform(0, 2 * np.pi)
    wave = np.cos(2 * np.pi * f0_hz * (t - t0) + phase)
    shape = beam_shape(PLATE_X_M, SPAN_M, LOAD_A_M)
    rows = []
    for i, s in enumerate(shape):
        rows.append(
            pd.DataFrame(
                {
                    "t": t,
                    "plate": i + 1,
                    "x": 10.0 + motion_mm[0] * wave + sigma_mm[0] * rng.standard_normal(t.size),
                    "y": -230.0 + motion_mm[1] * wave + sigma_mm[1] * rng.standard_normal(t.size),
                    "z": 1900.0 + amplitude_mm * s * wave + sigma_mm[2] * rng.standard_normal(t.size),
                }
            )
        )
    traj = pd.concat(rows, ignore_index=True)
    tl = t0 + np.arange(int(round(duration_s * lds_rate_hz))) / lds_rate_hz
    wl = np.cos(2 * np.pi * f0_hz * (tl - t0) + phase)
    lds = pd.concat(
        [
            pd.DataFrame(
                {
                    "t": tl,
                    "plate": p,
                    "z": amplitude_mm * shape[p - 1] * wl + 0.002 * rng.standard_normal(tl.size),
                }
            )
            for p in lds_plates
        ],
        ignore_index=True,
    )
    traj.insert(0, "segment", "day1")
    lds.insert(0, "segment", "day1")
    return traj, lds
