"""Simulate-then-extract: plates found, centroid noise, and the fitted deflection (both sensors).

The noise the simulator put into a centroid is measured with the simulator's own reference
extraction (`jaxdefl.simulate.centroids.plate_pixel_masks`: the pixels inside each plate at
rest, eroded by one pixel), on the same frames; the extracted centroids must match its
bias-removed RMS about the truth within 20 %.

"Visible" plates: in the camera's configured list (fully inside the field of view) and with at
least half of a full plate's reference pixels unoccluded (the Kinect sees only a sliver of plate
7 under the actuator; the thesis dropped that plate too, section 5.2.1).
"""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from jaxdefl.frames import extract_recording
from jaxdefl.io.recording import open_recording
from jaxdefl.simulate import simulate_to_dir
from jaxdefl.simulate.centroids import plate_pixel_masks
from jaxdefl.simulate.config import config_from_dict
from jaxdefl.simulate.scene import beam_shape, intrinsics, midspan_amplitude_mm

# with `pytest --dist loadgroup` one worker runs the module: its fixture simulates a 120-s
# Kinect recording, which each worker would otherwise simulate again
pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("extract_sim")]

CASES = {"tof": ("configs/exp2_tof_3hz.toml", 120.0), "kinect": ("configs/exp2_kinect_3hz.toml", 120.0)}


def _reference(cfg, rec) -> pd.DataFrame:
    k = intrinsics(cfg)
    masks = plate_pixel_masks(cfg)
    ray = {}  # a range pixel's z is its range over its ray's length
    for p, idx in masks.items():
        v, u = np.divmod(idx, k.width)
        xr, yr = (u - k.cx) / k.fx, (v - k.cy) / k.fy
        ray[p] = np.sqrt(xr * xr + yr * yr + 1) if rec.kind == "range" else 1.0
    rows = []
    for ch in rec.chunks(256):
        flat = ch.frames.reshape(len(ch.t), -1)  # only the plates' pixels are made float64
        for p, idx in masks.items():
            z = flat[:, idx].astype(np.float64) / ray[p]
            rows.append(pd.DataFrame({"t": ch.t, "plate": p, "z": np.nanmean(z, 1)}))
    return pd.concat(rows, ignore_index=True), {p: len(i) for p, i in masks.items()}


@pytest.fixture(scope="module", params=list(CASES))
def simulated(request, tmp_path_factory):
    path, duration = CASES[request.param]
    out = tmp_path_factory.mktemp(request.param)
    simulate_to_dir(path, out, duration_s=duration, progress=False)
    raw = json.loads((out / "config.json").read_text())
    raw["recording"]["session"] = ""
    cfg = config_from_dict(raw)
    rec = open_recording(out / "recording.zarr")
    truth = pd.read_csv(out / "truth.csv")
    ref, npix = _reference(cfg, rec)
    full = max(npix.values())
    visible = [p for p in cfg.camera.plates if npix.get(p, 0) >= 0.5 * full]
    return request.param, cfg, rec, truth, ref, visible, {}


def _extracted(simulated, realtime: bool) -> pd.DataFrame:
    """The recording's extraction (kept with the fixture: the two tests share the real-time one)."""
    rec, done = simulated[2], simulated[-1]
    if realtime not in done:
        done[realtime] = extract_recording(rec, realtime=realtime, chunk_frames=128, progress=False)
    return done[realtime]


def _merge(a, b):
    a, b = a.copy(), b.copy()
    a["tk"] = (a.t * 1e4).round().astype(np.int64)
    b["tk"] = (b.t * 1e4).round().astype(np.int64)
    return a.merge(b.drop(columns=["t"]), on=["tk", "plate"], suffixes=("", "_b"))


@pytest.mark.parametrize("realtime", [False, True])
def test_plates_found_and_centroid_noise(simulated, realtime):
    name, cfg, rec, truth, ref, visible, _ = simulated
    df = _extracted(simulated, realtime)
    assert set(visible) <= set(df.plate.unique())
    # never a plate that is not there: only plates in view, each once per frame
    assert not df.duplicated(["t", "plate"]).any()
    for p in visible:
        got = df[df.plate == p]
        assert len(got) >= 0.995 * rec.n_frames, (name, p, len(got), rec.n_frames)
        m = _merge(got, truth)
        r = _merge(ref[ref.plate == p], truth)
        rms = (m.z - m.z_b).std()
        rms_ref = (r.z - r.z_b).std()
        assert abs(rms / rms_ref - 1) < 0.2, (name, p, rms, rms_ref)


def test_fitted_deflection(simulated):
    from jaxdefl.fit import estimate_table

    name, cfg, rec, truth, ref, visible, _ = simulated
    df = _extracted(simulated, True)
    est = estimate_table(df[df.plate.isin(visible)], axes=("z",)).table
    t_mid = 0.5 * (df.t.min() + df.t.max())
    cycles = cfg.recording.cycles_at_start + cfg.loading.frequency_hz * (t_mid - cfg.t0_s)
    a_mid = float(midspan_amplitude_mm(cfg, cycles))
    xs = np.asarray(cfg.plate_x_mm())
    # a ToF camera measures the amplitude times its motion-artefact gain (3.4 % low at 3 Hz and
    # 20 Hz); the plate-centroid residual is the thesis' 0.76 mm, so sigma_A is ~0.02 mm on 120 s
    gain = 1.0
    if name == "tof":
        from jaxdefl.fit.motion import motion_artefact_response

        gain = float(motion_artefact_response(cfg.loading.frequency_hz, cfg.camera.frame_rate_hz)[0])
    for _, row in est.iterrows():
        a_true = gain * a_mid * float(beam_shape(xs[row.plate - 1], cfg.beam.span_mm, cfg.beam.load_a_mm))
        tol = max(0.1, 4 * row.sigma_amplitude_mm)
        assert abs(row.amplitude_mm - a_true) < tol, (name, row.plate, row.amplitude_mm, a_true)
    f0_err = np.abs(est["f0_hz"] - cfg.loading.frequency_hz)
    # The simulated Kinect adds a frame-common depth jitter (camera.frame_noise_mm = 0.4 mm shared
    # by all plates): on 60 s sigma_f0 is ~7e-5 Hz and all plates missed 1e-4 Hz together (the
    # simulator's own reference centroids too). The Kinect case records 120 s, where sigma_f0 is
    # ~2.5e-5 Hz (sigma_f0 ~ T^-1.5): the 1e-4 Hz criterion of issue 4 is 4 sigma, a fair test.
    assert (f0_err < 1e-4).all(), (name, est[["plate", "f0_hz"]].to_dict("records"))
