"""The diagnosis' data model: series, their nominal harmonics, the current model of each series,
and the contract between the search (`_search.py`) and the detectors of the candidate effects
(`effects/`). Its names are public as ``jaxdefl.diagnose.Context``, ``State``, ``Proposal``,
``Detector`` (and the helpers below); a new effect's detector is a `Detector` subclass.

Vocabulary
----------
- A *series* is one plate and axis of the camera's trajectory table, with time ``t`` in s
  relative to the record's first timestamp (`Context.t0`) and values ``y`` in mm.
- Its *nominal harmonic* is the thesis' model (5.29): y ≈ offset + C cos ω(t − t_ref) +
  D sin ω(t − t_ref). Without a reference it is the camera's own Gauss-Newton fit. With a
  reference (LDS), the z series of a plate that has an LDS is *tied*: its nominal harmonic is the
  LDS's (same ω, C, D: the camera should see what the LDS sees), only the offset is the camera's.
  Differences camera − LDS are then residual structure for `motion_artefact`/`timing_error`.
- The *state* of a series is its current model: the mean (nominal harmonic plus the accepted
  effects' terms) and the noise model (relative scale per sample, inlier mask and the outlier
  component). Its log-likelihood is computed by `loglik` alone, for every effect alike.
- A *detector* (`Detector`, one per effect id) looks at the states, runs its effect's
  signature test and returns
  `Proposal`s: new means / noise models for some series, the number of parameters added, the
  signature's p-value (already corrected for the effect's own scan, e.g. over frequencies), the
  located span and band, the fitted parameters with σ's, and a plain-language explanation. The
  search scores proposals by ΔBIC, controls the multiple testing and accepts the best.

Rules for effects: never refit what the nominal model owns with new parameters (re-estimating
the offset and, on untied series, the harmonic's C and D through `Context.nuisance` is allowed
and costs no parameter); build columns orthogonal to the harmonic where the physics allows
(centred time); count every new parameter in `Proposal.n_params`, including nonlinear ones and
each per-series amplitude; keep only the series whose own evidence pays for their own
parameters (see `keep_series`).
"""

from __future__ import annotations

import abc
import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from functools import cached_property

import numpy as np

from .._numerics import DELTA_BIC_MAX, difference_sigma, harmonic_design, wls
from ..settings import SENSORS as SENSOR_KINDS

__all__ = [
    "SENSOR_KINDS",
    "Series",
    "Harmonic",
    "State",
    "Context",
    "Proposal",
    "Detector",
    "loglik",
    "rms_equivalent",
    "regress",
    "weights",
    "regress_offset",
    "keep_series",
    "masked_fourier",
    "masked_periodogram",
    "peak_offset",
    "LOG_2PI",
]

LOG_2PI = math.log(2 * math.pi)
# the one weighted least squares (`jaxdefl._numerics.wls`) under its old name, for `_sensor_nominal`


@dataclass(frozen=True)
class Series:
    """One plate and axis of the recording.

    Attributes:
        plate, axis: the plate number and axis (``z``, ``x`` or ``y``).
        t: (sample,) s since `Context.t0`, increasing; missing samples are absent.
        y: (sample,) mm.
        k: (sample,) frame index on the record's frame clock (``round(t / dt)``).
        tied: the nominal harmonic is the reference's (z of a plate with an LDS).
    """

    plate: int
    axis: str
    t: np.ndarray
    y: np.ndarray
    k: np.ndarray
    tied: bool = False

    @property
    def n(self) -> int:
        return int(self.t.size)

    @property
    def key(self) -> str:
        return f"{self.plate}{self.axis}"


