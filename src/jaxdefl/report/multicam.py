"""The deflection amplitude along the whole beam from several cameras and the LDS (Fig. 6.19)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from ..synthetic import beam_shape  # noqa: E402

__all__ = ["plot_beam_profile", "fit_beam_shape"]


def fit_beam_shape(x_mm, amplitude_mm, sigma_mm, span_mm: float, load_a_mm: float) -> tuple[float, float]:
    """Mid-span amplitude of the elastic two-point-load shape through amplitudes along the beam:
    weighted least squares of one scale, (value, σ)."""
    g = beam_shape(np.asarray(x_mm, float) / 1000, span_mm / 1000, load_a_mm / 1000)
    w = 1.0 / np.asarray(sigma_mm, float) ** 2
    den = float(np.sum(w * g * g))
    return float(np.sum(w * g * np.asarray(amplitude_mm, float)) / den), float(1.0 / np.sqrt(den))


def plot_beam_profile(profile: pd.DataFrame, span_mm: float, load_a_mm: float, path: Path) -> None:
    """Amplitude per plate against its place along the beam: every camera (its registered x),
    the LDS, and the elastic curve fitted through the cameras' plates."""
    fig, ax = plt.subplots(figsize=(6.5, 3.6), constrained_layout=True)
    markers = iter("osD^v<>")
    cams = profile[profile["source"] != "lds"]
    for name, g in cams.groupby("source", sort=False):
        ax.errorbar(
            g["x_mm"],
            g["amplitude_mm"],
            yerr=2 * g["sigma_amplitude_mm"],
            fmt=next(markers),
            ms=4,
            capsize=2,
            label=f"{name} (±2σ)",
            alpha=0.8,
        )
    lds = profile[profile["source"] == "lds"]
    if len(lds):
        ax.plot(lds["x_mm"], lds["amplitude_mm"], "k*", ms=9, label="LDS")
    if len(cams):
        amp, sig = fit_beam_shape(
            cams["x_mm"], cams["amplitude_mm"], cams["sigma_amplitude_mm"], span_mm, load_a_mm
        )
        xs = np.linspace(0.0, span_mm, 200)
        ax.plot(
            xs,
            amp * beam_shape(xs / 1000, span_mm / 1000, load_a_mm / 1000),
            "C7-",
            lw=1,
            label=f"elastic shape, mid-span {amp:.3f} ± {sig:.3f} mm",
        )
    ax.set_xlabel("position along the beam x (mm)")
    ax.set_ylabel("deflection amplitude (mm)")
    ax.set_xlim(0, span_mm)
    ax.set_ylim(bottom=0)
    ax.legend(fontsize=7, loc="lower center")
    fig.savefig(path, dpi=120)
    plt.close(fig)
