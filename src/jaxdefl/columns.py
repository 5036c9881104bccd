"""Column groups shared by the estimates table and the tables built from it (no heavy imports)."""

from __future__ import annotations

__all__ = ["ESTIMATE_CORE"]

# the loading frequency and the deflection amplitude with their σ's, the columns every table shows
ESTIMATE_CORE = ("f0_hz", "sigma_f0_hz", "amplitude_mm", "sigma_amplitude_mm")