@dataclass(frozen=True)
class Harmonic:
    """offset + C cos ω(t − t_ref) + D sin ω(t − t_ref) = offset + A cos(ω(t − t_ref) − phase)."""

    omega: float
    C: float
    D: float
    offset: float
    t_ref: float
    sigma_omega: float = float("nan")
    sigma_amplitude: float = float("nan")

    @property
    def f0_hz(self) -> float:
        return self.omega / (2 * math.pi)

    @property
    def amplitude(self) -> float:
        return math.hypot(self.C, self.D)

    @property
    def phase(self) -> float:
        return math.atan2(self.D, self.C)

    def argument(self, t: np.ndarray) -> np.ndarray:
        """ω(t − t_ref) − phase: the motion's phase angle at ``t`` (0 at the peak of y)."""
        return self.omega * (np.asarray(t) - self.t_ref) - self.phase

    def motion(self, t: np.ndarray) -> np.ndarray:
        """The harmonic without its offset: A cos(ω(t − t_ref) − phase)."""
        return self.amplitude * np.cos(self.argument(t))

    def __call__(self, t: np.ndarray) -> np.ndarray:
        return self.offset + self.motion(t)


@dataclass(frozen=True)
class State:
    """The current model of one series.

    Attributes:
        mean: (sample,) model prediction (mm).
        scale: (sample,) relative noise σ per sample (the noise is σ̂ · scale, σ̂ profiled).
        inlier: (sample,) False for samples assigned to the outlier component.
        outlier_fraction, outlier_scale_mm: the outlier component (fraction 0: none).
        n_params: parameters of the model so far (nominal 4 or 1 when tied, plus effects).
        effects: ids of the accepted effects that touch this series.
    """

    mean: np.ndarray
    scale: np.ndarray
    inlier: np.ndarray
    outlier_fraction: float = 0.0
    outlier_scale_mm: float = 0.0
    n_params: int = 4
    effects: tuple[str, ...] = ()

    def with_(self, **kw) -> State:
        return replace(self, **kw)

    # The noise model's constants, computed once per state: `loglik` is called on the same
    # state for every proposal scored against it, and the boolean indexing and logarithms over
    # a long series would otherwise dominate scoring.
    @cached_property
    def n_inlier(self) -> int:
        return int(self.inlier.sum())

    @cached_property
    def all_inlier(self) -> bool:
        return self.n_inlier == self.inlier.size

    @cached_property
    def unit_scale(self) -> bool:
        return bool(np.all(self.scale == 1.0))

    @cached_property
    def log_scale_sum(self) -> float:
        """Σ log scale over the inliers."""
        if self.unit_scale:
            return 0.0
        return float(np.sum(np.log(self.scale[self.inlier])))


def loglik(y: np.ndarray, st: State, mean: np.ndarray | None = None) -> float:
    """Log-likelihood of ``y`` under the state (optionally with another ``mean``).

    Inliers: Gaussian with σ_i = σ̂ scale_i, σ̂ the maximum-likelihood value (profiled), so
    -2 log L = Σ 2 log σ_i + n (log 2π + 1). Outliers: Gaussian of σ = outlier_scale_mm about the
    mean, each sample also paying log ε (inliers log(1 − ε)): a hard-assigned two-component
    mixture.
    """
    mean = st.mean if mean is None else mean
    r = y - mean
    n_in = st.n_inlier
    if n_in == 0:
        return -np.inf
    if st.all_inlier:
        z = r if st.unit_scale else r / st.scale
    else:
        inl = st.inlier
        z = r[inl] / st.scale[inl]
    s2 = max(float(np.mean(z * z)), 1e-300)
    ll = -st.log_scale_sum - 0.5 * n_in * (math.log(s2) + LOG_2PI + 1.0)
    if st.outlier_fraction > 0:
        eps, s = st.outlier_fraction, st.outlier_scale_mm
        ro = r[~st.inlier]
        ll += n_in * math.log1p(-eps)
        ll += np.sum(math.log(eps) - math.log(s) - 0.5 * LOG_2PI - 0.5 * (ro / s) ** 2)
    return float(ll)


