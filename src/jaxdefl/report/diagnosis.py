"""Diagnosis report: a before/after figure per located effect and a markdown explanation."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from ..diagnose import ALPHA, ALPHA_NAMED, DELTA_BIC_MAX, loglik, masked_periodogram  # noqa: E402

__all__ = ["Findings", "plot_effect", "diagnosis_markdown", "selection_rule", "write_diagnosis_report"]


def _binned(t: np.ndarray, r: np.ndarray, nbins: int = 120):
    edges = np.linspace(t.min(), t.max() + 1e-9, nbins + 1)
    idx = np.clip(np.digitize(t, edges) - 1, 0, nbins - 1)
    cnt = np.bincount(idx, minlength=nbins)
    mean = np.bincount(idx, r, minlength=nbins) / np.maximum(cnt, 1)
    rms = np.sqrt(np.bincount(idx, r * r, minlength=nbins) / np.maximum(cnt, 1))
    centre = 0.5 * (edges[1:] + edges[:-1])
    ok = cnt > 0
    return centre[ok], mean[ok], rms[ok]


def _spectrum(ctx, i: int, r: np.ndarray):
    return masked_periodogram(ctx, i, r)


def plot_effect(diag, k: int, path: Path) -> Path:
    """Figure for accepted effect ``k``: binned residual mean and RMS against time, and the
    residual spectrum, before and after the effect was added, on its most affected series."""
    a = diag.accepted[k]
    ctx = diag.ctx
    p = a.proposal
    # the series that gained most
    gains = [loglik(ctx.series[i].y, p.states[i]) - loglik(ctx.series[i].y, a.before[i]) for i in p.series]
    i = p.series[int(np.argmax(gains))]
    s = ctx.series[i]
    r0 = s.y - a.before[i].mean
    r1 = s.y - p.states[i].mean
    fig, ax = plt.subplots(1, 3, figsize=(14, 3.8))
    for r, lab, c in ((r0, "before", "tab:red"), (r1, "after", "tab:blue")):
        tc, mean, rms = _binned(s.t, r)
        ax[0].plot(tc, mean, color=c, lw=1, label=lab)
        ax[1].plot(tc, rms, color=c, lw=1, label=lab)
        f, pw = _spectrum(ctx, i, r)
        m = max(1, f.size // 600)  # the largest power per bin of m frequencies: lines stay visible
        nb = f.size // m
        ax[2].semilogy(
            f[: nb * m].reshape(nb, m).mean(axis=1),
            np.maximum(pw[: nb * m].reshape(nb, m).max(axis=1), 1e-3),
            color=c,
            lw=0.8,
            label=lab,
        )
    ax[0].set(xlabel="t since start (s)", ylabel="binned residual mean (mm)", title="mean")
    ax[1].set(xlabel="t since start (s)", ylabel="binned residual RMS (mm)", title="noise level")
    ax[2].set(xlabel="frequency (Hz)", ylabel="normalised power (bin max)", title="residual spectrum")
    if p.band_hz:
        for x in p.band_hz:
            ax[2].axvline(x, color="k", lw=0.5, ls=":")
    for x in ax:
        x.legend(fontsize=8)
    fig.suptitle(
        f"{p.effect} — plate {s.plate} {s.axis}: ΔBIC {a.delta_bic:.0f}, "
        f"RMS {a.rms_before:.4f} → {a.rms_after:.4f} mm"
    )
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def _fmt_param(v: dict) -> str:
    val, sig = v.get("value"), v.get("sigma")
    if isinstance(val, float):
        if sig is not None and isinstance(sig, float) and math.isfinite(sig):
            return f"{val:.6g} ± {sig:.2g}"
        return f"{val:.6g}"
    return str(val)


def _where(u: dict) -> str:
    return f"plates {', '.join(map(str, u['plates']))} ({', '.join(u['axes'])})"


def _value(params: dict, name: str):
    v = params.get(name)
    return v.get("value") if isinstance(v, dict) else v


def _named_with_rivals(e: dict) -> str:
    """An effect's id, with the rivals the record does not tell it from (`or level_jump`)."""
    rivals = " or ".join(f"`{r}`" for r in e.get("not_told_from") or [])
    return f"`{e['id']}`" + (f" (or {rivals})" if rivals else "")


