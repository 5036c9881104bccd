"""The concealed-effect benchmark: the generator (`jaxdefl.simulate.effects`) and the scoring of
`experiments/concealed_effects.py`."""

from __future__ import annotations

import importlib.util
import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from jaxdefl.fit.motion import motion_artefact_response
from jaxdefl.simulate import simulate_trajectories
from jaxdefl.simulate.effects import (
    EFFECT_IDS,
    RMS_RATIO_RANGE,
    SIGNAL_MIN,
    CleanRecording,
    RecordingSpec,
    draw_effect,
    make_case,
    make_recording,
    sim_config,
)

ROOT = Path(__file__).resolve().parents[1]
SPEC = RecordingSpec(duration_s=180.0, n_plates=9, dropout_prob=0.1, reference=True)
CLEAN = RecordingSpec(
    duration_s=180.0, n_plates=9, dropout_prob=0.1, reference=True, noise_mm=(0.0, 0.0, 0.0)
)
SEED = 5


def _bench():
    spec = importlib.util.spec_from_file_location(
        "concealed_effects", ROOT / "experiments" / "concealed_effects.py"
    )
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


bench = _bench()


def _z(traj: pd.DataFrame, plate: int, axis: str = "z") -> tuple[np.ndarray, np.ndarray]:
    s = traj[traj.plate == plate]
    return s.t.to_numpy(), s[axis].to_numpy()


def _harmonic_fit(t, y, omega):
    """(offset, amplitude, phase φ of A cos(ω t − φ)) by linear least squares."""
    x = np.stack([np.ones_like(t), np.cos(omega * t), np.sin(omega * t)], axis=1)
    c, *_ = np.linalg.lstsq(x, y, rcond=None)
    return c[0], math.hypot(c[1], c[2]), math.atan2(c[2], c[1])


@pytest.fixture(scope="module")
def clean():
    traj, lds, truth = make_recording(CLEAN, [], SEED)
    return traj, lds, truth


# ---------------------------------------------------------------------------------------------
# the nominal recording


def test_nominal_is_the_simulator_kinematics():
    base = CleanRecording(SPEC, SEED)
    truth, lds = simulate_trajectories(sim_config(SPEC), SPEC.duration_s, SEED)
    pos = base.motion(base.t)
    for i, a in enumerate("xyz"):
        np.testing.assert_allclose(pos[..., i].ravel(), truth[a].to_numpy(), atol=1e-9)
    traj, lds2, _ = make_recording(CLEAN, [], SEED)
    np.testing.assert_allclose(traj.z.to_numpy(), truth.z.to_numpy(), atol=1e-9)
    pd.testing.assert_frame_equal(lds2, lds)
    assert sim_config(SPEC).fatigue.law == "none"  # amplitude growth is an effect, not the nominal


def test_tables_hide_the_labels():
    traj, lds, truth = make_case(11, ["level_jump", "outliers"], minutes=2)
    assert list(traj.columns) == ["segment", "t", "plate", "x", "y", "z"]
    assert lds is None or list(lds.columns) == ["segment", "t", "plate", "z"]
    assert not traj.attrs and (lds is None or not lds.attrs)
    for v in traj.segment.unique():
        assert not any(eid in str(v) for eid in EFFECT_IDS)
    assert {e["id"] for e in truth["effects"]} == {"level_jump", "outliers"}
    json.dumps(truth)  # the truth is plain JSON


def test_sensor_follows_the_effects():
    assert (
        make_case(2, ["motion_artefact"], minutes=1, sensor="structured_light")[2]["recording"]["sensor"]
        == "tof"
    )
    _, lds, truth = make_case(2, ["quantization", "timing_error"], minutes=1)
    assert truth["recording"]["sensor"] == "structured_light" and lds is not None
    with pytest.raises(ValueError, match="both a ToF and a structured-light"):
        make_case(2, ["motion_artefact", "quantization"], minutes=1)


def test_determinism_for_a_seed():
    a = make_case(3, ["drift"], minutes=2)
    b = make_case(3, ["drift"], minutes=2)
    c = make_case(4, ["drift"], minutes=2)
    pd.testing.assert_frame_equal(a[0], b[0])
    assert a[2] == b[2]
    assert len(a[0]) != len(c[0]) or not np.allclose(a[0].z, c[0].z)


