"""Reconcile against the simulator's chain (issue 23): `simulated` only where the twin shows the
effect, one injection for an effect reported on several axes, null bands that are 95th
percentiles."""

from __future__ import annotations

import dataclasses
import math
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest

from jaxdefl.io import validate_trajectory
from jaxdefl.reconcile import SensorCalibration, Twin, specs_from_diagnosis
from jaxdefl.reconcile.engine import keep_shown
from jaxdefl.reconcile.frames import pooled_null_95
from jaxdefl.reconcile.metrics import FAMILY, FAMILY_Q, null_95, null_family
from jaxdefl.simulate.effects import make_case
from jaxdefl.simulate.injection import make_spec

# one plausible spec per id the diagnosis can hand to the simulator
SPECS = {
    "drift": {"amplitude_mm": 1.0, "tau_s": 30.0},
    "level_jump": {"t_jump_s": 20.0, "size_mm": 0.5},
    "camera_shake": {"rms_mm": 0.3, "corner_hz": 0.05},
    "outliers": {"fraction": 0.05, "scale_mm": 5.0},
    "timing_error": {"offset_s": 0.005},
    "amplitude_modulation": {"depth": 0.1, "freq_hz": 0.1},
    "frequency_modulation": {"depth_rad": 0.2, "freq_hz": 0.1},
    "extra_periodic": {"freq_hz": 2.3, "amplitude_mm": 0.3},
    "harmonic_distortion": {"order": 2, "amplitude_mm": 0.2},
    "mode_shape": {"mode": 2, "freq_hz": 4.1, "amplitude_mm": 0.3, "phase_rad": 0.0},
    "stiffness_change": {"t_s": 20.0, "f0_change": 0.01, "amplitude_change": 0.02},
    "heteroscedastic_noise": {"modulation": 0.3, "phase_rad": 1.0},
    "quantization": {"step_mm": 1.0, "offset_mm": 0.2, "dither_mm": 0.2},
    "motion_artefact": {"tap_spread_s": 0.05},
}


@pytest.fixture(scope="module")
def twin_parts():
    traj, _, truth = make_case(3, [], minutes=1.0, sensor="tof")
    df = validate_trajectory(traj)
    plates = sorted(int(p) for p in df["plate"].unique())
    # the plates' places along the span, as `calibrate` reads them from a config
    cal = SensorCalibration({}, {}, 0.0, 0.0, {p: (p - 0.5) / (len(plates) + 1) for p in plates})
    return df, truth["recording"]["f0_hz"], cal


@pytest.mark.parametrize("eid", sorted(SPECS))
def test_every_id_the_diagnosis_maps_changes_the_twins_output(eid, twin_parts):
    df, f0, cal = twin_parts
    spec = make_spec(eid, SPECS[eid])
    twin = Twin(df, f0, cal)
    assert twin.shows(spec, seed=1)
    base, with_it = twin.simulate((), 1), twin.simulate((spec,), 1)
    cols = ["t", "x", "y", "z"]
    assert np.nanmax(np.abs(base[cols].to_numpy() - with_it[cols].to_numpy())) > 1e-4
    # kept as simulated
    assert keep_shown(twin, [(spec, "simulated")], 1)[0][0] is spec


def test_an_effect_the_twin_cannot_render_is_not_called_simulated(twin_parts):
    df, f0, _ = twin_parts
    mode = make_spec("mode_shape", SPECS["mode_shape"])
    clip = make_spec("clipping", {"plate": int(df["plate"].iloc[0]), "level_mm": 0.5})
    twin = Twin(df, f0)  # no calibration: the plates' places along the span are unknown
    out = keep_shown(twin, [(mode, "simulated"), (clip, "simulated")], 1)
    assert [s for s, _ in out] == [None, None]
    assert all("changes nothing" in why for _, why in out)
    # a mode with the plates' places moves z in its own shape (antisymmetric for n = 2)
    cal = SensorCalibration({}, {}, 0.0, 0.0, {1: 0.25, 2: 0.75})
    d = (
        Twin(df, f0, cal).simulate((mode,), 1)["z"].to_numpy()
        - Twin(df, f0, cal).simulate((), 1)["z"].to_numpy()
    )
    p = df["plate"].to_numpy()
    if {1, 2} <= set(p):
        np.testing.assert_allclose(d[p == 1][:50], -d[p == 2][:50], atol=1e-9)


