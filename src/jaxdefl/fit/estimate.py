"""The estimation stage end to end: windows -> periodogram peak -> harmonic fit -> estimates table."""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
import pandas as pd

from .._signals import check_interrupt
from ..columns import ESTIMATE_CORE
from ..series import Windows
from ..spectral import Periodogram, lomb_peaks
from ..status import STATUSES, Status
from .harmonic import N_PARAMS, HarmonicFit, fit_harmonics
from .models import SignalModel, fit_model, model_residual_noise, model_table
from .residual_noise import ResidualNoise, residual_noise

__all__ = ["ESTIMATE_COLUMNS", "STATUSES", "Estimates", "estimate_windows"]

ESTIMATE_COLUMNS = [
    "segment",
    "window",
    "t_start",
    "t_end",
    "plate",
    "axis",
    "n",
    *ESTIMATE_CORE,
    "phase_rad",
    "offset_mm",
    "sigma_residual_mm",
    "peak_fap",
    "status",
    "r2",
    "whiteness_p",
    "sigma_amplitude_white_mm",
    "sigma_f0_white_hz",
]
# the status vocabulary (`jaxdefl.status.Status`)
# A deflection beyond 1000 km is a logger's sentinel or a corrupt cell, not a measurement; its
# square would overflow the sums of the fit. Such a window gets a status, its neighbours go on.
MAX_ABS_VALUE_MM = 1e9
_BLOCK_CELLS = 1 << 18


@dataclass(frozen=True)
class Estimates:
    """Estimates of a batch of windows: the table of DESIGN.md plus the arrays behind it."""

    table: pd.DataFrame
    windows: Windows
    periodogram: Periodogram
    fit: HarmonicFit
    noise: ResidualNoise | None = None


