"""Markdown summaries that gather tables and figures."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd

from ..columns import ESTIMATE_CORE
from ..status import Status
from .figures import plot_fit, plot_frame, plot_periodogram

__all__ = ["camera_view_md", "md_table", "not_fitted_md", "reference_md", "write_demo_report"]


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


def _uncertainty_md(out: Path, unc: pd.DataFrame) -> str:
    counts = unc["flag"].value_counts().to_dict()
    trust = unc["trust_amplitude"].value_counts().to_dict()
    fitted = unc[unc["trust_amplitude"] != "none"]
    lines = [
        "Honesty flags of the 30-s windows (`estimates_30s_uncertainty.csv`; thresholds from the "
        "coverage study): "
        + ", ".join(f"{k} {v}" for k, v in counts.items())
        + "; trust (A): "
        + ", ".join(f"{k} {v}" for k, v in trust.items())
        + ". Where a window is flagged for "
        "SNR, cycles or drop-outs, trust the posterior (f0) or the Rice interval (A) rather than "
        "the linearised σ; `coloured_noise` keeps the default σ's (they use the residual's spectral "
        "density near f0); `inadequate_model` means the window is not one harmonic in noise.",
        "",
        "Model adequacy of the fitted windows: variance explained r2 "
        + (
            f"{fitted['r2'].min():.2f}-{fitted['r2'].max():.2f} (median {fitted['r2'].median():.2f}), "
            f"residual whiteness (Ljung-Box) p {fitted['whiteness_p'].min():.1e}-"
            f"{fitted['whiteness_p'].max():.2f} (inadequate below 1e-3 with r2 < 0.5)."
            if len(fitted)
            else "no window fitted."
        ),
    ]
    post = out / "estimates_30s_posterior.csv"
    if post.exists():
        p = pd.read_csv(post)
        cols = [
            "plate",
            "axis",
            "window",
            "amplitude_post_mm",
            "sigma_amplitude_post_mm",
            "sigma_amplitude_lin_mm",
            "sigma_ratio_amplitude",
            "sigma_f0_post_hz",
            "sigma_f0_lin_hz",
            "rho_post",
            "converged_chain",
        ]
        fmt = {
            "amplitude_post_mm": ".4f",
            "sigma_amplitude_post_mm": ".4f",
            "sigma_amplitude_lin_mm": ".4f",
            "sigma_ratio_amplitude": ".3f",
            "sigma_f0_post_hz": ".2e",
            "sigma_f0_lin_hz": ".2e",
            "rho_post": "+.2f",
        }
        lines += [
            "",
            "emcee posteriors (AR(1) noise likelihood, ρ its posterior mean) of three windows "
            "against the linearised (default) σ's "
            "(`estimates_30s_posterior.csv`, `estimates_30s_posterior.png`):",
            "",
            md_table(p[cols], fmt),
        ]
    return "\n".join(lines)


def _runs(values) -> str:
    """Sorted integers as runs: 0, 1, 2, 3, 7 -> "0–3, 7"."""
    v = sorted({int(x) for x in values})
    runs, start = [], None
    for a, b in zip(v, v[1:] + [None], strict=True):
        start = a if start is None else start
        if b != a + 1:
            runs.append(f"{start}" if start == a else f"{start}–{a}")
            start = None
    return ", ".join(runs)


def camera_view_md(cfg, extracted) -> str:
    """Why only some plates appear: the camera's field of view over the beam (``cfg``: the
    demo's `jaxdefl.simulate.SimConfig`; ``extracted``: the plates found in the frames)."""
    from ..simulate.scene import intrinsics, plate_image_bounds

    cam, k = cfg.camera, intrinsics(cfg)
    n = len(cfg.plate_x_mm())
    bounds = {p: plate_image_bounds(cfg, p) for p in range(1, n + 1)}
    inside = [p for p, (u0, u1, _, _) in bounds.items() if 0 <= u0 and u1 <= k.width]
    depth = cam.standoff_mm + cfg.plates.depth_below_top_mm
    half = depth * math.tan(math.radians(cam.fov_deg[0]) / 2)
    found = sorted(int(p) for p in extracted)
    outside = [p for p in range(1, n + 1) if p not in inside]
    text = (
        f"The camera ({k.width} × {k.height} pixels, field of view {cam.fov_deg[0]:g}° × "
        f"{cam.fov_deg[1]:g}°) looks down from {cam.standoff_mm:g} mm above the beam top at x = "
        f"{cam.x_mm:g} mm; at the plates' depth ({depth:g} mm from it) its view spans x = "
        f"{cam.x_mm - half:.0f}–{cam.x_mm + half:.0f} mm of the {cfg.beam.span_mm:g}-mm span. Plates "
        f"{_runs(inside)} of the {n} lie whole inside the image"
    )
    if found == inside:
        text += ", and those are the plates extracted"
    else:
        text += f"; the plates extracted are {_runs(found)}"
    if outside:
        lds_out = [p for p in cfg.lds.plates if p in outside]
        text += f". Plates {_runs(outside)} are outside the camera's view: they have no estimates" + (
            f" (the LDS under plate{'s' if len(lds_out) > 1 else ''} {_runs(lds_out)} "
            "have no camera plate to compare with)"
            if lds_out
            else ""
        )
    return text + "."