def test_controls_are_harmonic_plus_white_noise():
    traj, lds, truth = make_recording(SPEC, [], SEED)
    rec = truth["recording"]
    omega = 2 * math.pi * rec["f0_hz"]
    dt = 1.0 / SPEC.frame_rate_hz
    for plate in (1, 5, 9):
        for axis in "xyz":
            t, y = _z(traj, plate, axis)
            t = t - t[0]
            x = np.stack([np.ones_like(t), np.cos(omega * t), np.sin(omega * t)], axis=1)
            r = y - x @ np.linalg.lstsq(x, y, rcond=None)[0]
            sigma = rec["noise_mm"][axis][plate - 1]
            assert np.std(r) == pytest.approx(sigma, rel=0.05)
            # whiteness on the frame grid (drop-outs as gaps): autocorrelation at lags 1..10
            k = np.round(t / dt).astype(int)
            grid = np.zeros(k[-1] + 1)
            mask = np.zeros_like(grid)
            grid[k], mask[k] = r, 1.0
            for lag in range(1, 11):
                num = np.sum(grid[lag:] * grid[:-lag])
                n = np.sum(mask[lag:] * mask[:-lag])
                rho = num / (n * np.var(r))
                assert abs(rho) < 4.5 / math.sqrt(n), (plate, axis, lag, rho)
            # no periodogram peak beyond the white-noise expectation (FAP 1e-3 over the band)
            freqs = np.fft.rfftfreq(grid.size, dt)[1:]
            power = np.abs(np.fft.rfft(grid))[1:] ** 2 / (np.sum(mask) * np.var(r))
            assert power.max() < math.log(freqs.size / 1e-3) * 1.2


def test_noise_levels_and_decoys():
    traj, lds, truth = make_recording(
        RecordingSpec(
            duration_s=60.0, n_plates=11, frame_rate_hz=30.0, noisy_plate=4, noisy_factor=2.0, reference=False
        ),
        [],
        1,
    )
    assert lds is None
    sig = truth["recording"]["noise_mm"]
    assert sig["z"][3] > 1.5 * np.median(sig["z"])
    assert 0.7 < np.median(sig["z"]) < 1.2 and np.median(sig["y"]) < np.median(sig["x"]) < np.median(sig["z"])
    assert traj.plate.nunique() == 11


# ---------------------------------------------------------------------------------------------
# each effect is what its parameters say (injected into a noise-free recording, fitted back)


def _inject(effect):
    return make_recording(CLEAN, [effect], SEED)


def test_harmonic_distortion(clean):
    e = dict(id="harmonic_distortion", kind="mixed_pixels", plates=[4, 5], axes=["z"])
    e["parameters"] = {"order": 2, "amplitude_mm": 0.3, "phase_rad": 1.0}
    traj, _, truth = _inject(e)
    omega = 2 * math.pi * truth["recording"]["f0_hz"]
    for plate in range(1, 10):
        t, y = _z(traj, plate)
        _, y0 = _z(clean[0], plate)
        off, amp, phi = _harmonic_fit(t - t[0], y - y0, 2 * omega)
        if plate in (4, 5):
            assert amp == pytest.approx(0.3, rel=1e-6) and phi == pytest.approx(1.0, abs=1e-6)
        else:
            assert amp < 1e-9


def test_drift_and_level_jump(clean):
    d = dict(id="drift", kind="exponential", plates=list(range(1, 10)), axes=["z"])
    d["parameters"] = {"amplitude_mm": -0.4, "tau_s": 50.0}
    j = dict(id="level_jump", kind="one_plate", plates=[3], axes=["z"])
    j["parameters"] = {"t_jump_s": 100.0, "size_mm": 0.25}
    traj, _, truth = make_recording(CLEAN, [d, j], SEED)
    t, y = _z(traj, 6)
    trel = t - t[0]
    diff = y - _z(clean[0], 6)[1]
    slope, icpt = np.polyfit(trel, np.log(-diff), 1)
    assert -1 / slope == pytest.approx(50.0, rel=1e-6) and -math.exp(icpt) == pytest.approx(-0.4, rel=1e-6)
    t, y = _z(traj, 3)
    step = y - _z(clean[0], 3)[1] - (-0.4 * np.exp(-(t - t[0]) / 50.0))
    np.testing.assert_allclose(step, np.where(t - t[0] >= 100.0, 0.25, 0.0), atol=1e-9)
    (tj,) = [e for e in truth["effects"] if e["id"] == "level_jump"]
    assert tj["t_start"] == pytest.approx(t[0] + 100.0)


def test_extra_periodic(clean):
    fac = [0.8, 0.9, 1.0, 1.1, 1.2, 1.0, 1.0, 0.9, 1.1]
    e = dict(id="extra_periodic", kind="vibration", plates=list(range(1, 10)), axes=["z"])
    e["parameters"] = {"freq_hz": 1.7, "amplitude_mm": 0.2, "phase_rad": 0.3}
    e["plate_factors"] = {"z": fac}
    traj, _, truth = _inject(e)
    amps = []
    for plate in range(1, 10):
        t, y = _z(traj, plate)
        _, amp, phi = _harmonic_fit(t - t[0], y - _z(clean[0], plate)[1], 2 * math.pi * 1.7)
        amps.append(amp)
        assert phi == pytest.approx(-0.3, abs=1e-6)
    np.testing.assert_allclose(amps, 0.2 * np.asarray(fac), rtol=1e-6)
    assert truth["effects"][0]["parameters"]["amplitude_mm"] == pytest.approx(np.median(amps))


