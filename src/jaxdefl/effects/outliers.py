"""``outliers``: that fraction of the frames read the listed plates (default: all) N(0, scale²) off
(mixed pixels, segmentation failures)."""

from __future__ import annotations

import math

import numpy as np

from ._entry import Bench, Entry, Param, Report, positive
from ._range import columns


def inject(e, trel, n_plates, seed):
    """Each (frame, plate) drawn from a hash of its time: chunking moves nothing."""
    cols = columns(e, n_plates, off_plates=False)
    keys = np.round(trel * 1e6).astype(np.int64).astype(np.uint64)[:, None]
    salt = np.uint64((int(seed) * 0x9E3779B97F4A7C15) & 0xFFFFFFFFFFFFFFFF)
    keys = keys ^ (cols.astype(np.uint64)[None, :] << np.uint64(40)) ^ salt
    hit = _uniform(keys) < e.p("fraction")
    u1, u2 = _uniform(keys ^ np.uint64(0x5851F42D)), _uniform(keys ^ np.uint64(0x14057B7E))
    normal = np.sqrt(-2.0 * np.log1p(-u1)) * np.cos(2 * math.pi * u2)
    return cols, np.where(hit, e.p("scale_mm") * normal, 0.0)


def _uniform(keys: np.ndarray) -> np.ndarray:
    """Uniform [0, 1) numbers from uint64 keys (splitmix64): a counter-based random stream."""
    with np.errstate(over="ignore"):
        z = keys + np.uint64(0x9E3779B97F4A7C15)
        z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
        z = z ^ (z >> np.uint64(31))
    return (z >> np.uint64(11)).astype(np.float64) * 2.0**-53


def check(e, bad):
    if not 0 < e.p("fraction") < 1:
        raise bad("fraction", "a fraction of the frames in (0, 1)")
    positive("scale_mm", "a scale > 0 mm")(e, bad)


def from_diagnosis(r: Report) -> tuple[dict, tuple[int, ...]]:
    """The fraction, and the scale in range through the calibration's gains; on its plates."""
    scales = {k: abs(float(v)) for k, v in (r.detail.get("scales_mm") or {}).items()}
    return {"fraction": r.p["fraction"], "scale_mm": abs(r.per_range(scales, r.p["scale_mm"]))}, r.plates


def draw(b) -> dict:
    """The benchmark's outliers: 0.2-1 % of the samples of 1-3 plates at 4-12 σ."""
    rng = b.rng
    plates = sorted(rng.choice(b.everyone, size=int(rng.integers(1, 4)), replace=False).tolist())
    frac = b.loguniform(0.002, 0.01)
    sig = b.sigma_z(plates)
    scale = float(np.clip(max(b.target, 0.15) * sig / math.sqrt(frac), 4 * sig, 12 * sig))
    e = dict(
        kind=str(rng.choice(["gaussian", "sign"])),
        parameters={"fraction": frac, "scale_mm": round(scale, 4)},
        plates=plates,
        axes=["z"],
    )
    return e | {"id": ENTRY.id}


def _after_noise(base, e, pos, t_tab, extras):
    """A fraction of each plate's z samples (at least one) get an error N(0, s²) or ±s."""
    rng = np.random.default_rng([base.seed, 7002])
    p = e["parameters"]
    s = float(p["scale_mm"])
    count = 0
    for plate in e["plates"]:
        n = t_tab.size
        k = max(1, int(round(float(p["fraction"]) * n)))
        rows = rng.choice(n, size=k, replace=False)
        err = s * rng.standard_normal(k) if e["kind"] == "gaussian" else s * rng.choice([-1.0, 1.0], k)
        pos[rows, plate - 1, 2] += err
        count += k
    extras["outlier_count"] = count


def _strength(base, e):
    """RMS √ε s against each series' σ; S = n Σ (rms/σ)²."""
    p = e["parameters"]
    sig = base.sigma[np.ix_(np.asarray(e["plates"], int) - 1, ["xyz".index(a) for a in e["axes"]])]
    rms = math.sqrt(float(p["fraction"])) * float(p["scale_mm"])
    with np.errstate(divide="ignore"):
        ratio = rms / sig
    return float(np.sqrt(np.mean(ratio**2))), float(base.t.size * np.sum(ratio**2))


def _truth(base, e, p, out, t_tab, extras):
    """The realised fraction (the drawn one kept as ``fraction_nominal``)."""
    n_aff = t_tab.size * len(e["plates"])
    p["fraction_nominal"] = float(p["fraction"])
    p["fraction"] = float(extras.get("outlier_count", 0)) / n_aff


ENTRY = Entry(
    id="outliers",
    record_kinds=("forced_harmonic", "multi_tone"),
    meaning="that fraction of the frames read the plates N(0, scale²) off",
    rank=9,
    structural=False,  # a noise structure: the measurement's
    level="range",
    params=(Param("fraction", "of the frames"), Param("scale_mm", "mm")),
    inject=inject,
    check=check,
    from_diagnosis=from_diagnosis,
    example={"fraction": 0.01, "scale_mm": 8.0},
    draw=draw,
    scored=lambda kind: {"fraction": True, "scale_mm": True},
    bench=Bench(after_noise=_after_noise, strength=_strength, truth=_truth),
)
