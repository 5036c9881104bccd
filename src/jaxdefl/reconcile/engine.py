"""Recording against simulation: where they differ, what the diagnosis names, and whether the
simulation with the named physics comes back inside the null band.

1. The recording is diagnosed (`jaxdefl.diagnose.run_diagnosis`, with the camera facts of the
   simulation config): its f0, and the effects it names with their fitted parameters.
2. The simulation a user would set up (`Twin`: the recording's frame times, plates and fitted
   harmonics, white noise at each series' level and, with a calibration, the extraction's own
   outliers) is rendered ``n_sims`` times and compared with the recording on every metric
   (`jaxdefl.reconcile.metrics`, `compare`): *before*.
3. The null band: ``n_null`` further simulations of the same model, each compared as if it were
   the recording; ``null_95`` is the 95th percentile of those distances, ``null_family`` their
   1 − 0.05/9 percentile (the band the verdicts use: a recording is judged on 9 metrics at once,
   `metrics.FAMILY`).
4. The named effects that the simulator can inject become ``[[effect]]`` specs (range effects'
   sizes, lines' and harmonics' mid-span amplitudes and phases refitted to the recording as the
   twin renders them); the simulation is rendered again with them and compared again: *after*.

A metric is reconciled when *before* lies outside its family band and *after* inside it.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from .._errors import ConfigError
from .._numerics import harmonic_design
from .._signals import check_interrupt
from ..effects import INJECTABLE, Report, drift, extra_periodic, harmonic_distortion, level_jump
from ..effects import REGISTRY as VOCABULARY
from ..settings import ReconcileSettings
from ..simulate.injection import EffectSpec, make_spec
from .chain import apply_chain_null
from .metrics import METRICS, TableStats, distance, null_95, null_family, table_stats
from .twin import Twin, line_key

__all__ = [
    "Reconciliation",
    "compare",
    "effect_tables_toml",
    "keep_shown",
    "reconcile",
    "refine_motion_lines",
    "specs_from_diagnosis",
]


@dataclass
class Reconciliation:
    levels: list[dict]
    effects: list[dict]
    specs: tuple[EffectSpec, ...]
    diagnosis: dict
    f0_hz: float
    stats: dict[str, TableStats] = field(default_factory=dict)

    def verdict(self, row: dict) -> str:
        """*before* against the family band of the simulation as set up (`metrics.null_family`),
        *after* against the family band of the reconciled simulation (``after_family``: the
        same percentile of the distances of its own repeated renders); rows written before those
        existed are read against their 95 % band."""
        before, after = row["before"], row["after"]
        null = row.get("null_family", row["null_95"])
        null_after = row.get("after_family", null)
        if not all(np.isfinite([before, after, null, null_after])):
            return "not measured"
        if before <= null:
            return "agreed already"
        return "reconciled" if after <= null_after else "still apart"


def _value(p) -> float | str | None:
    return p.get("value") if isinstance(p, dict) else p


def _same_injection(a: tuple, b: tuple) -> bool:
    """Whether two reports (id, plates, locator, σ) are one injection: a range effect is one
    error of the pixels' ranges and a motion or clock effect one motion of the beam or one clock,
    whatever axes the diagnosis saw it on; they differ only in what locates them (a jump's time,
    a line's frequency, a harmonic's order, a mode's number), and two estimates of one locator
    from different axes agree within their errors (3 σ, or half the locator's resolution). Reports
    that stay apart are still sized together (`refine_range_effects`)."""
    (eid, plates, x, sx), (eid2, plates2, y, sy) = a, b
    if (eid, plates) != (eid2, plates2):
        return False
    if x is None or y is None:
        return x is None and y is None
    step = VOCABULARY[eid].locator[1]
    return abs(x - y) <= max(3.0 * math.hypot(sx, sy), 0.5 * step)


def _report(eid: str, params: dict, plates: tuple, sigmas: dict) -> tuple:
    """(id, plates, locator, its σ) of a report (`_same_injection`)."""
    name = (VOCABULARY[eid].locator or (None, 0.0))[0]
    if name is None or name not in params:
        return (eid, plates, None, 0.0)
    sigma = sigmas.get(name)
    sigma = float(sigma) if sigma is not None and math.isfinite(float(sigma)) else 0.0
    return (eid, plates, float(params[name]), sigma)


def specs_from_diagnosis(
    effects: list[dict], duration_s: float, calibration=None, n_plates: int = 0
) -> list[tuple[EffectSpec | None, str]]:
    """Each diagnosed effect as an ``[[effect]]`` spec, or None and the reason it is not one.

    Times in DIAG.json are relative to the table's first stamp, as the simulator's t_rel; the
    linear modulations there are about the record's middle (``t_ref_s`` = duration / 2); a
    polynomial drift becomes a warm-up with τ = the record's length, to be refitted. Range
    effects are sized in range through the calibration's gains; one seen on at least half of the
    ``n_plates`` plates is taken for the whole image (a camera effect), else for its plates.
    A range effect is one error of the pixels' ranges, seen on every axis of a plate (the centroid
    moves along its line of sight), and a motion effect one motion of the beam: the diagnosis
    may report either once per axis, and it is simulated once (the first report, z first: a
    motion's size is the mid-span's; the others say so, `_same_injection`)."""
    out: list[tuple[EffectSpec | None, str] | None] = [None] * len(effects)
    ranges: list = []
    # z first: a motion effect's amplitude is reported at mid-span, as z sees it
    order = sorted(range(len(effects)), key=lambda j: "z" not in effects[j].get("axes", ["z"]))
    for j in order:
        out[j] = _spec_of(effects[j], duration_s, calibration, n_plates, ranges)
    return out


def _spec_of(e: dict, duration_s: float, calibration, n_plates: int, ranges: list):
    """One diagnosed effect as (spec or None, why): its vocabulary entry's ``from_diagnosis``;
    ``ranges``: the injections made so far."""
    eid = e["id"]
    if eid not in INJECTABLE:
        return None, f"{eid} is not one of the effects the simulator injects ({', '.join(INJECTABLE)})"
    report = Report.of(e, duration_s, calibration, n_plates)
    params, plates = VOCABULARY[eid].from_diagnosis(report)
    if any(v is None or not math.isfinite(float(v)) for v in params.values()):
        return None, f"{eid}: a parameter was not estimated"
    sigmas = {k: v.get("sigma") for k, v in e.get("parameters", {}).items() if isinstance(v, dict)}
    key = _report(eid, params, plates, sigmas)
    if any(_same_injection(key, k) for k in ranges):
        return None, f"the same {eid} as one above, seen on other axes: simulated once"
    ranges.append(key)
    try:
        return make_spec(eid, _spec_values(eid, params), plates), "simulated"
    except ConfigError as err:
        return None, f"{eid}: fitted parameters outside what can be simulated ({err})"


def _spec_values(eid: str, params: dict) -> dict:
    """Numbers as floats; a plate number as an int (what `make_spec` takes)."""
    entry = VOCABULARY[eid]
    return {
        k: int(v) if (p := entry.param(k)) is not None and p.plate else float(v) for k, v in params.items()
    }


DRIFT, LINE = drift.ENTRY.id, extra_periodic.ENTRY.id
_SIZED = (DRIFT, level_jump.ENTRY.id)  # the range effects whose size the recording refits


def _range_columns(spec: EffectSpec, t: np.ndarray, tau: float | None = None) -> np.ndarray:
    if spec.id == DRIFT:
        return np.exp(-t / (spec.p("tau_s") if tau is None else tau))
    return (t >= spec.p("t_jump_s")).astype(float)


def _nuisance_free(twin: Twin, df: pd.DataFrame, gain_of) -> list:
    """Per series the range effects reach (its calibrated gain ≥ 0.05): (plate, t, its residual
    and the projector of its offset and harmonic, the gain, all in units of its noise, axis)."""
    out = []
    for s in twin.series:
        g = gain_of(s.plate, s.axis)
        if abs(g) < 0.05 or s.sigma <= 0:
            continue
        y = df[s.axis].to_numpy()[s.rows]
        q = np.linalg.qr(harmonic_design(twin.omega * s.t))[0]
        out.append((s.plate, s.t, (y - q @ (q.T @ y)) / s.sigma, q, g / s.sigma, s.axis))
    return out


def refine_range_effects(twin: Twin, df: pd.DataFrame, specs: tuple[EffectSpec, ...], calibration):
    """Fit a drift's or a jump's range size (and a drift's time constant, on a grid from a third
    to three times the diagnosed one) to the recording as the frame simulator would show them:
    one range effect seen through every series' calibrated gain (without a calibration: z, gain
    1), the series' offsets and harmonics as nuisances, weighted by their noise. The diagnosis
    fits a free size per series; this is the physics the simulator injects. Several range
    effects then have their sizes fitted together (`_joint_range_sizes`)."""

    def gain_of(plate: int, axis: str) -> float:
        if calibration is None:  # as the twin injects without one: z alone, gain 1
            return float(axis == "z")
        return calibration.gain_of(plate, axis)

    series = _nuisance_free(twin, df, gain_of)
    out = []
    for spec in specs:
        parts = [x for x in series if not spec.plates or x[0] in spec.plates]
        if spec.id not in _SIZED or not parts:
            out.append(spec)
            continue

        def fit(tau, spec=spec, parts=parts):
            num = den = 0.0
            for _, t, r, q, g, _ in parts:
                u = g * _range_columns(spec, t, tau)
                u = u - q @ (q.T @ u)
                num += float(u @ r)
                den += float(u @ u)
            return (num / den if den > 0 else 0.0), (num * num / den if den > 0 else 0.0)

        params = dict(spec.parameters)
        if spec.id == DRIFT:
            taus = spec.p("tau_s") * np.geomspace(0.33, 3.0, 61)
            gains = [fit(tau)[1] for tau in taus]
            tau = float(taus[int(np.argmax(gains))])
            params["tau_s"] = tau
            params["amplitude_mm"] = fit(tau)[0]
        else:
            params["size_mm"] = fit(None)[0]
        out.append(make_spec(spec.id, params, spec.plates))
    return _joint_range_sizes(series, tuple(out))


def _joint_range_sizes(series: list, specs: tuple[EffectSpec, ...]):
    """The range effects' sizes fitted together (time constants kept): every pixel reads their
    sum, so two reports of one step (a jump seen on z and, a little later, on x) share it
    instead of each taking all of it (injected side by side they doubled the step)."""
    idx = [j for j, sp in enumerate(specs) if sp.id in _SIZED]
    if len(idx) < 2:
        return specs
    ata = np.zeros((len(idx), len(idx)))
    atb = np.zeros(len(idx))
    for plate, t, r, q, g, _ in series:
        cols = [k for k, j in enumerate(idx) if not specs[j].plates or plate in specs[j].plates]
        if not cols:
            continue
        u = np.zeros((t.size, len(idx)))
        for k in cols:
            u[:, k] = g * _range_columns(specs[idx[k]], t)
        u = u - q @ (q.T @ u)
        ata += u.T @ u
        atb += u.T @ r
    size = np.linalg.lstsq(ata, atb, rcond=None)[0]
    out = list(specs)
    for k, j in enumerate(idx):
        name = "amplitude_mm" if specs[j].id == DRIFT else "size_mm"
        out[j] = make_spec(specs[j].id, {**dict(specs[j].parameters), name: float(size[k])}, specs[j].plates)
    return tuple(out)


_LINES = (LINE, harmonic_distortion.ENTRY.id)


def _line_columns(twin: Twin, spec: EffectSpec, t: np.ndarray) -> np.ndarray:
    """(t, 2) the cos and sin whose combination p cos + q sin is the spec's motion term as the
    twin renders it (`Twin.simulate`): an extra line at its frequency, a harmonic at its order
    of the simulator's phase θ."""
    if spec.id == LINE:
        arg = 2 * math.pi * spec.p("freq_hz") * t
    else:
        arg = spec.p("order") * (twin.omega * t - twin.phi_ref + math.pi / 2)
    return np.stack([np.cos(arg), np.sin(arg)], axis=1)


