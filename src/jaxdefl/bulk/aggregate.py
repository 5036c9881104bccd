"""Gather unit outputs into campaign tables, an xarray Dataset in Zarr, figures and a report."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pandas as pd

from ..columns import ESTIMATE_CORE
from ..fit import ESTIMATE_COLUMNS
from ..status import Status, UnitStatus
from ..synthetic import beam_shape
from .campaign import Campaign, check_plates
from .store import atomic_write_text, csv_text
from .units import read_unit_tables

__all__ = ["fit_profile", "gather", "per_day_table", "to_dataset"]

_VARS = ESTIMATE_COLUMNS[ESTIMATE_COLUMNS.index("n") :]  # the estimates of each window


def _write_csv(df: pd.DataFrame, path: Path) -> None:
    atomic_write_text(path, csv_text(df, float_format="%.10g"))


def to_dataset(est: pd.DataFrame):
    """Estimates as an xarray Dataset with dims (day, camera, window, plate, axis)."""
    ds = est.set_index(["day", "camera", "window", "plate", "axis"])[_VARS + ["cycles", "t_start", "t_end"]]
    ds = ds.to_xarray()
    ds["status"] = ds["status"].fillna(Status.ABSENT).astype(str)
    ds["cycles"] = ds["cycles"].max(dim=["window", "plate", "axis"])
    ds.attrs["description"] = "jaxdefl campaign estimates (thesis harmonic model, eq. 5.29-5.46)"
    return ds


def _write_zarr(ds, path: Path) -> None:
    """Write ``ds`` to ``path`` atomically: build beside it, then swap directories."""
    tmp = path.with_name(f".{path.name}.tmp")
    old = path.with_name(f".{path.name}.old")
    for p in (tmp, old):
        if p.exists():
            shutil.rmtree(p)
    ds.to_zarr(tmp, mode="w", consolidated=True, zarr_format=2)
    if path.exists():
        path.rename(old)
    tmp.rename(path)
    if old.exists():
        shutil.rmtree(old)


def per_day_table(
    whole: pd.DataFrame,
    comparison: pd.DataFrame,
    lds: pd.DataFrame,
    plate: int,
    truth: pd.DataFrame | None = None,
) -> pd.DataFrame:
    """Thesis Tables 6.12/6.16/6.17 for one plate: f0, A, σ's and the LDS differences per day."""
    cam = whole[(whole["plate"] == plate) & (whole["axis"] == "z")]
    cols = [
        "day",
        "camera",
        "cycles",
        "n",
        *ESTIMATE_CORE,
        "sigma_residual_mm",
        "status",
    ]
    cols += [c for c in ("amplitude_corrected_mm", "sigma_amplitude_corrected_mm") if c in cam]
    tab = cam[cols].sort_values(["camera", "day"]).reset_index(drop=True)
    if truth is not None and len(truth):
        tr = truth[(truth["plate"] == plate) & (truth["axis"] == "z")][["day", "camera", "amplitude_mm"]]
        tab = tab.merge(
            tr.rename(columns={"amplitude_mm": "amplitude_truth_mm"}), on=["day", "camera"], how="left"
        )
    if len(lds):
        ref = lds[(lds["plate"] == plate)][
            ["day", "camera", "f0_hz", "sigma_f0_hz", "amplitude_mm", "sigma_amplitude_mm"]
        ]
        ref = ref.rename(
            columns={c: f"{c}_lds" for c in ("f0_hz", "sigma_f0_hz", "amplitude_mm", "sigma_amplitude_mm")}
        )
        tab = tab.merge(ref, on=["day", "camera"], how="left")
        tab["delta_f0_hz"] = tab["f0_hz"] - tab["f0_hz_lds"]
        tab["delta_amplitude_mm"] = tab["amplitude_mm"] - tab["amplitude_mm_lds"]
    return tab


def fit_profile(whole: pd.DataFrame, plate_x_mm, span_mm: float, load_a_mm: float) -> pd.DataFrame:
    """Per day and camera: the elastic two-point-load curve s * shape(x) fitted to A by plate.

    Returns one row per day and camera: the fitted mid-span amplitude s (mm), its σ, and the
    RMS misfit of the plates' amplitudes about the curve.
    """
    rows = []
    z = whole[(whole["axis"] == "z") & (whole["status"] == Status.CONVERGED)]
    for (day, cam), g in z.groupby(["day", "camera"]):
        idx = g["plate"].to_numpy() - 1
        ok = (idx >= 0) & (idx < len(plate_x_mm))
        if ok.sum() < 2:
            continue
        x = np.asarray(plate_x_mm)[idx[ok]] / 1000.0
        shape = beam_shape(x, span_mm / 1000.0, load_a_mm / 1000.0)
        a = g["amplitude_mm"].to_numpy()[ok]
        sa = g["sigma_amplitude_mm"].to_numpy()[ok]
        wgt = 1 / np.maximum(sa, 1e-9) ** 2
        s = np.sum(wgt * shape * a) / np.sum(wgt * shape**2)
        resid = a - s * shape
        rows.append(
            dict(
                day=day,
                camera=cam,
                midspan_amplitude_mm=s,
                sigma_midspan_mm=float(np.sqrt(1 / np.sum(wgt * shape**2))),
                rms_misfit_mm=float(np.sqrt(np.mean(resid**2))),
                plates=int(ok.sum()),
            )
        )
    return pd.DataFrame(rows)


def gather(
    campaign: Campaign, out: Path, manifests: list[dict], units: pd.DataFrame, elapsed_s: float
) -> None:
    """Campaign outputs from the finished units (failed units are listed with their reasons)."""
    from ..report.campaign import write_campaign_report

    out = Path(out)
    ok = [m for m in manifests if m.get("status") == UnitStatus.OK]
    whole = read_unit_tables(out, ok, "whole.csv")
    windows = read_unit_tables(out, ok, "windows.csv")
    lds = read_unit_tables(out, ok, "lds.csv")
    comparison = read_unit_tables(out, ok, "comparison.csv")
    truth = read_unit_tables(out, ok, "truth.csv")
    if len(whole):  # before any of the campaign's outputs is written
        check_plates(campaign.path, campaign.processing, whole["plate"].unique())
    _write_csv(units, out / "units.csv")
    tables = {
        "estimates_whole.csv": whole,
        "estimates_windows.csv": windows,
        "estimates_lds.csv": lds,
        "estimates_truth.csv": truth,
        "comparison_lds.csv": comparison,
    }
    for name, df in tables.items():
        if len(df):
            _write_csv(df, out / name)
    proc = campaign.processing
    day_tab = (
        per_day_table(whole, comparison, lds, proc.reference_plate, truth) if len(whole) else pd.DataFrame()
    )
    profile = (
        fit_profile(whole, proc.plate_x_mm, proc.span_mm, proc.load_a_mm) if len(whole) else pd.DataFrame()
    )
    if len(day_tab):
        _write_csv(day_tab, out / "per_day.csv")
    if len(profile):
        _write_csv(profile, out / "profile.csv")
    if len(whole):
        _write_zarr(to_dataset(windows if len(windows) else whole), out / "results.zarr")
    write_campaign_report(out, campaign, units, whole, day_tab, profile, elapsed_s)