@dataclass(frozen=True)
class Findings:
    """What a diagnosis found, as its report shows it: the summary sentence, the advice and the
    tables are all written from this one structure, so they cannot disagree.

    named: DIAG.json's ``effects`` but the minor ones; minor: those its relevance marks minor
    (reported apart, never in the summary's lead); unnamed: its generic terms; unexplained: the residual tests
    that still fail; nominal_p, final_p: the whiteness p-values of the table; trajectory,
    reference, config: what the next commands are run on.
    """

    named: tuple[dict, ...]
    unnamed: tuple[dict, ...]
    unexplained: tuple[dict, ...]
    nominal_p: float
    final_p: float
    trajectory: str = "TRAJ.csv"
    reference: str | None = None
    config: str | None = None
    minor: tuple[dict, ...] = ()

    @classmethod
    def of(cls, d: dict) -> Findings:
        s = d.get("settings") or {}

        def is_minor(e: dict) -> bool:
            return bool((e.get("relevance") or {}).get("minor"))

        return cls(
            named=tuple(e for e in d["effects"] if not is_minor(e)),
            minor=tuple(e for e in d["effects"] if is_minor(e)),
            unnamed=tuple(d.get("unnamed") or ()),
            unexplained=tuple(d["unexplained"]),
            nominal_p=float(d["nominal"]["whiteness_p"]),
            final_p=float(d["final"]["whiteness_p"]),
            trajectory=s.get("trajectory") or "TRAJ.csv",
            reference=s.get("reference"),
            config=s.get("config"),
        )

    @property
    def nothing(self) -> bool:
        """No term of any kind and no residual test failing: the nominal model suffices."""
        return not (self.named or self.minor or self.unnamed or self.unexplained) and self.nominal_p >= ALPHA

    def summary(self) -> str:
        """The report's one-sentence verdict."""
        if self.nothing:
            return (
                "**No effect located**: the residuals are consistent with the nominal model "
                f"(whiteness p = {self.nominal_p:.2g})."
            )
        parts = []
        if self.named:
            n = len(self.named)
            parts.append(
                f"**{n} effect{'s' if n > 1 else ''} located**: "
                + ", ".join(_named_with_rivals(e) for e in self.named)
            )
        else:
            parts.append("**No named effect**")
        if self.unnamed:
            m = len(self.unnamed)
            big = max(self.unnamed, key=lambda u: u["rms_before_mm"] - u["rms_after_mm"])
            parts.append(
                f"{'and' if self.named else 'but'} {m} unnamed term{'s' if m > 1 else ''} outside the "
                f"vocabulary ({', '.join(u['kind'] for u in self.unnamed)}; the largest, `{big['kind']}` "
                f"on {_where(big)}, takes the residual RMS from {big['rms_before_mm']:.4g} to "
                f"{big['rms_after_mm']:.4g} mm)"
            )
        elif not self.named:
            parts.append(
                f"but the nominal residuals are not white (whiteness p = {self.nominal_p:.2g})"
                if self.nominal_p < ALPHA
                else "but residual tests fail"
            )
        if self.minor:
            parts.append(f"{len(self.minor)} minor finding{'s' if len(self.minor) > 1 else ''} apart")
        lead = ", ".join(parts)
        if self.unexplained:
            tail = (
                f"Structure remains that no term models ({len(self.unexplained)} residual "
                "test(s) fail): see *Unexplained structure*."
            )
        elif self.final_p < ALPHA:
            tail = f"The final residuals are still not white (whiteness p = {self.final_p:.2g})."
        else:
            tail = f"The final residuals are white (whiteness p = {self.final_p:.2g})."
        return f"{lead}. {tail} See *What to do next*."

    def advice(self) -> list[str]:
        """A sentence of advice and the next command for each finding that asks for one."""
        traj = self.trajectory
        stem = Path(traj).stem or "traj"
        config = self.config or "CONFIG.toml"
        out = []
        if self.named:
            out.append(
                "Simulate the named physics and check that it accounts for the difference between "
                f"the recording and its simulation: `jaxdefl reconcile {traj} --config {config} "
                f"--out {stem}_reconcile`."
            )
        for u in self.unnamed:
            out.append(_unnamed_advice(u, traj, stem, self.reference))
        if self.unexplained or (not self.named and not self.unnamed and self.nominal_p < ALPHA):
            what = "; ".join(sorted({u["description"] for u in self.unexplained})) or (
                "the residual is not white noise"
            )
            out.append(
                f"Structure that no term models ({what}): compare the recording with its simulation, "
                "statistic by statistic, to see where it departs: "
                f"`jaxdefl reconcile {traj} --config {config} --out {stem}_reconcile`."
            )
        return out


