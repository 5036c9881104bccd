"""Stage order lives here alone: tables -> windows -> periodogram -> fit -> tables and reports."""

from __future__ import annotations

import shutil
import tempfile
import time
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from . import __version__
from ._configs import config_dir
from ._errors import ConfigError, InputError, JaxdeflError, ParameterError
from .io import (
    layout_note,
    load_table,
    read_reference,
    read_trajectory,
    timestamp_note,
    write_trajectory,
)
from .io.output import TABLE_SUFFIXES, Outputs
from .progress import console, progress_bar, status, wrote
from .series import check_window_plan
from .settings import (
    DiagnoseSettings,
    ExtractSettings,
    FitSettings,
    ReconcileSettings,
    RunSettings,
    SimulateSettings,
)
from .status import UnitStatus

if TYPE_CHECKING:
    from .fit import Estimates

__all__ = ["demo", "diagnose_file", "extract_file", "fit_file", "run_file", "simulate_file"]


@contextmanager
def _progress(total: int, label: str, enabled: bool):
    """A progress bar with ETA when there is enough work to watch, else a status line (both
    plain lines off a terminal, `jaxdefl.progress`); a no-op when not ``enabled``."""
    if not enabled:
        yield lambda k: None
        return
    if total <= 4096:
        with status(f"{label} ({total}) ..."):
            yield lambda k: None
        return
    with progress_bar() as bar:
        task = bar.add_task(label, total=total)
        yield lambda k: bar.advance(task, k)


def _estimate(df: pd.DataFrame, progress: bool = True, **kw) -> Estimates:
    """`jaxdefl.fit.estimate_table` with a progress bar when there is enough work to watch."""
    # `jaxdefl.fit` (and JAX) imported where used: `simulate` and `extract` never load them
    from .fit import estimate_windows, windows_for

    w = windows_for(df, **{k: kw.pop(k) for k in ("axes", "window_s", "step_s") if k in kw})
    with _progress(len(w), "fitting windows", progress) as advance:
        return estimate_windows(w, on_block=advance, **kw)


def uncertainty_tables(
    est: Estimates, n_posterior: int, seed: int = 0, noise: str = "ar1"
) -> tuple[pd.DataFrame, pd.DataFrame | None]:
    """Honesty flags of every window and, for ``n_posterior`` windows (a seeded sample), emcee
    posteriors against the linearised σ's. Returns (uncertainty table, posterior table or None)."""
    from .uncertainty import posterior_table, uncertainty_table

    if n_posterior < 0:
        raise ConfigError(f"--posterior: expected a number of windows >= 0, got {n_posterior}")
    unc = uncertainty_table(est)
    post = posterior_table(est, n_posterior, seed=seed, noise=noise) if n_posterior > 0 else None
    trust = unc[["trust_amplitude", "trust_f0"]].to_numpy()
    n_bad = int(((trust != "linearised") & (trust != "none")).any(axis=1).sum())
    n_model = int((trust[:, 0] == "inadequate_model").sum())
    console.print(
        f"  uncertainty: {n_bad} of {len(unc)} windows flagged (linearised σ not to be trusted there)"
        + (f", {n_model} of them not one harmonic in noise (inadequate_model)" if n_model else "")
    )
    return unc, post


def write_uncertainty(outs: Outputs, unc: pd.DataFrame, post: pd.DataFrame | None, paths: dict) -> None:
    """Stage the uncertainty table, the posterior table and its figure (see `uncertainty_tables`)."""
    from .uncertainty import plot_posterior_vs_linearised

    outs.table(paths["uncertainty"], unc)
    if post is not None:
        outs.table(paths["posterior"], post)
        if len(post):
            outs.stage(paths["posterior_png"], lambda tmp: plot_posterior_vs_linearised(post, tmp))


def check_uncertainty(est: Estimates, out: Path, n_posterior: int, seed: int = 0) -> pd.DataFrame:
    """Honesty flags (OUT stem + _uncertainty.csv) and, for ``n_posterior`` windows, emcee
    posteriors against the linearised σ's (_posterior.csv and .png), written together."""
    unc, post = uncertainty_tables(est, n_posterior, seed=seed)
    with Outputs() as outs:
        write_uncertainty(outs, unc, post, companions(Path(out)))
    return unc


def settings_record(**settings) -> dict:
    """The effective settings beside an output, so every result says how it was made."""
    return {"jaxdefl_version": __version__, "written": time.strftime("%Y-%m-%dT%H:%M:%S%z"), **settings}


def write_estimates(table: pd.DataFrame, path: Path) -> None:
    """One estimates table, atomically (CSV or Parquet by the suffix; times to the microsecond)."""
    with Outputs() as outs:
        outs.table(path, table)


def companions(out: Path) -> dict[str, Path]:
    """The files `fit` writes beside OUT (same stem; tables in OUT's format)."""
    out = Path(out)
    suffix = out.suffix if out.suffix.lower() in TABLE_SUFFIXES else ".csv"
    stem = lambda tag, sfx=suffix: out.with_name(out.stem + tag + sfx)  # noqa: E731
    return {
        "sidecar": out.with_suffix(".json"),
        "reference": stem("_reference"),
        "comparison": stem("_comparison"),
        "uncertainty": stem("_uncertainty"),
        "posterior": stem("_posterior"),
        "posterior_png": stem("_posterior", ".png"),
    }