def test_a_motion_effect_reported_on_each_axis_is_injected_once():
    def line(axis, amp, freq=2.3):
        return {
            "id": "extra_periodic",
            "plates": [1, 2, 3],
            "axes": [axis],
            "parameters": {"freq_hz": {"value": freq}, "amplitude_mm": {"value": amp}},
        }

    def harmonic(axis):
        return {
            "id": "harmonic_distortion",
            "plates": [1, 2],
            "axes": [axis],
            "parameters": {"order": {"value": 2}, "amplitude_mm": {"value": 0.1}},
        }

    effects = [
        line("x", 0.05),
        line("z", 0.4),
        line("y", 0.02),
        line("z", 0.3, 5.1),
        harmonic("x"),
        harmonic("z"),
    ]
    mapped = specs_from_diagnosis(effects, duration_s=300.0, n_plates=4)
    specs = [s for s, _ in mapped if s is not None]
    assert sorted((s.id, s.p("freq_hz") if s.id == "extra_periodic" else 0) for s in specs) == [
        ("extra_periodic", 2.3),
        ("extra_periodic", 5.1),
        ("harmonic_distortion", 0),
    ]
    # the z report carries the mid-span amplitude the simulator injects
    assert mapped[1][0] is not None and mapped[1][0].p("amplitude_mm") == 0.4
    assert mapped[0][0] is None and "simulated once" in mapped[0][1]
    assert mapped[4][0] is None and mapped[5][0] is not None


def test_lognormal_null_band_is_a_95th_percentile_of_the_next_draw():
    rng = np.random.default_rng(0)
    exceed = []
    for _ in range(2000):
        d = np.exp(rng.normal(-1.0, 0.5, 9))
        band, how = null_95(d[:8])
        assert how == "lognormal"
        exceed.append(d[8] > band)
    # a prediction bound: 5 % of new draws above it, whatever n (binomial σ 0.5 %)
    assert abs(np.mean(exceed) - 0.05) < 0.015
    band, how = null_95(rng.random(40))
    assert how == "empirical" and 0.8 < band < 1.0
    # the empirical band of 20 renders is a 95th percentile of the next draw too (not a ~91st)
    exceed = []
    for _ in range(4000):
        d = rng.gamma(2.0, 1.0, 21)
        band, how = null_95(d[:20])
        assert how == "empirical"
        exceed.append(d[20] > band)
    assert abs(np.mean(exceed) - 1 / 21) < 0.01  # binomial σ 0.34 %


def test_a_recording_of_the_model_is_outside_some_family_band_at_most_5_percent_of_the_time():
    """`FAMILY` (9) metrics judged at once: at each one's 95 % band a recording of the simulated model lies
    outside one of them about 1 − 0.95⁹ = 37 % of the time; at the family band, about 5 %."""
    rng = np.random.default_rng(2)
    any95, anyfam = [], []
    for _ in range(1500):
        out95 = outfam = False
        for _metric in range(FAMILY):  # independent metrics, 20 null renders each (reconcile's)
            d = np.exp(rng.normal(-1.0, 0.5, 21))
            out95 |= d[20] > null_95(d[:20])[0]
            outfam |= d[20] > null_family(d[:20])
        any95.append(out95)
        anyfam.append(outfam)
    assert abs(np.mean(any95) - (1 - (20 / 21) ** FAMILY)) < 0.05
    assert abs(np.mean(anyfam) - 0.05) < 0.02  # binomial σ 0.6 %; the bound's own error


def test_the_family_band_of_pooled_frames_clips_is_its_percentile():
    rng = np.random.default_rng(3)
    m, s = 10, 0.05
    dist = lambda r: math.sqrt(np.mean(r**2))  # noqa: E731
    out = []
    for _ in range(6000):
        clips = [rng.normal(0, s, m) for _ in range(5)]
        out.append(dist(clips[4]) > pooled_null_95(clips[:4], FAMILY_Q))
    assert abs(np.mean(out) - (1 - FAMILY_Q)) < 0.004  # 0.0056 expected, binomial σ 0.001


