"""ToF sensor: NAR (Table 3.1), eq. 3.5-3.8 on static scenes, Table 6.1 noise, motion artefacts."""

import importlib.util
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from jaxdefl.simulate import TABLE_6_1_MM, config_from_dict, non_ambiguity_range_m, pixel_model, render_frames
from jaxdefl.simulate.artefacts import harmonic_fit, motion_artefact_study
from jaxdefl.simulate.centroids import plate_pixel_masks
from jaxdefl.simulate.tof import tof_model

ROOT = Path(__file__).parents[1]


def test_non_ambiguity_range_table_3_1():
    assert [round(non_ambiguity_range_m(f), 3) for f in (29, 30, 31)] == [5.169, 4.997, 4.835]
    assert non_ambiguity_range_m(30) == 299792458 / 60e6


def _raw_static():
    return {
        "recording": {"duration_s": 1.0},
        "loading": {"amplitude_mm": 0.0, "longitudinal_mm": 0.0, "lateral_mm": 0.0},
    }


def _static(**camera):
    return config_from_dict({**_raw_static(), "camera": {"dropout_prob": 0.0, **camera}})


def test_noise_free_range_is_the_geometry():
    cfg = _static(noise_scale=0.0, scattering=0.0, plates=[7])
    t, frames, amp, facts = render_frames(cfg)
    pm = pixel_model(cfg, supersample=1)
    idx = plate_pixel_masks(cfg, pm)[7]
    got = frames.reshape(len(t), -1)[:, idx]
    np.testing.assert_allclose(got, np.broadcast_to(pm.plate_range_mm[idx], got.shape), atol=2e-3)
    assert facts["fx"] > 0 and facts["nar_mm"] == pytest.approx(5168.835, abs=1e-3)
    assert np.all(amp > 0)


def test_range_wraps_at_the_non_ambiguity_range():
    # 60 MHz: NAR 2.498 m, shorter than the floor's range -> wrapped to [0, NAR)
    cfg = _static(noise_scale=0.0, modulation_mhz=60.0, fov_deg=[69.0, 56.0])
    t, frames, _, _ = render_frames(cfg)
    nar = non_ambiguity_range_m(60.0) * 1000
    assert frames.min() >= 0 and frames.max() < nar
    assert (frames < 1000).mean() > 0.05  # the floor at ~2.7-3.3 m comes back short


def _surface_scatter(frames, top):
    """Per-pixel STD of the top surface about its own plane, fitted frame by frame (Table 6.1's
    STD: the frame-correlated range error moves and tilts the whole surface and is not in it)."""
    n, h, w = frames.shape
    z = frames.reshape(n, -1)[:, top].astype(np.float64)
    v, u = np.divmod(top, w)
    design = np.stack([np.ones(top.size), u, v], axis=1)
    coef, *_ = np.linalg.lstsq(design, z.T, rcond=None)
    z = z - (design @ coef).T
    return float(np.median(z.std(axis=0, ddof=1)))


@pytest.mark.parametrize("fm", [29.0, 31.0])
def test_noise_matches_table_6_1(fm):
    for fs, expected in TABLE_6_1_MM[fm].items():
        # Table 6.1 was measured with Cam 3 (69 x 56 deg), whose centroid residuals calibrate it
        cfg = _static(frame_rate_hz=fs, modulation_mhz=fm, fov_deg=[69.0, 56.0], name="cam3")
        t, frames, _, _ = render_frames(cfg, duration_s=max(2.0, 40 / fs))
        top = tof_model(cfg, pixel_model(cfg)).top_pixels
        assert top.size > 200
        sd = _surface_scatter(frames, top)
        assert abs(sd / expected - 1) < 0.15, (fm, fs, sd, expected)


def test_noise_grows_with_frame_rate_and_falls_with_modulation():
    sds = {}
    for fs, fm in ((10.0, 29.0), (40.0, 29.0), (40.0, 31.0)):
        cfg = _static(frame_rate_hz=fs, modulation_mhz=fm)
        t, frames, _, _ = render_frames(cfg, duration_s=2.0)
        top = tof_model(cfg, pixel_model(cfg)).top_pixels
        sds[fs, fm] = _surface_scatter(frames, top)
    assert sds[10.0, 29.0] < sds[40.0, 31.0] < sds[40.0, 29.0]


def test_frame_common_range_error_moves_the_whole_surface():
    # the correlated part: the top surface's per-frame mean scatters by about the calibrated
    # sigma (its common part; the smooth part averages down over the surface)
    cfg = _static(frame_rate_hz=40.0, modulation_mhz=29.0, fov_deg=[69.0, 56.0], name="cam3")
    tm = tof_model(cfg, pixel_model(cfg))
    t, frames, _, _ = render_frames(cfg, duration_s=5.0)
    level = frames.reshape(len(t), -1)[:, tm.top_pixels].astype(np.float64).mean(axis=1)
    common = tm.sigma_corr_mm * math.sqrt(1 - tm.corr_spatial)
    assert tm.sigma_corr_mm > 10.0  # Table 6.2: 13.08 mm at 40 Hz for Cam 3
    assert np.std(level, ddof=1) == pytest.approx(common, rel=0.25)
    off = config_from_dict({**_raw_static(), "camera": {"dropout_prob": 0.0, "centroid_residual_mm": 0.0}})
    assert tof_model(off, pixel_model(off)).sigma_corr_mm == 0.0


