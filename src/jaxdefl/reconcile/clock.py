"""The clock level: the recording's frame stamps against the configured camera's clock.

A camera whose frames are taken (or stamped) at irregular instants leaves its trajectories
consistent with themselves: the twin renders at the recording's own stamps, so no trajectory
metric sees a jitter of the capture instants, and the fit uses the stamps as they are. What does
differ is the clock the config promises. The stamps are reduced to their scatter about their
frame clock (the frame indices of `jaxdefl.series.clock.fit_clock`, which resolves drop-outs, and
the least-squares line through them):

=============  ===========================================================================
metric         statistic (distance: absolute difference, in ms)
=============  ===========================================================================
clock_jitter   RMS of the frame stamps about the recovered clock t0 + k·dt
=============  ===========================================================================

The simulation's side is the configured camera's clock (`jaxdefl.simulate.lds.frame_clock`:
its frame rate, drop-outs and ``timestamp_jitter_ms``) over the recording's duration, drawn
`N_CLOCKS` times: the nominal value is their median, the null distances their differences from
it, the bands their 95th and 1 − 0.05/`metrics.FAMILY` percentiles. A band is never narrower
than `FLOOR_FRAMES` of a frame interval: stamps rounded to a millisecond scatter by 0.29 ms RMS,
which is a stamp's resolution, not a clock's jitter (0.02 of a frame is 1 ms at 20 Hz, 0.33 ms at
60 Hz). The RMS of n stamps is known to 1/√(2n) of itself (2 % for 1000 stamps), so for a
recording of more than a few hundred frames whose configured jitter is below half a frame the
floor is the band, and `N_CLOCKS` = 100 draws place the nominal value well enough. No
``[[effect]]`` changes the clock, so *after* is *before*: a clock outside its band
stays apart, with the config key that sets it in the advice.
"""

from __future__ import annotations

import numpy as np

from ..series.clock import fit_clock
from .metrics import FAMILY_Q

__all__ = ["CLOCK_METRICS", "FLOOR_FRAMES", "N_CLOCKS", "clock_levels", "stamp_jitter_s"]

CLOCK_METRICS = ("clock_jitter",)
N_CLOCKS = 100
FLOOR_FRAMES = 0.02


def stamp_jitter_s(t: np.ndarray, hint: float | None = None) -> float:
    """RMS (s) of the distinct stamps ``t`` about their frame clock: the frame indices of
    `fit_clock` (drop-outs resolved), the line through them by least squares. NaN with fewer than
    8 stamps or no clock."""
    t = np.unique(np.asarray(t, np.float64))
    t = t[np.isfinite(t)]
    if t.size < 8:
        return float("nan")
    tr = t - t[0]
    c = fit_clock(tr, hint)
    if not np.isfinite(c.dt):
        return float("nan")
    # the frame indices from the robust clock, the line through them by least squares
    k = c.k.astype(np.float64)
    a = np.column_stack([np.ones_like(k), k - k.mean()])
    res = tr - a @ np.linalg.lstsq(a, tr, rcond=None)[0]
    return float(np.sqrt(np.mean(res**2)))


def clock_levels(t: np.ndarray, cfg, seed: int = 0, n: int = N_CLOCKS) -> list[dict]:
    """The clock level's rows of ``reconcile.json`` for a recording's stamps ``t`` (s; one row per
    plate and frame is fine) against the config ``cfg``'s camera: {level, metric, before, after,
    null_95, null_family, null_method, recording_ms, simulation_ms}. Empty for a config without a
    frame rate."""
    from ..simulate.lds import frame_clock

    rate = float(getattr(cfg.camera, "frame_rate_hz", 0.0) or 0.0)
    if rate <= 0:
        return []
    hint = 1.0 / rate
    t = np.asarray(t, np.float64)
    rec = stamp_jitter_s(t, hint)
    duration = float(np.nanmax(t) - np.nanmin(t)) + hint
    sims = np.array([stamp_jitter_s(frame_clock(cfg, duration, seed + 7000 + j)[1], hint) for j in range(n)])
    sims = sims[np.isfinite(sims)]
    nominal = float(np.median(sims)) if sims.size else float("nan")
    null = np.abs(sims - nominal)
    floor = FLOOR_FRAMES * hint
    band = max(float(np.quantile(null, 0.95)), floor) if null.size else float("nan")
    family = max(float(np.quantile(null, FAMILY_Q)), floor) if null.size else float("nan")
    before = abs(rec - nominal)
    ms = 1e3
    return [
        dict(
            level="clock",
            metric="clock_jitter",
            before=before * ms,
            after=before * ms,
            null_95=band * ms,
            null_family=family * ms,
            null_method="simulated_clocks",
            recording_ms=rec * ms,
            simulation_ms=nominal * ms,
            configured_ms=float(getattr(cfg.camera, "timestamp_jitter_ms", 0.0)),
        )
    ]
