"""Real-time monitoring (`jaxdefl monitor`): recursive f0 and A per plate and axis, change alarms.

A stage: it imports frames, fit, io and simulate, never pipeline, bulk or cli.
"""

from .blocks import BlockAccumulator, BlockResult
from .detect import ChangeDetector, DetectorSettings, cusum_arl, cusum_threshold, gls_mean
from .engine import SNAPSHOT_COLUMNS, Monitor
from .estimator import METHODS, HarmonicTracker, TrackerSettings, initial_state
from .layout import Layout, fit_span, frames_from_table
from .sources import Source, follow_table, open_source, recording_source, simulated_source, table_source

__all__ = [
    "METHODS",
    "SNAPSHOT_COLUMNS",
    "BlockAccumulator",
    "BlockResult",
    "ChangeDetector",
    "DetectorSettings",
    "HarmonicTracker",
    "Layout",
    "Monitor",
    "Source",
    "TrackerSettings",
    "cusum_arl",
    "cusum_threshold",
    "fit_span",
    "follow_table",
    "frames_from_table",
    "gls_mean",
    "initial_state",
    "open_source",
    "recording_source",
    "simulated_source",
    "table_source",
]