def _windows(traj, plate, omega, width=10.0, axis="z"):
    t, y = _z(traj, plate, axis)
    t = t - t[0]
    out = []
    for w0 in np.arange(0.0, t[-1] - width, width):
        m = (t >= w0) & (t < w0 + width)
        out.append((w0 + width / 2, *_harmonic_fit(t[m], y[m], omega)))
    return np.asarray(out)  # (window, [t, offset, amplitude, phase])


def test_amplitude_modulation(clean):
    f0 = clean[2]["recording"]["f0_hz"]
    omega = 2 * math.pi * f0
    e = dict(id="amplitude_modulation", kind="linear", plates=list(range(1, 10)), axes=["z", "x"])
    e["parameters"] = {"relative_rate_per_s": 1e-3}
    traj, lds, truth = _inject(e)
    w = _windows(traj, 5, omega)
    w0 = _windows(clean[0], 5, omega)
    tmid = truth["recording"]["t_last"] - truth["recording"]["t_first"]
    ratio = w[:, 2] / w0[:, 2]
    np.testing.assert_allclose(ratio, 1 + 1e-3 * (w[:, 0] - tmid / 2), atol=2e-3)  # window vs mid
    wx = _windows(traj, 5, omega, axis="x")[:, 2] / _windows(clean[0], 5, omega, axis="x")[:, 2]
    np.testing.assert_allclose(wx, ratio, atol=1e-6)
    # the LDS sees the load's modulation too
    ll = lds[lds.plate == 5]
    t = ll.t.to_numpy() - truth["recording"]["t_first"]
    m0, m1 = t < 20, t > t[-1] - 20
    a0 = _harmonic_fit(t[m0], ll.z.to_numpy()[m0], omega)[1]
    a1 = _harmonic_fit(t[m1], ll.z.to_numpy()[m1], omega)[1]
    assert a1 / a0 == pytest.approx(
        (1 + 1e-3 * (t[-1] - 10 - tmid / 2)) / (1 + 1e-3 * (10 - tmid / 2)), rel=3e-3
    )


def test_frequency_modulation(clean):
    omega = 2 * math.pi * clean[2]["recording"]["f0_hz"]
    e = dict(id="frequency_modulation", kind="sinusoidal", plates=list(range(1, 10)), axes=["x", "y", "z"])
    e["parameters"] = {"depth_rad": 0.2, "freq_hz": 0.01, "phase_rad": 0.5}
    traj, _, _ = _inject(e)
    w = _windows(traj, 5, omega, width=5.0)
    w0 = _windows(clean[0], 5, omega, width=5.0)
    dphi = np.angle(np.exp(1j * (w0[:, 3] - w[:, 3])))  # phase advance of the camera
    np.testing.assert_allclose(dphi, 0.2 * np.sin(2 * math.pi * 0.01 * w[:, 0] + 0.5), atol=5e-3)
    # linear drift: the instantaneous frequency f0 + d (t - t_mid)
    e = dict(id="frequency_modulation", kind="linear", plates=list(range(1, 10)), axes=["x", "y", "z"])
    e["parameters"] = {"drift_hz_per_s": 2e-5}
    traj, _, truth = _inject(e)
    w = _windows(traj, 5, omega, width=5.0)
    dphi = np.unwrap(w0[:, 3] - w[:, 3])
    tm = (truth["recording"]["t_last"] - truth["recording"]["t_first"]) / 2
    c = np.polyfit(w[:, 0] - tm, dphi, 2)
    assert c[0] == pytest.approx(math.pi * 2e-5, rel=0.02)