# why a window has no fit, by its status (`jaxdefl.status.Status`)
_STATUS_WHY = {
    Status.TOO_FEW_SAMPLES: "fewer valid samples than the model needs",
    Status.TOO_FEW_CYCLES: "too few loading cycles in the window for the frequency to be told",
    Status.NO_SIGNIFICANT_PEAK: (
        "no spectral line stands out of the noise (peak false-alarm probability {fap}, above the "
        "{fap_max:g} that is fitted): the plate hardly moves along that axis"
    ),
    Status.DID_NOT_CONVERGE: "the Gauss-Newton fit did not converge",
    Status.VALUE_OUT_OF_RANGE: "a fitted value beyond the plausible range",
}


def not_fitted_md(windows: pd.DataFrame, fap_max: float) -> str:
    """Which windows have no fit (`not_fitted` in the honesty flags) and why, from their status."""
    bad = windows[windows["status"] != Status.CONVERGED]
    if not len(bad):
        return "Every window was fitted."
    lines = [f"{len(bad)} of {len(windows)} windows have no fit (`not_fitted` above), by their status:", ""]
    for (plate, axis, status), g in bad.groupby(["plate", "axis", "status"], sort=True):
        fap = g["peak_fap"]
        fap_text = f"{fap.min():.2g}" if fap.min() == fap.max() else f"{fap.min():.2g}–{fap.max():.2g}"
        why = _STATUS_WHY.get(status, str(status)).format(fap=fap_text, fap_max=fap_max)
        lines.append(
            f"- plate {plate} {axis}, window{'s' if len(g) > 1 else ''} {_runs(g['window'])}: "
            f"`{status}`: {why}."
        )
    return "\n".join(lines)


def reference_md(comparison: pd.DataFrame, cfg) -> str:
    """The camera-minus-LDS differences beyond 5 σ, and the one a defective sensor explains."""
    out = []
    bad = cfg.lds.defective_plate
    rest = comparison.loc[comparison["plate"] != bad, "delta_amplitude_mm"].abs()
    others = float(rest.max()) if len(rest) else math.nan
    for r in comparison.itertuples():
        z = r.delta_amplitude_mm / r.sigma_delta_amplitude_mm if r.sigma_delta_amplitude_mm > 0 else np.inf
        if abs(z) < 5:
            continue
        if r.plate == bad:
            out.append(
                f"Plate {r.plate}'s ΔA = {r.delta_amplitude_mm:+.3f} mm ({abs(z):.0f} σ) is not the camera's "
                f"error: its LDS is the sensor marked defective in the config (`lds.defective_plate = "
                f"{bad}`, as in the thesis), which reads {r.amplitude_ref_mm:.3f} mm where the camera reads "
                f"{r.amplitude_mm:.3f} mm"
                + (
                    f"; on the other plates the camera and the LDS differ by {others:.3f} mm at most."
                    if np.isfinite(others)
                    else "."
                )
            )
        else:
            out.append(
                f"Plate {r.plate}'s ΔA = {r.delta_amplitude_mm:+.3f} mm is {abs(z):.0f} σ from zero and no "
                "sensor of the config is marked defective there: diagnose the plate "
                "(`jaxdefl diagnose trajectories.csv --reference simulation/lds.csv --out diag.json`)."
            )
    return "\n\n".join(out)