def test_pooled_frames_band_is_a_95th_percentile_where_four_clips_give_an_80th():
    rng = np.random.default_rng(1)
    m, s = 10, 0.05
    ours, empirical = [], []
    for _ in range(2000):
        clips = [rng.normal(0, s, m) for _ in range(5)]
        band = pooled_null_95(clips[:4])
        dist = lambda r: math.sqrt(np.mean(r**2))  # noqa: E731
        ours.append(dist(clips[4]) > band)
        empirical.append(dist(clips[4]) > np.quantile([dist(c) for c in clips[:4]], 0.95))
    assert abs(np.mean(ours) - 0.05) < 0.015
    assert np.mean(empirical) > 0.15  # what the band from 4 clips' order statistic gave


def test_a_reference_plate_the_config_marks_defective_is_left_out():
    from jaxdefl._configs import resolve_config
    from jaxdefl.simulate import load_config, usable_reference

    cfg = load_config(resolve_config("exp1"))
    assert cfg.lds.defective_plate == 9
    ref = pd.DataFrame({"t": np.arange(6.0), "plate": [3, 9, 3, 9, 11, 9], "z": np.zeros(6)})
    kept, note = usable_reference(ref, cfg, "lds.csv")
    assert sorted(kept["plate"].unique()) == [3, 11] and len(kept) == 3
    assert "plate 9 left out" in note and "lds.csv" in note
    # only the defective plate: no reference at all, and the note says so
    none, note = usable_reference(ref[ref["plate"] == 9], cfg, "lds.csv")
    assert none is None and "without a reference" in note
    # nothing marked defective: the reference as it came
    good = dataclasses.replace(cfg, lds=dataclasses.replace(cfg.lds, defective_plate=0))
    same, note = usable_reference(ref, good)
    assert same is ref and note is None


def test_diagnose_with_a_config_ties_no_plate_to_its_defective_lds(tmp_path):
    from jaxdefl._configs import resolve_config
    from jaxdefl.pipeline import diagnose_file
    from jaxdefl.settings import DiagnoseSettings
    from jaxdefl.simulate import simulate_trajectories

    config = resolve_config("exp1")
    truth, lds = simulate_trajectories(config, 12.0, 3)
    rng = np.random.default_rng(0)
    for axis in "xyz":
        truth[axis] = truth[axis] + 0.05 * rng.standard_normal(len(truth))
    truth.to_csv(tmp_path / "traj.csv", index=False)
    lds.to_csv(tmp_path / "lds.csv", index=False)
    d = diagnose_file(
        tmp_path / "traj.csv",
        tmp_path / "diag.json",
        DiagnoseSettings(effects=("drift",)),  # the search is not what is tested
        reference=tmp_path / "lds.csv",
        config=config,
        figures=False,
        twins=0,
    )
    assert d["input"]["reference_plates"] == [3, 5, 7, 11]
    assert any("plate 9 left out of the reference" in n for n in d["notes"])
    # the sensor's 0.6 gain would have left a line at f0 on plate 9 (unexplained)
    assert not any(9 in u.get("plates", []) for u in d["unexplained"])


def _with_outliers(df, f0: float, seed: int, key=(7, "x"), rate: float = 0.01, size: float = 9.0):
    """``df`` with outliers of ±``size`` noise σ's on one series at ``rate`` (the chain's kind:
    a ToF camera's mixed-pixel frames on the plate under it)."""
    from jaxdefl.reconcile.metrics import series_residuals

    out = df.copy()
    rng = np.random.default_rng(seed)
    noise = series_residuals(df, f0)[key][2]
    rows = np.flatnonzero((out["plate"] == key[0]).to_numpy())
    hit = rows[rng.random(rows.size) < rate]
    out.loc[hit, key[1]] += rng.choice([-1.0, 1.0], hit.size) * size * noise
    return out


