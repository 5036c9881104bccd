"""Timestamps as real devices write them (issue 13, items 1 and 5): the recovered sample clock,
``--timestamps strict|reclock|merge``, jittered clocks on the batched path, units plausibility and
datetime columns.

Truth is always the simulated clock and signal: the clock fit must give back the integer frame
indices and the interval; a reclocked fit must equal the fit on the true timestamps; a jittered
clock must lose no frames and stay on the batched periodogram.
"""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from jaxdefl import ConfigError, InputError
from jaxdefl.cli import main
from jaxdefl.fit import estimate_windows
from jaxdefl.io import validate_trajectory
from jaxdefl.series import frame_clock, make_windows
from jaxdefl.series.clock import fit_clock

LOGGER_DT = 0.0077531  # the fatigue-rig logger


def cli(*args) -> int:
    return main([str(a) for a in args])


def _five_digits(t: np.ndarray) -> list[str]:
    return [f"{v:.5g}" for v in t]


def _ar1(rng, n: int, rho: float, sigma: float) -> np.ndarray:
    """AR(1) noise of marginal σ ``sigma``: slow thermal and frame-common errors."""
    e = rng.standard_normal(n) * sigma * np.sqrt(1 - rho**2)
    out = np.empty(n)
    out[0] = sigma * rng.standard_normal()
    for i in range(1, n):
        out[i] = rho * out[i - 1] + e[i]
    return out


def _jittered_table(seed, jitter_s=0.005, dropout=0.03, duration_s=120.0, noise="white", n_plates=3):
    """Camera frames at 20 Hz whose sample times jitter (the stamps are the sample times)."""
    rng = np.random.default_rng(seed)
    k = np.arange(int(duration_s * 20))
    k = k[rng.random(k.size) >= dropout]
    t = np.sort(k / 20.0 + rng.normal(0.0, jitter_s, k.size))  # a file lists frames in time order
    frames = []
    for p in range(1, n_plates + 1):
        ph = rng.uniform(0, 2 * np.pi)
        e = _ar1(rng, t.size, 0.6, 0.5) if noise == "ar1" else 0.5 * rng.standard_normal(t.size)
        z = 1900.0 + 2.0 * np.cos(2 * np.pi * 3.0672 * t + ph) + e
        frames.append(pd.DataFrame({"t": 1.7e9 + t, "plate": p, "z": z}))
    out = pd.concat(frames, ignore_index=True)
    out.attrs["frames"] = k  # the true frame index of every stamp (in time order)
    return out, 1.0 - k.size / (k[-1] + 1)


# -- the clock fit against the simulated clock -----------------------------------------------


@pytest.mark.parametrize(
    "jitter_frames, dropout",
    [(0.0, 0.85), (0.01, 0.03), (0.1, 0.03), (0.1, 0.3), (0.1, 0.85)],
)
def test_clock_fit_recovers_every_frame_index(jitter_frames, dropout):
    rng = np.random.default_rng(7)
    k = np.sort(rng.choice(6000, int(6000 * (1 - dropout)), replace=False))
    t = k * 0.05 + rng.normal(0, jitter_frames * 0.05, k.size)
    c = fit_clock(t - t[0])
    assert np.array_equal(c.k, k - k[0])
    assert abs(c.dt - 0.05) < 1e-6
    if jitter_frames:
        assert c.jitter_rms == pytest.approx(jitter_frames * 0.05, rel=0.1)


def test_clock_fit_reads_a_rounding_logger():
    """Five significant digits of k × 0.0077531 s: past 100 s the rounding step (10 ms) exceeds
    the interval, so stamps repeat; every row is still its own frame."""
    k = np.arange(21000)
    t = np.array(_five_digits(k * LOGGER_DT), dtype=float)
    assert (np.diff(t) == 0).sum() > 1000
    c = fit_clock(t)
    assert np.array_equal(c.k, k)
    assert abs(c.dt - LOGGER_DT) < 1e-9
    assert abs(c.drift_ppm) < 1.0


def test_frame_rate_hint_finds_the_clock_when_most_frames_are_lost():
    """With 95 % of frames lost and jitter, the spacings rarely show one frame; the nominal
    frame rate (diagnose's --frame-rate) starts the fit on the right interval."""
    rng = np.random.default_rng(2)
    k = np.sort(rng.choice(40000, 2000, replace=False))
    t = k * 0.05 + rng.normal(0, 0.002, k.size)
    dt, kk, on = frame_clock(t - t[0], hint=0.05)
    assert abs(dt - 0.05) < 1e-6 and np.array_equal(kk, k - k[0]) and on


