"""jaxdefl monitor: the recursive estimator against the batch fit, the block statistics, the CUSUM
thresholds, the [[change]] schedule, sources and the CLI; the detection study is slow-marked."""

from __future__ import annotations

import json
import os
import signal
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from jaxdefl._errors import ConfigError
from jaxdefl._signals import handle_signals
from jaxdefl.cli import main
from jaxdefl.monitor import (
    BlockAccumulator,
    ChangeDetector,
    DetectorSettings,
    Layout,
    Monitor,
    TrackerSettings,
    cusum_arl,
    cusum_threshold,
    fit_span,
    follow_table,
    gls_mean,
    initial_state,
    simulated_source,
)
from jaxdefl.monitor.detect import ThresholdTable, t_to_normal
from jaxdefl.simulate import config_from_dict, kinematics, simulate_to_dir, simulate_trajectories, write_live
from jaxdefl.simulate.schedule import amplitude_factor, frequency_phase


def _harmonic_frames(seed: int, duration_s: float = 60.0, fs: float = 20.0, common: float = 0.7):
    """13 plates × (z, x, y) on a jittered clock with drop-outs; z noise partly shared by the
    plates of a frame (as a ToF camera's range error)."""
    rng = np.random.default_rng(seed)
    lay = Layout(tuple(range(1, 14)), ("z", "x", "y"))
    n = int(duration_s * fs)
    t = 1.7e9 + np.arange(n) / fs + rng.normal(0, 2e-3, n)
    shape = np.sin(np.pi * np.arange(1, 14) / 14)
    amp = np.stack([2.3 * shape, np.full(13, 0.5), np.full(13, 0.05)], 1).ravel()
    sig = np.tile([0.76, 0.3, 0.1], 13)
    f0 = 3.068
    Y = 2000 + amp * np.sin(2 * np.pi * f0 * (t[:, None] - 1.7e9) + 0.4)
    noise = rng.standard_normal(Y.shape) * sig
    zc = np.arange(0, lay.n, 3)
    noise[:, zc] = noise[:, zc] * np.sqrt(1 - common) + np.sqrt(common) * 0.76 * rng.standard_normal((n, 1))
    Y = Y + noise
    Y[rng.random(n) < 0.03] = np.nan
    return t, Y, lay, f0


@pytest.mark.parametrize("method", ["ekf", "rls"])
def test_recursive_estimates_agree_with_the_batch_fit(method):
    """Without forgetting, the recursive estimates of a stationary record equal the batch fit of
    the same span within its σ's (amplitude, offset; f0 against the best series'), σ's alike."""
    t, Y, lay, f0 = _harmonic_frames(seed=11)
    n0 = int(10 * 20)
    st = TrackerSettings(method=method, f0_walk_hz=0.0, amplitude_walk=0.0, offset_walk_mm=0.0, memory_s=1e12)
    tr = initial_state(t[:n0], Y[:n0], fit_span(t[:n0], Y[:n0], lay), st)
    for k in range(n0, len(t)):
        tr.update(t[k], Y[k])
    est = tr.estimates()
    batch = fit_span(t, Y, lay)
    ok = (batch["status"] == "converged").to_numpy()
    assert ok.sum() >= 26  # z and x of every plate at least
    dA = (est["amplitude_mm"] - batch["amplitude_mm"]) / batch["sigma_amplitude_mm"]
    assert np.all(np.abs(dA[ok]) < 1.0), dA[ok]
    s_c = batch["sigma_residual_mm"] / np.sqrt(batch["n"])
    assert np.all(np.abs((est["offset_mm"] - batch["offset_mm"]) / s_c)[ok] < 1.0)
    ratio = est["sigma_amplitude_mm"][ok] / batch["sigma_amplitude_mm"].to_numpy()[ok]
    assert 0.85 < np.median(ratio) < 1.15
    best = int(np.nanargmin(np.where(ok, batch["sigma_f0_hz"], np.nan)))
    assert abs(est["f0_hz"][0] - batch["f0_hz"][best]) < batch["sigma_f0_hz"][best]
    # shared frequency, shared noise: σ_f0 from the covariance covers the truth
    assert abs(est["f0_hz"][0] - f0) < 3 * est["sigma_f0_hz"][0]
    assert est["sigma_f0_hz"][0] < batch["sigma_f0_hz"][best]


