"""Figures: posterior vs linearised σ's per window, and coverage against SNR."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
from matplotlib.ticker import (  # noqa: E402
    LogLocator,
    MaxNLocator,
    NullFormatter,
    NullLocator,
    ScalarFormatter,
)

__all__ = ["plot_posterior_vs_linearised", "plot_coverage"]


def plot_posterior_vs_linearised(table: pd.DataFrame, path) -> Path:
    """Posterior σ against linearised σ of A and f0 for every checked window (a `posterior_table`).

    Points on the diagonal mean the linearised σ (thesis 5.43-5.45) is what the posterior says;
    hollow markers are chains that did not pass `chain_diagnostics`.
    """
    path = Path(path)
    fig, axes = plt.subplots(1, 2, figsize=(8, 3.8), constrained_layout=True)
    ok = table["converged_chain"].to_numpy(bool)
    pairs = [
        ("sigma_amplitude_lin_mm", "sigma_amplitude_post_mm", "σ_A (mm)"),
        ("sigma_f0_lin_hz", "sigma_f0_post_hz", "σ_f0 (Hz)"),
    ]
    for ax, (xl, yl, name) in zip(axes, pairs, strict=True):
        x, y = table[xl].to_numpy(float), table[yl].to_numpy(float)
        for axis in table["axis"].unique():
            m = (table["axis"] == axis).to_numpy()
            ax.loglog(x[m & ok], y[m & ok], "o", ms=4, label=f"{axis}")
            if (m & ~ok).any():
                ax.loglog(
                    x[m & ~ok], y[m & ~ok], "o", ms=4, mfc="none", label=f"{axis} (chain not converged)"
                )
        finite = np.isfinite(x) & np.isfinite(y) & (x > 0) & (y > 0)
        if finite.any():
            lo, hi = min(x[finite].min(), y[finite].min()), max(x[finite].max(), y[finite].max())
            grid = np.array([lo / 1.2, hi * 1.2])
            ax.plot(grid, grid, "k-", lw=0.8)
            ax.fill_between(grid, grid / 1.1, grid * 1.1, color="0.85", label="±10 %")
            for axis in (ax.xaxis, ax.yaxis):
                _readable_log_ticks(axis, lo / 1.2, hi * 1.2)
        ax.set_xlabel(f"linearised {name}")
        ax.set_ylabel(f"posterior {name}")
        ax.legend(fontsize=7)
    fig.suptitle("posterior (emcee) vs linearised standard deviations", fontsize=9)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def _readable_log_ticks(axis, lo: float, hi: float) -> None:
    """Tick labels on a log axis whatever its range. Over a decade or two a log axis has one or
    no major tick to label (the σ_f0's of a few windows span a factor 1.5), so such an axis gets
    ticks at 1, 2, 5 × 10^k, or over less than a factor 3 a few evenly spaced ones, labelled in
    offset notation (3.6, 4.2, 4.8 × 10⁻⁴); wider ones keep their decades, minor labels off
    (they overlap)."""
    if hi / lo >= 1000:
        axis.set_minor_formatter(NullFormatter())
        return
    fmt = ScalarFormatter(useMathText=True)
    fmt.set_powerlimits((-2, 3))
    axis.set_major_locator(MaxNLocator(nbins=4) if hi / lo < 3 else LogLocator(base=10, subs=(1.0, 2.0, 5.0)))
    axis.set_major_formatter(fmt)
    axis.set_minor_locator(NullLocator())


def plot_coverage(binned: pd.DataFrame, path, x: str = "snr_mid", title: str = "") -> Path:
    """Empirical coverage of 95 % intervals against a binned feature (columns ``*_95``)."""
    path = Path(path)
    fig, ax = plt.subplots(figsize=(6.5, 3.8), constrained_layout=True)
    for col in [c for c in binned.columns if c.endswith("_95")]:
        ax.semilogx(binned[x], binned[col], "o-", ms=4, label=col)
    ax.axhspan(0.93, 0.97, color="0.88", label="93-97 %")
    ax.axhline(0.95, color="k", lw=0.8)
    ax.set_xlabel(x)
    ax.set_ylabel("empirical coverage")
    ax.set_ylim(0.5, 1.01)
    ax.legend(fontsize=7)
    ax.set_title(title, fontsize=9)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
