"""Simulator outputs: truth/LDS carry the configured motion, fatigue, determinism, CLI, Kinect."""

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import zarr
from scipy.optimize import least_squares

from jaxdefl.cli import main
from jaxdefl.io import read_reference, read_trajectory
from jaxdefl.simulate import (
    beam_shape,
    config_from_dict,
    load_config,
    midspan_amplitude_mm,
    render_frames,
    simulate_to_dir,
    simulate_trajectories,
)
from jaxdefl.simulate.structured_light import quantisation_step_px

CONFIGS = Path(__file__).parents[1] / "configs"


def fit_harmonic(t, y, f_start):
    """Nonlinear LS of y = c + a cos(w t) + b sin(w t) (time centred): amplitude, frequency."""
    tc = t - t.mean()

    def design(f):
        w = 2 * np.pi * f
        return np.stack([np.ones_like(tc), np.cos(w * tc), np.sin(w * tc)], axis=1)

    lin, *_ = np.linalg.lstsq(design(f_start), y, rcond=None)
    res = least_squares(lambda p: design(p[3]) @ p[:3] - y, np.r_[lin, f_start], x_scale=[1, 1, 1, 1e-4])
    c, a, b, f = res.x
    return float(np.hypot(a, b)), float(f), float(np.std(res.fun))


def test_truth_and_lds_carry_configured_amplitude_and_frequency():
    cfg = load_config(CONFIGS / "exp2_tof_3hz.toml")  # day 1: 3.0680 Hz, 2.32 mm at plate 7
    truth, lds = simulate_trajectories(cfg, duration_s=60.0, seed=2)
    shape = beam_shape(np.asarray(cfg.plate_x_mm()), cfg.beam.span_mm, cfg.beam.load_a_mm)
    for plate in (3, 7, 11):
        g = truth[truth.plate == plate]
        a, f, _ = fit_harmonic(g.t.to_numpy(), g.z.to_numpy(), 3.07)
        assert a == pytest.approx(2.32 * shape[plate - 1], rel=1e-3)
        assert f == pytest.approx(3.0680, abs=1e-6)
    g = truth[truth.plate == 7]
    assert fit_harmonic(g.t.to_numpy(), g.x.to_numpy(), 3.07)[0] == pytest.approx(0.5, rel=1e-3)
    assert fit_harmonic(g.t.to_numpy(), g.y.to_numpy(), 3.07)[0] == pytest.approx(0.05, rel=1e-3)
    for plate in (5, 7):
        g = lds[lds.plate == plate]
        a, f, sig = fit_harmonic(g.t.to_numpy(), g.z.to_numpy(), 3.07)
        assert a == pytest.approx(2.32 * shape[plate - 1], abs=5e-4)
        assert f == pytest.approx(3.0680, abs=2e-6)
        assert sig == pytest.approx(0.002, rel=0.05)  # 2 µm
    g = lds[lds.plate == 9]  # the defective sensor
    a, _, sig = fit_harmonic(g.t.to_numpy(), g.z.to_numpy(), 3.07)
    assert a == pytest.approx(0.6 * 2.32 * shape[8], rel=0.02) and sig > 0.03
    assert np.allclose(np.diff(np.unique(lds.t)), 1 / 300, atol=1e-6)
    # the frame clock: 20 Hz with ~3 % drop-outs, the same timestamps for every plate
    t7 = truth[truth.plate == 7].t.to_numpy()
    assert 0.94 < len(t7) / 1200 < 0.995 and np.allclose(np.diff(t7) * 20, np.round(np.diff(t7) * 20))