def rms_equivalent(total_loglik: float, n: int) -> float:
    """The σ (mm) of white Gaussian noise with the same likelihood: the residual RMS for a
    homoscedastic model, the geometric-mean σ for a heteroscedastic one."""
    return float(math.exp(-total_loglik / n - 0.5 * LOG_2PI - 0.5))


@dataclass
class Proposal:
    """What a detector proposes to add to the model.

    The search accepts the proposal when its likelihood-ratio statistic 2 Δlog L exceeds the χ²
    critical value at α / (effects screened × trials) with n_params − scan_params degrees of
    freedom (`_search.Calibration`).

    Attributes:
        effect: the effect id (DESIGN.md list).
        series: indices into `Context.series` of the series the effect touches.
        states: {series index: new State} for those series (new mean and/or noise model).
        n_params: parameters added in total (shared nonlinear ones once, per-series ones each).
        p_value: the signature test's p-value, corrected for the effect's own scan.
        parameters: {name: {"value": v, "sigma": s or None}} (JSON-able), the contract names.
        t_start, t_end: the located span in s since `Context.t0`.
        band_hz: [lo, hi] of the frequencies involved, or None.
        explanation: one or two sentences for a structural engineer.
        refine: optional callable returning the proposal refitted in full (e.g. the shared
            nonlinear parameters by `_varpro.fit_shared`), or None when the refit fails. Effects
            screen cheaply (grids, FFTs, linear fits at the grid optimum); the search calls
            ``refine`` only on the proposal it is about to accept, then scores it again.
        shape: {series index: factor} when the term is one signal times a known factor per series
            (a mode shape, signs included), so that noise shared by the plates of a frame is
            weighed against that pattern (`_correlation`); None: the same term on every series.
        trials: the look-elsewhere factor of the proposal's statistic: how many independent
            alternatives the effect's scan chose it from (frequencies × axes × kinds, jump
            times, orders, candidate series a subset was picked from); 1 for a term of known form.
        scan_params: how many of ``n_params`` the scan fixed (a frequency, a jump time, a time
            constant): they are counted in ``trials``, not as χ² degrees of freedom.
        inflation: how many times more the statistic varies than under white noise where the
            search's likelihood does not model it (a noise-level term under AR(1) noise: its
            squared residuals are correlated); the search divides 2 Δlog L by it.
    """

    effect: str
    series: list[int]
    states: dict[int, State]
    n_params: int
    p_value: float
    parameters: dict
    t_start: float
    t_end: float
    band_hz: list[float] | None
    explanation: str
    detail: dict = field(default_factory=dict)
    refine: Callable[[], Proposal | None] | None = None
    shape: dict[int, float] | None = None
    trials: float = 1.0
    scan_params: int = 0
    inflation: float = 1.0


