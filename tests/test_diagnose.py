"""The diagnosis core: likelihood, variable projection, residual tests, search, JSON, CLI, errors."""

from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd
import pytest
from scipy import optimize, signal, stats

from jaxdefl._errors import InputError, ParameterError
from jaxdefl.cli import main
from jaxdefl.diagnose import EFFECT_IDS, State, diagnose, loglik, rms_equivalent, run_diagnosis
from jaxdefl.diagnose._varpro import fit_shared
from jaxdefl.diagnose.detectors.extra_periodic import _columns as line_columns
from jaxdefl.settings import DiagnoseSettings

F0 = 3.0672


def record(
    minutes=10.0,
    plates=5,
    fs=20.0,
    seed=0,
    sigma=0.76,
    dropout=0.03,
    line=None,
    t0=1.7e9,
    with_lds=False,
    rho=0.0,
    drift=None,
    ar=0.0,
):
    """Harmonic plates (+ white noise, drop-outs) and optionally a line (freq, amp) on z.

    ``rho``: share of the noise variance common to all plates of a frame (a ToF camera's
    frame-wide range error). ``drift``: (amp mm, τ s) of a warm-up a·exp(−t/τ) on every z.
    ``ar``: lag-one autocorrelation of the noise on the frame clock (AR(1), same variance).
    """
    rng = np.random.default_rng(seed)
    n = int(minutes * 60 * fs)
    t = np.arange(n) / fs
    t = t[rng.random(n) >= dropout]
    ph = rng.uniform(0, 2 * np.pi)
    common = {a: rng.standard_normal(t.size) for a in "xz"} if rho > 0 else {"x": 0.0, "z": 0.0}

    def noise(axis, s):
        e = math.sqrt(rho) * common[axis] + math.sqrt(1 - rho) * rng.standard_normal(t.size)
        if ar:
            e = signal.lfilter([math.sqrt(1 - ar * ar)], [1.0, -ar], e)
        return s * e

    rows = []
    for p in range(1, plates + 1):
        amp = 2.4 * math.sin(math.pi * p / (plates + 1))
        z = 1900 + amp * np.cos(2 * np.pi * F0 * t + ph) + noise("z", sigma)
        x = 10 + 0.5 * np.cos(2 * np.pi * F0 * t + ph) + noise("x", 0.3)
        if line is not None:
            z = z + line[1] * np.cos(2 * np.pi * line[0] * t + 0.4)
        if drift is not None:
            z = z + drift[0] * np.exp(-t / drift[1])
        rows.append(pd.DataFrame({"t": t0 + t, "plate": p, "x": x, "z": z}))
    traj = pd.concat(rows, ignore_index=True)
    if not with_lds:
        return traj
    tl = np.arange(int(minutes * 60 * 300)) / 300.0
    lds = pd.concat(
        [
            pd.DataFrame(
                {
                    "t": t0 + tl,
                    "plate": p,
                    "z": 2.4 * math.sin(math.pi * p / (plates + 1)) * np.cos(2 * np.pi * F0 * tl + ph)
                    + 0.002 * rng.standard_normal(tl.size),
                }
            )
            for p in (2, 4)
        ],
        ignore_index=True,
    )
    return traj, lds


# --- kernels against independent references -------------------------------------------------


def test_loglik_is_the_gaussian_likelihood_at_the_ml_sigma():
    rng = np.random.default_rng(1)
    y = rng.normal(0.3, 0.7, 5000)
    mean = np.full(y.size, 0.3)
    st = State(mean=mean, scale=np.ones(y.size), inlier=np.ones(y.size, bool))
    sigma = np.sqrt(np.mean((y - mean) ** 2))
    assert loglik(y, st) == pytest.approx(stats.norm.logpdf(y, mean, sigma).sum(), rel=1e-12)
    assert rms_equivalent(loglik(y, st), y.size) == pytest.approx(sigma, rel=1e-12)
    # a relative noise profile: the same as scipy with σ_i = σ̂ scale_i
    scale = 1 + 0.3 * np.cos(np.arange(y.size) / 50)
    st2 = st.with_(scale=scale)
    s_hat = np.sqrt(np.mean(((y - mean) / scale) ** 2))
    assert loglik(y, st2) == pytest.approx(stats.norm.logpdf(y, mean, s_hat * scale).sum(), rel=1e-12)


