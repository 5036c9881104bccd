"""Run a campaign's units in-process or on dask.distributed, then gather the results."""

from __future__ import annotations

import ctypes
import gc
import time
from pathlib import Path

import pandas as pd
from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)

from .. import __version__
from .._errors import ConfigError
from .._signals import check_interrupt
from .campaign import Campaign
from .store import digest_text
from .units import estimate_unit, unit_inputs

__all__ = ["run_campaign"]

console = Console(stderr=True)


def _release_memory() -> None:
    """Hand freed memory back to the OS between units, so that the peak does not grow with
    the number of units (glibc keeps freed blocks of big tables in its arenas otherwise)."""
    gc.collect()
    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):  # not glibc
        pass


def _bar():
    return Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        console=console,
        transient=True,
    )


def _client(scheduler: str):
    """A dask.distributed client for "local[:N]" (a LocalCluster of N = 2 workers) or an address."""
    try:
        from dask.distributed import Client, LocalCluster
    except ImportError as err:  # pragma: no cover - distributed is a dependency
        raise ConfigError(f"--scheduler {scheduler}: dask.distributed is not installed ({err})") from None
    if scheduler == "local" or scheduler.startswith("local:"):
        n = scheduler.partition(":")[2] or "2"
        if not n.isdigit() or int(n) < 1:
            raise ConfigError(
                f"--scheduler: expected local or local:N with N >= 1 workers, got {scheduler!r}"
            )
        cluster = LocalCluster(
            n_workers=int(n),
            threads_per_worker=1,
            processes=True,
            dashboard_address=None,
            silence_logs=40,
        )
        return Client(cluster), cluster
    try:
        return Client(scheduler, timeout="10s"), None
    except (OSError, TimeoutError) as err:
        raise ConfigError(f"--scheduler: cannot reach a dask scheduler at {scheduler!r} ({err})") from None


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
    manifests = []
    t0 = time.perf_counter()
    with _bar() if progress else _NoBar() as bar:
        task = bar.add_task("estimating recordings", total=len(recs))
        if scheduler == "none":
            for rec, inp in zip(recs, inputs, strict=True):
                check_interrupt()  # finished units are kept; the rest waits for a rerun
                manifests.append(estimate_unit(rec, campaign.processing, out, config_hash, inp))
                _release_memory()
                bar.advance(task)
        else:
            from dask.distributed import as_completed

            client, cluster = _client(scheduler)
            try:
                futs = [
                    client.submit(
                        estimate_unit,
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


class _NoBar:
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False

    def add_task(self, *a, **k):
        return 0

    def advance(self, *a, **k):
        pass