def test_block_estimates_recover_frequency_offset_amplitude_and_offset():
    """A harmonic at ω_ref + δω: the block fit gives δω, A and C within 3 σ, over 40 blocks the
    standardised errors have unit spread (the σ's are honest)."""
    rng = np.random.default_rng(5)
    w_ref, dw, A, C, sd = 2 * np.pi * 3.0, 0.05, 1.5, 7.0, 0.5
    fs, T = 30.0, 200.0
    t = 1.7e9 + np.arange(int(T * fs)) / fs
    y = C + A * np.cos((w_ref + dw) * (t - 1.7e9) + 0.3) + sd * rng.standard_normal(t.size)
    acc = BlockAccumulator(1, w_ref, 1.7e9, 5.0, t[0], np.array([6.0]))
    blocks = acc.add(t, y[:, None])
    assert len(blocks) == 39
    zw = np.array([(b.domega[0] - dw) / b.sigma_domega[0] for b in blocks])
    za = np.array([(b.amplitude_mm[0] - A) / b.sigma_amplitude_mm[0] for b in blocks])
    zc = np.array([(b.offset_mm[0] - C) / b.sigma_offset_mm[0] for b in blocks])
    for z in (zw, za, zc):
        assert np.all(np.abs(z) < 4)
        assert 0.7 < z.std() < 1.3
    s2 = np.array([b.resid_var[0] for b in blocks])
    assert abs(np.mean(s2) / sd**2 - 1) < 0.05


def test_cusum_threshold_against_a_simulated_run_length():
    """Siegmund's ARL against the mean run length of simulated in-control CUSUMs."""
    k = 0.5
    h = cusum_threshold(200.0, k)
    assert cusum_arl(h, k) == pytest.approx(200.0, rel=1e-6)
    rng = np.random.default_rng(1)
    runs = 4000
    s = np.zeros(runs)
    length = np.zeros(runs)
    alive = np.ones(runs, bool)
    step = 0
    while alive.any() and step < 20000:
        step += 1
        s = np.where(alive, np.maximum(0, s + rng.standard_normal(runs) - k), s)
        hit = alive & (s > h)
        length[hit] = step
        alive &= ~hit
    assert abs(length.mean() / 200.0 - 1) < 0.1


def test_threshold_with_a_learnt_reference_keeps_the_nominal_rate():
    """A chart on a reference learnt from n blocks sees its error δ ~ N(0, 1/n) as a shift: with
    `ThresholdTable`'s h for n the simulated in-control alarm rate is the nominal one, with the
    h of a full reference it is well above."""
    rng = np.random.default_rng(3)
    arl, k, n = 300.0, 0.5, 60
    table = ThresholdTable(arl, k, 720)
    assert float(table(720)) == pytest.approx(cusum_threshold(arl, k, 1 / np.sqrt(720)), rel=1e-3)
    runs, steps = 4000, 2000
    rates = {}
    for name, h in (("learnt", float(table(n))), ("full", float(table(720)))):
        d = rng.normal(0, 1 / np.sqrt(n), runs)
        s = np.zeros(runs)
        alarms = 0
        for _ in range(steps):
            s = np.maximum(0.0, s + rng.standard_normal(runs) + d - k)
            hit = s > h
            alarms += int(hit.sum())
            s[hit] = 0.0
        rates[name] = alarms / (runs * steps) * arl
    assert abs(rates["learnt"] - 1) < 0.1, rates
    assert rates["full"] > 1.15, rates


