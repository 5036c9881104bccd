"""A configured structured-light camera's own physics: in the nominal model, or said as nominal.

A Kinect-class camera makes, by itself (`jaxdefl.simulate.structured_light`; thesis Table 4.2,
Table 6.21, Fig. 6.64):

- level jumps: the whole depth image steps at one instant (a re-calibration of the projector
  pattern), about ``jumps_per_minute`` a minute, each of RMS ``jump_mm``;
- a depth lattice: disparity comes in sub-pixel steps, so depth comes in steps
  Δz = ``depth_step_mm_at_2m`` · (z / 2 m)² that grow with the range.

When its config gives these values (`jaxdefl diagnose --config`, `jaxdefl reconcile`), they are
the sensor's nominal physics, as the four-phase lag is a configured ToF camera's
(`_context.nominal_tap_spread`), and the search is told them:

1. The configured level jumps join the nominal model (`nominal_level_jumps`): the steps of the
   plates' common depth residual (binary segmentation, `record_kind.binary_steps`), each at most
   JUMP_SIGMAS × ``jump_mm`` and no more of them than the Poisson count of the configured rate
   allows at POISSON_LEVEL, are fitted on every series with a size of its own (a depth step moves
   a plate's x and y by x/z and y/z of it). A jump beyond that size stays in the residual, where
   `level_jump` names it.
2. A named effect within the configured sizes is the sensor's nominal physics
   (`within_configured`): a quantization whose step is at most LATTICE_FACTOR × the configured
   depth step at the plates' range, a level jump at most JUMP_SIGMAS × ``jump_mm``. It stays in
   the model (the record has that physics) and is reported under ``nominal_physics``, with the
   configured size it was held against, never as missing. A coarser lattice or a larger jump is
   named.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
from scipy import stats

from .._numerics import wls
from ..effects import level_jump, quantization
from ._base import Context, State
from .record_kind import binary_steps

__all__ = ["nominal_level_jumps", "within_configured", "JUMP_SIGMAS", "LATTICE_FACTOR"]

# |N(0, σ)| beyond 4σ: 6e-5 per jump; a jump that large is not the configured camera's
JUMP_SIGMAS = 4.0
# a plate's centroid reads the pixels' lattice at most this much coarser (pixels at several
# depths, the dither's smoothing); a lattice coarser than that is not the configured camera's
LATTICE_FACTOR = 2.0
POISSON_LEVEL = 1e-3  # the count of jumps the configured rate exceeds with this probability
DEPTH_AT = 2000.0  # mm: the range at which ``depth_step_mm_at_2m`` is given


def _configured_jumps(ctx: Context) -> bool:
    return bool(ctx.jump_mm) and bool(ctx.jumps_per_minute)


def nominal_level_jumps(ctx: Context, states: list[State]) -> tuple[list[State], list[dict]]:
    """The configured camera's level jumps fitted into the nominal ``states``: (states, the
    jumps: ``t_s`` (table time), ``size_mm`` on the plates' common depth). Unchanged when the
    context has no configured jumps or no depth (z) series."""
    zi = ctx.indices("z")
    if not _configured_jumps(ctx) or not zi or ctx.n_frames < 20:
        return states, []
    resid = np.full((len(zi), ctx.n_frames), np.nan)
    for j, i in enumerate(zi):
        s = ctx.series[i]
        resid[j, s.k] = s.y - states[i].mean
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # frames no plate saw
        common = np.nanmedian(resid, axis=0)
    frames = np.flatnonzero(np.isfinite(common))
    if frames.size < 20:
        return states, []
    levels, cuts = binary_steps(common[frames])
    bound = JUMP_SIGMAS * float(ctx.jump_mm)
    steps = [(c, float(levels[c] - levels[c - 1])) for c in cuts]
    jumps = [(c, d) for c, d in steps if abs(d) <= bound]
    expected = float(ctx.jumps_per_minute) * ctx.duration_s / 60.0
    n_max = int(stats.poisson.isf(POISSON_LEVEL, max(expected, 1e-9))) + 1
    jumps = sorted(sorted(jumps, key=lambda j: -abs(j[1]))[:n_max])
    if not jumps:
        return states, []
    k_cut = [int(frames[c]) for c, _ in jumps]  # the first frame after each jump
    # the steps beyond the camera's are fitted alongside (so they bias no held jump's size) and
    # left in the residual, for `level_jump` to name
    k_other = [int(frames[c]) for c, _ in steps if int(frames[c]) not in k_cut]
    new = list(states)
    for i, s in enumerate(ctx.series):
        st = states[i]
        cols = np.stack([np.ones(s.n)] + [(s.k >= k).astype(float) for k in k_cut + k_other], axis=1)
        beta = wls(cols, s.y - st.mean)[0] if s.n > cols.shape[1] else np.zeros(cols.shape[1])
        held = cols[:, : 1 + len(k_cut)] @ beta[: 1 + len(k_cut)]
        new[i] = st.with_(mean=st.mean + held, n_params=st.n_params + len(k_cut))
    out = [
        {"t_s": float(ctx.t0 + (k - 0.5) * ctx.dt_s), "size_mm": d}
        for k, (_, d) in zip(k_cut, jumps, strict=True)
    ]
    return new, out


def _depth_mm(ctx: Context, plates) -> float:
    """The largest mean depth (z, camera frame) of ``plates``; DEPTH_AT when the table's z is not
    a depth (a world frame's deflection about 0)."""
    z = [float(np.mean(ctx.series[i].y)) for i in ctx.indices("z") if ctx.series[i].plate in set(plates)]
    z = [v for v in z if math.isfinite(v) and v > 100.0]
    return max(z) if z else DEPTH_AT


def within_configured(ctx: Context, effect: dict) -> str | None:
    """Why a named effect (a DIAG.json entry: ``id``, ``plates``, ``parameters``; for a jump
    optionally ``depth_step_mm``, its largest size on a depth series) is the configured
    structured-light camera's own physics, or None when it is not (or nothing is configured)."""
    eid = effect["id"]
    params = {
        k: (v.get("value") if isinstance(v, dict) else v) for k, v in effect.get("parameters", {}).items()
    }
    if eid == quantization.ENTRY.id and ctx.depth_step_mm_at_2m and params.get("step_mm") is not None:
        depth = _depth_mm(ctx, effect.get("plates", ctx.plates))
        q_cfg = float(ctx.depth_step_mm_at_2m) * (depth / DEPTH_AT) ** 2
        q = float(params["step_mm"])
        if q <= LATTICE_FACTOR * q_cfg:
            return (
                f"the configured structured-light camera's depth lattice: a {q:.3g}-mm step against "
                f"its {q_cfg:.3g} mm at the plates' {depth:.0f}-mm range ({ctx.depth_step_mm_at_2m:g} mm "
                f"at 2 m, growing as z²; at most {LATTICE_FACTOR:g}× that is the camera's own)"
            )
    if eid == level_jump.ENTRY.id and _configured_jumps(ctx) and params.get("size_mm") is not None:
        # the step on the depth series where known (the reported size is one over every axis;
        # a depth step moves x and y by x/z and y/z of it)
        size = effect.get("depth_step_mm")
        size = abs(float(params["size_mm"] if size is None else size))
        if size <= JUMP_SIGMAS * float(ctx.jump_mm):
            return (
                f"a level jump of the configured structured-light camera: {size:.3g} mm against its "
                f"{ctx.jumps_per_minute:g} jumps a minute of RMS {ctx.jump_mm:g} mm (at most "
                f"{JUMP_SIGMAS:g}× that is the camera's own)"
            )
    return None
