"""Trajectory tables to estimates: windowing and estimation of every segment, plate and axis."""

from __future__ import annotations

import time
from collections.abc import Callable

import pandas as pd

from .._errors import ConfigError
from ..series import Windows, make_windows
from .estimate import Estimates, estimate_windows
from .models import SignalModel

__all__ = ["estimate_table", "windows_for"]


def windows_for(
    df: pd.DataFrame,
    axes: tuple[str, ...] = ("z", "x", "y"),
    window_s: float | None = None,
    step_s: float | None = None,
    clocks: dict | None = None,
) -> Windows:
    """The windows `estimate_table` fits (see `jaxdefl.series.make_windows`)."""
    return make_windows(df, axes=axes, window_s=window_s, step_s=step_s, clocks=clocks)


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
    on_block: Callable[[int], None] | None = None,
    model: SignalModel | None = None,
    clocks: dict | None = None,
    timings: dict[str, float] | None = None,
) -> Estimates:
    """Windows of a validated trajectory table, estimated (see `estimate_windows`).

    ``clocks`` shares the series' frame clocks between calls on the same table (see
    `jaxdefl.series.make_windows`); ``timings`` gets the seconds of ``windowing`` added, and
    those of `estimate_windows`. Whole records (no ``window_s``) take the harmonic fit's refined
    endpoint (``refine`` of `estimate_windows`): within ~1e-6 σ of the least-squares optimum.

    Raises:
        ConfigError: a false-alarm limit outside (0, 1], bad window settings or axes.
    """
    if not 0 < fap_max <= 1:
        raise ConfigError(f"--fap-max: expected a probability in (0, 1], got {fap_max:g}")
    t0 = time.perf_counter()
    w = windows_for(df, axes=axes, window_s=window_s, step_s=step_s, clocks=clocks)
    if timings is not None:
        timings["windowing"] = timings.get("windowing", 0.0) + time.perf_counter() - t0
    return estimate_windows(
        w,
        fmin_hz=fmin_hz,
        fmax_hz=fmax_hz,
        oversampling=oversampling,
        fap_max=fap_max,
        keep=keep,
        on_block=on_block,
        model=model,
        timings=timings,
        refine=window_s is None,
    )
