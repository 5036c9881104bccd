"""A structured-light record (issue 23): its kind judged on the motion under the camera's level
jumps, and the configured camera's own physics (level jumps, depth lattice) held as nominal, while
a jump or a lattice beyond the configured sizes is still named."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from jaxdefl.diagnose import build_context, run_diagnosis
from jaxdefl.diagnose._sensor_nominal import JUMP_SIGMAS, LATTICE_FACTOR, within_configured
from jaxdefl.diagnose.record_kind import SLOW_SHARE, binary_steps, recognise
from jaxdefl.settings import DiagnoseSettings

F0 = 1.0224
FS = 30.0
# the shipped Kinect configs' camera (configs/exp2_kinect_*.toml)
KINECT = dict(sensor="structured_light", depth_step_mm_at_2m=3.0, jumps_per_minute=1.0, jump_mm=3.0)


def _kind(t, y):
    return recognise([(t, y)], float(np.median(np.diff(t))))


def _steps(t, times, sizes):
    return sum(d * (t >= tj) for tj, d in zip(times, sizes, strict=True))


# --- the record's kind, judged on the motion ---------------------------------------------------


@pytest.mark.parametrize("sizes", [(12.0, -6.0, 14.0, 8.0), (6.0, -4.0, 7.5, 4.0)])
def test_a_line_under_dominant_level_jumps_is_a_forced_harmonic_record(sizes):
    """A 2.5-mm loading line seen by a camera whose level jumps hold most of the variance (the
    first set: more than SLOW_SHARE of it slow, read as quasi-static before; the second: the
    steps' spectrum leaves the line a minor share, read as broadband before)."""
    rng = np.random.default_rng(3)
    t = np.arange(int(180 * FS)) / FS
    jumps = _steps(t, [31.0, 74.0, 122.0, 160.0], sizes)
    y = 2200 + 2.5 * np.cos(2 * np.pi * F0 * t) + jumps + 0.7 * rng.standard_normal(t.size)
    rk = _kind(t, y)
    if sizes[0] == 12.0:
        assert rk.slow_share >= SLOW_SHARE  # the jumps hold most of the variance ...
    assert rk.kind == "forced_harmonic"  # ... but the motion is the loading line
    assert abs(rk.lines_hz[0] - F0) < 2 / 180
    assert rk.level_path["steps"] >= 4 and rk.level_path["line_share_after"] > 0.8
    assert "level path" in rk.statement


def test_a_staircase_and_a_ramp_stay_quasi_static():
    rng = np.random.default_rng(4)
    fs = 50.0
    t = np.arange(int(14 * fs)) / fs
    # 5 steps out and 5 back, each a 0.2-s move then a 1-s dwell (the DROPBEAR roller's path)
    k = np.clip((t - 1.0) / 1.2, 0, 10)
    stairs = np.floor(k) + np.clip((k - np.floor(k)) * 6, 0, 1)
    path = 0.42 * np.where(stairs <= 5, stairs, 10 - stairs)
    assert _kind(t, path + 0.005 * rng.standard_normal(t.size)).kind == "quasi_static"
    ramp = np.clip(t / 3.0, 0, 1) * 4.0 + 0.02 * rng.standard_normal(t.size)
    assert _kind(t, ramp).kind == "quasi_static"
    # a slow load path with a weak line on it: the path is the motion
    t2 = np.arange(int(180 * FS)) / FS
    y = _steps(t2, [40.0, 90.0, 140.0], [5.0, 5.0, 5.0]) + 0.05 * np.cos(2 * np.pi * F0 * t2)
    assert _kind(t2, y + 0.3 * rng.standard_normal(t2.size)).kind == "quasi_static"


def test_binary_steps_finds_the_steps_and_stops_at_the_noise():
    rng = np.random.default_rng(5)
    n = 3000
    y = np.where(np.arange(n) >= 1000, 2.0, 0.0) + np.where(np.arange(n) >= 2200, -1.5, 0.0)
    levels, cuts = binary_steps(y + 0.3 * rng.standard_normal(n))
    assert len(cuts) == 2 and abs(cuts[0] - 1000) <= 3 and abs(cuts[1] - 2200) <= 3
    assert abs(levels[1500] - 2.0) < 0.05 and abs(levels[2500] - 0.5) < 0.05
    _, none = binary_steps(0.3 * rng.standard_normal(n))
    assert none == []


# --- the configured camera's own physics ----------------------------------------------------


def kinect_table(seconds=80.0, plates=3, jumps=((25.0, 3.0), (55.0, -2.5)), seed=0, sigma=0.6):
    """Plates at 2.2 m moving at F0 (2-3 mm) seen by a camera whose depth image steps at
    ``jumps`` ((t, mm), every plate alike; x and y move by x/z and y/z of it)."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(seconds * FS)) / FS
    common = _steps(t, [j[0] for j in jumps], [j[1] for j in jumps]) if jumps else np.zeros_like(t)
    rows = []
    for p in range(plates):
        x0, y0, z0 = -900.0 + 250 * p, -300.0, 2200.0
        z = z0 + common + (2 + 0.3 * p) * np.cos(2 * np.pi * F0 * t + 0.3)
        z = z + sigma * rng.standard_normal(t.size)
        x = x0 * z / z0 + 0.3 * sigma * rng.standard_normal(t.size)
        y = y0 * z / z0 + 0.3 * sigma * rng.standard_normal(t.size)
        rows.append(pd.DataFrame({"t": t, "plate": p + 4, "x": x, "y": y, "z": z}))
    return pd.concat(rows, ignore_index=True)


def lds_table(traj):
    """An LDS under each plate: its motion without the camera's offset, jumps and noise."""
    t = np.unique(traj["t"].to_numpy())
    plates = sorted(traj["plate"].unique())
    return pd.concat(
        [
            pd.DataFrame({"t": t, "plate": p, "z": (2 + 0.3 * j) * np.cos(2 * np.pi * F0 * t + 0.3)})
            for j, p in enumerate(plates)
        ],
        ignore_index=True,
    )


LIB = ("level_jump", "camera_shake", "drift", "extra_periodic")


def test_configured_level_jumps_are_nominal_and_a_larger_one_is_named():
    traj = kinect_table()
    d = run_diagnosis(traj, None, DiagnoseSettings(**KINECT, effects=LIB)).to_json()
    assert d["effects"] == [], [(e["id"], e["parameters"]) for e in d["effects"]]
    held = d["sensor_nominal"]["level_jumps"]
    assert len(held) == 2
    for j, (tj, size) in zip(held, [(25.0, 3.0), (55.0, -2.5)], strict=True):
        assert abs(j["t_s"] - tj) < 0.1 and abs(j["size_mm"] - size) < 0.3
    # without the config, the same jumps are structure the diagnosis locates (here unnamed)
    bare = run_diagnosis(traj, None, DiagnoseSettings(sensor="structured_light", effects=LIB)).to_json()
    assert bare["sensor_nominal"]["level_jumps"] == []
    assert bare["effects"] or bare["unnamed"]
    # a jump 5x the configured one is beyond the camera's own: named, with its size
    big = kinect_table(jumps=((25.0, 3.0), (55.0, 5 * 3.0)))
    d = run_diagnosis(big, lds_table(big), DiagnoseSettings(**KINECT, effects=LIB)).to_json()
    named = [e for e in d["effects"] if e["id"] == "level_jump"]
    assert named, [(e["id"], e["parameters"]) for e in d["effects"]]
    assert abs(named[0]["t_start"] - 55.0) < 0.2
    assert all(
        abs(j["size_mm"]) <= JUMP_SIGMAS * KINECT["jump_mm"] for j in d["sensor_nominal"]["level_jumps"]
    )


def _quantised_table(q_mm, seconds=30.0, plates=3, seed=1):
    """Plates at 2.2 m whose centroids read depth on a hard lattice of q_mm (a disparity
    camera's pixels rounded alike), 0.3 mm of noise after the rounding; a 15-20 mm stroke, so
    that a coarse lattice shows several steps."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(seconds * FS)) / FS
    rows = []
    for p in range(plates):
        h = 2200.0 + (15.0 + 1.5 * p) * np.cos(2 * np.pi * F0 * t + 0.2 * p)
        z = q_mm * np.round(h / q_mm) + 0.3 * rng.standard_normal(t.size)
        rows.append(pd.DataFrame({"t": t, "plate": p + 4, "z": z}))
    return pd.concat(rows, ignore_index=True)


# the configured lattice at the plates' 2.2 m: 3 mm at 2 m x (2.2 / 2)^2 = 3.63 mm
Q_CFG = KINECT["depth_step_mm_at_2m"] * (2200.0 / 2000.0) ** 2


@pytest.mark.parametrize(("q_mm", "nominal"), [(Q_CFG, True), (1.25 * LATTICE_FACTOR * Q_CFG, False)])
def test_the_configured_depth_lattice_is_nominal_and_a_coarser_one_is_named(q_mm, nominal):
    traj = _quantised_table(q_mm)
    d = run_diagnosis(traj, None, DiagnoseSettings(**KINECT, effects=("quantization",))).to_json()
    ids = [e["id"] for e in d["effects"]]
    held = [e["id"] for e in d["nominal_physics"]]
    if nominal:
        assert ids == [] and held == ["quantization"]
        assert "depth lattice" in d["nominal_physics"][0]["reason"]
        assert abs(d["nominal_physics"][0]["parameters"]["step_mm"]["value"] - q_mm) < 0.1 * q_mm
    else:
        assert ids == ["quantization"] and held == []
        assert abs(d["effects"][0]["parameters"]["step_mm"]["value"] - q_mm) < 0.1 * q_mm
    # without the config the same lattice is named
    bare = run_diagnosis(traj, None, DiagnoseSettings(sensor="structured_light", effects=("quantization",)))
    assert [a.proposal.effect for a in bare.accepted] == ["quantization"]


def test_within_configured_holds_the_sizes_the_config_gives():
    ctx, _, _ = build_context(kinect_table(seconds=20.0, jumps=()), None, DiagnoseSettings(**KINECT))
    q_cfg = Q_CFG

    def q(step):
        return {"id": "quantization", "plates": ctx.plates, "parameters": {"step_mm": {"value": step}}}

    def jump(size):
        return {"id": "level_jump", "plates": ctx.plates, "parameters": {"size_mm": {"value": size}}}

    assert within_configured(ctx, q(1.5 * q_cfg)) is not None
    assert within_configured(ctx, q(1.05 * LATTICE_FACTOR * q_cfg)) is None
    assert within_configured(ctx, jump(-9.0)) is not None
    assert within_configured(ctx, jump(5 * 3.0)) is None
    # a camera with nothing configured holds nothing as its own
    bare, _, _ = build_context(
        kinect_table(seconds=20.0, jumps=()), None, DiagnoseSettings(sensor="structured_light")
    )
    assert within_configured(bare, q(q_cfg)) is None and within_configured(bare, jump(1.0)) is None
    # a ToF camera carries no disparity lattice: the config's facts are not read for it
    tof, _, _ = build_context(
        kinect_table(seconds=20.0, jumps=()), None, DiagnoseSettings(**{**KINECT, "sensor": "tof"})
    )
    assert tof.depth_step_mm_at_2m is None and tof.jump_mm is None
