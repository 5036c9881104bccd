"""The camera's sampling and measurement effects (issue 24) against independent references: a
ToF camera's taps read a harmonic motion through the thesis' response (`fit.motion`), a lattice
rounds the noisy reading and its mean is the dither-smoothed staircase, a noise level with the
motion is what the diagnosis' likelihood estimates, and a report of either kind is simulated as
its detector parametrises it."""

from __future__ import annotations

import math

import numpy as np
import pytest

from jaxdefl._lattice import dithered_round_var, smoothed_staircase
from jaxdefl.effects import REGISTRY, Report
from jaxdefl.simulate.injection import make_spec, measurement_faults, sampled


def test_a_tof_camera_s_taps_read_a_harmonic_through_the_thesis_response():
    """The mean of the positions at 0, T/4, T/2, 3T/4 after the frame time is |H| cos(ωt + arg H),
    H of `fit.motion.motion_artefact_response` (eq. 5.51, taps over one frame period T)."""
    from jaxdefl.fit.motion import motion_artefact_response

    f0, tap = 3.07, 0.05
    t = np.linspace(0.0, 20.0, 4001)
    spec = make_spec("motion_artefact", {"tap_spread_s": tap})
    got = sampled((spec,), t, 0.0, lambda tt: np.cos(2 * math.pi * f0 * tt))
    gain, lag = motion_artefact_response(f0, 1.0 / tap)
    np.testing.assert_allclose(got, gain * np.cos(2 * math.pi * f0 * t + lag), atol=1e-12)
    assert 0.95 < gain < 0.97  # the thesis' 3.5 % at 3 Hz and 20 Hz frames


def _reading(n: int, plates: int, sigma: float, seed: int = 0):
    rng = np.random.default_rng(seed)
    z = rng.uniform(1000.0, 1010.0, plates)[None, :] * np.ones((n, 1))
    xyz = np.stack([np.zeros((n, plates)), np.ones((n, plates)), z], axis=-1)
    noise = sigma * rng.standard_normal((n, plates, 3))
    return xyz, noise


def test_a_lattice_rounds_the_noisy_reading():
    """With its noise before the rounding (the default), a reading is o + q round((z + e − o)/q);
    the plates not listed and x, y are left alone."""
    xyz, noise = _reading(500, 4, 0.4)
    want = 0.3 + 0.8 * np.round((xyz[..., 2] + noise[..., 2] - 0.3) / 0.8)
    before = xyz + noise
    spec = make_spec("quantization", {"step_mm": 0.8, "offset_mm": 0.3}, plates=(2, 3))
    measurement_faults((spec,), np.arange(500) / 20.0, xyz, noise, sigma=0.4, seed=1)
    got = xyz + noise
    np.testing.assert_allclose(got[:, 1:3, 2], want[:, 1:3], atol=1e-9)
    np.testing.assert_array_equal(got[:, [0, 3], 2], before[:, [0, 3], 2])
    np.testing.assert_array_equal(got[..., :2], before[..., :2])


@pytest.mark.parametrize("pixels", [None, 9])
def test_a_lattice_s_mean_reading_is_the_smoothed_staircase(pixels):
    """The mean of many readings at one depth is o + q E[round((z − o)/q + σ_d/q Z)]
    (`_lattice.smoothed_staircase`, the diagnosis' model term), the rest of the noise after the
    rounding adding none; one reading (P = 1) spreads as a rounded one, q² Var[round(x + σ_d/q Z)]
    (`_lattice.dithered_round_var`), plus the rest of the noise, σ² − σ_d²."""
    n, sigma, q, o, dither = 40000, 0.5, 0.6, 0.1, 0.15 if pixels is None else 0.9
    xyz, noise = _reading(n, 5, sigma, seed=2)
    params = {"step_mm": q, "offset_mm": o, "dither_mm": dither} | ({"pixels": pixels} if pixels else {})
    spec = make_spec("quantization", params)
    z = xyz[0, :, 2].copy()
    measurement_faults((spec,), np.arange(n) / 30.0, xyz, noise, sigma=sigma, seed=3)
    reading = xyz[..., 2] + noise[..., 2]
    se = reading.std(axis=0) / math.sqrt(n)
    assert np.all(np.abs(reading.mean(axis=0) - smoothed_staircase(z, q, o, dither)) < 4.5 * se)
    if pixels is None:  # σ_d < σ: the fewest readings that carry it is one
        var = q**2 * dithered_round_var((z - o) / q, dither / q) + sigma**2 - dither**2
        np.testing.assert_allclose(reading.var(axis=0), var, rtol=0.05)


def test_a_noise_level_with_the_motion_is_what_the_diagnosis_estimates():
    """The z noise scaled by 1 + m cos(arg − ψ): the diagnosis' likelihood (`fit_scale`, its
    model σ_i = σ0 (1 + θ·(cos φ_i, sin φ_i))) recovers θ = m (cos ψ, sin ψ) within 4 σ; x, y
    and the other plates keep their noise."""
    from jaxdefl.diagnose.detectors.heteroscedastic_noise import fit_scale

    n, m, psi = 30000, 0.3, 0.8
    xyz, noise = _reading(n, 3, 0.7, seed=4)
    before = noise.copy()
    t = np.arange(n) / 20.0
    arg = np.repeat((2 * math.pi * 3.07 * t - 1.1)[:, None], 3, axis=1)
    spec = make_spec("heteroscedastic_noise", {"modulation": m, "phase_rad": psi}, plates=(2,))
    measurement_faults((spec,), t, xyz, noise, sigma=0.7, arg=arg)
    np.testing.assert_array_equal(noise[:, [0, 2]], before[:, [0, 2]])
    np.testing.assert_array_equal(noise[:, 1, :2], before[:, 1, :2])
    x = np.stack([np.cos(arg[:, 1]), np.sin(arg[:, 1])], axis=1)
    theta, cov, _ = fit_scale(x, (noise[:, 1, 2] / 0.7) ** 2)
    want = m * np.array([math.cos(psi), math.sin(psi)])
    assert np.all(np.abs(theta - want) < 4 * np.sqrt(np.diag(cov))), (theta, want)


