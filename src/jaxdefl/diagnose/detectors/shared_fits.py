"""Fits shared by many series (motion_artefact, timing_error, amplitude_modulation, frequency_modulation).

- `Block`: the weighted projection of one series out of its free nuisance columns.
- the shared fits go to the diagnosis' one nonlinear solver, `_varpro.fit_shared` (optimistix
  Levenberg-Marquardt, jitted, all series batched), with the effect as a term without per-series
  amplitudes (``term_fn``: the modulation depth, the tap spread and the clock offset are shared;
  each series' scale is its known amplitude), each series' nuisance profiled out and its
  residual weighted by 1/σ̂² of its current residual. The terms are jax.numpy functions of one
  series (θ, t, aux); the same functions give the new means.
- `TiedModel`: the camera's view of the reference's harmonic on the tied series,
  offset + Re[H(ω; T) Z e^{iω(t/(1+ε) − δ − t_ref)}], with the tap spread T of the four-phase
  sampling and the camera clock's offset δ and rate ε; the two reference effects each fit their
  own parameters and re-estimate the other's when it is already in the model (the two commute
  and trade phase, so they are only told apart jointly).
- `Carriers`: per-series in-phase and quadrature carriers of the nominal harmonic (of the current
  motion where a modulation is already in the model), the demodulated residual combined across
  series on the frame clock and its low-frequency spectrum (the amplitude and phase modulation
  scans).
"""

from __future__ import annotations

import abc
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import jax.numpy as jnp
import numpy as np
from scipy import stats

from ..._numerics import harmonic_design
from ...effects import amplitude_modulation, frequency_modulation, motion_artefact, timing_error
from .._base import Context, Detector, Proposal, State, keep_series, loglik
from .._varpro import SharedFit, fit_shared
from .screening import param, updated, weights

__all__ = [
    "weights",
    "param",
    "updated",
    "Block",
    "SharedFit",
    "scan_p_value",
    "chi2_p_value",
    "tap_response",
    "quadrature_weight",
    "TiedModel",
    "TiedEffect",
    "tied_series",
    "AMBIGUOUS_CHI2",
    "motion_parameters",
    "Carriers",
    "one_sided",
]

_RIDGE = 1e-12


def _dot(a: np.ndarray, b: np.ndarray):
    """Σ a b of two long vectors. Not np.dot / @: OpenBLAS threads its 1-D dot, and on busy
    shared cores that costs 20 ms per call of 35k samples instead of 0.03 ms."""
    return np.einsum("i,i->", a, b)


def chi2_p_value(delta_chi2: float, dof: int) -> float:
    return float(stats.chi2.sf(max(float(delta_chi2), 0.0), dof))


def scan_p_value(power_max: float, n_independent: float) -> float:
    """P(max of n independent Exp(1) powers >= power_max): the scan-corrected p-value."""
    p1 = math.exp(-max(float(power_max), 0.0))
    return float(-math.expm1(max(n_independent, 1.0) * math.log1p(-min(p1, 1 - 1e-16))))


def one_sided(power: float, twin_power: float) -> bool:
    """A modulation puts matched lines at f0 ± f_m: all its power in one demodulation (in phase
    for amplitude, quadrature for phase). A single line at f0 + f_m (a vibration near the
    loading frequency) splits evenly between the two."""
    return twin_power > 20.0 and twin_power > 0.25 * power


class Block:
    """One series' weighted projection out of its nuisance columns ``nu`` (sample, q).

    ``proj(x)`` returns x minus its weighted LS fit by the nuisance, ``fit(x)`` the fit itself;
    ``chi2`` and ``normal`` work on Gram matrices (no projected copies). ``s2`` is σ̂² of the
    projected current residual ``r``.
    """

    def __init__(self, nu: np.ndarray, w: np.ndarray, r: np.ndarray):
        """nu: (sample, q) or its transpose's view of a (q, sample) array (cheaper)."""
        self.nu, self.w = nu, w
        self.nwT = nu.T * w  # (q, sample), C-ordered when nu is a view of one
        g = np.einsum("qn,nk->qk", self.nwT, nu)
        self.ginv = np.linalg.inv(g + _RIDGE * (np.trace(g) + 1e-300) * np.eye(g.shape[0]))
        self.n_used = int((w > 0).sum())
        self.s2 = 1.0
        self.s2 = self.chi2(r) / max(self.n_used - nu.shape[1], 1) or 1e-300

    def fit(self, x: np.ndarray) -> np.ndarray:
        if x.ndim == 1:
            return np.einsum("nq,q->n", self.nu, self.ginv @ np.einsum("qn,n->q", self.nwT, x))
        return self.nu @ (self.ginv @ (self.nwT @ x))

    def proj(self, x: np.ndarray) -> np.ndarray:
        return x - self.fit(x)

    def chi2(self, x: np.ndarray) -> float:
        """Σ w (proj x)² / σ̂²."""
        b = np.einsum("qn,n->q", self.nwT, x)  # not @: a one-row gemv is a threaded dot
        return float((_dot(self.w * x, x) - b @ self.ginv @ b) / self.s2)


