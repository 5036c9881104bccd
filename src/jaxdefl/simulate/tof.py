"""Time-of-flight camera (SR4000-class): four correlation samples taken one after the other.

Per pixel and frame the scene phasor P(t) = sum over what the pixel sees of
brightness x exp(i 4 pi f_m range / c) is evaluated at the four tap times t_k = t_frame +
offset_k / f_s (default offsets 0, 1/4, 1/2, 3/4 of the frame period), so a moving surface is seen
at a different range by every sample. The samples follow eq. 3.5 (C_k = |P| / 2 cos(phi + k pi/2)
+ B), amplitude and phase follow eq. 3.6-3.7, range eq. 3.8, wrapped at the non-ambiguity range
D = c / (2 f_m) (eq. 3.1). Motion artefacts (eq. 5.47-5.52) therefore come out of the sampling
itself; nothing is added on top.

Noise is white Gaussian on each correlation sample, sized so that the range noise on the beam top
surface matches Table 6.1 for the integration time (frame rate) and modulation frequency; pixels
darker than the top surface are noisier in proportion (sigma_range ∝ 1 / amplitude). Scattering
adds a small fraction of the frame-mean phasor to every pixel (a scene-dependent range bias).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .config import SPEED_OF_LIGHT_M_S, SimConfig
from .scene import KIND_BEAM_TOP, KIND_SPREADER, KIND_STATIC, PixelModel

__all__ = [
    "non_ambiguity_range_m",
    "integration_time_ms",
    "range_noise_mm",
    "ToFModel",
    "tof_model",
    "render_tof",
    "phase_from_samples",
]

# Section 4.3.2: integration times used for the frame rates of Experiment I.
_INTEGRATION_MS = {10.0: 21.0, 20.0: 8.5, 30.0: 4.4, 40.0: 2.2}
# Table 6.1: STD of the beam top surface (mm) at those integration times, per modulation frequency.
TABLE_6_1_MM = {
    29.0: {10.0: 2.38, 20.0: 2.56, 30.0: 3.14, 40.0: 5.34},
    31.0: {10.0: 1.61, 20.0: 1.95, 30.0: 2.53, 40.0: 3.94},
}
_AMPLITUDE_COUNTS = 20000.0  # amplitude units per unit brightness at 21 ms integration
_KINDS = (KIND_STATIC, KIND_BEAM_TOP, KIND_SPREADER)


def non_ambiguity_range_m(modulation_mhz: float) -> float:
    """Non-ambiguity range D = c / (2 f_m) in metres (eq. 3.1, Table 3.1)."""
    return SPEED_OF_LIGHT_M_S / (2.0 * modulation_mhz * 1e6)


def integration_time_ms(frame_rate_hz: float) -> float:
    """Integration time for a frame rate: Section 4.3.2's pairs, log-log interpolated."""
    f = np.log(list(_INTEGRATION_MS))
    t = np.log(list(_INTEGRATION_MS.values()))
    x = math.log(frame_rate_hz)
    if x <= f[0]:
        slope = (t[1] - t[0]) / (f[1] - f[0])
        return float(math.exp(t[0] + slope * (x - f[0])))
    if x >= f[-1]:
        slope = (t[-1] - t[-2]) / (f[-1] - f[-2])
        return float(math.exp(t[-1] + slope * (x - f[-1])))
    return float(math.exp(np.interp(x, f, t)))


def range_noise_mm(integration_ms: float, modulation_mhz: float) -> float:
    """Range STD on the beam top surface (Table 6.1), interpolated in log(integration time) and
    linearly in the modulation frequency (extrapolated outside 29-31 MHz, floored at 10 %)."""
    x = math.log(integration_ms)
    per_f = {}
    for fm, row in TABLE_6_1_MM.items():
        ti = np.log([_INTEGRATION_MS[f] for f in row])[::-1]
        s = np.log(list(row.values()))[::-1]
        if x <= ti[0]:
            val = s[0] + (s[1] - s[0]) / (ti[1] - ti[0]) * (x - ti[0])
        elif x >= ti[-1]:
            val = s[-1] + (s[-1] - s[-2]) / (ti[-1] - ti[-2]) * (x - ti[-1])
        else:
            val = np.interp(x, ti, s)
        per_f[fm] = math.exp(val)
    lo, hi = per_f[29.0], per_f[31.0]
    out = lo + (hi - lo) * (modulation_mhz - 29.0) / 2.0
    return float(max(out, 0.1 * min(lo, hi)))