def fit_file(
    traj: Path, out: Path, settings: FitSettings, reference: Path | None = None
) -> tuple[pd.DataFrame, pd.DataFrame | None]:
    """`jaxdefl fit`: read, estimate, write OUT (and OUT stem + _reference/_comparison/... beside).

    ``settings`` were validated whole when they were made (`jaxdefl.settings.FitSettings`);
    ``reference`` is the LDS table to fit and compare with.

    Order: the outputs are planned (none may be an input or another output), the inputs are
    read and checked against each other, everything is computed, and only then are all outputs
    committed together (`jaxdefl.io.output.Outputs`).
    """
    t0 = time.perf_counter()
    traj, out = Path(traj), Path(out)
    s = settings
    posterior, timestamps, spec = s.posterior, s.timestamps, s.spec
    outs = Outputs(inputs=[traj, reference])
    outs.reserve(out, "--out", suffixes=TABLE_SUFFIXES)
    paths = companions(out)
    outs.reserve(paths["sidecar"], "the settings sidecar (--out with .json)")
    if reference is not None:
        outs.reserve(paths["reference"], "the reference estimates")
        outs.reserve(paths["comparison"], "the comparison table")
    if posterior is not None:
        outs.reserve(paths["uncertainty"], "the uncertainty table")
        if posterior > 0:
            outs.reserve(paths["posterior"], "the posterior table")
            outs.reserve(paths["posterior_png"], "the posterior figure")

    df = read_trajectory(traj, timestamps=timestamps)
    layouts = {"trajectory": df.attrs.get("layout")}
    clocks = {"trajectory": df.attrs.get("timestamps")}
    axes = s.axes
    if axes is None:
        axes = tuple(a for a in ("z", "x", "y") if a in df.columns)
    ref = None
    if reference is not None:
        ref = read_reference(reference, timestamps=timestamps)
        layouts["reference"] = ref.attrs.get("layout")
        clocks["reference"] = ref.attrs.get("timestamps")
        shared = np.intersect1d(ref["plate"].unique(), df["plate"].unique())
        if not shared.size:
            raise ConfigError(
                f"--reference {reference}: no plate of the reference ({_plates(ref)}) "
                f"is in {traj} ({_plates(df)})"
            )
        if "z" not in axes:
            raise ConfigError("--reference: compares the z axis; --axes must include z")
    if (clipped := check_window_plan(df, axes, s.window_s, s.step_s, source=str(traj))) is not None:
        console.print(f"  {clipped}", highlight=False, soft_wrap=True)

    kw = dict(fmin_hz=s.fmin_hz, fmax_hz=s.fmax_hz, oversampling=s.oversampling, fap_max=s.fap_max)
    est = _estimate(df, axes=axes, window_s=s.window_s, step_s=s.step_s, model=spec, **kw)
    tab = est.table
    comparison = ref_tab = unc = post = None
    if ref is not None:
        from .fit import compare_with_reference, fit_reference

        ref_tab = fit_reference(ref, est, model=spec, **kw).table
        comparison = compare_with_reference(tab, ref_tab)
    if posterior is not None:
        unc, post = uncertainty_tables(est, posterior, noise=s.posterior_noise)

    with outs:
        outs.table(out, tab)
        outs.json(
            paths["sidecar"],
            settings_record(
                command="fit",
                posterior=posterior,
                posterior_noise=s.posterior_noise,
                trajectory=str(traj),
                window_s=s.window_s,
                step_s=s.step_s,
                axes=list(axes),
                reference=str(reference) if reference else None,
                timestamps=timestamps,
                clock={k: v for k, v in clocks.items() if v},
                **({"layout": {k: v for k, v in layouts.items() if v}} if any(layouts.values()) else {}),
                **kw,
                **({} if spec.is_default else dict(model=s.model, harmonics=s.harmonics, lines=s.lines)),
            ),
        )
        if ref_tab is not None:
            outs.table(paths["reference"], ref_tab)
            outs.table(paths["comparison"], comparison)
        if unc is not None:
            write_uncertainty(outs, unc, post, paths)
    for name, path in (("trajectory", traj), ("reference", reference)):
        if (note := layout_note(layouts.get(name), path)) is not None:
            console.print(f"  {note}", highlight=False, soft_wrap=True)
    for name, rep in clocks.items():
        if (note := timestamp_note(rep)) is not None:
            console.print(f"  {name}: {note}", highlight=False, soft_wrap=True)
    counts = tab["status"].value_counts().to_dict()
    written = [out, paths["sidecar"]]
    if ref_tab is not None:
        written += [paths["reference"], paths["comparison"]]
    if unc is not None:
        written.append(paths["uncertainty"])
        if post is not None:
            written.append(paths["posterior"])
    wrote(
        "fit",
        *written,
        detail=f"{len(tab)} windows, {', '.join(f'{k} {v}' for k, v in counts.items())}; "
        f"{time.perf_counter() - t0:.1f} s",
    )
    if comparison is not None:
        for _, r in comparison.iterrows():
            console.print(
                f"  plate {r['plate']:>2} window {r['window']}: ΔA = {r['delta_amplitude_mm']:+.4f} mm, "
                f"Δf0 = {r['delta_f0_hz']:+.2e} Hz"
            )
    return tab, comparison


def _plates(df: pd.DataFrame) -> str:
    p = np.sort(df["plate"].unique())
    return "plates " + ", ".join(map(str, p[:8].tolist())) + (" ..." if p.size > 8 else "")


