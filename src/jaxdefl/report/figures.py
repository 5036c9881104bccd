"""Figures: periodogram with significance levels, raw vs fitted trajectory."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from ..spectral import THESIS_ALPHAS, significance_level  # noqa: E402

__all__ = ["plot_fit", "plot_frame", "plot_periodogram"]


# the significance lines, from the strictest (highest) down: ordered colours of one sequential
# map and a line style each, so that lines a few tenths apart stay apart in print and in grey
_LEVEL_STYLES = ("-", "--", "-.", ":", (0, (5, 1.5)), (0, (3, 1, 1, 1, 1, 1)))


def plot_periodogram(freq_hz, power, n_indep, path: Path, title: str = "", alphas=THESIS_ALPHAS):
    """Lomb normalised periodogram with the thesis' significance levels (as in its Fig. 5.16).

    The levels are drawn from the strictest α down, each in its own colour (ordered along one
    colour map) and line style, and the legend, outside the axes, lists them in that order with
    the power each one stands at."""
    fig, ax = plt.subplots(figsize=(8, 3.6), constrained_layout=True)
    ax.semilogy(freq_hz, np.maximum(power, 1e-3), lw=0.7, color="k", label="$P_N$")
    ordered = sorted(alphas)
    cmap = plt.get_cmap("plasma")
    for k, a in enumerate(ordered):
        z = float(significance_level(a, n_indep))
        ax.axhline(
            z,
            ls=_LEVEL_STYLES[k % len(_LEVEL_STYLES)],
            lw=1.1,
            color=cmap(0.85 * k / max(len(ordered) - 1, 1)),
            label=f"α = {a:g} ($P_N$ = {z:.1f})",
        )
    fig.legend(fontsize=7, loc="outside right upper", title="significance", title_fontsize=7)
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel("normalised power $P_N$")
    ax.set_title(title, fontsize=9)
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_fit(
    t_s,
    y_mm,
    f0_hz,
    amplitude_mm,
    phase_rad,
    offset_mm,
    path: Path,
    title: str = "",
    seconds: float = 5.0,
):
    """Raw samples and the fitted harmonic over the first ``seconds`` of a window (t from t_mid)."""
    t_s = np.asarray(t_s)
    sel = t_s <= t_s.min() + seconds
    tt = np.linspace(t_s[sel].min(), t_s[sel].max(), 2000)
    model = offset_mm + amplitude_mm * np.cos(2 * np.pi * f0_hz * tt - phase_rad)
    fig, ax = plt.subplots(figsize=(7, 3.2), constrained_layout=True)
    ax.plot(t_s[sel], np.asarray(y_mm)[sel], ".", ms=3, color="tab:blue", label="raw")
    ax.plot(tt, model, "-", lw=1.2, color="k", label="fitted harmonic")
    ax.set_xlabel("time from window centre (s)")
    ax.set_ylabel("mm")
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=8, loc="upper right")
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_frame(frame_mm, intrinsics: dict, centroids, path: Path, title: str = ""):
    """One range/depth frame with the extracted plate centroids projected back onto the image."""
    fig, ax = plt.subplots(figsize=(6.4, 5.0), constrained_layout=True)
    img = np.asarray(frame_mm, float)
    lo, hi = np.nanpercentile(img, [2, 98])
    im = ax.imshow(img, cmap="viridis", vmin=lo, vmax=hi)
    fig.colorbar(im, ax=ax, shrink=0.8, label="mm")
    fx, fy, cx, cy = (float(intrinsics[k]) for k in ("fx", "fy", "cx", "cy"))
    for r in centroids.itertuples():
        u = fx * r.x / r.z + cx
        v = fy * r.y / r.z + cy
        ax.plot(u, v, "r+", ms=10, mew=1.5)
        ax.text(u + 2, v - 2, str(r.plate), color="w", fontsize=8)
    ax.set_title(title, fontsize=9)
    ax.set_xlabel("column (px)")
    ax.set_ylabel("row (px)")
    fig.savefig(path, dpi=120)
    plt.close(fig)
