"""[[effect]] tables: the simulator injects diagnosed physics where it acts (ranges, timestamps,
the beam's motion), with the diagnosis' parameters, and refuses what it cannot render."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from jaxdefl import ConfigError
from jaxdefl.simulate import config_from_dict, kinematics, render_frames
from jaxdefl.simulate.lds import truth_table

BASE = {"recording": {"duration_s": 6.0}, "camera": {"frame_rate_hz": 10.0}}


def _cfg(*effects):
    return config_from_dict({**BASE, "effect": list(effects)}, "<test>")


@pytest.mark.parametrize(
    "table, message",
    [
        ({"id": "no_such_effect"}, "key 'effect[1].id': expected one of drift,"),
        ({"id": "drift", "amplitude_mm": 1.0}, "key 'effect[1].tau_s': drift needs tau_s"),
        ({"id": "drift", "amplitude_mm": 1.0, "tau_s": 5.0, "size": 2}, "not a parameter of drift"),
        ({"id": "drift", "amplitude_mm": 1.0, "tau_s": -5.0}, "'effect[1].tau_s': expected a time constant"),
        ({"id": "level_jump", "t_jump_s": 1.0, "size_mm": "big"}, "'effect[1].size_mm': expected a number"),
        ({"id": "outliers", "fraction": 0.1, "scale_mm": 3.0, "plates": [0, 99]}, "expected a list of plate"),
        ({"id": "harmonic_distortion", "order": 2.5, "amplitude_mm": 0.1}, "expected an integer >= 2"),
    ],
)
def test_bad_effect_tables_are_one_line_errors(table, message):
    with pytest.raises(ConfigError) as err:
        _cfg(table)
    assert message in str(err.value) and "\n" not in str(err.value)


def test_range_effects_add_to_every_pixel_and_nothing_else_moves():
    """A warm-up drift and a jump read as range offsets of exactly the injected size; the noise
    streams do not depend on the effects, so the difference to the clean recording is the effect."""
    drift = {"id": "drift", "amplitude_mm": 1.5, "tau_s": 2.0}
    jump = {"id": "level_jump", "t_jump_s": 4.0, "size_mm": -0.8, "plates": [7]}
    cfg = _cfg(drift, jump)
    t, f, _, _ = render_frames(cfg, seed=3)
    t0, f0, _, _ = render_frames(dataclasses.replace(cfg, effects=()), seed=3)
    assert np.array_equal(t, t0)
    d = (f - f0).reshape(len(t), -1)
    trel = t - cfg.t0_s
    expect = 1.5 * np.exp(-trel / 2.0)
    # off the plates: the drift alone (float32 frames: ~1e-4 mm rounding at 2 m)
    assert np.nanmax(np.abs(np.nanmedian(d, axis=1) - expect)) < 2e-3
    # plate 7's pixels also jump after 4 s
    from jaxdefl.simulate import pixel_model

    on7 = pixel_model(cfg).plate_idx == 6
    d7 = np.nanmedian(d[:, on7], axis=1)
    assert np.nanmax(np.abs(d7 - expect - np.where(trel >= 4.0, -0.8, 0.0))) < 2e-3


def test_motion_effects_move_the_beam_as_the_diagnosis_models_them():
    am = {"id": "amplitude_modulation", "relative_rate_per_s": 0.05, "t_ref_s": 3.0}
    fm = {"id": "frequency_modulation", "depth_rad": 0.3, "freq_hz": 0.5, "phase_rad": 0.2}
    xp = {"id": "extra_periodic", "freq_hz": 7.3, "amplitude_mm": 0.4, "phase_rad": 1.0}
    cfg = _cfg(am, fm, xp)
    t = cfg.t0_s + np.linspace(0.0, 6.0, 2001)
    defl, _, _ = kinematics(cfg, t)
    ld = cfg.loading
    tau = t - cfg.t0_s
    theta = 2 * np.pi * ld.frequency_hz * tau + ld.phase_rad
    clean, _, _ = kinematics(dataclasses.replace(cfg, effects=()), t)
    good = np.abs(np.sin(theta)) > 0.3
    amp = np.where(good, clean - ld.mean_mm, 0.0) / np.where(good, np.sin(theta), 1.0)  # fatigue A(t)
    expect = (
        ld.mean_mm
        + amp * (1 + 0.05 * (tau - 3.0)) * np.sin(theta + 0.3 * np.sin(2 * np.pi * 0.5 * tau + 0.2))
        + 0.4 * np.cos(2 * np.pi * 7.3 * tau + 1.0)
    )
    assert np.max(np.abs(defl - expect)[good]) < 1e-9
    # the truth table (and so the LDS) follows the moved beam, each plate in the beam's shape
    z = truth_table(cfg, t)["z"].to_numpy().reshape(t.size, -1)
    z0 = truth_table(dataclasses.replace(cfg, effects=()), t)["z"].to_numpy().reshape(t.size, -1)
    moved = np.abs(defl - clean) > 0.05
    ratio = (z - z0)[moved] / (defl - clean)[moved, None]
    assert np.allclose(ratio, ratio[0], rtol=1e-6) and ratio[0, 6] > ratio[0, 0] > 0


def test_a_bending_mode_moves_each_plate_in_its_shape_in_the_truth_the_lds_and_the_frames():
    """mode_shape: plate p at x_p moves by a sin(nπ x_p/L) cos(2π f τ + ψ) (antisymmetric for n = 2:
    the plates either side of mid-span in opposite directions), the LDS alike, and the frames'
    plate pixels by the plate's displacement along their rays (the mid-span plate, a node, not)."""
    from jaxdefl.simulate.lds import lds_block

    mode = {"id": "mode_shape", "mode": 2, "freq_hz": 4.1, "amplitude_mm": 0.5, "phase_rad": 0.3}
    cfg = _cfg(mode)
    nominal = dataclasses.replace(cfg, effects=())
    t = cfg.t0_s + np.linspace(0.0, 6.0, 601)
    tau = t - cfg.t0_s
    z = truth_table(cfg, t)["z"].to_numpy().reshape(t.size, -1)
    z0 = truth_table(nominal, t)["z"].to_numpy().reshape(t.size, -1)
    xi = np.asarray(cfg.plate_x_mm()) / cfg.beam.span_mm
    expect = 0.5 * np.cos(2 * np.pi * 4.1 * tau + 0.3)[:, None] * np.sin(2 * np.pi * xi)[None, :]
    np.testing.assert_allclose(z - z0, expect, atol=1e-9)
    lds, lds0 = lds_block(cfg, 1, 0, 6.0), lds_block(nominal, 1, 0, 6.0)
    p = int(lds.plate.iloc[0])
    sel = (lds.plate == p).to_numpy()
    tl = lds.t.to_numpy()[sel] - cfg.t0_s
    np.testing.assert_allclose(
        lds.z.to_numpy()[sel] - lds0.z.to_numpy()[sel],
        0.5 * np.sin(2 * np.pi * xi[p - 1]) * np.cos(2 * np.pi * 4.1 * tl + 0.3),
        atol=1e-9,
    )
    t1, f1, _, _ = render_frames(cfg, seed=3)
    t0, f0, _, _ = render_frames(nominal, seed=3)
    assert np.array_equal(t1, t0)
    d = np.nan_to_num(f1 - f0)
    from jaxdefl.simulate.scene import pixel_model

    idx = pixel_model(cfg).plate_idx.reshape(f0.shape[1:])
    assert np.all(d[:, idx < 0] == 0)  # the scene off the plates does not move
    q = np.cos(2 * np.pi * 4.1 * (t0 - cfg.t0_s) + 0.3)
    seen = [j for j in range(len(xi)) if np.any(idx == j)]
    assert len(seen) >= 3
    for j in seen:  # ranges along oblique rays: within 10 % of the plate's displacement
        want = 0.5 * np.sin(2 * np.pi * xi[j]) * q
        np.testing.assert_allclose(
            d[:, idx == j].mean(axis=1), want, atol=0.1 * 0.5 * abs(np.sin(2 * np.pi * xi[j])) + 1e-6
        )
    # the plates either side of mid-span move in opposite directions
    assert np.corrcoef(d[:, idx == seen[0]].mean(axis=1), d[:, idx == seen[-1]].mean(axis=1))[0, 1] < -0.99


