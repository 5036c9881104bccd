"""Model adequacy (r2, Ljung-Box whiteness) and the noise colour behind the default σ's."""

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy import signal, stats

from jaxdefl.fit import estimate_windows, frame_positions, residual_noise
from jaxdefl.io import validate_trajectory
from jaxdefl.series import make_windows
from jaxdefl.uncertainty import WHITENESS_P_MIN, noise_series, uncertainty_table

CONFIGS = Path(__file__).parents[1] / "configs"


def _ljung_box_slow(r: np.ndarray, k: np.ndarray, lags: int) -> float:
    """Ljung-Box p of residuals ``r`` at frame indices ``k`` (a sorted subset of a frame clock):
    autocorrelations over the pairs each lag has, Q = n(n+2) Σ ρ_h² / n_h (Ljung & Box 1978 when
    no frame is missing: n_h = n - h)."""
    r = r - r.mean()
    n = r.size
    pos = {int(kk): i for i, kk in enumerate(k)}
    q = 0.0
    for h in range(1, lags + 1):
        prods = [r[i] * r[pos[int(kk) + h]] for i, kk in enumerate(k) if int(kk) + h in pos]
        if prods:
            rho = np.sum(prods) / np.sum(r**2)
            q += rho**2 / len(prods)
    return float(stats.chi2.sf(n * (n + 2) * q, lags))


def _table(y: np.ndarray, fs=20.0, dropout=0.0, seed=0) -> pd.DataFrame:
    rng = np.random.default_rng(seed)
    b, n = y.shape
    keep = rng.random((b, n)) >= dropout
    keep[:, 0] = keep[:, -1] = True
    t = np.broadcast_to(1.7e9 + np.arange(n) / fs, (b, n))
    plate = np.repeat(np.arange(b), n).reshape(b, n)
    return validate_trajectory(pd.DataFrame({"t": t[keep], "plate": plate[keep], "z": y[keep]}))


def _harmonic(b, n, amp=2.5, sigma=0.75, f0=3.0, fs=20.0, seed=0, kind="white", rho=0.6):
    rng = np.random.default_rng(seed)
    t = np.arange(n) / fs
    ph = rng.uniform(0, 2 * np.pi, b)
    return amp * np.cos(2 * np.pi * f0 * t + ph[:, None]) + sigma * noise_series(rng, b, n, kind, rho)


@pytest.mark.parametrize("dropout", [0.0, 0.2])
def test_ljung_box_matches_a_slow_reference(dropout):
    df = _table(_harmonic(6, 400, seed=1), dropout=dropout, seed=2)
    est = estimate_windows(make_windows(df, axes=("z",)))
    w, f = est.windows, est.fit
    g, _ = frame_positions(w, np.arange(len(w)))
    for i in range(len(w)):
        m = w.mask[i]
        r = w.y[i, m] - (f.params[i, 0] * np.cos(f.params[i, 3] * w.t[i, m])
                         + f.params[i, 1] * np.sin(f.params[i, 3] * w.t[i, m]) + f.params[i, 2])
        want = _ljung_box_slow(r, g[i, m], int(est.noise.lags[i]))
        assert est.table["whiteness_p"].iat[i] == pytest.approx(want, rel=1e-6, abs=1e-12)


def test_whiteness_p_is_uniform_under_white_noise_and_r2_is_the_explained_share():
    est = estimate_windows(make_windows(_table(_harmonic(300, 600, seed=3), seed=4), axes=("z",)))
    p = est.table["whiteness_p"].to_numpy()
    assert stats.kstest(p, "uniform").pvalue > 1e-3
    assert np.mean(p < WHITENESS_P_MIN) < 0.01
    # E[r2] = (A²/2) / (A²/2 + σ²) for a harmonic in white noise
    assert np.median(est.table["r2"]) == pytest.approx(3.125 / (3.125 + 0.5625), abs=0.01)
    assert (est.noise.kappa > 0.6).all() and (est.noise.kappa < 1.6).all()
    assert np.median(est.noise.kappa) == pytest.approx(1.0, abs=0.03)


