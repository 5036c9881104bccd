"""``heteroscedastic_noise``: a noise level that depends on the motion's phase or changes over the
record. A measurement effect: the z noise of the listed plates (default: all) is scaled by
1 + m·cos(arg − ψ) + r·(t_rel − t_ref), arg each plate's motion angle (0 at the peak of its z),
the diagnosis' model σ_i = σ0 (1 + θ·x_i) of either kind."""

from __future__ import annotations

import numpy as np

from ._entry import Bench, Entry, Param, Reading, Report, bench_plates, non_negative

MODULATION_RANGE = (0.15, 0.4)  # the benchmark's modulation m


def factor(e, t_rel: np.ndarray, arg: np.ndarray | None) -> np.ndarray:
    """(frame, plate) the noise level's factor (at least 0) at ``t_rel`` and motion angles ``arg``
    ((frame, plate); needed only for a modulation with the motion's phase)."""
    t_rel = np.asarray(t_rel, np.float64)
    f = 1.0 + e.p("rate_per_s") * (t_rel - e.p("t_ref_s"))[:, None]
    if e.p("modulation"):
        if arg is None:
            raise ValueError(f"{e.id}: the motion's phase is needed for a modulation with it")
        f = f + e.p("modulation") * np.cos(np.asarray(arg, np.float64) - e.p("phase_rad"))
    return np.maximum(f, 0.0)


def inject(e, r: Reading) -> None:
    cols = r.columns(e.plates)
    arg = None if r.arg is None else np.asarray(r.arg)[:, cols]
    r.noise[:, cols, 2] *= factor(e, r.t_rel, arg)


def check(e, bad):
    non_negative("modulation", "a modulation >= 0 (ψ holds its sign)")(e, bad)
    if not e.p("modulation") < 1:
        raise bad("modulation", "a modulation < 1 (the noise level stays > 0)")
    if e.p("modulation") == 0 and e.p("rate_per_s") == 0:
        raise bad("modulation", "a modulation or a rate_per_s != 0")


def from_diagnosis(r: Report) -> tuple[dict, tuple[int, ...]]:
    """Kind "phase": the modulation and its phase after the motion's peak; kind "time": the
    modulation over the record's half (m at its ends, about its middle) as a rate about the
    middle. On its plates."""
    m = float(r.p["modulation"])
    if r.kind == "time":
        half = 0.5 * r.duration_s
        return {"rate_per_s": m / half, "t_ref_s": half}, r.plates
    return {"modulation": abs(m), "phase_rad": float(r.p.get("phase_rad") or 0.0)}, r.plates


def draw(b) -> dict:
    """The benchmark's noise level: with the motion's phase or over the record, m 0.15-0.4 raised
    (up to the range's top) until the likelihood signal is enough."""
    rng = b.rng
    plates = b.everyone if rng.random() < 0.5 else b.adjacent(b.n_plates, int(rng.integers(1, 4)))
    kind = str(rng.choice(["phase", "time"]))
    e = dict(
        id=ENTRY.id,
        kind=kind,
        parameters={"modulation": round(float(rng.uniform(*MODULATION_RANGE)), 4)}
        | ({"phase_rad": b.psi} if kind == "phase" else {}),
        plates=plates,
        axes=["z"],
    )
    for _ in range(8):  # raise m (up to the range's top) until the signal is enough
        _, s = b.measure(e)
        if s >= b.signal_min or e["parameters"]["modulation"] >= MODULATION_RANGE[1]:
            break
        e["parameters"]["modulation"] = min(MODULATION_RANGE[1], e["parameters"]["modulation"] * 1.2)
    return e


def _u(base, e, t_tab: np.ndarray) -> np.ndarray:
    """The benchmark's u: cos(ω t_rel − φ − ψ) (kind "phase"), or the time from the middle over
    the half record (kind "time")."""
    if e["kind"] == "phase":
        trel = t_tab - t_tab[0]
        return np.cos(base.omega * trel - base.phase - float(e["parameters"]["phase_rad"]))
    mid = 0.5 * (t_tab[0] + t_tab[-1])
    return (t_tab - mid) / (0.5 * (t_tab[-1] - t_tab[0]))


def _noise_scale(base, e, t_tab, scale):
    """σ_i = σ0 (1 + m u_i) on z of its plates."""
    scale[:, bench_plates(e), 2] = 1.0 + float(e["parameters"]["modulation"]) * _u(base, e, t_tab)[:, None]


def _strength(base, e):
    """(m, S = 2 n Var[log(1 + m u)] × the series touched): the likelihood signal of a scale."""
    m = float(e["parameters"]["modulation"])
    v = np.log1p(m * _u(base, e, base.t))
    return m, float(2.0 * base.t.size * np.var(v) * (len(e["plates"]) * len(e["axes"])))


ENTRY = Entry(
    id="heteroscedastic_noise",
    record_kinds=("forced_harmonic",),
    meaning="noise level that depends on the motion's phase or changes over the record",
    rank=10,
    structural=False,  # a noise structure: the measurement's
    level="measurement",
    params=(
        Param("modulation", "relative, the noise level's swing with the motion's phase", 0.0),
        Param("phase_rad", "rad after the peak of the motion, where the noise is largest", 0.0),
        Param("rate_per_s", "1/s, the noise level's relative change per second", 0.0),
        Param("t_ref_s", "s after the recording start, where the rate's term is 0", 0.0),
    ),
    inject=inject,
    check=check,
    from_diagnosis=from_diagnosis,
    plated=True,
    example={"modulation": 0.4, "phase_rad": 0.8},
    draw=draw,
    # growing noise has a sign; with the motion's phase, ψ holds the sign
    scored=lambda kind: {"modulation": kind == "time"},
    bench=Bench(noise_scale=_noise_scale, strength=_strength),
)
