"""Figures and the demo summary's explanations (issue 25.17, 25.18): the posterior figure's axes
carry tick labels over any range, psd.png's significance lines are told apart and listed in
order, reconcile's level figures keep their title and tallest bar inside, and the demo summary
says why plates are missing, why windows have no fit and which LDS is defective."""

from __future__ import annotations

import math

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
import pytest  # noqa: E402
from matplotlib.colors import to_rgba  # noqa: E402

from jaxdefl.reconcile.engine import Reconciliation  # noqa: E402
from jaxdefl.report import figures  # noqa: E402
from jaxdefl.report.reconcile import plot_level  # noqa: E402
from jaxdefl.report.summary import camera_view_md, not_fitted_md, reference_md  # noqa: E402
from jaxdefl.simulate import load_config  # noqa: E402
from jaxdefl.spectral import THESIS_ALPHAS, significance_level  # noqa: E402
from jaxdefl.uncertainty import plot_posterior_vs_linearised  # noqa: E402


@pytest.fixture
def keep_figures(monkeypatch):
    """Keep the figures the plotting functions close, to inspect them."""
    made = []
    monkeypatch.setattr(plt, "close", lambda fig=None: made.append(fig))
    return made


def _labels(axis) -> list[str]:
    lo, hi = sorted(axis.get_view_interval())
    return [
        t.get_text()
        for t, v in zip(axis.get_ticklabels(), axis.get_ticklocs(), strict=True)
        if lo <= v <= hi and t.get_text()
    ]


@pytest.mark.parametrize("spread", [1.05, 1.5, 8.0, 30.0])
def test_posterior_figure_labels_every_axis_whatever_its_range(tmp_path, keep_figures, spread):
    # σ_f0 of a few windows within a factor 1.5 (the demo's): a log axis with no decade inside
    base = np.array([3.8e-4, 3.9e-4, 4.3e-4])
    f0 = base[0] * spread ** np.linspace(0, 1, 3)
    table = pd.DataFrame(
        {
            "axis": ["z", "y", "x"],
            "sigma_amplitude_lin_mm": [0.046, 0.0064, 0.0105],
            "sigma_amplitude_post_mm": [0.044, 0.0065, 0.0101],
            "sigma_f0_lin_hz": f0,
            "sigma_f0_post_hz": f0 * np.array([0.97, 1.0, 0.96]),
            "converged_chain": [True, True, True],
        }
    )
    plot_posterior_vs_linearised(table, tmp_path / "p.png")
    (fig,) = keep_figures
    fig.canvas.draw()
    for ax in fig.axes:
        for axis in (ax.xaxis, ax.yaxis):
            labels = _labels(axis)
            assert len(labels) >= 2, (axis, labels)
            # the labels with their offset (×10⁻⁴) name values inside the axis' range
            assert len(set(labels)) == len(labels)


def test_psd_significance_lines_are_distinct_ordered_and_listed(tmp_path, keep_figures):
    rng = np.random.default_rng(0)
    f = np.linspace(0.01, 10, 4000)
    p = rng.exponential(1.0, f.size)
    p[1200] = 800.0
    figures.plot_periodogram(f, p, 1500.0, tmp_path / "psd.png", title="t")
    (fig,) = keep_figures
    ax = fig.axes[0]
    levels = [line for line in ax.get_lines() if line.get_label().startswith("α")]
    assert len(levels) == len(THESIS_ALPHAS) == 6
    # from the strictest α down, at the thesis' levels
    alphas = [float(line.get_label().split("=")[1].split("(")[0]) for line in levels]
    assert alphas == sorted(THESIS_ALPHAS)
    heights = [line.get_ydata()[0] for line in levels]
    np.testing.assert_allclose(heights, [float(significance_level(a, 1500.0)) for a in alphas])
    assert np.all(np.diff(heights) < 0)
    # every line its own colour (apart by more than a shade) and its own style
    colours = np.array([to_rgba(line.get_color())[:3] for line in levels])
    gaps = [np.abs(colours[i] - colours[j]).sum() for i in range(6) for j in range(i + 1, 6)]
    assert min(gaps) > 0.15
    styles = {repr(line._dash_pattern) for line in levels}
    assert len(styles) == 6
    # the legend lists them in the same order, outside the axes
    (legend,) = fig.legends
    texts = [t.get_text() for t in legend.get_texts()]
    assert [t for t in texts if t.startswith("α")] == [line.get_label() for line in levels]
    fig.canvas.draw()
    r = fig.canvas.get_renderer()
    assert not legend.get_window_extent(r).overlaps(ax.get_window_extent(r))


