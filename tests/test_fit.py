import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest
from astropy.timeseries import LombScargle
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import least_squares

from jaxdefl.fit import estimate_windows, fit_harmonic, fit_harmonics
from jaxdefl.io import validate_trajectory
from jaxdefl.series import make_windows
from jaxdefl.spectral import lomb_peaks


def _reference_fit(t, y):
    """The per-window recipe a user writes today: astropy periodogram, scipy 'lm', numpy covariance."""
    tc = t - 0.5 * (t[0] + t[-1])
    span = t[-1] - t[0]
    freq = np.arange(1, int(5 * span * 10)) / (5 * span)
    p = LombScargle(tc, y, fit_mean=False, center_data=True).power(freq, method="fast")
    om = 2 * np.pi * freq[np.argmax(p)]
    g = np.stack([np.cos(om * tc), np.sin(om * tc), np.ones_like(tc)], 1)
    c, d, e = np.linalg.lstsq(g, y, rcond=None)[0]

    def res(q):
        return y - (q[0] * np.cos(q[3] * tc) + q[1] * np.sin(q[3] * tc) + q[2])

    sol = least_squares(res, [c, d, e, om], method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15)
    q = sol.x
    cs, sn = np.cos(q[3] * tc), np.sin(q[3] * tc)
    jac = np.stack([cs, sn, np.ones_like(tc), tc * (-q[0] * sn + q[1] * cs)], 1)
    r = res(q)
    cov = np.sum(r**2) / (y.size - 4) * np.linalg.inv(jac.T @ jac)
    a = np.hypot(q[0], q[1])
    al = q[:2] / a
    return dict(
        f0=q[3] / (2 * np.pi),
        a=a,
        sigma_a=np.sqrt(al @ cov[:2, :2] @ al),
        sigma_f0=np.sqrt(cov[3, 3]) / (2 * np.pi),
        sigma_r=np.sqrt(np.sum(r**2) / (y.size - 4)),
    )


def test_agrees_with_astropy_scipy_reference(make_table):
    frames = [
        make_table(duration_s=d, amp=a, sigma=s, dropout=do, f0=f, seed=i, t0=1.7e9 + 1e4 * i).assign(
            plate=i + 1
        )
        for i, (d, a, s, do, f) in enumerate(
            [
                (60, 2.4, 0.76, 0.03, 3.0672),
                (30, 0.5, 0.4, 0.1, 1.028),
                (120, 0.05, 0.017, 0.05, 3.01),
                (45, 4.0, 2.5, 0.2, 0.95),
            ]
        )
    ]
    df = validate_trajectory(pd.concat(frames, ignore_index=True))
    w = make_windows(df, axes=("z",))
    est = estimate_windows(w)
    assert (est.table["status"] == "converged").all()
    for i in range(len(w)):
        m = w.mask[i]
        t = df[df["plate"] == i + 1]["t"].to_numpy()
        ref = _reference_fit(t, w.y[i, m])
        row = est.table.iloc[i]
        assert abs(row["f0_hz"] - ref["f0"]) < 0.05 * ref["sigma_f0"]
        assert abs(row["amplitude_mm"] - ref["a"]) < 0.05 * ref["sigma_a"]
        # The reference is the white-noise recipe (thesis 5.42-5.45): the white σ's.
        assert row["sigma_amplitude_white_mm"] == pytest.approx(ref["sigma_a"], rel=0.01)
        assert row["sigma_f0_white_hz"] == pytest.approx(ref["sigma_f0"], rel=0.01)
        assert row["sigma_residual_mm"] == pytest.approx(ref["sigma_r"], rel=0.01)


def test_thesis_day1_sigmas(make_table):
    """Table 6.17, Day 1 at 3 Hz: N = 35083, σ_r 0.76 mm, σ_A 0.0057 mm, σ_f0 7.43e-7 Hz."""
    df = validate_trajectory(make_table(duration_s=35083 / 20, dropout=0.0, amp=2.37, sigma=0.76, seed=11))
    est = estimate_windows(make_windows(df, axes=("z",)))
    row = est.table.iloc[0]
    assert row["n"] == 35083
    assert row["sigma_residual_mm"] == pytest.approx(0.76, rel=0.03)
    assert row["sigma_amplitude_mm"] == pytest.approx(0.0057, rel=0.15)
    assert row["sigma_f0_hz"] == pytest.approx(7.43e-7, rel=0.15)
    assert abs(row["f0_hz"] - 3.0672) < 4 * row["sigma_f0_hz"]
    assert abs(row["amplitude_mm"] - 2.37) < 4 * row["sigma_amplitude_mm"]