def test_timing_error_and_motion_artefact(clean):
    traj0, lds0, truth0 = clean
    rec = truth0["recording"]
    e = dict(id="timing_error", kind="rate", plates=list(range(1, 10)), axes=["x", "y", "z"])
    e["parameters"] = {"rate_ppm": 150.0}
    traj, lds, _ = _inject(e)
    dt = traj.t.to_numpy() - traj0.t.to_numpy()
    np.testing.assert_allclose(dt, 150e-6 * (traj0.t.to_numpy() - rec["t_first"]), atol=1e-6)  # epoch s
    np.testing.assert_array_equal(traj.z.to_numpy(), traj0.z.to_numpy())  # only the clock is wrong
    pd.testing.assert_frame_equal(lds, lds0)
    e = dict(id="timing_error", kind="offset", plates=list(range(1, 10)), axes=["x", "y", "z"])
    e["parameters"] = {"offset_s": 0.005}
    traj, _, _ = _inject(e)
    np.testing.assert_allclose(traj.t.to_numpy() - traj0.t.to_numpy(), 0.005, atol=1e-6)

    tap = 1 / 20.0
    e = dict(id="motion_artefact", kind="sequential_taps", plates=list(range(1, 10)), axes=["x", "y", "z"])
    e["parameters"] = {"tap_spread_s": tap}
    traj, _, truth = _inject(e)
    omega = 2 * math.pi * rec["f0_hz"]
    gain, lag = motion_artefact_response(rec["f0_hz"], 1 / tap)
    for plate, axis in ((5, "z"), (2, "z"), (7, "x")):
        t, y = _z(traj, plate, axis)
        _, y0 = _z(traj0, plate, axis)
        _, a, p = _harmonic_fit(t - t[0], y, omega)
        _, a0, p0 = _harmonic_fit(t - t[0], y0, omega)
        assert a / a0 == pytest.approx(float(gain), rel=1e-6)
        assert np.angle(np.exp(1j * (p0 - p))) == pytest.approx(float(lag), abs=1e-6)  # a phase lead in t


def test_outliers_heteroscedastic_quantization(clean):
    traj0 = clean[0]
    e = dict(
        id="outliers", kind="sign", plates=[2, 8], axes=["z"], parameters={"fraction": 0.01, "scale_mm": 4.0}
    )
    traj, _, truth = _inject(e)
    d = (traj.z - traj0.z).to_numpy()
    hit = np.abs(d) > 0
    assert set(traj.plate[hit]) == {2, 8}
    np.testing.assert_allclose(np.abs(d[hit]), 4.0, atol=1e-9)
    n = len(traj) / 9
    assert truth["effects"][0]["parameters"]["fraction"] == pytest.approx(hit.sum() / (2 * n))
    assert truth["effects"][0]["parameters"]["fraction"] == pytest.approx(0.01, rel=0.05)

    e = dict(id="heteroscedastic_noise", kind="phase", plates=[1, 2, 3], axes=["z"])
    e["parameters"] = {"modulation": 0.3, "phase_rad": 0.7}
    het, _, truth = make_recording(SPEC, [e], SEED)
    ctl, _, _ = make_recording(SPEC, [], SEED)
    rec = truth["recording"]
    omega = 2 * math.pi * rec["f0_hz"]
    for plate in (1, 3, 6):
        t, yh = _z(het, plate)
        _, yc = _z(ctl, plate)
        _, y0 = _z(traj0, plate)
        ratio = (yh - y0) / (yc - y0)
        u = np.cos(omega * (t - t[0]) - rec["motion_phase_rad"] - 0.7)
        np.testing.assert_allclose(ratio, 1 + 0.3 * u if plate <= 3 else 1.0, atol=1e-6)
    # the motion phase is that of y = A cos(ω t_rel − φ)
    t, y0 = _z(traj0, 5)
    assert _harmonic_fit(t - t[0], y0, omega)[2] == pytest.approx(rec["motion_phase_rad"], abs=1e-6)

    sl = RecordingSpec(
        sensor="structured_light", frame_rate_hz=30.0, duration_s=60.0, n_plates=9, noise_mm=(0, 0, 0)
    )
    e = dict(id="quantization", kind="depth_steps", plates=list(range(1, 10)), axes=["z"])
    e["parameters"] = {"step_mm": 0.8, "offset_mm": 0.3}
    q, _, _ = make_recording(sl, [e], 2)
    c, _, _ = make_recording(sl, [], 2)
    k = (q.z.to_numpy() - 0.3) / 0.8
    np.testing.assert_allclose(k, np.round(k), atol=1e-6)
    assert np.abs(q.z - c.z).max() <= 0.4 + 1e-9


# a structured-light recording with every plate's noise alike (the quantization generator tests)
_SL_SPEC = RecordingSpec(
    sensor="structured_light",
    frame_rate_hz=30.0,
    duration_s=120.0,
    n_plates=9,
    noise_mm=(0.4, 0.15, 0.5),
    plate_noise_spread=0.0,
)