@pytest.mark.parametrize("rho,f0", [(0.6, 1.0), (0.9, 3.0), (-0.5, 3.0)])
def test_kappa_follows_the_ar1_spectrum_at_f0(rho, f0):
    """The residual's density near f0 over its mean is, for AR(1) noise, (1 - ρ²) / |1 - ρ e^{-iωdt}|²."""
    df = _table(_harmonic(100, 600, f0=f0, seed=5, kind="ar1", rho=rho), seed=6)
    est = estimate_windows(make_windows(df, axes=("z",)), fmin_hz=0.6 * f0, fmax_hz=1.4 * f0)
    want = (1 - rho**2) / abs(1 - rho * np.exp(-2j * np.pi * f0 / 20.0)) ** 2
    assert np.median(est.noise.kappa) == pytest.approx(want, rel=0.1)
    assert (est.table["whiteness_p"] < WHITENESS_P_MIN).mean() > 0.9
    ratio = est.table["sigma_amplitude_mm"] / est.table["sigma_amplitude_white_mm"]
    np.testing.assert_allclose(ratio, np.sqrt(est.noise.kappa))


def test_broadband_record_is_an_inadequate_model_and_a_thesis_window_is_not():
    """Filtered random noise (no harmonic) in 30-s windows: the periodogram still finds a peak and
    the fit converges, but the residual is far from white and the harmonic explains little, so
    the trust column says inadequate_model. Harmonics at the thesis' SNR, white and AR(1), do not."""
    rng = np.random.default_rng(7)
    n = 600
    broad = []
    for cut in (0.5, 2.0, 5.0):
        b, a = signal.butter(4, cut, fs=20.0)
        broad.append(signal.lfilter(b, a, rng.standard_normal((4, 4 * n)), axis=1)[:, -n:])
    b, a = signal.butter(4, (1.0, 5.0), btype="band", fs=20.0)
    broad.append(signal.lfilter(b, a, rng.standard_normal((4, 4 * n)), axis=1)[:, -n:])
    y = np.concatenate(broad + [_harmonic(4, n, seed=8), _harmonic(4, n, seed=9, kind="ar1", rho=0.6)])
    est = estimate_windows(make_windows(_table(y, seed=10), axes=("z",)), fap_max=1.0)
    unc = uncertainty_table(est)
    noise = (np.arange(len(y)) < 16) & (est.table["status"] == "converged").to_numpy()
    good = slice(16, 24)
    assert noise.sum() >= 12  # the slowest noise may leave too few cycles in a window
    assert (est.table["whiteness_p"][noise] < WHITENESS_P_MIN).all()
    assert (unc["trust_amplitude"][noise] == "inadequate_model").all()
    assert (unc["trust_f0"][noise] == "inadequate_model").all()
    assert (unc["trust_amplitude"].iloc[good] == "linearised").all(), unc.iloc[good]
    assert (unc["flag"].iloc[20:24] == "coloured_noise").all()  # AR(1): trusted, σ's coloured


def test_residual_noise_leaves_unfitted_windows_nan():
    est = estimate_windows(make_windows(_table(_harmonic(2, 200, seed=1)), axes=("z",)))
    res = np.random.default_rng(0).standard_normal(est.windows.y.shape)
    out = residual_noise(est.windows, res, np.array([3.0, np.nan]))
    assert np.isnan(out.kappa[1]) and np.isnan(out.whiteness_p[1])
    assert np.isfinite(out.kappa[0])


@pytest.mark.slow
@pytest.mark.parametrize("config", ["exp2_tof_3hz.toml", "exp2_tof_1hz.toml"])
def test_thesis_simulated_days_are_not_inadequate(config):
    """The simulator's Experiment II day 1 (ToF camera noise, frame-common range error, drop-outs):
    a 30-s window of every plate and axis keeps trust ``linearised`` (never inadequate_model)."""
    from jaxdefl.simulate import load_config, measured_centroids, render_frames

    cfg = load_config(CONFIGS / config, "day1")
    t, frames, _, _ = render_frames(cfg, duration_s=30.0, seed=3)
    traj = validate_trajectory(measured_centroids(cfg, t, frames))
    est = estimate_windows(make_windows(traj, axes=("z", "x", "y"), window_s=30.0))
    unc = uncertainty_table(est)
    fitted = unc["trust_amplitude"] != "none"
    assert fitted.sum() >= 12
    assert not (unc["trust_amplitude"] == "inadequate_model").any(), unc[unc.flag != "ok"]
    assert (est.table["r2"][fitted] > 0.5).all()
