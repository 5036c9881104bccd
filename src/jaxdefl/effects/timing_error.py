"""``timing_error``: the camera's clock against the reference's: stamps = t + offset + rate·t_rel."""

from __future__ import annotations

from ._entry import Bench, Entry, Param, Report


def inject(e, trel):
    return e.p("offset_s") + e.p("rate_ppm") * 1e-6 * trel


def from_diagnosis(r: Report) -> tuple[dict, tuple[int, ...]]:
    """The offset and/or rate fitted; one clock (no plates)."""
    return {k: r.p[k] for k in ("offset_s", "rate_ppm") if r.p.get(k) is not None}, ()


def draw(b) -> dict:
    """The benchmark's clock: late stamps of 2-10 ms, or a rate of 20-200 ppm sized to the target."""
    e = {"id": ENTRY.id, "plates": b.everyone, "axes": list(b.axes)}
    if b.rng.random() < 0.5:  # late timestamps (stamped on delivery): 2-10 ms
        return e | dict(kind="offset", parameters={"offset_s": float(b.rng.uniform(0.002, 0.010))})
    # a clock rate of 20-200 ppm, as small in that range as the noise target asks: over 15-20
    # minutes a rate above ~40 ppm puts the camera-LDS mismatch above the raw noise
    e |= dict(kind="rate", parameters={"rate_ppm": float(b.rng.choice([-1.0, 1.0])) * 20.0})
    return b.sized(e, "rate_ppm", (20.0, 200.0))


def _clock(base, e, t):
    """t_cam = t_true + offset + rate·(t_true − t_first)."""
    p = e["parameters"]
    return t + float(p.get("offset_s", 0.0)) + float(p.get("rate_ppm", 0.0)) * 1e-6 * (t - base.t_first)


ENTRY = Entry(
    id="timing_error",
    record_kinds=("forced_harmonic",),
    meaning="the camera's clock: stamps = t + offset + rate·t_rel",
    rank=7,
    structural=False,  # a clock's offset or rate: the measurement's
    needs_reference=True,
    level="timestamps",
    params=(Param("offset_s", "s", 0.0), Param("rate_ppm", "ppm", 0.0)),
    inject=inject,
    from_diagnosis=from_diagnosis,
    example={"offset_s": 0.01},
    draw=draw,
    scored=lambda kind: {"offset_s": True} if kind == "offset" else {"rate_ppm": True},
    bench=Bench(clock=_clock),
)
