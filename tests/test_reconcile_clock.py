"""The clock level of `jaxdefl reconcile` (`jaxdefl.reconcile.clock`): the frame stamps' scatter
about their recovered clock against the configured camera's, with the simulator's own clock as
the null."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from jaxdefl.reconcile.clock import FLOOR_FRAMES, clock_levels, stamp_jitter_s
from jaxdefl.reconcile.engine import Reconciliation
from jaxdefl.simulate import load_config
from jaxdefl.simulate.lds import frame_clock

CONFIG = Path(__file__).resolve().parents[1] / "configs" / "exp2_tof_3hz.toml"


@pytest.fixture(scope="module")
def cfg():
    return load_config(CONFIG, "day1")


def _with_jitter(cfg, ms: float, dropout: float | None = None):
    cam = dataclasses.replace(cfg.camera, timestamp_jitter_ms=ms)
    if dropout is not None:
        cam = dataclasses.replace(cam, dropout_prob=dropout)
    return dataclasses.replace(cfg, camera=cam)


def _verdict(row):
    return Reconciliation([], [], (), {}, 3.0).verdict(row)


def test_stamp_jitter_is_the_sample_scatter_of_the_drawn_jitter():
    """Against the jitter itself (the draws' own RMS): 20 Hz, 8 ms, 30 % of the frames lost. A
    few stamps are a frame off where a neighbour is lost and the jitter crosses half a frame (4
    of 2800 here: no clock can tell), which raises the RMS by 2 %."""
    rng = np.random.default_rng(3)
    k = np.sort(rng.choice(4000, 2800, replace=False))
    e = 0.008 * rng.standard_normal(k.size)
    t = 1.7e9 + k / 20.0 + e
    assert stamp_jitter_s(t) == pytest.approx(np.sqrt(np.mean((e - e.mean()) ** 2)), rel=0.04)
    # a table repeats every stamp once per plate: the distinct stamps are the frames
    assert stamp_jitter_s(np.repeat(t, 13)) == pytest.approx(stamp_jitter_s(t), rel=1e-9)
    assert stamp_jitter_s(1.7e9 + k / 20.0) < 1e-6


def test_a_clock_that_jitters_against_a_regular_configured_one_stays_apart(cfg):
    _, t = frame_clock(_with_jitter(cfg, 8.0), 120.0, 5)
    (row,) = clock_levels(t, cfg, seed=11, n=100)
    assert row["recording_ms"] == pytest.approx(8.0, rel=0.1) and row["simulation_ms"] < 1e-3, row
    assert row["before"] > 5 * row["null_family"] and _verdict(row) == "still apart", row
    assert row["after"] == row["before"]  # no [[effect]] changes the clock


def test_stamps_rounded_to_a_millisecond_are_the_configured_regular_clock(cfg):
    """A 30-Hz camera stamped to the millisecond: 0.29 ms of rounding is a stamp's resolution,
    below the band's floor (0.02 frame = 0.67 ms)."""
    cfg = dataclasses.replace(cfg, camera=dataclasses.replace(cfg.camera, frame_rate_hz=30.0))
    _, t = frame_clock(cfg, 120.0, 5)
    (row,) = clock_levels(np.round(t, 3), cfg, seed=11, n=50)
    assert 0.2 < row["recording_ms"] < 0.35 and row["null_family"] >= FLOOR_FRAMES * 1e3 / 30.0, row
    assert _verdict(row) == "agreed already", row


def test_the_band_holds_the_configured_jitter_and_finds_a_larger_one(cfg):
    """A camera configured with 3 ms of jitter and 10 % drop-outs: its own clocks (other seeds)
    lie inside the family band; 5 ms lies outside (2 ms, above the 1-ms floor: the RMS of 2000
    stamps is known to 1.6 %, 0.05 ms, so at these sizes the floor is the band)."""
    conf = _with_jitter(cfg, 3.0, dropout=0.1)
    for seed in range(10):
        _, t = frame_clock(conf, 120.0, 100 + seed)
        (row,) = clock_levels(t, conf, seed=11, n=50)
        assert _verdict(row) == "agreed already" and row["null_family"] == pytest.approx(1.0), row
    _, t = frame_clock(_with_jitter(cfg, 5.0, dropout=0.1), 120.0, 7)
    (row,) = clock_levels(t, conf, seed=11, n=50)
    assert _verdict(row) == "still apart" and row["recording_ms"] == pytest.approx(5.0, rel=0.05), row
    assert row["simulation_ms"] == pytest.approx(3.0, rel=0.05), row