def test_shared_frequency_fit_matches_scipy_least_squares():
    rng = np.random.default_rng(2)
    ts = [np.sort(rng.uniform(0, 300, 3000)) for _ in range(3)]
    rs = [
        0.2 * (k + 1) * np.cos(2 * np.pi * 1.37 * t + k) + 0.5 * rng.standard_normal(t.size)
        for k, t in enumerate(ts)
    ]
    fit = fit_shared(
        line_columns,
        np.array([1.3702]),
        ts,
        rs,
        [np.ones(t.size) for t in ts],
        [np.ones((t.size, 1)) for t in ts],
        scale=np.array([1 / 300]),
    )

    def resid(p):
        f = p[0]
        out = []
        for k, (t, r) in enumerate(zip(ts, rs, strict=True)):
            a, b, c = p[1 + 3 * k : 4 + 3 * k]
            out.append(r - a * np.cos(2 * np.pi * f * t) - b * np.sin(2 * np.pi * f * t) - c)
        return np.concatenate(out)

    ref = optimize.least_squares(resid, np.r_[1.3702, np.zeros(9)], method="lm", xtol=1e-14, ftol=1e-14)
    jac = ref.jac
    s2 = np.sum(ref.fun**2) / (ref.fun.size - ref.x.size)
    sigma_f = math.sqrt(s2 * np.linalg.inv(jac.T @ jac)[0, 0])
    assert fit.converged
    assert abs(fit.theta[0] - ref.x[0]) < 0.01 * sigma_f
    assert math.sqrt(fit.theta_cov[0, 0]) == pytest.approx(sigma_f, rel=0.01)
    assert np.allclose(fit.beta[:, :2].ravel(), ref.x[1:].reshape(3, 3)[:, :2].ravel(), atol=1e-3 * 0.5 / 30)


def test_residual_tests_are_calibrated_on_white_noise():
    from jaxdefl.diagnose import Context, Harmonic, Series
    from jaxdefl.diagnose._whiteness import TESTS, residual_tests

    rng = np.random.default_rng(3)
    n = 2000
    t = np.arange(n) * 0.05
    series, nominal, states = [], [], []
    for i in range(300):
        y = rng.standard_normal(n)
        series.append(Series(i, "z", t, y, np.arange(n)))
        nominal.append(Harmonic(2 * np.pi * F0, 1.0, 0.0, 0.0, 50.0))
        states.append(State(np.zeros(n), np.ones(n), np.ones(n, bool)))
    ctx = Context(series, nominal, nominal, {}, {}, 0.0, t[-1], 0.05, n, F0)
    p = {k: np.array([residual_tests(ctx, i, states[i])[k]["p"] for i in range(300)]) for k in TESTS}
    for k, v in p.items():
        # each test is a valid (at most slightly conservative) p-value under white noise
        assert np.mean(v < 0.05) < 0.05 + 3 * math.sqrt(0.05 * 0.95 / 300), k
        assert np.mean(v < 0.5) > 0.3, k


# --- the search -----------------------------------------------------------------------------


@pytest.fixture(scope="module")
def clean():
    return diagnose(record(seed=11))


def test_clean_record_comes_back_clean(clean):
    assert clean["effects"] == []
    assert clean["unexplained"] == []
    assert clean["final"] == {**clean["final"], "rms_mm": clean["nominal"]["rms_mm"]}
    assert clean["nominal"]["whiteness_p"] > 0.01


def test_json_contract(clean):
    assert {"nominal", "effects", "unexplained", "final"} <= set(clean)
    for part in ("nominal", "final"):
        assert {"rms_mm", "bic", "whiteness_p"} <= set(clean[part])
    json.dumps(clean)  # JSON-able all the way down
    ids = {c["id"] for c in clean["cannot_tell"]}
    assert {"motion_artefact", "timing_error"} <= ids  # no reference given
    reasons = {c["id"]: c["reason"] for c in clean["cannot_tell"]}
    assert "reference" in reasons["motion_artefact"]


def test_extra_periodic_is_located_and_improves_the_fit():
    traj = record(seed=12, line=(1.37, 0.15))
    d = diagnose(traj)
    assert [e["id"] for e in d["effects"]] == ["extra_periodic"]
    e = d["effects"][0]
    assert e["plates"] == [1, 2, 3, 4, 5] and e["axes"] == ["z"]
    assert e["delta_bic"] < -10 and e["rms_after_mm"] < e["rms_before_mm"]
    par = e["parameters"]
    assert abs(par["freq_hz"]["value"] - 1.37) < 4 * par["freq_hz"]["sigma"]
    assert par["amplitude_mm"]["value"] == pytest.approx(0.15, rel=0.25)
    assert e["band_hz"][0] < 1.37 < e["band_hz"][1]
    assert e["t_start"] == pytest.approx(traj["t"].min()) and e["t_end"] == pytest.approx(traj["t"].max())
    assert d["final"]["bic"] < d["nominal"]["bic"]
    # the acceptance test as DIAG.json states it: a line's amplitude and phase (its frequency is
    # scanned), χ²₂ at α / (effects screened · frequencies scanned)
    assert e["lr_dof"] == 2 and e["trials"] > 100 and e["lr"] > e["lr_critical"]
    crit = e["lr_critical"]  # χ²₂'s quantile at the level: exp(−crit / 2) = level
    assert math.exp(-crit / 2) * e["trials"] < 0.05
    assert d["unexplained"] == []


