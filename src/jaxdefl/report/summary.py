"""Markdown summaries that gather tables and figures."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from .figures import plot_fit, plot_periodogram

__all__ = ["md_table", "write_demo_report"]


def md_table(df: pd.DataFrame, floatfmt: dict[str, str]) -> str:
    cols = list(df.columns)
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for r in df.to_dict("records"):
        cells = []
        for c in cols:
            v = r[c]
            cells.append(format(v, floatfmt[c]) if c in floatfmt and pd.notna(v) else str(v))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def write_demo_report(out: Path, traj, whole, windowed, comparison, timings: dict) -> Path:
    """Figures and ``summary.md`` for the demo; returns the summary's path."""
    tab = whole.table
    z = tab[tab["axis"] == "z"]
    mid = int(z.iloc[len(z) // 2].name) if len(z) else 0
    row = tab.loc[mid]
    w = whole.windows
    if mid in whole.periodogram.spectra:
        f, p = whole.periodogram.spectra[mid]
        plot_periodogram(
            f,
            p,
            whole.periodogram.n_indep[mid],
            out / "psd.png",
            title=f"Lomb periodogram, plate {row['plate']} {row['axis']}",
        )
    m = w.mask[mid]
    plot_fit(
        w.t[mid, m],
        w.y[mid, m],
        row["f0_hz"],
        row["amplitude_mm"],
        row["phase_rad"],
        row["offset_mm"],
        out / "fit.png",
        title=f"plate {row['plate']} {row['axis']}: raw and fitted",
    )
    keep_cols = [
        "plate",
        "axis",
        "n",
        "f0_hz",
        "sigma_f0_hz",
        "amplitude_mm",
        "sigma_amplitude_mm",
        "sigma_residual_mm",
        "peak_fap",
        "status",
    ]
    fmt = {
        "f0_hz": ".5f",
        "sigma_f0_hz": ".2e",
        "amplitude_mm": ".3f",
        "sigma_amplitude_mm": ".4f",
        "sigma_residual_mm": ".3f",
        "peak_fap": ".1e",
    }
    wt = windowed.table
    ok = wt[(wt["status"] == "converged") & (wt["axis"] == "z")]
    per_plate = (
        ok.groupby("plate")
        .agg(
            windows=("amplitude_mm", "size"),
            amplitude_mm=("amplitude_mm", "mean"),
            scatter_mm=("amplitude_mm", "std"),
            median_sigma_mm=("sigma_amplitude_mm", "median"),
        )
        .reset_index()
    )
    cmp_fmt = {
        "delta_amplitude_mm": "+.4f",
        "sigma_delta_amplitude_mm": ".4f",
        "delta_f0_hz": "+.2e",
        "amplitude_mm": ".4f",
        "amplitude_ref_mm": ".4f",
    }
    cmp_cols = ["plate", "amplitude_mm", "amplitude_ref_mm", "delta_amplitude_mm",
                "sigma_delta_amplitude_mm", "delta_f0_hz"]
    text = f"""# jaxdefl demo report

Simulated Experiment II (3 Hz loading, SR4000-class ToF camera at 20 Hz, 13 plates, LDS under
plates 3, 5, 7, 9, 11); {len(traj)} trajectory rows. Files: `trajectories.csv`, `lds.csv`,
`estimates_whole.csv` (one fit per plate and axis), `estimates_60s.csv` (60-s windows),
`estimates_lds.csv`, `comparison_lds.csv`; figures `psd.png`, `fit.png`.

Timings: simulation {timings["simulate_s"]:.1f} s, whole-series fits {timings["fit_whole_s"]:.2f} s,
{len(wt)} windowed fits {timings["fit_windows_s"]:.2f} s (JIT compilation included).

## Whole-series estimates (vertical axis)

{md_table(z[keep_cols], fmt)}

## 60-s windows (vertical axis): mean amplitude, scatter between windows and median σ_A

{md_table(per_plate, {"amplitude_mm": ".4f", "scatter_mm": ".4f", "median_sigma_mm": ".4f"})}

The scatter of the windowed amplitudes should match the median σ_A if the linearised
uncertainty is honest.

## Camera minus LDS (thesis-style ΔA and Δf0)

{md_table(comparison[cmp_cols], cmp_fmt)}

![periodogram](psd.png)

![fit](fit.png)
"""
    path = out / "summary.md"
    path.write_text(text)
    return path