@pytest.mark.parametrize("n_metrics", [1, 5])
def test_reconcile_level_figure_keeps_its_title_and_tallest_bar(n_metrics):
    metrics = ["envelope", "noise_mm", "slow_mm", "line_ratio", "outlier_rate"][:n_metrics]
    rows = [
        dict(level="lvl", metric=m, before=b, after=a, null_95=n)
        for m, b, a, n in zip(
            metrics,
            [0.2, 0.05, 2.1, 0.3, 4.6],
            [0.05, 0.04, 0.2, 0.25, 4.5],
            [0.1, 0.08, 0.3, 0.2, 0.4],
            strict=False,
        )
    ]
    rec = Reconciliation(levels=rows, effects=[], specs=(), diagnosis={}, f0_hz=3.0)
    fig = plot_level(rec, "lvl")
    fig.canvas.draw()
    r = fig.canvas.get_renderer()
    ax = fig.axes[0]
    whole = fig.bbox
    for artist in (ax.title, *fig.legends):
        box = artist.get_window_extent(r)
        assert whole.x0 - 1 <= box.x0 and box.x1 <= whole.x1 + 1, artist
    top = ax.get_ylim()[1]
    tallest = max(max(x["before"], x["after"], x["null_95"]) for x in rows)
    assert top >= 2 * tallest  # headroom above the tallest bar: nothing clipped
    plt.close(fig)


# -- the demo summary's explanations ---------------------------------------------------------


def _inside_by_pinhole(cfg) -> list[int]:
    """Plates whose top face projects wholly inside the image: a pinhole from the field of
    view, written out independently of the simulator's scene code."""
    cam, pl = cfg.camera, cfg.plates
    w = 176  # the SR4000's columns
    fx = (w / 2) / math.tan(math.radians(cam.fov_deg[0]) / 2)
    depth = cam.standoff_mm + pl.depth_below_top_mm
    inside = []
    for k in range(pl.count):
        x = pl.x0_mm + k * pl.spacing_mm - cam.x_mm
        u = [fx * (x + s * pl.length_mm / 2) / depth + (w - 1) / 2 + 0.5 for s in (-1, 1)]
        if min(u) >= 0 and max(u) <= w:
            inside.append(k + 1)
    return inside


def test_the_demo_summary_says_why_only_some_plates_appear():
    cfg = load_config("exp2_tof_3hz")
    inside = _inside_by_pinhole(cfg)
    assert inside == list(range(4, 11))  # the demo's plates 4-10
    text = camera_view_md(cfg, inside)
    assert "field of view 43.6° × 34.6°" in text and "Plates 4–10 of the 13 lie whole inside" in text
    assert "those are the plates extracted" in text
    assert "Plates 1–3, 11–13 are outside the camera's view" in text
    assert "LDS under plates 3, 11" in text  # two sensors with nothing to compare
    # the span seen along the beam at the plates' depth
    half = (1900 + 295) * math.tan(math.radians(43.6 / 2))
    assert f"x = {1700 - half:.0f}–{1700 + half:.0f} mm" in text
    # a plate in view that was not extracted is named as such
    assert "the plates extracted are 4–6, 8–10" in camera_view_md(cfg, [4, 5, 6, 8, 9, 10])


def test_not_fitted_windows_are_explained_by_their_status():
    w = pd.DataFrame(
        {
            "plate": [7, 7, 7, 7, 5, 5],
            "axis": ["x", "x", "x", "x", "z", "y"],
            "window": [0, 1, 2, 3, 0, 2],
            "status": ["no_significant_peak"] * 4 + ["converged", "too_few_cycles"],
            "peak_fap": [0.98, 1.0, 1.0, 0.99, 0.0, 0.2],
        }
    )
    text = not_fitted_md(w, fap_max=0.01)
    assert text.startswith("5 of 6 windows have no fit (`not_fitted`")
    assert "plate 7 x, windows 0–3: `no_significant_peak`" in text and "0.98–1" in text and "0.01" in text
    assert "plate 5 y, window 2: `too_few_cycles`" in text
    assert "plate 5 z" not in text
    assert not_fitted_md(w[w.status == "converged"], 0.01) == "Every window was fitted."


def test_the_defective_lds_is_named_for_its_plate():
    cfg = load_config("exp2_tof_3hz")
    assert cfg.lds.defective_plate == 9
    cmp = pd.DataFrame(
        {
            "plate": [5, 7, 9],
            "amplitude_mm": [2.0117, 2.2392, 2.0259],
            "amplitude_ref_mm": [2.0798, 2.3205, 1.2476],
            "delta_amplitude_mm": [-0.0682, -0.0813, 0.7783],
            "sigma_delta_amplitude_mm": [0.0237, 0.0230, 0.0224],
        }
    )
    text = reference_md(cmp, cfg)
    assert "Plate 9's ΔA = +0.778 mm" in text and "marked defective in the config" in text
    assert "lds.defective_plate = 9" in text and "Plate 5" not in text and "Plate 7" not in text
    assert "on the other plates the camera and the LDS differ by 0.081 mm at most" in text
    # a large difference on a sound sensor is not blamed on it
    cmp.loc[0, "delta_amplitude_mm"] = 0.5
    assert "no sensor of the config is marked defective there" in reference_md(cmp, cfg)