def test_the_twins_outlier_rate_null_covers_a_control_with_the_chains_outliers():
    # a control of a chain that makes outliers (here on plate 7 x), and a calibration clip of the
    # same chain: the twin calibrated on the clip renders them, so the control's outlier_rate is
    # inside its null band; the uncalibrated twin (none) puts it outside
    from jaxdefl.reconcile.engine import compare
    from jaxdefl.reconcile.sensor import _outliers

    traj, _, truth = make_case(5, [], minutes=1.5, sensor="tof")
    f0 = truth["recording"]["f0_hz"]
    rec = _with_outliers(validate_trajectory(traj), f0, seed=1)
    clip_traj, _, _ = make_case(6, [], minutes=1.0, sensor="tof")
    clip = _with_outliers(validate_trajectory(clip_traj), f0, seed=2)
    found = _outliers(clip, f0)
    n, sizes = found[(7, "x")]
    assert len(sizes) >= 2 and all(abs(u) > 4.5 for u in sizes)
    assert sum(len(v[1]) for k, v in found.items() if k != (7, "x")) <= 2  # Gaussian elsewhere
    cal = SensorCalibration({}, {}, 0.0, 0.0, {}, found)

    def outlier_row(calibration):
        levels, _ = compare(Twin(rec, f0, calibration), rec, n_sims=3, n_null=12, seed=3)
        return next(r for r in levels if r["metric"] == "outlier_rate")

    with_chain, without = outlier_row(cal), outlier_row(None)
    assert with_chain["before"] <= with_chain["null_95"], with_chain
    assert without["before"] > without["null_95"], without
    # the outliers are the twin's own: the same seed renders them the same with or without an effect
    twin = Twin(rec, f0, cal)
    a = twin.simulate((), 4)
    b = twin.simulate((make_spec("level_jump", {"t_jump_s": 30.0, "size_mm": 0.5}),), 4)
    np.testing.assert_array_equal(a["x"].to_numpy(), b["x"].to_numpy())


def test_a_line_reported_on_x_alone_is_injected_once_as_the_beams_motion():
    # the twin renders a line as the beam's motion on every series, in the way the series carries
    # the load; a diagnosis that reports it on x and y only (z left out) gives one injection, whose
    # mid-span amplitude and phase are refitted to the recording and reproduce it
    from jaxdefl.reconcile.engine import refine_motion_lines

    traj, _, truth = make_case(5, [], minutes=2.0, sensor="tof")
    df, f0 = validate_trajectory(traj), truth["recording"]["f0_hz"]
    twin = Twin(df, f0)
    line = make_spec("extra_periodic", {"freq_hz": 2.3, "amplitude_mm": 0.4, "phase_rad": 0.7})
    rec, base = twin.simulate((line,), 4), twin.simulate((), 4)
    t = df["t"].to_numpy() - df["t"].min()
    for key in ((7, "x"), (3, "z")):
        rows = (df["plate"] == key[0]).to_numpy()
        k = twin.transfer[key]
        assert abs(k) > 0.1
        want = k * 0.4 * np.cos(2 * math.pi * 2.3 * t[rows] + 0.7)
        np.testing.assert_allclose((rec[key[1]] - base[key[1]]).to_numpy()[rows], want, atol=1e-9)

    def report(axis, amp):
        return {
            "id": "extra_periodic",
            "plates": [1, 2, 3],
            "axes": [axis],
            "parameters": {"freq_hz": {"value": 2.3, "sigma": 1e-4}, "amplitude_mm": {"value": amp}},
        }

    mapped = specs_from_diagnosis([report("x", 0.09), report("y", 0.01)], duration_s=120.0, n_plates=13)
    specs = tuple(s for s, _ in mapped if s is not None)
    assert len(specs) == 1 and "simulated once" in mapped[1][1]
    (fitted,) = refine_motion_lines(twin, rec, specs)
    assert fitted.p("amplitude_mm") == pytest.approx(0.4, rel=0.05)  # z's fit: 0.6-mm noise
    assert math.cos(fitted.p("phase_rad") - 0.7) > 0.998
    # x carries the line as the transfer at f0 says: its gain against z's is 1
    assert twin.line_gain[("extra_periodic", 2.3)]["x"] == pytest.approx(1.0, abs=0.1)
    again = twin.simulate((fitted,), 4)
    assert np.nanmax(np.abs(again[["x", "y", "z"]].to_numpy() - rec[["x", "y", "z"]].to_numpy())) < 0.02


def test_the_twins_noise_leaves_out_a_named_line_it_renders():
    # a line well above f0 moves the series a lot from frame to frame: left in the noise level,
    # it would be rendered twice (once as noise, once as the line)
    from jaxdefl.reconcile.metrics import series_residuals

    traj, _, truth = make_case(5, [], minutes=1.0, sensor="tof")
    df, f0 = validate_trajectory(traj), truth["recording"]["f0_hz"]
    noise = {k: v[2] for k, v in series_residuals(df, f0).items()}
    lined = df.copy()
    t = lined["t"].to_numpy() - lined["t"].min()
    lined["z"] = lined["z"] + 3.0 * np.cos(2 * math.pi * 5.5 * t)
    twin = Twin(lined, f0)
    before = {(s.plate, s.axis): s.sigma for s in twin.series if s.axis == "z"}
    twin.noise_without_lines([5.5])
    after = {(s.plate, s.axis): s.sigma for s in twin.series if s.axis == "z"}
    for key, sigma in after.items():
        assert before[key] > 2 * noise[key]  # the line in the noise
        assert sigma == pytest.approx(noise[key], rel=0.1)  # the line left out


