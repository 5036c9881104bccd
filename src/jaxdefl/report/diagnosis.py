"""Diagnosis report: a before/after figure per located effect and a markdown explanation."""

from __future__ import annotations

import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

__all__ = ["plot_effect", "diagnosis_markdown", "write_diagnosis_report"]


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
    from ..diagnose._base import masked_periodogram

    return masked_periodogram(ctx, i, r)


def plot_effect(diag, k: int, path: Path) -> Path:
    """Figure for accepted effect ``k``: binned residual mean and RMS against time, and the
    residual spectrum, before and after the effect was added, on its most affected series."""
    a = diag.accepted[k]
    ctx = diag.ctx
    p = a.proposal
    # the series that gained most
    from ..diagnose._base import loglik

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


def diagnosis_markdown(d: dict, figures: list[str]) -> str:
    """The DIAG.json dict as a report a structural engineer can read."""
    inp, nom, fin = d["input"], d["nominal"], d["final"]
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
        "The nominal model is the thesis' harmonic (eq. 5.29) per plate and axis plus white noise; "
        "with a reference, the camera's z of a plate with an LDS is expected to move exactly as the LDS "
        "(only its offset is free). Effects are added one at a time when the Bayesian information "
        "criterion improves by more than 10 (ΔBIC < −10) and their signature test survives the "
        "multiple-testing correction; RMS is the likelihood-equivalent noise σ over the series an effect "
        "touches (the plain residual RMS for mean terms).",
        "",
        "| | RMS (mm) | BIC | whiteness p |",
        "|---|---|---|---|",
        f"| nominal | {nom['rms_mm']:.4f} | {nom['bic']:.1f} | {nom['whiteness_p']:.3g} |",
        f"| final | {fin['rms_mm']:.4f} | {fin['bic']:.1f} | {fin['whiteness_p']:.3g} |",
        "",
    ]
    rec = d.get("record") or {}
    if rec.get("statement"):
        lines += [f"**Record kind: {d['record_kind'].replace('_', ' ')}** — {rec['statement']}.", ""]
        fc = rec.get("forcing_change") or {}
        if fc.get("verdict"):
            lines += [f"A change at t = {fc['t_s']:.3f} s: {fc['verdict']}.", ""]
    if not d["effects"] and d["unexplained"]:
        lines += ["**No effect located**, but the residuals are not white: see *Unexplained structure*.", ""]
    elif not d["effects"]:
        lines += ["**No effect located**: the residuals are consistent with the nominal model.", ""]
    for k, e in enumerate(d["effects"]):
        if (e.get("relevance") or {}).get("minor"):
            continue
        lines += [
            f"## {k + 1}. `{e['id']}`",
            "",
            e["explanation"],
            "",
            f"- where: plates {', '.join(map(str, e['plates']))}, axes {', '.join(e['axes'])}, "
            f"t {e['t_start']:.3f} – {e['t_end']:.3f} s"
            + (f", band {e['band_hz'][0]:.4f} – {e['band_hz'][1]:.4f} Hz" if e.get("band_hz") else ""),
            f"- evidence: ΔBIC {e['delta_bic']:.1f}, signature p {e['p_value']:.2g}; RMS "
            f"{e['rms_before_mm']:.4f} → {e['rms_after_mm']:.4f} mm",
            "- parameters: " + "; ".join(f"{name} = {_fmt_param(v)}" for name, v in e["parameters"].items()),
        ]
        if k < len(figures):
            lines += ["", f"![{e['id']}]({figures[k]})"]
        lines.append("")
    minor = [e for e in d["effects"] if (e.get("relevance") or {}).get("minor")]
    if minor:
        lines += ["## Minor findings", ""]
        for e in minor:
            r = e["relevance"]
            lines.append(
                f"- `{e['id']}`: {r['residual_share']:.1%} of the residual on its series, "
                f"{r['size_vs_motion']:.2%} of the motion"
            )
        lines.append("")
    if d.get("dropped"):
        lines += ["## Dropped by the backward step", ""]
        lines += [f"- `{x['id']}`: {x['reason']}" for x in d["dropped"]]
        lines.append("")
    if d.get("unnamed"):
        lines += ["## Structure outside the vocabulary (unnamed, modelled)", ""]
        for u in d["unnamed"]:
            where = f"plates {', '.join(map(str, u['plates']))} ({', '.join(u['axes'])})"
            lines += [
                f"- `{u['kind']}` on {where}: {u['explanation']}",
                f"  ΔBIC {u['delta_bic']:.1f}; residual RMS {u['rms_before_mm']:.4g} → "
                f"{u['rms_after_mm']:.4g} mm; "
                + "; ".join(
                    f"{name} = {_fmt_param(v) if isinstance(v, dict) else v}"
                    for name, v in u["parameters"].items()
                ),
            ]
        lines.append("")
    if d["unexplained"]:
        lines += ["## Unexplained structure", ""]
        for u in d["unexplained"]:
            where = f"plates {', '.join(map(str, u['plates']))} ({', '.join(u['axes'])})"
            band = f", near {0.5 * (u['band_hz'][0] + u['band_hz'][1]):.4f} Hz" if u.get("band_hz") else ""
            lines.append(f"- {u['description']}: {where}{band}, p = {u['p_value']:.2g} (test `{u['test']}`)")
        lines.append("")
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
