"""The open world of `jaxdefl diagnose` (issue 12.3): structure outside the vocabulary located and
modelled by generic terms (``unnamed``), gates from information rather than cycle counts, and
coloured-noise controls that stay quiet.

The two real-record stand-ins are simulated: a friction damper driven at 1 Hz for 7 s whose
amplitude ramps 3.4 → 12.8 → 3.4 mm (a 50-Hz displacement log), and a 0.25-s hammer record of a
beam at 10 kHz, a 240-Hz mode (ζ 1 %) and its 696-Hz bending mode (ζ 0.8 %), both dying away.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
from scipy import stats
from scipy.signal import lfilter

from jaxdefl.diagnose import build_context, diagnose
from jaxdefl.diagnose.detectors import load_detectors
from jaxdefl.diagnose.unnamed import ar1_loglik, ar1_rho

T0 = 1.7e9


def ar1(rng, n, rho, sigma):
    """AR(1) noise of marginal σ ``sigma``."""
    return lfilter([1.0], [1.0, -rho], rng.standard_normal(n) * sigma * math.sqrt(1 - rho**2))


def damper(seed, rho=0.5, sigma=0.3, fs=50.0, jitter_s=0.002):
    """7 s at 1 Hz, amplitude ramped linearly 3.4 → 12.8 → 3.4 mm; AR(1) noise, jittered clock."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 7.0, 1.0 / fs)
    env = 3.4 + (12.8 - 3.4) * (1.0 - np.abs(t - 3.5) / 3.5)
    tt = t + jitter_s * rng.standard_normal(t.size)  # the motion at the true acquisition times
    y = 40.0 + env * np.cos(2 * np.pi * 1.0 * tt + 0.3) + ar1(rng, t.size, rho, sigma)
    return pd.DataFrame({"t": T0 + t, "plate": 1, "z": y}), env


def mode(t, f, zeta, a, phase):
    wn = 2 * np.pi * f / math.sqrt(1 - zeta**2)
    return a * np.exp(-zeta * wn * t) * np.cos(2 * np.pi * f * t + phase)


def hammer(seed, sigma=0.002, rho=0.3):
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 0.25, 1e-4)
    y = 0.2 + mode(t, 240.0, 0.010, 0.12, 0.2) + mode(t, 696.0, 0.008, 0.05, 0.7)
    return pd.DataFrame({"t": T0 + t, "plate": 1, "z": y + ar1(rng, t.size, rho, sigma)})


@pytest.mark.parametrize("seed", [1, 2])
def test_the_dampers_envelope_is_modelled_and_halves_the_rms(seed):
    traj, env = damper(seed)
    d = diagnose(traj)
    assert d["effects"] == []  # no vocabulary name for a test rig's load ramp
    (u,) = [u for u in d["unnamed"] if u["kind"] == "envelope"]
    assert u["delta_bic"] < -10 and u["plates"] == [1] and u["axes"] == ["z"]
    assert u["rms_after_mm"] <= 0.5 * u["rms_before_mm"]
    assert d["final"]["rms_mm"] <= 0.5 * d["nominal"]["rms_mm"]
    # the envelope's swing, relative to the nominal amplitude: 12.8 / 3.4
    par = u["parameters"]
    ratio = par["envelope_max"]["value"] / par["envelope_min"]["value"]
    assert ratio == pytest.approx(12.8 / 3.4, rel=0.2)
    assert "no named effect" in u["explanation"]


def test_the_hammer_records_modes_and_damping_are_found():
    d = diagnose(hammer(3))
    assert d["effects"] == []
    # a free decay is recognised before anything is named: its damped modes are the nominal model
    assert d["record_kind"] == "free_decay"
    (bend,) = [m for m in d["record"]["modes"] if abs(m["freq_hz"] - 696.0) < 1.0]
    assert bend["damping_ratio"] == pytest.approx(0.008, rel=0.1)
    assert bend["amplitude_at_start"] == pytest.approx(0.05, rel=0.1)
    (first,) = [m for m in d["record"]["modes"] if abs(m["freq_hz"] - 240.0) < 1.0]
    assert first["damping_ratio"] == pytest.approx(0.010, rel=0.1)
    assert d["input"]["f0_hz"] == pytest.approx(240.0, abs=0.5)
    assert d["final"]["rms_mm"] < 1.5 * 0.002 * 1.0  # down to the noise