def test_coverage_at_thesis_snr():
    """Over many windows at thesis-like SNR, 95 % intervals contain the truth 93-97 % of the time."""
    rng = np.random.default_rng(2024)
    n_win, fs, dur = 1500, 20.0, 30.0
    n = int(fs * dur)
    f_true = rng.uniform(2.9, 3.1, n_win)
    a_true = rng.uniform(2.0, 2.6, n_win)
    ph = rng.uniform(0, 2 * np.pi, n_win)
    t = np.arange(n) / fs
    rows = []
    for i in range(n_win):
        keep = rng.random(n) > 0.03
        y = a_true[i] * np.cos(2 * np.pi * f_true[i] * t[keep] + ph[i]) + 0.76 * rng.standard_normal(
            keep.sum()
        )
        rows.append(pd.DataFrame({"t": t[keep] + 1.7e9, "plate": i, "z": y}))
    est = estimate_windows(make_windows(validate_trajectory(pd.concat(rows)), axes=("z",)))
    tab = est.table
    assert (tab["status"] == "converged").all()
    za = np.abs(tab["amplitude_mm"] - a_true) / tab["sigma_amplitude_mm"]
    zf = np.abs(tab["f0_hz"] - f_true) / tab["sigma_f0_hz"]
    for z in (za, zf):
        cover = np.mean(z < 1.959964)
        assert 0.93 <= cover <= 0.97, cover


def test_time_shift_of_1e9_s_changes_nothing(make_table):
    a = estimate_windows(
        make_windows(validate_trajectory(make_table(t0=100.0, duration_s=40, seed=5)), axes=("z",))
    )
    b = estimate_windows(
        make_windows(validate_trajectory(make_table(t0=100.0 + 1e9, duration_s=40, seed=5)), axes=("z",))
    )
    for c in ("f0_hz", "amplitude_mm", "sigma_amplitude_mm", "sigma_f0_hz", "offset_mm"):
        np.testing.assert_allclose(a.table[c], b.table[c], rtol=1e-7)
    # float64 epoch timestamps are rounded to ~1e-7 s: a phase difference of omega * 1e-7 rad.
    np.testing.assert_allclose(a.table["phase_rad"], b.table["phase_rad"], atol=1e-5)


@settings(max_examples=8, deadline=None)
@given(shift=st.floats(min_value=-1e9, max_value=1e9), seed=st.integers(0, 1000))
def test_time_shift_property(shift, seed):
    from conftest import harmonic_table

    base = harmonic_table(t0=1.7e9, duration_s=20, seed=seed)
    a = estimate_windows(make_windows(validate_trajectory(base), axes=("z",)))
    b = estimate_windows(make_windows(validate_trajectory(base.assign(t=base["t"] + shift)), axes=("z",)))
    # Equal to far below their own σ (the solver stops once a step is < 1e-2 σ).
    assert abs(a.fit.amplitude_mm[0] - b.fit.amplitude_mm[0]) < 1e-2 * a.fit.sigma_amplitude_mm[0]
    assert abs(a.fit.f0_hz[0] - b.fit.f0_hz[0]) < 1e-2 * a.fit.sigma_f0_hz[0]
    np.testing.assert_allclose(a.fit.sigma_f0_hz, b.fit.sigma_f0_hz, rtol=1e-4)


def test_vmap_equals_loop_and_jit_equals_eager(make_table):
    df = validate_trajectory(make_table(n_plates=3, duration_s=20, seed=8))
    w = make_windows(df, axes=("z",))
    p = lomb_peaks(w)
    batch = fit_harmonics(w, p.freq_hz)
    for i in range(len(w)):
        args = (
            jnp.asarray(w.t[i]),
            jnp.asarray(w.y[i]),
            jnp.asarray(w.mask[i].astype(float)),
            2 * np.pi * p.freq_hz[i],
        )
        eager = fit_harmonic(*args)
        jitted = jax.jit(fit_harmonic)(*args)
        assert float(eager["A"]) == pytest.approx(batch.amplitude_mm[i], rel=1e-10)
        assert float(jitted["A"]) == pytest.approx(float(eager["A"]), rel=1e-10)
        assert float(jitted["omega"]) == pytest.approx(float(eager["omega"]), rel=1e-12)
        assert float(eager["sigma_A"]) == pytest.approx(batch.sigma_amplitude_mm[i], rel=1e-8)