def refine_motion_lines(twin: Twin, df: pd.DataFrame, specs: tuple[EffectSpec, ...]):
    """Fit an extra line's or a harmonic's mid-span amplitude and phase (its frequency or order
    kept) to the recording as the twin renders it: one motion of the beam seen on every series
    through its transfer (`Twin.transfer`), the series' offsets and harmonics as nuisances,
    weighted by their noise. The diagnosis reports a line's median amplitude on the axis that
    carries it, and no phase the twin can use; this is the motion the simulator injects.

    The amplitude is fitted per axis: z's (else the axis with most evidence) sizes the spec, and
    the others' sizes against it become the twin's gains for it (`Twin.line_gain`): a ToF
    camera's range channel (z) passes a motion faster than the load less than the image's x and
    y do (measured at 5.5 Hz on SR4000 frames: z 0.75-0.9 of x and y, relative to f0), which the
    transfer at f0 cannot say. ``twin.line_gain`` is set in place."""
    series = _nuisance_free(twin, df, lambda plate, axis: twin.transfer.get((plate, axis), 0.0))
    axes = {a: [x for x in series if x[5] == a] for a in ("z", "x", "y")}
    out = []
    for spec in specs:
        if spec.id not in _LINES or not series:
            out.append(spec)
            continue
        fits = {}
        for axis, parts in axes.items():
            ata, atb = np.zeros((2, 2)), np.zeros(2)
            for _, t, r, q, g, _ in parts:
                u = g * _line_columns(twin, spec, t)
                u = u - q @ (q.T @ u)
                ata += u.T @ u
                atb += u.T @ r
            if parts and np.linalg.cond(ata) < 1e8:
                coef = np.linalg.solve(ata, atb)
                fits[axis] = (coef, float(coef @ ata @ coef))  # its amplitudes and their evidence
        if not fits:
            out.append(spec)
            continue
        main = "z" if "z" in fits else max(fits, key=lambda a: fits[a][1])
        p, qs = fits[main][0]
        size = math.hypot(p, qs)
        twin.line_gain[line_key(spec)] = {
            a: (float(np.hypot(*c)) / size if size > 0 else 1.0) for a, (c, _) in fits.items()
        }
        params = dict(spec.parameters)
        params["amplitude_mm"] = float(math.hypot(p, qs))
        # a cos(2πft + ψ) = a cos ψ cos − a sin ψ sin; a cos(kθ − ψ) = a cos ψ cos + a sin ψ sin
        params["phase_rad"] = float(math.atan2(-qs if spec.id == LINE else qs, p))
        out.append(make_spec(spec.id, params, spec.plates))
    return tuple(out)