def shared_fit(
    term_fn: Callable,
    theta0: np.ndarray,
    blocks: list[Block],
    t: list[np.ndarray],
    targets: list[np.ndarray],
    aux: dict,
    scale: np.ndarray,
    bounds: tuple[np.ndarray, np.ndarray] | None = None,
) -> SharedFit:
    """θ of χ²(θ) = Σ_series |P_s (target_s − term_s(θ))|²_w / σ̂_s² by `fit_shared`: each
    block's nuisance profiled out, its weights over its σ̂², the covariance (JᵀJ)⁻¹."""
    return fit_shared(
        None,
        np.asarray(theta0, np.float64),
        t,
        targets,
        [b.w / b.s2 for b in blocks],
        [np.asarray(b.nu) for b in blocks],
        aux=aux,
        scale=scale,
        term_fn=term_fn,
        bounds=bounds,
        known_scale=True,
        max_steps=64,
    )


# ---------------------------------------------------------------------------------------------
# the camera against the reference (tied series)


def tap_response(
    omega,
    tap_spread_s: float,
    offsets=(0.0, 0.25, 0.5, 0.75),
    derivative: bool = False,
    xp=np,
    quadrature: float = 0.5,
):
    """H(ω; T) of four taps at offsets·T after the frame time (`fit.motion`, vectorised over ω);
    with ``derivative`` also dH/dT. ``xp``: numpy, or jax.numpy inside a fit's term.

    The phase is atan2(C₃ − C₁, C₀ − C₂): for a pixel at modulation phase φ₀ a small motion
    reaches it through the (0, 2) pair with weight sin²φ₀ and through the (1, 3) pair with
    weight cos²φ₀ (``quadrature``; ½, the default, is the mean over φ₀: a range not known).
    """
    w, T = omega, tap_spread_s
    o = offsets
    al, be = (o[0] + o[2]) / 2, (o[2] - o[0]) / 2
    ga, ka = (o[1] + o[3]) / 2, (o[3] - o[1]) / 2
    e1, e2 = xp.exp(1j * w * al * T), xp.exp(1j * w * ga * T)
    c1, c2 = xp.cos(w * be * T), xp.cos(w * ka * T)
    q = quadrature
    h = (1 - q) * e1 * c1 + q * e2 * c2
    if not derivative:
        return h
    s1, s2 = xp.sin(w * be * T), xp.sin(w * ka * T)
    dh = w * ((1 - q) * e1 * (1j * al * c1 - be * s1) + q * e2 * (1j * ga * c2 - ka * s2))
    return h, dh


def quadrature_weight(range_mm: float, modulation_mhz: float) -> float:
    """cos²φ₀ of a surface at ``range_mm`` from a ToF camera modulated at ``modulation_mhz``
    (φ₀ = 4π f_m r / c, eq. 3.1): the weight of the (1, 3) tap pair in `tap_response`."""
    phi = 4 * math.pi * modulation_mhz * 1e6 * range_mm * 1e-3 / 299_792_458.0
    return math.cos(phi) ** 2


def motion_parameters(ctx: Context, T: float, sigma_T: float) -> dict:
    """The contract parameters of `motion_artefact` for a tap spread T (gain and lag at f0)."""
    w0 = 2 * math.pi * ctx.f0_hz
    h, dh = tap_response(w0, float(T), np.asarray(ctx.tap_offsets, np.float64), derivative=True)
    gain, lag = float(abs(h)), float(np.angle(h))
    dgain = float((np.conj(h) * dh).real / max(abs(h), 1e-300))
    dlag = float((dh / h).imag)
    return {
        "tap_spread_s": param(T, sigma_T),
        "gain": param(gain, abs(dgain) * sigma_T),
        "lag_deg": param(math.degrees(lag), math.degrees(abs(dlag) * sigma_T)),
    }


