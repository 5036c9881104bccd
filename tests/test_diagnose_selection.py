"""Selection that survives a wrong residual model (issue 23, Build item 2), record kinds (item 4)
and the lattice read from the values (item 3).

- backward elimination: an effect made redundant by a later, better one is dropped, with the
  reason;
- the flexible alternative: a smooth misfit is not called several level jumps, an envelope is
  modelled unnamed;
- relevance: every effect carries its share of the residual and its size against the motion;
- record kinds on simulated records of each kind, and `value_lattice` against the lattice drawn.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from jaxdefl.diagnose import build_context, diagnose
from jaxdefl.diagnose._correlation import frame_correlation
from jaxdefl.diagnose._search import Accepted, Calibration, _backward, _flexible_alternative, _score
from jaxdefl.diagnose.detectors import load_detectors
from jaxdefl.diagnose.record_kind import recognise, value_lattice

F0 = 2.3


def table(t, zs) -> pd.DataFrame:
    return pd.concat(
        [pd.DataFrame({"t": t, "plate": p + 1, "z": z}) for p, z in enumerate(zs)], ignore_index=True
    )


def harmonic_record(seconds=120.0, fs=20.0, plates=4, sigma=0.3, seed=0, envelope=None, warmup=None):
    """Plates moving at F0 (amplitudes 2-3 mm) in white noise; ``envelope(t)`` scales the motion
    (a smooth ramp), ``warmup`` = (a mm, τ s) adds a·exp(−t/τ) to every plate."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(seconds * fs)) / fs
    env = np.ones_like(t) if envelope is None else envelope(t)
    zs = []
    for p in range(plates):
        z = 500 + (2 + 0.3 * p) * env * np.cos(2 * np.pi * F0 * t + 0.3) + sigma * rng.standard_normal(t.size)
        if warmup is not None:
            z = z + warmup[0] * np.exp(-t / warmup[1])
        zs.append(z)
    return table(t, zs)


def _search_parts(traj):
    ctx, nominal, _ = build_context(traj)
    corr = frame_correlation(ctx, nominal)
    n_total = sum(s.n for s in ctx.series)
    lib = load_detectors()
    calib = Calibration(len(lib))
    return ctx, nominal, corr, n_total, lib, calib


def _accept(ctx, states, p, calib, corr, n_total):
    d, r0, r1, lr = _score(ctx, states, p, n_total, corr)
    new = list(states)
    for i in p.series:
        new[i] = p.states[i]
    return Accepted(p, d, r0, r1, {i: states[i] for i in p.series}, lr, calib.critical(p)), new


def test_backward_elimination_drops_an_effect_a_later_better_one_makes_redundant():
    """A warm-up first taken by a level jump (accepted: it explains part of it), then a drift
    proposed on what the jump left: once the drift is refitted without the jump, the jump no
    longer pays for itself and is dropped, with the reason naming the drift."""
    traj = harmonic_record(seconds=180.0, warmup=(1.2, 40.0), seed=3)
    ctx, states, corr, n_total, lib, calib = _search_parts(traj)
    jumps = [p for p in lib["level_jump"].propose(ctx, states) if p.series]
    assert jumps, "the warm-up must look like a jump to the jump's screen"
    jump = min(jumps, key=lambda p: _score(ctx, states, p, n_total, corr)[0])
    a_jump, states = _accept(ctx, states, jump, calib, corr, n_total)
    assert a_jump.lr > a_jump.lr_critical
    drifts = [p for p in lib["drift"].propose(ctx, states) if p.series]
    assert drifts
    drift = min(drifts, key=lambda p: _score(ctx, states, p, n_total, corr)[0])
    a_drift, states = _accept(ctx, states, drift, calib, corr, n_total)
    assert a_drift.lr > a_drift.lr_critical
    dropped = []
    states2, kept = _backward(ctx, states, [a_jump, a_drift], dropped, calib, corr, n_total, lib)
    assert [a.proposal.effect for a in kept] == ["drift"]
    assert [d.effect for d in dropped] == ["level_jump"]
    assert "drift" in dropped[0].reason and dropped[0].lr < dropped[0].lr_critical
    # the model after the drop explains the warm-up: the residual is the noise (σ 0.3 mm)
    r = np.concatenate([s.y - st.mean for s, st in zip(ctx.series, states2, strict=True)])
    assert np.std(r) == pytest.approx(0.3, rel=0.1)