@dataclass(frozen=True)
class Context:
    """Everything an effect may look at (read-only).

    Attributes:
        series: the camera's series.
        nominal: (series,) nominal harmonic of each series (tied ones: the reference's harmonic
            with the camera's offset).
        free: (series,) the camera's own harmonic fit of each series.
        reference: {plate: Series} of the LDS (axis ``z``), empty without a reference.
        reference_harmonic: {plate: Harmonic} fitted to the LDS over the camera's span.
        t0: epoch (or table) time of t = 0; duration_s: span of the record.
        dt_s: frame interval; n_frames: frames on the clock (max k + 1).
        f0_hz: the loading frequency (median of the nominal fits).
        sensor: a `SENSOR_KINDS` kind or None (unknown); frame_rate_hz, modulation_mhz: sensor facts
            (frame_rate_hz measured from the table when not given).
        tap_offsets: the ToF tap offsets (fractions of the frame period), default evenly spread.
        tap_spread_s: the tap spread the nominal model already holds (s; 0: none): with a
            configured ToF camera the tied series' nominal is the reference seen through its
            taps (`_context.nominal_tap_spread`), so the reference effects find what remains.
        left_out: series not diagnosed, each ``{"plate", "axis", "status", "n"}`` (status
            ``too_few_samples`` or ``value_out_of_range``, as in the estimates table).
        depth_step_mm_at_2m, jumps_per_minute, jump_mm: a configured structured-light camera's
            depth lattice (its step at 2 m, growing as z²) and level jumps (rate, RMS size);
            None when not known (`_sensor_nominal`).
    """

    series: list[Series]
    nominal: list[Harmonic]
    free: list[Harmonic]
    reference: dict[int, Series]
    reference_harmonic: dict[int, Harmonic]
    t0: float
    duration_s: float
    dt_s: float
    n_frames: int
    f0_hz: float
    sensor: str | None = None
    frame_rate_hz: float | None = None
    modulation_mhz: float | None = None
    tap_offsets: tuple[float, ...] = (0.0, 0.25, 0.5, 0.75)
    tap_spread_s: float = 0.0
    left_out: tuple[dict, ...] = ()
    depth_step_mm_at_2m: float | None = None
    jumps_per_minute: float | None = None
    jump_mm: float | None = None
    _nuisance: dict = field(default_factory=dict, init=False, repr=False, compare=False)
    _noise: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    @property
    def plates(self) -> list[int]:
        return sorted({s.plate for s in self.series})

    def indices(self, axis: str | None = None, tied: bool | None = None) -> list[int]:
        """Indices of the series on ``axis`` (all axes if None), optionally only (un)tied ones."""
        return [
            i
            for i, s in enumerate(self.series)
            if (axis is None or s.axis == axis) and (tied is None or s.tied == tied)
        ]

    def nuisance(self, i: int, t: np.ndarray | None = None) -> np.ndarray:
        """(sample, k) columns an effect may re-estimate for free on series i: the offset, and on
        an untied series the harmonic's cosine and sine (its C and D).

        On the series' own times the columns are computed once per context (every effect asks
        for them at every screening) and returned read-only.
        """
        if t is None:
            if i not in self._nuisance:
                cols = self._nuisance_at(i, self.series[i].t)
                cols.setflags(write=False)
                self._nuisance[i] = cols
            return self._nuisance[i]
        return self._nuisance_at(i, t)

    def noise_sigma(self, i: int) -> float:
        """Series i's noise σ (mm) from the first differences of its residual about the nominal
        harmonic (1.4826 MAD / √2: slow structure and outliers barely move it); cached."""
        if i not in self._noise:
            s = self.series[i]
            self._noise[i] = difference_sigma(s.y - self.nominal[i](s.t), s.k)
        return self._noise[i]

    def _nuisance_at(self, i: int, t: np.ndarray) -> np.ndarray:
        if self.series[i].tied:
            return np.ones((t.size, 1))
        h = self.nominal[i]
        return harmonic_design(h.omega * (t - h.t_ref))


