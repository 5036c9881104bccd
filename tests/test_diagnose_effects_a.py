"""Effects harmonic_distortion, drift, level_jump, outliers, heteroscedastic_noise, quantization:
each one found on the series it was injected into, below the noise, with its parameters within
25 %, and nothing that would pass the search's gates on clean series."""

from __future__ import annotations

import math

import numpy as np
import pytest

from jaxdefl._numerics import wls
from jaxdefl.diagnose import Context, Harmonic, Series, State, loglik
from jaxdefl.diagnose._search import Calibration

F0 = 3.0
OMEGA = 2 * math.pi * F0
PHASE = 1.1  # the motion's phase: clean = level + A cos(ω t − PHASE)
N_TESTS = 11  # effects screened: the search's calibrated test splits α over them


def make_case(
    inject=None,
    n_plates=4,
    minutes=10.0,
    fs=20.0,
    sigma=0.76,
    seed=0,
    axes=("z", "x"),
    amplitude=3.0,
    base_z=2000.0,
    dropout=0.03,
    phase=PHASE,
):
    """A hand-built context: harmonic + white noise per plate and axis, with ``inject(t, p, axis,
    clean, eps, sigma) -> y`` changing what it wants; the nominal harmonic is linear LS at f0."""
    rng = np.random.default_rng(seed)
    dt = 1.0 / fs
    n_frames = int(minutes * 60 * fs)
    k_all = np.arange(n_frames)
    series, nominal, states = [], [], []
    duration = (n_frames - 1) * dt
    t_ref = 0.5 * duration
    for p in range(1, n_plates + 1):
        keep = rng.random(n_frames) >= dropout
        k = k_all[keep]
        t = k * dt
        for axis in axes:
            amp = (
                amplitude
                * (0.6 + 0.4 * math.sin(math.pi * p / (n_plates + 1)))
                * (1.0 if axis == "z" else 0.3)
            )
            level = base_z + 10.0 * p if axis == "z" else 100.0 * p
            clean = level + amp * np.cos(OMEGA * t - phase)
            eps = rng.standard_normal(t.size)
            sig = sigma if axis == "z" else 0.4 * sigma
            y = clean + sig * eps if inject is None else inject(t, p, axis, clean, eps, sig)
            a = OMEGA * (t - t_ref)
            beta, _, _ = wls(np.stack([np.ones_like(t), np.cos(a), np.sin(a)], axis=1), y)
            h = Harmonic(OMEGA, float(beta[1]), float(beta[2]), float(beta[0]), t_ref)
            series.append(Series(p, axis, t, y, k))
            nominal.append(h)
            states.append(State(mean=h(t), scale=np.ones(t.size), inlier=np.ones(t.size, bool)))
    ctx = Context(
        series=series,
        nominal=nominal,
        free=list(nominal),
        reference={},
        reference_harmonic={},
        t0=0.0,
        duration_s=duration,
        dt_s=dt,
        n_frames=n_frames,
        f0_hz=F0,
        frame_rate_hz=fs,
    )
    return ctx, states


def total_gain(ctx, states, prop):
    return sum(
        loglik(ctx.series[i].y, st) - loglik(ctx.series[i].y, states[i]) for i, st in prop.states.items()
    )


def delta_bic(ctx, states, prop):
    n = sum(s.n for s in ctx.series)  # the whole record: the most demanding penalty
    return -2.0 * total_gain(ctx, states, prop) + prop.n_params * math.log(n)


def passing(ctx, states, props):
    """The proposals the search's calibrated test accepts (white noise: LR = 2 Δlog L)."""
    cal = Calibration(N_TESTS)
    return [p for p in props if cal.passes(p, 2.0 * total_gain(ctx, states, p), 1.0, 0.0)]


def keys(ctx, prop):
    return sorted(ctx.series[i].key for i in prop.series)


def value(prop, name):
    return prop.parameters[name]["value"]