def test_backward_keeps_effects_that_are_both_there():
    """A jump and a separate line: neither explains the other, both stay."""
    traj = harmonic_record(seconds=180.0, seed=4)
    t = traj["t"].to_numpy()
    traj["z"] = traj["z"] + 0.6 * (t > 100.0) + 0.35 * np.cos(2 * np.pi * 0.71 * t)
    ctx, states, corr, n_total, lib, calib = _search_parts(traj)
    acc = []
    for eid in ("level_jump", "extra_periodic"):
        props = [p for p in lib[eid].propose(ctx, states) if p.series]
        p = min(props, key=lambda p: _score(ctx, states, p, n_total, corr)[0])
        a, states = _accept(ctx, states, p, calib, corr, n_total)
        acc.append(a)
    dropped = []
    _, kept = _backward(ctx, states, acc, dropped, calib, corr, n_total, lib)
    assert [a.proposal.effect for a in kept] == ["level_jump", "extra_periodic"] and dropped == []


def test_two_effects_that_trade_places_end_the_search(monkeypatch):
    """Two effects that explain the same residual, each dropped by the backward step when the
    other is added (seen on a registered camera: outliers and heteroscedastic_noise, 1,000
    rounds without end): the search stops at the first model it has had before, and says so."""
    import jaxdefl.diagnose._search as search
    from jaxdefl.diagnose._search import Dropped, run_diagnosis

    traj = harmonic_record(seconds=120.0, warmup=(1.5, 30.0), seed=5)
    t = traj["t"].to_numpy()
    traj["z"] = traj["z"] + 0.8 * np.cos(2 * np.pi * 0.61 * t)  # a second cause besides the warm-up
    rounds = []

    def trading(ctx, states, accepted, dropped, calib, corr, n_total, usable):
        newest, older = accepted[-1], accepted[:-1]
        for a in older:  # the newest replaces every older effect, whatever the evidence
            states = search._without(states, a)
            dropped.append(Dropped(a.proposal.effect, "traded", 0.0, 1.0, newest.proposal.effect))
        return states, [newest]

    monkeypatch.setattr(search, "_backward", trading)
    d = run_diagnosis(traj, on_round=lambda r, e: rounds.append(e))
    assert len(rounds) < 20, rounds
    assert any("came back to a model it had already had" in n for n in d.notes), d.notes
    assert len(d.accepted) == 1


def _ramp_hold_ramp(t):
    """The friction damper's envelope: up over the first fifth, held, down over the last fifth."""
    T = t[-1]
    return np.clip(np.minimum(t / (0.2 * T), (T - t) / (0.2 * T)), 0.05, 1.0)


def test_a_smooth_misfit_is_not_called_level_jumps():
    """Level jumps accepted on a smooth misfit (a slow hump of the camera's range, alike on the
    plates: the jumps each take a part of it) are dropped when the flexible alternative (an unnamed smooth trend) is fitted on
    the same residual: given it, they no longer pass."""
    traj = harmonic_record(seconds=120.0, sigma=0.3, seed=5)
    t = traj["t"].to_numpy()
    traj["z"] = traj["z"] + 0.6 * np.exp(-(((t - 60.0) / 25.0) ** 2))  # a smooth hump, no step
    ctx, states, corr, n_total, lib, calib = _search_parts(traj)
    acc = []
    for _ in range(2):
        props = [p for p in lib["level_jump"].propose(ctx, states) if p.series]
        if not props:
            break
        p = min(props, key=lambda p: _score(ctx, states, p, n_total, corr)[0])
        a, new = _accept(ctx, states, p, calib, corr, n_total)
        if not a.lr > a.lr_critical:
            break
        acc.append(a)
        states = new
    assert acc, "the envelope misfit must pass a jump's own test (the failure being guarded)"
    dropped = []
    _, kept, terms = _flexible_alternative(
        ctx, states, acc, dropped, [], calib, corr, n_total, load_detectors(), {}
    )
    assert kept == []
    assert {d.effect for d in dropped} == {"level_jump"}
    assert all("unnamed" in d.reason for d in dropped)
    assert terms and terms[0].kind in ("envelope", "trend")


