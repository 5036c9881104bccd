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
    otsu_threshold,
    points_from_depth,
    points_from_range,
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


def test_labels_match_scipy_partition():
    rng = np.random.default_rng(5)
    mask = rng.random((3, 40, 50)) > 0.6
    labels, k = label_components(torch.from_numpy(mask)[:, None])
    labels = labels[:, 0].numpy()
    for i in range(3):
        ref, n = ndimage.label(mask[i], structure=np.ones((3, 3)))
        assert labels[i].max() == n
        # same partition: a bijection between our labels and scipy's
        pairs = set(zip(labels[i][mask[i]].tolist(), ref[mask[i]].tolist(), strict=True))
        assert len(pairs) == n
    assert k == max(ndimage.label(m, structure=np.ones((3, 3)))[1] for m in mask)


def test_region_stats_match_regionprops():
    img = _scene(7)
    mask = img > 25
    labels, k = label_components(torch.from_numpy(mask)[:, None])
    st = region_stats(labels, k, values=torch.from_numpy(img)[:, None])
    for i in range(img.shape[0]):
        lab = labels[i, 0].numpy()
        for rp in regionprops(lab, intensity_image=img[i]):
            j = rp.label - 1
            assert st["area"][i, j].item() == rp.area
            assert st["v"][i, j].item() == pytest.approx(rp.centroid[0])
            assert st["u"][i, j].item() == pytest.approx(rp.centroid[1])
            assert st["major"][i, j].item() == pytest.approx(rp.axis_major_length, rel=1e-9, abs=1e-9)
            assert st["minor"][i, j].item() == pytest.approx(rp.axis_minor_length, rel=1e-9, abs=1e-7)
            assert st["mean"][i, j, 0].item() == pytest.approx(rp.intensity_mean)


def test_fake_eccentricity_separates_discs_from_strips():
    yy, xx = np.mgrid[:60, :80]
    disc = (xx - 20) ** 2 + (yy - 30) ** 2 <= 8**2
    strip = (np.abs(xx - 60) <= 13) & (np.abs(yy - 30) <= 3)
    labels, k = label_components(torch.from_numpy(disc | strip)[None, None])
    ecc = region_stats(labels, k)["eccentricity"][0].numpy()
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


def test_erosion_matches_scipy():
    rng = np.random.default_rng(2)
    mask = rng.random((2, 30, 40)) > 0.3
    ours = erode(torch.from_numpy(mask)[:, None])[:, 0].numpy()
    for i in range(2):
        ref = ndimage.binary_erosion(mask[i], structure=np.ones((3, 3)), border_value=0)
        assert np.array_equal(ours[i], ref)


def test_points_from_range_and_depth_agree():
    h, w = 12, 16
    fx = fy = 20.0
    cx, cy = 7.5, 5.5
    depth = torch.full((1, 1, h, w), 1900.0, dtype=torch.float64)
    p = points_from_depth(depth, fx, fy, cx, cy)
    rng = torch.linalg.vector_norm(p, dim=1, keepdim=True)
    q = points_from_range(rng, fx, fy, cx, cy)
    assert torch.allclose(p, q, atol=1e-9)


def test_shape_errors():
    with pytest.raises(ValueError, match=r"x: expected a tensor of shape \(B, 1, H, W\), got \(3, 4\)"):
        otsu_threshold(torch.zeros(3, 4))


# The per-chunk pipeline's numpy kernels (frames/pipeline.py) against references.


@pytest.mark.parametrize("seed", [0, 1])
def test_pipeline_otsu_from_mask_pixels_equals_masked_image(seed):
    from jaxdefl.frames.pipeline import _otsu_in_mask, _otsu_masked

    img = _scene(seed).astype(np.float32)
    b, h, w = img.shape
    mask = np.random.default_rng(seed).random(img.shape) < 0.3
    mask[1] = True  # a frame with no unmasked zeros
    mask[2] = False  # a frame with nothing in the mask
    am = np.where(mask, img, np.float32(0))
    fidx = np.flatnonzero(mask)
    fr = fidx // (h * w)
    fast = _otsu_in_mask(img.reshape(-1)[fidx], fr, h * w, b)
    slow = _otsu_masked(am)
    np.testing.assert_array_equal(fast, slow)
    for i in (0, 1, 3):  # the masked image's Otsu is skimage's
        assert slow[i] == pytest.approx(threshold_otsu(am[i]), rel=1e-5)


def test_pipeline_erosion_box_mean_and_median_match_references():
    import torch.nn.functional as F

    from jaxdefl.frames.pipeline import _box_mean, _erode3, top_level

    rng = np.random.default_rng(3)
    fg = rng.random((3, 20, 30)) < 0.8
    ref = np.stack([ndimage.binary_erosion(f, np.ones((3, 3)), border_value=0) for f in fg])
    np.testing.assert_array_equal(_erode3(fg), ref)
    z = rng.normal(1000, 5, (3, 20, 30)).astype(np.float32)
    z[0, 5, 5] = np.nan
    pool = F.avg_pool2d(torch.from_numpy(z)[:, None], 5, stride=1, padding=2, count_include_pad=False)[:, 0]
    np.testing.assert_allclose(_box_mean(z, 5), pool.numpy(), rtol=1e-6)
    assert np.isnan(_box_mean(z, 5)[0, 3:8, 3:8]).all() and np.isfinite(_box_mean(z, 5)[0, 8:]).all()
    t = z.reshape(3, -1)[:, :41].copy()
    t[1, ::2] = np.nan
    t[2] = np.nan
    np.testing.assert_array_equal(
        top_level(t, np.arange(41)), torch.nanmedian(torch.from_numpy(t), 1).values.numpy()
    )
