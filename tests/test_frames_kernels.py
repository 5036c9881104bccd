import numpy as np
import pytest
import torch
from scipy import ndimage
from skimage.filters import threshold_otsu
from skimage.measure import EllipseModel, regionprops

from jaxdefl.frames import (
    erode,
    fit_ellipse,
    label_components,
    opening,
    otsu_threshold,
    region_stats,
)


def _scene(seed, b=4, h=60, w=80):
    rng = np.random.default_rng(seed)
    img = rng.normal(10, 2, (b, h, w))
    for i in range(b):
        for _ in range(6):
            r0, c0 = rng.integers(0, h - 10), rng.integers(0, w - 20)
            img[i, r0 : r0 + rng.integers(3, 10), c0 : c0 + rng.integers(3, 20)] += rng.uniform(20, 40)
    return img


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_otsu_matches_skimage(seed):
    img = _scene(seed)
    thr = otsu_threshold(torch.from_numpy(img)[:, None])
    for i in range(img.shape[0]):
        assert thr[i].item() == pytest.approx(threshold_otsu(img[i]), rel=1e-9)


def test_otsu_respects_valid_mask():
    img = _scene(3)
    valid = np.zeros_like(img, bool)
    valid[:, 10:50, 10:70] = True
    thr = otsu_threshold(torch.from_numpy(img)[:, None], torch.from_numpy(valid)[:, None])
    for i in range(img.shape[0]):
        assert thr[i].item() == pytest.approx(threshold_otsu(img[i][valid[i]]), rel=1e-9)


def test_otsu_of_band_masked_float32_amplitude_matches_skimage():
    """As the pipeline calls it: float32 amplitude, the pixels outside the band set to zero."""
    img = (_scene(4) * 37.0).astype(np.float32)
    band = np.random.default_rng(4).random(img.shape) < 0.3
    band[1] = True  # a frame without zeros
    masked = np.where(band, img, np.float32(0))
    thr = otsu_threshold(torch.from_numpy(masked)[:, None])
    for i in range(img.shape[0]):
        assert thr[i].item() == pytest.approx(threshold_otsu(masked[i]), rel=1e-6)
        # the same foreground
        assert np.array_equal(masked[i] > np.float32(thr[i].item()), masked[i] > threshold_otsu(masked[i]))


@pytest.mark.parametrize("p", [0.0, 0.3, 0.6, 0.75, 0.9, 1.0])
def test_labels_equal_scipy_on_the_stacked_frames(p):
    rng = np.random.default_rng(5)
    mask = rng.random((3, 40, 50)) < p
    mask[1, 10:30, 5:45] = True  # a large component
    labels, n = label_components(torch.from_numpy(mask)[:, None])
    # scipy on the frames stacked into one tall image, an empty row under each
    tall = np.concatenate([np.pad(f, ((0, 1), (0, 0))) for f in mask])
    ref, n_ref = ndimage.label(tall, structure=np.ones((3, 3)))
    assert n == n_ref
    np.testing.assert_array_equal(labels[:, 0].numpy(), ref.reshape(3, 41, 50)[:, :40])


def test_labels_of_spirals_and_diagonals():
    """Long winding components (many union-find rounds) and corner-only contacts."""
    m = np.zeros((1, 41, 41), bool)
    m[0, 0, :] = m[0, :, 40] = m[0, 40, :] = m[0, 4:, 0] = True  # a spiral's outer turns
    m[0, 4, :36] = m[0, 4:36, 36] = m[0, 36, 4:37] = m[0, 8:37, 4] = m[0, 8, 4:32] = True
    for k in range(12, 30):
        m[0, k, 12 + (k % 2)] = True  # a zigzag joined only at corners
    labels, n = label_components(torch.from_numpy(m)[:, None])
    ref, n_ref = ndimage.label(m[0], structure=np.ones((3, 3)))
    assert n == n_ref
    np.testing.assert_array_equal(labels[0, 0].numpy(), ref)