PPM = 1e-6
# a tap spread's gain loss must beat a pure phase shift (a clock offset) by this much in χ² for
# `motion_artefact` and `timing_error` to be told apart; below it the data cannot separate them
AMBIGUOUS_CHI2 = 10.0
TIED_EFFECTS = (motion_artefact.ENTRY.id, timing_error.ENTRY.id)  # needs_reference in the vocabulary
NAMES = ("tap_spread_s", "offset_s", "rate_ppm")


class TiedEffect(Detector):
    """An effect of the camera against the reference (motion_artefact, timing_error): seen on the
    reference-tied z series only, through their `TiedModel`."""

    needs_reference = True

    def propose(self, ctx: Context, states: list[State]) -> list[Proposal]:
        idx = tied_series(self, ctx, states)
        if idx is None:
            return []
        period = 1.0 / ctx.frame_rate_hz if ctx.frame_rate_hz else ctx.dt_s
        return self.propose_tied(ctx, states, TiedModel(ctx, states, idx), period)

    @abc.abstractmethod
    def propose_tied(self, ctx: Context, states: list[State], model: TiedModel, period: float):
        """The proposals on the tied series of ``model`` (``period``: the frame period, s)."""


def tied_series(effect, ctx: Context, states: list[State]) -> list[int] | None:
    """The reference-tied z series a tied effect (motion_artefact, timing_error) may propose on,
    or None when it cannot tell or is already in the model."""
    if effect.cannot_tell(ctx) is not None:
        return None
    idx = ctx.indices("z", tied=True)
    if not idx or any(effect.id in states[i].effects for i in idx):
        return None
    return idx


def tied_motion(theta, t, aux, xp=np):
    """Re[H(ω; T) Z e^{iω(t/(1+ε) − δ − t_ref)}] of one tied series at θ = (T, δ, ε ppm)
    (``aux``: omega, zr, zi, t_ref and the tap offsets o0..o3; ``xp``: numpy or jax.numpy)."""
    om = aux["omega"]
    h = tap_response(om, theta[0], (aux["o0"], aux["o1"], aux["o2"], aux["o3"]), xp=xp)
    tt = t / (1.0 + theta[2] * PPM)
    z = (aux["zr"] + 1j * aux["zi"]) * xp.exp(1j * om * (tt - theta[1] - aux["t_ref"]))
    return xp.real(h * z)


def tied_term(theta, t, aux):
    """`tied_motion` in jax.numpy: the term `shared_fit` fits."""
    return tied_motion(theta, t, aux, jnp)


# steps of θ = (T, δ, ε) the solver's tolerances are measured in: 1 ms, 0.1 ms, 1 ppm
TIED_SCALE = np.array([1e-3, 1e-4, 1.0])