# -- --timestamps reclock / strict / merge on the logger -----------------------------


@pytest.fixture(scope="module")
def logger_files(tmp_path_factory):
    d = tmp_path_factory.mktemp("logger")
    rng = np.random.default_rng(21)
    k = np.arange(21000)
    t = k * LOGGER_DT
    z = 0.8 * np.cos(2 * np.pi * 1.0 * t + 0.3) + 0.05 * rng.standard_normal(k.size)
    pd.DataFrame({"t": _five_digits(t), "plate": 1, "z": z}).to_csv(d / "logger.csv", index=False)
    pd.DataFrame({"t": t, "plate": 1, "z": z}).to_csv(d / "exact.csv", index=False, float_format="%.12g")
    return d


def test_strict_names_reclock_and_reclock_fits_like_the_true_clock(logger_files, capsys):
    d = logger_files
    assert cli("fit", d / "logger.csv", "--out", d / "strict.csv") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--timestamps reclock" in err[0] and "--timestamps merge" in err[0], err
    assert "logger.csv: row " in err[0] and not (d / "strict.csv").exists()

    assert cli("fit", d / "logger.csv", "--out", d / "re.csv", "--timestamps", "reclock") == 0
    note = [line for line in capsys.readouterr().err.splitlines() if "reclocked" in line]
    assert len(note) == 1 and "interval 0.007753" in note[0] and "drift" in note[0], note
    clock = json.loads((d / "re.json").read_text())["clock"]["trajectory"]["segments"][0]
    assert abs(clock["interval_s"] - LOGGER_DT) < 1e-6
    # the rounding step is up to 10 ms: uniform, RMS below 10 ms / √12 and above 1 ms / √12
    assert 1e-3 / np.sqrt(12) < clock["jitter_rms_s"] < 1e-2 / np.sqrt(12)
    assert cli("fit", d / "exact.csv", "--out", d / "exact_est.csv") == 0
    re, ex = pd.read_csv(d / "re.csv").iloc[0], pd.read_csv(d / "exact_est.csv").iloc[0]
    assert re["status"] == "converged"
    # against the simulated truth, and against the fit on the true timestamps (same samples)
    assert abs(re["f0_hz"] - 1.0) < 2 * re["sigma_f0_hz"]
    assert abs(re["amplitude_mm"] - 0.8) < 2 * re["sigma_amplitude_mm"]
    assert abs(re["f0_hz"] - ex["f0_hz"]) < 0.01 * ex["sigma_f0_hz"]
    assert abs(re["amplitude_mm"] - ex["amplitude_mm"]) < 0.01 * ex["sigma_amplitude_mm"]


def test_merge_averages_duplicates_and_strict_refuses_them(tmp_path, capsys):
    df = pd.DataFrame(
        {
            "t": [0.0, 0.0, 0.05, 0.05, 0.10],
            "plate": [1, 1, 1, 1, 1],
            "z": [1.0, 3.0, np.nan, 2.0, 4.0],
        }
    )
    got = validate_trajectory(df, "dup.csv", timestamps="merge")
    assert got["t"].tolist() == [0.0, 0.05, 0.10]
    assert got["z"].tolist() == [2.0, 2.0, 4.0]  # a missing value does not count
    assert got.attrs["timestamps"] == {"policy": "merge", "rows_merged": 2, "rows": 3}
    with pytest.raises(
        InputError, match=r"dup.csv: row 3: plate 1 repeats t=0.0 of row 2 .*--timestamps merge"
    ):
        validate_trajectory(df, "dup.csv")
    with pytest.raises(
        ConfigError, match=r"--timestamps: expected one of strict, reclock, merge, got 'bogus'"
    ):
        validate_trajectory(df, "dup.csv", timestamps="bogus")


# -- jittered camera clocks: no frame lost, batched --------------------------------------------


@pytest.fixture
def no_one_window_loop(monkeypatch):
    """The non-uniform periodogram must not be reached: jittered windows stay on the batched
    frame grid."""
    import jaxdefl.spectral.lomb as lomb

    def refuse(*a, **k):
        raise AssertionError("a window left the batched periodogram")

    monkeypatch.setattr(lomb, "_peaks_nufft", refuse)