def simulate_file(config: Path, out: Path, settings: SimulateSettings) -> list[Path]:
    """`jaxdefl simulate`: the recording of ``config`` in ``out``; returns the folders written.

    A config with several ``[[session]]`` entries and no session picked (``--session`` or the
    config's ``recording.session``) makes every session, each in ``out/<session name>/``; one
    session, or a config without sessions, is written to ``out`` itself. With ``live``, the
    measured centroids are appended to ``out/trajectory.csv`` as they come
    (`jaxdefl.simulate.write_live`).
    """
    import tomllib

    from ._configs import resolve_config
    from .simulate import load_config, simulate_to_dir, write_live
    from .simulate.config import list_sessions

    s, out, t0 = settings, Path(out), time.perf_counter()
    cfg = load_config(config, s.session)  # every error before anything is written
    if cfg.cameras and s.live:
        raise ConfigError(
            f"{config}: --live simulates one camera; got {len(cfg.cameras)} [[camera]] tables "
            "(drop --live, or keep one [camera] table)"
        )
    if cfg.cameras:  # [[camera]] tables: a recording per camera
        from .simulate.multicam import multicam_outputs

        simulate_to_dir(config, out, duration_s=s.duration_s, seed=s.seed)
        wrote(
            "simulate",
            *(out / n for n in multicam_outputs(cfg)),
            detail=f"{len(cfg.cameras)} cameras; {time.perf_counter() - t0:.1f} s",
        )
        return [out]
    if s.live:
        write_live(config, out, duration_s=s.duration_s, seed=s.seed, speed=s.speed, session=s.session)
        wrote("simulate", out / "trajectory.csv", detail=f"live, {time.perf_counter() - t0:.1f} s")
        return [out]
    raw = tomllib.loads(resolve_config(config).read_text())
    names = list_sessions(raw)
    picked = s.session or raw.get("recording", {}).get("session") or None
    if len(names) <= 1 or picked is not None or len(set(names)) < len(names):
        simulate_to_dir(config, out, duration_s=s.duration_s, seed=s.seed, session=s.session)
        made = picked or (names[0] if names else None)
        wrote(
            "simulate",
            *(out / n for n in ("recording.zarr", "truth.csv", "lds.csv", "config.json")),
            detail=(f"session {made} of {len(names)}; " if len(names) > 1 else "")
            + f"{time.perf_counter() - t0:.1f} s",
        )
        return [out]
    console.print(
        f"jaxdefl simulate: {config} has {len(names)} sessions ({', '.join(names)}): each goes to "
        f"{out}/<session>/ (--session NAME makes one, in {out} itself)",
        markup=False,
        highlight=False,
        soft_wrap=True,
    )
    dirs = []
    for k, name in enumerate(names):
        console.print(
            f"jaxdefl simulate: session {k + 1}/{len(names)}: {name}", markup=False, highlight=False
        )
        dirs.append(simulate_to_dir(config, out / name, duration_s=s.duration_s, seed=s.seed, session=name))
    wrote(
        "simulate",
        *dirs,
        detail=f"{len(dirs)} sessions, each with recording.zarr, truth.csv, lds.csv and config.json; "
        f"{time.perf_counter() - t0:.1f} s",
    )
    return dirs


def extract_file(recording: Path, out: Path, settings: ExtractSettings) -> None:
    """`jaxdefl extract`: the plates of every frame of ``recording`` to the table ``out``
    (`jaxdefl.frames.extract_to_table`), with a closing line."""
    from .frames import extract_to_table
    from .io.camera import camera_sidecar

    t0 = time.perf_counter()
    extract_to_table(recording, out, settings)
    side = camera_sidecar(out)
    wrote("extract", out, *([side] if side.is_file() else []), detail=f"{time.perf_counter() - t0:.1f} s")


def run_file(config: Path, out: Path, settings: RunSettings) -> pd.DataFrame:
    """`jaxdefl run`: a campaign config to ``out`` (see `jaxdefl.bulk`); ``settings``
    (`jaxdefl.settings.RunSettings`, validated when made): the scheduler, and the timestamp
    policy that overrides the campaign's ``processing.timestamps``."""
    from .bulk import load_campaign, run_campaign

    t0 = time.perf_counter()
    campaign = load_campaign(config)
    if settings.timestamps is not None:
        campaign = replace(campaign, processing=replace(campaign.processing, timestamps=settings.timestamps))
    console.print(
        f"jaxdefl run: campaign {campaign.name}: {len(campaign.recordings)} recording(s) -> {out}",
        markup=False,
        highlight=False,
    )
    units = run_campaign(campaign, out, scheduler=settings.scheduler)
    n_ok = int((units["status"] == UnitStatus.OK).sum())
    written = [Path(out) / n for n in ("report.md", "per_day.csv", "results.zarr")]
    wrote(
        "run",
        *([p for p in written if p.exists()] or [out]),
        detail=f"{campaign.name}: {n_ok}/{len(units)} recordings estimated, "
        f"{int(units['skipped'].sum())} reused; {time.perf_counter() - t0:.1f} s",
    )
    failed = units[units["status"] != UnitStatus.OK]
    for r in failed.itertuples():
        console.print(f"  [red]failed[/] {r.unit}: {r.reason}")
    if len(failed):
        first = failed.iloc[0]
        raise JaxdeflError(
            f"{len(failed)} of {len(units)} units failed (first: {first['unit']}: {first['reason']}); "
            f"the others are in {Path(out) / 'report.md'}"
        )
    return units


# --------------------------------------------------------------------------------------------
# demo


DEMO_CONFIG = "exp2_tof_3hz.toml"