class TiedModel:
    """offset + Re[H(ω; T) Z e^{iω(t/(1+ε) − δ − t_ref)}] on the tied series, θ = (T, δ, ε ppm).

    ``other[s]`` is the rest of the current model of series s (its accepted effects other than
    the two reference ones, and the offset), so that a new mean is other + term(θ) + offset fit.
    ``current`` holds θ of the current model: 0 for what is not accepted, else re-fitted to the
    current means (noise-free), so no bookkeeping outside the states is needed.
    """

    def __init__(self, ctx: Context, states: list[State], idx: list[int]):
        self.ctx, self.idx = ctx, idx
        self.t = [ctx.series[i].t for i in idx]
        self.y = [ctx.series[i].y for i in idx]
        self.w = [weights(states[i]) for i in idx]
        self.blocks = [
            Block(ctx.nuisance(i), w, ctx.series[i].y - states[i].mean)
            for i, w in zip(idx, self.w, strict=True)
        ]
        h = [ctx.nominal[i] for i in idx]
        self.omega = np.array([x.omega for x in h])
        self.Z = np.array([x.C - 1j * x.D for x in h])
        self.t_ref = np.array([x.t_ref for x in h])
        self.offsets = ctx.tap_offsets
        taps = {f"o{j}": float(o) for j, o in enumerate(ctx.tap_offsets)}
        self.aux = [
            {"omega": float(om), "zr": float(z.real), "zi": float(z.imag), "t_ref": float(tr), **taps}
            for om, z, tr in zip(self.omega, self.Z, self.t_ref, strict=True)
        ]
        self.accepted = {e for i in idx for e in states[i].effects if e in TIED_EFFECTS}
        means = [states[i].mean for i in idx]
        cur = np.zeros(3)
        free = []
        if motion_artefact.ENTRY.id in self.accepted:
            free.append(0)
            cur[0] = 0.5 / ctx.frame_rate_hz if ctx.frame_rate_hz else ctx.dt_s / 2
        if timing_error.ENTRY.id in self.accepted:
            free += [1, 2]
        if free:  # the accepted reference effects' parameters, from the current means
            cur = self.fit(cur, free, data=means).theta
        self.current = cur
        self.other = [m - self.term(k, cur) for k, m in enumerate(means)]

    def term(self, k: int, theta: np.ndarray) -> np.ndarray:
        """The motion of tied series k at θ."""
        return tied_motion(np.asarray(theta, np.float64), self.t[k], self.aux[k])

    def fit(
        self,
        theta0: np.ndarray,
        free: Sequence[int],
        data: list[np.ndarray] | None = None,
        bounds: Sequence[tuple[float, float]] | None = None,
    ) -> SharedFit:
        """Fit the ``free`` components of θ (the others fixed at theta0, ``bounds`` per free
        component) to y − other (or to ``data``, e.g. the current means)."""
        base = np.asarray(theta0, float).copy()
        lo, hi = base.copy(), base.copy()
        for j, f in enumerate(free):
            lo[f], hi[f] = bounds[j] if bounds else (-np.inf, np.inf)
        targets = data if data is not None else [y - o for y, o in zip(self.y, self.other, strict=True)]
        aux = {name: [a[name] for a in self.aux] for name in self.aux[0]}
        return shared_fit(tied_term, base, self.blocks, self.t, targets, aux, TIED_SCALE, (lo, hi))

    def chi2_at(self, theta: np.ndarray) -> float:
        return sum(
            b.chi2(y - o - self.term(k, theta))
            for k, (b, y, o) in enumerate(zip(self.blocks, self.y, self.other, strict=True))
        )

    def means(self, theta: np.ndarray) -> list[np.ndarray]:
        """New means: other + term(θ) + the offset refitted."""
        out = []
        for k, (b, y, o) in enumerate(zip(self.blocks, self.y, self.other, strict=True)):
            m = o + self.term(k, theta)
            out.append(m + b.fit(y - m))
        return out

    def observed_ratio(self) -> tuple[np.ndarray, np.ndarray]:
        """Per tied series: the camera's own harmonic over the reference's at mid-record, as
        (gain, phase lead rad): what H e^{-iωδ} must explain."""
        mid = 0.5 * self.ctx.duration_s
        g, ph = [], []
        for i in self.idx:
            f, n = self.ctx.free[i], self.ctx.nominal[i]
            zf = (f.C - 1j * f.D) * np.exp(1j * f.omega * (mid - f.t_ref))
            zn = (n.C - 1j * n.D) * np.exp(1j * n.omega * (mid - n.t_ref))
            r = zf / zn if abs(zn) > 0 else np.nan
            g.append(abs(r))
            ph.append(np.angle(r))
        return np.array(g), np.array(ph)


def tied_proposal_states(
    ctx: Context, states: list[State], model: TiedModel, theta: np.ndarray, effect: str, n_shared: int
):
    """(kept indices, {index: State}, gains) of the tied series whose likelihood the new θ raises."""
    means = model.means(theta)
    gains, new = {}, {}
    for k, i in enumerate(model.idx):
        st = states[i]
        y = ctx.series[i].y
        gains[i] = loglik(y, st, means[k]) - loglik(y, st)
    kept = sorted(i for i, g in gains.items() if keep_series(g, 0, ctx.series[i].n))
    for j, i in enumerate(kept):
        k = model.idx.index(i)
        new[i] = updated(states[i], effect, n_shared if j == 0 else 0, mean=means[k])
    return kept, new, gains


# ---------------------------------------------------------------------------------------------
# carriers of the current motion (amplitude and phase modulation)

MODULATIONS = (amplitude_modulation.ENTRY.id, frequency_modulation.ENTRY.id)