def test_fatigue_follows_the_log_law():
    raw = {
        "recording": {"cycles_at_start": 32400.0},
        "loading": {"frequency_hz": 3.0, "amplitude_mm": 2.32},
        "lds": {"plates": [7]},
        "fatigue": {"law": "log", "cycles": [32400, 880286], "amplitude_mm": [2.32, 2.63]},
    }
    cfg = config_from_dict(raw)
    assert midspan_amplitude_mm(cfg, 880286) == pytest.approx(2.63)
    assert midspan_amplitude_mm(cfg, 32400) == pytest.approx(2.32)
    _, lds = simulate_trajectories(cfg, duration_s=3600.0, seed=0)  # 10,800 cycles
    t = lds.t.to_numpy()
    for t_mid in (30.0, 1800.0, 3570.0):
        sel = np.abs(t - cfg.t0_s - t_mid) <= 30.0
        a, _, _ = fit_harmonic(t[sel], lds.z.to_numpy()[sel], 3.0)
        expected = midspan_amplitude_mm(cfg, 32400 + 3.0 * t_mid)
        assert a == pytest.approx(expected, abs=3e-4)
    assert midspan_amplitude_mm(cfg, 32400 + 3.0 * 3570) - 2.32 == pytest.approx(0.0270, abs=5e-4)
    # day 11 of the shipped config sits on the same curve's end point
    day11 = load_config(CONFIGS / "exp2_tof_3hz.toml", session="day11")
    assert midspan_amplitude_mm(day11, 880286) == pytest.approx(2.63)


def _small_config(tmp_path, chunk=200, extra=""):
    text = (
        (CONFIGS / "exp2_tof_3hz.toml").read_text().replace("chunk_frames = 200", f"chunk_frames = {chunk}")
    )
    p = tmp_path / f"sim_{chunk}.toml"
    p.write_text(text + extra)
    return p


def _read(out):
    g = zarr.open_group(str(out / "recording.zarr"), mode="r")
    return g["range"][:], g["amplitude"][:], g["timestamps"][:], dict(g.attrs)


def test_deterministic_for_a_seed_and_independent_of_chunking(tmp_path):
    cfg = _small_config(tmp_path, chunk=200)
    cfg7 = _small_config(tmp_path, chunk=7)
    a = simulate_to_dir(cfg, tmp_path / "a", duration_s=2.0, seed=5, progress=False)
    b = simulate_to_dir(cfg7, tmp_path / "b", duration_s=2.0, seed=5, progress=False)
    c = simulate_to_dir(cfg, tmp_path / "c", duration_s=2.0, seed=6, progress=False)
    ra, aa, ta, _ = _read(a)
    rb, ab, tb, _ = _read(b)
    rc, _, tc, _ = _read(c)
    np.testing.assert_array_equal(ra, rb)
    np.testing.assert_array_equal(aa, ab)
    np.testing.assert_array_equal(ta, tb)
    assert (a / "truth.csv").read_bytes() == (b / "truth.csv").read_bytes()
    assert (a / "lds.csv").read_bytes() == (b / "lds.csv").read_bytes()
    assert not np.array_equal(ra[: min(len(ra), len(rc))], rc[: min(len(ra), len(rc))])


def test_cli_simulate_writes_the_recording(tmp_path):
    out = tmp_path / "rec"
    cfg = str(CONFIGS / "exp2_tof_3hz.toml")
    assert main(["simulate", cfg, "--out", str(out), "--duration", "5", "--session", "day1"]) == 0
    rng, amp, t, attrs = _read(out)
    assert rng.shape == amp.shape == (len(t), 144, 176) and 90 <= len(t) <= 100
    assert t.dtype == np.float64 and 1.7e9 <= t[0] < 1.7e9 + 1 and np.all(np.diff(t) > 0)
    for key in ("fx", "fy", "cx", "cy", "width", "height", "sensor", "frame_rate_hz", "modulation_mhz"):
        assert key in attrs
    assert attrs["sensor"] == "sr4000" and attrs["modulation_mhz"] == 29.0
    g = zarr.open_group(str(out / "recording.zarr"), mode="r")
    assert g["range"].chunks[0] == 200
    truth = read_trajectory(out / "truth.csv")
    lds = read_reference(out / "lds.csv")
    assert set(truth.plate) == set(range(1, 14)) and set(lds.plate) == {3, 5, 7, 9, 11}
    np.testing.assert_allclose(np.sort(truth.t.unique()), t, atol=1e-6)
    ref_truth, ref_lds = simulate_trajectories(CONFIGS / "exp2_tof_3hz.toml", duration_s=5, seed=3)
    np.testing.assert_allclose(
        truth.sort_values(["plate", "t"]).z.to_numpy(),
        ref_truth.sort_values(["plate", "t"]).z.to_numpy(),
        atol=2e-6,
    )
    assert len(lds) == len(ref_lds) == 5 * 1500
    eff = (out / "config.json").read_text()
    assert '"duration_s": 5.0' in eff and '"seed": 3' in eff