def _demo_recording(out: Path, duration_s: float, seed: int):
    """Simulate Experiment II day 1 (3 Hz, SR4000 at 20 Hz) into ``out/simulation``."""
    from .simulate import simulate_to_dir

    cfg = config_dir() / DEMO_CONFIG
    if not cfg.is_file():
        raise JaxdeflError(f"{cfg}: the demo's simulation config is missing from the installed package")
    sim = out / "simulation"
    simulate_to_dir(cfg, sim, duration_s=duration_s, seed=seed)
    return sim


def demo(out: Path, duration_s: float = 120.0, seed: int = 1) -> Path:
    """The main job on the built-in default: frames -> trajectories -> fits -> report in ``out``.

    Returns the report's path."""

    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ConfigError(f"--out {out}: is a file; expected a directory")
    if not (np.isfinite(duration_s) and duration_s > 0):
        raise ConfigError(f"--duration: expected a positive duration in s, got {duration_s:g}")
    out.mkdir(parents=True, exist_ok=True)
    # everything is made in a staging directory inside OUT and renamed into place at the end:
    # an interrupted demo leaves the previous report whole
    staging = Path(tempfile.mkdtemp(dir=out, prefix=".jaxdefl-tmp-demo-"))
    outs = Outputs()
    try:
        report = _demo_into(staging, duration_s, seed)
        for p in sorted(staging.iterdir()):
            outs.adopt(out / p.name, p)
        outs.commit()
    finally:
        outs.discard()
        shutil.rmtree(staging, ignore_errors=True)
    wrote("demo", out / report.name, detail=f"figures and tables in {out}")
    return out / report.name


def _demo_into(out: Path, duration_s: float, seed: int) -> Path:
    from .fit import compare_with_reference, fit_reference
    from .frames import extract_recording
    from .io.recording import open_recording
    from .report.summary import write_demo_report
    from .simulate import load_config

    t0 = time.perf_counter()
    console.print(
        f"[bold]jaxdefl demo[/]: simulating {duration_s:.0f} s of Experiment II day 1 "
        "(3 Hz loading, SR4000 at 20 Hz, 29 MHz)"
    )
    sim = _demo_recording(out, duration_s, seed)
    t_sim = time.perf_counter() - t0
    t1 = time.perf_counter()
    console.print("jaxdefl demo: extracting the plates from every simulated frame", markup=False)
    rec = open_recording(sim / "recording.zarr")
    traj = extract_recording(rec, realtime=False)
    write_trajectory(traj, out / "trajectories.csv")
    t_extract = time.perf_counter() - t1
    lds = read_reference(sim / "lds.csv")
    truth = read_trajectory(sim / "truth.csv")
    t1 = time.perf_counter()
    traj_v = read_trajectory(out / "trajectories.csv")
    console.print("jaxdefl demo: fitting the whole record and 30-s windows", markup=False)
    whole = _estimate(traj_v, keep=tuple(range(3 * traj_v["plate"].nunique())))
    t_whole = time.perf_counter() - t1
    t1 = time.perf_counter()
    windowed = _estimate(traj_v, window_s=30.0)
    t_windowed = time.perf_counter() - t1
    with status("jaxdefl demo: the simulator's truth and the LDS fitted ..."):
        true_fit = _estimate(truth, axes=("z",), progress=False)
        ref = fit_reference(lds, whole)
    comparison = compare_with_reference(whole.table, ref.table)
    write_estimates(whole.table, out / "estimates_whole.csv")
    write_estimates(windowed.table, out / "estimates_30s.csv")
    with status("jaxdefl demo: emcee posteriors of 3 windows against the linearised σ's ..."):
        uncertainty = check_uncertainty(windowed, out / "estimates_30s.csv", n_posterior=3, seed=seed)
    write_estimates(ref.table, out / "estimates_lds.csv")
    write_estimates(comparison, out / "comparison_lds.csv")
    with status("jaxdefl demo: figures and summary.md ..."):
        report = write_demo_report(
            out,
            rec,
            traj_v,
            whole,
            windowed,
            comparison,
            true_fit.table,
            uncertainty,
            timings=dict(
                simulate_s=t_sim, extract_s=t_extract, fit_whole_s=t_whole, fit_windows_s=t_windowed
            ),
            cfg=load_config(config_dir() / DEMO_CONFIG),
        )
    console.print(f"jaxdefl demo: done in {time.perf_counter() - t0:.1f} s", markup=False)
    return report


_CAMERA_FACTS = (
    "sensor",
    "frame_rate_hz",
    "modulation_mhz",
    "tap_offsets",
    "depth_step_mm_at_2m",
    "jumps_per_minute",
    "jump_mm",
)


def _camera_facts(config: Path | None, camera: str | None = None) -> dict:
    """Sensor, frame rate, modulation and tap offsets from a simulation config (TOML); of a
    structured-light camera, its depth lattice and level jumps (its nominal physics). ``camera``:
    one camera of a several-camera config (default: its first)."""
    if config is None:
        return {}
    from .simulate import load_config

    cfg = load_config(config)
    cam = cfg.for_camera(camera).camera if camera is not None else cfg.camera
    facts = {
        "sensor": "tof" if cam.sensor == "sr4000" else "structured_light",
        "frame_rate_hz": cam.frame_rate_hz,
    }
    if cam.sensor == "sr4000":
        facts["modulation_mhz"] = cam.modulation_mhz
        facts["tap_offsets"] = tuple(cam.tap_offsets)
    else:
        facts["depth_step_mm_at_2m"] = cam.depth_resolution_mm_at_2m
        facts["jumps_per_minute"] = cam.jumps_per_minute
        facts["jump_mm"] = cam.jump_mm
    return facts


