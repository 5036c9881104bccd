"""camera_shake and stiffness_change (issue 12): each lives in the simulator (frames) and in the
diagnosis; the diagnosis recovers the injected parameters below the noise, names nothing on
controls with AR(1) (ρ 0.6) or frame-common noise, and is not taken for its neighbours (a
timing error or a vibration for the shake; a steady amplitude trend, a frequency drift or a
level jump for the crack), nor they for it."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy.signal import lfilter
from test_diagnose_effects_a import make_case as make_plates
from test_diagnose_effects_b import F0, accept, make_case, passing, value, within
from test_diagnose_effects_b import delta_bic as dbic

from jaxdefl.diagnose.detectors.amplitude_modulation import EFFECT as AM
from jaxdefl.diagnose.detectors.camera_shake import EFFECT as SHAKE
from jaxdefl.diagnose.detectors.extra_periodic import EFFECT as EXTRA
from jaxdefl.diagnose.detectors.frequency_modulation import EFFECT as FM
from jaxdefl.diagnose.detectors.level_jump import EFFECT as JUMP
from jaxdefl.diagnose.detectors.motion_artefact import EFFECT as MOTION
from jaxdefl.diagnose.detectors.stiffness_change import EFFECT as CRACK
from jaxdefl.diagnose.detectors.timing_error import EFFECT as TIMING
from jaxdefl.simulate import config_from_dict, pixel_model, render_frames
from jaxdefl.simulate.injection import make_spec, shake_displacement

OMEGA = 2 * math.pi * F0


def shake(rms: float, corner: float, seed: int = 3):
    spec = make_spec("camera_shake", {"rms_mm": rms, "corner_hz": corner})
    return lambda t: shake_displacement(spec, t, seed)


def best(ctx, states, effect):
    found = passing(ctx, states, effect.propose(ctx, states))
    return found[0] if found else None


# ------------------------------------------------------------------------------ the simulator


def test_camera_shake_moves_every_pixel_alike():
    """The camera moves along its optical axis: the plates' pixels and the static scene (floor
    targets, beam top) read the same displacement, which is `shake_displacement`'s."""
    base = {"recording": {"duration_s": 3.0}, "camera": {"frame_rate_hz": 10.0}}
    table = {"id": "camera_shake", "rms_mm": 0.6, "corner_hz": 0.3, "amplitude_mm": 0.4, "freq_hz": 0.7}
    cfg = config_from_dict({**base, "effect": [table]}, "<test>")
    t, f, _, _ = render_frames(cfg, seed=3)
    t0, f0, _, _ = render_frames(dataclasses.replace(cfg, effects=()), seed=3)
    d = (f - f0).reshape(len(t), -1)
    expect = shake_displacement(cfg.effects[0], t - cfg.t0_s, 3)
    assert np.std(expect) > 0.3
    on7 = pixel_model(cfg).plate_idx == 6
    for pixels in (~on7, on7):
        assert np.nanmax(np.abs(np.nanmedian(d[:, pixels], axis=1) - expect)) < 2e-3
    # chunking the frames does not move it: the value at a time is the same from any start
    assert np.allclose(shake_displacement(cfg.effects[0], (t - cfg.t0_s)[20:], 3), expect[20:])


# ------------------------------------------------------------------------------ camera_shake


def test_camera_shake_found_with_its_size_not_as_a_clock_or_a_vibration():
    """0.14 mm RMS of slow camera motion (σ 0.76 mm) on both axes, LDS under plates 2 and 4: the
    shake is named on every plate with its RMS; against the LDS the camera's clock and taps see
    nothing, and a vibration line does not explain it better."""
    u = shake(0.14, 0.02)
    ctx, states = make_case(seed=5, duration=300.0, axes=("z", "x"), lds_plates=(2, 4), extra=u)
    p = best(ctx, states, SHAKE)
    assert p is not None and value(p, "axis") in ("z", "x")
    assert sorted({ctx.series[i].plate for i in p.series}) == [1, 2, 3, 4, 5]
    truth = float(np.std(u(np.arange(0, 300, 0.05))))
    assert within(value(p, "rms_mm"), truth)
    assert dbic(ctx, states, p) < -100
    for eff in (TIMING, MOTION):
        assert best(ctx, states, eff) is None, eff.id
    line = best(ctx, states, EXTRA)
    assert line is None or dbic(ctx, states, line) > dbic(ctx, states, p)
    # after the shake of both axes, nothing of it is left
    states = accept(states, p)
    q = best(ctx, states, SHAKE)
    assert q is not None and value(q, "axis") != value(p, "axis")
    states = accept(states, q)
    assert best(ctx, states, SHAKE) is None


def _coloured(kind: str, seed: int):
    """An inject for `make_plates`: AR(1) noise (ρ 0.6) per plate and axis, or white noise of which
    60 % of the variance is shared by the plates of a frame; σ as the white case's."""
    rng = np.random.default_rng([seed, 44])
    common = rng.standard_normal(20 * 600 + 1)
    own: dict = {}

    def inject(t, p, axis, clean, eps, sig):
        k = np.rint(t * 20.0).astype(int)
        if kind == "ar1":
            key = (p, axis)
            if key not in own:
                own[key] = lfilter([1.0], [1.0, -0.6], rng.standard_normal(k.max() + 1)) * math.sqrt(0.64)
            return clean + sig * own[key][k]
        return clean + sig * (math.sqrt(0.4) * eps + math.sqrt(0.6) * common[k])

    return inject