def test_truth_and_lds_share_the_sign_of_the_deflection():
    cfg = load_config(CONFIGS / "exp2_tof_3hz.toml")
    truth, lds = simulate_trajectories(cfg, duration_s=2.0, seed=1)
    tr = truth[truth.plate == 7]
    ld = lds[lds.plate == 7]
    z_at = np.interp(tr.t, ld.t, ld.z)
    assert np.corrcoef(tr.z - tr.z.mean(), z_at)[0, 1] > 0.999  # downward positive in both


def test_kinect_depth_is_quantised_with_steps_growing_as_z_squared():
    raw = {
        "camera": {
            "sensor": "kinect",
            "plates": [7],
            "frame_noise_mm": 0.0,
            "session_shift_mm": 0.0,
            "jumps_per_minute": 0.0,
            "dropout_prob": 0.0,
        },
        "loading": {"frequency_hz": 1.0},
    }
    cfg = config_from_dict(raw)
    t, depth, amp, facts = render_frames(cfg, duration_s=0.2)
    assert depth.shape == (6, 480, 640) and facts["sensor"] == "kinect"
    q = quantisation_step_px(cfg, facts["fx"])
    bf = cfg.camera.baseline_mm * facts["fx"]
    n = bf / depth / q
    np.testing.assert_allclose(n, np.round(n), atol=1e-3)
    step = lambda z: z**2 * q / bf  # noqa: E731
    assert step(2000.0) == pytest.approx(3.0) and step(2800.0) / step(1400.0) == pytest.approx(4.0)


def test_kinect_session_shift_and_jumps():
    raw = {
        "camera": {"sensor": "kinect", "noise_scale": 0.0, "dropout_prob": 0.0, "jumps_per_minute": 30.0},
        "loading": {"amplitude_mm": 0.0, "longitudinal_mm": 0.0, "lateral_mm": 0.0},
    }
    cfg = config_from_dict(raw)
    from jaxdefl.simulate.structured_light import session_offsets_mm

    t = cfg.t0_s + np.arange(0, 10, 1 / 30)
    shifts = [session_offsets_mm(cfg, t, seed, 10.0) for seed in range(40)]
    firsts = np.array([s[0] for s in shifts])
    assert 8.0 < np.std(firsts) * np.sqrt(2) < 26.0  # sessions differ by about 17 mm
    assert any(len(np.unique(s)) > 1 for s in shifts)  # level jumps inside a record


@pytest.mark.slow
def test_engine_fit_recovers_configured_motion(tmp_path):
    """Simulate -> `jaxdefl fit` on lds.csv and truth.csv gives back amplitude and frequency."""
    from jaxdefl.io import write_trajectory

    cfg = config_from_dict(
        {"loading": {"frequency_hz": 3.0680, "amplitude_mm": 2.32}, "fatigue": {"law": "none"}}
    )
    truth, lds = simulate_trajectories(cfg, duration_s=60.0, seed=4)
    write_trajectory(truth[truth.plate == 7], tmp_path / "truth.csv")
    write_trajectory(lds, tmp_path / "lds.csv")
    for name in ("lds", "truth"):
        est_path = tmp_path / f"est_{name}.csv"
        assert main(["fit", str(tmp_path / f"{name}.csv"), "--out", str(est_path), "--axes", "z"]) == 0
        est = pd.read_csv(est_path)
        row = est[(est.plate == 7) & (est.axis == "z")].iloc[0]
        if name == "lds":
            assert abs(row.amplitude_mm - 2.32) < 4 * row.sigma_amplitude_mm + 1e-6
            assert abs(row.f0_hz - 3.0680) < 4 * row.sigma_f0_hz + 1e-9
        else:
            assert row.amplitude_mm == pytest.approx(2.32, abs=1e-5)
            assert row.f0_hz == pytest.approx(3.0680, abs=1e-7)