def _with_sensor_facts(settings: DiagnoseSettings, config: Path | None, traj: Path):
    """``settings`` with what the flags do not say of the camera: from the ``config``, then from
    the facts `jaxdefl extract` wrote beside ``traj`` (``TRAJ.camera.json``), and a note saying
    where the sensor kind came from (None when no source names it)."""
    from .io.camera import camera_sidecar, read_camera_sidecar

    given = settings.sensor
    from_config = _camera_facts(config)
    recorded = read_camera_sidecar(traj)
    settings = settings.with_camera(from_config).with_camera(recorded)
    if settings.sensor is None:
        return settings, None
    if given is not None:
        source = "--sensor"
    elif from_config:
        source = f"the config {config}"
    else:
        source = f"the recording's attributes ({camera_sidecar(traj).name})"
    note = f"sensor: {settings.sensor}, from {source}"
    if recorded.get("sensor") not in (None, settings.sensor):
        note += f"; the recording's attributes say {recorded['sensor']}"
        console.print(f"  [yellow]{note}[/]", highlight=False, soft_wrap=True)
    return settings, note


# Memory a diagnosis adds per row of the table to what the process holds once the table is read
# (measured peak RSS, 10 plates, one axis: 1.95 GB for 0.97 M rows, 6.1 GB for 4.85 M rows, from
# ~0.6 GB at the start; the search holds several residual and weight vectors per series at once).
_DIAGNOSE_BYTES_PER_ROW = 1500
_DIAGNOSE_SAY_BYTES = 1 << 30  # larger estimates are said before the work starts


def _check_diagnosis_memory(df: pd.DataFrame, traj: Path, settings: DiagnoseSettings) -> None:
    """Estimate the diagnosis' memory from the rows it will use; say it when large and refuse it
    when the system has less available."""
    import resource

    from ._resources import check_available_memory, size_text

    rows = len(df)
    if settings.segment is not None and "segment" in df.columns:
        rows = int((df["segment"].astype(str) == settings.segment).sum())
    need = _DIAGNOSE_BYTES_PER_ROW * rows
    check_available_memory(
        need, f"{traj}: diagnosing {rows:,} rows", "diagnose one --segment or a shorter record"
    )
    if need > _DIAGNOSE_SAY_BYTES:
        held = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024  # Linux: KiB
        console.print(
            f"diagnose: {traj}: {rows:,} rows, ~{size_text(held + need)} of memory",
            highlight=False,
            soft_wrap=True,
        )


def _chain_null(d: dict, config: Path, settings, twins: int, duration_s: float, with_reference: bool) -> dict:
    """DIAG.json with the twins' null applied (`jaxdefl.reconcile.chain`)."""
    from .reconcile.chain import apply_chain_null, chain_null

    with status(f"jaxdefl diagnose: simulating, extracting and diagnosing {twins} twins of {config} ..."):
        null = chain_null(
            config, settings, clip_s=min(60.0, duration_s), k=twins, with_reference=with_reference
        )
    return apply_chain_null(d, null, duration_s)


def _usable_reference(ref: pd.DataFrame | None, config: Path | None, source: Path | None):
    """(the reference without the plate the config marks defective, a note or None)."""
    if ref is None or config is None:
        return ref, None
    from .simulate import load_config, usable_reference

    return usable_reference(ref, load_config(config), str(source))


def diagnose_file(
    traj: Path,
    out: Path,
    settings: DiagnoseSettings,
    reference: Path | None = None,
    config: Path | None = None,
    figures: bool = True,
    twins: int = 4,
) -> dict:
    """`jaxdefl diagnose`: read, diagnose, write OUT.json, OUT.md and a figure per effect.

    With a ``config``, ``twins`` simulated twins of it are the null of every named effect
    (`jaxdefl.reconcile.chain`): what they find as strongly is the sensor's nominal physics.

    ``settings`` were validated whole when they were made (`jaxdefl.settings.DiagnoseSettings`);
    what they do not say of the camera comes from the simulation ``config``, when given.
    """
    from .diagnose import run_diagnosis
    from .report.diagnosis import write_diagnosis_report

    traj, out = Path(traj), Path(out)
    outs = Outputs(inputs=[traj, reference, config])
    outs.reserve(out, "--out", suffixes=(".json",))
    outs.reserve(out.with_suffix(".md"), "the diagnosis report")
    settings, sensor_note = _with_sensor_facts(settings, config, traj)
    # the tables as read: `run_diagnosis` validates them (once; validation sorts every row)
    with status(f"jaxdefl diagnose: reading {traj}"):
        df = load_table(traj)
        ref = load_table(reference) if reference is not None else None
    ref, ref_note = _usable_reference(ref, config, reference)
    _check_diagnosis_memory(df, traj, settings)

    def on_round(r: int, eid: str | None) -> None:
        console.print(f"round {r + 1}: " + (f"located [bold]{eid}[/bold]" if eid else "nothing more to add"))

    with status(f"jaxdefl diagnose: {traj} against the nominal model ..."):
        diag = run_diagnosis(
            df, ref, settings, source=str(traj), reference_source=str(reference), on_round=on_round
        )
    if ref_note:
        diag.notes.insert(0, ref_note)
    if sensor_note:
        diag.notes.insert(0, sensor_note)
    for note in diag.notes:
        if "timestamps reclocked" in note or "timestamps merged" in note:
            console.print(f"  {note}", highlight=False, soft_wrap=True)
    d = diag.to_json()
    if config is not None and twins > 0:
        named = d["effects"]
        d = _chain_null(d, config, settings, twins, diag.ctx.duration_s, ref is not None)
        kept = {id(e) for e in d["effects"]}  # the report lists what DIAG.json keeps
        diag.accepted = [a for a, e in zip(diag.accepted, named, strict=True) if id(e) in kept]
    d["settings"] = {
        "jaxdefl_version": __version__,
        "trajectory": str(traj),
        "reference": str(reference) if reference else None,
        "config": str(config) if config else None,
        **{k: v for k in _CAMERA_FACTS if (v := getattr(settings, k)) is not None},
        "segment": settings.segment,
        "effects": list(settings.effects) if settings.effects else None,
        "timestamps": settings.timestamps,
    }
    with outs:
        outs.json(out, d)
        written = write_diagnosis_report(diag, d, out, outs, figures=figures)
    names = ", ".join(e["id"] for e in d["effects"]) or "none"
    wrote(
        "diagnose",
        *written,
        out,
        detail=f"effects: {names}; unnamed: {len(d.get('unnamed') or [])}; unexplained: "
        f"{len(d['unexplained'])}; RMS {d['nominal']['rms_mm']:.4f} -> {d['final']['rms_mm']:.4f} mm; "
        f"{diag.seconds:.1f} s",
    )
    return d