def test_reference_ties_the_nominal_and_stays_clean():
    traj, lds = record(seed=13, with_lds=True)
    d = diagnose(traj, lds)
    tied = {(s["plate"], s["axis"]) for s in d["nominal"]["series"] if s["tied_to_reference"]}
    assert tied == {(2, "z"), (4, "z")}
    assert d["effects"] == [] and d["unexplained"] == []
    assert "motion_artefact" not in {c["id"] for c in d["cannot_tell"]}


def test_degenerate_inputs_say_cannot_tell():
    one = record(minutes=10, plates=1, seed=14)
    d = diagnose(one)
    assert d["input"]["plates"] == [1]
    short = record(minutes=0.2, plates=3, seed=15)  # 12 s: 37 loading cycles
    d = diagnose(short)
    ids = {c["id"] for c in d["cannot_tell"]}
    assert {"drift", "amplitude_modulation", "frequency_modulation"} <= ids
    assert not any(e["id"] in ids for e in d["effects"])
    for c in d["cannot_tell"]:
        assert c["reason"]


def test_noise_shared_by_the_plates_of_a_frame_is_not_an_effect():
    # A ToF frame's range error is largely common to all plates (thesis Tables 6.2/6.17; the
    # simulator's per-frame error). Counted as independent it reads as level jumps,
    # modulations and distortions alike on every plate (3-7 such effects per record before the
    # design effect); discounted, the record is clean and ρ is recovered.
    for seed in (0, 1):
        d = diagnose(record(plates=9, seed=seed, rho=0.85))
        assert d["effects"] == []
        for axis in ("x", "z"):
            assert d["nominal"]["frame_correlation"][axis] == pytest.approx(0.85, abs=0.03)
        assert any("correlated within a frame" in n for n in d["notes"])
    d = diagnose(record(plates=9, seed=2))
    assert all(v < 0.02 for v in d["nominal"]["frame_correlation"].values())
    assert not any("correlated within a frame" in n for n in d["notes"])


def test_a_common_line_is_still_found_under_frame_common_noise():
    # Against noise common to the plates only the frame-common part of the noise hides a
    # common line (σ √(ρ + (1 - ρ)/m) = 0.70 mm here): a 0.3 mm line (0.39 σ) is found.
    d = diagnose(record(plates=9, seed=3, rho=0.85, line=(1.37, 0.3)))
    assert [e["id"] for e in d["effects"]] == ["extra_periodic"]
    e = d["effects"][0]
    assert e["plates"] == list(range(1, 10)) and e["axes"] == ["z"]
    assert e["parameters"]["amplitude_mm"]["value"] == pytest.approx(0.3, rel=0.25)


def test_a_camera_warm_up_under_the_noise_is_a_drift_not_a_jump():
    # 0.12 mm decaying over 200 s on every plate (S ≈ 19 per series, too little alone): one
    # warm-up shared by the plates (τ and one amplitude) against one jump shared by them (a time
    # and one size) on the same data; the smooth approach fits better and is not called a step.
    d = diagnose(record(plates=9, seed=5, drift=(0.12, 200.0)))
    assert [e["id"] for e in d["effects"]] == ["drift"]
    e = d["effects"][0]
    assert e["plates"] == list(range(1, 10)) and e["axes"] == ["z"] and e["detail"]["mode"] == "common"
    p = e["parameters"]
    assert p["kind"]["value"] == "exponential"
    assert p["amplitude_mm"]["value"] == pytest.approx(0.12, rel=0.3)
    assert p["tau_s"]["value"] == pytest.approx(200.0, rel=0.4)


def test_a_line_below_every_plate_is_found_by_their_coherent_sum():
    # 0.04 mm at 2.31 Hz on every plate (S ≈ 16 per series: no plate pays for its own two
    # amplitudes): the plates' Fourier coefficients summed coherently find it, one amplitude
    # shared by the plates (3 parameters) models it.
    d = diagnose(record(plates=9, seed=4, line=(2.31, 0.04)))
    assert [e["id"] for e in d["effects"]] == ["extra_periodic"]
    e = d["effects"][0]
    assert e["plates"] == list(range(1, 10)) and e["detail"]["mode"] == "common"
    f = e["parameters"]["freq_hz"]
    assert abs(f["value"] - 2.31) < 4 * f["sigma"] < 1e-3
    assert e["parameters"]["amplitude_mm"]["value"] == pytest.approx(0.04, rel=0.3)


