import numpy as np
import pandas as pd
import pytest
from astropy.timeseries import LombScargle

from jaxdefl import ConfigError
from jaxdefl.io import validate_trajectory
from jaxdefl.series import make_windows
from jaxdefl.spectral import (
    false_alarm_probability,
    lomb_peaks,
    lomb_slow,
    significance_level,
)


def _windows(make_table, t0=0.0, **kw):
    return make_windows(validate_trajectory(make_table(t0=t0, **kw)), axes=("z",))


@pytest.mark.parametrize("dropout", [0.0, 0.03, 0.3])
def test_grid_equals_slow_reference(make_table, dropout):
    w = _windows(make_table, duration_s=20, dropout=dropout, seed=3)
    assert w.on_clock[0]
    p = lomb_peaks(w, method="grid", keep=(0,))
    f, power = p.spectra[0]
    m = w.mask[0]
    ref = lomb_slow(w.t[0, m], w.y[0, m], f)
    np.testing.assert_allclose(power, ref, rtol=1e-8, atol=1e-8 * ref.max())


@pytest.mark.parametrize("search_dtype", ["float64", "float32"])
def test_a_grid_searched_in_sub_grids_equals_the_slow_reference(make_table, monkeypatch, search_dtype):
    """A grid longer than one FFT chunk is searched residue by residue (interleaved sub-grids,
    so that its memory does not grow with the oversampling): every bin and every peak is the
    one of the slow reference on the same grid."""
    import jaxdefl.spectral.lomb as lomb

    w = _windows(make_table, duration_s=20, dropout=0.05, seed=4, n_plates=3)
    monkeypatch.setattr(lomb, "_CHUNK_CELLS", 1 << 11)
    monkeypatch.setattr(lomb, "_SUB_CELLS", 1 << 10)
    strides = []
    strided = lomb._grid_batch_strided
    monkeypatch.setattr(
        lomb, "_grid_batch_strided", lambda *a, **k: strides.append(k["stride"]) or strided(*a, **k)
    )
    p = lomb_peaks(w, method="grid", keep=(1,), oversampling=7, search_dtype=search_dtype)
    f, power = p.spectra[1]
    assert strides and min(strides) > 1  # each window's grid was searched in sub-grids
    m = w.mask[1]
    ref = lomb_slow(w.t[1, m], w.y[1, m], f)
    tol = 1e-8 if search_dtype == "float64" else 1e-3
    np.testing.assert_allclose(power, ref, rtol=tol, atol=tol * ref.max())
    for r in range(w.y.shape[0]):
        m = w.mask[r]
        ref = lomb_slow(w.t[r, m], w.y[r, m], f)
        top = int(np.argmax(ref))
        assert abs(p.freq_hz[r] - f[top]) <= p.df_hz[r]
        np.testing.assert_allclose(p.power[r], ref[top], rtol=1e-10)


def test_nufft_equals_slow_reference_on_irregular_times():
    rng = np.random.default_rng(1)
    t = np.sort(rng.uniform(0, 30, 500))
    y = 1.5 * np.sin(2 * np.pi * 1.03 * t) + rng.standard_normal(t.size)
    w = make_windows(validate_trajectory(pd.DataFrame({"t": t, "plate": 1, "z": y})), axes=("z",))
    assert not w.on_clock[0]
    p = lomb_peaks(w, keep=(0,))
    assert p.method[0] == "nufft"
    f, power = p.spectra[0]
    m = w.mask[0]
    ref = lomb_slow(w.t[0, m], w.y[0, m], f)
    np.testing.assert_allclose(power, ref, atol=1e-6 * ref.max())
    assert abs(p.freq_hz[0] - 1.03) < 0.01


def test_thesis_pn_equals_astropy_standard_without_floating_mean(make_table):
    w = _windows(make_table, duration_s=15, seed=4)
    p = lomb_peaks(w, keep=(0,))
    f, power = p.spectra[0]
    m = w.mask[0]
    n = m.sum()
    ls = LombScargle(w.t[0, m], w.y[0, m], fit_mean=False, center_data=True, normalization="standard")
    ref = ls.power(f, method="slow") * (n - 1) / 2
    # The last bin is the exact Nyquist frequency, where astropy evaluates 0/0 without a guard.
    np.testing.assert_allclose(power[:-1], ref[:-1], rtol=1e-7, atol=1e-9)


def test_peak_is_refined_between_bins(make_table):
    w = _windows(make_table, duration_s=60, sigma=0.05, f0=2.71828, seed=5)
    p = lomb_peaks(w)
    assert abs(p.freq_hz[0] - 2.71828) < 0.05 * p.df_hz[0] * 5


def test_nyquist_bin_is_finite():
    t = np.arange(400) * 0.05
    y = np.cos(np.pi * t / 0.05) + 0.01 * np.random.default_rng(0).standard_normal(t.size)
    w = make_windows(validate_trajectory(pd.DataFrame({"t": t, "plate": 1, "z": y})), axes=("z",))
    p = lomb_peaks(w, keep=(0,))
    f, power = p.spectra[0]
    assert np.all(np.isfinite(power))
    assert f[-1] == pytest.approx(10.0)


