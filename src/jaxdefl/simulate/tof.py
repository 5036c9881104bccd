"""Time-of-flight camera (SR4000-class): four correlation samples taken one after the other.

Per pixel and frame the scene phasor P(t) = sum over what the pixel sees of
brightness x exp(i 4 pi f_m range / c) is evaluated at the four tap times t_k = t_frame +
offset_k / f_s (default offsets 0, 1/4, 1/2, 3/4 of the frame period), so a moving surface is seen
at a different range by every sample. The samples follow eq. 3.5 (C_k = |P| / 2 cos(phi + k pi/2)
+ B), amplitude and phase follow eq. 3.6-3.7, range eq. 3.8, wrapped at the non-ambiguity range
D = c / (2 f_m) (eq. 3.1). Motion artefacts (eq. 5.47-5.52) therefore come out of the sampling
itself; nothing is added on top.

Noise has two parts.

- White Gaussian noise on each correlation sample, sized so that the range noise on the beam top
  surface matches Table 6.1 for the integration time (frame rate) and modulation frequency; pixels
  darker than the top surface are noisier in proportion (sigma_range ∝ 1 / amplitude). Table 6.1 is
  read as the scatter of the top surface about its own (per-frame) surface: the thesis' plate
  centroids, means of tens of pixels, scatter about the fitted motion as much as or more than a
  single pixel does (Table 6.2: 3.32 mm at 20 Hz for Cam 3 against 2.56 mm per pixel), so most of
  their noise cannot be independent from pixel to pixel.
- A per-frame range error shared by the pixels: the phase of the modulation reference against
  which all pixels demodulate wanders from frame to frame (clock jitter and temperature of the
  illumination driver), a common phase offset delta, i.e. a common range error delta / k that is
  larger at short integration times (less averaging) and, for the same phase jitter, smaller at
  higher modulation frequency. A share (``camera.correlated_spatial_fraction``) is a random tilt
  of the range field (the LED array's phase is not uniform over the field), so plates far apart
  are only partly correlated. Its size is calibrated, per camera unit, so that a plate centroid's
  residual about the true motion (what `jaxdefl fit` reports as sigma_residual_mm) matches the
  thesis: Table 6.2 for Cam 3 (29 MHz) and Cam 4 (31 MHz) at 10-40 Hz, Tables 6.12/6.17 for Cam 2
  (0.76 mm at 20 Hz, 29 MHz); the per-pixel part's contribution to the centroid is subtracted.
  Other frame rates are interpolated in log(integration time), other modulation frequencies
  scaled as Table 6.1.

Scattering adds a small fraction of the frame-mean phasor to every pixel (a scene-dependent
range bias).
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
    "centroid_residual_mm",
    "calibration_unit",
    "TABLE_6_2_MM",
    "TABLE_6_7_MM",
    "TABLE_6_12_RESIDUAL_MM",
    "TABLE_6_17_RESIDUAL_MM",
]

# Section 4.3.2: integration times used for the frame rates of Experiment I.
_INTEGRATION_MS = {10.0: 21.0, 20.0: 8.5, 30.0: 4.4, 40.0: 2.2}
# Table 6.1: STD of the beam top surface (mm) at those integration times, per modulation frequency.
TABLE_6_1_MM = {
    29.0: {10.0: 2.38, 20.0: 2.56, 30.0: 3.14, 40.0: 5.34},
    31.0: {10.0: 1.61, 20.0: 1.95, 30.0: 2.53, 40.0: 3.94},
}
# Plate-centroid residual sigma (mm) by frame rate: Table 6.2 (Experiment I, 1 Hz loading; Cam 3
# at 29 MHz, Cam 4 at 31 MHz) and Table 6.7 (3 Hz loading, the same cameras).
TABLE_6_2_MM = {
    "cam3": {10.0: 2.37, 20.0: 3.32, 30.0: 6.05, 40.0: 13.08},
    "cam4": {10.0: 1.18, 20.0: 1.78, 30.0: 2.73, 40.0: 4.83},
}
TABLE_6_7_MM = {
    "cam3": {10.0: 2.51, 20.0: 3.72, 30.0: 5.34, 40.0: 12.09},
    "cam4": {10.0: 1.24, 20.0: 1.71, 30.0: 2.67, 40.0: 4.52},
}
# Experiment II, Cam 2 (USB SR4000, 20 Hz, 29 MHz): residual sigma per day, Tables 6.12 (1 Hz) and
# 6.17 (3 Hz). Day 1 of both (0.75, 0.76 mm; the mean of Table 6.12 is 0.76) calibrates Cam 2.
TABLE_6_12_RESIDUAL_MM = {"day1": 0.75, "day2": 0.74, "day3": 0.80, "day6": 0.71, "day8": 0.79, "day9": 0.77}
TABLE_6_17_RESIDUAL_MM = {
    "day1": 0.76,
    "day2": 0.79,
    "day3": 0.71,
    "day4": 0.62,
    "day5": 0.82,
    "day7": 0.73,
    "day8": 0.77,
    "day9": 0.77,
    "day10": 0.57,
    "day11": 0.56,
}
_CAM2_RESIDUAL_20HZ_MM = 0.76
_UNIT_MODULATION_MHZ = {"cam2": 29.0, "cam3": 29.0, "cam4": 31.0}
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


def _loglog(row: dict[float, float], integration_ms: float) -> float:
    """A table by frame rate, interpolated in log(value) against log(integration time) (linear
    extrapolation beyond the end points)."""
    x = math.log(integration_ms)
    ti = np.log([_INTEGRATION_MS[f] for f in row])[::-1]
    s = np.log(list(row.values()))[::-1]
    if x <= ti[0]:
        val = s[0] + (s[1] - s[0]) / (ti[1] - ti[0]) * (x - ti[0])
    elif x >= ti[-1]:
        val = s[-1] + (s[-1] - s[-2]) / (ti[-1] - ti[-2]) * (x - ti[-1])
    else:
        val = np.interp(x, ti, s)
    return math.exp(val)


def range_noise_mm(integration_ms: float, modulation_mhz: float) -> float:
    """Range STD on the beam top surface (Table 6.1), interpolated in log(integration time) and
    linearly in the modulation frequency (extrapolated outside 29-31 MHz, floored at 10 %)."""
    per_f = {fm: _loglog(row, integration_ms) for fm, row in TABLE_6_1_MM.items()}
    lo, hi = per_f[29.0], per_f[31.0]
    out = lo + (hi - lo) * (modulation_mhz - 29.0) / 2.0
    return float(max(out, 0.1 * min(lo, hi)))


def calibration_unit(cfg: SimConfig) -> str:
    """The thesis camera whose centroid residuals calibrate the correlated range error."""
    cam = cfg.camera
    return cam.calibration or (cam.name if cam.name in _UNIT_MODULATION_MHZ else "cam2")


def centroid_residual_mm(unit: str, integration_ms: float, modulation_mhz: float) -> float:
    """Plate-centroid residual sigma (mm) of a thesis camera unit at an integration time and
    modulation frequency: Table 6.2 for cam3/cam4 (log-log in the integration time); cam2 is
    0.76 mm at 20 Hz (Tables 6.12/6.17) with the geometric mean of cam3's and cam4's frame-rate
    dependence. Another modulation frequency scales as the per-pixel noise of Table 6.1."""
    if unit in TABLE_6_2_MM:
        base = _loglog(TABLE_6_2_MM[unit], integration_ms)
    else:
        shape = math.sqrt(
            _loglog(TABLE_6_2_MM["cam3"], integration_ms) * _loglog(TABLE_6_2_MM["cam4"], integration_ms)
        )
        ref = math.sqrt(TABLE_6_2_MM["cam3"][20.0] * TABLE_6_2_MM["cam4"][20.0])
        base = _CAM2_RESIDUAL_20HZ_MM * shape / ref
    fm0 = _UNIT_MODULATION_MHZ.get(unit, 29.0)
    return base * range_noise_mm(integration_ms, modulation_mhz) / range_noise_mm(integration_ms, fm0)


def _spatial_basis(h: int, w: int) -> np.ndarray:
    """(2, h*w) smooth modes across the image: a range gradient along the columns and one along
    the rows (a per-frame tilt of the range field), each of unit mean square over the frame. A
    tilt leaves a surface's scatter about its fitted plane (Table 6.1) unchanged, while plates
    in different parts of the image are only partly correlated."""
    cu = math.sqrt(3.0) * ((np.arange(w) + 0.5) / w * 2 - 1)
    cv = math.sqrt(3.0) * ((np.arange(h) + 0.5) / h * 2 - 1)
    uu = np.broadcast_to(cu[None, :], (h, w)).ravel()
    vv = np.broadcast_to(cv[:, None], (h, w)).ravel()
    return np.stack([uu, vv]).astype(np.float32)


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
    camera_xy_mm: np.ndarray  # (2,) camera X, Y (world mm)
    plate_depth_mm: float  # vertical distance from the camera to the plates' top faces at rest
    plate_shape: np.ndarray  # (plate,) deflection / mid-span deflection
    sigma_corr_mm: float = 0.0  # per-frame correlated range error (sigma, mm)
    corr_spatial: float = 0.0  # share of its variance that varies across the image
    corr_basis: np.ndarray | None = None  # (2, p) smooth modes
    centroid_residual_mm: float = 0.0  # the centroid residual it is calibrated to
    centroid_independent_mm: float = 0.0  # the per-pixel noise's share of a plate centroid


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
    # correlated part: what the centroid residual needs beyond the per-pixel noise averaged over a
    # plate's eroded pixels (median over the plates in view)
    if cam.centroid_residual_mm >= 0:
        target = cam.centroid_residual_mm * cam.noise_scale
    else:
        target = centroid_residual_mm(calibration_unit(cfg), t_int, cam.modulation_mhz) * cam.noise_scale
    from .centroids import plate_pixel_masks

    masks = plate_pixel_masks(cfg, pm)
    inv_norm = 1.0 / pm.plate_gain
    ind, gz = [], []
    for idx in masks.values():
        sig_r = sigma_c * math.sqrt(2.0) / (k * np.maximum(np.abs(plate_base[idx]), 1e-12))
        ind.append(np.sqrt(np.sum((sig_r * inv_norm[idx]) ** 2)) / idx.size)
        gz.append(float(np.mean(inv_norm[idx])))
    sig_ind = float(np.median(ind)) if ind else 0.0
    g = float(np.median(gz)) if gz else 1.0
    sigma_corr = math.sqrt(max(target**2 - sig_ind**2, 0.0)) / g
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
        camera_xy_mm=np.array([cam.x_mm, cam.y_mm]),
        plate_depth_mm=float(pm.plate_drop_mm),
        plate_shape=np.asarray(pm.plate_shape, float),
        sigma_c=float(sigma_c),
        offset_b=(0.25 * amp + 200.0).astype(np.float32),
        scattering=cam.scattering,
        top_pixels=top,
        nar_mm=non_ambiguity_range_m(cam.modulation_mhz) * 1000,
        integration_ms=t_int,
        sigma_corr_mm=float(sigma_corr),
        corr_spatial=float(cam.correlated_spatial_fraction),
        corr_basis=_spatial_basis(pm.intr.height, pm.intr.width),
        centroid_residual_mm=float(target),
        centroid_independent_mm=sig_ind,
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


def _kernel(correlated: bool = True):
    """The jitted block renderer (built once per variant; jax imported lazily)."""
    name = "tof_corr" if correlated else "tof"
    if name in _KERNELS:
        return _KERNELS[name]
    import jax
    import jax.numpy as jnp

    def one_frame(key, defl, dx, dy, m):
        # defl, dx, dy: (4,) at the four tap times
        if correlated:
            # the frame's modulation-phase offset: common part plus smooth modes across the image
            a = jax.random.normal(jax.random.fold_in(key, 7), (3,), dtype=jnp.float32)
            eps = m["corr_c0"] * a[0] + m["corr_c1"] * (a[1:] @ m["corr_basis"])
            offset = jnp.exp(1j * (m["k"] * eps)).astype(jnp.complex64)

        def tap(i):
            d = defl[i]
            bg = jnp.sum(m["bg_base"] * jnp.exp(1j * (m["k"] * m["bg_gain"] * d)), axis=1)
            # the plates' rectangles where they are at this tap: moved along and across the beam,
            # and seen smaller as they move down (footprints are at the plates' rest depth)
            sc = (m["pdepth"] / (m["pdepth"] + m["pshape"] * d))[:, None]
            shift = jnp.stack([dx[i], dx[i], dy[i], dy[i]])
            e = m["pcam"] + (m["edges"] + shift - m["pcam"]) * sc
            idx = m["pidx"]
            ok = idx >= 0
            ii = jnp.maximum(idx, 0)
            fp = m["foot"]
            ox = jnp.clip(jnp.minimum(fp[:, 1], e[ii, 1]) - jnp.maximum(fp[:, 0], e[ii, 0]), 0)
            oy = jnp.clip(jnp.minimum(fp[:, 3], e[ii, 3]) - jnp.maximum(fp[:, 2], e[ii, 2]), 0)
            f = jnp.where(ok, ox / (fp[:, 1] - fp[:, 0]) * oy / (fp[:, 3] - fp[:, 2]), 0.0)
            f = (f * (1 - m["occ"])).astype(jnp.float32)
            plate = m["pbase"] * jnp.exp(1j * (m["k"] * m["pgain"] * d))
            p = (1 - f) * bg + f * plate
            if correlated:
                p = p * offset
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

    _KERNELS[name] = block
    return block


def device_model_of(tm: ToFModel) -> dict:
    """The arrays of ``tm`` on the device, as `render_tof` reads them (only it, in its scope)."""
    import jax.numpy as jnp

    from .._jax import float64

    with float64():
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
            pcam=jnp.asarray(np.repeat(tm.camera_xy_mm, 2), jnp.float32),
            pdepth=jnp.float32(tm.plate_depth_mm),
            pshape=jnp.asarray(tm.plate_shape, jnp.float32),
            sigma_c=jnp.float32(tm.sigma_c),
            B=jnp.asarray(tm.offset_b),
            scatter=jnp.complex64(tm.scattering),
            corr_c0=jnp.float32(tm.sigma_corr_mm * math.sqrt(1.0 - tm.corr_spatial)),
            corr_c1=jnp.float32(tm.sigma_corr_mm * math.sqrt(tm.corr_spatial / 2.0)),
            corr_basis=jnp.asarray(
                tm.corr_basis if tm.corr_basis is not None else np.zeros((2, tm.bg_base.shape[0]), np.float32)
            ),
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

    from .._jax import float64

    kern = _kernel(correlated=tm.sigma_corr_mm > 0)
    with float64():  # the draws and complex phasors as in a float64 process (the CLI)
        m = device_model if device_model is not None else device_model_of(tm)
        base = jax.random.PRNGKey(seed)
        n = len(frame_index)
        rng_out = np.empty((n, tm.bg_base.shape[0]), np.float32)
        amp_out = np.empty_like(rng_out)
        for s in range(0, n, block):
            e = min(n, s + block)
            pad = block - (e - s)
            fi = np.pad(frame_index[s:e], (0, pad), mode="edge")
            keys = jax.vmap(lambda i: jax.random.fold_in(base, i))(jnp.asarray(fi, jnp.uint32))
            args = [
                np.pad(a[s:e], ((0, pad), (0, 0)), mode="edge").astype(np.float32) for a in (defl, dx, dy)
            ]
            r, a = kern(keys, *args, m)
            rng_out[s:e] = np.asarray(r)[: e - s]
            amp_out[s:e] = np.asarray(a)[: e - s]
    return rng_out, amp_out