def test_t_to_normal_matches_scipy():
    from scipy import stats

    t = np.array([-9.0, -2.5, 0.0, 0.7, 3.0, 12.0])
    dof = np.array([5.0, 20.0, 95.0, 95.0, 40.0, 95.0])
    want = stats.norm.isf(stats.t.sf(np.abs(t), dof)) * np.sign(t)
    np.testing.assert_allclose(t_to_normal(t, dof), want, rtol=1e-9, atol=1e-12)
    assert np.isnan(t_to_normal(np.array([np.nan]), np.array([10.0]))[0])


def _block_stream(n_blocks: int, step_block: int | None, seed: int, phi: float = 0.6):
    """Blocks of 4 plates (z) at 20 Hz, 3 Hz loading; plate 2's noise is AR(1) (``phi`` per frame,
    the same marginal σ), so its block offsets spread twice what their white-noise σ says; an
    offset step of 0.3 mm on plate 2 from block ``step_block``."""
    from scipy.signal import lfilter

    rng = np.random.default_rng(seed)
    fs, w, block_s = 20.0, 2 * np.pi * 3.0, 5.0
    t = 1.7e9 + np.arange(int(n_blocks * block_s * fs)) / fs
    amp = np.array([1.0, 2.0, 2.0, 1.0])
    noise = 0.5 * rng.standard_normal((t.size, 4))
    noise[:, 1] = lfilter([np.sqrt(1 - phi**2)], [1, -phi], noise[:, 1])
    Y = 100.0 + amp * np.sin(w * (t[:, None] - 1.7e9) + 0.4) + noise
    if step_block is not None:
        Y[int(step_block * block_s * fs) :, 1] += 0.3
    acc = BlockAccumulator(4, w, 1.7e9, block_s, t[0] - 1e-9, np.full(4, 100.0))
    return acc.add(t, Y)


def _detect(blocks):
    det = ChangeDetector(Layout((1, 2, 3, 4), ("z",)), DetectorSettings(), f0_hz=3.0)
    alarms = []
    for i, b in enumerate(blocks):
        alarms += [(i, e) for e in det.step(b, np.eye(4)) if e["event"] == "alarm"]
    return det, alarms


def test_series_with_coloured_noise_does_not_alarm_but_a_real_change_does():
    """Coloured noise the block σ's do not see (AR(1) per frame: block offsets spread 2× their σ):
    over 3 h without change, with a threshold for 1 alarm a day, no alarm (charted on the model σ
    alone, its offset chart alarmed 17 times); the reference measures the spread (≈ 2 for that
    series, 1 for the white ones); a 0.3-mm offset step on that series (≈ 3 of its real block σ's)
    is still found within a minute, as a sensor offset of plate 2."""
    blocks = _block_stream(2200, None, seed=31)
    det, alarms = _detect(blocks)
    assert not alarms, [e["message"] for _, e in alarms]
    spread = det.ref_C.spread()
    assert 1.6 < spread[1] < 2.5 and np.all(spread[[0, 2, 3]] < 1.1), spread
    blocks = _block_stream(200, 150, seed=32)
    det, alarms = _detect(blocks)
    assert alarms, "the step was not found"
    i, ev = alarms[0]
    assert ev["quantity"] == "offset" and ev["class"] == "sensor" and ev["plates"] == [2], ev
    assert 150 <= i <= 150 + 12
    assert abs(ev["size"][0] - 0.3) < 3 * ev["sigma"][0] + 0.05


def test_gls_mean_matches_weighted_least_squares():
    rng = np.random.default_rng(2)
    v, s = rng.normal(size=5), rng.uniform(0.5, 2, 5)
    corr = 0.3 + 0.7 * np.eye(5)
    m, sm = gls_mean(v, s, corr)
    cov = corr * np.outer(s, s)
    w = np.linalg.inv(cov)
    one = np.ones(5)
    assert m == pytest.approx(one @ w @ v / (one @ w @ one), rel=1e-6)
    assert sm == pytest.approx(1 / np.sqrt(one @ w @ one), rel=1e-6)


