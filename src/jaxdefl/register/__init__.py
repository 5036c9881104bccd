"""Registration of several cameras into the beam's frame and onto one clock.

Public surface:

- `register_cameras(cams, geometry, lds)` -> `Registration`: every camera's pose in the beam
  frame (with σ's), its clock offset and rate, its plates in the beam frame on the reference
  clock, amplitude and phase per plate and camera, and the shared plates fused with a
  consistency test.
- `CameraInput`, `BeamGeometry`, `scene_points`: the inputs.
- kernels: `solve_pose`, `rotation_matrix`, `fit_reference`, `fit_clock`, `harmonic`, `fuse`.
"""

from ._clock import fit_clock, fit_reference, fuse, harmonic
from ._pose import PARAMS, rotation_matrix, solve_pose
from ._scene import BeamGeometry, plane_landmarks, scene_points
from .register import CONSISTENCY_P_MIN, CameraInput, Registration, register_cameras

__all__ = [
    "register_cameras",
    "Registration",
    "CameraInput",
    "BeamGeometry",
    "scene_points",
    "plane_landmarks",
    "solve_pose",
    "rotation_matrix",
    "PARAMS",
    "fit_reference",
    "fit_clock",
    "harmonic",
    "fuse",
    "CONSISTENCY_P_MIN",
]