def test_a_noise_level_reported_over_the_record_is_simulated_as_its_detector_parametrises_it():
    """Kind "time": σ = σ0 (1 + m u), u = (t − mid)/(duration/2): the spec's factor is 1 − m at
    the start, 1 at the middle and 1 + m at the end."""
    entry = REGISTRY["heteroscedastic_noise"]
    report = {"id": entry.id, "parameters": {"kind": {"value": "time"}, "modulation": {"value": -0.25}}}
    params, plates = entry.from_diagnosis(Report.of(report | {"plates": [1, 2]}, 300.0, None, 11))
    spec = make_spec(entry.id, params, plates)
    xyz, noise = np.zeros((3, 11, 3)), np.ones((3, 11, 3))
    measurement_faults((spec,), np.array([0.0, 150.0, 300.0]), xyz, noise)
    np.testing.assert_allclose(noise[:, :2, 2], [[1.25, 1.25], [1.0, 1.0], [0.75, 0.75]])
    assert np.all(noise[:, 2:] == 1.0)


@pytest.mark.parametrize("share", [0.0, 0.15])
def test_a_lattice_reported_with_its_rounding_s_share_of_the_noise_keeps_the_reading_s_noise(share):
    """``rounded_noise_share`` λ (the diagnosis' noise model, σ² ((1 − λ) + λ v/v̄)): over
    depths spread across many steps, the reading's variance about its mean staircase is σ² within
    a few per cent, the rounding λσ² of it (its excess where the steps fall mid-way between two
    levels over where they fall on one, as `dithered_round_var` profiles it)."""
    n, sigma, q, dither = 60000, 1.0, 2.0, 0.4
    rng = np.random.default_rng(5)
    z = rng.uniform(1000.0, 1040.0, n)
    xyz = np.zeros((n, 1, 3))
    xyz[:, 0, 2] = z
    noise = sigma * rng.standard_normal((n, 1, 3))
    params = {"step_mm": q, "offset_mm": 0.0, "dither_mm": dither, "rounded_noise_share": share}
    measurement_faults((make_spec("quantization", params),), np.arange(n) / 30.0, xyz, noise, sigma=sigma)
    r = xyz[:, 0, 2] + noise[:, 0, 2] - smoothed_staircase(z, q, 0.0, dither)
    assert abs(r.var() / sigma**2 - 1.0) < 0.05
    x = z / q - np.round(z / q)  # the depth's place between two levels
    v = dithered_round_var(x, dither / q)
    hi, lo = v > np.quantile(v, 0.8), v < np.quantile(v, 0.2)
    excess = (r[hi].var() - r[lo].var()) / (q * q * (v[hi].mean() - v[lo].mean()))  # ∝ 1/P
    v_bar = float(np.mean(dithered_round_var(np.arange(64) / 64.0, dither / q)))
    assert abs(excess * q * q * v_bar - share * sigma**2) < 0.05, excess


@pytest.mark.parametrize(
    "table, match",
    [
        ({"id": "quantization", "step_mm": 0.0}, r"effect\[1\]\.step_mm': expected a step > 0 mm, got 0"),
        ({"id": "quantization", "step_mm": 1.0, "pixels": 2.5}, r"\.pixels': expected a whole count >= 1"),
        (
            {"id": "quantization", "step_mm": 1.0, "dither_mm": -0.1},
            r"\.dither_mm': expected a noise >= 0 mm",
        ),
        (
            {"id": "quantization", "step_mm": 1.0, "rounded_noise_share": 1.5},
            r"\.rounded_noise_share': expected a share of the noise's variance in \[0, 1\]",
        ),
        (
            {"id": "quantization", "step_mm": 1.0, "plates": [12]},
            r"\.plates': expected a list of plate numbers",
        ),
        ({"id": "heteroscedastic_noise", "modulation": -0.2}, r"\.modulation': expected a modulation >= 0"),
        ({"id": "heteroscedastic_noise", "modulation": 1.0}, r"\.modulation': expected a modulation < 1"),
        ({"id": "heteroscedastic_noise"}, r"\.modulation': expected a modulation or a rate_per_s != 0"),
        ({"id": "motion_artefact", "tap_spread_s": 0.0}, r"\.tap_spread_s': expected a spread > 0 s"),
        ({"id": "motion_artefact"}, r"\.tap_spread_s': motion_artefact needs tap_spread_s"),
    ],
)
def test_a_bad_table_of_a_measurement_or_sampling_effect_is_one_line_naming_its_key(table, match):
    from jaxdefl._errors import ConfigError
    from jaxdefl.simulate.injection import parse_effects

    with pytest.raises(ConfigError, match=match):
        parse_effects("cfg.toml", [table], 11)


def test_a_noise_level_with_the_motion_needs_the_motion_s_angle():
    spec = make_spec("heteroscedastic_noise", {"modulation": 0.2})
    with pytest.raises(ValueError, match="the motion's phase is needed"):
        measurement_faults((spec,), np.zeros(3), np.zeros((3, 2, 3)), np.ones((3, 2, 3)))
