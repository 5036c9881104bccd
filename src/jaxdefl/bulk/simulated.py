"""Campaigns that make their own recordings with the simulator.

```toml
[simulate]
config = "exp2_tof_3hz.toml"      # simulation config, relative to the campaign file
sessions = ["day1", "day2"]       # its [[session]] entries to record (default: all)
duration_s = 600.0                # per recording
seed = 1                          # default: the config's
realtime = false                  # extraction mode (tracked plates when true)
unit_frames = 2000                # frames per extraction unit
```

Each session goes through three kinds of units, each resumable on its own:
``sim-<day>-<camera>`` (frames, truth and LDS), ``ext-<day>-<camera>-<k>`` (plates extracted
from frames ``k * unit_frames ..``, one trajectory part each) and the usual estimate unit over
the merged trajectories (``trajectories.csv`` in the simulation unit, written atomically).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pandas as pd

from ..status import UnitStatus
from .campaign import Recording
from .store import atomic_write_text, digest_path, digest_text, run_unit

__all__ = ["ensure_simulated", "extract_unit", "simulate_unit"]


def simulate_unit(rec: Recording, out_dir: Path) -> dict:
    """Frames, truth and LDS of one session into ``units/sim-<day>-<camera>/``."""
    from ..simulate import simulate_to_dir

    spec = rec.simulate
    unit_dir = Path(out_dir) / "units" / f"sim-{rec.unit_id}"
    inputs = {
        "config": digest_path(Path(spec["config"])),
        "spec": digest_text(repr(sorted((k, spec[k]) for k in ("session", "duration_s", "seed")))),
    }

    def work(unit_dir: Path) -> list[str]:
        simulate_to_dir(
            spec["config"],
            unit_dir,
            duration_s=spec["duration_s"],
            seed=spec["seed"],
            progress=False,
            session=spec["session"],
        )
        return ["recording.zarr", "truth.csv", "lds.csv"]

    return run_unit(unit_dir, f"sim-{rec.unit_id}", inputs, "simulate", work)


def extract_unit(rec: Recording, out_dir: Path, part: int, start: int, stop: int, sim_manifest: dict) -> dict:
    """Plates of frames ``start .. stop`` of a simulated recording -> ``ext-.../part.csv``."""
    from ..frames import Extractor
    from ..frames.extract import centroid_table
    from ..io.recording import open_recording

    spec = rec.simulate
    uid = f"ext-{rec.unit_id}-{part:03d}"
    unit_dir = Path(out_dir) / "units" / uid
    zarr_sig = sim_manifest["outputs"]["recording.zarr"]
    inputs = {
        "recording": digest_text(repr(sorted(zarr_sig.items()))),
        "frames": f"{start}:{stop}",
        "realtime": str(spec["realtime"]),
    }

    def work(unit_dir: Path) -> list[str]:
        rec_z = open_recording(Path(out_dir) / "units" / f"sim-{rec.unit_id}" / "recording.zarr")
        from ..frames.pipeline import PlateGeometry

        geo = PlateGeometry(rec_z.plate_x_mm, rec_z.camera_x_mm) if rec_z.plate_x_mm is not None else None
        ex = Extractor(rec_z.intrinsics, rec_z.kind, geo, spec["realtime"], source=str(rec_z.path))
        parts = []
        for s in range(start, stop, 256):
            t, fr, amp = rec_z._read(s, min(stop, s + 256))
            cents, plates = ex.run(fr, amp)
            parts.append(centroid_table(t, cents, plates, rec_z.segment))
        df = pd.concat(parts, ignore_index=True)
        atomic_write_text(unit_dir / "part.csv", df.to_csv(index=False, float_format="%.6f"))
        return ["part.csv"]

    return run_unit(unit_dir, uid, inputs, "extract", work)


def _run_all(calls: list[tuple], scheduler: str, bar, task) -> list[dict]:
    """Run (fn, *args) calls in-process or on dask; results in the order of ``calls``."""
    if scheduler == "none":
        out = []
        for fn, *args in calls:
            out.append(fn(*args))
            bar.advance(task)
        return out
    from dask.distributed import wait

    from .scheduling import connect

    client, cluster = connect(scheduler)
    try:
        futs = [client.submit(fn, *args, pure=False) for fn, *args in calls]
        for f in futs:
            wait(f)
            bar.advance(task)
        return [f.result() for f in futs]
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def ensure_simulated(campaign, out: Path, scheduler: str = "none", progress: bool = True) -> list[Recording]:
    """Make (or reuse) every simulated recording and its extracted trajectories.

    Returns the campaign's recordings with ``trajectories`` and ``lds`` pointing at the files;
    a session whose simulation or extraction failed carries the reason in ``failed``, which its
    estimate unit reports.
    """
    from ..io.recording import open_recording
    from .scheduling import NoBar, progress_bar

    out = Path(out)
    recs = list(campaign.recordings)
    with progress_bar() if progress else NoBar() as bar:
        task = bar.add_task("simulating recordings", total=len(recs))
        sims = _run_all([(simulate_unit, r, out) for r in recs], scheduler, bar, task)
        calls, owner = [], []
        for r, sm in zip(recs, sims, strict=True):
            if sm["status"] != UnitStatus.OK:
                continue
            n = open_recording(out / "units" / f"sim-{r.unit_id}" / "recording.zarr").n_frames
            step = r.simulate["unit_frames"]
            for k, s in enumerate(range(0, n, step)):
                calls.append((extract_unit, r, out, k, s, min(n, s + step), sm))
                owner.append(r.unit_id)
        task = bar.add_task("extracting plates", total=len(calls))
        exts = _run_all(calls, scheduler, bar, task)
    resolved = []
    for r, sm in zip(recs, sims, strict=True):
        sim_dir = out / "units" / f"sim-{r.unit_id}"
        mine = [m for m, o in zip(exts, owner, strict=True) if o == r.unit_id]
        traj = sim_dir / "trajectories.csv"
        if sm["status"] == UnitStatus.OK and mine and all(m["status"] == UnitStatus.OK for m in mine):
            merged = pd.concat(
                [pd.read_csv(out / "units" / m["unit"] / "part.csv") for m in mine], ignore_index=True
            )
            merged = merged.sort_values(["plate", "t"], kind="stable")
            text = merged.to_csv(index=False, float_format="%.6f")
            if not traj.exists() or traj.read_text() != text:
                atomic_write_text(traj, text)
            attrs = open_recording(sim_dir / "recording.zarr").attrs
            tof = attrs.get("sensor") == "sr4000"
            resolved.append(
                replace(
                    r,
                    trajectories=traj,
                    lds=sim_dir / "lds.csv",
                    truth=sim_dir / "truth.csv",
                    frame_rate_hz=float(attrs["frame_rate_hz"]) if tof else None,
                    tap_offsets=tuple(attrs["tap_offsets"]) if tof else None,
                )
            )
        else:
            bad = next((m for m in [sm, *mine] if m["status"] != UnitStatus.OK), sm)
            reason = bad.get("reason") or f"{r.unit_id}: no frames to extract"
            resolved.append(replace(r, trajectories=traj, lds=None, failed=reason))
    return resolved
