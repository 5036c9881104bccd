"""Signal models beyond the thesis' single harmonic, batched like it: harmonics of f0, several
independent lines (modes), damped sinusoids (free-vibration records).

Model of one window, ``t`` centred on the window's samples as for the default fit:

    y(t) = E + Σ_j exp(-λ_l(j) t) [C_j cos(k_j ω_l(j) t) + D_j sin(k_j ω_l(j) t)]

- ``harmonics=K``: components j = 1..K share one frequency ω, k_j = j, no decay.
- ``lines=N``: N components, each with its own frequency ω_j (k_j = 1), no decay.
- ``kind="damped"`` (with ``lines=N``, default 1): each line also decays at its own rate
  λ_j = ζ_j ω_n,j, with ω_n,j² = ω_j² + λ_j² (ω_j is the damped frequency seen in the record).

Parameters p = [C_1, D_1, ..., C_m, D_m, E, ω_1..ω_L, (λ_1..λ_L)]. Per window, by variable
projection: the linear C, D, E are solved exactly (weighted least squares) wherever the
nonlinear θ = [ω's, λ's] are, and only θ is iterated: from the start (periodogram frequencies;
for a damped model, decay rates from the envelope of a few segments) one Gauss-Newton step,
then the scaled optimistix Gauss-Newton every fit uses (`jaxdefl.fit.harmonic.gauss_newton`)
on θ with Kaufman's Jacobian; the covariance σ0² (JᵀWJ)⁻¹ of all parameters (thesis
5.42-5.43) from the sums of its last evaluation, and derived quantities (amplitudes, phases,
damping ratios) by the delta method (5.44-5.45). Lines after the first are found one at a time: the highest
periodogram peak of the residual of the lines found so far (fitted jointly), then all N lines
are fitted jointly; they keep the order they were found in (line 1 is the periodogram's highest
peak, the line the thesis model fits).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd

from .._jax import float64, persistent_jit
from .._sincos import sincos
from ..series import Windows
from ..settings import MAX_HARMONICS, MAX_LINES, MODEL_KINDS, SignalModel, signal_model
from ..spectral import Periodogram, lomb_peaks
from ..status import Status
from .harmonic import ATOL, MAX_STEPS, RTOL, HarmonicFit, batch_windows, gauss_newton, normal_equations
from .residual_noise import ResidualNoise, residual_noise

__all__ = [
    "MAX_HARMONICS",
    "MAX_LINES",
    "MODEL_KINDS",
    "ModelFit",
    "SignalModel",
    "fit_model",
    "fit_model_window",
    "model_columns",
    "model_residual_noise",
    "model_table",
    "model_values",
    "signal_model",
]

# Segments of a window whose amplitudes give a damped model's start decay rate (a weighted
# straight line through their log amplitudes).
_ENVELOPE_SEGMENTS = 8
# Samples solved together by one vmapped Gauss-Newton loop (a few windows). Unlike the default
# model, whose windows all take 2 evaluations, these take 2 to 6, and a vmapped loop runs as
# many steps as its slowest window: small groups waste fewer steps (K = 3 on workload W: 1.5-1.8x
# less time than the default's 64-window groups, `experiments/bench_models.py`; with windows in
# periodogram-power order, 8k samples stay faster than 16k or 32k for K = 3 and damped). Since
# the solver works on the compressed residual (`fit_model_window`), a step's fixed cost weighs
# more than the steps a larger group wastes: 16k samples (8 windows of W) take 0.31-0.36 ms a
# window against 0.38-0.41 for 8k (K = 3), 0.35-0.36 against 0.37-0.38 (damped, its weakest
# windows; CPU time, load 3-4).
GROUP_CELLS = 1 << 14


# --------------------------------------------------------------------------------------------
# the kernel (one window)


def _design(spec: SignalModel, theta, t):
    """Columns of the linear parameters C, D, E (`SignalModel` order) at the nonlinear ones
    ``theta`` = [ω_1..ω_L, (λ_1..λ_L)]."""
    m = spec.n_components
    cols = [None] * (2 * m + 1)
    cols[2 * m] = jnp.ones_like(t)
    env = [jnp.exp(-theta[spec.lines + line] * t) for line in range(spec.lines)] if spec.damped else None
    s1 = c1 = None
    for j in range(m):
        line, k = spec.line_of(j), spec.multiplier(j)
        if k == 1:
            sk, ck = s1, c1 = sincos(theta[line] * t)
        else:
            # harmonic k from harmonic k - 1 and the fundamental by the angle-addition formulas
            # (a few multiply-adds instead of a sincos; error ~k ulp)
            sk, ck = sk * c1 + ck * s1, ck * c1 - sk * s1
        c, s = (ck * env[line], sk * env[line]) if spec.damped else (ck, sk)
        cols[2 * j], cols[2 * j + 1] = c, s
    return cols


def _theta_columns(spec: SignalModel, lin, g, t):
    """Jacobian columns of the nonlinear parameters (ω's, then λ's) at the linear parameters
    ``lin``, from the design columns ``g`` (`_design`)."""
    om_cols = [0.0] * spec.lines
    decay_cols = [0.0] * spec.lines
    for j in range(spec.n_components):
        line, k = spec.line_of(j), spec.multiplier(j)
        c, s = g[2 * j], g[2 * j + 1]
        om_cols[line] = om_cols[line] + k * (lin[2 * j + 1] * c - lin[2 * j] * s)  # d osc / d(ωt)
        if spec.damped:
            decay_cols[line] = decay_cols[line] - (lin[2 * j] * c + lin[2 * j + 1] * s)
    return [t * c for c in om_cols] + ([t * c for c in decay_cols] if spec.damped else [])


def _value(spec: SignalModel, p, t):
    """The model at parameters ``p`` (`SignalModel` order)."""
    n_lin = 2 * spec.n_components + 1
    g = _design(spec, p[n_lin:], t)
    return sum(p[i] * g[i] for i in range(n_lin))


def _project(spec: SignalModel, theta, t, yc, w):
    """Variable projection at ``theta``: the linear parameters by weighted least squares, the
    residual r, and the normal equations of Kaufman's Jacobian of r over ``theta`` (the
    nonlinear columns V with their part in the span of the linear ones G removed): JᵀWJ and
    JᵀWr = -VᵀWr (GᵀWr = 0 at the linear solution); also the sums the normal matrix of all
    parameters is made of (GᵀWG, GᵀWV, VᵀWV). Returns (r, JᵀWJ, VᵀWr, sums)."""
    g = _design(spec, theta, t)
    import jax.scipy.linalg as jsl  # imported when the kernel is traced

    gtg, gty = normal_equations(g, w, yc)
    chol = jsl.cho_factor(gtg)  # one factorisation for both solves
    lin = jsl.cho_solve(chol, gty)
    r = jnp.where(w > 0, yc - sum(lin[i] * g[i] for i in range(len(g))), 0.0)
    v = _theta_columns(spec, lin, g, t)
    wv = [w * c for c in v]
    gtv = jnp.stack([jnp.stack([jnp.sum(a * b) for a in wv]) for b in g])  # (lin, theta)
    vtv = jnp.stack([jnp.stack([jnp.sum(a * b) for b in v]) for a in wv])
    vtr = jnp.stack([jnp.sum(a * r) for a in wv])
    coef = jsl.cho_solve(chol, gtv)
    sums = dict(lin=lin, gtg=gtg, gtv=gtv, vtv=vtv, rss=jnp.sum(w * r**2), rr=jnp.sum(r**2))
    return r, vtv - gtv.T @ coef, vtr, sums


def _segment_sums(t, yc, w, omega, g_n):
    """Per-segment sums for the amplitude of the line at ``omega`` in ``g_n`` consecutive
    segments of the window: (sample count, Σt, Σc², Σcs, Σs², Σcy, Σsy, Σy²), each (segment,).

    The samples (in time order, as `Windows` holds them) are first summed in blocks of a few
    (at least four blocks a segment), and each block goes to the segment of its mean time: a
    segment's edges move by up to half a block (a start value depends on them, not the fit),
    and the (segment x block) product costs a few times less than a (segment x sample) one or
    a scatter-add over the samples (those were a quarter of a damped fit's time).
    """
    valid = w > 0
    lo = jnp.min(jnp.where(valid, t, jnp.inf))
    hi = jnp.max(jnp.where(valid, t, -jnp.inf))
    s, c = sincos(omega * t)
    wy = w * yc
    size, block = t.shape[0], 1
    while size % (2 * block) == 0 and size // (2 * block) >= 4 * g_n:
        block *= 2
    sums = [
        x.reshape(size // block, block).sum(axis=1)
        for x in (w, w * t, w * c * c, w * c * s, w * s * s, c * wy, s * wy, yc * wy)
    ]
    t_block = sums[1] / jnp.maximum(sums[0], 1e-300)
    seg = jnp.clip(jnp.floor((t_block - lo) / jnp.maximum(hi - lo, 1e-300) * g_n), 0, g_n - 1)
    onehot = (seg[None, :] == jnp.arange(g_n)[:, None]).astype(t.dtype)  # (segment, block)
    return (onehot @ jnp.stack(sums, axis=1)).T


def _envelope_slope(sums):
    """Decay rate from `_segment_sums`: a straight line through the segments' log amplitudes,
    weighted by (A / σ_A)² (the inverse variance of a log amplitude). Returns (rate, segments
    used)."""
    n_seg, t_sum, a11, a12, a22, b1, b2, yy = sums
    t_seg = t_sum / jnp.maximum(n_seg, 1e-300)
    det = a11 * a22 - a12**2
    good = (n_seg >= 4) & (det > 1e-3 * (a11 + a22) ** 2 / 4)
    det = jnp.where(good, det, 1.0)
    cc = (a22 * b1 - a12 * b2) / det
    dd = (a11 * b2 - a12 * b1) / det
    amp2 = cc**2 + dd**2
    # (A / σ_A)² = A² n / (2 σ²), σ² from the segment's residual; segments within 3 σ_A of the
    # noise (whose amplitude is the noise's, and whose far times would pull the line) are left out
    noise2 = jnp.maximum(yy - (cc * b1 + dd * b2), 0.0) / jnp.maximum(n_seg - 2, 1)
    snr2 = amp2 * n_seg / (2 * jnp.maximum(noise2, 1e-300))
    good = good & (amp2 > 0) & (snr2 > 9)
    wt = jnp.where(good, snr2, 0.0)
    la = 0.5 * jnp.log(jnp.where(good, amp2, 1.0))
    sw = jnp.sum(wt)
    tm = jnp.sum(wt * t_seg) / jnp.maximum(sw, 1e-300)
    lm = jnp.sum(wt * la) / jnp.maximum(sw, 1e-300)
    stt = jnp.sum(wt * (t_seg - tm) ** 2)
    slope = jnp.sum(wt * (t_seg - tm) * (la - lm)) / jnp.where(stt > 0, stt, 1.0)
    used = jnp.sum(good)
    return jnp.where((used >= 2) & (stt > 0), -slope, 0.0), used


def _decay_start(spec: SignalModel, t, yc, w, omegas):
    """Start decay rate of each line from its envelope (`_envelope_slope`) over
    `_ENVELOPE_SEGMENTS` segments, or over four times as many when fewer than three of those
    rise above the noise (a record that decays within a small part of the window)."""
    out = []
    for line in range(spec.lines):
        fine = _segment_sums(t, yc, w, omegas[line], 4 * _ENVELOPE_SEGMENTS)
        # floor(32 x) // 4 == floor(8 x): the coarse segments are the fine ones four by four
        coarse = fine.reshape(fine.shape[0], _ENVELOPE_SEGMENTS, 4).sum(axis=-1)
        lam_coarse, n_coarse = _envelope_slope(coarse)
        lam_fine, n_fine = _envelope_slope(fine)
        out.append(jnp.where((n_coarse < 3) & (n_fine >= 2), lam_fine, lam_coarse))
    return jnp.stack(out)


def fit_model_window(spec: SignalModel, t, y, w, omega0, rtol=RTOL, atol=ATOL, max_steps=MAX_STEPS):
    """Fit ``spec`` to one window. Arrays are (sample,); ``w`` weights (0 = masked); ``omega0``
    (line,) start angular frequencies.

    Returns a dict: ``p`` (param,) with the offset E including the mean of y and time measured
    from ``origin`` (in the time of ``t``; 0 unless damped), ``cov`` (param,
    param), variance factor ``s0sq``, residual σ ``sigma_res``, ``n``, ``steps`` and ``ok``
    (solver converged, numbers finite).
    """
    m, n_par = spec.n_components, spec.n_params
    valid = w > 0
    n = jnp.sum(valid)
    ybar = jnp.sum(w * y) / jnp.sum(w)
    yc = jnp.where(valid, y - ybar, 0.0)
    theta0 = omega0
    origin = jnp.zeros(())
    if spec.damped:
        lam0 = _decay_start(spec, t, yc, w, omega0)
        theta0 = jnp.concatenate([omega0, lam0])
        # Time origin at the centroid of the first line's energy e^{-2λt}: there the model is
        # nearly linear in the decay over the samples that matter, where at the window's centre
        # a decay of a few e-folds makes C and D tiny and Gauss-Newton's linearisation poor.
        x = jnp.where(valid, -2 * lam0[0] * t, -jnp.inf)
        e = w * jnp.exp(x - jnp.max(x))
        origin = jnp.sum(e * t) / jnp.sum(e)
        t = jnp.where(valid, t - origin, 0.0)

    # Variable projection: the C, D, E are solved exactly (linear least squares) wherever the
    # frequencies (and decays) θ are, and Gauss-Newton iterates on θ alone, with Kaufman's
    # Jacobian (its gradient is exact, so the optimum is that of all the parameters). One step
    # from the start (periodogram frequencies; decays from the envelope) is taken here; a step
    # of more than a quarter cycle, or of more than one e-fold of decay, over the window is not
    # (a start far from any optimum).
    r0, s_theta, vtr0, _ = _project(spec, theta0, t, yc, w)
    step = jnp.linalg.solve(s_theta, vtr0)
    span = jnp.max(jnp.where(valid, jnp.abs(t), 0.0))
    k_max = spec.multiplier(m - 1)
    near = jnp.all(jnp.isfinite(step)) & jnp.all(jnp.abs(step[: spec.lines]) * k_max * span < 0.5 * jnp.pi)
    if spec.damped:
        near = near & jnp.all(jnp.abs(step[spec.lines :]) * span < 1.0)
    theta1 = theta0 + jnp.where(near, step, 0.0)

    # Scaled to units of σ as in `fit_harmonic`: the noise from the linearised residual after the
    # step, the σ of each of θ from the projected normal matrix (the θ block of the inverse of
    # the whole normal matrix).
    rss_lin = jnp.sum(w * r0**2)
    rss = jnp.where(near, rss_lin - step @ vtr0, rss_lin)
    rss = jnp.maximum(rss, 1e-20 * rss_lin)
    noise = jnp.sqrt(jnp.maximum(rss / jnp.maximum(n - n_par, 1), 1e-300))
    scale = noise * jnp.sqrt(jnp.abs(jnp.diag(jnp.linalg.inv(s_theta))))

    def residual(u, _):
        # The weighted residual f = √w r / noise (n samples) with Kaufman's Jacobian J, handed
        # to optimistix compressed to p + 1 numbers with the same Gauss-Newton steps and loss:
        # with JᵀJ = L Lᵀ (Cholesky), f̃ = [L⁻¹ Jᵀf, (|f|² - |L⁻¹ Jᵀf|²)^½] and J̃ = [Lᵀ; 0]
        # give J̃ᵀJ̃ = JᵀJ, J̃ᵀf̃ = Jᵀf and |f̃| = |f|. The solver's work per step is then that of
        # a (p + 1) x p problem, not n x p (damped fit 0.43 -> 0.37 ms a window, bench_models).
        # Value f̃, derivative J̃: f̃ + J̃ (u - u) with f̃ and J̃ held constant.
        u_c = jax.lax.stop_gradient(u)
        _, s_theta, vtr, sums = _project(spec, theta1 + u_c * scale, t, yc, w)
        chol = jnp.linalg.cholesky(s_theta * jnp.outer(scale, scale) / noise**2)
        g = jsl.solve_triangular(chol, -scale * vtr / noise**2, lower=True)
        rest = jnp.sqrt(jnp.maximum(sums["rss"] / noise**2 - g @ g, 0.0))
        f = jnp.concatenate([g, rest[None]]) + jnp.concatenate([chol.T @ (u - u_c), jnp.zeros(1)])
        return f, sums

    import jax.scipy.linalg as jsl  # imported when the kernel is traced
    import optimistix as optx

    sol = gauss_newton(residual, theta1.size, rtol, atol, max_steps, has_aux=True)
    theta = theta1 + sol.value * scale
    # the sums at the solution (the last evaluation is at it): the normal matrix of all
    # parameters [[GᵀWG, GᵀWV], [VᵀWG, VᵀWV]], the covariance σ0² (JᵀWJ)⁻¹
    sums = sol.state.aux
    p = jnp.concatenate([sums["lin"], theta])
    jtj = jnp.block([[sums["gtg"], sums["gtv"]], [sums["gtv"].T, sums["vtv"]]])
    dof = n - n_par
    s0sq = sums["rss"] / dof
    cov = s0sq * jnp.linalg.inv(jtj)
    diag = jnp.diag(cov)
    ok = (
        (sol.result == optx.RESULTS.successful)
        & jnp.all(jnp.isfinite(p))
        & jnp.all(jnp.isfinite(diag))
        & jnp.all(diag >= 0)
    )
    return dict(
        p=p.at[spec.offset_index].add(ybar),
        origin=origin,
        cov=cov,
        s0sq=s0sq,
        sigma_res=jnp.sqrt(sums["rr"] / dof),
        n=n,
        steps=sol.stats["num_steps"],
        ok=ok,
    )


@persistent_jit(static_argnames=("spec", "rtol", "atol", "max_steps", "group"))
def _fit_batch(t, y, w, omega0, *, spec, rtol, atol, max_steps, group):
    """`fit_model_window` over the leading axis, vmapped in groups of ``group`` windows."""

    def one(args):
        return fit_model_window(spec, *args, rtol, atol, max_steps)

    return jax.lax.map(one, (t, y, w, omega0), batch_size=group)


@partial(jax.jit, static_argnames=("spec",))
def _values(p, t, *, spec):
    return jax.vmap(lambda pp, tt: _value(spec, pp, tt))(p, t)


@float64()
def model_values(
    spec: SignalModel, params: np.ndarray, t: np.ndarray, origin_s: np.ndarray | None = None
) -> np.ndarray:
    """The model ``spec`` with ``params`` (window, param) at times ``t`` (window, sample),
    ``t`` relative to each window's ``t_centre`` as in `Windows.t`, the parameters' time origin
    at ``origin_s`` (window,) from it (`ModelFit.origin_s`; default 0)."""
    if origin_s is not None:
        t = t - np.asarray(origin_s)[:, None]
    return np.asarray(_values(jnp.asarray(params), jnp.asarray(t), spec=spec))


# --------------------------------------------------------------------------------------------
# batches of windows


@dataclass(frozen=True)
class ModelFit(HarmonicFit):
    """Fit of a `SignalModel` to every window (NaN where a window was not fitted).

    The `HarmonicFit` fields describe the first component (the fundamental, or the first line
    found) at the time origin of the windows, so that code written for the default
    model reads the first component; ``params``/``cov`` are its [C, D, E, ω] block.

    Extra attributes:
        model_params: (window, param) every parameter, `SignalModel` order (E with the mean),
            with time measured from ``origin_s``.
        model_cov: (window, param, param) their covariance.
        origin_s: (window,) time origin of the parameters from the window's ``t_centre`` (0
            unless damped: there the first component's amplitude and phase are at it too).
        line_fap: (window, line) false-alarm probability of the periodogram peak each line
            was found at.
    """

    model_params: np.ndarray
    model_cov: np.ndarray
    line_fap: np.ndarray
    origin_s: np.ndarray


def _solve(spec, w, rows, weights, omega0, power, rtol, atol, max_steps):
    """`fit_model_window` on the windows at ``rows``. A vmapped Gauss-Newton loop runs as many
    steps as its slowest window, and the steps a window takes depend on its SNR: windows go to
    the solver in the order of their periodogram peak's ``power``, so that those solved
    together take about as many steps."""
    order = np.argsort(power[rows], kind="stable")
    fit_batch = partial(_fit_batch, spec=spec, rtol=rtol, atol=atol, max_steps=max_steps)
    out = batch_windows(fit_batch, w, rows[order], weights, omega0, group_cells=GROUP_CELLS)
    back = np.empty_like(order)
    back[order] = np.arange(order.size)
    return {k: v[back] for k, v in out.items()}


def fit_model(
    w: Windows,
    periodogram: Periodogram,
    rows: np.ndarray,
    spec: SignalModel,
    weights: np.ndarray | None = None,
    fmin_hz: float | None = None,
    fmax_hz: float | None = None,
    oversampling: float = 5.0,
    rtol: float = RTOL,
    atol: float = ATOL,
    max_steps: int = MAX_STEPS,
) -> ModelFit:
    """Fit ``spec`` to the windows at ``rows``, starting at the periodogram's peak.

    Lines after the first start at the highest periodogram peak (same band and oversampling)
    of the residual of the lines found so far, fitted jointly; a window whose partial fit fails
    is not fitted. Lines keep the order they were found in.

    Returns:
        ModelFit with one entry per window of ``w``.
    """
    b, n_lines, n_par = len(w), spec.lines, spec.n_params
    rows = np.asarray(rows, dtype=np.int64)
    rows = rows[w.mask[rows].sum(axis=1) > n_par + 1]
    omega0 = np.full((b, n_lines), np.nan)
    fap = np.full((b, n_lines), np.nan)
    omega0[:, 0] = 2 * np.pi * periodogram.freq_hz
    fap[:, 0] = periodogram.fap
    power = np.nan_to_num(np.asarray(periodogram.power, dtype=float))
    for line in range(1, n_lines):
        if not rows.size:
            break
        part = dataclasses.replace(spec, lines=line)
        out = _solve(part, w, rows, weights, omega0[:, :line], power, rtol, atol, max_steps)
        rows = rows[out["ok"]]
        if not rows.size:
            break
        sub = w.select(rows)
        resid = sub.y - model_values(part, out["p"][out["ok"]], sub.t, out["origin"][out["ok"]])
        sub = dataclasses.replace(sub, y=np.where(sub.mask, resid, 0.0))
        pk = lomb_peaks(
            sub, fmin_hz=fmin_hz, fmax_hz=fmax_hz, oversampling=oversampling, search_dtype="float32"
        )
        omega0[rows, line] = 2 * np.pi * pk.freq_hz
        fap[rows, line] = pk.fap
        rows = rows[np.isfinite(pk.freq_hz)]

    p = np.full((b, n_par), np.nan)
    cov = np.full((b, n_par, n_par), np.nan)
    scal = {k: np.full(b, np.nan) for k in ("s0sq", "sigma_res", "origin")}
    n = np.zeros(b, np.int64)
    steps = np.zeros(b, np.int64)
    ok = np.zeros(b, bool)
    if rows.size:
        out = _solve(spec, w, rows, weights, omega0, power, rtol, atol, max_steps)
        p[rows], cov[rows] = out["p"], out["cov"]
        for k in scal:
            scal[k][rows] = out[k]
        n[rows], steps[rows], ok[rows] = out["n"], out["steps"], out["ok"]
    p[~ok], cov[~ok], fap[~ok] = np.nan, np.nan, np.nan
    for k in scal:
        scal[k][~ok] = np.nan

    i = [0, 1, spec.offset_index, spec.omega_index(0)]
    c, d = p[:, 0], p[:, 1]
    amp = np.hypot(c, d)
    with np.errstate(invalid="ignore", divide="ignore"):
        alpha = np.stack([c, d], axis=-1) / amp[:, None]
    var_a = np.einsum("bi,bij,bj->b", alpha, cov[:, :2, :2], alpha)
    two_pi = 2 * np.pi
    return ModelFit(
        f0_hz=p[:, spec.omega_index(0)] / two_pi,
        sigma_f0_hz=np.sqrt(cov[:, i[3], i[3]]) / two_pi,
        amplitude_mm=amp,
        sigma_amplitude_mm=np.sqrt(var_a),
        phase_rad=np.arctan2(d, c),
        offset_mm=p[:, spec.offset_index],
        sigma_residual_mm=scal["sigma_res"],
        variance_factor=scal["s0sq"],
        params=p[:, i],
        cov=cov[:, i][:, :, i],
        n=n,
        steps=steps,
        converged=ok,
        model_params=p,
        model_cov=cov,
        line_fap=fap,
        origin_s=scal["origin"],
    )


# --------------------------------------------------------------------------------------------
# the estimates table


def _amp_phase(p, cov, ci, di, oi, k, dt_ref, lam_i=None, t_ref_rel=None):
    """Amplitude and phase of one component at a reference time, with σ's by the delta method.

    ``dt_ref`` = t_origin - t_ref (phase: + k ω dt_ref, t_origin the parameters' time origin);
    for a decaying component the amplitude is taken at ``t_ref_rel`` = t_ref - t_origin:
    A exp(-λ t_ref_rel).
    """
    c, d, om = p[:, ci], p[:, di], p[:, oi]
    amp = np.hypot(c, d)
    with np.errstate(invalid="ignore", divide="ignore"):
        # gradients over (C, D, ω[, λ])
        g_amp = [c / amp, d / amp, np.zeros_like(c)]
        g_ph = [-d / amp**2, c / amp**2, k * dt_ref]
    idx = [ci, di, oi]
    if lam_i is not None:
        env = np.exp(-p[:, lam_i] * t_ref_rel)
        g_amp = [g * env for g in g_amp] + [-t_ref_rel * amp * env]
        g_ph = g_ph + [np.zeros_like(c)]
        idx.append(lam_i)
        amp = amp * env
    sub = cov[:, idx][:, :, idx]
    ga, gp = np.stack(g_amp, axis=-1), np.stack(g_ph, axis=-1)
    sa = np.sqrt(np.einsum("bi,bij,bj->b", ga, sub, ga))
    sp = np.sqrt(np.einsum("bi,bij,bj->b", gp, sub, gp))
    phase = np.angle(np.exp(1j * (np.arctan2(d, c) + k * om * dt_ref)))
    return amp, sa, phase, sp


def _damping(p, cov, oi, li):
    """Damping ratio ζ = λ / ω_n and natural frequency ω_n / 2π, with σ's (delta method)."""
    om, lam = p[:, oi], p[:, li]
    wn = np.hypot(om, lam)
    sub = cov[:, [oi, li]][:, :, [oi, li]]
    g_z = np.stack([-lam * om / wn**3, om**2 / wn**3], axis=-1)
    g_n = np.stack([om / wn, lam / wn], axis=-1) / (2 * np.pi)
    return (
        lam / wn,
        np.sqrt(np.einsum("bi,bij,bj->b", g_z, sub, g_z)),
        wn / (2 * np.pi),
        np.sqrt(np.einsum("bi,bij,bj->b", g_n, sub, g_n)),
    )


def model_columns(
    tab: pd.DataFrame, fit: HarmonicFit, spec: SignalModel, kappa: np.ndarray | None = None
) -> tuple[pd.DataFrame, list[str]]:
    """The estimates table of a `SignalModel`: the default columns describe the first
    component, and each further component gets its own (see docs/guide/fit-models.md).

    ``tab`` has ``t_start``, ``t_mid``, ``t_centre``, ``n`` and ``status`` (a windows table).
    Phases are at ``t_mid``; for a damped model the amplitude and phase are the initial ones, at
    ``t_start``. ``kappa`` (window, component) inflates each component's variances (the
    residual's spectral density at its frequency over its mean, `jaxdefl.fit.residual_noise`);
    None gives the white-noise σ's. Returns the table and the names of the added columns.
    """
    tab = tab.copy()
    b, n_par = len(tab), spec.n_params
    if isinstance(fit, ModelFit):
        p, cov, fap, origin = fit.model_params, fit.model_cov, fit.line_fap, fit.origin_s
    else:  # no window was fitted
        p, cov = np.full((b, n_par), np.nan), np.full((b, n_par, n_par), np.nan)
        fap, origin = np.full((b, spec.lines), np.nan), np.zeros(b)
    t_org = tab["t_centre"].to_numpy() + np.nan_to_num(origin)  # the parameters' time origin
    t_ref = (tab["t_start"] if spec.damped else tab["t_mid"]).to_numpy()
    added: list[str] = []
    two_pi = 2 * np.pi
    for j in range(spec.n_components):
        line, k = spec.line_of(j), spec.multiplier(j)
        oi = spec.omega_index(line)
        li = spec.decay_index(line) if spec.damped else None
        infl = 1.0 if kappa is None else np.sqrt(kappa[:, j])
        amp, sa, ph, sp = _amp_phase(p, cov, 2 * j, 2 * j + 1, oi, k, t_org - t_ref, li, t_ref - t_org)
        tag = "" if j == 0 else f"_{j + 1}"
        new = {}
        if j == 0 or spec.lines > 1:
            if j > 0:
                new[f"f0{tag}_hz"] = p[:, oi] / two_pi
            new[f"sigma_f0{tag}_hz"] = np.sqrt(cov[:, oi, oi]) / two_pi * infl
        new[f"amplitude{tag}_mm"] = amp
        new[f"sigma_amplitude{tag}_mm"] = sa * infl
        new[f"phase{tag}_rad"] = ph
        new[f"sigma_phase{tag}_rad"] = sp * infl
        if spec.lines > 1:
            new[f"peak_fap{tag}"] = fap[:, j]
            if j == 0 and "peak_fap" in tab:  # a window not fitted keeps its periodogram's FAP
                new["peak_fap"] = np.where(np.isfinite(fap[:, 0]), fap[:, 0], tab["peak_fap"].to_numpy())
        if spec.damped:
            z, sz, fn, sfn = _damping(p, cov, oi, li)
            new[f"damping_ratio{tag}"] = z
            new[f"sigma_damping_ratio{tag}"] = sz * infl
            new[f"natural_frequency{tag}_hz"] = fn
            new[f"sigma_natural_frequency{tag}_hz"] = sfn * infl
        for name, v in new.items():
            tab[name] = v
            if name not in _DEFAULT_NAMES and name not in added:
                added.append(name)
    few = (tab["status"].to_numpy() == Status.DID_NOT_CONVERGE) & (tab["n"].to_numpy() <= n_par + 1)
    tab.loc[few, "status"] = Status.TOO_FEW_SAMPLES
    return tab, added


def model_residual_noise(
    w: Windows, fit: HarmonicFit, spec: SignalModel, rows: np.ndarray, resid: np.ndarray
) -> ResidualNoise:
    """`residual_noise` of the whole model's residual, for the windows at ``rows`` that were
    fitted (run by each block of `jaxdefl.fit.estimate_windows` on its own thread): ``r2``,
    ``whiteness_p`` and ``kappa`` (window, component), the residual's spectral density at each
    component's frequency. ``resid`` (window, sample) receives the residual of ``rows``."""
    m = spec.n_components
    if not isinstance(fit, ModelFit):  # no window was fitted
        fit_rows = np.zeros(0, np.int64)
        f_hz = np.full((len(w), m), np.nan)
    else:
        fit_rows = rows[fit.converged[rows]]
        # the model at all of ``rows`` (NaN where not fitted): one compiled shape per block size
        resid[rows] = w.y[rows] - model_values(spec, fit.model_params[rows], w.t[rows], fit.origin_s[rows])
        omega = fit.model_params[:, [spec.omega_index(spec.line_of(j)) for j in range(m)]]
        f_hz = omega * np.array([spec.multiplier(j) for j in range(m)]) / (2 * np.pi)
    return residual_noise(w, resid, f_hz, rows=fit_rows)


def model_table(
    w: Windows, tab: pd.DataFrame, fit: HarmonicFit, spec: SignalModel, noise: ResidualNoise | None
) -> tuple[pd.DataFrame, list[str], ResidualNoise]:
    """`model_columns` with the σ's honest under coloured noise, and the adequacy columns.

    From the whole model's residual (``noise``, `model_residual_noise` of every window; None
    when no window was fitted): ``r2``, ``whiteness_p`` and, per component, the residual's
    spectral density at the component's frequency, which scales that component's σ's;
    ``sigma_amplitude_white_mm``/``sigma_f0_white_hz`` keep the first component's white-noise
    σ's, as for the default model.

    Returns:
        The table, the names of the model's added columns, and the first component's
        `ResidualNoise`.
    """
    b = len(w)
    kappa = None
    if noise is None:
        noise = residual_noise(w, w.y, np.full(b, np.nan), rows=np.zeros(0, np.int64))  # all NaN
    else:
        kappa = noise.kappa
        noise = dataclasses.replace(noise, kappa=kappa[:, 0])
    white, _ = model_columns(tab, fit, spec)
    tab, added = model_columns(tab, fit, spec, kappa)
    tab["r2"] = noise.r2
    tab["whiteness_p"] = noise.whiteness_p
    tab["sigma_amplitude_white_mm"] = white["sigma_amplitude_mm"]
    tab["sigma_f0_white_hz"] = white["sigma_f0_hz"]
    return tab, added, noise


_DEFAULT_NAMES = ("f0_hz", "sigma_f0_hz", "amplitude_mm", "sigma_amplitude_mm", "phase_rad", "peak_fap")
