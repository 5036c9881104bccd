"""Missing-physics diagnosis: where a recording departs from the nominal model, which physics
was left out, its model and how much the fit improves (``jaxdefl diagnose``).

Public surface:

- `run_diagnosis(traj, reference=None, settings=None)` -> `Diagnosis` (states before and after,
  for figures and reports); ``settings`` a `jaxdefl.settings.DiagnoseSettings`.
- `diagnose(traj, reference=None, **settings)` -> the DIAG.json dict (DESIGN.md contract), with
  the settings' fields as keywords (``sensor="tof", frame_rate_hz=20.0``).
- `EFFECT_IDS`, `load_effects()`: the library of candidate effects.
- `attribute(traj, reference=None, settings=None)` -> `Attribution`: a registered multi-camera
  table diagnosed camera by camera, each finding said to be a camera's or the structure's
  (``jaxdefl attribute``).
"""

from ._search import ALPHA, ALPHA_NAMED, DELTA_BIC_MAX, Diagnosis, diagnose, run_diagnosis
from .attribution import Attribution, attribute
from .effects import EFFECT_IDS, load_effects

__all__ = [
    "ALPHA",
    "ALPHA_NAMED",
    "Attribution",
    "DELTA_BIC_MAX",
    "Diagnosis",
    "EFFECT_IDS",
    "attribute",
    "diagnose",
    "load_effects",
    "run_diagnosis",
]