def write_demo_report(
    out: Path,
    rec,
    traj,
    whole,
    windowed,
    comparison,
    truth_fit,
    uncertainty,
    timings: dict,
    cfg=None,
    fap_max: float = 0.01,
) -> Path:
    """Figures and ``summary.md`` for the demo; returns the summary's path.

    Args:
        rec: the simulated recording (`jaxdefl.io.recording.Recording`), for the frame figure.
        traj: extracted trajectories; whole, windowed: `Estimates`; comparison: camera - LDS;
        truth_fit: estimates table of the simulator's true plate trajectories (z).
        uncertainty: honesty flags of the windowed estimates (`jaxdefl.pipeline.check_uncertainty`).
        cfg: the simulation config (`jaxdefl.simulate.SimConfig`): the camera's view and the
            defective LDS are read from it. fap_max: the fits' largest false-alarm probability.
    """
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
    t_from_mid = w.t[mid, m] + (w.table["t_centre"].iat[mid] - w.table["t_mid"].iat[mid])
    plot_fit(
        t_from_mid,
        w.y[mid, m],
        row["f0_hz"],
        row["amplitude_mm"],
        row["phase_rad"],
        row["offset_mm"],
        out / "fit.png",
        title=f"plate {row['plate']} {row['axis']}: raw and fitted",
    )
    chunk = next(rec.chunks(1))
    t0 = float(chunk.t[0])
    first = traj[np.isclose(traj["t"], t0, rtol=0, atol=1e-6)]
    plot_frame(
        chunk.frames[0],
        rec.intrinsics,
        first,
        out / "frame.png",
        title=f"first frame ({rec.kind}) and the extracted plate centroids",
    )
    keep_cols = [
        "plate",
        "axis",
        "n",
        *ESTIMATE_CORE,
        "sigma_residual_mm",
        "peak_fap",
        "r2",
        "whiteness_p",
        "status",
    ]
    fmt = {
        "f0_hz": ".5f",
        "sigma_f0_hz": ".2e",
        "amplitude_mm": ".3f",
        "sigma_amplitude_mm": ".4f",
        "sigma_residual_mm": ".3f",
        "peak_fap": ".1e",
        "r2": ".3f",
        "whiteness_p": ".2g",
    }
    truth = truth_fit[["plate", "f0_hz", "amplitude_mm"]].rename(
        columns={"f0_hz": "f0_true_hz", "amplitude_mm": "amplitude_true_mm"}
    )
    vs = z.merge(truth, on="plate")
    vs = vs.assign(
        amplitude_error_mm=vs["amplitude_mm"] - vs["amplitude_true_mm"],
        f0_error_hz=vs["f0_hz"] - vs["f0_true_hz"],
    )
    vs_cols = [
        "plate",
        "amplitude_mm",
        "amplitude_true_mm",
        "amplitude_error_mm",
        "sigma_amplitude_mm",
        "f0_error_hz",
    ]
    vs_fmt = {
        "amplitude_mm": ".4f",
        "amplitude_true_mm": ".4f",
        "amplitude_error_mm": "+.4f",
        "sigma_amplitude_mm": ".4f",
        "f0_error_hz": "+.2e",
    }
    wt = windowed.table
    ok = wt[(wt["status"] == Status.CONVERGED) & (wt["axis"] == "z")]
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
    cmp_cols = [
        "plate",
        "amplitude_mm",
        "amplitude_ref_mm",
        "delta_amplitude_mm",
        "sigma_delta_amplitude_mm",
        "delta_f0_hz",
    ]
    cmp_fmt = {
        "delta_amplitude_mm": "+.4f",
        "sigma_delta_amplitude_mm": ".4f",
        "delta_f0_hz": "+.2e",
        "amplitude_mm": ".4f",
        "amplitude_ref_mm": ".4f",
    }
    frames_n = rec.n_frames
    text = f"""# jaxdefl demo report

Simulated Experiment II, day 1: 3 Hz loading, an SR4000-class ToF camera at 20 Hz (29 MHz,
four correlation samples taken in turn over each frame, so the motion itself biases the range),
3 % frame drop-outs, LDS under plates 3, 5, 7, 9, 11 (plate 9's sensor defective, as in the
thesis). {frames_n} frames -> plates extracted from every frame (depth classification, Otsu,
connected components, eccentricity, erosion) -> {len(traj)} centroid rows -> Lomb periodogram
and Gauss-Newton fits.

Files: `simulation/` (recording.zarr, truth.csv, lds.csv), `trajectories.csv` (extracted),
`estimates_whole.csv` (one fit per plate and axis), `estimates_30s.csv` (30-s windows),
`estimates_lds.csv`, `comparison_lds.csv`; figures `frame.png`, `psd.png`, `fit.png`.

Timings: simulation {timings["simulate_s"]:.1f} s, extraction {timings["extract_s"]:.1f} s,
whole-record fits {timings["fit_whole_s"]:.2f} s, {len(wt)} windowed fits {timings["fit_windows_s"]:.2f} s
(JIT compilation included).

![frame](frame.png)

{camera_view_md(cfg, traj["plate"].unique()) if cfg is not None else ""}

## Whole-record estimates (vertical axis)

{md_table(z[keep_cols], fmt)}

σ's are the default ones (the residual's spectral density near f0, honest under coloured noise;
the white-noise σ's are `sigma_*_white` in the CSV); r2 is the variance the harmonic explains,
whiteness_p the Ljung-Box p-value of the residual.

## Extracted trajectories against the simulator's truth

The amplitude error combines the extraction and the ToF motion artefact (about -0.14 mm per
4 mm of motion at 3 Hz and 20 Hz, thesis Fig. 6.9).

{md_table(vs[vs_cols], vs_fmt)}

## 30-s windows (vertical axis): mean amplitude, scatter between windows and median σ_A

{md_table(per_plate, {"amplitude_mm": ".4f", "scatter_mm": ".4f", "median_sigma_mm": ".4f"})}

The scatter of the windowed amplitudes should match the median σ_A if the linearised
uncertainty is honest.

## Camera minus LDS (thesis-style ΔA and Δf0)

{md_table(comparison[cmp_cols], cmp_fmt)}

{reference_md(comparison, cfg) if cfg is not None else ""}

## How far to trust the σ's

{_uncertainty_md(out, uncertainty)}

{not_fitted_md(wt, fap_max)}

![periodogram](psd.png)

![fit](fit.png)
"""
    path = out / "summary.md"
    path.write_text(text)
    return path
