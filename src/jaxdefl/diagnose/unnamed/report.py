"""The open world's report text: an accepted generic term (`UnnamedTerm`) located (plates, axes,
time span, band), its parameters with σ's, and its explanation for a structural engineer."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .._base import Context, State

__all__ = ["UnnamedTerm", "describe_term"]


@dataclass
class UnnamedTerm:
    """An accepted generic term.

    Attributes:
        kind: ``line``, ``envelope`` or ``trend``.
        series: indices into `Context.series`; means: {series index: new mean}.
        n_params: parameters added; parameters: {name: {"value", "sigma"}} (JSON-able).
        t_start, t_end: located span (s since t0); band_hz: [lo, hi] or None.
        delta_bic, rms_before_mm, rms_after_mm: evidence and the plain residual RMS of its series.
        explanation: one or two sentences for a structural engineer.
    """

    kind: str
    series: list[int]
    means: dict[int, np.ndarray]
    n_params: int
    parameters: dict
    t_start: float
    t_end: float
    band_hz: list[float] | None
    explanation: str
    delta_bic: float = math.nan
    rms_before_mm: float = math.nan
    rms_after_mm: float = math.nan
    detail: dict = field(default_factory=dict)
    # the fitted term itself (its mean change per series), for the search's backfitting
    change: dict = field(default_factory=dict, repr=False)
    candidate: object = field(default=None, repr=False)


def _median_sigma(values: dict, sigmas: dict) -> float | None:
    """σ of the series whose value is nearest the reported median (the typical series')."""
    if not sigmas:
        return None
    med = float(np.median(list(values.values())))
    i = min(values, key=lambda j: abs(values[j] - med))
    return sigmas.get(i)


def describe_term(ctx: Context, c, states: list[State], sig: dict) -> UnnamedTerm:
    """The report of candidate ``c`` (a `terms.Candidate`) on ``states``, its parameters' σ's
    ``sig`` (`terms.term_sigmas`)."""
    plates = sorted({ctx.series[i].plate for i in c.series})
    axes = sorted({ctx.series[i].axis for i in c.series})
    where = f"plate(s) {', '.join(map(str, plates))} ({', '.join(axes)})"
    # located span: where the term moves the model most (its mean change above 10 % of its peak)
    t_lo, t_hi = math.inf, -math.inf
    for i in c.series:
        d = np.abs(c.means[i] - states[i].mean)
        on = d >= 0.1 * d.max() if d.size and d.max() > 0 else np.ones(d.size, bool)
        t = ctx.series[i].t[on]
        if t.size:
            t_lo, t_hi = min(t_lo, float(t.min())), max(t_hi, float(t.max()))
    if not math.isfinite(t_lo):
        t_lo, t_hi = 0.0, ctx.duration_s
    par, band, text, detail = _TEXTS[c.kind](ctx, c, sig, where)
    return UnnamedTerm(c.kind, c.series, c.means, c.n_params, par, t_lo, t_hi, band, text, detail=detail)


def _line_text(ctx: Context, c, sig: dict, where: str) -> tuple[dict, list[float], str, dict]:
    """A line's parameters, band, explanation and per-series detail."""
    info = c.info
    f, lam = info["freq_hz"], info["decay_per_s"]
    amps = info["amplitudes_mm"]
    a_med = float(np.median(list(amps.values())))
    amp_sig = sig.get("amplitudes_mm", {})
    par = {
        "freq_hz": {"value": f, "sigma": sig.get("freq_hz")},
        "amplitude_mm": {"value": a_med, "sigma": _median_sigma(amps, amp_sig)},
    }
    half = max(1.0 / ctx.duration_s, lam / (2 * math.pi))
    text = (
        f"A periodic motion at {f:.4g} Hz ({f / ctx.f0_hz:.3f} × the loading frequency) of about "
        f"{a_med:.3g} mm on {where}"
    )
    if lam > 0:
        zeta = lam / (2 * math.pi * f)
        par["damping_ratio"] = {"value": zeta, "sigma": sig.get("damping_ratio")}
        par["decay_per_s"] = {"value": lam, "sigma": sig.get("decay_per_s")}
        text += (
            f", dying away with a damping ratio of {100 * zeta:.2g} % (a free vibration of a "
            "mode the loading does not drive)"
        )
    if info.get("common"):
        text += " (the same motion on every one of them: the camera or the whole scene vibrating)"
    text += ": structure no named effect explains."
    detail = {
        "amplitudes_mm": {ctx.series[i].key: {"value": a, "sigma": amp_sig.get(i)} for i, a in amps.items()}
    }
    return par, [f - half, f + half], text, detail


def _envelope_text(ctx: Context, c, sig: dict, where: str) -> tuple[dict, list[float], str, dict]:
    """An envelope's parameters, band and explanation."""
    info = c.info
    env = info["relative_envelope"]
    lo, hi = float(env.min()), float(env.max())
    par = {
        "form": info["form"],
        "envelope_min": {"value": lo, "sigma": sig.get("envelope_min")},
        "envelope_max": {"value": hi, "sigma": sig.get("envelope_max")},
    }
    if info["form"] == "spline":
        par["knots"] = int(info["knots"])
        shape = f"a smooth envelope ({info['knots']} interior knots)"
    else:
        lam = info["decay_per_s"]
        par["decay_per_s"] = {"value": lam, "sigma": sig.get("decay_per_s")}
        par["damping_ratio"] = {
            "value": lam / (2 * math.pi * ctx.f0_hz),
            "sigma": sig.get("damping_ratio"),
        }
        shape = (
            f"an exponential {'decay' if lam > 0 else 'growth'} (damping ratio "
            f"{100 * lam / (2 * math.pi * ctx.f0_hz):.2g} %)"
        )
    text = (
        f"The amplitude of the motion at {ctx.f0_hz:.4g} Hz changes during the record on {where}: "
        f"{shape}, from {lo:.2f} to {hi:.2f} times the nominal amplitude: structure no named "
        "effect explains (a load ramp, a free decay, a changing stiffness)."
    )
    df = 1.0 / ctx.duration_s
    band = [ctx.f0_hz - 2 * df * (1 + info.get("knots", 0)), ctx.f0_hz + 2 * df * (1 + info.get("knots", 0))]
    return par, band, text, {}


def _trend_text(ctx: Context, c, sig: dict, where: str) -> tuple[dict, list[float], str, dict]:
    """A trend's parameters, band, explanation and per-series detail."""
    info = c.info
    swing = info["swing_mm"]
    s_med = float(np.median(list(swing.values())))
    par = {
        "knots": None if info["knots"] is None else int(info["knots"]),
        "form": info["form"],
        "swing_mm": {"value": s_med, "sigma": _median_sigma(swing, sig.get("swing_mm", {}))},
    }
    shape = {
        "own": "each plate its own way",
        "shared": "one shape shared by the plates, a scale each",
        "common": "the same motion on every plate: the camera or the whole scene moving",
    }[info["form"]]
    if info["knots"] is None:
        shape += ", a step alone"
    if info["step_s"] is not None:
        par["step_at_s"] = {"value": float(info["step_s"]), "sigma": None}
        shape += f", with a step at {info['step_s']:.1f} s"
    text = (
        f"The measured position wanders slowly by about {s_med:.3g} mm (peak to peak) on {where} "
        f"({shape}): structure no named effect explains."
    )
    detail = {
        "swing_mm": {
            ctx.series[i].key: {"value": v, "sigma": sig.get("swing_mm", {}).get(i)} for i, v in swing.items()
        }
    }
    return par, [0.0, ((info["knots"] or 0) + 1) / ctx.duration_s], text, detail


_TEXTS = {"line": _line_text, "envelope": _envelope_text, "trend": _trend_text}
