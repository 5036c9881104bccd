"""``quantization``: depth read in steps (a structured-light camera's disparity lattice, a
logger's ADC): each reading is the mean of ``pixels`` readings rounded to the lattice
``offset_mm`` + k·``step_mm`` after their noise (`jaxdefl._lattice.quantised_readings`, which
the concealed benchmark renders too). A measurement effect: the readings of z, last (after the
noise's other effects)."""

from __future__ import annotations

import math

import numpy as np

from .._lattice import dithered_round_var, quantised_readings, smoothed_staircase
from ._entry import Bench, Entry, Param, Reading, Report

# the benchmark's pixels averaged per reading (log-uniform) and their noise before rounding σ_d / q
PIXELS_RANGE = (20.0, 200.0)
DITHER_RATIO_RANGE = (0.12, 0.25)


def inject(e, r: Reading) -> None:
    """Plate by plate, z rounded with its noise: the reading's noise σ is split into the pixels'
    part before the rounding and the rest after it (`quantised_readings`); σ_d (``dither_mm``)
    defaults to σ√P (the whole noise before the rounding), P (``pixels``) to `_pixels`. With
    ``rounded_noise_share`` λ (and no ``pixels``), σ is the reading's whole noise, the rounding's
    part included: the pixels' rounded mean spreads by q² v̄/P ≈ λσ² about its staircase and the
    noise drawn is scaled to leave σ² in all (as the diagnosis' noise model has it). σ is the
    reading's (its median over the frames), or the drawn noise's RMS where the reading does not
    say."""
    given = dict(e.parameters)
    q, o = e.p("step_mm"), e.p("offset_mm")
    salt = int(round(abs(float(r.t_rel[0])) * 1e3)) if r.t_rel.size else 0  # a block's own stream
    for col in r.columns(e.plates):
        noise = r.noise[:, col, 2]
        sig_f = r.noise_sigma(col, 2)
        if sig_f is None:
            sig_f = np.full(noise.shape, math.sqrt(float(np.mean(noise * noise))) if noise.size else 0.0)
        sigma = float(np.median(sig_f)) if sig_f.size else 0.0
        n_px = _pixels(e, sigma)
        dither = e.p("dither_mm") if "dither_mm" in given else sigma * math.sqrt(n_px)
        with np.errstate(divide="ignore", invalid="ignore"):
            eps = np.where(sig_f > 0, noise / sig_f, 0.0)
        if "rounded_noise_share" in given and "pixels" not in given and sigma > 0:
            # the noise drawn: σ² less what the pixels' rounded mean adds, q² v̄/P (about λσ²),
            # over the σ_d²/P of it that the pixels' mean takes from the noise drawn
            added = (q * q * _mean_rounded_var(e) - dither * dither) / n_px
            keep = math.sqrt(max(1.0 - added / (sigma * sigma), 0.0))
            noise, sig_f = noise * keep, sig_f * keep
        rng = np.random.default_rng([int(r.seed), 7005, int(r.plates[col]), salt])
        z = r.xyz[:, col, 2]
        r.xyz[:, col, 2] = quantised_readings(z, noise, sig_f, eps, q, o, n_px, dither, rng)
        r.noise[:, col, 2] = 0.0


PIXELS_MAX = 100  # the most readings a centroid averages here (its rounding noise ≤ q²/400 then)


def _pixels(e, sigma: float) -> int:
    """P: ``pixels`` when given; else the fewest readings whose mean noise σ_d/√P fits in the
    reading's σ (in its (1 − λ)σ² with ``rounded_noise_share`` λ), and with λ as many as leave
    the rounding λ of the noise's variance, q² v̄/P = λ σ² (v̄ `_mean_rounded_var`, P the nearest
    whole count; λ = 0: `PIXELS_MAX`); at most `PIXELS_MAX` (a step
    too small for λσ² leaves the rounding less, a dither too large for the rest is the whole
    noise before the rounding)."""
    given = dict(e.parameters)
    if "pixels" in given:
        return int(round(e.p("pixels")))
    if "dither_mm" not in given or not sigma > 0:
        return 1
    q, dither = e.p("step_mm"), e.p("dither_mm")
    share = e.p("rounded_noise_share") if "rounded_noise_share" in given else 0.0
    rest = sigma * math.sqrt(max(1.0 - share, 1e-12))
    fewest = min(max(1, math.ceil((dither / rest) ** 2 - 1e-9)), PIXELS_MAX)
    if "rounded_noise_share" not in given:
        return fewest
    want = PIXELS_MAX if share <= 0 else round(q * q * _mean_rounded_var(e) / (share * sigma * sigma))
    return int(min(max(want, fewest), PIXELS_MAX))


def _mean_rounded_var(e) -> float:
    """v̄: the variance of one reading rounded after a noise ``dither_mm`` (steps², over a step's
    places, `dithered_round_var`)."""
    return float(np.mean(dithered_round_var(np.arange(64) / 64.0, e.p("dither_mm") / e.p("step_mm"))))