def test_region_stats_match_regionprops():
    img = _scene(7)
    mask = img > 25
    mask[2, 20:24, 0:3] = True  # a region on the frame's border
    labels, n = label_components(torch.from_numpy(mask)[:, None])
    st = region_stats(labels, n, row0=5, height=70)
    seen = 0
    for i in range(img.shape[0]):
        lab = labels[i, 0].numpy()
        for rp in regionprops(lab):
            j = rp.label - 1
            seen += 1
            assert st["frame"][j].item() == i
            assert st["area"][j].item() == rp.area
            assert st["v"][j].item() == pytest.approx(rp.centroid[0] + 5)
            assert st["u"][j].item() == pytest.approx(rp.centroid[1])
            assert st["major"][j].item() == pytest.approx(rp.axis_major_length, rel=1e-9, abs=1e-9)
            assert st["minor"][j].item() == pytest.approx(rp.axis_minor_length, rel=1e-9, abs=1e-7)
            r0, c0, r1, c1 = rp.bbox
            on_border = c0 == 0 or c1 == lab.shape[1] or r1 + 5 == 70
            assert st["border"][j].item() == on_border
    assert seen == n and st["border"].any()


def test_fake_eccentricity_separates_discs_from_strips():
    yy, xx = np.mgrid[:60, :80]
    disc = (xx - 20) ** 2 + (yy - 30) ** 2 <= 8**2
    strip = (np.abs(xx - 60) <= 13) & (np.abs(yy - 30) <= 3)
    labels, k = label_components(torch.from_numpy(disc | strip)[None, None])
    ecc = region_stats(labels, k)["eccentricity"].numpy()
    assert sorted(ecc.round(2).tolist()) == pytest.approx([0.25, 1.0], abs=0.03)


@pytest.mark.parametrize(
    "params", [(40.0, 30.0, 12.0, 7.0, 0.4), (10.0, -5.0, 30.0, 29.0, -1.2), (0, 0, 5, 2, 0.0)]
)
def test_ellipse_fit_recovers_truth_and_matches_skimage(params):
    xc, yc, a, b, th = params
    s = np.linspace(0, 2 * np.pi, 80, endpoint=False)
    rng = np.random.default_rng(0)
    x = xc + a * np.cos(s) * np.cos(th) - b * np.sin(s) * np.sin(th) + 0.01 * rng.standard_normal(s.size)
    y = yc + a * np.cos(s) * np.sin(th) + b * np.sin(s) * np.cos(th) + 0.01 * rng.standard_normal(s.size)
    e = fit_ellipse(x, y)
    assert e.xc == pytest.approx(xc, abs=0.02) and e.yc == pytest.approx(yc, abs=0.02)
    assert e.a == pytest.approx(a, abs=0.03) and e.b == pytest.approx(b, abs=0.03)
    m = EllipseModel.from_estimate(np.stack([x, y], 1))
    assert e.xc == pytest.approx(m.center[0], abs=0.02) and e.yc == pytest.approx(m.center[1], abs=0.02)
    assert sorted([e.a, e.b]) == pytest.approx(sorted(m.axis_lengths), abs=0.03)
    if a - b > 1:
        d = (e.theta - th + np.pi / 2) % np.pi - np.pi / 2
        assert abs(d) < 0.01


def test_ellipse_fit_refuses_degenerate_points():
    assert fit_ellipse(np.arange(5.0), np.arange(5.0)) is None
    assert fit_ellipse(np.arange(20.0), 2 * np.arange(20.0)) is None


@pytest.mark.parametrize("size", [3, 5])
def test_erosion_and_opening_match_scipy(size):
    rng = np.random.default_rng(size)
    mask = rng.random((2, 30, 40)) > 0.2
    se = np.ones((size, size))
    er = erode(torch.from_numpy(mask)[:, None], size)[:, 0].numpy()
    op = opening(torch.from_numpy(mask)[:, None], size)[:, 0].numpy()
    for i in range(2):
        np.testing.assert_array_equal(er[i], ndimage.binary_erosion(mask[i], structure=se, border_value=0))
        np.testing.assert_array_equal(op[i], ndimage.binary_opening(mask[i], structure=se))
    assert er.any() and op.any()


def test_shape_errors():
    with pytest.raises(ValueError, match=r"x: expected a tensor of shape \(B, 1, H, W\), got \(3, 4\)"):
        otsu_threshold(torch.zeros(3, 4))