def test_change_schedule_in_the_config():
    cfg = config_from_dict(
        {"change": [{"kind": "stiffness", "t_s": 5.0, "stiffness_change": -0.02}]}, "c.toml"
    )
    (ch,) = cfg.changes
    assert ch.f0_change == pytest.approx(np.sqrt(0.98) - 1)
    assert ch.amplitude_change == pytest.approx(1 / 0.98 - 1)
    tau = np.array([4.0, 6.0, 6.001])
    ph = frequency_phase(cfg.changes, 3.0, tau)
    assert (ph[2] - ph[1]) / 0.001 == pytest.approx(2 * np.pi * 3.0 * np.sqrt(0.98), rel=1e-9)
    assert amplitude_factor(cfg.changes, tau) == pytest.approx([1.0, 1 / 0.98, 1 / 0.98])
    # the motion is phase continuous through the change; before it, as without a schedule
    only_f = config_from_dict(
        {"change": [{"kind": "stiffness", "t_s": 5.0, "f0_change": -0.01, "amplitude_change": 0.0}]}, "c.toml"
    )
    t = only_f.t0_s + np.array([4.0, 4.999999, 5.000001])
    d, _, _ = kinematics(only_f, t)
    assert abs(d[2] - d[1]) < 1e-3
    d0, _, _ = kinematics(config_from_dict({}, "c.toml"), t)
    assert d[0] == pytest.approx(d0[0])
    bad = [
        ({"kind": "crack", "t_s": 1}, "change\\[0\\].kind.*expected one of stiffness"),
        ({"kind": "debond", "t_s": 1, "plate": 14}, "change\\[0\\].plate.*1..13"),
        ({"kind": "sensor_fault", "t_s": 1, "plate": 2, "fault": "smoke"}, "fault.*lost, jump, noise"),
        ({"kind": "stiffness", "stiffness_change": -0.1}, "change\\[0\\].t_s"),
        ({"kind": "stiffness", "t_s": 1, "plate": 3}, "unknown key 'change\\[0\\].plate'"),
    ]
    for table, msg in bad:
        with pytest.raises(ConfigError, match=msg):
            config_from_dict({"change": [table]}, "c.toml")


def _tiny_config(tmp: Path, extra: str = "", duration: float = 60.0) -> Path:
    p = tmp / "live.toml"
    p.write_text(
        f'[recording]\nduration_s = {duration}\n[camera]\nframe_rate_hz = 20.0\n[fatigue]\nlaw = "none"\n'
        + extra
    )
    return p


def test_follow_a_growing_table(tmp_path):
    """`simulate --live` appends to a table while the follower reads it: every frame arrives once."""
    cfg = _tiny_config(tmp_path, duration=12.0)
    th = threading.Thread(target=write_live, args=(cfg, tmp_path / "live"), kwargs=dict(speed=24.0))
    th.start()
    try:
        time.sleep(0.3)
        src = follow_table(tmp_path / "live" / "trajectory.csv", idle_s=1.5, poll_s=0.02)
        got = [t for t, _ in src.chunks]
    finally:
        th.join()
    t = np.concatenate(got)
    assert np.all(np.diff(t) > 0)
    n_rows = sum(1 for _ in open(tmp_path / "live" / "trajectory.csv")) - 1
    assert len(t) * 13 == n_rows
    assert src.layout.plates == tuple(range(1, 14)) and src.layout.axes == ("z", "x", "y")


