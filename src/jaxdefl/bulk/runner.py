"""Run a campaign's units in-process or on dask.distributed, then gather the results."""

from __future__ import annotations

import importlib
import os
import threading
import time
from concurrent.futures import FIRST_COMPLETED, ThreadPoolExecutor, wait
from pathlib import Path

import pandas as pd
from threadpoolctl import threadpool_limits

from .. import __version__
from .._signals import check_interrupt
from .campaign import Campaign
from .scheduling import NoBar, connect, progress_bar, release_memory
from .store import digest_text
from .units import estimate_unit, unit_inputs

__all__ = ["run_campaign"]


# Units run side by side in-process: a unit's Python stages (reading, windowing, tables) hold
# the GIL while the other's kernels (XLA, numpy, pyarrow release it) run on the second core.
UNIT_THREADS = 2


# What `gather` imports (matplotlib through the report, xarray and the duck-array libraries it
# probes, zarr): ~1 s of imports that otherwise run after the last unit, on one core.
_AGGREGATE_MODULES = ("jaxdefl.report.campaign", "xarray", "zarr", "dask.array")


def _import_for_aggregate() -> threading.Thread:
    """Import the aggregate's libraries on a thread of their own while the units run (Python's
    import lock makes `gather`'s own imports wait for a module half imported here)."""

    def load():
        for name in _AGGREGATE_MODULES:
            try:
                importlib.import_module(name)
            except Exception:  # noqa: BLE001 - `gather` imports it again and reports the error
                pass

    thread = threading.Thread(target=load, name="jaxdefl-imports", daemon=True)
    thread.start()
    return thread


def _run_in_process(recs, inputs, campaign: Campaign, out: Path, config_hash: str):
    """Yield the manifests of the units, run on UNIT_THREADS threads (at most that many
    started at a time, so that an interrupt leaves the rest for a rerun)."""
    todo = list(zip(recs, inputs, strict=True))
    threads = max(1, min(UNIT_THREADS, os.cpu_count() or 1))
    # Units run side by side on the cores: BLAS's own threads would only spin against them (the
    # clock fit of a day's stamps took 10x the CPU time). Set once for the pool, not per unit:
    # overlapping units would restore each other's setting.
    with threadpool_limits(limits=1, user_api="blas"), ThreadPoolExecutor(max_workers=threads) as pool:
        running: set = set()
        try:
            while todo or running:
                while todo and len(running) < threads:
                    check_interrupt()  # finished units are kept; the rest waits for a rerun
                    rec, inp = todo.pop(0)
                    running.add(pool.submit(estimate_unit, rec, campaign.processing, out, config_hash, inp))
                done, running = wait(running, return_when=FIRST_COMPLETED)
                for fut in done:
                    yield fut.result()
                release_memory()
        finally:
            todo.clear()
            for fut in running:
                fut.cancel()


def _estimate_unit_on_worker(*args):
    """`estimate_unit` on a dask worker, with single-threaded BLAS (see `_run_in_process`)."""
    with threadpool_limits(limits=1, user_api="blas"):
        return estimate_unit(*args)


def run_campaign(
    campaign: Campaign, out: Path, scheduler: str = "none", progress: bool = True
) -> pd.DataFrame:
    """Run every unit (skipping finished, fresh ones) and gather tables, figures and a report.

    Returns the unit table: unit, day, camera, status, reason, seconds, skipped.
    """
    from .aggregate import gather

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    config_hash = digest_text(campaign.processing.digest_source() + __version__)
    recs = list(campaign.recordings)
    if campaign.simulate is not None:
        from .simulated import ensure_simulated

        recs = ensure_simulated(campaign, out, scheduler=scheduler, progress=progress)
    inputs = [unit_inputs(r) for r in recs]
    importing = _import_for_aggregate()
    manifests = []
    t0 = time.perf_counter()
    with progress_bar() if progress else NoBar() as bar:
        task = bar.add_task("estimating recordings", total=len(recs))
        if scheduler == "none":
            for man in _run_in_process(recs, inputs, campaign, out, config_hash):
                manifests.append(man)
                bar.advance(task)
        else:
            from dask.distributed import as_completed

            client, cluster = connect(scheduler)
            try:
                futs = [
                    client.submit(
                        _estimate_unit_on_worker,
                        rec,
                        campaign.processing,
                        out,
                        config_hash,
                        inp,
                        key=f"estimate-{rec.unit_id}-{config_hash[:8]}",
                        pure=False,
                    )
                    for rec, inp in zip(recs, inputs, strict=True)
                ]
                for fut in as_completed(futs):
                    check_interrupt()
                    manifests.append(fut.result())
                    bar.advance(task)
            finally:
                client.close()
                if cluster is not None:
                    cluster.close()
    check_interrupt()
    importing.join()
    manifests.sort(key=lambda m: m["unit"])
    units = pd.DataFrame(
        [
            {k: m.get(k) for k in ("unit", "day", "camera", "status", "reason", "seconds")}
            | {"skipped": bool(m.get("skipped", False))}
            for m in manifests
        ]
    )
    gather(campaign, out, manifests, units, elapsed_s=time.perf_counter() - t0)
    return units