def test_fap_round_trip_and_monotone():
    m = np.array([1.0, 10.0, 1000.0])
    for a in (0.001, 0.01, 0.5):
        z = significance_level(a, m)
        np.testing.assert_allclose(false_alarm_probability(z, m), a, rtol=1e-10)
    z = np.linspace(0, 30, 50)
    assert np.all(np.diff(false_alarm_probability(z, 100)) <= 0)


def test_fap_is_calibrated_on_null_data():
    """On white noise the peak FAP is (close to) uniform: P(FAP < a) ~ a."""
    rng = np.random.default_rng(7)
    n_win, n = 800, 256
    t = np.tile(np.arange(n) * 0.05, n_win)
    frames = pd.DataFrame(
        {"t": t, "plate": np.repeat(np.arange(n_win), n), "z": rng.standard_normal(n * n_win)}
    )
    w = make_windows(validate_trajectory(frames), axes=("z",))
    fap = lomb_peaks(w).fap
    for a in (0.1, 0.5):
        frac = np.mean(fap < a)
        # Press's M = N is approximate (oversampled grids and the floor on M): within a third.
        assert 0.6 * a < frac < 1.35 * a, (a, frac)


def test_band_errors(make_table):
    w = _windows(make_table, duration_s=10)
    with pytest.raises(ConfigError, match=r"--fmin/--fmax: expected fmin < fmax, got 5 and 2"):
        lomb_peaks(w, fmin_hz=5, fmax_hz=2)
    with pytest.raises(ConfigError, match=r"--fmin: expected >= 0 Hz, got -1"):
        lomb_peaks(w, fmin_hz=-1)
    with pytest.raises(ConfigError, match=r"fewer than 3 frequencies"):
        lomb_peaks(w, fmin_hz=3.0, fmax_hz=3.01)
    with pytest.raises(ConfigError, match=r"--oversampling: expected >= 1, got 0.5"):
        lomb_peaks(w, oversampling=0.5)
    with pytest.raises(ConfigError, match=r"method: expected one of auto, grid, nufft; got 'fft'"):
        lomb_peaks(w, method="fft")


def test_grid_method_refuses_irregular_times():
    t = np.sort(np.random.default_rng(0).uniform(0, 10, 100))
    w = make_windows(validate_trajectory(pd.DataFrame({"t": t, "plate": 1, "z": np.sin(t)})), axes=("z",))
    with pytest.raises(ConfigError, match=r"not on a regular frame clock; use 'nufft'"):
        lomb_peaks(w, method="grid")


def test_time_shift_invariance(make_table):
    a = lomb_peaks(_windows(make_table, t0=0.0, duration_s=30, seed=9))
    b = lomb_peaks(_windows(make_table, t0=1e9, duration_s=30, seed=9))
    np.testing.assert_allclose(a.freq_hz, b.freq_hz, rtol=1e-9)
    np.testing.assert_allclose(a.power, b.power, rtol=1e-6)


def test_float32_search_reports_the_exact_float64_peak(make_table):
    w = _windows(make_table, duration_s=60, seed=12, n_plates=4)
    a = lomb_peaks(w, search_dtype="float64")
    b = lomb_peaks(w, search_dtype="float32")
    np.testing.assert_allclose(b.power, a.power, rtol=1e-10)
    np.testing.assert_allclose(b.fap, a.fap, rtol=1e-8)
    np.testing.assert_allclose(b.freq_hz, a.freq_hz, atol=1e-4 * a.df_hz[0])
    with pytest.raises(ConfigError, match=r"search_dtype: expected float64 or float32, got 'float16'"):
        lomb_peaks(w, search_dtype="float16")


def test_clock_is_fitted_per_window_where_the_series_clock_breaks():
    """A logger restart shifts the clock by a fraction of a frame: each window keeps its grid."""
    t = np.arange(2400) * 0.05
    t[1200:] += 0.013
    y = np.cos(2 * np.pi * 3.0 * t)
    df = validate_trajectory(pd.DataFrame({"t": t, "plate": 1, "z": y}))
    w = make_windows(df, axes=("z",), window_s=60.0)
    assert len(w) == 2 and w.on_clock.all()
    # each window's stamps are its grid exactly (the offset is a constant within the window)
    for i in range(2):
        m = w.mask[i]
        rel = w.t[i, m] - w.t[i, m][0]
        assert np.max(np.abs(rel - w.k[i, m] * w.dt[i])) < 1e-9
    # the whole series scatters by 0.13 frame RMS about one clock: snapped to its grid
    whole = make_windows(df, axes=("z",))
    assert whole.on_clock[0] and whole.dt[0] == pytest.approx(0.05, rel=1e-3)
    p = lomb_peaks(whole)
    assert p.method[0] == "grid" and abs(p.freq_hz[0] - 3.0) < 0.01