@pytest.mark.parametrize("ar, seed", [(0.6, 6), (0.8, 7)])
def test_noise_correlated_from_frame_to_frame_is_not_an_effect(ar, seed):
    # AR(1) noise wanders: counted as white it reads as level jumps on most plates (8 of them at
    # ρ = 0.8). The slow signatures weigh their statistics by the long-run variance.
    d = diagnose(record(plates=9, seed=seed, ar=ar))
    assert d["effects"] == []


def test_a_noise_free_table_says_cannot_tell():
    # A simulation's truth written with 6 decimals: any structure is "significant" against
    # rounding errors, so nothing is reported, with the reason.
    t = np.arange(6000) / 20.0
    rows = [
        pd.DataFrame(
            {
                "t": 1.7e9 + t,
                "plate": p,
                "x": np.round(10 + 0.5 * np.cos(2 * np.pi * F0 * t), 6),
                "z": np.round(1900 + 2.4 * p / 5 * np.cos(2 * np.pi * F0 * t), 6),
            }
        )
        for p in range(1, 6)
    ]
    d = diagnose(pd.concat(rows, ignore_index=True))
    assert d["effects"] == [] and d["unexplained"] == []
    assert {c["id"] for c in d["cannot_tell"]} == set(EFFECT_IDS)
    why = {c["id"]: c["reason"] for c in d["cannot_tell"]}
    assert "reference" in why["motion_artefact"]  # its own reason comes first
    assert all("noise" in why[e] for e in EFFECT_IDS if e not in ("motion_artefact", "timing_error"))


def test_only_named_effects_are_searched():
    # the line is outside the vocabulary searched: located and modelled as unnamed, never named
    d = diagnose(record(seed=16, line=(1.37, 0.15)), effects=("drift",))
    assert d["effects"] == []
    (u,) = d["unnamed"]
    assert u["kind"] == "line" and u["band_hz"][0] - 0.01 < 1.37 < u["band_hz"][1] + 0.01
    assert set(u["plates"]) <= {1, 2, 3, 4, 5} and u["axes"] == ["z"]
    assert u["parameters"]["freq_hz"]["value"] == pytest.approx(1.37, abs=2e-3)
    assert u["delta_bic"] < -10 and u["rms_after_mm"] < u["rms_before_mm"]
    assert "extra_periodic" not in u["explanation"]
    assert not any(u["test"] == "spectrum" for u in d["unexplained"])  # modelled, so explained
    d = diagnose(record(seed=16, line=(1.37, 0.15)), effects=("drift",), open_world=False)
    assert d["unnamed"] == [] and any(u["test"] == "spectrum" for u in d["unexplained"])


# --- errors and the CLI ---------------------------------------------------------------------


def test_errors_name_the_parameter():
    """Settings out of their domain fail when made, before any table is looked at; a segment
    the table lacks fails in the stage; both name the parameter (the CLI maps it to its flag)."""
    traj = record(minutes=1, plates=2)
    for kw, match in (
        (dict(sensor="lidar"), "sensor: expected one of tof, structured_light, lds, accelerometer, camera_tracking, logger, got 'lidar'"),
        (dict(frame_rate_hz=-1.0), "frame_rate_hz: expected a positive rate in Hz, got -1"),
        (dict(modulation_mhz=0.0), "modulation_mhz: expected a positive frequency"),
        (dict(effects=("wobble",)), "effects: unknown effect 'wobble'"),
        (dict(effects="drift,wobble"), "effects: unknown effect 'wobble'"),
        (dict(tap_offsets=(0.0, 0.5)), "tap_offsets: expected 4 fractions"),
    ):
        with pytest.raises(ParameterError, match=match):
            DiagnoseSettings(**kw)
    assert DiagnoseSettings(effects=" drift, outliers ").effects == ("drift", "outliers")
    two = pd.concat([traj.assign(segment="day1"), traj.assign(segment="day2", t=traj.t + 1e4)])
    with pytest.raises(ParameterError, match="segment: <table> has 2 segments .*choose one"):
        run_diagnosis(two)
    with pytest.raises(ParameterError, match="segment: 'day3' is not in"):
        run_diagnosis(two, settings=DiagnoseSettings(segment="day3"))
    with pytest.raises(InputError, match="timestamps, the diagnosis needs at least 64"):
        run_diagnosis(traj.groupby("plate").head(10))
    flat = traj.assign(z=1900.0 + np.random.default_rng(0).standard_normal(len(traj)), x=0.0)
    with pytest.raises(InputError, match="no plate and axis shows a significant periodic motion"):
        run_diagnosis(flat)


