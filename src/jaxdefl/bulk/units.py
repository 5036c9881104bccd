"""Units of work: plain functions of paths that write their outputs and manifest, then return it.

They run in-process or as dask tasks unchanged (top-level functions, picklable arguments).
"""

from __future__ import annotations

import time
from contextlib import contextmanager
from pathlib import Path

import pandas as pd

from .._errors import JaxdeflError
from ..status import Status
from .campaign import Processing, Recording
from .store import atomic_write_text, csv_text, digest_path, run_unit

__all__ = ["estimate_unit", "unit_inputs"]


def unit_inputs(rec: Recording) -> dict:
    """Digests of a recording's input files ("missing" for an absent one)."""
    out = {"failed": rec.failed} if rec.failed else {}
    if rec.frame_rate_hz is not None:
        out["sensor"] = f"{rec.frame_rate_hz}:{rec.tap_offsets}"
    for name in ("trajectories", "lds", "truth"):
        p = getattr(rec, name)
        if p is not None:
            out[name] = digest_path(p) if Path(p).exists() else "missing"
    return out


@contextmanager
def _stage(stages: dict[str, float], name: str):
    """Add the seconds of the ``with`` block to ``stages[name]``."""
    t0 = time.perf_counter()
    try:
        yield
    finally:
        stages[name] = stages.get(name, 0.0) + time.perf_counter() - t0


def _csv(df: pd.DataFrame) -> str:
    return csv_text(df, float_format="%.10g")


def _correct_motion(df: pd.DataFrame, rec: Recording) -> pd.DataFrame:
    """Amplitudes corrected for the ToF motion artefact (`jaxdefl.fit.motion`): A / gain(f0)."""
    from ..fit.motion import EVEN_TAPS, motion_artefact_response

    gain, _ = motion_artefact_response(
        df["f0_hz"].to_numpy(), rec.frame_rate_hz, rec.tap_offsets or EVEN_TAPS
    )
    return df.assign(
        motion_gain=gain,
        amplitude_corrected_mm=df["amplitude_mm"] / gain,
        sigma_amplitude_corrected_mm=df["sigma_amplitude_mm"] / gain,
    )


def estimate_unit(
    rec: Recording, proc: Processing, out_dir: Path, config_hash: str, inputs: dict | None = None
) -> dict:
    """Estimates of one recording: whole-record fits, windows, LDS fits and differences.

    Writes ``whole.csv``, ``windows.csv`` (when windowed), ``lds.csv`` and ``comparison.csv``
    (when a reference is given) under ``out_dir/units/<day-camera>/``. A failure (missing or
    invalid file, no valid samples) is recorded in the manifest with its reason; it never raises.
    """
    from ..fit import compare_with_reference, estimate_table, fit_reference, signal_model
    from ..io import load_table, read_reference, read_trajectory, validate_trajectory

    inputs = unit_inputs(rec) if inputs is None else inputs
    tag = dict(day=rec.day, camera=rec.camera, cycles=rec.cycles)
    extra = dict(tag)  # the manifest's extra fields: the tags, then the stage times

    stages: dict[str, float] = {}  # seconds per stage, kept in the manifest

    def work(unit_dir: Path) -> list[str]:
        if rec.failed:
            raise JaxdeflError(rec.failed)
        if inputs.get("trajectories") == "missing":
            raise JaxdeflError(f"{rec.trajectories}: file not found")
        with _stage(stages, "reading"):
            raw = load_table(rec.trajectories)
        with _stage(stages, "validation"):
            traj = validate_trajectory(raw, rec.trajectories, timestamps=proc.timestamps)
        del raw
        axes = tuple(a for a in proc.axes if a in traj.columns)
        kw = dict(
            fmin_hz=proc.fmin_hz,
            fmax_hz=proc.fmax_hz,
            oversampling=proc.oversampling,
            fap_max=proc.fap_max,
            model=signal_model(proc.model, proc.harmonics, proc.lines),
        )
        clocks: dict = {}  # the series' frame clocks, fitted once for the record and its windows
        whole_t: dict[str, float] = {}
        whole = estimate_table(traj, axes=axes, clocks=clocks, timings=whole_t, **kw)
        stages["windowing"] = stages.get("windowing", 0.0) + whole_t.pop("windowing")
        stages["whole-record fit"] = sum(whole_t.values())
        if not (whole.table["status"] == Status.CONVERGED).any():
            raise JaxdeflError(
                f"{rec.trajectories}: no plate and axis could be fitted "
                f"({', '.join(sorted(set(whole.table['status'])))})"
            )
        outputs = {"whole.csv": whole.table.assign(**tag)}
        if proc.window_s is not None:
            win = estimate_table(
                traj,
                axes=axes,
                window_s=proc.window_s,
                step_s=proc.step_s,
                clocks=clocks,
                timings=stages,
                **kw,
            )
            outputs["windows.csv"] = win.table.assign(**tag)
        if proc.correct_motion_artefact and rec.frame_rate_hz is not None:
            for name in list(outputs):
                outputs[name] = _correct_motion(outputs[name], rec)
        if rec.truth is not None:
            truth = read_trajectory(rec.truth)
            truth = truth[truth["plate"].isin(traj["plate"].unique())]
            outputs["truth.csv"] = estimate_table(truth, axes=("z",), **kw).table.assign(**tag)
        if rec.lds is not None:
            if inputs.get("lds") == "missing":
                raise JaxdeflError(f"{rec.lds}: file not found")
            with _stage(stages, "LDS comparison"):
                ref = fit_reference(read_reference(rec.lds, timestamps=proc.timestamps), whole, **kw)
                outputs["lds.csv"] = ref.table.assign(**tag)
                outputs["comparison.csv"] = compare_with_reference(whole.table, ref.table).assign(**tag)
        with _stage(stages, "writing"):
            for name, df in outputs.items():
                atomic_write_text(unit_dir / name, _csv(df))
        extra["stage_seconds"] = {k: round(v, 4) for k, v in stages.items()}
        return list(outputs)

    unit_dir = Path(out_dir) / "units" / rec.unit_id
    return run_unit(unit_dir, rec.unit_id, inputs, config_hash, work, extra=extra)


def read_unit_tables(out_dir: Path, manifests: list[dict], name: str) -> pd.DataFrame:
    """Concatenate one output table over all finished units (empty if none has it)."""
    frames = []
    for man in manifests:
        if name in man.get("outputs", {}):
            frames.append(pd.read_csv(Path(out_dir) / "units" / man["unit"] / name))
    return pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()