@pytest.mark.parametrize("noise", ["white", "ar1"])
def test_jitter_of_5_ms_at_20_hz_loses_no_frame_and_stays_batched(noise, no_one_window_loop):
    from jaxdefl.uncertainty import honesty_features

    df, lost = _jittered_table(seed=31 if noise == "white" else 32, noise=noise)
    w = make_windows(validate_trajectory(df), axes=("z",), window_s=30.0)
    assert w.on_clock.all()
    np.testing.assert_allclose(w.dt, 0.05, rtol=1e-4)
    est = estimate_windows(w)
    assert set(est.periodogram.method) == {"grid"}
    feat = honesty_features(est)
    # the frames are all there but the drop-outs: counted on the recovered clock
    assert np.all(np.abs(feat["missing"].to_numpy() - lost) < 0.02), feat["missing"].tolist()
    tab = est.table
    assert (tab["status"] == "converged").all()
    # against the truth (AR(1) ρ 0.6 at 20 Hz is nearly white near 3 Hz: the σ's still hold)
    z_f = np.abs(tab["f0_hz"] - 3.0672) / tab["sigma_f0_hz"]
    z_a = np.abs(tab["amplitude_mm"] - 2.0) / tab["sigma_amplitude_mm"]
    assert z_f.max() < 4.0 and z_a.max() < 4.0, (z_f.tolist(), z_a.tolist())


def test_jitter_gives_the_same_estimates_as_a_perfect_clock():
    """Same signal and noise, sampled on a jittered and on a perfect clock: the estimates agree
    well within their σ (the fit uses the stamps; only the periodogram snaps them)."""
    jit, _ = _jittered_table(seed=41, n_plates=2)
    perfect, _ = _jittered_table(seed=41, n_plates=2, jitter_s=0.0)
    a = estimate_windows(make_windows(validate_trajectory(jit), axes=("z",))).table
    b = estimate_windows(make_windows(validate_trajectory(perfect), axes=("z",))).table
    assert (a["status"] == "converged").all() and (b["status"] == "converged").all()
    assert np.all(np.abs(a["amplitude_mm"] - b["amplitude_mm"]) < 0.5 * b["sigma_amplitude_mm"])
    assert np.all(np.abs(a["f0_hz"] - b["f0_hz"]) < 0.5 * b["sigma_f0_hz"])


def test_jitter_beyond_a_quarter_frame_takes_the_batched_non_uniform_path(monkeypatch):
    """20 ms RMS at 20 Hz is 0.4 frame: off the grid, so nifty-ls, one call per window span for
    all the plates sharing its frames (not one per window), equal to the direct sums."""
    import nifty_ls

    from jaxdefl.spectral import lomb_peaks, lomb_slow

    calls = []
    real = nifty_ls.lombscargle

    def counting(t, y, *a, **k):
        calls.append(np.shape(y))
        return real(t, y, *a, **k)

    monkeypatch.setattr(nifty_ls, "lombscargle", counting)
    df, _ = _jittered_table(seed=8, jitter_s=0.020, duration_s=62.0, n_plates=3)
    w = make_windows(validate_trajectory(df), axes=("z",), window_s=30.0)
    assert len(w) == 6 and not w.on_clock.any()
    p = lomb_peaks(w, keep=(0, 2))
    assert set(p.method) == {"nufft"}
    assert len(calls) == 2 and all(shape[0] == 3 for shape in calls)
    for r in (0, 2):
        f, power = p.spectra[r]
        m = w.mask[r]
        ref = lomb_slow(w.t[r, m], w.y[r, m], f)
        np.testing.assert_allclose(power, ref, atol=1e-6 * ref.max())
    assert np.all(np.abs(p.freq_hz - 3.0672) < 0.01)