def test_quantization_rounds_each_pixel_after_its_noise():
    """Each quantised z is the mean of P pixel readings rounded after their own noise: binned by
    the position on the step, its mean is the smoothed staircase (not the hard one), its variance
    about it is the pixels' rounding variance / P (the series' noise is not added a second time),
    its unrounded noise is the control's (same seed), and the draw is reproducible."""
    import dataclasses

    from scipy.special import ndtri

    from jaxdefl._lattice import smoothed_staircase

    sl = _SL_SPEC
    q, o, pixels, sig = 3.5, 0.3, 4, 0.5
    dither = sig * math.sqrt(pixels)  # σ_d / q = 0.29: the steps' first harmonic at 20 %
    e = dict(id="quantization", kind="depth_steps", plates=list(range(1, 10)), axes=["z"])
    e["parameters"] = {"step_mm": q, "offset_mm": o, "pixels": pixels}
    traj, _, _ = make_recording(sl, [e], 4)
    again, _, _ = make_recording(sl, [e], 4)
    ctl, _, _ = make_recording(sl, [], 4)
    clean, _, _ = make_recording(dataclasses.replace(sl, noise_mm=(0.0, 0.0, 0.0)), [], 4)
    np.testing.assert_array_equal(traj.z, again.z)
    np.testing.assert_array_equal(traj.x, ctl.x)
    h, z = clean.z.to_numpy(), traj.z.to_numpy()
    m = smoothed_staircase(h, q, o, dither)
    frac = np.mod((h - o) / q, 1.0)
    b = np.minimum((frac * 8).astype(int), 7)
    for k in range(8):
        sel = b == k
        se = 0.75 / math.sqrt(sel.sum())  # noise + rounding σ ≈ 0.7 mm
        assert abs(np.mean(z[sel] - m[sel])) < 4 * se
        hard = q * np.round((h[sel] - o) / q) + o  # far off, except next to a level
        assert abs(np.mean(z[sel] - hard)) > 10 * se or k in (0, 7)
    assert np.ptp([np.mean(m[b == k] - h[b == k]) for k in range(8)]) > 0.25  # a visible staircase
    # Var(mean of P readings | h) = Var(one reading | h) / P, the reading's from the normal's quantiles
    zq = sig * math.sqrt(pixels) * ndtri((np.arange(20_000) + 0.5) / 20_000)
    grid = (np.arange(64) + 0.5) / 64
    v1 = np.array([np.var(q * np.round(g + zq / q)) for g in grid])
    expected = float(np.mean(v1[np.minimum((frac * 64).astype(int), 63)])) / pixels
    assert np.var(z - m) == pytest.approx(expected, rel=0.05)
    assert expected > 1.5 * sig**2  # so that the noise counted twice (+σ²) would show
    # the unrounded mean of the pixels' noise is the control's noise
    assert np.corrcoef(z - m, ctl.z.to_numpy() - h)[0, 1] > 0.5


def test_quantization_with_a_pixel_noise_of_its_own():
    """``dither_mm`` apart from the series' noise (the benchmark's draw): the pixels' noise σ_d
    before rounding, the rest σ² − σ_d²/P after it. The mean is the smoothed staircase of σ_d, the
    variance about it q² Var[round]/P + the rest, and the control differs by the rounding alone."""
    import dataclasses

    from jaxdefl._lattice import dithered_round_var, smoothed_staircase

    sl = _SL_SPEC
    q, o, pixels, dither, sig = 2.0, 0.9, 30, 0.4, 0.5
    e = dict(id="quantization", kind="depth_steps", plates=list(range(1, 10)), axes=["z"])
    e["parameters"] = {"step_mm": q, "offset_mm": o, "pixels": pixels, "dither_mm": dither}
    traj, _, truth = make_recording(sl, [e], 6)
    ctl, _, _ = make_recording(sl, [], 6)
    clean, _, _ = make_recording(dataclasses.replace(sl, noise_mm=(0.0, 0.0, 0.0)), [], 6)
    h, z = clean.z.to_numpy(), traj.z.to_numpy()
    m = smoothed_staircase(h, q, o, dither)
    b = np.minimum((np.mod((h - o) / q, 1.0) * 8).astype(int), 7)
    for k in range(8):
        sel = b == k
        assert abs(np.mean(z[sel] - m[sel])) < 4 * sig / math.sqrt(sel.sum())
    v = q * q * dithered_round_var((h - o) / q, dither / q) / pixels + sig**2 - dither**2 / pixels
    assert np.var(z - m) == pytest.approx(float(np.mean(v)), rel=0.05)
    rounding = z - ctl.z.to_numpy() - (m - h)  # the control's noise cancels: what is left is small
    assert np.std(rounding) < 0.5 * sig
    assert truth["effects"][0]["rms_ratio"] == pytest.approx(np.std(m - h) / sig, rel=0.3)