def attribute_file(
    traj: Path,
    out: Path,
    settings: DiagnoseSettings,
    reference: Path | None = None,
    column: str = "camera",
    config: Path | None = None,
    session: str | None = None,
    twins: int = 4,
) -> dict:
    """`jaxdefl attribute`: diagnose every camera of a registered trajectory and say of each
    finding whether it is on a camera's side or the structure's (`jaxdefl.diagnose.attribution`);
    OUT.json and OUT.md. With the recording's several-camera ``config``: each camera is diagnosed
    with its own sensor facts, and what ``twins`` simulated twins of that camera find by
    themselves (`reconcile.chain.chain_null`, one render for all cameras) is its nominal physics,
    not a finding."""
    from .diagnose.attribution import attribute, attribution_table

    traj, out = Path(traj), Path(out)
    outs = Outputs(inputs=[traj, reference, config])
    outs.reserve(out, "--out", suffixes=(".json",))
    outs.reserve(out.with_suffix(".md"), "the attribution report")
    cfg = None
    if config is not None:
        from .simulate import load_config

        cfg = load_config(config, session)  # checked before anything is read
        if not cfg.cameras:
            raise ConfigError(f"--config {config}: has one camera; expected [[camera]] tables (several)")
    with status(f"jaxdefl attribute: reading {traj}"):
        df = load_table(traj)
        ref = load_table(reference) if reference is not None else None
    _check_diagnosis_memory(df, traj, settings)
    per_camera, nulls = None, None
    if cfg is not None and column in df.columns:
        names = [str(c) for c in pd.unique(df[column].astype(str))]
        unknown = [c for c in names if c not in cfg.camera_names]
        if unknown:
            raise InputError(
                f"{traj}: camera {unknown[0]!r} is not in --config {config}; expected one of "
                + ", ".join(cfg.camera_names)
            )
        per_camera = {c: settings.with_camera(_camera_facts(config, c)) for c in names}
        if twins > 0:
            from .reconcile.chain import apply_chain_null, chain_null

            duration = float(df["t"].max() - df["t"].min())
            nulls = {}
            for c in names:
                say = f"jaxdefl attribute: simulating, extracting and diagnosing {twins} twins of {c} ..."
                with status(say):
                    null = chain_null(
                        config,
                        per_camera[c],
                        clip_s=min(60.0, duration),
                        k=twins,
                        with_reference=ref is not None,
                        session=session,
                        camera=c,
                    )
                nulls[c] = lambda d, seconds, null=null: apply_chain_null(d, null, seconds)

    def on_camera(c: str) -> None:
        console.print(f"diagnosing camera [bold]{c}[/bold]")

    with status(f"jaxdefl attribute: {traj}, camera by camera ..."):
        a = attribute(
            df,
            ref,
            settings,
            column=column,
            source=str(traj),
            on_camera=on_camera,
            per_camera=per_camera,
            nulls=nulls,
        )
    d = a.to_json()
    d["settings"] = {
        "jaxdefl_version": __version__,
        "trajectory": str(traj),
        "reference": str(reference) if reference else None,
        "config": str(config) if config else None,
        "twins": twins if nulls else 0,
        "camera_column": column,
        "effects": list(settings.effects) if settings.effects else None,
        "timestamps": settings.timestamps,
    }
    rows = attribution_table(a)
    md = [
        f"# Attribution of {traj.name}",
        "",
        "Cameras: "
        + ", ".join(f"{c} (plates {', '.join(map(str, v['plates']))})" for c, v in a.cameras.items())
        + f"; shared plates: {', '.join(map(str, a.shared_plates)) or 'none'}.",
        "",
        "| effect | named by | attribution | why |",
        "| --- | --- | --- | --- |",
        *[f"| {' | '.join(r)} |" for r in rows],
    ]
    if not rows:
        md.append("| none | | | no camera's diagnosis named an effect |")
    with outs:
        outs.json(out, d)
        outs.text(out.with_suffix(".md"), "\n".join(md) + "\n")
    for r in rows:
        console.print(f"  {r[0]} ({r[1]}): [bold]{r[2]}[/bold] - {r[3]}", highlight=False, soft_wrap=True)
    wrote(
        "attribute",
        out,
        out.with_suffix(".md"),
        detail=f"{len(rows)} findings: "
        + (", ".join(f"{r[0]} {r[2]}" for r in rows) or "none")
        + f"; {a.seconds:.1f} s",
    )
    return d