def test_diagnose_names_no_jump_on_an_envelope_and_reports_relevance():
    """End to end: the ramped envelope is modelled unnamed, no level jump is named; every
    effect (a line added) carries its relevance."""
    traj = harmonic_record(seconds=60.0, envelope=_ramp_hold_ramp, sigma=0.05, seed=6)
    t = traj["t"].to_numpy()
    traj["z"] = traj["z"] + 0.05 * np.cos(2 * np.pi * 0.83 * t)
    d = diagnose(traj)
    ids = [e["id"] for e in d["effects"]]
    assert "level_jump" not in ids and "stiffness_change" not in ids
    assert any(u["kind"] == "envelope" for u in d["unnamed"])
    assert d["record_kind"] == "forced_harmonic"
    for e in d["effects"]:
        r = e["relevance"]
        assert 0.0 <= r["residual_share"] <= 1.0 and r["size_vs_motion"] > 0
        assert r["minor"] == (e["id"] in d["minor"])


# --- record kinds ---------------------------------------------------------------------------


def _kind(t, y):
    return recognise([(t, y)], float(np.median(np.diff(t))))


def test_record_kinds_of_simulated_records():
    rng = np.random.default_rng(7)
    fs = 200.0
    t = np.arange(int(8 * fs)) / fs
    noise = 0.02 * rng.standard_normal(t.size)
    one = np.cos(2 * np.pi * 5.3 * t) + 0.03 * np.cos(2 * np.pi * 10.6 * t) + noise
    assert _kind(t, one).kind == "forced_harmonic"
    # three tones, not harmonics of one another
    tones = np.cos(2 * np.pi * 13 * t) + 0.6 * np.cos(2 * np.pi * 21.5 * t) + 0.4 * np.sin(2 * np.pi * 37 * t)
    rk = _kind(t, tones + noise)
    assert rk.kind == "multi_tone"
    assert sorted(round(f, 1) for f in rk.lines_hz) == [13.0, 21.5, 37.0]
    # a damped mode from an impact
    decay = np.exp(-2 * np.pi * 0.02 * 9.0 * t) * np.cos(2 * np.pi * 9.0 * t) + noise
    rk = _kind(t, decay)
    assert rk.kind == "free_decay" and rk.decay_ratio > 10
    # band-limited random excitation
    from scipy.signal import lfilter

    w0, zeta = 2 * np.pi * 9.0 / fs, 0.05  # a randomly excited 9-Hz resonance
    x = lfilter(
        [1.0],
        [1.0, -2 * math.exp(-zeta * w0) * math.cos(w0), math.exp(-2 * zeta * w0)],
        rng.standard_normal(t.size),
    )
    assert _kind(t, x + noise).kind == "broadband"
    # white noise beside a weak line is measurement noise, not a broadband motion
    assert _kind(t, 0.7 * np.cos(2 * np.pi * 5.3 * t) + rng.standard_normal(t.size)).kind == "forced_harmonic"
    # a slow ramp and hold (a load path)
    ramp = np.clip(t / 3.0, 0, 1) * 4.0 + noise
    assert _kind(t, ramp).kind == "quasi_static"


