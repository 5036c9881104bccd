"""Stage order lives here alone: tables -> windows -> periodogram -> fit -> tables and reports."""

from __future__ import annotations

import json
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pandas as pd
from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

from . import __version__
from ._errors import ConfigError, JaxdeflError
from .fit import Estimates, estimate_windows
from .io import load_table, read_reference, read_trajectory, write_trajectory
from .series import make_windows, windows_like

__all__ = ["compare_with_reference", "demo", "estimate_table", "fit_file", "fit_reference"]

console = Console(stderr=True)

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


@contextmanager
def _progress(total: int, label: str, enabled: bool):
    """A rich progress bar with ETA when there is enough work to watch; else a no-op."""
    if not enabled or total <= 4096:
        yield lambda k: None
        return
    cols = (
        TextColumn("{task.description}"),
        BarColumn(),
        TextColumn("{task.completed}/{task.total}"),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
    )
    with Progress(*cols, console=console, transient=True) as bar:
        task = bar.add_task(label, total=total)
        yield lambda k: bar.advance(task, k)


def estimate_table(
    df: pd.DataFrame,
    axes: tuple[str, ...] = ("z", "x", "y"),
    window_s: float | None = None,
    step_s: float | None = None,
    fmin_hz: float | None = None,
    fmax_hz: float | None = None,
    oversampling: float = 5.0,
    fap_max: float = 0.01,
    keep: tuple[int, ...] = (),
    progress: bool = True,
) -> Estimates:
    """Windows of a validated trajectory table, estimated (see `jaxdefl.fit.estimate_windows`)."""
    if not 0 < fap_max <= 1:
        raise ConfigError(f"--fap-max: expected a probability in (0, 1], got {fap_max}")
    w = make_windows(df, axes=axes, window_s=window_s, step_s=step_s)
    with _progress(len(w), "fitting windows", progress) as advance:
        return estimate_windows(
            w,
            fmin_hz=fmin_hz,
            fmax_hz=fmax_hz,
            oversampling=oversampling,
            fap_max=fap_max,
            keep=keep,
            on_block=advance,
        )


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


def check_uncertainty(est: Estimates, out: Path, n_posterior: int, seed: int = 0) -> pd.DataFrame:
    """Honesty flags of every window (OUT stem + _uncertainty.csv) and, for ``n_posterior``
    windows, emcee posteriors against the linearised σ's (_posterior.csv and .png)."""
    from .uncertainty import (
        debiased_amplitude,
        honesty_features,
        honesty_flags,
        plot_posterior_vs_linearised,
        posterior_table,
        rice_interval,
    )

    if n_posterior < 0:
        raise ConfigError(f"--posterior: expected a number of windows >= 0, got {n_posterior}")
    tab = est.table
    feat = honesty_features(est)
    flags = honesty_flags(est)
    lo, hi = rice_interval(tab["amplitude_mm"].to_numpy(), tab["sigma_amplitude_mm"].to_numpy())
    low = np.char.find(flags.astype(str), "low_snr") >= 0
    unc = tab[["segment", "window", "plate", "axis"]].assign(
        snr=feat["snr"].to_numpy(),
        cycles=feat["cycles"].to_numpy(),
        missing=feat["missing"].to_numpy(),
        flag=flags,
        trust_amplitude=np.where(
            flags == "ok", "linearised", np.where(low, "rice_or_posterior", "posterior")
        ),
        trust_f0=np.where(flags == "ok", "linearised", "posterior"),
        amplitude_debiased_mm=debiased_amplitude(
            tab["amplitude_mm"].to_numpy(), tab["sigma_amplitude_mm"].to_numpy()
        ),
        amplitude_rice_lo95_mm=lo,
        amplitude_rice_hi95_mm=hi,
    )
    unc.loc[flags == "not_fitted", ["trust_amplitude", "trust_f0"]] = "none"
    write_estimates(unc, out.with_name(out.stem + "_uncertainty.csv"))
    if n_posterior > 0:
        post = posterior_table(est, n_posterior, seed=seed)
        write_estimates(post, out.with_name(out.stem + "_posterior.csv"))
        if len(post):
            plot_posterior_vs_linearised(post, out.with_name(out.stem + "_posterior.png"))
    n_bad = int(((flags != "ok") & (flags != "not_fitted")).sum())
    console.print(
        f"  uncertainty: {n_bad} of {len(flags)} windows flagged (linearised σ not to be trusted there)"
    )
    return unc


def _sidecar(path: Path, **settings) -> None:
    """The effective settings beside an output, so every result says how it was made."""
    meta = {
        "jaxdefl_version": __version__,
        "written": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        **settings,
    }
    path.with_suffix(".json").write_text(json.dumps(meta, indent=2, default=str) + "\n")


