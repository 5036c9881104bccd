"""Simulation and recording side by side (``jaxdefl reconcile``): where they differ, which
physics the simulation left out, the simulation with it, and the comparison again.

Public surface: `reconcile` -> `Reconciliation`, `specs_from_diagnosis`, `effect_tables_toml`,
`Twin` (the simulation a user would set up for a trajectory table), `table_stats`, `distance`,
`METRICS`.
"""

from .engine import Reconciliation, effect_tables_toml, reconcile, specs_from_diagnosis
from .metrics import METRICS, distance, table_stats
from .sensor import SensorCalibration, calibrate
from .twin import Twin

__all__ = [
    "METRICS",
    "Reconciliation",
    "SensorCalibration",
    "calibrate",
    "Twin",
    "distance",
    "effect_tables_toml",
    "reconcile",
    "specs_from_diagnosis",
    "table_stats",
]