def test_multi_tone_forcing_step_is_located_not_named():
    """Three forcing lines whose drive steps up by 50 % mid-record: the kind is multi-tone, the
    change is located at its time with the lines' common ratio and frequencies kept (a change
    of the forcing), and nothing is named for it (no crack, no jump, no modulation)."""
    rng = np.random.default_rng(8)
    fs = 400.0
    t = np.arange(int(4 * fs)) / fs
    gain = np.where(t < 2.1, 1.0, 1.5)
    y = gain * (
        0.05 * np.cos(2 * np.pi * 100 * t)
        + 0.04 * np.cos(2 * np.pi * 120 * t + 1)
        + 0.06 * np.sin(2 * np.pi * 150 * t)
    )
    y = y + 0.004 * rng.standard_normal(t.size)
    d = diagnose(table(t, [y]))
    assert d["record_kind"] == "multi_tone"
    fc = d["record"]["forcing_change"]
    assert abs(fc["t_s"] - 2.1) < 0.1
    assert fc["cause"] == "forcing"
    assert all(abs(r - 1.5) < 0.05 for r in fc["amplitude_ratio"])
    assert d["effects"] == []
    reasons = {c["id"]: c["reason"] for c in d["cannot_tell"]}
    assert "multi tone" in reasons["stiffness_change"] and "multi tone" in reasons["harmonic_distortion"]


# --- the lattice read from the values -------------------------------------------------------


@pytest.mark.parametrize("q", [0.0015, 0.37, 2.6])
def test_value_lattice_reads_the_step_drawn(q):
    rng = np.random.default_rng(9)
    y = 40 + 10 * np.sin(np.linspace(0, 20, 3000)) + 0.3 * rng.standard_normal(3000)
    yq = q * np.round(y / q) + 1e-12 * rng.standard_normal(3000)  # last-digit noise of a product
    assert value_lattice(yq) == pytest.approx(q, rel=0.01)
    assert value_lattice(y) is None  # not on a lattice
    # a centroid of many rounded pixels sits on no lattice of its own
    px = q * np.round((y[:, None] + 0.4 * q * rng.standard_normal((3000, 40))) / q)
    assert value_lattice(px.mean(axis=1)) is None or value_lattice(px.mean(axis=1)) < q / 20


def test_a_lattice_below_the_noise_is_resolution_not_quantization():
    """A logger's fine ADC step under the noise is the record's resolution: quantization is not
    named, and the report says what the lattice is."""
    rng = np.random.default_rng(10)
    fs = 128.0
    t = np.arange(int(30 * fs)) / fs
    z = (
        12.7 * np.cos(2 * np.pi * 2.0 * t)
        + 0.2 * np.cos(2 * np.pi * 4.0 * t)
        + 0.05 * rng.standard_normal(t.size)
    )
    z = 0.0015 * np.round(z / 0.0015)
    d = diagnose(table(t, [z]))
    assert "quantization" not in [e["id"] for e in d["effects"]]
    res = d["record"]["resolution"]
    assert res["step"] == pytest.approx(0.0015, rel=0.01) and res["below_noise"]
    assert any("resolution" in n for n in d["notes"])
    assert not math.isnan(d["nominal"]["rms_mm"])


def test_a_name_the_record_cannot_tell_from_its_rival_says_so():
    # A common warm-up of 0.04 mm (τ 2 min) on 10 plates over 3 minutes: a level jump fits the
    # same residual about as well (issue 23: warm-ups named level jumps on short records). Whichever
    # the search names, the other is reported as not told apart, in DIAG.json and in the report.
    from jaxdefl.report.diagnosis import diagnosis_markdown

    named = set()
    for seed in range(4):
        d = diagnose(harmonic_record(seconds=180, plates=10, seed=seed, warmup=(0.04, 120.0)))
        (e,) = [e for e in d["effects"] if e["id"] in ("drift", "level_jump")]
        other = "level_jump" if e["id"] == "drift" else "drift"
        named.add(e["id"])
        rival = next(r for r in e["rivals"] if r["id"] == other)
        assert rival["margin"] < 6 and other in e["not_told_from"], e["rivals"]
        assert rival["footprint"] == ["a slow change of the mean"]
        md = diagnosis_markdown(d, [])
        assert f"`{e['id']}` (or `{other}`)" in md  # in the summary, or among the minor findings
        assert e["relevance"]["minor"] or f"**not told apart** from `{other}`" in md
    assert named == {"drift", "level_jump"}  # the record does not decide: both names occur
    # a warm-up five times larger is told from a step: named, and no rival within the margin
    for seed in range(2):
        d = diagnose(harmonic_record(seconds=180, plates=10, seed=seed, warmup=(0.2, 120.0)))
        (e,) = [e for e in d["effects"] if e["id"] in ("drift", "level_jump")]
        assert e["id"] == "drift" and e["not_told_from"] == [], e["rivals"]
        assert next(r for r in e["rivals"] if r["id"] == "level_jump")["margin"] > 20


