"""Reconcile report: the before/after table, the effects, and a figure per level."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

__all__ = ["plot_level", "reconcile_markdown"]

_MEANING = {
    "noise_mm": "short-term noise of the residual",
    "slow_mm": "slow residual (10-s means: drifts, jumps)",
    "line_ratio": "lines in the residual spectrum above 0.1 Hz",
    "frame_common": "residual shared by the plates of a frame",
    "outlier_rate": "samples beyond 4.5 σ",
    "envelope": "change of the harmonic over ten windows (modulations)",
    "range_noise": "pixels' short-term range noise against their amplitude",
    "valid_share": "share of valid pixel ranges against amplitude",
}


def _frames_lines(rec) -> list[str]:
    """The frames level per amplitude bin: the recording's statistic over the simulation's."""
    rows = [r for r in rec.levels if r["level"] == "frames" and r.get("recording")]
    if not rows:
        return []
    out = [
        "",
        "## Frames: the recording's pixels over the frame simulator's, by amplitude decile",
        "",
        "| metric | " + " | ".join(f"d{k + 1}" for k in range(len(rows[0]["recording"]))) + " |",
        "|---|" + "---|" * len(rows[0]["recording"]),
    ]
    for r in rows:
        ratios = [
            f"{a / b:.2f}" if a is not None and b not in (None, 0) else "–"
            for a, b in zip(r["recording"], r["simulation"], strict=True)
        ]
        out.append(f"| {r['metric']} | " + " | ".join(ratios) + " |")
    noise = next((r for r in rows if r["metric"] == "range_noise"), None)
    if noise is not None and rec.verdict(noise) == "still apart":
        out += [
            "",
            "The camera's range noise is not the configured sensor's: no effect of the vocabulary "
            "changes it, so set the config's noise (modulation frequency, integration time, "
            "`noise_scale`) to the recording's before reading the other levels.",
        ]
    return out


def plot_level(rec, level: str):
    """Bars of the distances before and after, with the null band, for one level's metrics."""
    rows = [r for r in rec.levels if r["level"] == level]
    fig, ax = plt.subplots(figsize=(1.6 + 1.3 * len(rows), 3.4), constrained_layout=True)
    x = np.arange(len(rows))
    before = [r["before"] for r in rows]
    after = [r["after"] for r in rows]
    null = [r["null_95"] for r in rows]
    ax.bar(x - 0.2, before, 0.4, label="simulation as set up", color="tab:red")
    ax.bar(x + 0.2, after, 0.4, label="with the named effects", color="tab:blue")
    for xi, n in zip(x, null, strict=True):
        ax.hlines(n, xi - 0.45, xi + 0.45, colors="k", linestyles="--")
    ax.plot([], [], "k--", label="null band (95 %)")
    ax.set_xticks(x, [r["metric"] for r in rows], rotation=20)
    ax.set_yscale("symlog", linthresh=1e-3)
    ax.set_ylabel("distance recording - simulation")
    ax.set_title(f"{level}: recording against simulation")
    ax.legend(fontsize=7)
    return fig


def _num(v) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)


def reconcile_markdown(rec, d: dict, figures: list[str], recording: str, config: str) -> str:
    lines = [
        "# jaxdefl reconcile",
        "",
        f"Recording `{recording}` against the simulation of `{config}` (the same frame times, plates "
        f"and fitted harmonics, f0 = {rec.f0_hz:.6f} Hz, white noise at each series' level). Each "
        "distance is the recording's against the simulation's statistics; the null band is the "
        "95th percentile of the same distance between repeated simulations.",
        "",
        "| level | metric | what it measures | before | after | null 95 % | verdict |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rec.levels:
        lines.append(
            f"| {r['level']} | {r['metric']} | {_MEANING.get(r['metric'], '')} | {r['before']:.4g} | "
            f"{r['after']:.4g} | {r['null_95']:.4g} | {rec.verdict(r)} |"
        )
    lines += _frames_lines(rec)
    lines += ["", "## Physics named by the diagnosis", ""]
    if not rec.effects:
        lines.append("None: the diagnosis found nothing beyond the nominal model.")
    for e in rec.effects:
        params = ", ".join(f"{k} = {_num(v)}" for k, v in e["parameters"].items() if v is not None)
        lines.append(
            f"- **{e['id']}** (plates {', '.join(map(str, e['plates'])) or 'all'}; ΔBIC "
            f"{e['delta_bic']:.1f}): {params}. "
            + ("Simulated as an `[[effect]]` table." if e["simulated"] else f"Not simulated: {e['note']}.")
        )
        if e.get("explanation"):
            lines.append(f"  {e['explanation']}")
    unexplained = d.get("unexplained", [])
    if unexplained:
        lines += ["", "## Structure the vocabulary does not explain", ""]
        for u in unexplained:
            lines.append(f"- {u}")
    apart = [r["metric"] for r in rec.levels if rec.verdict(r) == "still apart"]
    lines += [
        "",
        "## Reading it",
        "",
        (
            "Every metric that differed is back inside its null band: the simulation with the named "
            "physics reproduces the recording."
            if not apart
            else f"Still outside the null band: {', '.join(apart)}. The named effects do not account for "
            "all of the difference there; either their simulated form is simpler than the recording's "
            "(e.g. one amplitude for every plate), or physics outside the vocabulary is at work."
        ),
        "",
        f"The reconciled simulation config is `{d['config']}` (`jaxdefl simulate {d['config']} --out DIR`).",
        "",
    ]
    lines += [f"![{f}]({f})" for f in figures]
    return "\n".join(lines) + "\n"