def close(a, b, tol=0.25):
    return abs(a - b) <= tol * abs(b)


# ---------------------------------------------------------------------------------------------
# harmonic_distortion


def test_harmonic_distortion_found_on_its_plates():
    from jaxdefl.diagnose.detectors.harmonic_distortion import EFFECT

    def inject(t, p, axis, clean, eps, sig):
        y = clean + sig * eps
        if axis == "z" and p in (2, 3):
            y = y + 0.2 * np.cos(2 * OMEGA * t - 1.0)
        return y

    ctx, states = make_case(inject, seed=1)
    good = passing(ctx, states, EFFECT.propose(ctx, states))
    per = [p for p in good if p.detail["mode"] == "per_series"]
    assert len(per) == 1 and per[0].n_params == 4
    for prop in (per[0], min(good, key=lambda p: delta_bic(ctx, states, p))):
        assert keys(ctx, prop) == ["2z", "3z"]
        assert value(prop, "order") == 2
        assert close(value(prop, "amplitude_mm"), 0.2)


def test_harmonic_distortion_common_to_all_plates():
    from jaxdefl.diagnose.detectors.harmonic_distortion import EFFECT

    def inject(t, p, axis, clean, eps, sig):
        y = clean + sig * eps
        return y + 0.04 * np.cos(3 * OMEGA * t - 2.0) if axis == "z" else y

    ctx, states = make_case(inject, seed=7, n_plates=5)
    good = passing(ctx, states, EFFECT.propose(ctx, states))
    best = min(good, key=lambda p: delta_bic(ctx, states, p))
    assert best.detail["mode"] == "common"
    assert keys(ctx, best) == [f"{p}z" for p in range(1, 6)]
    assert value(best, "order") == 3
    assert close(value(best, "amplitude_mm"), 0.04)
    assert best.n_params == 2


def test_harmonic_distortion_clean():
    from jaxdefl.diagnose.detectors.harmonic_distortion import EFFECT

    for seed in range(3):
        ctx, states = make_case(seed=10 + seed, n_plates=5)
        assert passing(ctx, states, EFFECT.propose(ctx, states)) == []


# ---------------------------------------------------------------------------------------------
# drift


@pytest.mark.parametrize("amp, tau", [(0.25, 120.0), (-0.4, 300.0)])
def test_drift_exponential(amp, tau):
    from jaxdefl.diagnose.detectors.drift import EFFECT

    def inject(t, p, axis, clean, eps, sig):
        y = clean + sig * eps
        return y + amp * np.exp(-t / tau) if axis == "z" else y

    ctx, states = make_case(inject, seed=2, n_plates=5)
    props = EFFECT.propose(ctx, states)
    good = passing(ctx, states, props)
    assert good
    best = min(good, key=lambda p: delta_bic(ctx, states, p))
    assert value(best, "kind") == "exponential"
    assert close(value(best, "tau_s"), tau, 0.4)  # the grid's estimate, before the refit
    best = best.refine()  # what the search does before accepting it
    assert passing(ctx, states, [best])
    assert keys(ctx, best) == [f"{p}z" for p in range(1, 6)]
    assert close(value(best, "amplitude_mm"), amp)
    assert close(value(best, "tau_s"), tau)


def test_drift_clean():
    from jaxdefl.diagnose.detectors.drift import EFFECT

    for seed in range(3):
        ctx, states = make_case(seed=20 + seed, n_plates=5)
        assert passing(ctx, states, EFFECT.propose(ctx, states)) == []


# ---------------------------------------------------------------------------------------------
# level_jump