# --------------------------------------------------------------------------------------------
# reconcile


def _is_frames(recording: Path) -> bool:
    """A frame recording (zarr, TUM, npz), not a trajectory table."""
    return recording.suffix.lower() not in (".csv", ".parquet", ".pq", ".gz", ".txt")


def _reconcile_input(recording: Path, segment: str | None, timestamps: str = "strict") -> pd.DataFrame:
    """A trajectory table as read, or a frame recording's extracted trajectories; one segment."""
    from .io import validate_trajectory

    if not _is_frames(recording):
        df = read_trajectory(recording, timestamps=timestamps)
    else:
        from .frames import extract_recording
        from .io.recording import open_recording

        frames_policy = "reclock" if timestamps == "reclock" else "strict"
        frames = extract_recording(open_recording(recording, timestamps=frames_policy))
        df = validate_trajectory(frames, recording, timestamps=timestamps)
    segments = list(pd.unique(df["segment"]))
    if segment is None:
        if len(segments) > 1:
            console.print(f"reconcile: {recording} holds segments {', '.join(segments)}; using {segments[0]}")
        segment = segments[0]
    elif segment not in segments:
        raise ParameterError(
            "segment", f"{recording} has no segment {segment!r}; expected one of {', '.join(segments)}"
        )
    return df[df["segment"] == segment].reset_index(drop=True)


def reconcile_file(
    recording: Path,
    config: Path,
    out: Path,
    settings: ReconcileSettings,
    reference: Path | None = None,
    twins: int = 4,
) -> dict:
    """`jaxdefl reconcile`: DIR/reconcile.json, DIR/reconciled.toml, DIR/report.md and figures.

    ``settings`` were validated whole when they were made (`jaxdefl.settings.ReconcileSettings`);
    what they do not say of the camera comes from ``config``.
    """
    import json
    import tomllib

    import matplotlib.pyplot as plt

    from ._configs import resolve_config
    from .reconcile import calibrate, effect_tables_toml, reconcile
    from .report.reconcile import plot_level, reconcile_markdown
    from .simulate import config_from_dict, load_config

    recording, out = Path(recording), Path(out)
    config = resolve_config(config)
    session, seed, timestamps = settings.session, settings.seed, settings.timestamps
    if out.exists() and not out.is_dir():
        raise ConfigError(f"--out {out}: is a file; expected a directory")
    cfg = load_config(config, session)  # checked before anything is read or written
    outs = Outputs(inputs=[recording, config, reference])
    names = ("reconcile.json", "reconciled.toml", "report.md", "trajectories.png", "estimates.png")
    if _is_frames(recording):
        names += ("frames.png",)
    for name in names:
        outs.reserve(out / name, f"--out {out}: {name}")
    df = _reconcile_input(recording, settings.segment, timestamps)
    ref = read_reference(reference, timestamps=timestamps) if reference is not None else None
    ref, ref_note = _usable_reference(ref, config, reference)
    settings = replace(settings, diagnosis=settings.diagnosis.with_camera(_camera_facts(config)))
    with status("jaxdefl reconcile: simulating and extracting a calibration clip ...") as step:
        calibration = calibrate(cfg, seconds=10.0, seed=seed)
        chain = None
        if twins > 0:
            from .reconcile.chain import chain_null

            step.update(f"jaxdefl reconcile: simulating, extracting and diagnosing {twins} twins ...")
            duration = float(df["t"].max() - df["t"].min())
            chain = chain_null(
                config,
                settings.diagnosis,
                clip_s=min(60.0, duration),
                k=twins,
                with_reference=ref is not None,
                session=session,
            )
        rec = reconcile(
            df,
            ref,
            settings,
            source=str(recording),
            on_step=lambda msg: step.update(f"jaxdefl reconcile: {msg} ..."),
            calibration=calibration,
            chain=chain,
        )
    if _is_frames(recording):
        # the frames level: the recording's first seconds against clips of the frame simulator
        from .io.recording import open_recording
        from .reconcile.frames import frame_levels
        from .simulate.injection import FRAME_LEVELS

        with status("jaxdefl reconcile: comparing the frames with the frame simulator's ..."):
            frames_policy = "reclock" if timestamps == "reclock" else "strict"
            shown = tuple(s for s in rec.specs if s.level in FRAME_LEVELS)
            rec.levels[:0] = frame_levels(
                open_recording(recording, timestamps=frames_policy), cfg, rec.f0_hz, shown, seed=seed
            )
    # the clock level: the recording's stamps against the configured camera's clock
    from .reconcile.clock import clock_levels

    rec.levels.extend(clock_levels(df["t"].to_numpy(), cfg, seed=seed))
    base = Path(config).read_text()
    toml = (
        base.rstrip("\n")
        + f"\n\n# [[effect]] tables added by jaxdefl {__version__} reconcile: the physics that the\n"
        + f"# diagnosis named in {recording}, with its fitted parameters (times from the first frame).\n\n"
        + effect_tables_toml(rec.specs)
    )
    config_from_dict(tomllib.loads(toml), str(out / "reconciled.toml"), session)  # simulate accepts it
    notes = list(rec.diagnosis.get("notes") or [])
    if ref_note:
        notes.insert(0, ref_note)
    d = {
        "levels": rec.levels,
        "effects": rec.effects,
        "config": "reconciled.toml",
        "unexplained": rec.diagnosis.get("unexplained", []),
        "nominal_physics": rec.diagnosis.get("nominal_physics", []),
        "notes": notes,
        "f0_hz": rec.f0_hz,
        "settings": {
            "jaxdefl_version": __version__,
            "recording": str(recording),
            "config": str(config),
            "reference": str(reference) if reference else None,
            "session": session if session is not None else (cfg.recording.session or None),
            "segment": str(df["segment"].iat[0]),
            "null_sims": settings.n_null,
            "seed": seed,
            "sensor": cfg.camera.sensor,
        },
    }
    for r in d["levels"]:
        r["verdict"] = rec.verdict(r)
    with outs:
        outs.text(out / "reconcile.json", json.dumps(d, indent=2, default=float))
        outs.text(out / "reconciled.toml", toml)
        figs = []
        for level in ("frames", "trajectories", "estimates"):
            if not any(r["level"] == level for r in rec.levels):
                continue
            fig = plot_level(rec, level)
            outs.figure(out / f"{level}.png", fig, dpi=110)
            figs.append(f"{level}.png")
            plt.close(fig)
        outs.text(out / "report.md", reconcile_markdown(rec, d, figs, str(recording), str(config), str(out)))
    verdicts = ", ".join(f"{r['metric']} {r['verdict']}" for r in d["levels"])
    names = ", ".join(e["id"] for e in rec.effects) or "none"
    wrote(
        "reconcile",
        out / "report.md",
        out / "reconcile.json",
        out / "reconciled.toml",
        *(out / f for f in figs),
        detail=f"effects: {names}; {verdicts}",
    )
    return d