class Detector(abc.ABC):
    """The detector of one candidate effect: subclasses set the class attributes and implement
    `propose`; each module of `effects/` exports one instance as ``EFFECT``.

    Attributes:
        id: the DESIGN.md effect id.
        meaning: what physics it stands for (one line, for reports).
        needs_reference: it can only be told against an LDS reference.
        min_plates: plates needed (an effect defined as common to all plates needs several).
        plausible, plausible_unit, gate_params: the information gate (`expected_delta_bic`): the
            size of the effect at a plausible magnitude and the parameters its simplest form adds.
            Units: ``"noise"`` (× the series' noise σ), ``"motion"`` (× its motion amplitude),
            ``"seconds"`` (a timing error: × its motion's velocity amplitude ωA), ``"mm"`` (an
            absolute amplitude), and ``"mm_per_s"`` (a rate: × the record's duration, the term's
            RMS that of a ramp). An effect with its own shape overrides `plausible_rms`.
        noise_structure: it models the noise (its level, its outliers), not the mean: a generic
            mean term that explains the same residual better goes before it (`run_diagnosis`).
        sensors: the sensor kinds (`SENSOR_KINDS`) that can produce it; on a record of another
            kind (`Context.sensor`, from the recording, the config or ``--sensor``) it is not a
            name the diagnosis may give (`cannot_tell`). Default: every kind.
        causes: {sensor kind: the mechanism that makes it on that sensor}, for explanations
            (`cause`); a kind not listed gets ``causes["*"]``.
        structural: the beam itself can make it (its motion or its shape change), not only a
            measurement. Seen alike by several cameras, a structural effect is the structure's;
            one that only a measurement makes (a noise structure, a clock, a camera's motion) is
            the cameras' common physics (`jaxdefl.diagnose.attribution`). Default: not
            ``noise_structure``.
    """

    id: str = ""
    meaning: str = ""
    needs_reference: bool = False
    min_plates: int = 1
    plausible: float = 0.2
    plausible_unit: str = "noise"
    gate_params: int = 3
    noise_structure: bool = False
    sensors: tuple[str, ...] = SENSOR_KINDS
    causes: dict[str, str] = {}  # noqa: RUF012 (read-only class data)
    structural: bool | None = None

    @classmethod
    def can_be_structural(cls) -> bool:
        return (not cls.noise_structure) if cls.structural is None else cls.structural

    def cause(self, ctx: Context) -> str:
        """The mechanism that makes this effect on the record's sensor (for explanations)."""
        return self.causes.get(ctx.sensor or "*", self.causes.get("*", ""))

    def plausible_rms(self, ctx: Context, i: int) -> float:
        """RMS (mm) of the effect's term on series i at a plausible magnitude."""
        h = ctx.nominal[i]
        u = self.plausible_unit
        if u == "noise":
            return self.plausible * ctx.noise_sigma(i)
        if u == "motion":
            return self.plausible * h.amplitude / math.sqrt(2)
        if u == "seconds":
            return self.plausible * h.omega * h.amplitude / math.sqrt(2)
        if u == "mm":
            return self.plausible / math.sqrt(2)
        if u == "mm_per_s":
            return self.plausible * ctx.duration_s / math.sqrt(12)
        raise ValueError(f"plausible_unit: unknown unit {u!r}")

    def gate_design_effect(self, ctx: Context, corr) -> float:
        """The smallest design effect (`_correlation`) the effect's term can have on this
        record's noise: its evidence at a plausible size is divided by it. 1 unless the term
        has a known pattern across the series (an effect with one overrides this)."""
        return 1.0

    def expected_delta_bic(self, ctx: Context, design_effect: float = 1.0) -> float:
        """ΔBIC an effect of plausible size would reach on this record: −Σ n_s (rms_s/σ_s)² +
        k log N over the series, σ_s each series' noise (`Context.noise_sigma`). The evidence
        grows as SNR² × samples: a short clean record is told, a long noisy one may not be."""
        signal = 0.0
        n_total = 0
        for i, s in enumerate(ctx.series):
            n_total += s.n
            sig = ctx.noise_sigma(i)
            if sig > 0 and math.isfinite(sig):
                signal += s.n * (self.plausible_rms(ctx, i) / sig) ** 2
        return -signal / design_effect + self.gate_params * math.log(max(n_total, 2))

    def cannot_tell(self, ctx: Context, corr=None) -> str | None:
        """Why this effect cannot be told on this record, or None when it can; ``corr``: the
        noise's correlation across the series of a frame (`_correlation.FrameCorrelation`), for
        an effect whose evidence depends on its pattern (`gate_design_effect`)."""
        if ctx.sensor is not None and ctx.sensor not in self.sensors:
            return (
                f"a {ctx.sensor} sensor does not produce it (only {', '.join(self.sensors)}): "
                "not a name for this record"
            )
        if self.needs_reference and not ctx.reference:
            return "needs a reference (--reference LDS.csv) on at least one plate"
        if len(ctx.plates) < self.min_plates:
            return f"needs at least {self.min_plates} plates, the table has {len(ctx.plates)}"
        dbic = self.expected_delta_bic(ctx, 1.0 if corr is None else self.gate_design_effect(ctx, corr))
        # the information gate: tried when an effect of plausible size would be strong evidence
        if not dbic < DELTA_BIC_MAX:
            return (
                f"not enough evidence: an effect of plausible size would reach ΔBIC {dbic:.0f} on "
                f"this record ({sum(s.n for s in ctx.series)} samples, {ctx.duration_s:.3g} s, "
                f"needs < {DELTA_BIC_MAX:.0f})"
            )
        return None

    @abc.abstractmethod
    def propose(self, ctx: Context, states: list[State]) -> list[Proposal]:
        """Screen the current states; proposals for this effect, or [] when nothing is there."""