@pytest.mark.parametrize(
    "rho, seconds, fs, seed",
    [
        (0.3, 7.0, 50.0, 11),
        (0.8, 7.0, 50.0, 12),
        pytest.param(0.6, 120.0, 20.0, 13, marks=pytest.mark.slow),
        pytest.param(0.8, 300.0, 20.0, 14, marks=pytest.mark.slow),
    ],
)
def test_coloured_noise_controls_stay_quiet(rho, seconds, fs, seed):
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, seconds, 1.0 / fs)
    rows = []
    for p in (1, 2, 3):
        y = 10.0 + 2.0 * p * np.cos(2 * np.pi * 1.3 * t + p) + ar1(rng, t.size, rho, 0.4)
        rows.append(pd.DataFrame({"t": T0 + t, "plate": p, "z": y}))
    d = diagnose(pd.concat(rows, ignore_index=True))
    assert d["effects"] == [] and d["unnamed"] == [], (d["effects"], d["unnamed"])


def test_ar1_likelihood_agrees_with_the_full_covariance():
    # the exact AR(1) likelihood with gaps against scipy's multivariate normal, σ profiled
    rng = np.random.default_rng(5)
    k = np.sort(rng.choice(400, size=150, replace=False))
    rho = 0.6
    r = ar1(rng, 400, rho, 1.3)[k]
    lag = np.abs(k[:, None] - k[None, :])
    corr = rho**lag / (1 - rho**2)  # in units of the innovation variance
    s2 = float(r @ np.linalg.solve(corr, r) / r.size)
    ref = stats.multivariate_normal(mean=np.zeros(r.size), cov=s2 * corr).logpdf(r)
    assert ar1_loglik(r, k, rho) == pytest.approx(ref, rel=1e-9)
    white = ar1_loglik(r, k, 0.0)
    assert white == pytest.approx(stats.norm(0, math.sqrt(np.mean(r**2))).logpdf(r).sum(), rel=1e-9)


@pytest.mark.parametrize("rho", [0.0, 0.3, 0.8])
def test_ar1_rho_from_differences_ignores_slow_structure(rho):
    rng = np.random.default_rng(int(10 * rho) + 1)
    n = 20000
    k = np.arange(n)
    slow = 3.0 * np.sin(2 * np.pi * k / n)  # a drift ten times the noise
    est = ar1_rho(ar1(rng, n, rho, 0.3) + slow, k)
    assert est == pytest.approx(rho, abs=0.03)


def test_gates_follow_snr_and_samples_not_cycles():
    # the same 12-s record (37 cycles): a plausible distortion (1 % of the motion) or drift (1 mm
    # in 10 minutes) is out of reach at 0.5 mm of noise and told at 0.02 mm
    rng = np.random.default_rng(9)
    t = np.arange(0.0, 12.0, 1.0 / 30)
    effects = load_detectors()
    why = {}
    for sigma in (0.5, 0.02):
        rows = [
            pd.DataFrame(
                {
                    "t": T0 + t,
                    "plate": p,
                    "z": 3.0 * np.cos(2 * np.pi * 3.07 * t) + sigma * rng.standard_normal(t.size),
                }
            )
            for p in (1, 2, 3)
        ]
        ctx, _, _ = build_context(pd.concat(rows, ignore_index=True))
        assert ctx.noise_sigma(0) == pytest.approx(sigma, rel=0.15)
        why[sigma] = {e: eff.cannot_tell(ctx) for e, eff in effects.items()}
    assert "not enough evidence" in why[0.5]["harmonic_distortion"]
    assert why[0.02]["harmonic_distortion"] is None
    assert "not enough evidence" in why[0.5]["drift"]  # 1 mm in 10 min: 0.02 mm in 12 s
    assert why[0.02]["drift"] is None  # ... which 0.02-mm noise can tell


