"""Camera clocks from the motion: a reference sinusoid, each camera's offset and rate against it.

The reference is the loading's motion on the true clock (an LDS) or on the reference camera's
clock: ``L(t) = a cos(w (t - t0)) + b sin(w (t - t0))``, w = 2 pi f. A camera whose clock reads
``s = t0 + offset + (1 + rate) (t - t0)`` sees plate p move as ``g_p L(t(s)) + c_p`` with
``t(s) = t0 + (s - t0 - offset) / (1 + rate)``: one least squares (optimistix) over the offset,
the rate and every plate's gain and mean, all plates and frames at once. A plate's gain is free
(its place along the beam and the camera's scale), so the clock rests on the phase alone; the
offset is found modulo the loading period (the start takes the one within half a period of 0).
"""

from __future__ import annotations

import numpy as np

from .._jax import float64
from .._numerics import harmonic_design, wls

__all__ = ["fit_reference", "fit_clock", "harmonic", "fuse", "sampling_delay_s"]


def sampling_delay_s(range_mm, nar_mm: float, tap_offsets, frame_rate_hz: float):
    """When, after its stamp, a four-tap ToF frame sees a moving surface (s).

    The phase comes from re = C0 - C2 and im = C3 - C1 (eq. 3.7): for a range that changes
    linearly over the frame, re is taken at the mean time of taps 0 and 2 and im at that of taps
    1 and 3, and a small change of the true phase phi moves the measured one by cos^2(phi) of
    im's share plus sin^2(phi) of re's (differentiate atan2(im, re)): the instant the range
    stands for depends on where the range falls in the modulation cycle, phi = 2 pi range / NAR.
    """
    o = np.asarray(tap_offsets, float) / frame_rate_hz
    t_re, t_im = (o[0] + o[2]) / 2, (o[1] + o[3]) / 2
    phi = 2 * np.pi * np.asarray(range_mm, float) / nar_mm
    return t_im * np.cos(phi) ** 2 + t_re * np.sin(phi) ** 2


_KERNELS: dict = {}


def _linear(t: np.ndarray, z: np.ndarray, f: float, t0: float) -> tuple[np.ndarray, np.ndarray]:
    """Least squares z = a cos + b sin + c at frequency f: (a, b, c), their covariance."""
    x = harmonic_design(2 * np.pi * f * (t - t0))[:, [1, 2, 0]]
    coef, cov, _ = wls(x, z)
    return coef, cov


def harmonic(t: np.ndarray, z: np.ndarray, f: float, t0: float) -> dict:
    """Amplitude and phase (z = A cos(w (t - t0) - phase) + c) at a known frequency, with σ's from
    the least-squares covariance (white residuals)."""
    (a, b, c), cov = _linear(np.asarray(t, float), np.asarray(z, float), f, t0)
    amp = float(np.hypot(a, b))
    g_amp = np.array([a, b]) / amp
    g_ph = np.array([-b, a]) / amp**2
    cab = cov[:2, :2]
    return dict(
        amplitude_mm=amp,
        sigma_amplitude_mm=float(np.sqrt(g_amp @ cab @ g_amp)),
        phase_rad=float(np.arctan2(b, a)),
        sigma_phase_rad=float(np.sqrt(g_ph @ cab @ g_ph)),
        mean_mm=float(c),
        n=int(len(t)),
    )


def _kernel(name: str):
    if name in _KERNELS:
        return _KERNELS[name]
    import jax
    import jax.numpy as jnp
    import optimistix as optx

    if name == "reference":

        def resid(p, args):
            t, z, t0 = args
            w = 2 * jnp.pi * p[0] * (t - t0)
            return z - (p[1] * jnp.cos(w) + p[2] * jnp.sin(w) + p[3])

    else:

        def resid(p, args):
            s, z, plate, t0, ref, mask, n = args
            tau = (s - t0 - p[0] * 1e-3) / (1 + p[1] * 1e-6)
            w = 2 * jnp.pi * ref[0] * tau
            shape = ref[1] * jnp.cos(w) + ref[2] * jnp.sin(w)
            return mask * (z - (p[2:][plate] * shape + p[2:][n + plate]))

    def solve(p0, *args):
        sol = optx.least_squares(
            resid, optx.LevenbergMarquardt(rtol=1e-8, atol=1e-8), p0, args=args, max_steps=400, throw=False
        )
        r = resid(sol.value, args)
        jac = jax.jacfwd(resid)(sol.value, args)
        return sol.value, r, jac, sol.result == optx.RESULTS.successful

    _KERNELS[name] = jax.jit(solve, static_argnums=(7,) if name == "clock" else ())
    return _KERNELS[name]


def _cov(r: np.ndarray, jac: np.ndarray) -> np.ndarray:
    s2 = float(r @ r) / max(len(r) - jac.shape[1], 1)
    return s2 * np.linalg.pinv(jac.T @ jac)


def fit_reference(t: np.ndarray, z: np.ndarray, t0: float, f0: float) -> dict:
    """The reference sinusoid (f, a, b, c) of one series on its own clock, from ``f0`` (Hz)."""
    t, z = np.asarray(t, float), np.asarray(z, float)
    (a, b, c), _ = _linear(t, z, f0, t0)
    with float64():
        import jax.numpy as jnp

        p, r, jac, ok = _kernel("reference")(
            jnp.array([f0, a, b, c]), jnp.asarray(t), jnp.asarray(z), jnp.float64(t0)
        )
        p, r, jac = np.asarray(p), np.asarray(r), np.asarray(jac)
    cov = _cov(r, jac)
    return dict(
        f_hz=float(p[0]),
        a=float(p[1]),
        b=float(p[2]),
        c=float(p[3]),
        sigma_f_hz=float(np.sqrt(cov[0, 0])),
        ok=bool(ok),
    )