def weights(st: State) -> np.ndarray:
    """(sample,) least-squares weights of a state: 1/scale² on inliers, 0 on outliers."""
    return np.where(st.inlier, 1.0 / st.scale**2, 0.0)


def regress(
    ctx: Context, i: int, st: State, y: np.ndarray, cols: np.ndarray, nuisance: np.ndarray | None = None
):
    """Fit effect columns plus the free nuisance of series i (``nuisance``, default
    `Context.nuisance`) to its current residual, by the package's one weighted least squares.

    Returns (beta of the effect columns, their covariance, the new mean of the series).
    """
    nu = ctx.nuisance(i) if nuisance is None else nuisance
    beta, cov, fitted = wls(np.concatenate([cols, nu], axis=1), y - st.mean, weights(st))
    k = cols.shape[1]
    return beta[:k], cov[:k, :k], st.mean + fitted


def regress_offset(ctx: Context, i: int, st: State, y: np.ndarray, cols: np.ndarray):
    """As `regress`, with the offset as the only nuisance (for terms far from the loading
    frequency, where re-estimating the harmonic would only cost time)."""
    return regress(ctx, i, st, y, cols, np.ones((y.size, 1)))


def keep_series(delta_loglik: float, k_own: int, n: int, margin: float = 0.0) -> bool:
    """A series stays in a proposal when its own evidence pays for its own parameters (BIC)."""
    return 2.0 * delta_loglik > k_own * math.log(max(n, 2)) + margin


def peak_offset(p_left: float, p_mid: float, p_right: float) -> float:
    """Offset (in grid steps, within ±0.5) of a peak from a parabola through log powers."""
    a, b, c = (math.log(max(v, 1e-300)) for v in (p_left, p_mid, p_right))
    den = a - 2 * b + c
    return float(np.clip(0.5 * (a - c) / den, -0.5, 0.5)) if den < 0 else 0.0


def masked_fourier(ctx: Context, i: int, r: np.ndarray, oversample: int = 1):
    """Fourier coefficients of a residual on the frame clock (zero-filled gaps), normalised by
    the residual variance so that white noise gives unit mean power (complex: a line common to
    several series adds up coherently in their sum).

    Returns (freq_hz (freq,), coef (freq,) complex), frequencies k/(M dt) from 1/(M dt) to
    Nyquist, M = oversample × frames.
    """
    s = ctx.series[i]
    m = int(ctx.n_frames * oversample)
    g = np.zeros(m)
    g[s.k] = r - r.mean()
    var = float(np.mean((r - r.mean()) ** 2)) or 1e-300
    coef = np.fft.rfft(g)[1:] / math.sqrt(s.n * var)
    freq = np.arange(1, m // 2 + 1) / (m * ctx.dt_s)
    return freq, coef


def masked_periodogram(ctx: Context, i: int, r: np.ndarray, oversample: int = 1):
    """Classical periodogram of a residual on the frame clock (`masked_fourier`'s |·|²): white
    noise gives Exp(1) powers.

    Returns (freq_hz (freq,), power (freq,)), frequencies k/(M dt) from 1/(M dt) to Nyquist,
    M = oversample × frames.
    """
    freq, coef = masked_fourier(ctx, i, r, oversample)
    return freq, coef.real**2 + coef.imag**2