def test_timing_error_moves_the_written_stamps_only():
    cfg = _cfg({"id": "timing_error", "offset_s": 0.004, "rate_ppm": 100.0})
    t, f, _, _ = render_frames(cfg, seed=2)
    t0, f0, _, _ = render_frames(dataclasses.replace(cfg, effects=()), seed=2)
    assert np.allclose(t - t0, 0.004 + 1e-4 * (t0 - cfg.t0_s), atol=1e-6)  # epoch seconds: 2.4e-7 s spacing
    assert np.array_equal(f, f0, equal_nan=True)


def test_effects_round_trip_through_the_effective_config():
    tables = [{"id": "drift", "amplitude_mm": 1.0, "tau_s": 60.0, "plates": [3, 5]}]
    cfg = _cfg(*tables)
    again = config_from_dict(cfg.to_dict(), "<again>")  # the effective config (config.json) reads back
    assert again.effects == cfg.effects and again == dataclasses.replace(cfg, source="<again>")
    changed = config_from_dict(
        {
            **BASE,
            "change": [
                {"kind": "stiffness", "t_s": 2.0, "stiffness_change": -0.01},
                {"kind": "sensor_fault", "t_s": 1.0, "plate": 3, "fault": "jump", "size": 2.0},
            ],
        }
    )
    assert config_from_dict(changed.to_dict()).changes == changed.changes