_NOT_SHOWN = (
    "{} changes nothing in the trajectory simulation of this recording (it cannot render it here): "
    "not simulated, so 'after' would not test it"
)


def keep_shown(twin: Twin, mapped: list, seed: int = 0) -> list[tuple[EffectSpec | None, str]]:
    """``mapped`` (spec or None, why) with None and the reason where the twin's output does not
    change by the spec: `simulated` means the simulation shows the effect, so what the twin
    cannot render (a mode without the plates' places along the span, one plate's clipping) is
    said, not claimed."""
    return [
        (spec, why) if spec is None or twin.shows(spec, seed) else (None, _NOT_SHOWN.format(spec.id))
        for spec, why in mapped
    ]


def _median_distance(r: TableStats, sims: list[TableStats], metric: str) -> float:
    d = [distance(r, s, metric) for s in sims]
    d = [x for x in d if np.isfinite(x)]
    return float(np.median(d)) if d else float("nan")


def compare(
    twin: Twin,
    df: pd.DataFrame,
    specs: tuple[EffectSpec, ...] = (),
    n_sims: int = 4,
    n_null: int = 20,
    seed: int = 0,
    calibration=None,
    say: Callable[[str], None] = lambda _msg: None,
) -> tuple[list[dict], dict[str, TableStats]]:
    """The trajectories' and estimates' rows of reconcile.json: each metric's distance of the
    recording ``df`` from ``n_sims`` renders of ``twin`` without (*before*) and with ``specs``
    (*after*), its null band from ``n_null`` further renders (`null_95`, `null_family`), and
    the reconciled simulation's own family band from ``n_null`` renders with ``specs``
    (``after_family``); and the statistics of the recording, the first nominal render and the
    first reconciled one.

    The band that *after* is read against is the reconciled simulation's: a line or a
    modulation makes its carrier statistic vary more between renders than the noise alone (the
    periodogram's peak is then the line's, whose power scatters with its noise), so a recording
    of the reconciled model itself would lie outside the nominal model's band more often than
    the family level allows. Without specs it is the nominal band."""
    f0 = twin.f0_hz
    rec = table_stats(df, f0)
    nominal, fixed, null, null_fixed = [], [], [], []
    for m in range(n_sims):
        check_interrupt()
        nominal.append(table_stats(twin.simulate((), seed=seed + 1 + m), f0))
        fixed.append(table_stats(twin.simulate(specs, seed=seed + 1 + m), f0) if specs else nominal[-1])
    say("null band from repeated simulation")
    for j in range(n_null):
        check_interrupt()
        null.append(table_stats(twin.simulate((), seed=seed + 1000 + j), f0))
        if specs:  # the reconciled simulation's own band, on the same seeds
            null_fixed.append(table_stats(twin.simulate(specs, seed=seed + 1000 + j), f0))
    levels = []
    for metric, level in METRICS.items():
        distances = [_median_distance(p, nominal, metric) for p in null]
        band, how = null_95(distances)
        family = null_family(distances)
        after_family = (
            null_family([_median_distance(p, fixed, metric) for p in null_fixed]) if specs else family
        )
        if metric == "frame_common" and calibration is not None:
            # the simulator's share was measured on a short clip: its error widens the band
            band = math.hypot(band, 1.96 * calibration.frame_common_se)
            family = math.hypot(family, 1.96 * calibration.frame_common_se)
            after_family = math.hypot(after_family, 1.96 * calibration.frame_common_se)
        levels.append(
            dict(
                level=level,
                metric=metric,
                before=_median_distance(rec, nominal, metric),
                after=_median_distance(rec, fixed, metric),
                null_95=band,
                null_family=family,
                after_family=after_family,
                null_method=how,
            )
        )
    return levels, {"recording": rec, "nominal": nominal[0], "reconciled": fixed[0]}