@pytest.mark.parametrize("plates, size, t_j", [((1, 2, 3, 4, 5), 0.15, 250.0), ((3,), -0.3, 420.0)])
def test_level_jump(plates, size, t_j):
    from jaxdefl.diagnose.detectors.level_jump import EFFECT

    def inject(t, p, axis, clean, eps, sig):
        y = clean + sig * eps
        return y + size * (t >= t_j) if axis == "z" and p in plates else y

    ctx, states = make_case(inject, seed=3, n_plates=5)
    good = passing(ctx, states, EFFECT.propose(ctx, states))
    prop = min(good, key=lambda p: delta_bic(ctx, states, p))
    assert prop.detail["mode"] == ("common" if len(plates) > 1 else "per_series")
    assert keys(ctx, prop) == [f"{p}z" for p in plates]
    assert abs(value(prop, "t_jump_s") - t_j) < 2.0
    assert close(value(prop, "size_mm"), size)


@pytest.mark.parametrize("seed", [6, 34])
def test_level_jump_on_one_plate_among_many_stays_there(seed):
    """A 0.25-mm jump on one plate of twelve (24 series): the other series, fitted at its split,
    pass the plain BIC now and then (χ²₁ > log n: 0.2 % each); paying for being chosen among
    the series keeps the jump on its plate and its size that plate's."""
    from jaxdefl.diagnose.detectors.level_jump import EFFECT

    def inject(t, p, axis, clean, eps, sig):
        y = clean + sig * eps
        return y + 0.25 * (t >= 380.0) if axis == "z" and p == 7 else y

    ctx, states = make_case(inject, seed=seed, n_plates=12)
    good = passing(ctx, states, EFFECT.propose(ctx, states))
    prop = min(good, key=lambda p: delta_bic(ctx, states, p))
    assert keys(ctx, prop) == ["7z"]
    assert close(value(prop, "size_mm"), 0.25)


def test_level_jump_common_below_each_plate():
    """0.06 mm on every plate: ~12 χ² units each, too little alone, plenty together."""
    from jaxdefl.diagnose.detectors.level_jump import EFFECT

    def inject(t, p, axis, clean, eps, sig):
        y = clean + sig * eps
        return y - 0.06 * (t >= 333.3) if axis == "z" else y

    ctx, states = make_case(inject, seed=8, n_plates=6)
    good = passing(ctx, states, EFFECT.propose(ctx, states))
    prop = min(good, key=lambda p: delta_bic(ctx, states, p))
    assert prop.detail["mode"] == "common" and prop.n_params == 2
    assert len(prop.series) >= 5 and all(ctx.series[i].axis == "z" for i in prop.series)
    sig_t = prop.parameters["t_jump_s"]["sigma"]
    assert 1.0 < sig_t < 20.0 and abs(value(prop, "t_jump_s") - 333.3) < 4 * sig_t
    assert close(value(prop, "size_mm"), -0.06)


def test_level_jump_clean():
    from jaxdefl.diagnose.detectors.level_jump import EFFECT

    for seed in range(3):
        ctx, states = make_case(seed=30 + seed, n_plates=5)
        assert passing(ctx, states, EFFECT.propose(ctx, states)) == []


# ---------------------------------------------------------------------------------------------
# extra_periodic


def test_extra_periodic_amplitude_is_the_depth_axis():
    """A vibration at 4.1 Hz, 0.3 mm along z and 0.1 mm along x on every plate: the reported
    amplitude is the z series' (a median over both axes, 0.2 mm, described neither)."""
    from jaxdefl.diagnose.detectors.extra_periodic import EFFECT

    def inject(t, p, axis, clean, eps, sig):
        a = 0.3 if axis == "z" else 0.1
        return clean + sig * eps + a * np.cos(2 * np.pi * 4.1 * t + 0.7)

    ctx, states = make_case(inject, seed=12, n_plates=5)
    good = passing(ctx, states, EFFECT.propose(ctx, states))
    (prop,) = [p for p in good if p.detail.get("mode") != "common"]  # amplitudes per series
    assert {ctx.series[i].axis for i in prop.series} == {"z", "x"}
    assert close(value(prop, "freq_hz"), 4.1, 0.001)
    assert close(value(prop, "amplitude_mm"), 0.3, 0.1)
    assert close(prop.detail["median_amplitude_by_axis_mm"]["x"], 0.1, 0.25)
    # and one amplitude shared by the plates of each axis
    common = {p.detail["amplitude_axis"]: p for p in good if p.detail.get("mode") == "common"}
    assert sorted(common) == ["x", "z"] and all(p.n_params == 3 for p in common.values())
    assert close(value(common["z"], "amplitude_mm"), 0.3, 0.1)
    assert close(value(common["x"], "amplitude_mm"), 0.1, 0.25)