@pytest.mark.parametrize("eid", EFFECT_IDS)
def test_drawn_magnitudes_are_below_the_noise_and_detectable(eid):
    spec = RecordingSpec(
        sensor="structured_light" if eid == "quantization" else "tof",
        frame_rate_hz=30.0 if eid == "quantization" else 20.0,
        duration_s=900.0,
        n_plates=11,
        dropout_prob=0.1,
    )
    base = CleanRecording(spec, 9)
    rng = np.random.default_rng(1)
    e = draw_effect(eid, base, rng)
    _, _, truth = make_recording(spec, [e], 9, base=base)
    te = truth["effects"][0]
    assert te["signal"] >= 0.95 * SIGNAL_MIN
    if eid == "heteroscedastic_noise":
        assert 0.15 <= te["rms_ratio"] <= 0.4
    elif eid not in ("timing_error", "motion_artefact"):  # these two: physical ranges of T, offset, rate
        assert RMS_RATIO_RANGE[0] * 0.95 <= te["rms_ratio"] <= 0.62
    assert te["plates"] and te["axes"]


# ---------------------------------------------------------------------------------------------
# scoring


def _truth(effects, t_first=1000.0):
    return {
        "recording": dict(
            sensor="tof",
            frame_rate_hz=20.0,
            duration_s=900.0,
            n_plates=13,
            dropout_prob=0.1,
            reference=True,
            t_first=t_first,
        ),
        "effects": effects,
    }


def _eff(eid, plates, **pars):
    return {
        "id": eid,
        "plates": plates,
        "axes": ["z"],
        "t_start": 0,
        "t_end": 1,
        "band_hz": None,
        "parameters": {k: {"value": v, "sigma": abs(v) * 0.05} for k, v in pars.items()},
        "delta_bic": -50.0,
        "rms_before_mm": 0.8,
        "rms_after_mm": 0.79,
        "explanation": "",
    }


def _res(case, kind, truth, effects, seconds=1.0):
    return {
        "plan": {"case": case, "kind": kind, "seed": case, "effects": [e["id"] for e in truth["effects"]]},
        "truth": truth,
        "diag": {"nominal": {}, "effects": effects, "unexplained": [], "final": {}},
        "seconds": seconds,
        "error": "",
    }


JUMP = {
    "id": "level_jump",
    "kind": "one_plate",
    "plates": [4],
    "axes": ["z"],
    "parameters": {"t_jump_s": 300.0, "size_mm": 0.5},
}
DRIFT = {
    "id": "drift",
    "kind": "exponential",
    "plates": list(range(1, 14)),
    "axes": ["z"],
    "parameters": {"amplitude_mm": -0.4, "tau_s": 100.0},
}
MOTION = {
    "id": "motion_artefact",
    "kind": "",
    "plates": list(range(1, 14)),
    "axes": ["x", "y", "z"],
    "parameters": {"tap_spread_s": 0.05},
    "detectable_plates": [3, 5, 7, 9, 11],
}


def test_score_perfect_and_wrong_reports():
    results = [
        _res(0, "single", _truth([JUMP]), [_eff("level_jump", [4], t_jump_s=301.0, size_mm=0.55)]),
        _res(
            1,
            "pair",
            _truth([DRIFT, JUMP]),
            [_eff("drift", list(range(1, 14)), amplitude_mm=-0.41, tau_s=140.0)],
        ),
        _res(2, "single", _truth([MOTION]), [_eff("motion_artefact", [3, 5, 7], tap_spread_s=0.049)]),
        _res(3, "single", _truth([JUMP]), [_eff("level_jump", [9], t_jump_s=300.0, size_mm=0.5)]),
        _res(4, "control", _truth([]), []),
        _res(5, "control", _truth([]), [_eff("outliers", [2], fraction=0.01, scale_mm=3.0)]),
    ]
    results[2]["diag"]["effects"][0]["delta_bic"] = -5.0  # not a good report
    cases, conf, s = bench.score(results)
    by = {(r.case, r.injected): r for r in cases.itertuples()}
    assert by[(0, "level_jump")].detected and by[(0, "level_jump")].recovered
    assert by[(0, "level_jump")].jump_error_s == pytest.approx(1.0)
    assert by[(1, "drift")].detected and not by[(1, "drift")].recovered  # tau 40 % off
    assert json.loads(by[(1, "drift")].param_errors)["tau_s"] == pytest.approx(0.4)
    assert not by[(1, "level_jump")].named
    assert by[(2, "motion_artefact")].detected  # half of the reference plates is enough
    assert by[(2, "motion_artefact")].jaccard == pytest.approx(3 / 5)
    assert by[(3, "level_jump")].named and not by[(3, "level_jump")].located
    assert by[(3, "level_jump")].jaccard == 0.0
    assert conf.loc["level_jump", "level_jump"] == 2 and conf.loc["level_jump", "none"] == 1
    assert conf.loc["none", "none"] == 1 and conf.loc["none", "outliers"] == 1
    assert s["detected"] == pytest.approx(3 / 5) and s["false_positive"] == pytest.approx(0.5)
    assert s["quality"] == pytest.approx(4 / 5)
    assert not s["targets"]["every report dBIC < -10 and lower RMS"]
    assert s["recovered_of_detected"] == pytest.approx(2 / 3)