@pytest.mark.slow
def test_diagnosis_grids_follow_the_recovered_clock_and_the_frame_rate():
    """5 ms of jitter at 20 Hz: the diagnosis' frame grid is the 20 Hz clock (the smallest
    spacing would be ~30 ms), every sample on its own frame; --frame-rate starts the fit."""
    from jaxdefl.diagnose import build_context
    from jaxdefl.settings import DiagnoseSettings

    df, _ = _jittered_table(seed=12, duration_s=40.0, n_plates=2)
    t = np.unique(df["t"].to_numpy())
    true_k = df.attrs["frames"] - df.attrs["frames"][0]
    for rate in (None, 20.0):
        ctx, _, notes = build_context(df, settings=DiagnoseSettings(frame_rate_hz=rate, axes=("z",)))
        assert abs(ctx.dt_s - 0.05) < 1e-5 and ctx.frame_rate_hz == pytest.approx(20.0, rel=1e-4)
        s = ctx.series[0]
        np.testing.assert_array_equal(s.k, true_k[np.searchsorted(t - t[0], s.t)])
        assert not any("not on a regular frame clock" in n for n in notes)


# -- units ------------------------------------------------------------------------------------


def _plain_table(t, z, t_name="t", z_name="z"):
    return pd.DataFrame({t_name: t, "plate": 1, z_name: z})


@pytest.mark.parametrize(
    "scale, name",
    [(1e3, "t_ms"), (1e6, "t_us"), (1e9, "t_ns")],
)
def test_epoch_in_sub_second_units_is_an_error_naming_the_unit(scale, name):
    t = (1.7e9 + np.arange(40) * 0.05) * scale
    z = np.cos(np.arange(40))
    with pytest.raises(
        InputError, match=rf"x.csv: column 't' has no unit .* rename the column {name} .* t_s"
    ):
        validate_trajectory(_plain_table(t, z), "x.csv")
    got = validate_trajectory(_plain_table(t, z, t_name=name), "x.csv")
    np.testing.assert_allclose(got["t"], 1.7e9 + np.arange(40) * 0.05, rtol=0, atol=2e-6)


def test_metres_for_a_sub_mm_motion_is_an_error_and_a_unit_confirms():
    rng = np.random.default_rng(3)
    t = np.arange(200) * 0.05
    z_m = 1.9 + 0.0005 * np.cos(2 * np.pi * 3 * t) + 1e-5 * rng.standard_normal(t.size)
    with pytest.raises(InputError, match=r"m.csv: column 'z' has no unit.*metres.* z_m .* z_mm"):
        validate_trajectory(_plain_table(t, z_m), "m.csv")
    np.testing.assert_allclose(validate_trajectory(_plain_table(t, z_m, z_name="z_m"))["z"], z_m * 1000)
    np.testing.assert_allclose(validate_trajectory(_plain_table(t, z_m, z_name="z_mm"))["z"], z_m)
    # a motion of millimetres in mm near zero is plausible and read as is, and so is a
    # micrometre-level vibration centred on zero (a hammer record's mode): ambiguous, not refused
    validate_trajectory(_plain_table(t, 2.0 * np.cos(2 * np.pi * 3 * t)))
    validate_trajectory(_plain_table(t, 0.003 * np.cos(2 * np.pi * 3 * t)))


def test_micrometres_are_an_error():
    t = np.arange(100) * 0.05
    with pytest.raises(InputError, match=r"micrometres\? rename the column z_um"):
        validate_trajectory(_plain_table(t, 1.9e6 + 500 * np.cos(t)), "u.csv")


@pytest.mark.parametrize("tz", [None, "Europe/Berlin"])
def test_datetime64_parquet_fits_like_float_seconds(tmp_path, tz, capsys):
    df, _ = _jittered_table(seed=5, jitter_s=0.0, duration_s=30.0, n_plates=2)
    df.attrs = {}
    df["t"] = np.round(df["t"], 6)
    stamps = pd.to_datetime(np.round(df["t"] * 1e6).astype(np.int64), unit="us")
    if tz:
        stamps = stamps.dt.tz_localize("UTC").dt.tz_convert(tz)
    df.to_parquet(tmp_path / "float.parquet")
    df.assign(t=stamps).to_parquet(tmp_path / "dated.parquet")
    assert cli("fit", tmp_path / "float.parquet", "--out", tmp_path / "a.csv") == 0
    assert cli("fit", tmp_path / "dated.parquet", "--out", tmp_path / "b.csv") == 0
    a, b = pd.read_csv(tmp_path / "a.csv"), pd.read_csv(tmp_path / "b.csv")
    np.testing.assert_allclose(b["t_start"], a["t_start"], rtol=0, atol=1e-6)
    for col in ("f0_hz", "amplitude_mm", "sigma_f0_hz", "phase_rad"):
        np.testing.assert_allclose(b[col], a[col], rtol=1e-6)


