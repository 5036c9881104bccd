"""Sensor and scene simulator: the beam and its fatigue, ToF and structured-light cameras, LDS.

Public surface:

- `load_config(path)` -> `SimConfig`; `config_from_dict(raw)`.
- `simulate_to_dir(config_path, out_dir, duration_s, seed)`: recording.zarr, truth.csv, lds.csv,
  config.json (the CLI's ``jaxdefl simulate``).
- `simulate_trajectories(config, duration_s, seed)` -> (truth, lds) without rendering frames.
- `render_frames(config, duration_s, seed)`: frames in memory for small runs.
- `camera_blocks(config, duration_s, seed)`: a live camera's measured centroids, block by block,
  with the scheduled effects (stiffness loss, debonding, sensor faults); `write_live` appends
  them to a growing trajectory table (``jaxdefl simulate --live``).
- `REGISTRY`, `EffectSpec`: the effects the simulator injects (the injectable entries of the
  vocabulary `jaxdefl.effects`, injected by `jaxdefl.simulate.injection`), spelled ``[[effect]]``
  or, for the scheduled ones, ``[[change]]`` (`jaxdefl.simulate.schedule`).
- `measured_centroids(...)`: plate centroids measured from rendered ToF range frames.
- physics helpers: `non_ambiguity_range_m`, `range_noise_mm`, `integration_time_ms`, `beam_shape`,
  `midspan_amplitude_mm`, `kinematics`.
"""

from .centroids import measured_centroids
from .config import SimConfig, config_from_dict, load_config
from .injection import REGISTRY, EffectSpec
from .lds import frame_clock, lds_block, truth_table, usable_reference
from .live import camera_blocks, centroid_noise_mm, write_live
from .scene import beam_shape, intrinsics, kinematics, midspan_amplitude_mm, pixel_model
from .tof import TABLE_6_1_MM, integration_time_ms, non_ambiguity_range_m, range_noise_mm
from .writer import render_frames, simulate_to_dir, simulate_trajectories, tap_times

__all__ = [
    "SimConfig",
    "load_config",
    "config_from_dict",
    "simulate_to_dir",
    "simulate_trajectories",
    "render_frames",
    "measured_centroids",
    "frame_clock",
    "truth_table",
    "lds_block",
    "usable_reference",
    "beam_shape",
    "intrinsics",
    "kinematics",
    "midspan_amplitude_mm",
    "pixel_model",
    "non_ambiguity_range_m",
    "range_noise_mm",
    "integration_time_ms",
    "tap_times",
    "TABLE_6_1_MM",
    "REGISTRY",
    "EffectSpec",
    "camera_blocks",
    "centroid_noise_mm",
    "write_live",
]