# ---------------------------------------------------------------------------------------------
# outliers


@pytest.mark.parametrize("kind", ["gaussian", "sign"])
def test_outliers(kind):
    from jaxdefl.diagnose.detectors.outliers import EFFECT

    frac, scale = 0.005, 5.0 * 0.76
    hit = {}

    def inject(t, p, axis, clean, eps, sig):
        y = clean + sig * eps
        if axis == "z" and p in (2, 4):
            rng = np.random.default_rng(p)
            rows = rng.choice(t.size, size=int(round(frac * t.size)), replace=False)
            err = scale * (
                rng.standard_normal(rows.size) if kind == "gaussian" else rng.choice([-1.0, 1.0], rows.size)
            )
            y[rows] += err
            hit[p] = rows
        return y

    ctx, states = make_case(inject, seed=4, n_plates=5)
    props = EFFECT.propose(ctx, states)
    assert len(passing(ctx, states, props)) == 1
    (prop,) = props
    assert keys(ctx, prop) == ["2z", "4z"]
    assert close(value(prop, "fraction"), frac)
    assert close(value(prop, "scale_mm"), scale)
    assert prop.n_params == 4


def test_outliers_clean():
    from jaxdefl.diagnose.detectors.outliers import EFFECT

    for seed in range(3):
        ctx, states = make_case(seed=40 + seed, n_plates=5)
        assert passing(ctx, states, EFFECT.propose(ctx, states)) == []


# ---------------------------------------------------------------------------------------------
# heteroscedastic_noise


@pytest.mark.parametrize("kind, m, plates", [("phase", 0.3, (2, 3)), ("time", -0.25, (1, 2, 3, 4, 5))])
def test_heteroscedastic_noise(kind, m, plates):
    from jaxdefl.diagnose.detectors.heteroscedastic_noise import EFFECT

    psi = 0.8

    def inject(t, p, axis, clean, eps, sig):
        if axis != "z" or p not in plates:
            return clean + sig * eps
        if kind == "phase":
            u = np.cos(OMEGA * t - PHASE - psi)
        else:
            u = (t - 0.5 * t[-1]) / (0.5 * t[-1])
        return clean + sig * (1 + m * u) * eps

    ctx, states = make_case(inject, seed=5, n_plates=5)
    props = EFFECT.propose(ctx, states)
    good = passing(ctx, states, props)
    best = min(good, key=lambda p: delta_bic(ctx, states, p))
    assert value(best, "kind") == kind
    assert keys(ctx, best) == [f"{p}z" for p in plates]
    assert close(value(best, "modulation"), m)
    if kind == "phase":
        assert abs(math.remainder(value(best, "phase_rad") - psi, 2 * math.pi)) < 0.3


def test_heteroscedastic_noise_clean():
    from jaxdefl.diagnose.detectors.heteroscedastic_noise import EFFECT

    for seed in range(3):
        ctx, states = make_case(seed=50 + seed, n_plates=5)
        assert passing(ctx, states, EFFECT.propose(ctx, states)) == []


# ---------------------------------------------------------------------------------------------
# quantization