def estimate_windows(
    w: Windows,
    fmin_hz: float | None = None,
    fmax_hz: float | None = None,
    oversampling: float = 5.0,
    fap_max: float = 0.01,
    min_cycles: float = 2.0,
    weights: np.ndarray | None = None,
    keep: tuple[int, ...] = (),
    block: int = 4096,
    on_block: Callable[[int], None] | None = None,
    workers: int | None = None,
    model: SignalModel | None = None,
    timings: dict[str, float] | None = None,
    refine: bool = False,
) -> Estimates:
    """Estimate f0, A and their σ's for every window; failures become statuses.

    Statuses: ``too_few_samples`` (fewer than the windowing's minimum), ``too_few_cycles`` (the
    peak frequency times the window span is below ``min_cycles``), ``no_significant_peak``
    (false-alarm probability above ``fap_max``), ``did_not_converge`` (Gauss-Newton failed or
    gave non-finite numbers), ``value_out_of_range`` (a value beyond MAX_ABS_VALUE_MM), else
    ``converged``.

    Args:
        block: most windows per periodogram/fit call; ``on_block(k)`` is called after each
            with the number of windows done (for progress bars).
        workers: threads running blocks at once (default: one per core).
        model: the signal model (default: the thesis' harmonic + offset); other models add
            columns (see `jaxdefl.fit.models.model_columns`).
        timings: if given, ``kernel`` and ``residual`` are increased by the seconds of this
            call spent in the periodogram + fit and in the residual statistics (the call's wall
            time split in the proportion of the blocks' thread times).
        refine: the harmonic fit's estimates converged further at no extra pass (see
            `jaxdefl.fit.harmonic.fit_harmonics`); `estimate_table` asks it for whole records.
    """
    t_call = time.perf_counter()
    if model is not None and model.is_default:
        model = None
    b = len(w)
    status = w.table["status"].to_numpy(dtype=object).copy()
    wild = (np.abs(np.where(w.mask, w.y, 0.0)) > MAX_ABS_VALUE_MM).any(axis=1)
    status[(status == Status.CONVERGED) & wild] = Status.VALUE_OUT_OF_RANGE
    todo = np.flatnonzero((status == Status.CONVERGED) & (w.mask.sum(axis=1) > N_PARAMS + 1))
    status[(status == Status.CONVERGED) & (w.mask.sum(axis=1) <= N_PARAMS + 1)] = Status.TOO_FEW_SAMPLES
    nan = np.full(b, np.nan)
    per = {k: nan.copy() for k in ("freq_hz", "power", "fap", "n_indep", "fmin_hz", "fmax_hz", "df_hz")}
    method = np.full(b, "", dtype=object)
    spectra: dict = {}
    fit_parts = []

    spans = _span(w)

    def run(rows: np.ndarray):
        # Whole-batch arrays indexed by ``rows``: no copy of the windows per block.
        t_block = time.perf_counter()
        rowset = set(rows.tolist())
        p = lomb_peaks(
            w,
            rows=rows,
            fmin_hz=fmin_hz,
            fmax_hz=fmax_hz,
            oversampling=oversampling,
            keep=tuple(k for k in keep if k in rowset),
            search_dtype="float32",
        )
        few_cycles = p.freq_hz[rows] * spans[rows] < min_cycles
        insignificant = ~(p.fap[rows] <= fap_max)
        go = ~few_cycles & ~insignificant
        st = np.where(
            few_cycles,
            Status.TOO_FEW_CYCLES,
            np.where(insignificant, Status.NO_SIGNIFICANT_PEAK, Status.CONVERGED),
        )
        if model is None:
            f = fit_harmonics(w, p.freq_hz, rows=rows[go], weights=weights, refine=refine, residual=resid)
        else:
            search = dict(fmin_hz=fmin_hz, fmax_hz=fmax_hz, oversampling=oversampling)
            f = fit_model(w, p, rows[go], model, weights=weights, **search)
        converged = f.converged[rows]
        t_fit = time.perf_counter()
        # Model adequacy and σ's honest under coloured noise (`residual_noise`), on this
        # thread: numpy releases the GIL, so the blocks' statistics run side by side.
        ok = rows[converged]
        if model is None:  # ``resid`` filled by the fit
            noise = residual_noise(w, resid, f.f0_hz, rows=ok)
        else:
            noise = model_residual_noise(w, f, model, rows, resid)
        took = (t_fit - t_block, time.perf_counter() - t_fit)
        return rows, p, np.where(go & ~converged, Status.DID_NOT_CONVERGE, st), f, noise, took

    # Blocks run on a thread per core: XLA and the FFTs release the GIL. A block holds at least
    # 256 windows, or fewer long ones (~2^18 samples: the 39 whole records of a campaign day
    # run as 2 blocks, not 1), so that every core has work.
    workers = max(1, os.cpu_count() or 1) if workers is None else max(1, workers)
    least = min(256, max(1, _BLOCK_CELLS // max(1, w.t.shape[1])))
    size = min(block, max(least, -(-todo.size // workers)))
    blocks = [todo[i : i + size] for i in range(0, todo.size, size)]
    resid = np.empty_like(w.y)  # rows filled by their block
    spent = {"kernel": 0.0, "residual": 0.0}  # thread seconds of the blocks
    noise_parts = []
    with ThreadPoolExecutor(max_workers=workers) as pool:
        for rows, p, st, f, noise, took in (fut.result() for fut in [pool.submit(run, r) for r in blocks]):
            spent["kernel"] += took[0]
            spent["residual"] += took[1]
            for k in per:
                per[k][rows] = getattr(p, k)[rows]
            method[rows] = p.method[rows]
            spectra.update(p.spectra)
            status[rows] = st
            fit_parts.append((rows, f))
            noise_parts.append((rows, noise))
            if on_block is not None:
                on_block(rows.size)
            check_interrupt()
    fit = _merge_fits(b, fit_parts)
    if timings is not None:
        wall, busy = time.perf_counter() - t_call, sum(spent.values()) or 1.0
        for k, v in spent.items():
            timings[k] = timings.get(k, 0.0) + wall * v / busy
    periodogram = Periodogram(
        per["freq_hz"],
        per["power"],
        per["fap"],
        per["n_indep"],
        per["fmin_hz"],
        per["fmax_hz"],
        per["df_hz"],
        method,
        spectra,
    )
    # The table is made in one go: a column added to a frame at a time re-builds its column
    # index each time (~1 ms with pandas' string index, holding the GIL the other unit waits for).
    cols = {c: w.table[c] for c in w.table.columns}
    cols["status"] = status
    cols["f0_hz"] = fit.f0_hz
    cols["sigma_f0_hz"] = fit.sigma_f0_hz
    cols["amplitude_mm"] = fit.amplitude_mm
    cols["sigma_amplitude_mm"] = fit.sigma_amplitude_mm
    # The fit is centred on the window's data; report the phase at the window's mid time.
    shift = fit.params[:, 3] * (w.table["t_centre"].to_numpy() - w.table["t_mid"].to_numpy())
    cols["phase_rad"] = np.angle(np.exp(1j * (fit.phase_rad + shift)))
    cols["offset_mm"] = fit.offset_mm
    cols["sigma_residual_mm"] = fit.sigma_residual_mm
    cols["peak_fap"] = periodogram.fap
    if model is not None:
        # adequacy and σ's from the whole model's residual (`jaxdefl.fit.models.model_table`)
        noise = _merge_fits(b, noise_parts, ResidualNoise) if noise_parts else None
        tab, added, noise = model_table(w, pd.DataFrame(cols, index=w.table.index), fit, model, noise)
        return Estimates(tab[ESTIMATE_COLUMNS + added], w, periodogram, fit, noise)
    # Model adequacy and σ's honest under coloured noise (`residual_noise`): the white-noise σ's
    # (thesis 5.43-5.45) are kept beside; the default ones use the residual's density near f0.
    noise = _merge_fits(b, noise_parts, ResidualNoise)
    cols["r2"] = noise.r2
    cols["whiteness_p"] = noise.whiteness_p
    cols["sigma_amplitude_white_mm"] = fit.sigma_amplitude_mm
    cols["sigma_f0_white_hz"] = fit.sigma_f0_hz
    cols["sigma_amplitude_mm"] = fit.sigma_amplitude_mm * np.sqrt(noise.kappa)
    cols["sigma_f0_hz"] = fit.sigma_f0_hz * np.sqrt(noise.kappa)
    tab = pd.DataFrame({c: cols[c] for c in ESTIMATE_COLUMNS}, index=w.table.index)
    return Estimates(tab, w, periodogram, fit, noise)


def _span(w: Windows) -> np.ndarray:
    n = w.mask.sum(axis=1)
    lo = np.where(w.mask, w.t, np.inf).min(axis=1)
    hi = np.where(w.mask, w.t, -np.inf).max(axis=1)
    span = np.where(n > 1, hi - lo, 0.0)  # an empty window's inf - inf never reaches arithmetic
    return span * n / np.maximum(n - 1, 1)


def _merge_fits(b: int, parts: list[tuple[np.ndarray, object]], default=HarmonicFit):
    """One dataclass of (window, ...) arrays from the blocks' (rows, part) pairs."""
    cls = type(parts[0][1]) if parts else default
    fields = cls.__dataclass_fields__
    out = {}
    for name in fields:
        if parts:
            proto = getattr(parts[0][1], name)
        else:
            proto = (
                np.zeros((0, 4, 4))
                if name == "cov"
                else np.zeros((0, 4))
                if name == "params"
                else np.zeros(0)
            )
        shape = (b,) + proto.shape[1:]
        arr = np.zeros(shape, proto.dtype) if proto.dtype.kind in "biu" else np.full(shape, np.nan)
        for rows, f in parts:
            arr[rows] = getattr(f, name)[rows]
        out[name] = arr
    return cls(**out)