def test_score_signs_phases_and_fallbacks():
    hd = {
        "id": "harmonic_distortion",
        "kind": "",
        "plates": [2, 3],
        "axes": ["z"],
        "parameters": {"order": 3, "amplitude_mm": 0.3, "phase_rad": 1.0},
    }
    r = bench.score_effect(hd, [_eff("harmonic_distortion", [2, 3, 4], order=3, amplitude_mm=-0.31)], 0.0)
    assert r["recovered"] and r["jaccard"] == pytest.approx(2 / 3)  # amplitude sign is a phase
    r = bench.score_effect(hd, [_eff("harmonic_distortion", [2, 3], order=2, amplitude_mm=0.3)], 0.0)
    assert r["detected"] and not r["recovered"]  # the wrong order
    r = bench.score_effect(DRIFT, [_eff("drift", list(range(1, 14)), amplitude_mm=0.4, tau_s=100.0)], 0.0)
    assert r["detected"] and not r["recovered"]  # the drift's sign matters
    rep = _eff("level_jump", [4], size_mm=0.5)
    rep["t_start"] = 1302.0
    r = bench.score_effect(JUMP, [rep], 1000.0)
    assert r["jump_error_s"] == pytest.approx(2.0) and r["recovered"]
    r = bench.score_effect(JUMP, [_eff("level_jump", [4])], 0.0)  # no parameters reported
    assert r["detected"] and not r["recovered"]
    assert not bench.good_report({"delta_bic": -20, "rms_before_mm": 0.8, "rms_after_mm": 0.81})
    assert bench.good_report({"delta_bic": -20, "rms_before_mm": 0.8, "rms_after_mm": 0.79})


def test_plan_has_singles_pairs_and_controls():
    plan = bench.plan_cases(30, 20, seed=1)
    singles = [p for p in plan if p["kind"] == "single"]
    pairs = [p for p in plan if p["kind"] == "pair"]
    assert len(singles) == 23 and len(pairs) == 7 and sum(p["kind"] == "control" for p in plan) == 20
    assert {p["effects"][0] for p in singles} == set(EFFECT_IDS)
    for p in pairs:
        assert len(set(p["effects"])) == 2 and frozenset(p["effects"]) not in bench.INCOMPATIBLE
    assert len({p["seed"] for p in plan}) == len(plan)


def _stand_in(traj, reference=None, sensor=None, frame_rate_hz=None, modulation_mhz=None):
    """A tiny diagnosis for the plumbing: a common level jump by a cumulative-sum change point."""
    assert set(traj.columns) == {"segment", "t", "plate", "x", "y", "z"}
    assert sensor in ("tof", "structured_light") and frame_rate_hz in (20.0, 30.0)
    z = traj.pivot_table(index="t", columns="plate", values="z")
    t = z.index.to_numpy()
    trel = t - t[0]
    omega = 2 * math.pi * 3.068
    x = np.stack([np.ones_like(trel), np.cos(omega * trel), np.sin(omega * trel)], axis=1)
    r = z.to_numpy() - x @ np.linalg.lstsq(x, z.to_numpy(), rcond=None)[0]
    m = r.mean(axis=1)
    c = np.cumsum(m - m.mean())
    k = int(np.argmax(np.abs(c)))
    n = len(m)
    stat = c[k] ** 2 / (k + 1) / (n - k - 1) * n / np.var(m)
    effects = []
    if stat > 40:
        size = m[k + 1 :].mean() - m[: k + 1].mean()
        effects.append(
            {
                "id": "level_jump",
                "plates": list(map(int, z.columns)),
                "axes": ["z"],
                "t_start": float(t[k + 1]),
                "t_end": float(t[k + 1]),
                "band_hz": None,
                "parameters": {
                    "t_jump_s": {"value": float(trel[k + 1]), "sigma": 1.0},
                    "size_mm": {"value": float(size), "sigma": 0.01},
                },
                "delta_bic": -stat,
                "rms_before_mm": 1.0,
                "rms_after_mm": 0.99,
                "explanation": "a step",
            }
        )
    return {"nominal": {}, "effects": effects, "unexplained": [], "final": {}, "cannot_tell": []}