@dataclass(frozen=True)
class ToFModel:
    """Per-pixel arrays for the ToF kernel (p = pixels)."""

    k_rad_per_mm: float
    bg_base: np.ndarray  # (p, 3) complex: static phasor of each component at rest
    bg_gain: np.ndarray  # (p, 3) d range / d mid-span deflection
    plate_base: np.ndarray  # (p,) complex
    plate_gain: np.ndarray  # (p,) d range / d mid-span deflection (includes the plate's shape)
    plate_idx: np.ndarray  # (p,)
    plate_foot: np.ndarray  # (p, 4)
    plate_occ: np.ndarray  # (p,)
    plate_edges: np.ndarray  # (plate, 4)
    sigma_c: float  # correlation-sample noise
    offset_b: np.ndarray  # (p,) background offset B of eq. 3.5
    scattering: float
    top_pixels: np.ndarray  # (n,) pixels that see only the beam top (for precision checks)
    nar_mm: float
    integration_ms: float


def tof_model(cfg: SimConfig, pm: PixelModel) -> ToFModel:
    """Aggregate the static ray-cast into per-pixel phasor components for the ToF kernel."""
    cam = cfg.camera
    fm = cam.modulation_mhz * 1e6
    k = 4 * math.pi * fm / (SPEED_OF_LIGHT_M_S * 1000.0)  # rad per mm of range
    t_int = cam.integration_time_ms or integration_time_ms(cam.frame_rate_hz)
    scale = _AMPLITUDE_COUNTS * t_int / 21.0
    nsub = pm.sub_kind.shape[1]
    phase = np.mod(k * pm.sub_range_mm, 2 * np.pi)
    ph = scale * pm.sub_bright * np.exp(1j * phase)
    bases, gains = [], []
    for kind in _KINDS:
        m = pm.sub_kind == kind
        bases.append((ph * m).sum(axis=1) / nsub)
        cnt = m.sum(axis=1)
        gains.append(np.where(cnt > 0, (pm.sub_gain * m).sum(axis=1) / np.maximum(cnt, 1), 0.0))
    bg_base = np.stack(bases, axis=1).astype(np.complex64)
    bg_gain = np.stack(gains, axis=1).astype(np.float32)
    pidx = pm.plate_idx
    shape = np.where(pidx >= 0, pm.plate_shape[np.maximum(pidx, 0)], 0.0)
    plate_base = scale * pm.plate_bright * np.exp(1j * np.mod(k * pm.plate_range_mm, 2 * np.pi))
    top = np.flatnonzero((pm.sub_kind == KIND_BEAM_TOP).all(axis=1) & (pidx < 0))
    # Noise: sigma_range(top surface) from Table 6.1 at the median top-surface amplitude.
    k_ref = (
        float(np.median(np.abs(bg_base[top, 1]))) if top.size else float(np.median(np.abs(bg_base).sum(1)))
    )
    sigma_range = range_noise_mm(t_int, cam.modulation_mhz) * cam.noise_scale
    sigma_c = sigma_range * k * k_ref / math.sqrt(2.0)
    amp = np.abs(bg_base).sum(axis=1)
    return ToFModel(
        k_rad_per_mm=k,
        bg_base=bg_base,
        bg_gain=bg_gain,
        plate_base=plate_base.astype(np.complex64),
        plate_gain=(pm.plate_gain * shape).astype(np.float32),
        plate_idx=pidx,
        plate_foot=pm.plate_foot.astype(np.float64),
        plate_occ=pm.plate_occ.astype(np.float32),
        plate_edges=pm.plate_edges,
        sigma_c=float(sigma_c),
        offset_b=(0.25 * amp + 200.0).astype(np.float32),
        scattering=cam.scattering,
        top_pixels=top,
        nar_mm=non_ambiguity_range_m(cam.modulation_mhz) * 1000,
        integration_ms=t_int,
    )


def phase_from_samples(c):
    """Amplitude (eq. 3.6) and phase in [0, 2 pi) (eq. 3.7, four-quadrant) from samples (..., 4)."""
    import jax.numpy as jnp

    re = c[..., 0] - c[..., 2]
    im = c[..., 3] - c[..., 1]
    amp = jnp.sqrt(re * re + im * im) / 2
    phi = jnp.mod(jnp.arctan2(im, re), 2 * jnp.pi)
    return amp, phi


_KERNELS: dict = {}