def current_motion(ctx: Context, i: int, mean: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(A(t), ψ(t)) of the motion in a model mean: mean ≈ c + A(t) cos(arg(t) + ψ(t)), arg the
    nominal harmonic's, by linear LS of (1, cos arg, sin arg) over a sliding window of two
    loading periods (moving sums on the frame clock; the mean is noise-free, so the window only
    has to average out the 2ω term and other effects' lines). A modulation already accepted is
    in A and ψ; a new one multiplies or shifts that motion, not the nominal harmonic, so the
    product of the two is in the model rather than left as side lines at f_AM ± f_FM."""
    s, h = ctx.series[i], ctx.nominal[i]
    n = ctx.n_frames
    half = max(int(round(1.0 / (ctx.f0_hz * ctx.dt_s))), 2)
    arg = h.argument(s.t)
    cols = harmonic_design(arg).T
    lo = np.clip(s.k - half, 0, n)
    hi = np.clip(s.k + half + 1, 0, n)

    def window_sum(x):
        c = np.concatenate([[0.0], np.cumsum(np.bincount(s.k, weights=x, minlength=n)[:n])])
        return c[hi] - c[lo]

    gram = np.empty((s.n, 3, 3))
    rhs = np.empty((s.n, 3))
    for j in range(3):
        rhs[:, j] = window_sum(cols[j] * mean)
        for m in range(j, 3):
            gram[:, j, m] = gram[:, m, j] = window_sum(cols[j] * cols[m])
    ridge = 1e-9 * np.trace(gram, axis1=1, axis2=2)[:, None, None] * np.eye(3)
    beta = np.linalg.solve(gram + ridge, rhs[..., None])[..., 0]
    z = beta[:, 1] - 1j * beta[:, 2]
    return np.abs(z), np.angle(z)


@dataclass
class _Carrier:
    i: int
    a: float | np.ndarray  # the motion's amplitude (mm): nominal, or A(t) of the current model
    cos: np.ndarray  # cos(arg)
    sin: np.ndarray  # sin(arg)
    arg: np.ndarray  # the motion's phase angle: nominal, or + ψ(t) of the current model
    r: np.ndarray  # current residual
    w: np.ndarray
    scan: Block  # nuisance of the scan: offset, cos, sin at ω (also on tied series)
    block: Block  # the free nuisance of the series (`Context.nuisance`)
    trend: Block  # the scan's, and on tied series a phase trend (a clock rate, `timing_error`'s)
    absorbed: Block | None  # tied series: the carrier's cos, sin (what the LDS's harmonic holds)


_CACHE: dict = {}


class Carriers:
    """The series with a real motion (amplitude ≥ ``min_snr`` σ_A) and their carriers.

    In-phase column a cos(arg) (amplitude modulation: y += a u(t) cos arg) and quadrature column
    −a sin(arg) (phase modulation: y += −a δφ(t) sin arg), a and arg from the nominal harmonic,
    or on a series that already carries a modulation its current motion (`current_motion`).
    The nuisance blocks stay at the nominal harmonic's cos and sin (its free C and D).
    """

    def __init__(self, ctx: Context, states: list[State], min_snr: float = 10.0):
        self.ctx = ctx
        self.items: list[_Carrier] = []
        self._grids: dict = {}
        t_mid = 0.5 * ctx.duration_s
        for i, s in enumerate(ctx.series):
            st, h = states[i], ctx.nominal[i]
            a = h.amplitude
            w = weights(st)
            r = s.y - st.mean
            # σ_A ≈ σ̂ sqrt(2 / Σw): the amplitude must stand well above it
            s2 = float(np.sum(w * r * r)) / max(int((w > 0).sum()), 1)
            if not a * math.sqrt(0.5 * float(w.sum()) / max(s2, 1e-300)) >= min_snr:
                continue
            arg = h.argument(s.t)
            c, sn = np.cos(arg), np.sin(arg)
            one = np.ones_like(s.t)
            scan = Block(np.stack([one, c, sn]).T, w, r)
            if s.tied:  # the camera's offset is all that is free; the scans still take out C, D
                block = Block(one[:, None], w, r)
                trend = Block(np.stack([one, c, sn, sn * (s.t - t_mid)]).T, w, r)
                absorbed = Block(np.stack([c, sn]).T, w, r)
            else:  # the free nuisance: offset, C, D (`Context.nuisance`, the same span)
                block = trend = scan
                absorbed = None
            if any(e in MODULATIONS for e in st.effects):
                a, psi = current_motion(ctx, i, st.mean)
                arg = arg + psi
                c, sn = np.cos(arg), np.sin(arg)
            self.items.append(_Carrier(i, a, c, sn, arg, r, w, scan, block, trend, absorbed))

    @classmethod
    def cached(cls, ctx: Context, states: list[State]) -> Carriers:
        """The carriers of (ctx, states), shared by the effects of one search round."""
        key = _CACHE.get("key")
        if key is not None and key[0] is ctx and len(key[1]) == len(states):
            if all(a is b for a, b in zip(key[1], states, strict=True)):
                return _CACHE["value"]
        value = cls(ctx, states)
        _CACHE["key"] = (ctx, tuple(states))
        _CACHE["value"] = value
        return value

    def column(self, it: _Carrier, kind: str) -> np.ndarray:
        return it.a * it.cos if kind == "in_phase" else -it.a * it.sin

    def grid(self, kind: str, trend: bool = False) -> tuple[np.ndarray, float]:
        """(frame,) demodulated residual combined across series (Σ w r̃ x / σ̂² per frame), and
        Q = Σ w x² / σ̂²."""
        key = (kind, trend)
        if key not in self._grids:
            ctx = self.ctx
            n = ctx.n_frames
            grid = np.zeros(n)
            q = 0.0
            for it in self.items:
                s = ctx.series[it.i]
                x = self.column(it, kind)
                b = it.trend if trend else it.scan
                rp = b.proj(it.r)
                grid += np.bincount(s.k, weights=it.w * rp * x / b.s2, minlength=n)[:n]
                q += float(np.sum(it.w * x * x) / b.s2)
            self._grids[key] = (grid, q)
        return self._grids[key]

    def power_at(self, kind: str, f_hz: float, trend: bool = False) -> float:
        """Combined power (Exp(1) under white noise) of the ``kind`` demodulation at one frequency."""
        grid, q = self.grid(kind, trend)
        k = np.nonzero(grid)[0]
        n_f = _dot(np.exp(-2j * np.pi * f_hz * k * self.ctx.dt_s), grid[k])
        return float(abs(n_f) ** 2 / max(q, 1e-300))

    def scan(self, kind: str, f_lo: float, f_hi: float, oversample: int = 4, trend: bool = False):
        """Spectrum of the demodulated residual combined across series, weighted by a²/σ̂².

        Returns (freq_hz, power, n_independent, grid): power is |N(f)|²/Q with
        N(f) = Σ_s Σ_t w r̃ x e^{-2πi f t}/σ̂², Q = Σ w x²/σ̂² (Exp(1) under white noise, f away
        from 0 and 2 f0); grid is the (frame,) combined demodulated series for refinement.
        """
        ctx = self.ctx
        n = ctx.n_frames
        grid, q = self.grid(kind, trend)
        m = int(oversample * n)
        spec = np.fft.rfft(grid, m)
        freq = np.arange(spec.size) / (m * ctx.dt_s)
        band = (freq >= f_lo) & (freq <= f_hi)
        power = np.abs(spec[band]) ** 2 / max(q, 1e-300)
        # the peak is searched on an oversampled grid: count twice the independent frequencies
        # (calibrated on white noise: p-values of the maximum then come out uniform)
        n_ind = max(2.0 * (f_hi - f_lo) * n * ctx.dt_s, 1.0)
        return freq[band], power, n_ind, grid, q

    def refine_peak(self, grid: np.ndarray, q: float, f_peak: float, half_width: float, n_fine: int = 41):
        """The combined power on a fine grid around ``f_peak`` (direct DFT of the nonzero frames):
        (frequency of the maximum, its power, N(f) there)."""
        k = np.nonzero(grid)[0]
        g = grid[k]
        t = k * self.ctx.dt_s
        f = np.linspace(f_peak - half_width, f_peak + half_width, n_fine)
        spec = np.exp(-2j * np.pi * np.outer(f, t)) @ g
        p = np.abs(spec) ** 2 / max(q, 1e-300)
        j = int(np.argmax(p))
        fj = float(f[j])
        if 0 < j < n_fine - 1:  # parabola through the three best
            y0, y1, y2 = p[j - 1], p[j], p[j + 1]
            den = y0 - 2 * y1 + y2
            fj += float(0.5 * (y0 - y2) / den * (f[1] - f[0])) if den < 0 else 0.0
        n_peak = complex(_dot(np.exp(-2j * np.pi * fj * t), g))
        return fj, abs(n_peak) ** 2 / max(q, 1e-300), n_peak

    def linear_stat(self, kind: str, u: Callable[[np.ndarray], np.ndarray], trend: bool = False):
        """(χ²₁ statistic, estimate, σ) of a shared coefficient b in y += b u(t) x(t)."""
        num = den = 0.0
        for it in self.items:
            x = self.column(it, kind) * u(self.ctx.series[it.i].t)
            b = it.trend if trend else it.scan
            xp = b.proj(x)
            num += float(np.sum(it.w * xp * it.r) / b.s2)
            den += float(np.sum(it.w * xp * xp) / b.s2)
        den = max(den, 1e-300)
        return num * num / den, num / den, 1.0 / math.sqrt(den)

    def fit(self, term: Callable, theta0: np.ndarray, scale: np.ndarray) -> SharedFit:
        """Fit shared θ of ``term(theta, t, aux) -> (sample,)`` (jax.numpy, one carrier; aux:
        a, cos, sin, arg, half = duration/2, omega: the nominal harmonic's) over all carriers,
        each series' free nuisance profiled out, the term as `visible` gives it."""
        items = self.items
        half = 0.5 * self.ctx.duration_s
        aux: dict = {k: [] for k in ("a", "cos", "sin", "arg", "absorbed", "absorber", "half", "omega")}
        for it in items:
            aux["a"].append(np.broadcast_to(np.asarray(it.a, np.float64), it.cos.shape))
            aux["cos"].append(it.cos)
            aux["sin"].append(it.sin)
            aux["arg"].append(it.arg)
            if it.absorbed:  # the weighted LS fit on the carrier's cos, sin: nu @ (P x)
                aux["absorbed"].append(np.asarray(it.absorbed.nu))
                aux["absorber"].append((it.absorbed.ginv @ it.absorbed.nwT).T)
            else:
                aux["absorbed"].append(np.zeros((it.w.size, 2)))
                aux["absorber"].append(np.zeros((it.w.size, 2)))
            aux["half"].append(half)
            aux["omega"].append(self.ctx.nominal[it.i].omega)
        t = [self.ctx.series[it.i].t for it in items]
        blocks = [it.block for it in items]
        return shared_fit(visible(term), theta0, blocks, t, [it.r for it in items], aux, scale)

    def proposal_states(self, states: list[State], fit: SharedFit, effect: str, n_shared: int):
        """(kept, {index: State}, gains): the new means of a `fit` (its term and nuisance) on
        every carrier. The term is one function of time acting on the whole beam's motion,
        fitted on all the carriers, and its evidence is weighed on all of them: keeping only the
        series where it happens to be individually significant is a look at the data that the
        test does not pay for (on frame-common noise it named a 7 % amplitude trend on two of
        seven plates at the critical value, which the term fitted on every plate does not
        reach)."""
        ctx = self.ctx
        gains, means = {}, {}
        for k, it in enumerate(self.items):
            st = states[it.i]
            y = ctx.series[it.i].y
            mean = st.mean + fit.term[k] + fit.fitted[k]
            means[it.i] = mean
            gains[it.i] = loglik(y, st, mean) - loglik(y, st)
        kept = sorted(gains)
        new = {
            i: updated(states[i], effect, n_shared if j == 0 else 0, mean=means[i])
            for j, i in enumerate(kept)
        }
        return kept, new, gains


_VISIBLE: dict = {}


def visible(term: Callable) -> Callable:
    """``term`` as the model of each series carries it: on a tied series without its part along
    the carrier's cos and sin (``aux["absorbed"]``, its weighted LS fit ``aux["absorber"]``; zero
    columns elsewhere). The LDS sees the
    same load, so the reference's harmonic, fitted over the record, already holds the
    modulation's projection on the carrier (e.g. the mean phase of a few modulation cycles);
    counted again, it is a phase or gain offset against the LDS that `timing_error` or
    `motion_artefact` would take up. (On untied series the free C and D take it up alike.)
    One wrapper per term: its compiled solver is reused."""
    if term not in _VISIBLE:

        def seen(theta, t, aux):
            m = term(theta, t, aux)
            return m - aux["absorbed"] @ (aux["absorber"].T @ m)

        _VISIBLE[term] = seen
    return _VISIBLE[term]