# one example table per registry id: adding an effect to the registry needs its line here
EXAMPLES = {
    "drift": {"amplitude_mm": 1.5, "tau_s": 2.0},
    "level_jump": {"t_jump_s": 3.0, "size_mm": -0.8, "plates": [7]},
    "camera_shake": {"rms_mm": 0.5, "corner_hz": 0.2, "amplitude_mm": 0.3, "freq_hz": 1.3},
    "outliers": {"fraction": 0.3, "scale_mm": 5.0, "plates": [6, 7]},
    "timing_error": {"offset_s": 0.004, "rate_ppm": 100.0},
    "amplitude_modulation": {"depth": 0.2, "freq_hz": 0.5, "phase_rad": 0.3},
    "frequency_modulation": {"drift_hz_per_s": 0.02, "t_ref_s": 3.0},
    "extra_periodic": {"freq_hz": 7.3, "amplitude_mm": 0.4},
    "harmonic_distortion": {"order": 2, "amplitude_mm": 0.3, "phase_rad": 1.0},
    "stiffness_change": {"t_s": 2.0, "stiffness_change": -0.05},
    "debond": {"t_s": 2.0, "duration_s": 3.0, "plate": 7, "amplitude_change": -0.5},
    "sensor_fault": {"t_s": 2.0, "plate": 3, "fault": "jump", "size": 2.0},
    "mode_shape": {"mode": 2, "freq_hz": 4.1, "amplitude_mm": 0.5, "phase_rad": 0.3},
    "clipping": {"plate": 7, "level_mm": 0.5},
    "heteroscedastic_noise": {"modulation": 0.5, "phase_rad": 0.3, "plates": [3, 4]},
    "quantization": {"step_mm": 1.0, "offset_mm": 0.2, "plates": [5]},
    "motion_artefact": {"tap_spread_s": 0.1},
}


def _toml(key: str, tables: list[dict]) -> str:
    def value(v):
        return (
            f'"{v}"'
            if isinstance(v, str)
            else (f"[{', '.join(map(str, v))}]" if isinstance(v, list) else repr(v))
        )

    base = "[recording]\nduration_s = 6.0\n[camera]\nframe_rate_hz = 10.0\nwidth = 88\nheight = 72\n"
    return base + "".join(
        f"[[{key}]]\n" + "".join(f"{k} = {value(v)}\n" for k, v in t.items()) for t in tables
    )