@pytest.mark.parametrize("q, o", [(1.0, 0.37), (0.45, 0.1)])
def test_quantization(q, o):
    from jaxdefl.diagnose.detectors.quantization import EFFECT

    def inject(t, p, axis, clean, eps, sig):
        if axis == "z":
            clean = q * np.round((clean - o) / q) + o
        return clean + sig * eps

    ctx, states = make_case(inject, seed=6, n_plates=5)
    props = EFFECT.propose(ctx, states)
    assert len(passing(ctx, states, props)) == 1
    (prop,) = props
    assert keys(ctx, prop) == [f"{p}z" for p in range(1, 6)]
    assert close(value(prop, "step_mm"), q, 0.05)
    # the levels' absolute place needs q to ~1e-5 at 2 m: only its range is checked
    assert 0.0 <= value(prop, "offset_mm") < value(prop, "step_mm")


def test_quantization_clean():
    from jaxdefl.diagnose.detectors.quantization import EFFECT

    for seed in range(3):
        ctx, states = make_case(seed=60 + seed, n_plates=5)
        assert passing(ctx, states, EFFECT.propose(ctx, states)) == []


def test_smoothed_staircase_follows_a_stratified_noise_average():
    """E[round(x + sZ)] (a finite sum of Φ) against the slow reference: q·round averaged over
    400 000 noise values at the normal's quantiles; then its limits (s = 0: the hard staircase,
    s large: h) and the first harmonic's damping exp(−2π²s²)."""
    from scipy.special import ndtri

    from jaxdefl._lattice import dithered_round, smoothed_staircase

    q, o = 0.8, 0.23
    h = np.linspace(2000.0, 2003.0, 37)
    z = ndtri((np.arange(400_000) + 0.5) / 400_000)
    for dither in (0.01 * q, 0.1 * q, 0.25 * q, 0.5 * q, 1.2 * q):
        slow = np.array([np.mean(q * np.round((hk + dither * z - o) / q) + o) for hk in h])
        np.testing.assert_allclose(smoothed_staircase(h, q, o, dither), slow, atol=1e-3 * q)
    np.testing.assert_array_equal(smoothed_staircase(h, q, o, 0.0), q * np.round((h - o) / q) + o)
    np.testing.assert_allclose(smoothed_staircase(h, q, o, 3.0 * q), h, atol=1e-12)
    x = np.linspace(0.0, 1.0, 256, endpoint=False)
    for s in (0.2, 0.3):
        first = 2 * np.mean((dithered_round(x, s) - x) * np.sin(2 * np.pi * x))
        assert first == pytest.approx(-math.exp(-2 * math.pi**2 * s * s) / math.pi, rel=1e-3)


def _pixel_readings(q, o, pixels, seed):
    """Inject noise before rounding: each z the mean of ``pixels`` readings o + q·round((clean +
    e_i − o)/q), e_i iid N(0, pixels·σ²) (the unrounded mean has the series' σ)."""
    rng = np.random.default_rng(seed)

    def inject(t, p, axis, clean, eps, sig):
        if axis != "z":
            return clean + sig * eps
        e = sig * math.sqrt(pixels) * rng.standard_normal((t.size, pixels))
        return np.mean(q * np.round((clean[:, None] + e - o) / q) + o, axis=1)

    return inject