def test_cli_monitor_writes_its_files_and_stops_at_until(tmp_path):
    cfg = _tiny_config(tmp_path, duration=40.0)
    out = tmp_path / "mon"
    _, lds = simulate_trajectories(cfg, 40.0, 0)
    lds.to_csv(tmp_path / "lds.csv", index=False)
    code = main(
        ["monitor", "--config", str(cfg), "--out", str(out), "--speed", "0", "--until", "30"]
        + ["--reference", str(tmp_path / "lds.csv")]
    )
    assert code == 0
    events = [json.loads(x) for x in (out / "events.jsonl").read_text().splitlines()]
    assert events[0]["state"] == "learning" and events[-1]["state"] == "stopped"
    import pandas as pd

    from jaxdefl.monitor import SNAPSHOT_COLUMNS

    est = pd.read_csv(out / "estimates.csv")
    assert list(est.columns) == SNAPSHOT_COLUMNS
    assert est["t_end"].max() <= est["t_start"].min() + 30.0 + 1e-6
    z7 = est[(est.plate == 7) & (est.axis == "z") & (est.segment == "camera")]
    assert np.all(np.abs(z7["f0_hz"] - 3.068) < 4 * z7["sigma_f0_hz"])
    # the LDS monitored alongside: plates 3, 5, 7, 9, 11, same frequency, mid-span amplitude
    ref = est[est.segment == "reference"]
    assert set(ref.plate) == {3, 5, 7, 9, 11} and len(ref) >= 10
    r7 = ref[ref.plate == 7].iloc[-1]
    assert abs(r7.f0_hz - 3.068) < 4 * r7.sigma_f0_hz
    assert abs(r7.amplitude_mm - 2.32) < 4 * r7.sigma_amplitude_mm + 0.01
    assert (out / "snapshot.png").stat().st_size > 0
    # a replay of a table works the same way, and a bad speed is a one-line error
    assert main(["monitor", "--replay", str(out / "estimates.csv"), "--out", str(tmp_path / "m2")]) == 2
    assert main(["monitor", "--config", str(cfg), "--out", str(tmp_path / "m3"), "--speed", "-1"]) == 2


def test_sigint_and_duration_stop_cleanly(tmp_path, capsys):
    """--duration stops on the wall clock; SIGINT exits 130 with the logs whole and a stopped event."""
    cfg = _tiny_config(tmp_path, duration=600.0)
    cmd = ["monitor", "--config", str(cfg), "--speed", "8"]
    out1 = tmp_path / "d"
    assert main([*cmd, "--out", str(out1), "--duration", "1.5"]) == 0
    last = json.loads((out1 / "events.jsonl").read_text().splitlines()[-1])
    assert last["reason"] == "--duration"
    out2 = tmp_path / "i"
    timer = threading.Timer(2.5, os.kill, (os.getpid(), signal.SIGINT))
    timer.start()
    try:
        code = main([*cmd, "--out", str(out2)])
    finally:
        timer.cancel()
        with handle_signals():  # forget the recorded signal: later tests check for one
            pass
    assert code == 130
    assert "monitor stopped" in capsys.readouterr().err
    lines = (out2 / "events.jsonl").read_text().splitlines()
    assert json.loads(lines[-1])["reason"].startswith("interrupted")
    text = (out2 / "estimates.csv").read_text()
    assert text.endswith("\n")
    n_cols = len(text.splitlines()[0].split(","))
    assert all(len(x.split(",")) == n_cols for x in text.splitlines())


# -- the detection study (slow) ---------------------------------------------------------------


def _run(cfg: Path, duration: float, seed: int, track: bool = True) -> list[dict]:
    src = simulated_source(cfg, duration_s=duration, seed=seed)
    mon = Monitor(src.layout, track=track)
    events = []
    for t, Y in src.chunks:
        events += mon.feed(t, Y)
    return [e for e in events if e["event"] == "alarm"]