def fit_clock(
    stamps: np.ndarray,
    z: np.ndarray,
    plate: np.ndarray,
    t0: float,
    ref: dict,
    delay_s: np.ndarray | float = 0.0,
) -> dict:
    """A camera's clock offset (ms) and rate error (ppm) against the reference ``ref``.

    Args:
        stamps, z, plate: (row,) the camera's stamps (s), a plate's vertical motion (mm), its
            plate number; every plate in view at once.
        t0: the clock's epoch (s); ref: `fit_reference`'s result.
        delay_s: (row,) or scalar: how long after its stamp (camera clock) a row's measurement
            was taken (`sampling_delay_s`).
    """
    delay_row = np.broadcast_to(np.asarray(delay_s, float), np.shape(stamps))
    stamps = np.asarray(stamps, float) + delay_row
    z = np.asarray(z, float)
    plates, idx = np.unique(np.asarray(plate), return_inverse=True)
    n = len(plates)
    f, a, b = ref["f_hz"], ref["a"], ref["b"]
    # the start: the offset from the phase of the strongest plate, within half a period of 0
    fits = [_linear(stamps[idx == i], z[idx == i], f, t0)[0] for i in range(n)]
    best = int(np.argmax([np.hypot(c[0], c[1]) for c in fits]))
    dphi = np.angle(np.exp(1j * (np.arctan2(fits[best][1], fits[best][0]) - np.arctan2(b, a))))
    off0 = dphi / (2 * np.pi * f) * 1e3
    amp_ref = np.hypot(a, b)
    g0 = [np.hypot(c[0], c[1]) / amp_ref for c in fits]
    c0 = [c[2] for c in fits]
    rows = len(z)
    size = max(256, 1 << (rows - 1).bit_length())  # shape buckets: one compilation each
    pad = size - rows
    with float64():
        import jax.numpy as jnp

        p, r, jac, ok = _kernel("clock")(
            jnp.asarray([off0, 0.0, *g0, *c0]),
            jnp.asarray(np.r_[stamps, np.full(pad, t0)]),
            jnp.asarray(np.r_[z, np.zeros(pad)]),
            jnp.asarray(np.r_[idx, np.zeros(pad, idx.dtype)]),
            jnp.float64(t0),
            jnp.asarray([f, a, b]),
            jnp.asarray(np.r_[np.ones(rows), np.zeros(pad)]),
            n,
        )
        p, r, jac = np.asarray(p), np.asarray(r)[:rows], np.asarray(jac)[:rows]
    # a frame's range error is shared by its plates: the covariance is the cluster-robust
    # sandwich with a frame per cluster (White 1980; Liang & Zeger 1986), and the frames'
    # residuals correlated in time grow it by sqrt((1 + rho) / (1 - rho)), rho their lag-1
    # correlation
    frame, inv = np.unique(np.round(stamps - delay_row, 6), return_inverse=True)
    score = np.zeros((len(frame), jac.shape[1]))
    np.add.at(score, inv, jac * r[:, None])
    bread = np.linalg.pinv(jac.T @ jac)
    dof = len(frame) / max(len(frame) - 2, 1)
    cs = np.zeros(len(frame))
    np.add.at(cs, inv, r)
    rho = float(np.clip(np.sum(cs[1:] * cs[:-1]) / max(np.sum(cs**2), 1e-300), 0.0, 0.95))
    cov = bread @ (score.T @ score) @ bread * dof * (1 + rho) / (1 - rho)
    # the clock's offset mid-recording: where the data pin it (the epoch's is extrapolated)
    lever_ms_per_ppm = (float(np.mean(stamps)) - t0) * 1e-3
    grad = np.array([1.0, lever_ms_per_ppm])
    return dict(
        offset_ms=float(p[0]),
        sigma_offset_ms=float(np.sqrt(cov[0, 0])),
        rate_ppm=float(p[1]),
        sigma_rate_ppm=float(np.sqrt(cov[1, 1])),
        t_mid_s=float(np.mean(stamps)),
        offset_mid_ms=float(p[0] + p[1] * lever_ms_per_ppm),
        sigma_offset_mid_ms=float(np.sqrt(grad @ cov[:2, :2] @ grad)),
        rho=rho,
        gains=dict(zip(plates.tolist(), p[2 : 2 + n].tolist(), strict=True)),
        rms_mm=float(np.sqrt(np.mean(r**2))),
        ok=bool(ok),
    )


def fuse(values: np.ndarray, sigmas: np.ndarray) -> dict:
    """Inverse-variance mean of one quantity seen by several cameras and the χ² test of their
    agreement (p-value of χ² with n - 1 degrees of freedom)."""
    from scipy.stats import chi2

    v, s = np.asarray(values, float), np.asarray(sigmas, float)
    w = 1.0 / s**2
    mean = float(np.sum(w * v) / np.sum(w))
    stat = float(np.sum(w * (v - mean) ** 2))
    dof = len(v) - 1
    return dict(
        value=mean,
        sigma=float(1.0 / np.sqrt(np.sum(w))),
        chi2=stat,
        dof=dof,
        p_value=float(chi2.sf(stat, dof)) if dof > 0 else 1.0,
    )