def test_quantization_with_noise_before_rounding():
    """σ_d/q = 0.25 (4 pixels of 1.52 mm, centroid σ 0.76 mm, q = 6 mm): the first harmonic is
    30 % of the hard staircase's, so the hard model is far off. The smoothed staircase is found on
    every z series, its step and dither recovered, and it fits better than the best hard
    staircase (which the search would not even propose)."""
    from jaxdefl.diagnose.detectors.quantization import EFFECT, Quantization, staircase

    q, o, pixels = 6.0, 0.37, 4
    dither = 0.76 * math.sqrt(pixels)
    ctx, states = make_case(_pixel_readings(q, o, pixels, 3), seed=7, n_plates=5, amplitude=6.0)
    props = EFFECT.propose(ctx, states)
    assert len(passing(ctx, states, props)) == 1
    (prop,) = props
    assert keys(ctx, prop) == [f"{p}z" for p in range(1, 6)]
    assert close(value(prop, "step_mm"), q, 0.03)
    assert close(value(prop, "dither_mm"), dither, 0.25)
    hard = Quantization()
    hard.dithers = (0.0,)
    gain_hard = max((total_gain(ctx, states, p) for p in hard.propose(ctx, states)), default=0.0)
    assert total_gain(ctx, states, prop) > gain_hard + 20.0
    # even at the true step and levels, the hard staircase of the nominal fits worse than no
    # staircase at all, the smoothed one better
    rss = {}
    for d in (None, 0.0, dither):
        rss[d] = 0.0
        for i in (i for i, s in enumerate(ctx.series) if s.axis == "z"):
            h = states[i].mean
            r = ctx.series[i].y - (h if d is None else staircase(h, q, o, d))
            rss[d] += float(np.sum((r - r.mean()) ** 2))
    assert rss[dither] < 0.97 * rss[None] < 0.97 * rss[0.0]


def test_quantization_does_not_depend_on_the_sensor_hint():
    """The same pixel-quantised data with the hint saying ToF: still found, alike."""
    import dataclasses

    from jaxdefl.diagnose.detectors.quantization import EFFECT

    ctx, states = make_case(_pixel_readings(6.0, 0.37, 4, 3), seed=7, n_plates=5, amplitude=6.0)
    ref = EFFECT.propose(ctx, states)
    for sensor in ("tof", "structured_light"):
        tof = dataclasses.replace(ctx, sensor=sensor)
        props = EFFECT.propose(tof, states)
        assert len(passing(tof, states, props)) == 1
        assert value(props[0], "step_mm") == value(ref[0], "step_mm")


def test_quantization_not_taken_from_coloured_noise():
    """Smooth data, AR(1) noise (ρ 0.3-0.8), no quantization: nothing passes."""
    from jaxdefl.diagnose.detectors.quantization import EFFECT

    for seed, rho in enumerate((0.3, 0.6, 0.8)):

        def inject(t, p, axis, clean, eps, sig, rho=rho):
            from scipy.signal import lfilter

            e = lfilter([math.sqrt(1 - rho * rho)], [1.0, -rho], eps)
            return clean + sig * e

        ctx, states = make_case(inject, seed=70 + seed, n_plates=5)
        assert passing(ctx, states, EFFECT.propose(ctx, states)) == []


def test_strided_running_median_follows_the_exact_one_on_a_coloured_spectrum():
    """`local_median` takes the window's median every width/32 bins and interpolates: against the
    exact running median (a slow numpy version) on a red spectrum with excluded bands, the
    difference stays within the median's own sampling noise (~9 % for 201 Exp(1) values)."""
    import warnings

    from jaxdefl.diagnose.detectors.extra_periodic import local_median

    def exact(x, width=201):
        pad = width // 2
        xp = np.concatenate([np.full(pad, np.nan), x, np.full(pad, np.nan)])
        win = np.lib.stride_tricks.sliding_window_view(xp, width)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            med = np.nanmedian(win, axis=1)
        ok = (np.sum(np.isfinite(win), axis=1) >= width // 4) & np.isfinite(med)
        return np.where(ok, med, np.nanmedian(x))[: x.size]

    rng = np.random.default_rng(3)
    f = np.linspace(0.01, 15.0, 30_000)
    x = rng.exponential(1.0, f.size) * (1.0 + 3.0 / np.sqrt(f))
    x[(np.abs(f - 3.07) < 0.2) | (np.abs(f - 6.14) < 0.2)] = np.nan
    r = np.abs(local_median(x) / exact(x) - 1.0)
    assert np.median(r) < 0.01 and np.quantile(r, 0.99) < 0.08
    flat = rng.exponential(1.0, 5_000)
    assert np.allclose(local_median(flat, width=21), exact(flat, width=21))  # a step of 1 bin: exact
