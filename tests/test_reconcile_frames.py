"""The frames level of `jaxdefl reconcile` (`jaxdefl.reconcile.frames`): per-pixel short-term
range noise and valid share by amplitude decile, against a slow per-pixel reference and the
frame simulator."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from jaxdefl.reconcile.frames import distance, frame_levels, frame_stats


def _clip(seed=0, n=120, h=30, w=40, scale=1.0, lattice=0.0, nan_low=0.0):
    """Frames whose pixel noise is 300 / amplitude mm (the ToF law), a third of them moving
    with a 3-Hz harmonic of 4 mm and a slow drift; optionally rounded, optionally invalid."""
    rng = np.random.default_rng(seed)
    t = 1.7e9 + np.arange(n) / 20.0
    amp = np.broadcast_to(np.linspace(30, 600, w)[None, :], (h, w)).copy()
    sigma = scale * 300.0 / amp
    tt = (t - t[0])[:, None, None]
    moving = np.zeros((h, w), bool)
    moving[: h // 3] = True
    motion = np.where(moving, 4.0 * np.cos(2 * math.pi * 3.0 * tt + 0.3), 0.0)
    fr = 2000.0 + motion + 0.05 * tt + sigma * rng.standard_normal((n, h, w))
    if lattice:
        fr = lattice * np.round(fr / lattice)
    if nan_low:
        low = amp < 100
        fr[:, low] = np.where(rng.random((n, int(low.sum()))) < nan_low, np.nan, fr[:, low])
    amps = np.broadcast_to(amp, (n, h, w)) * (1 + 0.01 * rng.standard_normal((n, h, w)))
    return t, fr.astype(np.float32), amps.astype(np.float32), sigma


def _slow_reference(t, fr, f0):
    """Per pixel, one at a time: least squares on [1, t, cos, sin], then the normal-scaled MAD
    of the first differences / √2 (scipy)."""
    n, h, w = fr.shape
    tt = t - t[0]
    a = np.stack([np.ones(n), tt, np.cos(2 * math.pi * f0 * tt), np.sin(2 * math.pi * f0 * tt)], 1)
    out = np.full(h * w, np.nan)
    for p in range(h * w):
        y = fr.reshape(n, -1)[:, p].astype(float)
        if not np.all(np.isfinite(y)):
            continue
        res = y - a @ np.linalg.lstsq(a, y, rcond=None)[0]
        out[p] = stats.median_abs_deviation(np.diff(res), scale="normal") / math.sqrt(2)
    return out


def test_range_noise_per_bin_matches_a_slow_per_pixel_reference_and_the_truth():
    t, fr, amp, sigma = _clip()
    st = frame_stats(t, fr, amp, 3.0)
    ref = _slow_reference(t, fr, 3.0)
    key = np.median(amp.reshape(len(t), -1), axis=0)
    for k in range(len(st.edges) - 1):
        sel = (key >= st.edges[k]) & (key < st.edges[k + 1])
        assert st.pixels[k] == sel.sum() >= 20
        assert st.range_noise[k] == pytest.approx(np.median(ref[sel]), rel=1e-4)
        # the moving third of the pixels keeps only its noise: the truth within 10 %
        assert st.range_noise[k] == pytest.approx(np.median(sigma.reshape(-1)[sel]), rel=0.1)
    assert np.all(st.valid_share == 1.0)


def test_a_noisier_camera_is_far_and_the_same_camera_is_near():
    t, fr, amp, _ = _clip(seed=1)
    base = frame_stats(t, fr, amp, 3.0)
    same = frame_stats(*_clip(seed=2)[:3], 3.0, base.edges)
    noisy = frame_stats(*_clip(seed=3, scale=1.5)[:3], 3.0, base.edges)
    assert distance(same, base, "range_noise") < 0.08
    assert distance(noisy, base, "range_noise") == pytest.approx(math.log(1.5), rel=0.2)


def test_values_on_a_lattice_and_invalid_pixels():
    # ranges rounded to 1 mm with noise well below a step: most first differences are 0, the
    # MAD would say 0; the plain deviation is the (rounded) noise
    t, fr, amp, _ = _clip(seed=4, scale=0.3, lattice=1.0)
    st = frame_stats(t, fr, amp, 3.0)
    assert np.all(st.range_noise[np.isfinite(st.range_noise)] > 0)
    # a 30 % invalid share on the low-amplitude pixels is seen in their deciles only
    t, fr, amp, _ = _clip(seed=5, nan_low=0.3)
    st = frame_stats(t, fr, amp, 3.0)
    assert st.valid_share[0] == pytest.approx(0.7, abs=0.03)
    assert st.valid_share[-1] == 1.0


@pytest.mark.slow
def test_frame_levels_find_a_noisier_camera_than_configured():
    from jaxdefl.io.recording import Recording
    from jaxdefl.simulate import load_config, render_frames

    root = Path(__file__).resolve().parents[1]
    cfg = load_config(root / "configs" / "exp2_tof_3hz.toml")
    f0 = cfg.loading.frequency_hz

    def recording(c, seed):
        t, fr, amp, facts = render_frames(c, 3.0, seed)
        return Recording(
            path=Path("<clip>"),
            kind=facts["frame_kind"],
            n_frames=len(t),
            height=fr.shape[1],
            width=fr.shape[2],
            intrinsics={k: float(facts[k]) for k in ("fx", "fy", "cx", "cy")},
            segment=str(facts["segment"]),
            attrs=facts,
            _read=lambda s, e: (t[s:e], fr[s:e], amp[s:e]),
        )

    noisy = dataclasses.replace(cfg, camera=dataclasses.replace(cfg.camera, noise_scale=1.6))
    rows = {r["metric"]: r for r in frame_levels(recording(noisy, 7), cfg, f0, seed=11, n_null=3)}
    r = rows["range_noise"]
    assert r["before"] > 3 * r["null_95"] and r["before"] == pytest.approx(math.log(1.6), rel=0.3), r
    rows = {r["metric"]: r for r in frame_levels(recording(cfg, 7), cfg, f0, seed=11, n_null=3)}
    assert rows["range_noise"]["before"] <= 2 * rows["range_noise"]["null_95"], rows
