"""The camera against its reference: the same estimation on an LDS table over the camera's
windows, and the thesis-style differences (ΔA, Δf0 with their σ's, Tables 6.12/6.17)."""

from __future__ import annotations

import numpy as np
import pandas as pd

from ..series import windows_like
from .estimate import Estimates, estimate_windows

__all__ = ["COMPARISON_COLUMNS", "compare_with_reference", "fit_reference"]

COMPARISON_COLUMNS = [
    "segment",
    "window",
    "t_start",
    "t_end",
    "plate",
    "f0_hz",
    "f0_ref_hz",
    "delta_f0_hz",
    "sigma_delta_f0_hz",
    "amplitude_mm",
    "amplitude_ref_mm",
    "delta_amplitude_mm",
    "sigma_delta_amplitude_mm",
    "status",
    "status_ref",
]


def fit_reference(ref: pd.DataFrame, camera: Estimates, **kw) -> Estimates:
    """The same estimation on a reference (LDS) table, over the camera's z windows."""
    w = windows_like(ref, camera.windows.table)
    return estimate_windows(w, **kw)


def compare_with_reference(cam: pd.DataFrame, ref: pd.DataFrame) -> pd.DataFrame:
    """Thesis-style differences camera - reference (ΔA, Δf0) per segment, window and plate."""
    keys = ["segment", "window", "plate"]
    c = cam[cam["axis"] == "z"]
    m = c.merge(ref, on=keys, suffixes=("", "_ref"))
    out = pd.DataFrame({k: m[k] for k in keys})
    out.insert(2, "t_start", m["t_start"])
    out.insert(3, "t_end", m["t_end"])
    out["f0_hz"] = m["f0_hz"]
    out["f0_ref_hz"] = m["f0_hz_ref"]
    out["delta_f0_hz"] = m["f0_hz"] - m["f0_hz_ref"]
    out["sigma_delta_f0_hz"] = np.hypot(m["sigma_f0_hz"], m["sigma_f0_hz_ref"])
    out["amplitude_mm"] = m["amplitude_mm"]
    out["amplitude_ref_mm"] = m["amplitude_mm_ref"]
    out["delta_amplitude_mm"] = m["amplitude_mm"] - m["amplitude_mm_ref"]
    out["sigma_delta_amplitude_mm"] = np.hypot(m["sigma_amplitude_mm"], m["sigma_amplitude_mm_ref"])
    out["status"] = m["status"]
    out["status_ref"] = m["status_ref"]
    return out[COMPARISON_COLUMNS]