def _unnamed_advice(u: dict, traj: str, stem: str, reference: str | None) -> str:
    """One sentence of advice and the next command for an unnamed term, by its kind."""
    where = _where(u)
    par = u["parameters"]
    if u["kind"] == "line":
        f = _value(par, "freq_hz")
        at = f" at {f:.4g} Hz" if isinstance(f, float) else ""
        return (
            f"`line`{at} on {where}: a vibration that is not the loading (a mode of the structure, a "
            "machine nearby, the camera mount); fit it beside the loading line so it does not bias "
            f"the estimates: `jaxdefl fit {traj} --lines 2 --out {stem}_lines.csv`."
        )
    if u["kind"] == "envelope":
        if par.get("form") == "exponential":
            return (
                f"`envelope` on {where}: the motion dies away (a free decay); fit the damped model: "
                f"`jaxdefl fit {traj} --model damped --out {stem}_damped.csv`."
            )
        return (
            f"`envelope` on {where}: the loading amplitude changes during the record (a load ramp, a "
            "changing stiffness); follow it in windows: "
            f"`jaxdefl fit {traj} --window 30 --out {stem}_30s.csv`."
        )
    # trend: a slow change of the mean
    if reference is None:
        return (
            f"`trend` on {where}: the mean wanders or steps (a camera warming up or moved, a support "
            "settling); a reference sensor tells the camera's drift from the structure's: "
            f"`jaxdefl diagnose {traj} --reference LDS.csv --out {stem}_diag.json`."
        )
    return (
        f"`trend` on {where}: the mean wanders or steps although the reference does not (the camera "
        "or its mount moved); windowed estimates take their own offset and are hardly affected: "
        f"`jaxdefl fit {traj} --window 30 --out {stem}_30s.csv`."
    )


def selection_rule(alpha: float = ALPHA_NAMED) -> str:
    """How the search accepts a term, in words, with the levels it uses (`jaxdefl.diagnose`;
    ``alpha`` the family-wise level of the named effects, DIAG.json's ``input.alpha``)."""
    return (
        "A named effect is accepted when its likelihood-ratio statistic 2 Δlog L (against AR(1) "
        "noise for mean terms, frame-common noise discounted by its design effect) exceeds the χ² "
        f"critical value at the family-wise level α = {alpha:g} split over the effects "
        "screened and the trials of the effect's own scan (Bonferroni: the look-elsewhere effect), "
        "its signature's p-value passes the same level, and the RMS of the series it touches goes "
        "down; BIC only chooses between competing explanations that pass. Structure the named "
        "effects leave is then modelled by generic unnamed terms (line, envelope, trend), each "
        f"kept when ΔBIC < {DELTA_BIC_MAX:g}. The final residuals are tested for whiteness at "
        f"α = {ALPHA:g}; what fails is reported as unexplained."
    )