@pytest.mark.slow
def test_f0_drop_detected_within_60_s(tmp_path):
    """0.5 % f0 drop (stiffness loss) at a time the detector is not told, 3 Hz loading, 20 Hz
    ToF camera: one structural f0 alarm within 60 s, its size within 3 σ, nothing else."""
    t_change = float(np.random.default_rng(7).uniform(330, 390))  # after the 5-min learning
    cfg = _tiny_config(
        tmp_path,
        f'[[change]]\nkind = "stiffness"\nt_s = {t_change}\nf0_change = -0.005\namplitude_change = 0.0\n',
    )
    alarms = _run(cfg, t_change + 80, seed=21)
    assert len(alarms) == 1, alarms
    (a,) = alarms
    assert a["class"] == "structural" and a["quantity"] == "f0"
    t0 = 1.7e9
    assert 0 <= a["t"] - (t0 + t_change) <= 60
    assert abs(a["t_change"] - (t0 + t_change)) <= 10
    assert abs(a["size"] - (-0.005 * 3.068)) < 3 * a["sigma"] + 0.1 * 0.005 * 3.068


@pytest.mark.slow
def test_amplitude_step_on_one_plate_and_sensor_faults(tmp_path):
    """A 3 % amplitude step of plate 7 (15 min after the learning, when the references hold enough
    blocks for half a block σ to stand out at one false alarm a day) is a `plate` alarm naming
    plate 7; a lost plate, a jump and a noise increase on other plates just after the learning are
    `sensor` alarms; nothing is called structural."""
    cfg = _tiny_config(
        tmp_path,
        '[[change]]\nkind = "debond"\nt_s = 1200\nplate = 7\namplitude_change = 0.03\n'
        '[[change]]\nkind = "sensor_fault"\nt_s = 340\nplate = 3\nfault = "jump"\nsize = 1.0\n'
        '[[change]]\nkind = "sensor_fault"\nt_s = 350\nplate = 11\nfault = "noise"\nsize = 2.0\n'
        '[[change]]\nkind = "sensor_fault"\nt_s = 360\nduration_s = 30\nplate = 5\nfault = "lost"\n',
    )
    # detection only (the tracker's per-frame updates do not change the alarms): 35 min of data
    alarms = _run(cfg, 2100, seed=4, track=False)
    assert not [a for a in alarms if a["class"] == "structural"], alarms
    amp = [a for a in alarms if a["quantity"] == "amplitude"]
    assert amp and all(a["plates"] == [7] and a["class"] == "plate" for a in amp), amp
    assert amp[0]["size"] > 0
    got = {(a["quantity"], tuple(a["plates"])) for a in alarms if a["class"] == "sensor"}
    assert ("offset", (3,)) in got and ("noise", (11,)) in got and ("samples", (5,)) in got, got


@pytest.mark.slow
def test_replay_of_a_frame_recording(tmp_path):
    """--replay of a .zarr recording goes through the tracked extraction: the plates in view,
    three axes, the loading frequency."""
    cfg = _tiny_config(tmp_path, duration=14.0)
    simulate_to_dir(cfg, tmp_path / "sim", progress=False)
    out = tmp_path / "mon"
    code = main(
        ["monitor", "--replay", str(tmp_path / "sim" / "recording.zarr"), "--out", str(out)]
        + ["--speed", "0", "--snapshot", "2"]
    )
    assert code == 0
    import pandas as pd

    est = pd.read_csv(out / "estimates.csv")
    assert set(est.axis) == {"z", "x", "y"} and est.plate.nunique() >= 5
    last = est[est.axis == "z"].groupby("plate").tail(1)
    assert np.all(np.abs(last.f0_hz - 3.068) < 4 * last.sigma_f0_hz + 1e-3)


@pytest.mark.slow
def test_coherent_amplitude_change_is_structural(tmp_path):
    """Every plate's amplitude +4 % (a stiffness change under load control, frequency held): the
    amplitude alarms are `structural`, none names a single plate as `plate`."""
    cfg = _tiny_config(
        tmp_path, '[[change]]\nkind = "stiffness"\nt_s = 1200\nf0_change = 0.0\namplitude_change = 0.04\n'
    )
    alarms = _run(cfg, 1800, seed=8, track=False)
    amp = [a for a in alarms if a["quantity"] == "amplitude"]
    assert amp and amp[0]["class"] == "structural", alarms
    assert not [a for a in amp if a["class"] == "plate"], amp
    assert abs(amp[0]["size"] - 0.04) < 3 * amp[0]["sigma"] + 0.005