def _bench():
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "experiments" / "concealed_effects.py"
    spec = importlib.util.spec_from_file_location("concealed_effects", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_held_out_mode_plans_and_scores_unnamed_modelling():
    bench = _bench()
    plan = bench.plan_cases(3, 4, seed=2, held_out="drift", ar1_controls=0.5)
    assert [p["effects"] for p in plan[:3]] == [["drift"]] * 3
    assert all(p["held_out"] == "drift" for p in plan)
    rhos = [p.get("ar1_rho") for p in plan[3:]]
    assert sum(r is not None for r in rhos) == 2 and all(0.3 <= r <= 0.8 for r in rhos if r)
    calls = []

    def stand_in(traj, reference=None, **kw):
        calls.append(kw)
        return {"effects": [], "unnamed": []}

    truth_rec = {"frame_rate_hz": 20.0}
    bench._blind_call(stand_in, None, None, {"sensor": "tof", **truth_rec}, "drift")
    assert "drift" not in calls[0]["effects"] and len(calls[0]["effects"]) == len(bench.EFFECT_IDS) - 1
    injected = {"id": "drift", "plates": [1, 2, 3, 4]}
    strong = {"delta_bic": -40.0, "plates": [2, 3, 4]}
    assert bench.unnamed_located(injected, [strong])
    assert not bench.unnamed_located(injected, [dict(strong, delta_bic=-5.0)])  # too weak
    assert not bench.unnamed_located(injected, [dict(strong, plates=[4, 9])])  # elsewhere


def test_ar1_controls_are_coloured():
    bench = _bench()
    rng = np.random.default_rng(0)
    t = 1.7e9 + np.arange(6000) / 20.0
    traj = pd.DataFrame({"t": t, "plate": 1, "x": 0.0, "y": 0.0, "z": 0.0})
    truth = {"recording": {"frame_rate_hz": 20.0, "t_first": t[0], "noise_mm": {a: [0.5] for a in "xyz"}}}
    out = bench.add_ar1_noise(traj, truth, 0.6, seed=int(rng.integers(1000)))
    z = out["z"].to_numpy()
    assert np.std(z) == pytest.approx(1.0, rel=0.1)  # twice the white σ
    assert np.corrcoef(z[1:], z[:-1])[0, 1] == pytest.approx(0.6, abs=0.05)


def _line_fit(traj, corr=None):
    """The unnamed line on a record's nominal residual, refined, with its σ's (`term_sigmas`)."""
    from jaxdefl.diagnose.unnamed import best_term, term_sigmas

    ctx, nominal, _ = build_context(traj)
    d, c = best_term(ctx, nominal, corr, kinds=("line",))
    return ctx, nominal, c, term_sigmas(ctx, nominal, c, corr)


@pytest.mark.slow
@pytest.mark.parametrize("rho, n_cases", [(0.0, 40), (0.6, 40)])
def test_an_unnamed_lines_sigmas_cover_the_truth(rho, n_cases):
    # a 2.37-Hz line of 0.08 mm beside a 1.1-Hz loading, white or AR(1) noise of 0.1 mm on a
    # jittered clock with drop-outs: the 95 % intervals of frequency and amplitude cover the
    # truth in 90-99 % of the cases (the white-noise σ would cover ~70 % under ρ = 0.6)
    f1, a1 = 2.37, 0.08
    hits = {"freq_hz": 0, "amplitude_mm": 0}
    for seed in range(n_cases):
        rng = np.random.default_rng([seed, int(10 * rho)])
        t = np.arange(0.0, 60.0, 1.0 / 30)
        keep = rng.random(t.size) > 0.05
        tt = t + 0.002 * rng.standard_normal(t.size)
        y = 20.0 + 4.0 * np.cos(2 * np.pi * 1.1 * tt) + a1 * np.cos(2 * np.pi * f1 * tt + rng.uniform(0, 6.3))
        y = y + ar1(rng, t.size, rho, 0.1)
        traj = pd.DataFrame({"t": T0 + t[keep], "plate": 1, "z": y[keep]})
        ctx, nominal, c, sig = _line_fit(traj)
        f, (amp,) = c.info["freq_hz"], c.info["amplitudes_mm"].values()
        hits["freq_hz"] += abs(f - f1) < 1.96 * sig["freq_hz"]
        hits["amplitude_mm"] += abs(amp - a1) < 1.96 * sig["amplitudes_mm"][c.series[0]]
    for name, h in hits.items():
        assert 0.90 * n_cases <= h <= 0.99 * n_cases + 1, (name, h)


def test_an_unnamed_lines_sigmas_agree_with_curve_fit():
    # white noise: the GLS σ's equal scipy's curve_fit (absolute_sigma off) on the same residual
    from scipy.optimize import curve_fit

    rng = np.random.default_rng(4)
    t = np.arange(0.0, 40.0, 1.0 / 25)
    y = 5.0 + 3.0 * np.cos(2 * np.pi * 0.9 * t) + 0.1 * np.sin(2 * np.pi * 3.3 * t + 1.0)
    traj = pd.DataFrame({"t": T0 + t, "plate": 1, "z": y + 0.08 * rng.standard_normal(t.size)})
    ctx, nominal, c, sig = _line_fit(traj)
    i = c.series[0]
    s = ctx.series[i]
    r = s.y - nominal[i].mean

    def model(tt, f, a, b, o):
        return a * np.cos(2 * np.pi * f * tt) + b * np.sin(2 * np.pi * f * tt) + o

    p, cov = curve_fit(model, s.t, r, p0=[c.info["freq_hz"], 0.05, 0.05, 0.0])
    assert p[0] == pytest.approx(c.info["freq_hz"], abs=0.05 * math.sqrt(cov[0, 0]))
    assert sig["freq_hz"] == pytest.approx(math.sqrt(cov[0, 0]), rel=0.03)
    amp = math.hypot(p[1], p[2])
    g = np.array([p[1], p[2]]) / amp
    assert sig["amplitudes_mm"][i] == pytest.approx(math.sqrt(g @ cov[1:3, 1:3] @ g), rel=0.03)


def test_a_held_out_jump_under_common_noise_is_modelled_unnamed_not_named_a_drift():
    # a 0.25-mm step on all six plates at 70 s, noise 70 % common to the frame: with level_jump
    # out of the registry, the step is an unnamed trend common to the plates, with its σ's, and
    # drift (which can bend an exponential into a step) claims nothing; with level_jump in the
    # registry the generic step (the same fit, the same parameters) does not take it first
    from jaxdefl.diagnose.detectors import EFFECT_IDS

    rng = np.random.default_rng(21)
    t = np.arange(0.0, 150.0, 1.0 / 20)
    common = 0.1 * rng.standard_normal(t.size)
    rows = []
    for p in range(1, 7):
        own = 0.065 * rng.standard_normal(t.size)
        y = 30.0 + (1.0 + 0.3 * p) * np.cos(2 * np.pi * 2.1 * t + p) + 0.25 * (t > 70.0) + common + own
        rows.append(pd.DataFrame({"t": T0 + t, "plate": p, "z": y}))
    traj = pd.concat(rows, ignore_index=True)
    full = diagnose(traj)  # with the whole registry the step is the named level jump
    assert [e["id"] for e in full["effects"]] == ["level_jump"] and full["unnamed"] == []
    d = diagnose(traj, effects=tuple(e for e in EFFECT_IDS if e != "level_jump"))
    assert d["effects"] == [], d["effects"]
    (u,) = d["unnamed"]
    assert u["kind"] == "trend" and u["plates"] == [1, 2, 3, 4, 5, 6] and u["delta_bic"] < -10
    par = u["parameters"]
    assert par["form"] == "common" and par["step_at_s"]["value"] == pytest.approx(70.0, abs=1.0)
    assert abs(par["swing_mm"]["value"] - 0.25) < 3 * par["swing_mm"]["sigma"] < 0.1


def test_a_held_out_camera_shake_is_one_common_trend_at_fine_knots_not_named_lines():
    # a 0.3-mm RMS first-order low-pass sway (corner 0.02 Hz) of the camera, the same on six
    # plates, 150 s at 20 Hz: with camera_shake out of the registry it is one unnamed trend common
    # to the plates at knots finer than the per-series grid (12 knots left its faster part to
    # named extra_periodic lines, level jumps and a drift), and no vocabulary name
    from jaxdefl.diagnose.detectors import EFFECT_IDS
    from jaxdefl.diagnose.unnamed import KNOTS

    rng = np.random.default_rng(1)
    t = np.arange(0.0, 150.0, 1.0 / 20)
    u = lfilter([1.0], [1.0, -math.exp(-2 * math.pi * 0.02 / 20)], rng.standard_normal(t.size))
    u = 0.3 * (u - u.mean()) / u.std()
    rows = []
    for p in range(1, 7):
        y = 30.0 + (1.0 + 0.3 * p) * np.cos(2 * np.pi * 2.1 * t + p) + u + 0.3 * rng.standard_normal(t.size)
        rows.append(pd.DataFrame({"t": T0 + t, "plate": p, "z": y}))
    traj = pd.concat(rows, ignore_index=True)
    d = diagnose(traj, effects=tuple(e for e in EFFECT_IDS if e != "camera_shake"))
    assert d["effects"] == [], [e["id"] for e in d["effects"]]
    (term,) = d["unnamed"]
    par = term["parameters"]
    assert term["kind"] == "trend" and par["form"] == "common" and par["knots"] > max(KNOTS)
    assert term["plates"] == [1, 2, 3, 4, 5, 6] and term["delta_bic"] < -10
    swing = par["swing_mm"]
    assert 0 < swing["sigma"] < 0.1 and swing["value"] == pytest.approx(np.ptp(u), rel=0.15)


@pytest.mark.parametrize("sparse", [False, True])
def test_shared_fit_equals_one_joint_weighted_least_squares(sparse):
    """`unnamed.terms.shared_fit` (shared columns with each series' nuisance profiled out) gives the
    coefficients and means of one weighted least squares over all series at once, with the
    shared columns and a block of nuisance columns per series (a slow dense reference); dense
    and sparse (B-spline) columns alike."""
    from types import SimpleNamespace

    from scipy import sparse as sps

    from jaxdefl.diagnose.unnamed.terms import bspline, shared_fit

    rng = np.random.default_rng(4)
    series, states, nus = [], [], []
    for n in (400, 530, 470):
        t = np.sort(rng.uniform(0, 60, n))
        nu = np.stack([np.ones(n), np.cos(2 * np.pi * t), np.sin(2 * np.pi * t)], axis=1)
        y = rng.normal(size=n) + 0.3 * np.sin(t / 9)
        scale = rng.uniform(0.5, 2.0, n)
        inlier = rng.uniform(size=n) > 0.05
        series.append(SimpleNamespace(t=t, y=y))
        states.append(SimpleNamespace(mean=0.1 * nu[:, 1], scale=scale, inlier=inlier))
        nus.append(nu)
    sigma = [1.3, 0.7, 1.1]
    ctx = SimpleNamespace(series=series, nuisance=lambda i: nus[i], noise_sigma=lambda i: sigma[i])

    def cols_of(i):
        return bspline(series[i].t, 0.0, 60.0, 6, sparse=sparse)[:, 1:]

    beta, means, gammas = shared_fit(ctx, states, [0, 1, 2], cols_of)

    # the reference: one stacked design, shared columns then each series' own nuisance block
    k, p = cols_of(0).shape[1], 3
    rows, rhs, wts = [], [], []
    for i in range(3):
        x = cols_of(i)
        x = x.toarray() if sps.issparse(x) else x
        own = np.zeros((x.shape[0], 3 * p))
        own[:, i * p : (i + 1) * p] = nus[i]
        rows.append(np.concatenate([x, own], axis=1))
        rhs.append(series[i].y - states[i].mean)
        wts.append(np.where(states[i].inlier, 1.0 / states[i].scale ** 2, 0.0) / sigma[i] ** 2)
    a, r, w = np.concatenate(rows), np.concatenate(rhs), np.concatenate(wts)
    sw = np.sqrt(w)
    ref = np.linalg.lstsq(a * sw[:, None], r * sw, rcond=None)[0]
    np.testing.assert_allclose(beta, ref[:k], rtol=1e-8, atol=1e-10)
    for i in range(3):
        np.testing.assert_allclose(gammas[i], ref[k + i * p : k + (i + 1) * p], rtol=1e-8, atol=1e-10)
        x = cols_of(i)
        fitted = np.asarray(x @ ref[:k]).ravel() + nus[i] @ ref[k + i * p : k + (i + 1) * p]
        np.testing.assert_allclose(means[i], states[i].mean + fitted, rtol=1e-8, atol=1e-10)