def test_iso_strings_in_a_csv_are_epoch_seconds():
    t = ["2023-11-14T22:13:20.000001Z", "2023-11-14T22:13:20.050001Z", "2023-11-14T23:13:20.1+01:00"]
    got = validate_trajectory(pd.DataFrame({"t": t, "plate": 1, "z": [1.0, 2.0, 3.0]}))
    np.testing.assert_allclose(
        got["t"], [1700000000.000001, 1700000000.050001, 1700000000.1], rtol=0, atol=1e-7
    )


# -- the other commands that read tables ------------------------------------------------------


@pytest.mark.slow
def test_run_and_diagnose_read_tables_with_the_policy(tmp_path, capsys):
    """A logger table (five significant digits, stamps repeated past 100 s): `run` with
    processing.timestamps = "reclock" estimates it, strict fails the unit naming reclock;
    `diagnose --timestamps reclock` reads it and says so."""
    rng = np.random.default_rng(4)
    k = np.arange(14000)
    t = k * LOGGER_DT
    frames = []
    for p in (1, 2):
        z = 1.5 * p * np.cos(2 * np.pi * 1.0 * t + p) + 0.05 * rng.standard_normal(k.size)
        frames.append(pd.DataFrame({"t": _five_digits(t), "plate": p, "z": z}))
    pd.concat(frames).to_csv(tmp_path / "log.csv", index=False)
    toml = (
        '[processing]\naxes = ["z"]\nreference_plate = 1\ntimestamps = "{}"\n'
        '[[recording]]\nday = 1\ncamera = "logger"\ncycles = 1\ntrajectories = "log.csv"\n'
    )
    (tmp_path / "strict.toml").write_text(toml.format("strict"))
    assert cli("run", tmp_path / "strict.toml", "--out", tmp_path / "o1") == 1
    assert "--timestamps reclock" in capsys.readouterr().err
    (tmp_path / "re.toml").write_text(toml.format("reclock"))
    assert cli("run", tmp_path / "re.toml", "--out", tmp_path / "o2") == 0
    whole = pd.read_csv(tmp_path / "o2" / "estimates_whole.csv")
    assert (whole["status"] == "converged").all()
    assert np.all(np.abs(whole["f0_hz"] - 1.0) < 4 * whole["sigma_f0_hz"])
    # the command-line flag overrides the campaign's policy
    assert cli("run", tmp_path / "strict.toml", "--out", tmp_path / "o3", "--timestamps", "reclock") == 0

    assert cli("diagnose", tmp_path / "log.csv", "--out", tmp_path / "d.json", "--no-figures") == 2
    code = cli(
        "diagnose",
        tmp_path / "log.csv",
        "--out",
        tmp_path / "d.json",
        "--no-figures",
        "--timestamps",
        "reclock",
    )
    assert code == 0
    d = json.loads((tmp_path / "d.json").read_text())
    assert d["settings"]["timestamps"] == "reclock"
    assert "timestamps reclocked: interval 0.007753" in capsys.readouterr().err


def test_frame_recordings_take_strict_or_reclock(tmp_path):
    """An .npz whose frame times a logger rounded (repeats past 100 s): strict refuses it naming
    reclock; reclock gives every frame its time on the recovered clock; merge is for tables."""
    from jaxdefl.io.recording import open_recording

    k = np.arange(14000)
    t = np.array(_five_digits(k * LOGGER_DT), dtype=float)
    np.savez(
        tmp_path / "r.npz",
        depth=np.zeros((k.size, 2, 2), np.float32),
        timestamps=t,
        intrinsics=np.array([500.0, 500.0, 1.0, 1.0]),
    )
    with pytest.raises(
        InputError, match=r"r.npz: timestamps: timestamps must increase.*--timestamps reclock"
    ):
        open_recording(tmp_path / "r.npz")
    with pytest.raises(ConfigError, match=r"--timestamps merge: frame recordings take strict or reclock"):
        open_recording(tmp_path / "r.npz", timestamps="merge")
    rec = open_recording(tmp_path / "r.npz", timestamps="reclock")
    got = np.concatenate([ch.t for ch in rec.chunks(4096)])
    np.testing.assert_allclose(got, k * LOGGER_DT, rtol=0, atol=0.01 * LOGGER_DT)  # a hundredth of a frame
    assert abs(rec.clock["segments"][0]["interval_s"] - LOGGER_DT) < 1e-9