def _live(cfg, seed=4):
    from jaxdefl.simulate import camera_blocks

    ts, xs = zip(*camera_blocks(cfg, 6.0, seed, block_frames=25), strict=True)
    return np.concatenate(ts), np.concatenate(xs)


def test_every_registry_effect_simulates_from_a_toml_table_and_round_trips(tmp_path):
    """Each id of the registry, written as a TOML [[effect]] table, loads, reads back from the
    effective config (to_dict) and changes what its level shows: frames (ranges, stamps, the beam's
    motion) or, for a plate's motion and sensor faults, the live camera's centroids."""
    from jaxdefl.simulate import REGISTRY, load_config
    from jaxdefl.simulate.injection import FRAME_LEVELS

    assert set(EXAMPLES) == set(REGISTRY)
    nominal = load_config(_write(tmp_path / "nominal.toml", _toml("effect", [])))
    t0, f0, _, _ = render_frames(nominal, seed=3)
    lt0, lx0 = _live(nominal)
    for eid, params in EXAMPLES.items():
        cfg = load_config(_write(tmp_path / f"{eid}.toml", _toml("effect", [{"id": eid, **params}])))
        (spec,) = cfg.effects
        assert spec.id == eid and spec.level == REGISTRY[eid].level
        assert config_from_dict(cfg.to_dict(), cfg.source) == cfg, eid
        if spec.level in FRAME_LEVELS:
            t, f, _, _ = render_frames(cfg, seed=3)
            moved = not np.array_equal(t, t0) or not np.array_equal(f, f0, equal_nan=True)
            assert moved, eid
        else:
            with pytest.raises(ConfigError, match=f"effect {eid} acts on trajectories only"):
                render_frames(cfg, seed=3)
        lt, lx = _live(cfg)
        assert np.array_equal(lt, lt0)  # the frame clock is the camera's, never an effect's
        if spec.level not in ("range", "timestamps"):  # the live camera sees no pixels nor stamps
            assert not np.array_equal(lx, lx0, equal_nan=True), eid


def _write(path, text):
    path.write_text(text)
    return path


@pytest.mark.parametrize(
    "change",
    [
        {"kind": "stiffness", "t_s": 2.0, "stiffness_change": -0.05},
        {"kind": "stiffness", "t_s": 1.0, "duration_s": 2.0, "f0_change": -0.01, "amplitude_change": 0.0},
        {"kind": "debond", "t_s": 2.0, "plate": 7},
        {"kind": "sensor_fault", "t_s": 3.0, "duration_s": 1.0, "plate": 5, "fault": "lost"},
        {"kind": "sensor_fault", "t_s": 1.0, "plate": 11, "fault": "noise"},
    ],
)
def test_a_change_table_is_a_spelling_of_its_registry_effect(tmp_path, change):
    """[[change]] kind = K and [[effect]] id = (K's id) with the same keys give the same spec, the
    same live centroids, truth and (where frames can show it) the same frames."""
    from jaxdefl.simulate import load_config
    from jaxdefl.simulate.schedule import CHANGE_IDS

    effect = {"id": CHANGE_IDS[change["kind"]], **{k: v for k, v in change.items() if k != "kind"}}
    a = load_config(_write(tmp_path / "change.toml", _toml("change", [change])))
    b = load_config(_write(tmp_path / "effect.toml", _toml("effect", [effect])))
    assert a.effects == b.effects and a.changes == b.changes == a.effects
    for x, y in zip(_live(a), _live(b), strict=True):
        assert np.array_equal(x, y, equal_nan=True)
    t = a.t0_s + np.linspace(0.0, 6.0, 301)
    assert truth_table(a, t).equals(truth_table(b, t))
    assert not truth_table(a, t).equals(truth_table(dataclasses.replace(a, effects=()), t)) or (
        change["kind"] == "sensor_fault"
    )
    if change["kind"] == "stiffness":
        for x, y in zip(render_frames(a, seed=2)[:3], render_frames(b, seed=2)[:3], strict=True):
            assert np.array_equal(x, y, equal_nan=True)