def test_the_twin_shares_a_plates_noise_across_axes_as_the_recording_does():
    # a ToF camera's range noise moves a centroid along its line of sight: a plate's x and z noise
    # are nearly one variable; the twin renders that correlation, measured on the recording
    from jaxdefl.reconcile.metrics import series_residuals

    traj, _, truth = make_case(5, [], minutes=1.0, sensor="tof")
    df, f0 = validate_trajectory(traj), truth["recording"]["f0_hz"]
    rng = np.random.default_rng(3)
    los = 1.5 * rng.standard_normal(len(df))  # along the line of sight
    df["z"] = df["z"] + los
    df["x"] = df["x"] - 0.5 * los
    twin = Twin(df, f0)

    def corr(table, plate):
        res = series_residuals(table, f0)
        return np.corrcoef(res[(plate, "z")][1], res[(plate, "x")][1])[0, 1]

    sim = twin.simulate((), 2)
    for plate in (2, 7):
        want = corr(df, plate)
        assert want < -0.3
        assert twin.axis_corr[plate][0, 1] == pytest.approx(want, abs=0.05)
        assert corr(sim, plate) == pytest.approx(want, abs=0.08)


def test_a_structured_light_cameras_configured_jumps_are_the_twins_not_missing_physics():
    # a control of a camera whose whole depth image steps (the configured Kinect: 1 a minute,
    # N(0, 3 mm)): the twin that draws the configured jumps has the recording's slow_mm,
    # line_ratio and outlier_rate inside their family bands; without them, slow_mm lies far outside
    from jaxdefl.reconcile.engine import Reconciliation, compare
    from jaxdefl.simulate.structured_light import session_offsets_mm

    traj, _, truth = make_case(7, [], minutes=3.0, sensor="tof")
    f0 = truth["recording"]["f0_hz"]
    rec = validate_trajectory(traj)
    gains = {(p, a): g for p in rec["plate"].unique() for a, g in (("z", 1.0), ("x", 0.3), ("y", -0.14))}
    cam = SimpleNamespace(jumps_per_minute=1.0, jump_mm=3.0, session_shift_mm=0.0)
    cfg = SimpleNamespace(camera=cam, t0_s=0.0)
    t = rec["t"].to_numpy() - rec["t"].min()
    step = session_offsets_mm(cfg, t, seed=11, duration_s=float(t.max()))
    assert np.unique(step).size >= 2  # the record has at least one jump
    for axis in ("z", "x", "y"):
        rec[axis] = rec[axis] + gains[(1, axis)] * step
    jumps = SensorCalibration({}, gains, 0.0, 0.0, {}, {}, jumps_per_minute=1.0, jump_mm=3.0)
    plain = SensorCalibration({}, gains, 0.0, 0.0, {}, {})
    judge = Reconciliation([], [], (), {}, f0)

    def rows(calibration):
        levels, _ = compare(Twin(rec, f0, calibration), rec, n_sims=3, n_null=20, seed=3)
        return {r["metric"]: r for r in levels}

    with_jumps, without = rows(jumps), rows(plain)
    for metric in ("slow_mm", "line_ratio", "outlier_rate", "noise_mm"):
        assert judge.verdict(with_jumps[metric]) == "agreed already", with_jumps[metric]
    assert without["slow_mm"]["before"] > 5 * without["slow_mm"]["null_family"], without["slow_mm"]
    # drawn anew per simulation, the same with or without an effect for one seed
    twin = Twin(rec, f0, jumps)
    a, b = twin.simulate((), 4), twin.simulate((), 5)
    assert not np.allclose(a["z"].to_numpy(), b["z"].to_numpy())
    c = twin.simulate((make_spec("extra_periodic", {"freq_hz": 2.3, "amplitude_mm": 0.01}),), 4)
    np.testing.assert_allclose(c["z"].to_numpy(), a["z"].to_numpy(), atol=0.02)
