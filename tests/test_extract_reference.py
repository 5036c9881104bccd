"""Batched extraction against a slow, independent per-frame reference on simulated recordings.

The reference runs every frame on its own with scipy.ndimage (labelling, erosion),
skimage (Otsu) and numpy moments in float64, following the thesis' steps (5.1-5.2) with the
`Scene` that `calibrate_scene` found: depth band relative to the frame's beam-top level, Otsu
on the band-masked amplitude (ToF), 5x5 mean and smoothness constraint (structured light),
8-connected regions, size / fake-eccentricity / line checks, 3x3 erosion, 3-sigma clip
(structured light) and the mean of the eroded pixels' 3D points. The batched extraction must
find the same plates in the same frames and give centroids equal within 0.01 mm; the tracked
mode's centroids must equal the plain per-plate means over the tracked pixels; and the
calibration's plate templates must be the reference's regions on the calibration frame.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.ndimage as ndi
from skimage.filters import threshold_otsu

from jaxdefl.frames import PlateGeometry, Tracker, calibrate_scene, detect_chunk
from jaxdefl.simulate import render_frames

EIGHT = np.ones((3, 3), bool)
TOL_MM = 0.01
CASES = {
    "tof_exp2": ("configs/exp2_tof_3hz.toml", 4.0, 3),
    "tof_exp1": ("configs/exp1.toml", 4.0, 5),
    "kinect_exp2": ("configs/exp2_kinect_3hz.toml", 1.5, 4),
}


@pytest.fixture(scope="module", params=list(CASES))
def recording(request):
    path, duration, seed = CASES[request.param]
    t, frames, amp, facts = render_frames(path, duration_s=duration, seed=seed)
    kind = facts["frame_kind"]
    intr = {k: facts[k] for k in ("fx", "fy", "cx", "cy")}
    geo = PlateGeometry(np.asarray(facts["plate_x_mm"]), facts["camera_x_mm"])
    frames = frames.astype(np.float32)
    amp = amp.astype(np.float32)
    scene = calibrate_scene(frames, amp, intr, kind, geo)
    return request.param, frames, amp, scene


def _lower_median(x):
    x = np.sort(x[np.isfinite(x)])
    return x[(x.size - 1) // 2] if x.size else np.nan


def _box_mean(z, k):
    """k x k mean over the pixels inside the frame (a NaN spoils its windows only)."""
    r = k // 2
    pad = np.pad(z, r, constant_values=0.0)
    ones = np.pad(np.ones_like(z), r, constant_values=0.0)
    win = np.lib.stride_tricks.sliding_window_view
    return win(pad, (k, k)).sum(axis=(2, 3)) / win(ones, (k, k)).sum(axis=(2, 3))


def _reference_regions(scene, z_full, amp_full, top, rows, band):
    """Regions of one frame: list of dicts (area, u, v, ecc, border, x, y, z, n_eroded, pixels)."""
    r0, r1 = rows
    H, W = scene.height, scene.width
    z = z_full[r0:r1]
    zs = _box_mean(z, scene.smooth) if scene.smooth > 1 else z
    with np.errstate(invalid="ignore"):
        rel = zs - top
        fg = (rel > band[0]) & (rel < band[1])
        if scene.smooth > 1:
            lim = 12.0  # 2 x 6 mm/px, the steepest depth change across a plate
            steep = np.zeros_like(fg)
            steep[1:-1] |= ~(np.abs(zs[2:] - zs[:-2]) < lim)
            steep[:, 1:-1] |= ~(np.abs(zs[:, 2:] - zs[:, :-2]) < lim)
            fg &= ~steep
    if scene.use_amplitude and amp_full is not None:
        masked = np.where(fg, amp_full[r0:r1], 0.0).astype(np.float32)
        if masked.max() > masked.min():
            fg &= masked > threshold_otsu(masked)
    lab, n = ndi.label(fg, structure=EIGHT)
    eroded = ndi.binary_erosion(fg, structure=EIGHT, border_value=0)
    vv, uu = np.mgrid[r0:r1, 0:W].astype(np.float64)
    regions = []
    for k in range(1, n + 1):
        m = lab == k
        u, v = uu[m], vv[m]
        cov = np.cov(np.stack([u, v]), bias=True) if u.size > 1 else np.zeros((2, 2))
        ev = np.linalg.eigvalsh(cov)
        ecc = np.sqrt(max(ev[0], 0.0) / ev[1]) if ev[1] > 0 else 0.0
        e = m & eroded & np.isfinite(z)
        ze = z[e].astype(np.float64)
        pix = ((vv[e].astype(np.int64)) * W + uu[e].astype(np.int64)).ravel()
        if scene.kind == "depth" and ze.size:
            keep = np.abs(ze - ze.mean()) <= 3.0 * ze.std() + 1e-6
            ze, pix = ze[keep], pix[keep]
        xr, yr = scene.xr.ravel()[pix], scene.yr.ravel()[pix]
        regions.append(
            dict(
                area=u.size,
                u=u.mean(),
                v=v.mean(),
                ecc=ecc,
                minor=4 * np.sqrt(max(ev[0], 0.0)),
                border=bool((u == 0).any() or (u == W - 1).any() or (v == 0).any() or (v == H - 1).any()),
                x=(ze * xr).mean() if ze.size else np.nan,
                y=(ze * yr).mean() if ze.size else np.nan,
                z=ze.mean() if ze.size else np.nan,
                n_eroded=ze.size,
                pixels=np.sort(pix),
            )
        )
    return regions


def _zframe(scene, frame):
    f = frame.astype(np.float64)
    return f * scene.inv_norm if scene.kind == "range" else f


def _reference_detect(scene, frames, amp):
    """(frame, plate, 3) centroids, one frame at a time."""
    n_pl = scene.plates.size
    out = np.full((frames.shape[0], n_pl, 3), np.nan)
    for i in range(frames.shape[0]):
        z = _zframe(scene, frames[i])
        top = _lower_median(z.ravel()[scene.top_idx])
        regs = _reference_regions(scene, z, None if amp is None else amp[i], top, scene.rows, scene.band)
        claims = {}
        for r in regs:
            if r["n_eroded"] < 3 or r["border"]:
                continue
            num = int(scene.number(np.array([r["x"]]), np.array([r["u"]]))[0])
            if num not in scene.plates:
                continue
            j = int(np.flatnonzero(scene.plates == num)[0])
            ratio = r["area"] / scene.area[j]
            on_line = abs(r["v"] - (scene.line[0] + scene.line[1] * r["u"])) <= 2 * scene.line_tol_px
            if 0.6 < ratio < 1.6 and abs(r["ecc"] - scene.ecc[j]) < 0.2 and on_line:
                claims.setdefault(j, []).append(r)
        for j, rs in claims.items():
            if len(rs) == 1:
                out[i, j] = rs[0]["x"], rs[0]["y"], rs[0]["z"]
    return out


def test_full_detection_equals_reference(recording):
    name, frames, amp, scene = recording
    assert scene.plates.size >= 3, name
    got = np.concatenate(
        [
            detect_chunk(scene, frames[s : s + 32], None if amp is None else amp[s : s + 32])
            for s in range(0, len(frames), 32)
        ]
    )
    ref = _reference_detect(scene, frames, amp)
    found = np.isfinite(ref[..., 2])
    assert found.mean() > 0.95, (name, found.mean())
    np.testing.assert_array_equal(np.isfinite(got[..., 2]), found, err_msg=name)
    assert np.nanmax(np.abs(got - ref)) < TOL_MM, (name, np.nanmax(np.abs(got - ref)))


def test_calibration_templates_are_reference_regions(recording):
    """The plates' templates and tracked pixels: the reference's regions on the calibration frame."""
    name, frames, amp, scene = recording
    z = np.stack([_zframe(scene, f) for f in frames[:15]])
    with np.errstate(all="ignore"):
        zmed = np.nanmedian(z, axis=0)
    amed = None if amp is None else np.median(amp[:15], axis=0)
    regs = _reference_regions(scene, zmed, amed, scene.top_z_mm, (0, scene.height), scene.band)
    for j in range(scene.plates.size):
        r = min(regs, key=lambda r: np.hypot(r["u"] - scene.u[j], r["v"] - scene.v[j]))
        assert r["area"] == scene.area[j], (name, j)
        assert r["u"] == pytest.approx(scene.u[j], abs=1e-9) and r["v"] == pytest.approx(scene.v[j], abs=1e-9)
        assert r["ecc"] == pytest.approx(scene.ecc[j], abs=1e-9)
        np.testing.assert_array_equal(np.sort(np.asarray(scene.track[j])), r["pixels"], err_msg=name)


def test_tracked_centroids_equal_per_plate_means(recording):
    name, frames, amp, scene = recording
    got, lost = Tracker(scene).centroids(frames)
    lo, hi = scene.band
    for i in range(frames.shape[0]):
        z = _zframe(scene, frames[i]).ravel()
        top = _lower_median(z[scene.top_idx])
        for j, pix in enumerate(scene.track):
            ze = z[pix]
            ok = np.isfinite(ze)
            ze, p = ze[ok], np.asarray(pix)[ok]
            if scene.kind == "depth" and ze.size:
                keep = np.abs(ze - ze.mean()) <= 3.0 * ze.std() + 1e-6
                ze, p = ze[keep], p[keep]
            want_lost = ze.size < 0.8 * len(pix) or not (lo < ze.mean() - top < hi)
            assert lost[i, j] == want_lost, (name, i, j)
            if not want_lost:
                want = [(ze * scene.xr.ravel()[p]).mean(), (ze * scene.yr.ravel()[p]).mean(), ze.mean()]
                np.testing.assert_allclose(got[i, j], want, atol=TOL_MM, rtol=0, err_msg=name)