def test_weights_constant_equal_unweighted_and_calibrate_variance_factor():
    rng = np.random.default_rng(3)
    t = np.arange(1200) * 0.05
    sigma = np.where(np.arange(t.size) % 2 == 0, 0.2, 1.0)
    y = 2.0 * np.cos(2 * np.pi * 3.0 * t) + sigma * rng.standard_normal(t.size)
    w = make_windows(validate_trajectory(pd.DataFrame({"t": t, "plate": 1, "z": y})), axes=("z",))
    p = lomb_peaks(w)
    plain = fit_harmonics(w, p.freq_hz)
    const = fit_harmonics(w, p.freq_hz, weights=np.full(w.t.shape, 4.0))
    np.testing.assert_allclose(const.amplitude_mm, plain.amplitude_mm, rtol=1e-9)
    np.testing.assert_allclose(const.sigma_amplitude_mm, plain.sigma_amplitude_mm, rtol=1e-9)
    wts = np.zeros(w.t.shape)
    wts[0, : t.size] = 1 / sigma**2
    weighted = fit_harmonics(w, p.freq_hz, weights=wts)
    assert weighted.variance_factor[0] == pytest.approx(1.0, abs=0.1)
    assert weighted.sigma_amplitude_mm[0] < plain.sigma_amplitude_mm[0]


def test_statuses_never_abort_the_batch(make_table):
    rng = np.random.default_rng(0)
    good = make_table(duration_s=30, seed=1).assign(plate=1)
    noise = pd.DataFrame({"t": np.arange(600) * 0.05 + 1.7e9, "plate": 2, "z": rng.standard_normal(600)})
    few = pd.DataFrame({"t": 1.7e9 + np.arange(5) * 0.05, "plate": 3, "z": rng.standard_normal(5)})
    slow = pd.DataFrame(
        {
            "t": 1.7e9 + np.arange(600) * 0.05,
            "plate": 4,
            "z": np.cos(2 * np.pi * 0.02 * np.arange(600) * 0.05) * 5,
        }
    )
    df = validate_trajectory(pd.concat([good, noise, few, slow], ignore_index=True))
    est = estimate_windows(make_windows(df, axes=("z",)), fmin_hz=0.01)
    st = dict(zip(est.table["plate"], est.table["status"], strict=True))
    assert st == {
        1: "converged",
        2: "no_significant_peak",
        3: "too_few_samples",
        4: "too_few_cycles",
    }
    failed = est.table[est.table["status"] != "converged"]
    assert failed["amplitude_mm"].isna().all()
    assert np.isfinite(est.table.loc[est.table["plate"] == 1, "amplitude_mm"]).all()


def test_windows_split_and_align(make_table):
    df = validate_trajectory(make_table(n_plates=2, duration_s=300, seed=2, axes=("z", "x")))
    w = make_windows(df, axes=("z", "x"), window_s=60, step_s=30)
    tab = w.table
    assert len(tab) == 2 * 2 * 9
    assert tab.groupby(["plate", "axis"])["t_start"].apply(lambda s: np.allclose(np.diff(s), 30)).all()
    assert (tab["t_end"] - tab["t_start"] == 60).all()
    est = estimate_windows(w)
    assert (est.table["status"] == "converged").all()
    assert np.all(np.abs(est.table["f0_hz"] - 3.0672) < 5 * est.table["sigma_f0_hz"])


@pytest.mark.parametrize("scale", [1.0, 1e3, 1e6])
def test_sincos_matches_numpy(scale):
    from jaxdefl._sincos import sincos

    x = (np.random.default_rng(0).random(200_000) - 0.5) * 2 * scale
    s, c = jax.jit(sincos)(jnp.asarray(x))
    np.testing.assert_allclose(np.asarray(s), np.sin(x), rtol=0, atol=3e-16 * max(1.0, scale / 1e4))
    np.testing.assert_allclose(np.asarray(c), np.cos(x), rtol=0, atol=3e-16 * max(1.0, scale / 1e4))