REGISTER_OUTPUTS = (
    "poses.csv",
    "clocks.csv",
    "landmarks.csv",
    "trajectory.csv",
    "profile.csv",
    "common.csv",
    "registration.json",
    "profile.png",
)


def register_files(
    recordings: list[Path],
    trajectories: list[Path],
    config: Path,
    out: Path,
    lds: Path | None = None,
    sample_frames: int = 100,
) -> Path:
    """`jaxdefl register`: every camera's pose and clock, its plates in the beam frame, the
    profile along the beam and the shared plates fused (`jaxdefl.register`), in ``out``.

    Each camera is a recording (its median frame and amplitude: floor, beam top, floor targets)
    and the trajectory `extract` made of it (camera frame); ``config`` gives the beam's geometry.
    """
    import json

    from .io.recording import open_recording
    from .register import BeamGeometry, CameraInput, register_cameras, scene_points
    from .report.multicam import plot_beam_profile
    from .simulate import load_config

    out = Path(out)
    if len(recordings) != len(trajectories):
        raise ParameterError(
            "trajectory",
            f"expected one --trajectory per recording, in the same order; got {len(recordings)} "
            f"recordings and {len(trajectories)} trajectories",
        )
    if len(recordings) < 1:
        raise ParameterError("recordings", "expected at least one recording")
    if sample_frames < 1:
        raise ParameterError("sample_frames", f"expected a number of frames >= 1, got {sample_frames}")
    if out.exists() and not out.is_dir():
        raise ConfigError(f"--out {out}: is a file; expected a directory")
    geo = BeamGeometry.from_config(load_config(config))
    ref = read_reference(lds) if lds is not None else None
    cams, names = [], []
    for rec_path, traj_path in zip(recordings, trajectories, strict=True):
        rec = open_recording(rec_path)
        name = str(rec.attrs.get("camera") or Path(rec_path).stem)
        if name in names:
            name = f"{name}_{len(names) + 1}"
        names.append(name)
        step = max(1, rec.n_frames // sample_frames)
        frames, amps = [], []
        for chunk in rec.chunks(256):
            keep = (np.arange(chunk.start, chunk.start + len(chunk.t)) % step) == 0
            frames.append(chunk.frames[keep])
            if chunk.amplitude is not None:
                amps.append(chunk.amplitude[keep])
        frames = np.concatenate(frames)
        amp = np.nanmedian(np.concatenate(amps), axis=0) if amps else None
        a = rec.attrs
        taps = None
        if rec.kind == "range" and "tap_offsets" in a and "nar_mm" in a and "frame_rate_hz" in a:
            taps = (tuple(a["tap_offsets"]), float(a["frame_rate_hz"]), float(a["nar_mm"]))
        traj = read_trajectory(traj_path)
        cams.append(
            CameraInput(name, traj, scene_points(frames, rec.intrinsics, rec.kind), amplitude=amp, taps=taps)
        )
    reg = register_cameras(cams, geo, ref)
    outs = Outputs(inputs=[*recordings, *trajectories, config] + ([lds] if lds is not None else []))
    for name in REGISTER_OUTPUTS:
        outs.reserve(out / name, f"--out {out}: {name}")
    with outs:
        for name, df in (
            ("poses.csv", reg.poses),
            ("clocks.csv", reg.clocks),
            ("landmarks.csv", reg.landmarks),
            ("trajectory.csv", reg.trajectory),
            ("profile.csv", reg.profile),
            ("common.csv", reg.common),
        ):
            df.to_csv(outs.path(out / name), index=False, float_format="%.6f")
        outs.text(
            out / "registration.json", json.dumps({"reference": reg.reference, "cameras": names}, indent=2)
        )
        plot_beam_profile(reg.profile, geo.span_mm, geo.load_a_mm, outs.path(out / "profile.png"))
    wrote("register", *(out / n for n in REGISTER_OUTPUTS), detail=f"{len(cams)} cameras")
    return out