def _crack_record(s, t_c=90.0, seconds=180.0, fs=20.0, plates=10, sigma=0.3, seed=0):
    """Plates at F0 whose beam loses a relative stiffness s at t_c (the simulator's crack: the
    frequency × √(1 + s) from t_c, the phase continuous, the amplitude × 1/(1 + s))."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(seconds * fs)) / fs
    phi, a = math.sqrt(1 + s) - 1, 1 / (1 + s) - 1
    after = np.clip(t - t_c, 0.0, None)
    zs = []
    for p in range(plates):
        amp = (2 + 0.3 * p) * np.where(t >= t_c, 1 + a, 1.0)
        arg = 2 * np.pi * F0 * (t + phi * after) + 0.3
        zs.append(500 + amp * np.cos(arg) + sigma * rng.standard_normal(t.size))
    return table(t, zs)


def test_a_name_that_wins_only_by_its_parameter_count_is_not_told_apart():
    # A crack of 4e-5 (a 0.02-rad phase bend by the end of 3 minutes): a frequency drift, one
    # parameter cheaper, is named; ΔBIC prefers it by more than 6, but by AIC (2 a parameter, not
    # ln n) the margin is below 6, so the record does not tell them apart (issue 23: cracks named
    # frequency drifts). A crack ten times larger is named and told from the drift by both.
    d = diagnose(_crack_record(-4e-5, seed=1))
    (e,) = d["effects"]
    assert e["id"] == "frequency_modulation", d["effects"]
    crack = next(r for r in e["rivals"] if r["id"] == "stiffness_change")
    n_total = 180 * 20 * 10
    assert crack["aic_margin"] == pytest.approx(crack["margin"] - (math.log(n_total) - 2), abs=1e-6)
    assert crack["margin"] > 6 > crack["aic_margin"] and e["not_told_from"] == ["stiffness_change"]
    d = diagnose(_crack_record(-4e-4, seed=0))
    (e,) = d["effects"]
    drift = next(r for r in e["rivals"] if r["id"] == "frequency_modulation")
    assert e["id"] == "stiffness_change" and min(drift["margin"], drift["aic_margin"]) > 20, e["rivals"]
    assert e["not_told_from"] == []


def _line_of_sight_record(seconds=120.0, fs=20.0, plates=8, seed=0, warmup=(0.5, 30.0)):
    """A ToF-like table: each plate's x, y, z read one range error along its line of sight
    (gains 0.15, 0.1, 1; frame-common range noise ρ 0.8 plus a little of each axis' own), the
    motion on z, and a warm-up (a mm, τ s) in range: one event seen on three axes."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(seconds * fs)) / fs
    common = rng.standard_normal(t.size)
    warm = warmup[0] * np.exp(-t / warmup[1])
    rows = []
    for p in range(plates):
        r = 0.8 * (math.sqrt(0.8) * common + math.sqrt(0.2) * rng.standard_normal(t.size)) + warm
        z = 500 + (2 + 0.2 * p) * np.cos(2 * np.pi * F0 * t + 0.3) + r
        x = 40.0 * p + 0.15 * r + 0.02 * rng.standard_normal(t.size)
        y = 10.0 + 0.1 * r + 0.02 * rng.standard_normal(t.size)
        rows.append(pd.DataFrame({"t": t, "plate": p + 1, "x": x, "y": y, "z": z}))
    return pd.concat(rows, ignore_index=True)


def test_one_event_named_on_several_axes_is_one_instance_for_the_flexible_alternative():
    # issue 23, frame-level seeds 411 and 416: a warm-up named on a plate's x, y and z was weighed
    # as "several" drifts against one unnamed trend; the three, discounted once for the axes'
    # shared noise, paid every instance's parameters, and the trend took the name's place
    from types import SimpleNamespace

    from jaxdefl.diagnose._search import _events

    ctx, _, _ = build_context(_line_of_sight_record(seconds=30.0, warmup=(0.0, 1.0)))
    by = {(s.plate, s.axis): i for i, s in enumerate(ctx.series)}

    def inst(plates, axis, **par):
        p = SimpleNamespace(
            series=[by[(q, axis)] for q in plates], parameters={k: {"value": v} for k, v in par.items()}
        )
        return SimpleNamespace(proposal=p)

    every = range(1, 9)
    assert _events(ctx, "drift", [inst(every, "z"), inst(every, "y"), inst([1, 2, 3, 5, 6, 7, 8], "x")]) == 1
    assert _events(ctx, "drift", [inst([1, 2, 3], "z"), inst([6, 7, 8], "z")]) == 2
    assert _events(ctx, "level_jump", [inst(every, "z", t_jump_s=30.2), inst(every, "x", t_jump_s=30.5)]) == 1
    assert _events(ctx, "level_jump", [inst(every, "z", t_jump_s=30.2), inst(every, "x", t_jump_s=80.0)]) == 2
    d = diagnose(_line_of_sight_record())
    drifts = [e for e in d["effects"] if e["id"] == "drift"]
    assert drifts and not [x for x in d.get("dropped", []) if x["id"] == "drift"], (
        d["effects"],
        d["dropped"],
    )


def test_an_accepted_instance_is_not_proposed_again():
    # frame-level seed 417: a line in the load's shape on z was named as two mode-3 instances at
    # one frequency, on overlapping plates and with opposite signs; one mode has one amplitude
    from types import SimpleNamespace

    from jaxdefl.diagnose._search import _repeats

    ctx, _, _ = build_context(_line_of_sight_record(seconds=30.0, warmup=(0.0, 1.0)))
    by = {(s.plate, s.axis): i for i, s in enumerate(ctx.series)}

    def prop(eid, plates, axis, **par):
        return SimpleNamespace(
            effect=eid,
            series=[by[(q, axis)] for q in plates],
            parameters={k: {"value": v} for k, v in par.items()},
        )

    mode = prop("mode_shape", [4, 5, 7, 8], "z", mode=3, freq_hz=3.3743)
    done = [SimpleNamespace(proposal=mode)]
    assert _repeats(ctx, prop("mode_shape", [5, 6, 7], "z", mode=3, freq_hz=3.3742), done)
    assert not _repeats(ctx, prop("mode_shape", [5, 6, 7], "z", mode=3, freq_hz=4.2), done)
    assert not _repeats(ctx, prop("mode_shape", [5, 6, 7], "z", mode=2, freq_hz=3.3742), done)
    assert not _repeats(ctx, prop("mode_shape", [5, 6, 7], "x", mode=3, freq_hz=3.3742), done)
    jump = [SimpleNamespace(proposal=prop("level_jump", [1, 2, 3], "z", t_jump_s=10.2))]
    assert _repeats(ctx, prop("level_jump", [2, 3], "z", t_jump_s=10.6), jump)
    assert not _repeats(ctx, prop("level_jump", [2, 3], "z", t_jump_s=20.0), jump)
    warm = [SimpleNamespace(proposal=prop("drift", [1, 2, 3], "z"))]
    assert not _repeats(ctx, prop("drift", [2, 3], "z"), warm)  # no locator: never a repeat