def test_replay_of_a_logger_table_with_a_repeated_stamp_takes_a_timestamp_policy(tmp_path, capsys):
    """A logger that wrote one stamp twice with other values (and a drifting, rounded clock):
    strict refuses naming the policies; merge and reclock replay it; a followed source stays
    strict."""
    import pandas as pd

    cfg = _tiny_config(tmp_path, duration=40.0)
    truth, _ = simulate_trajectories(cfg, 40.0, 0)
    rng = np.random.default_rng(5)
    t_true = np.sort(truth["t"].unique())
    t_logged = np.round(1000.0 + (t_true - t_true[0]) * (1 + 7e-5), 4)  # drifting, 0.1 ms rounding
    rows = truth.assign(t=truth["t"].map(dict(zip(t_true, t_logged, strict=True))))
    rows["z"] = rows["z"] + 0.5 * rng.standard_normal(len(rows))
    # a repeated stamp with another value (the logger wrote one frame twice, re-read)
    dup = rows.iloc[[130]].assign(z=rows["z"].iloc[130] + 1.0)
    table = tmp_path / "logger.csv"
    pd.concat([rows.iloc[:131], dup, rows.iloc[131:]]).to_csv(table, index=False)
    base = ["monitor", "--replay", str(table), "--speed", "0", "--until", "30"]
    assert main([*base, "--out", str(tmp_path / "strict")]) == 2
    assert "--timestamps reclock" in capsys.readouterr().err
    assert not (tmp_path / "strict").exists()
    for policy in ("merge", "reclock"):
        assert main([*base, "--out", str(tmp_path / policy), "--timestamps", policy]) == 0
        est = pd.read_csv(tmp_path / policy / "estimates.csv")
        z7 = est[(est.plate == 7) & (est.axis == "z")].iloc[-1]
        assert abs(z7.f0_hz - 3.068 * (1 - 7e-5)) < 4 * z7.sigma_f0_hz  # on the logger's clock
    assert main(["monitor", str(table), "--out", str(tmp_path / "f"), "--timestamps", "reclock"]) == 2
    assert "applies to --replay of a table" in capsys.readouterr().err


def test_a_replay_shorter_than_the_learning_says_it_never_left_learning(tmp_path, capsys):
    """Issue 25.15: a 1-min record against 5 min of learning gives no alarm and says why; with
    1-s blocks (60 of them: 1 min) the same monitor leaves learning and says nothing of it."""
    cfg = _tiny_config(tmp_path, duration=80.0)
    traj, _ = simulate_trajectories(cfg, 80.0, 0)
    traj.to_csv(tmp_path / "traj.csv", index=False)
    out = tmp_path / "short"
    assert main(["monitor", "--replay", str(tmp_path / "traj.csv"), "--out", str(out), "--speed", "0"]) == 0
    err = capsys.readouterr().err
    stop = [json.loads(x) for x in (out / "events.jsonl").read_text().splitlines()][-1]
    assert stop["state"] == "stopped" and stop["still_learning"] is True
    for text in (stop["message"], err):
        assert "never left `learning`" in text and "5 min" in text and "--block 5 s" in text
    out = tmp_path / "long"
    args = ["monitor", "--replay", str(tmp_path / "traj.csv"), "--out", str(out), "--speed", "0"]
    assert main([*args, "--block", "1"]) == 0
    events = [json.loads(x) for x in (out / "events.jsonl").read_text().splitlines()]
    assert any(e.get("state") == "monitoring" for e in events)
    assert "still_learning" not in events[-1] and "never left" not in capsys.readouterr().err
