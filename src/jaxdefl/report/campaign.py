"""Campaign report: fatigue curve, deflection profiles, per-day tables, unit statuses."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from ..status import Status, UnitStatus
from ..synthetic import beam_shape  # noqa: E402
from .summary import md_table  # noqa: E402

__all__ = ["plot_fatigue", "plot_profiles", "write_campaign_report"]


def plot_fatigue(day_tab: pd.DataFrame, path: Path, plate: int) -> None:
    """A against the number of load cycles, camera and LDS (thesis Fig. 6.55)."""
    fig, ax = plt.subplots(figsize=(6.5, 3.6), constrained_layout=True)
    for cam, g in day_tab.groupby("camera"):
        c = g["cycles"]
        ax.errorbar(c, g["amplitude_mm"], yerr=g["sigma_amplitude_mm"], fmt="o-", ms=4, label=f"{cam}")
        if "amplitude_corrected_mm" in g:
            ax.plot(c, g["amplitude_corrected_mm"], "^-", ms=4, label=f"{cam}, motion artefact corrected")
        if "amplitude_truth_mm" in g:
            ax.plot(c, g["amplitude_truth_mm"], "k:", lw=1, label="simulated truth")
        if "amplitude_mm_lds" in g and g["amplitude_mm_lds"].notna().any():
            lds, sigma = g["amplitude_mm_lds"], g["sigma_amplitude_mm_lds"]
            ax.errorbar(c, lds, yerr=sigma, fmt="s--", ms=4, label=f"LDS (with {cam})")
    ax.set_xlabel("number of load cycles")
    ax.set_ylabel(f"amplitude, plate {plate} (mm)")
    ax.set_title("fatigue curve", fontsize=9)
    ax.legend(fontsize=8)
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_profiles(
    whole: pd.DataFrame, profile: pd.DataFrame, plate_x_mm, span_mm, load_a_mm, path: Path
) -> None:
    """Amplitude along the beam per day with the fitted elastic curve."""
    fig, ax = plt.subplots(figsize=(6.5, 3.6), constrained_layout=True)
    xs = np.linspace(0, span_mm, 200)
    z = whole[(whole["axis"] == "z") & (whole["status"] == Status.CONVERGED)]
    cmap = plt.cm.viridis
    days = sorted(profile["day"].unique())
    for i, row in enumerate(profile.itertuples()):
        g = z[(z["day"] == row.day) & (z["camera"] == row.camera)]
        x = np.asarray(plate_x_mm)[g["plate"].to_numpy() - 1]
        col = cmap(days.index(row.day) / max(len(days) - 1, 1))
        ax.errorbar(x, g["amplitude_mm"], yerr=g["sigma_amplitude_mm"], fmt="o", ms=3, color=col)
        ax.plot(
            xs,
            row.midspan_amplitude_mm * beam_shape(xs / 1000, span_mm / 1000, load_a_mm / 1000),
            "-",
            lw=0.8,
            color=col,
            label=f"day {row.day} {row.camera}" if i < 12 else None,
        )
    ax.set_xlabel("position along the beam (mm)")
    ax.set_ylabel("deflection amplitude (mm)")
    ax.set_title("deflection profiles and elastic two-point-load fits", fontsize=9)
    ax.legend(fontsize=7, ncol=2)
    fig.savefig(path, dpi=120)
    plt.close(fig)


def write_campaign_report(out: Path, campaign, units, whole, day_tab, profile, elapsed_s: float) -> Path:
    proc = campaign.processing
    parts = [
        f"# Campaign {campaign.name}\n",
        f"{len(units)} recordings; {int((units['status'] == 'ok').sum())} estimated, "
        f"{int((units['status'] != 'ok').sum())} failed, {int(units['skipped'].sum())} reused from "
        f"an earlier run; {elapsed_s:.1f} s.\n",
        "## Units\n",
        md_table(units, {"seconds": ".2f"}),
        "",
    ]
    if len(day_tab):
        plot_fatigue(day_tab, out / "fatigue.png", proc.reference_plate)
        cols = [
            c
            for c in [
                "day",
                "camera",
                "cycles",
                "f0_hz",
                "amplitude_mm",
                "amplitude_corrected_mm",
                "amplitude_truth_mm",
                "f0_hz_lds",
                "amplitude_mm_lds",
                "delta_f0_hz",
                "delta_amplitude_mm",
                "sigma_f0_hz",
                "sigma_amplitude_mm",
                "sigma_residual_mm",
                "sigma_f0_hz_lds",
                "sigma_amplitude_mm_lds",
            ]
            if c in day_tab
        ]
        fmt = {
            "f0_hz": ".4f",
            "f0_hz_lds": ".4f",
            "amplitude_mm": ".3f",
            "amplitude_corrected_mm": ".3f",
            "amplitude_truth_mm": ".3f",
            "amplitude_mm_lds": ".3f",
            "delta_f0_hz": "+.4f",
            "delta_amplitude_mm": "+.3f",
            "sigma_f0_hz": ".2e",
            "sigma_amplitude_mm": ".4f",
            "sigma_residual_mm": ".2f",
            "sigma_f0_hz_lds": ".2e",
            "sigma_amplitude_mm_lds": ".2e",
        }
        parts += [
            f"## Plate {proc.reference_plate} per day (thesis Tables 6.12, 6.16, 6.17)\n",
            md_table(day_tab[cols], fmt),
            "",
            "![fatigue curve](fatigue.png)\n",
        ]
    if len(profile):
        plot_profiles(whole, profile, proc.plate_x_mm, proc.span_mm, proc.load_a_mm, out / "profile.png")
        parts += [
            "## Deflection profile along the beam\n",
            md_table(
                profile,
                {"midspan_amplitude_mm": ".3f", "sigma_midspan_mm": ".4f", "rms_misfit_mm": ".3f"},
            ),
            "",
            "![profiles](profile.png)\n",
        ]
    failed = units[units["status"] != UnitStatus.OK]
    if len(failed):
        parts += ["## Failed units\n"] + [f"- `{r.unit}`: {r.reason}" for r in failed.itertuples()]
    path = out / "report.md"
    path.write_text("\n".join(parts) + "\n")
    return path