def test_benchmark_plumbing_with_a_stand_in(tmp_path, monkeypatch):
    plan = [
        {"case": 0, "kind": "single", "effects": ["level_jump"], "seed": 21},
        {"case": 1, "kind": "control", "effects": [], "seed": 22},
    ]
    results = bench.run_benchmark(plan, minutes=2.0, diagnose=_stand_in, log=None, out=tmp_path)
    assert len(list((tmp_path / "results").glob("case_*.json"))) == 2  # saved as they end

    def fail(*args, **kw):
        raise AssertionError("a saved case ran again")

    again = bench.run_benchmark(plan, minutes=2.0, diagnose=fail, log=None, out=tmp_path)  # resumes
    assert [r["diag"] for r in again] == [r["diag"] for r in results]
    cases, conf, summary, md = bench.write_outputs(tmp_path, results, {"minutes": 2.0})
    assert (tmp_path / "cases.csv").exists() and (tmp_path / "confusion.csv").exists()
    assert "Concealed-effect benchmark" in (tmp_path / "summary.md").read_text()
    assert len(cases) == 2 and summary["n_controls"] == 1
    assert set(pd.read_csv(tmp_path / "confusion.csv", index_col=0).index) >= {"none", "level_jump"}
    assert not results[0]["error"] and not results[1]["error"]
    again = bench.score(bench.load_results(tmp_path))
    pd.testing.assert_frame_equal(again[0], cases)


# ---------------------------------------------------------------------------------------------
# end to end on the real diagnosis


SMALL_BENCHMARK = [
    {"case": 0, "kind": "single", "effects": ["level_jump"], "seed": 31},
    {"case": 1, "kind": "single", "effects": ["harmonic_distortion"], "seed": 32},
    {"case": 2, "kind": "single", "effects": ["extra_periodic"], "seed": 33},
    {"case": 3, "kind": "single", "effects": ["drift"], "seed": 34},
    {"case": 4, "kind": "control", "effects": [], "seed": 35},
    {"case": 5, "kind": "control", "effects": [], "seed": 36},
    {"case": 6, "kind": "single", "effects": ["timing_error"], "seed": 37},
    {"case": 7, "kind": "pair", "effects": ["level_jump", "outliers"], "seed": 38},
]


@pytest.mark.slow
@pytest.mark.parametrize("plan", SMALL_BENCHMARK, ids=lambda p: f"{p['case']}-{p['kind']}")
def test_small_benchmark_meets_the_targets(plan):
    """The benchmark's targets on its small plan (10-minute records), case by case so the cases
    spread over the test workers: every effect detected with its parameters recovered and
    nothing else reported (the targets' 90 % of 7 effect cases and 5 % of 2 controls leave no
    miss and no false report)."""
    (result,) = bench.run_benchmark([plan], minutes=10.0, log=None)
    cases, _, s = bench.score([result])
    assert s["errors"] == 0, cases.error.tolist()
    assert s["reports"] == 0 or s["quality"] == 1.0, cases.reported_ids.tolist()
    if plan["effects"]:
        assert s["detected"] == 1.0 and s["recovered_of_detected"] == 1.0, cases.to_dict("records")
    else:
        assert s["false_positive"] == 0, cases.reported_ids.tolist()


# benchmark cases that once reported a wrong or extra id or a parameter off by > 25 % (plan seeds:
# case N of --seed S has seed 100000 S + N): a level jump on plate 3 also taken on plate 6 (size
# off by 40 %), coarse quantization leaving harmonic_distortion and aliased extra_periodic lines
# (21) or a step 2 % off leaving harmonic_distortion (100010), a half-frame tap spread taken as a
# clock offset, a deep phase modulation leaving a clock offset against the LDS, a support plate
# whose own line at 2 f0 was taken for its nominal harmonic (100001: heteroscedastic_noise
# reported), an extra line on z and x whose amplitude was the median over both axes (100018)
ONCE_FAILED = [
    (14, ["level_jump"]),
    (21, ["quantization"]),
    (100010, ["quantization"]),
    (22, ["motion_artefact"]),
    (5, ["frequency_modulation"]),
    (100001, ["harmonic_distortion"]),
    (100018, ["extra_periodic"]),
]


@pytest.mark.slow
@pytest.mark.parametrize("seed, effects", ONCE_FAILED)
def test_benchmark_cases_that_once_failed(seed, effects):
    plan = {"case": seed, "kind": "single", "effects": effects, "seed": seed}
    (result,) = bench.run_benchmark([plan], log=None)
    cases, _, s = bench.score([result])
    assert s["errors"] == 0, cases.error.tolist()
    (row,) = cases.itertuples()
    assert row.reported_ids == effects[0] and row.detected, row
    assert row.recovered, row.param_errors