@pytest.mark.parametrize("kind", ["ar1", "frame_common"])
def test_controls_name_neither(kind):
    """Controls with AR(1) noise (ρ 0.6) or noise shared by the plates of a frame: no shake (its
    statistic is over the long-run variance of the plates' mean) and no crack."""
    from test_diagnose_effects_a import passing as passing_a

    for seed in (1, 2):
        ctx, states = make_plates(_coloured(kind, seed), n_plates=6, seed=seed)
        for eff in (SHAKE, CRACK):
            assert passing_a(ctx, states, eff.propose(ctx, states)) == [], (kind, seed, eff.id)


def test_a_warm_up_or_a_jump_is_not_a_shake():
    """An exponential warm-up and a step common to the plates: drift's and level_jump's shapes with
    2 parameters; the shake's spline, if it passes at all, is worse by BIC."""
    from jaxdefl.diagnose.detectors.drift import EFFECT as DRIFT

    for extra, named in ((lambda t: 0.3 * np.exp(-t / 120.0), DRIFT), (lambda t: 0.12 * (t >= 250.0), JUMP)):
        ctx, states = make_case(seed=6, axes=("z",), extra=extra)
        own = best(ctx, states, named)
        assert own is not None, named.id
        s = best(ctx, states, SHAKE)
        assert s is None or dbic(ctx, states, s) > dbic(ctx, states, own), named.id


# ------------------------------------------------------------------------------ stiffness_change


def crack(s: float, t_c: float):
    """The simulator's crack: amplitude × 1/(1 + s), frequency × √(1 + s), phase continuous."""
    am = lambda t: np.where(t >= t_c, 1.0 / (1.0 + s), 1.0)  # noqa: E731
    fm = lambda t: OMEGA * (math.sqrt(1.0 + s) - 1.0) * np.maximum(t - t_c, 0.0)  # noqa: E731
    return {"am": am, "fm": fm}


@pytest.mark.parametrize("lds", [(), pytest.param((2, 4), marks=pytest.mark.slow)])
def test_crack_found_with_its_time_and_stiffness(lds):
    """A 0.01 % stiffness loss at 380 s (a 0.2-rad phase by the end): named with s and t_c, better
    than a frequency drift, an amplitude trend or a level jump (which see parts of it)."""
    ctx, states = make_case(seed=7, axes=("z", "x"), lds_plates=lds, **crack(-1e-4, 380.0))
    p = best(ctx, states, CRACK)
    assert p is not None
    assert within(value(p, "stiffness_change"), -1e-4)
    assert abs(value(p, "t_s") - 380.0) < max(15.0, 3 * p.parameters["t_s"]["sigma"])
    for eff in (FM, AM, JUMP):
        other = best(ctx, states, eff)
        assert other is None or dbic(ctx, states, other) > dbic(ctx, states, p), eff.id
    states = accept(states, p)
    for eff in (CRACK, FM, AM):
        assert best(ctx, states, eff) is None, eff.id


def test_amplitude_step_under_load_control():
    """A crack under load control at the actuator's frequency: the amplitude alone steps by +3 %."""
    ctx, states = make_case(seed=8, axes=("z", "x"), am=lambda t: np.where(t >= 200.0, 1.03, 1.0))
    p = best(ctx, states, CRACK)
    assert p is not None and p.detail["variant"] == "amplitude"
    assert within(value(p, "amplitude_change"), 0.03) and abs(value(p, "t_s") - 200.0) < 15.0


def test_a_steady_amplitude_trend_is_not_a_crack():
    """Fatigue's linear amplitude trend (2e-4 /s): amplitude_modulation, not a step."""
    ctx, states = make_case(seed=7, axes=("z", "x"), am=lambda t: 1 + 2e-4 * (t - 300.0))
    am = best(ctx, states, AM)
    assert am is not None
    c = best(ctx, states, CRACK)
    assert c is None or dbic(ctx, states, c) > dbic(ctx, states, am)


def test_diagnosed_shake_and_crack_become_effect_tables():
    """`reconcile` writes what the diagnosis fitted as [[effect]] tables the simulator accepts."""
    from jaxdefl.reconcile.engine import specs_from_diagnosis

    def par(v):
        return {"value": v, "sigma": None}

    diag = [
        {
            "id": "camera_shake",
            "plates": [1, 2, 3],
            "parameters": {"rms_mm": par(0.12), "corner_hz": par(0.01)},
        },
        {
            "id": "stiffness_change",
            "plates": [1, 2, 3],
            "parameters": {
                "t_s": par(120.0),
                "stiffness_change": par(-0.01),
                "f0_change": par(math.sqrt(0.99) - 1),
                "amplitude_change": par(1 / 0.99 - 1),
            },
        },
    ]
    (shake_spec, why1), (crack_spec, why2) = specs_from_diagnosis(diag, 600.0, None, 3)
    assert why1 == why2 == "simulated"
    assert shake_spec.to_dict() == {"id": "camera_shake", "rms_mm": 0.12, "corner_hz": 0.01, **ZERO_SWAY}
    assert crack_spec.p("t_s") == 120.0 and math.isclose(crack_spec.p("f0_change"), math.sqrt(0.99) - 1)


ZERO_SWAY = {"amplitude_mm": 0.0, "freq_hz": 0.0, "phase_rad": 0.0}