def diagnosis_markdown(d: dict, figures: list[str]) -> str:
    """The DIAG.json dict as a report a structural engineer can read."""
    inp, nom, fin = d["input"], d["nominal"], d["final"]
    found = Findings.of(d)
    lines = [
        "# Diagnosis: what the nominal model leaves out",
        "",
        f"Record: {len(inp['plates'])} plates ({', '.join(map(str, inp['plates']))}), axes "
        f"{', '.join(inp['axes'])}, {inp['duration_s'] / 60:.1f} min, frame interval "
        f"{inp['frame_interval_s'] * 1e3:.2f} ms, loading frequency {inp['f0_hz']:.4f} Hz"
        + (
            f", LDS reference on plates {', '.join(map(str, inp['reference_plates']))}"
            if inp["reference_plates"]
            else ", no reference"
        )
        + ".",
        "",
        found.summary(),
        "",
        "The nominal model is the thesis' harmonic (eq. 5.29) per plate and axis plus white noise; "
        "with a reference, the camera's z of a plate with an LDS is expected to move exactly as the LDS "
        "(only its offset is free). "
        + selection_rule(inp.get("alpha", ALPHA_NAMED))
        + " RMS is the likelihood-equivalent noise σ "
        "over the series a term touches (the plain residual RMS for mean terms).",
        "",
        "| | RMS (mm) | BIC | whiteness p |",
        "|---|---|---|---|",
        f"| nominal | {nom['rms_mm']:.4f} | {nom['bic']:.1f} | {found.nominal_p:.3g} |",
        f"| final | {fin['rms_mm']:.4f} | {fin['bic']:.1f} | {found.final_p:.3g} |",
        "",
    ]
    rec = d.get("record") or {}
    if rec.get("statement"):
        lines += [f"**Record kind: {d['record_kind'].replace('_', ' ')}** — {rec['statement']}.", ""]
        fc = rec.get("forcing_change") or {}
        if fc.get("verdict"):
            lines += [f"A change at t = {fc['t_s']:.3f} s: {fc['verdict']}.", ""]
    shown: set[str] = set()
    for k, e in enumerate(found.named):
        test = (
            f"2 Δlog L {e['lr']:.1f} against {e['lr_critical']:.1f} (χ² with {e.get('lr_dof', '?')} dof, "
            f"{e.get('trials', 1):.0f} trials), "
            if e.get("lr") is not None and e.get("lr_critical") is not None
            else ""
        )
        lines += [
            f"## {k + 1}. `{e['id']}`",
            "",
            e["explanation"],
            "",
            f"- where: plates {', '.join(map(str, e['plates']))}, axes {', '.join(e['axes'])}, "
            f"t {e['t_start']:.3f} – {e['t_end']:.3f} s"
            + (f", band {e['band_hz'][0]:.4f} – {e['band_hz'][1]:.4f} Hz" if e.get("band_hz") else ""),
            f"- evidence: {test}signature p {e['p_value']:.2g}, ΔBIC {e['delta_bic']:.1f}; RMS "
            f"{e['rms_before_mm']:.4f} → {e['rms_after_mm']:.4f} mm",
            "- parameters: " + "; ".join(f"{name} = {_fmt_param(v)}" for name, v in e["parameters"].items()),
        ]
        if close := [r for r in e.get("rivals", []) if r["id"] in e.get("not_told_from", [])]:
            lines.append(
                "- **not told apart** from "
                + ", ".join(
                    f"`{r['id']}` (ΔBIC margin {r['margin']:.1f}, AIC margin {r.get('aic_margin', r['margin']):.1f})"
                    for r in close
                )
                + f" on this record: the same residual fits both within 6 ({close[0]['footprint'][0]}), "
                "by ΔBIC or by AIC; the name is the better description, not an established one"
            )
        if fig := next((f for f in figures if f.endswith(f"_{e['id']}.png") and f not in shown), None):
            shown.add(fig)  # figures follow the search's acceptances: matched by the effect's id
            lines += ["", f"![{e['id']}]({fig})"]
        lines.append("")
    if found.minor:
        lines += ["## Minor findings", ""]
        for e in found.minor:
            r = e["relevance"]
            lines.append(
                f"- {_named_with_rivals(e)}: {r['residual_share']:.1%} of the residual on its series, "
                f"{r['size_vs_motion']:.2%} of the motion"
            )
        lines.append("")
    if d.get("nominal_physics"):
        lines += ["## The sensor's own physics (not missing)", ""]
        lines += [f"- `{x['id']}` on {_where(x)}: {x['reason']}" for x in d["nominal_physics"]]
        lines.append("")
    if d.get("dropped"):
        lines += ["## Dropped by the backward step", ""]
        lines += [f"- `{x['id']}`: {x['reason']}" for x in d["dropped"]]
        lines.append("")
    if found.unnamed:
        lines += ["## Structure outside the vocabulary (unnamed, modelled)", ""]
        for u in found.unnamed:
            lines += [
                f"- `{u['kind']}` on {_where(u)}: {u['explanation']}",
                f"  ΔBIC {u['delta_bic']:.1f}; residual RMS {u['rms_before_mm']:.4g} → "
                f"{u['rms_after_mm']:.4g} mm; "
                + "; ".join(
                    f"{name} = {_fmt_param(v) if isinstance(v, dict) else v}"
                    for name, v in u["parameters"].items()
                ),
            ]
        lines.append("")
    if found.unexplained:
        lines += ["## Unexplained structure", ""]
        for u in found.unexplained:
            band = f", near {0.5 * (u['band_hz'][0] + u['band_hz'][1]):.4f} Hz" if u.get("band_hz") else ""
            lines.append(
                f"- {u['description']}: {_where(u)}{band}, p = {u['p_value']:.2g} (test `{u['test']}`)"
            )
        lines.append("")
    if advice := found.advice():
        lines += ["## What to do next", ""] + [f"- {a}" for a in advice] + [""]
    if d["cannot_tell"]:
        lines += ["## Cannot tell", ""]
        lines += [f"- `{c['id']}`: {c['reason']}" for c in d["cannot_tell"]]
        lines.append("")
    if d.get("notes"):
        lines += ["## Notes", ""] + [f"- {n}" for n in d["notes"]] + [""]
    return "\n".join(lines)


def write_diagnosis_report(diag, d: dict, out_json: Path, outs, figures: bool = True) -> list[Path]:
    """Stage OUT.md and a figure per effect (OUT_<k>_<effect>.png) beside OUT.json in ``outs``
    (a `jaxdefl.io.output.Outputs`: they are committed together with OUT.json)."""
    out_json = Path(out_json)
    paths = []
    if figures:
        for k, a in enumerate(diag.accepted):
            final = out_json.with_name(f"{out_json.stem}_{k + 1}_{a.proposal.effect}.png")
            paths.append(outs.stage(final, lambda tmp, k=k: plot_effect(diag, k, tmp)))
    md = out_json.with_suffix(".md")
    outs.text(md, diagnosis_markdown(d, [p.name for p in paths]))
    return [md, *paths]
