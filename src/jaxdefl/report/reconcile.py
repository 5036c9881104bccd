"""Reconcile report: the before/after table, the effects, and a figure per level."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from .diagnosis import selection_rule  # noqa: E402

__all__ = ["ReconcileFindings", "plot_level", "reconcile_markdown"]

_MEANING = {
    "noise_mm": "short-term noise of the residual",
    "slow_mm": "slow residual (10-s means: drifts, jumps)",
    "line_ratio": "lines in the residual spectrum above 0.1 Hz",
    "frame_common": "residual shared by the plates of a frame",
    "outlier_rate": "samples beyond 4.5 σ",
    "envelope": "change of the harmonic over ten windows (modulations)",
    "range_noise": "pixels' short-term range noise against their amplitude",
    "valid_share": "share of valid pixel ranges against amplitude",
    "clock_jitter": "frame stamps' scatter about the frame clock (ms)",
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


def _clock_lines(rec) -> list[str]:
    """The clock level in words: the recording's stamp scatter and the configured camera's."""
    row = next((r for r in rec.levels if r["metric"] == "clock_jitter"), None)
    if row is None or row.get("recording_ms") is None:
        return []
    return [
        "",
        f"Clock: the recording's frame stamps scatter by {row['recording_ms']:.3g} ms RMS about its "
        f"frame clock; the configured camera's by {row['simulation_ms']:.3g} ms "
        f"(`timestamp_jitter_ms` = {row.get('configured_ms', 0.0):g}). The trajectories cannot show a "
        "jitter of the instants a frame is taken (the simulation renders the recording's own stamps), "
        "so it is compared here.",
    ]


def plot_level(rec, level: str):
    """Bars of the distances before and after, with the null band, for one level's metrics.

    The figure is wide enough for its title with a single metric, the y range leaves headroom
    above the tallest bar (a symlog axis autoscales flush with it), and the legend sits below
    the axes, where it hides no bar."""
    rows = [r for r in rec.levels if r["level"] == level]
    fig, ax = plt.subplots(figsize=(max(5.0, 1.6 + 1.3 * len(rows)), 3.8), constrained_layout=True)
    x = np.arange(len(rows))
    before = [r["before"] for r in rows]
    after = [r["after"] for r in rows]
    null = [r["null_95"] for r in rows]
    family = [r.get("null_family", r["null_95"]) for r in rows]
    ax.bar(x - 0.2, before, 0.4, label="simulation as set up", color="tab:red")
    ax.bar(x + 0.2, after, 0.4, label="with the named effects", color="tab:blue")
    after_band = [r.get("after_family", f) for r, f in zip(rows, family, strict=True)]
    for xi, n, fam, fa in zip(x, null, family, after_band, strict=True):
        ax.hlines(n, xi - 0.45, xi + 0.45, colors="k", linestyles="--")
        ax.hlines(fam, xi - 0.45, xi + 0.45, colors="k", linestyles=":")
        if fa != fam:
            ax.hlines(fa, xi, xi + 0.45, colors="tab:blue", linestyles=":")
    ax.plot([], [], "k--", label="null band (95 %)")
    ax.plot([], [], "k:", label="family band (the verdict's)")
    if any(fa != fam for fa, fam in zip(after_band, family, strict=True)):
        ax.plot([], [], ":", color="tab:blue", label="family band after (reconciled model's)")
    ax.set_xticks(x, [r["metric"] for r in rows], rotation=20)
    ax.set_yscale("symlog", linthresh=1e-3)
    values = np.array([v for v in before + after + null + family + after_band if v is not None], float)
    top = float(np.nanmax(values[np.isfinite(values)])) if np.isfinite(values).any() else 1.0
    ax.set_ylim(0.0, max(top, 1e-3) * 3.0)  # headroom: half a decade above the tallest bar
    ax.set_xlim(-0.6, len(rows) - 0.4)
    ax.set_ylabel("distance recording - simulation")
    ax.set_title(f"{level}: recording against simulation", fontsize=10)
    fig.legend(fontsize=7, loc="outside lower center", ncol=3, frameon=False)
    return fig


def _num(v) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)


# what to do about a metric that stays apart: a sentence of advice and the next command
# ({rec}: the recording, {table}: its trajectory table, {out}: the reconcile folder,
# {stem}: a name)
_ADVICE = {
    "noise_mm": (
        "the residual's short-term noise is not the simulated camera's: set the config's camera "
        "noise (`noise_scale`, `modulation_mhz`, `integration_time_ms`) to the recording's level and "
        "reconcile again",
        "jaxdefl reconcile {rec} --config {out}/reconciled.toml --out {out}_2",
    ),
    "slow_mm": (
        "a slow residual (a drift, a jump, a camera moved) that the named effects do not reproduce: "
        "the diagnosis' unnamed `trend` terms say where; a reference sensor tells the camera's "
        "drift from the structure's",
        "jaxdefl diagnose {table} --reference LDS.csv --out {stem}_diag.json",
    ),
    "line_ratio": (
        "lines in the residual spectrum that the simulation lacks (a mode, a machine nearby): the "
        "diagnosis' unnamed `line` terms give their frequencies; fit them beside the loading",
        "jaxdefl fit {table} --lines 2 --out {stem}_lines.csv",
    ),
    "frame_common": (
        "the plates of a frame share more (or less) noise than the simulated camera's: set the "
        "config's `centroid_residual_mm` and `correlated_spatial_fraction` to the recording's and "
        "reconcile again",
        "jaxdefl reconcile {rec} --config {out}/reconciled.toml --out {out}_2",
    ),
    "outlier_rate": (
        "the recording has more samples beyond 4.5 σ than its simulation (mixed pixels at plate "
        "edges, drop-outs read as positions): look at where they fall in the diagnosis",
        "jaxdefl diagnose {table} --out {stem}_diag.json",
    ),
    "envelope": (
        "the harmonic's amplitude or phase changes from window to window more than simulated (a "
        "load ramp, a changing stiffness): follow it in windows",
        "jaxdefl fit {table} --window 30 --out {stem}_30s.csv",
    ),
    "range_noise": (
        "the camera's pixel range noise is not the configured sensor's: set the config's noise "
        "(`modulation_mhz`, `integration_time_ms`, `noise_scale`) first, it changes every other level",
        "jaxdefl reconcile {rec} --config {out}/reconciled.toml --out {out}_2",
    ),
    "clock_jitter": (
        "the frame stamps scatter about the frame clock more (or less) than the configured camera's "
        "(`timestamp_jitter_ms`): where the frames were taken at their stamps, set the camera's "
        "`timestamp_jitter_ms` to the recording's; where they were stamped on delivery, take the "
        "frame clock instead of the stamps",
        "jaxdefl reconcile {rec} --config {cfg} --timestamps reclock --out {out}_reclock",
    ),
    "valid_share": (
        "the share of valid pixel ranges differs from the simulated camera's (saturation, low "
        "amplitude, multipath): check the camera's standoff and the scene in the config",
        "jaxdefl reconcile {rec} --config {out}/reconciled.toml --out {out}_2",
    ),
}


@dataclass(frozen=True)
class ReconcileFindings:
    """What a reconciliation found, as its report shows it: the summary sentence, the advice and
    the tables are all written from this one structure.

    rows: the levels' metrics with their verdicts; named: the effects simulated or not;
    unnamed, unexplained: what the diagnosis found outside the vocabulary; recording, config,
    out: what the next commands are run on.
    """

    rows: tuple[dict, ...]
    named: tuple[dict, ...]
    unnamed: tuple[dict, ...]
    unexplained: tuple[dict, ...]
    recording: str = "RECORDING"
    config: str = "CONFIG.toml"
    out: str = "reconcile_out"

    @classmethod
    def of(cls, rec, d: dict, recording: str, config: str, out: str = "reconcile_out") -> ReconcileFindings:
        rows = tuple({**r, "verdict": r.get("verdict") or rec.verdict(r)} for r in rec.levels)
        diag = rec.diagnosis or {}
        return cls(
            rows=rows,
            named=tuple(rec.effects),
            unnamed=tuple(diag.get("unnamed") or ()),
            unexplained=tuple(d.get("unexplained") or diag.get("unexplained") or ()),
            recording=recording,
            config=config,
            out=out,
        )

    def metrics(self, verdict: str) -> list[str]:
        return list(dict.fromkeys(r["metric"] for r in self.rows if r["verdict"] == verdict))

    def summary(self) -> str:
        apart, fixed = self.metrics("still apart"), self.metrics("reconciled")
        counts: dict[str, int] = {}
        for e in self.named:
            counts[e["id"]] = counts.get(e["id"], 0) + 1
        named = ", ".join(f"`{k}`" + (f" ×{n}" if n > 1 else "") for k, n in counts.items())
        if apart:
            n = len(dict.fromkeys(r["metric"] for r in self.rows if r["verdict"] != "not measured"))
            text = (
                f"**Still apart**: {len(apart)} of {n} metrics ({', '.join(apart)}) stay outside their "
                "null band"
                + (
                    f" with the named effects ({named}) simulated"
                    if named
                    else "; the diagnosis named no effect"
                )
            )
        elif fixed:
            text = (
                f"**Reconciled**: every metric that differed ({', '.join(fixed)}) is back inside its "
                f"null band with the named effects ({named or 'none'}) simulated"
            )
        else:
            text = "**Agreed already**: every metric measured is inside its null band as set up"
        if self.unnamed:
            m = len(self.unnamed)
            text += (
                f"; {'it' if not self.named else 'the diagnosis'} also modelled {m} unnamed "
                f"term{'s' if m > 1 else ''} outside the "
                f"vocabulary ({', '.join(u['kind'] for u in self.unnamed)}), which the simulation does "
                "not reproduce"
            )
        if self.unexplained:
            text += f"; {len(self.unexplained)} residual structure(s) stay unexplained"
        return text + "." + (" See *What to do next*." if self.advice() else "")

    def advice(self) -> list[str]:
        stem = Path(self.recording).stem or "rec"
        # diagnose and fit read trajectory tables: a frame recording is extracted first
        frames = Path(self.recording).suffix.lower() not in (".csv", ".parquet", ".pq", ".gz", ".txt")
        table = f"{stem}_trajectories.csv" if frames else self.recording
        fill = dict(rec=self.recording, table=table, cfg=self.config, out=self.out, stem=stem)

        def command(cmd: str) -> str:
            text = f"`{cmd.format(**fill)}`"
            if frames and "{table}" in cmd:
                text = f"`jaxdefl extract {self.recording} --out {table}`, then " + text
            return text

        out = []
        for m in self.metrics("still apart"):
            sentence, cmd = _ADVICE.get(
                m,
                (
                    "a statistic the simulation does not reproduce",
                    "jaxdefl diagnose {table} --out {stem}_diag.json",
                ),
            )
            out.append(f"`{m}`: {sentence}: {command(cmd)}.")
        if self.unnamed and not self.metrics("still apart"):
            out.append(
                "The unnamed terms are not simulated; read them in the diagnosis: "
                + command("jaxdefl diagnose {table} --out {stem}_diag.json")
                + "."
            )
        return out


def reconcile_markdown(rec, d: dict, figures: list[str], recording: str, config: str, out: str = "") -> str:
    """The reconcile report; its summary, advice and tables come from one `ReconcileFindings`."""
    found = ReconcileFindings.of(rec, d, recording, config, out or "reconcile_out")
    lines = [
        "# jaxdefl reconcile",
        "",
        found.summary(),
        "",
        f"Recording `{recording}` against the simulation of `{config}` (the same frame times, plates "
        f"and fitted harmonics, f0 = {rec.f0_hz:.6f} Hz, white noise at each series' level shared by "
        "a plate's axes as the recording's, and the extraction's own outliers when a config "
        "calibrates them). Each "
        "distance is the recording's against the simulation's statistics; the null band is the "
        "95th percentile of the same distance between repeated simulations. The effects are those "
        "the diagnosis names (`jaxdefl diagnose`). The verdict reads the family band, the "
        "1 − 0.05/9 percentile of the same distances: a recording is judged on 9 metrics at once, "
        "and at each one's 95th percentile a recording of the simulated model itself would lie "
        "outside one of them a third of the time. *After* is read against the reconciled "
        "simulation's own family band (the same percentile of the distances between its repeated "
        "renders: a line or a modulation scatters its statistic more than noise alone). " + selection_rule(),
        "",
        "| level | metric | what it measures | before | after | null 95 % | family band | band after "
        "| verdict |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in found.rows:
        fam = r.get("null_family", r["null_95"])
        lines.append(
            f"| {r['level']} | {r['metric']} | {_MEANING.get(r['metric'], '')} | {r['before']:.4g} | "
            f"{r['after']:.4g} | {r['null_95']:.4g} | {fam:.4g} | {r.get('after_family', fam):.4g} | "
            f"{r['verdict']} |"
        )
    lines += _frames_lines(rec)
    lines += _clock_lines(rec)
    lines += ["", "## Physics named by the diagnosis", ""]
    if not found.named:
        lines.append(
            "None of the vocabulary"
            + (": see the unnamed structure below." if found.unnamed or found.unexplained else ".")
        )
    for e in found.named:
        params = ", ".join(f"{k} = {_num(v)}" for k, v in e["parameters"].items() if v is not None)
        lines.append(
            f"- **{e['id']}** (plates {', '.join(map(str, e['plates'])) or 'all'}; ΔBIC "
            f"{e['delta_bic']:.1f}): {params}. "
            + ("Simulated as an `[[effect]]` table." if e["simulated"] else f"Not simulated: {e['note']}.")
        )
        if e.get("explanation"):
            lines.append(f"  {e['explanation']}")
    if found.unnamed or found.unexplained:
        lines += ["", "## Structure the vocabulary does not name (not simulated)", ""]
        for u in found.unnamed:
            lines.append(f"- unnamed `{u['kind']}`: {u.get('explanation', '')}")
        for u in found.unexplained:
            lines.append(f"- unexplained: {_unexplained_text(u)}")
    if d.get("notes"):
        lines += ["", "## Notes", ""] + [f"- {n}" for n in d["notes"]]
    lines += ["", "## What to do next", ""]
    lines += [f"- {a}" for a in found.advice()] or [
        "- Nothing: the simulation with the named physics reproduces the recording."
    ]
    session = (d.get("settings") or {}).get("session")
    pick = f" --session {session}" if session else ""  # a config of several sessions makes them all
    lines += [
        "",
        f"The reconciled simulation config is `{d['config']}` "
        f"(`jaxdefl simulate {d['config']}{pick} --out DIR`).",
        "",
    ]
    lines += [f"![{f}]({f})" for f in figures]
    return "\n".join(lines) + "\n"


def _unexplained_text(u) -> str:
    if not isinstance(u, dict):
        return str(u)
    where = f"plates {', '.join(map(str, u.get('plates', [])))} ({', '.join(u.get('axes', []))})"
    return f"{u.get('description', u.get('test', ''))}: {where}, p = {u.get('p_value', float('nan')):.2g}"