def check(e, bad):
    if not e.p("step_mm") > 0:
        raise bad("step_mm", "a step > 0 mm")
    given = dict(e.parameters)
    if "pixels" in given and not (e.p("pixels") >= 1 and float(e.p("pixels")).is_integer()):
        raise bad("pixels", "a whole count >= 1")
    if "dither_mm" in given and not e.p("dither_mm") >= 0:
        raise bad("dither_mm", "a noise >= 0 mm")
    if "rounded_noise_share" in given and not 0 <= e.p("rounded_noise_share") <= 1:
        raise bad("rounded_noise_share", "a share of the noise's variance in [0, 1]")


def from_diagnosis(r: Report) -> tuple[dict, tuple[int, ...]]:
    """The step, its levels, the noise before the rounding and the rounding's share of the noise
    as reported (the pixels that leave it that share, `_pixels`); on its plates, or every plate
    when seen on at least half of them (one camera, one lattice)."""
    p = r.p
    out = {"step_mm": p["step_mm"], "offset_mm": p.get("offset_mm") or 0.0}
    for name in ("dither_mm", "rounded_noise_share"):
        if p.get(name) is not None:
            out[name] = p[name]
    return out, () if r.whole else r.plates


def draw(b) -> dict:
    """The benchmark's lattice (structured light only): P pixels of noise σ_d before the rounding,
    the step the smallest that reaches the target (`Draw.quantization_step`), a random offset."""
    if b.spec.sensor != "structured_light":
        raise ValueError("quantization: only for structured-light recordings (spec.sensor)")
    rng = b.rng
    pixels = int(round(b.loguniform(*PIXELS_RANGE)))
    ratio = float(rng.uniform(*DITHER_RATIO_RANGE))
    e = dict(
        id=ENTRY.id,
        kind="depth_steps",
        parameters={"step_mm": 1.0, "offset_mm": 0.0, "pixels": pixels, "dither_mm": ratio},
        plates=b.everyone,
        axes=["z"],
    )
    q = b.quantization_step(e, ratio)
    e["parameters"] |= {"step_mm": q, "dither_mm": ratio * q, "offset_mm": float(rng.uniform(0, q))}
    return e


def _pixel_dither(base, e, j: int) -> float:
    """σ_d (mm) of plate j's pixels before rounding: ``dither_mm``, default σ√P (the whole noise)."""
    p = e["parameters"]
    if "dither_mm" in p:
        return float(p["dither_mm"])
    return float(base.sigma[j, 2]) * math.sqrt(int(p.get("pixels", 1)))


def _readings(base, e, pos, noise, scale):
    """Each plate's z as a disparity camera reads it (`quantised_readings`): the draw of the
    recording without quantisation (`CleanRecording.eps`, frame-common and line-of-sight parts
    included) split before and after the rounding with a stream of the recording's seed and the
    plate, so that a control and a quantised case differ by the rounding alone."""
    p = e["parameters"]
    q, o, n_px = float(p["step_mm"]), float(p["offset_mm"]), int(p.get("pixels", 1))
    for j in np.asarray(e["plates"], int) - 1:
        sig_f = base.sigma[j, 2] * scale[:, j, 2]
        rng = np.random.default_rng([base.seed, 7004, j])
        pos[:, j, 2] = quantised_readings(
            pos[:, j, 2], noise[:, j, 2], sig_f, base.eps[:, j, 2], q, o, n_px, _pixel_dither(base, e, j), rng
        )
        noise[:, j, 2] = 0.0


def _mean_reading(base, e, pos):
    """The staircase smoothed by the pixels' noise (the rest of the rounding is noise)."""
    q, o = float(e["parameters"]["step_mm"]), float(e["parameters"]["offset_mm"])
    pos = pos.copy()
    for j in np.asarray(e["plates"], int) - 1:
        pos[:, j, 2] = smoothed_staircase(pos[:, j, 2], q, o, _pixel_dither(base, e, j))
    return pos


ENTRY = Entry(
    id="quantization",
    meaning="depth measured in steps (structured-light disparity quantisation, a logger's ADC)",
    rank=11,
    # a disparity or a converter's lattice; a ToF camera's phase is not read in steps
    sensors=("structured_light", "lds", "accelerometer", "camera_tracking", "logger"),
    structural=False,
    level="measurement",
    params=(
        Param("step_mm", "mm, the lattice's step"),
        Param("offset_mm", "mm, a level of the lattice", 0.0),
        Param(
            "dither_mm",
            "mm, a pixel's noise before the rounding; optional: the reading's × √pixels",
            optional=True,
        ),
        Param(
            "pixels",
            "readings averaged per centroid; optional: from rounded_noise_share, else the fewest that "
            "carry dither_mm",
            optional=True,
        ),
        Param(
            "rounded_noise_share",
            "of the reading's noise variance, the rounding's (as the diagnosis reports it); optional",
            optional=True,
        ),
    ),
    inject=inject,
    check=check,
    from_diagnosis=from_diagnosis,
    plated=True,
    order=1,  # the reading's last step: whatever shaped its noise, it is rounded
    example={"step_mm": 1.5, "offset_mm": 0.4, "dither_mm": 0.3},
    draw=draw,
    scored=lambda kind: {"step_mm": True},
    bench=Bench(readings=_readings, mean_reading=_mean_reading),
)