def write_estimates(table: pd.DataFrame, path: Path) -> None:
    """Estimates CSV with full float64 precision (epoch t_start survives to the microsecond)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    table.to_csv(path, index=False, float_format="%.10g")


def fit_file(
    traj: Path,
    out: Path,
    window_s: float | None = None,
    step_s: float | None = None,
    axes: tuple[str, ...] | None = None,
    fmin_hz: float | None = None,
    fmax_hz: float | None = None,
    oversampling: float = 5.0,
    fap_max: float = 0.01,
    reference: Path | None = None,
    posterior: int | None = None,
) -> tuple[pd.DataFrame, pd.DataFrame | None]:
    """`jaxdefl fit`: read, estimate, write OUT (and OUT stem + _reference/_comparison.csv)."""
    t0 = time.perf_counter()
    df = read_trajectory(traj)
    if axes is None:
        axes = tuple(a for a in ("z", "x", "y") if a in df.columns)
    kw = dict(fmin_hz=fmin_hz, fmax_hz=fmax_hz, oversampling=oversampling, fap_max=fap_max)
    est = estimate_table(df, axes=axes, window_s=window_s, step_s=step_s, **kw)
    out = Path(out)
    tab = est.table
    write_estimates(tab, out)
    _sidecar(
        out,
        command="fit",
        posterior=posterior,
        trajectory=str(traj),
        window_s=window_s,
        step_s=step_s,
        axes=list(axes),
        reference=str(reference) if reference else None,
        **kw,
    )
    comparison = None
    if reference is not None:
        ref = read_reference(reference)
        ref_est = fit_reference(ref, est, **kw)
        write_estimates(ref_est.table, out.with_name(out.stem + "_reference.csv"))
        comparison = compare_with_reference(tab, ref_est.table)
        write_estimates(comparison, out.with_name(out.stem + "_comparison.csv"))
    if posterior is not None:
        check_uncertainty(est, out, posterior)
    counts = tab["status"].value_counts().to_dict()
    console.print(
        f"[bold]jaxdefl fit[/]: {len(tab)} windows in {time.perf_counter() - t0:.1f} s -> {out} "
        f"({', '.join(f'{k} {v}' for k, v in counts.items())})"
    )
    if comparison is not None:
        for _, r in comparison.iterrows():
            console.print(
                f"  plate {r['plate']:>2} window {r['window']}: ΔA = {r['delta_amplitude_mm']:+.4f} mm, "
                f"Δf0 = {r['delta_f0_hz']:+.2e} Hz"
            )
    return tab, comparison


def run_file(config: Path, out: Path, scheduler: str = "none") -> pd.DataFrame:
    """`jaxdefl run`: a campaign config to ``out`` (see `jaxdefl.bulk`)."""
    from .bulk import load_campaign, run_campaign

    t0 = time.perf_counter()
    campaign = load_campaign(config)
    units = run_campaign(campaign, out, scheduler=scheduler)
    n_ok = int((units["status"] == "ok").sum())
    console.print(
        f"[bold]jaxdefl run[/]: {campaign.name}: {n_ok}/{len(units)} recordings estimated "
        f"({int(units['skipped'].sum())} reused) in {time.perf_counter() - t0:.1f} s "
        f"-> {Path(out) / 'report.md'}"
    )
    for r in units[units["status"] != "ok"].itertuples():
        console.print(f"  [red]failed[/] {r.unit}: {r.reason}")
    return units


# --------------------------------------------------------------------------------------------
# demo


CONFIG_DIR = Path(__file__).resolve().parents[2] / "configs"
DEMO_CONFIG = "exp2_tof_3hz.toml"


def _demo_recording(out: Path, duration_s: float, seed: int):
    """Simulate Experiment II day 1 (3 Hz, SR4000 at 20 Hz) into ``out/simulation``."""
    from .simulate import simulate_to_dir

    cfg = CONFIG_DIR / DEMO_CONFIG
    if not cfg.is_file():
        raise JaxdeflError(f"{cfg}: the demo's simulation config is missing (run the demo from a checkout)")
    sim = out / "simulation"
    simulate_to_dir(cfg, sim, duration_s=duration_s, seed=seed)
    return sim


def demo(out: Path, duration_s: float = 120.0, seed: int = 1) -> None:
    """The main job on the built-in default: frames -> trajectories -> fits -> report in ``out``."""
    from .frames import extract_recording
    from .io.recording import open_recording
    from .report.summary import write_demo_report

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    console.print(
        f"[bold]jaxdefl demo[/]: simulating {duration_s:.0f} s of Experiment II day 1 "
        "(3 Hz loading, SR4000 at 20 Hz, 29 MHz)"
    )
    sim = _demo_recording(out, duration_s, seed)
    t_sim = time.perf_counter() - t0
    t1 = time.perf_counter()
    rec = open_recording(sim / "recording.zarr")
    traj = extract_recording(rec, realtime=False)
    write_trajectory(traj, out / "trajectories.csv")
    t_extract = time.perf_counter() - t1
    lds = read_reference(sim / "lds.csv")
    truth = read_trajectory(sim / "truth.csv")
    t1 = time.perf_counter()
    traj_v = read_trajectory(out / "trajectories.csv")
    whole = estimate_table(traj_v, keep=tuple(range(3 * traj_v["plate"].nunique())))
    t_whole = time.perf_counter() - t1
    t1 = time.perf_counter()
    windowed = estimate_table(traj_v, window_s=30.0)
    t_windowed = time.perf_counter() - t1
    true_fit = estimate_table(truth, axes=("z",), progress=False)
    ref = fit_reference(lds, whole)
    comparison = compare_with_reference(whole.table, ref.table)
    write_estimates(whole.table, out / "estimates_whole.csv")
    write_estimates(windowed.table, out / "estimates_30s.csv")
    uncertainty = check_uncertainty(windowed, out / "estimates_30s.csv", n_posterior=3, seed=seed)
    write_estimates(ref.table, out / "estimates_lds.csv")
    write_estimates(comparison, out / "comparison_lds.csv")
    report = write_demo_report(
        out,
        rec,
        traj_v,
        whole,
        windowed,
        comparison,
        true_fit.table,
        uncertainty,
        timings=dict(simulate_s=t_sim, extract_s=t_extract, fit_whole_s=t_whole, fit_windows_s=t_windowed),
    )
    console.print(f"[bold]jaxdefl demo[/]: report in {report} ({time.perf_counter() - t0:.1f} s)")


def _camera_facts(config: Path | None) -> dict:
    """Sensor, frame rate, modulation and tap offsets from a simulation config (TOML)."""
    if config is None:
        return {}
    from .simulate import load_config

    cam = load_config(config).camera
    facts = {
        "sensor": "tof" if cam.sensor == "sr4000" else "structured_light",
        "frame_rate_hz": cam.frame_rate_hz,
    }
    if cam.sensor == "sr4000":
        facts["modulation_mhz"] = cam.modulation_mhz
        facts["tap_offsets"] = tuple(cam.tap_offsets)
    return facts


def diagnose_file(
    traj: Path,
    out: Path,
    reference: Path | None = None,
    sensor: str | None = None,
    frame_rate_hz: float | None = None,
    modulation_mhz: float | None = None,
    config: Path | None = None,
    segment: str | None = None,
    effects: tuple[str, ...] | None = None,
    figures: bool = True,
) -> dict:
    """`jaxdefl diagnose`: read, diagnose, write OUT.json, OUT.md and a figure per effect.

    Flags override what a simulation ``config`` says of the camera.
    """
    from .diagnose import run_diagnosis
    from .report.diagnosis import write_diagnosis_report

    facts = _camera_facts(config)
    for key, val in (
        ("sensor", sensor),
        ("frame_rate_hz", frame_rate_hz),
        ("modulation_mhz", modulation_mhz),
    ):
        if val is not None:
            facts[key] = val
    # the tables as read: `run_diagnosis` validates them (once; validation sorts every row)
    df = load_table(traj)
    ref = load_table(reference) if reference is not None else None

    def on_round(r: int, eid: str | None) -> None:
        console.print(f"round {r + 1}: " + (f"located [bold]{eid}[/bold]" if eid else "nothing more to add"))

    with console.status("diagnosing ..."):
        diag = run_diagnosis(
            df,
            ref,
            segment=segment,
            effects=effects,
            source=str(traj),
            reference_source=str(reference),
            on_round=on_round,
            **facts,
        )
    d = diag.to_json()
    d["settings"] = {
        "jaxdefl_version": __version__,
        "trajectory": str(traj),
        "reference": str(reference) if reference else None,
        "config": str(config) if config else None,
        **{k: v for k, v in facts.items()},
        "segment": segment,
        "effects": list(effects) if effects else None,
    }
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(d, indent=2, default=str) + "\n")
    written = write_diagnosis_report(diag, d, out, figures=figures)
    names = ", ".join(e["id"] for e in d["effects"]) or "none"
    console.print(
        f"effects: {names}; unexplained: {len(d['unexplained'])}; RMS {d['nominal']['rms_mm']:.4f} -> "
        f"{d['final']['rms_mm']:.4f} mm; {diag.seconds:.1f} s -> {out}, {written[0]}"
    )
    return d