@pytest.mark.parametrize("dropout", [0.7, 0.85])
def test_heavy_dropouts_keep_the_frame_clock(make_table, dropout):
    df = validate_trajectory(make_table(duration_s=30, dropout=dropout, seed=4))
    w = make_windows(df, axes=("z",))
    assert w.on_clock[0] and w.dt[0] == pytest.approx(0.05, rel=1e-9)
    est = estimate_windows(w)
    row = est.table.iloc[0]
    assert row["status"] == "converged"
    assert abs(row["f0_hz"] - 3.0672) < 5 * row["sigma_f0_hz"]


def test_phase_is_referenced_to_the_window_mid_time():
    rng = np.random.default_rng(1)
    t = 1.7e9 + np.arange(2400) * 0.05
    t = t[rng.random(t.size) > 0.2]
    t = t[t > t[0] + 7.3]  # the data do not start at the window start
    t_mid = 0.5 * (t[0] + t[-1])
    y = 2.0 * np.cos(2 * np.pi * 3.0 * (t - t_mid) - 0.7) + 0.05 * rng.standard_normal(t.size)
    est = estimate_windows(
        make_windows(validate_trajectory(pd.DataFrame({"t": t, "plate": 1, "z": y})), axes=("z",))
    )
    assert est.table["phase_rad"].iat[0] == pytest.approx(0.7, abs=0.01)


def test_plates_on_separate_clocks_in_one_segment():
    rng = np.random.default_rng(2)
    frames = []
    for plate, t0 in ((1, 1.7e9), (2, 1.7e9 + 5e3), (3, 1.7e9 + 2e4)):
        t = t0 + np.arange(1200) * 0.05
        z = 1.5 * np.cos(2 * np.pi * 2.9 * t + plate) + 0.3 * rng.standard_normal(t.size)
        frames.append(pd.DataFrame({"t": t, "plate": plate, "z": z}))
    est = estimate_windows(make_windows(validate_trajectory(pd.concat(frames)), axes=("z",)))
    assert (est.table["status"] == "converged").all()
    assert np.all(np.abs(est.table["f0_hz"] - 2.9) < 5 * est.table["sigma_f0_hz"])


@pytest.mark.parametrize("motion_hz, frame_hz, error_mm", [(1, 10, -0.061), (3, 10, -0.53), (3, 20, -0.14)])
def test_motion_artefact_response_matches_thesis_fig_6_9(motion_hz, frame_hz, error_mm):
    from jaxdefl.fit.motion import motion_artefact_response

    gain, lag = motion_artefact_response(motion_hz, frame_hz)
    assert 4.0 * (gain - 1) == pytest.approx(error_mm, abs=0.012)
    assert 0 < lag < np.pi / 2
    with pytest.raises(ValueError, match=r"tap_offsets: expected four offsets"):
        motion_artefact_response(3.0, 20.0, (0.0, 0.5))


@pytest.mark.parametrize("refine", [False, True])
def test_fit_residual_equals_the_numpy_residual_at_the_estimates(make_table, refine):
    """The residual the fit hands to the residual statistics (from its own last pass; with
    ``refine``, moved to the refined estimates to first order) is numpy's y - model at the
    reported parameters, on every valid sample, drop-outs included."""
    from jaxdefl.fit import harmonic_residual

    df = validate_trajectory(make_table(n_plates=3, duration_s=120, seed=4, axes=("z", "x")))
    w = make_windows(df, axes=("z", "x"), window_s=None if refine else 30.0)
    p = lomb_peaks(w)
    got = np.full(w.y.shape, np.nan)
    f = fit_harmonics(w, p.freq_hz, refine=refine, residual=got)
    assert f.converged.all()
    want = harmonic_residual(w, f.params)
    diff = np.abs(np.where(w.mask, got - want, 0.0)) / f.sigma_residual_mm[:, None]
    assert diff.max() < 1e-9, diff.max()
    # the numpy residual differs from the model at the loop's endpoint by more than that
    if refine:
        loop = fit_harmonics(w, p.freq_hz)
        moved = np.abs(np.where(w.mask, want - harmonic_residual(w, loop.params), 0.0))
        assert (moved / f.sigma_residual_mm[:, None]).max() > 1e-8
