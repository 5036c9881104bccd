"""Missing-physics diagnosis: where a recording departs from the nominal model, which physics
was left out, its model and how much the fit improves (``jaxdefl diagnose``).

Public surface:

- `run_diagnosis(traj, reference=None, settings=None)` -> `Diagnosis` (states before and after,
  for figures and reports); ``settings`` a `jaxdefl.settings.DiagnoseSettings`.
- `diagnose(traj, reference=None, **settings)` -> the DIAG.json dict (DESIGN.md contract), with
  the settings' fields as keywords (``sensor="tof", frame_rate_hz=20.0``).
- `EFFECT_IDS`, `load_detectors()`: the library of candidate effects ({id: its `Detector`}).
- `attribute(traj, reference=None, settings=None)` -> `Attribution`: a registered multi-camera
  table diagnosed camera by camera, each finding said to be a camera's or the structure's
  (``jaxdefl attribute``).

The extension contract (a new effect's detector; the how-to "Write a detector" in the docs):

- `Detector`: the base class of an effect's detector (its id, sensors, information gate and
  `Detector.propose`).
- `Context`: what a detector may look at (the series, their nominal harmonics, the sensor's
  facts); `build_context` makes one from a trajectory table.
- `State`: the current model of one series (mean and noise model); `Proposal`: what a detector
  proposes to add to it; `Series`, `Harmonic`: a series and its nominal harmonic.
- helpers every detector uses: `loglik` (the one likelihood), `rms_equivalent`, `keep_series`,
  `regress`, `regress_offset`, `weights`, `masked_fourier`, `masked_periodogram`, `peak_offset`.
"""

from ._base import (
    Context,
    Detector,
    Harmonic,
    Proposal,
    Series,
    State,
    keep_series,
    loglik,
    masked_fourier,
    masked_periodogram,
    peak_offset,
    regress,
    regress_offset,
    rms_equivalent,
    weights,
)
from ._context import build_context
from ._search import ALPHA, ALPHA_NAMED, DELTA_BIC_MAX, Diagnosis, diagnose, run_diagnosis
from .attribution import Attribution, attribute
from .detectors import EFFECT_IDS, load_detectors

__all__ = [
    "ALPHA",
    "ALPHA_NAMED",
    "Attribution",
    "Context",
    "DELTA_BIC_MAX",
    "Detector",
    "Diagnosis",
    "EFFECT_IDS",
    "Harmonic",
    "Proposal",
    "Series",
    "State",
    "attribute",
    "build_context",
    "diagnose",
    "keep_series",
    "load_detectors",
    "loglik",
    "masked_fourier",
    "masked_periodogram",
    "peak_offset",
    "regress",
    "regress_offset",
    "rms_equivalent",
    "run_diagnosis",
    "weights",
]