def test_cli_writes_json_report_and_figures(tmp_path):
    traj = record(seed=17, line=(1.37, 0.15))
    path = tmp_path / "traj.csv"
    traj.to_csv(path, index=False)
    out = tmp_path / "diag.json"
    assert main(["diagnose", str(path), "--out", str(out), "--sensor", "tof", "--frame-rate", "20"]) == 0
    d = json.loads(out.read_text())
    assert [e["id"] for e in d["effects"]] == ["extra_periodic"]
    assert d["settings"]["sensor"] == "tof" and d["input"]["frame_rate_hz"] == 20
    md = (tmp_path / "diag.md").read_text()
    assert "extra_periodic" in md and "ΔBIC" in md
    assert (tmp_path / "diag_1_extra_periodic.png").stat().st_size > 10_000


def test_cli_bad_arguments_exit_2(tmp_path, capsys):
    path = tmp_path / "traj.csv"
    record(minutes=1, plates=2).to_csv(path, index=False)
    assert main(["diagnose", str(path), "--out", str(tmp_path / "d.json"), "--sensor", "sonar"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--sensor" in err
    assert main(["diagnose", str(tmp_path / "missing.csv"), "--out", str(tmp_path / "d.json")]) == 2


def test_config_supplies_the_camera_facts(tmp_path):
    from jaxdefl.pipeline import _camera_facts

    facts = _camera_facts("configs/exp2_tof_3hz.toml")
    assert facts["sensor"] == "tof" and facts["frame_rate_hz"] == 20 and len(facts["tap_offsets"]) == 4
    assert _camera_facts("configs/exp2_kinect_3hz.toml")["sensor"] == "structured_light"


def test_every_effect_id_is_in_the_library():
    from jaxdefl.diagnose import load_detectors

    assert set(load_detectors()) == set(EFFECT_IDS)


def test_generator_frame_common_noise_is_recovered_and_comes_back_clean():
    # The concealed-effect benchmark's frame-common decoy, end to end: the table's noise is
    # shared by the plates of a frame as specified, and the diagnosis sees ρ and reports nothing.
    from jaxdefl.simulate.effects import RecordingSpec, make_recording

    spec = RecordingSpec(duration_s=300.0, n_plates=9, reference=False, frame_common=0.7)
    traj, _, truth = make_recording(spec, [], seed=5)
    assert truth["recording"]["frame_common"] == 0.7
    d = diagnose(traj, sensor="tof", frame_rate_hz=20.0)
    assert d["effects"] == []
    for axis, rho in d["nominal"]["frame_correlation"].items():
        assert rho == pytest.approx(0.7, abs=0.05), axis


@pytest.mark.parametrize("seed", [6, 7])
def test_line_of_sight_noise_is_counted_once_per_plate_not_once_per_axis(seed):
    # A ToF plate's x, y and z come from the same ranges along the same rays: its axes share one
    # noise (the extracted SR4000 frames give |ρ| 0.9-1.0). The generator reproduces it (the
    # correlation of a plate's axes is the line-of-sight share, signed by the ray), and the
    # diagnosis, which weighs evidence over the series jointly, reports nothing on such controls;
    # with the correlation taken axis by axis it counted each plate's noise three times.
    from jaxdefl.simulate.effects import RecordingSpec, make_recording

    spec = RecordingSpec(duration_s=180.0, n_plates=9, reference=False, frame_common=0.7, line_of_sight=0.9)
    traj, _, truth = make_recording(spec, [], seed=seed)
    assert truth["recording"]["line_of_sight"] == 0.9
    for plate, g in traj.groupby("plate"):
        w = 2 * np.pi * truth["recording"]["f0_hz"] * (g.t.to_numpy() - g.t.min())
        a = np.column_stack([np.ones_like(w), np.cos(w), np.sin(w)])
        rx, rz = (v - a @ np.linalg.lstsq(a, v, rcond=None)[0] for v in (g.x.to_numpy(), g.z.to_numpy()))
        assert abs(np.corrcoef(rx, rz)[0, 1]) == pytest.approx(0.9, abs=0.05), plate
    d = diagnose(traj, sensor="tof", frame_rate_hz=20.0)
    assert d["effects"] == [] and d["unnamed"] == []
    assert any("axes share their noise" in n for n in d["notes"])