def test_motion_artefacts_match_fig_6_9():
    table = motion_artefact_study(motion_hz=(1.0, 3.0), frame_rates_hz=(10.0, 20.0))
    err = {(r.motion_hz, r.frame_rate_hz): r.amplitude_error_mm for r in table.itertuples()}
    assert err[1.0, 10.0] == pytest.approx(-0.061, abs=0.012)
    assert err[3.0, 10.0] == pytest.approx(-0.53, abs=0.012)
    assert err[3.0, 20.0] == pytest.approx(-0.14, abs=0.012)
    lag = table[(table.motion_hz == 1.0) & (table.frame_rate_hz == 10.0)].phase_lag_deg.iloc[0]
    assert lag == pytest.approx(-13.2, abs=2.0)


def test_no_artefact_when_all_samples_are_taken_at_once():
    from jaxdefl.simulate.artefacts import motion_artefact_ranges

    t, true, _ = motion_artefact_ranges(3.0, 10.0, 4.0)
    a, _, _ = harmonic_fit(t, true, 3.0)
    assert a == pytest.approx(4.0, abs=0.01)  # 4 mm / cos(ray angle) ~ 4.002


def test_motion_artefacts_experiment_script(tmp_path):
    spec = importlib.util.spec_from_file_location(
        "motion_artefacts", ROOT / "experiments" / "motion_artefacts.py"
    )
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    out = tmp_path / "ma.csv"
    assert mod.main(["--out", str(out), "--duration", "3"]) == 0
    df = pd.read_csv(out)
    assert list(df.columns[:4]) == ["motion_hz", "frame_rate_hz", "amplitude_error_mm", "phase_lag_deg"]
    assert len(df) == 8 and out.with_suffix(".png").stat().st_size > 10_000
    # the error falls with the frame rate, faster motion hurts more
    for _, g in df.groupby("motion_hz"):
        assert np.all(np.diff(np.abs(g.amplitude_error_mm)) < 0)
    assert math.isclose(df.amplitude_error_mm.min(), -0.533, abs_tol=0.012)


def test_plates_lie_below_the_beam_top_and_above_the_floor():
    # thesis 4.1 / 5.1.1: plates bonded at the bottom of the beam's side, kept by the depth
    # classification between the beam top (second threshold) and the floor (first)
    cfg = _static()
    pm = pixel_model(cfg, supersample=1)
    tm = tof_model(cfg, pm)
    top_depth = np.median(pm.sub_depth_mm[tm.top_pixels, 0])
    plate_depth = pm.plate_depth_mm[0]
    assert top_depth == pytest.approx(cfg.camera.standoff_mm, abs=1.0)
    assert plate_depth == pytest.approx(top_depth + cfg.plates.depth_below_top_mm, abs=1.0)
    assert top_depth < plate_depth < cfg.camera.standoff_mm + cfg.scene.floor_below_top_mm


def test_centroids_follow_the_plates_in_plane_motion():
    # interior pixels cannot see a plate sliding in its own plane; the edge pixels' coverage can
    from jaxdefl.simulate import measured_centroids, simulate_trajectories

    raw = {
        "recording": {"cycles_at_start": 1.0},
        "fatigue": {"law": "none"},
        "loading": {"frequency_hz": 3.0, "amplitude_mm": 2.3, "longitudinal_mm": 0.5, "lateral_mm": 0.05},
        "camera": {"noise_scale": 0.0, "dropout_prob": 0.0, "tap_offsets": [0.0, 0.0, 0.0, 0.0]},
    }
    cfg = config_from_dict(raw)
    t, frames, amp, _ = render_frames(cfg, duration_s=2.0)
    truth, _ = simulate_trajectories(cfg, duration_s=2.0)
    fixed = measured_centroids(cfg, t, frames)
    follow = measured_centroids(cfg, t, frames, amplitude=amp)
    for plate in (5, 7, 9):
        tr = truth[truth.plate == plate]
        g, g0 = follow[follow.plate == plate], fixed[fixed.plate == plate]
        ax_, phx, _ = harmonic_fit(g.t.to_numpy(), g.x.to_numpy(), 3.0)
        ay, phy, _ = harmonic_fit(g.t.to_numpy(), g.y.to_numpy(), 3.0)
        _, pht, _ = harmonic_fit(tr.t.to_numpy(), tr.z.to_numpy(), 3.0)
        assert ax_ == pytest.approx(0.5, rel=0.3) and math.cos(phx - pht) > 0.99, (plate, ax_)
        assert ay == pytest.approx(0.05, abs=0.045) and math.cos(phy - pht) > 0.9, (plate, ay)
    # the fixed interior pixels: no longitudinal motion at mid-image (plate 7), and a spurious
    # perspective term in y (the rays meet the plate farther out as it moves down: ~0.3 mm)
    g0 = fixed[fixed.plate == 7]
    assert harmonic_fit(g0.t.to_numpy(), g0.x.to_numpy(), 3.0)[0] < 0.02
    assert harmonic_fit(g0.t.to_numpy(), g0.y.to_numpy(), 3.0)[0] > 0.2