def reconcile(
    df: pd.DataFrame,
    reference: pd.DataFrame | None = None,
    settings: ReconcileSettings | None = None,
    source: str = "<table>",
    on_step: Callable[[str], None] | None = None,
    calibration=None,
    chain=None,
) -> Reconciliation:
    """Compare a validated one-segment trajectory table with its simulation, before and after the
    diagnosed effects are added to the simulation. ``settings`` (`ReconcileSettings`; default:
    its defaults): the simulations' counts and seed, what the diagnosis knows of the camera.
    ``calibration`` (`calibrate`): what the frame simulator and the extraction make of the sensor
    (frame-common noise, range gains). ``chain`` (`chain.chain_null`): the twins' null; a named
    effect within it is the sensor's own physics, not simulated (``nominal_physics``)."""
    from ..diagnose import run_diagnosis

    say = on_step or (lambda _msg: None)
    say("diagnosing the recording")
    settings = settings if settings is not None else ReconcileSettings()
    n_sims, n_null, seed = settings.n_sims, settings.n_null, settings.seed
    diag = run_diagnosis(df, reference, settings.diagnosis, source=source).to_json()
    if chain is not None:
        diag = apply_chain_null(diag, chain, float(df["t"].max() - df["t"].min()))
    f0s = [s["f0_hz"] for s in diag["nominal"]["series"] if s["axis"] == "z" and np.isfinite(s["f0_hz"])]
    f0 = float(np.median(f0s)) if f0s else float(np.median([s["f0_hz"] for s in diag["nominal"]["series"]]))
    duration = float(df["t"].max() - df["t"].min())
    n_plates = int(df["plate"].nunique())
    mapped = specs_from_diagnosis(diag["effects"], duration, calibration, n_plates)
    specs = tuple(s for s, _ in mapped if s is not None)

    say("simulating the experiment")
    twin = Twin(df, f0, calibration)
    specs = refine_motion_lines(twin, df, refine_range_effects(twin, df, specs, calibration))
    twin.noise_without_lines(
        [s.p("freq_hz") if s.id == LINE else s.p("order") * f0 for s in specs if s.id in _LINES]
    )
    refined = iter(specs)
    mapped = [(next(refined) if spec is not None else None, why) for spec, why in mapped]
    mapped = keep_shown(twin, mapped, seed)
    specs = tuple(spec for spec, _ in mapped if spec is not None)
    levels, stats = compare(twin, df, specs, n_sims, n_null, seed, calibration, say)
    effects = []
    for e, (spec, why) in zip(diag["effects"], mapped, strict=True):
        effects.append(
            dict(
                id=e["id"],
                parameters={k: _value(v) for k, v in e["parameters"].items()},
                plates=e.get("plates", []),
                axes=e.get("axes", []),
                delta_bic=e.get("delta_bic"),
                lr=e.get("lr"),
                null_lr_95=e.get("null_lr_95"),
                simulated=spec is not None,
                injected=spec.to_dict() if spec is not None else None,
                note=why,
                explanation=e.get("explanation", ""),
            )
        )
    return Reconciliation(levels, effects, specs, diag, f0, stats)


def effect_tables_toml(specs: tuple[EffectSpec, ...]) -> str:
    """``[[effect]]`` tables in TOML (numbers with full precision)."""
    lines = []
    for s in specs:
        lines.append("[[effect]]")
        lines.append(f'id = "{s.id}"')
        for k, v in s.parameters:
            lines.append(f"{k} = {float(v)!r}")
        if s.plates:
            lines.append(f"plates = [{', '.join(str(p) for p in s.plates)}]")
        lines.append("")
    return "\n".join(lines)