def _kernel():
    """The jitted block renderer (built once; jax imported lazily)."""
    if "tof" in _KERNELS:
        return _KERNELS["tof"]
    import jax
    import jax.numpy as jnp

    def one_frame(key, defl, dx, dy, m):
        # defl, dx, dy: (4,) at the four tap times
        def tap(i):
            d = defl[i]
            bg = jnp.sum(m["bg_base"] * jnp.exp(1j * (m["k"] * m["bg_gain"] * d)), axis=1)
            e = m["edges"]
            idx = m["pidx"]
            ok = idx >= 0
            ii = jnp.maximum(idx, 0)
            fp = m["foot"]
            ox = jnp.clip(
                jnp.minimum(fp[:, 1], e[ii, 1] + dx[i]) - jnp.maximum(fp[:, 0], e[ii, 0] + dx[i]), 0
            )
            oy = jnp.clip(
                jnp.minimum(fp[:, 3], e[ii, 3] + dy[i]) - jnp.maximum(fp[:, 2], e[ii, 2] + dy[i]), 0
            )
            f = jnp.where(ok, ox / (fp[:, 1] - fp[:, 0]) * oy / (fp[:, 3] - fp[:, 2]), 0.0)
            f = (f * (1 - m["occ"])).astype(jnp.float32)
            plate = m["pbase"] * jnp.exp(1j * (m["k"] * m["pgain"] * d))
            p = (1 - f) * bg + f * plate
            p = p + m["scatter"] * jnp.mean(p)
            rot = jnp.array([1, 1j, -1, -1j], dtype=jnp.complex64)[i]
            return jnp.real(p * rot) / 2 + m["B"]

        c = jnp.stack([tap(i) for i in range(4)], axis=-1)  # (p, 4)
        c = c + m["sigma_c"] * jax.random.normal(key, c.shape, dtype=jnp.float32)
        amp, phi = phase_from_samples(c)
        return (phi / m["k"]).astype(jnp.float32), amp.astype(jnp.float32)

    @jax.jit
    def block(keys, defl, dx, dy, m):
        return jax.vmap(one_frame, in_axes=(0, 0, 0, 0, None))(keys, defl, dx, dy, m)

    _KERNELS["tof"] = block
    return block


def _device_model(tm: ToFModel) -> dict:
    import jax.numpy as jnp

    return dict(
        k=jnp.float32(tm.k_rad_per_mm),
        bg_base=jnp.asarray(tm.bg_base),
        bg_gain=jnp.asarray(tm.bg_gain),
        pbase=jnp.asarray(tm.plate_base),
        pgain=jnp.asarray(tm.plate_gain),
        pidx=jnp.asarray(tm.plate_idx),
        foot=jnp.asarray(tm.plate_foot, jnp.float32),
        occ=jnp.asarray(tm.plate_occ),
        edges=jnp.asarray(tm.plate_edges, jnp.float32),
        sigma_c=jnp.float32(tm.sigma_c),
        B=jnp.asarray(tm.offset_b),
        scatter=jnp.complex64(tm.scattering),
    )


def render_tof(
    tm: ToFModel,
    frame_index: np.ndarray,
    defl: np.ndarray,
    dx: np.ndarray,
    dy: np.ndarray,
    seed: int,
    block: int = 16,
    device_model: dict | None = None,
):
    """Render frames: (frame,) indices and (frame, 4) tap kinematics -> range, amplitude (frame, p).

    Each frame's noise comes from ``fold_in(seed, frame_index)``, so output does not depend on how
    frames are grouped into blocks or chunks. Range is in mm, wrapped to [0, NAR).
    """
    import jax
    import jax.numpy as jnp

    kern = _kernel()
    m = device_model if device_model is not None else _device_model(tm)
    base = jax.random.PRNGKey(seed)
    n = len(frame_index)
    rng_out = np.empty((n, tm.bg_base.shape[0]), np.float32)
    amp_out = np.empty_like(rng_out)
    for s in range(0, n, block):
        e = min(n, s + block)
        pad = block - (e - s)
        fi = np.pad(frame_index[s:e], (0, pad), mode="edge")
        keys = jax.vmap(lambda i: jax.random.fold_in(base, i))(jnp.asarray(fi, jnp.uint32))
        args = [np.pad(a[s:e], ((0, pad), (0, 0)), mode="edge").astype(np.float32) for a in (defl, dx, dy)]
        r, a = kern(keys, *args, m)
        rng_out[s:e] = np.asarray(r)[: e - s]
        amp_out[s:e] = np.asarray(a)[: e - s]
    return rng_out, amp_out
