"""Batched Lomb normalised periodogram (thesis eq. 5.25-5.28) in float64 JAX.

Two ways to get the sums the periodogram needs, chosen per window through `METHODS`:

- ``"grid"``: samples on a frame clock with drop-outs, t_i = t_0 + k_i dt. On the frequency grid
  f_j = j / (M dt), sum_i h_i exp(-2 pi i f_j t_i) is bin j of the FFT of the zero-filled masked
  grid of length M, and the tau sums are bin 2j of the FFT of the mask. Exact, O(M log M).
- ``"nufft"``: truly irregular times, through nifty-ls (a non-uniform FFT), batched over the
  windows that share their timestamps (the plates and axes of a window: one call per window
  span, not per window).

Both feed the same peak search: the highest grid bin, refined by a parabola through its
neighbours, with its false-alarm probability (`jaxdefl.spectral.fap`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import jax
import jax.numpy as jnp
import numpy as np
import scipy.fft

from .._errors import ConfigError, ParameterError
from .._jax import persistent_jit
from .._shapes import bucket, chunk_rows, pow2_at_least
from .._sincos import sincos
from ..series import Windows
from ..series.rows import unique_rows
from ..series.windows import MAX_BATCH_BYTES
from .fap import false_alarm_probability, n_independent

__all__ = ["METHODS", "Periodogram", "lomb_direct", "lomb_from_sums", "lomb_grid", "lomb_peaks"]

Method = Literal["auto", "grid", "nufft"]

# Largest number of complex grid cells per FFT chunk (~64 MB): chunks of a few hundred windows.
_CHUNK_CELLS = 1 << 22
# Working memory per frequency of one window's periodogram (FFT buffers, tau sums, powers), and
# per extra series of a non-uniform one. A single FFT over the whole grid peaked at ~53 B per
# grid point on a 2-core machine and ~110-160 B on the CI machine (its FFT keeps more buffers).
# A window whose grid is longer than _CHUNK_CELLS is therefore searched in interleaved sub-grids
# of at most _SUB_CELLS bins (`_grid_batch_strided`): its peak memory no longer grows with the
# oversampling (0.52 GiB at an oversampling of 26,214 on a 1,280-sample window, against 1.73 GiB
# in one FFT, on the 2-core machine). The bound then covers a kept spectrum and caps the work.
_BYTES_PER_FREQ = 128
_SUB_CELLS = 1 << 20
_BYTES_PER_SERIES_FREQ = 8


def _check_memory(n_freq: int, length: int, rows: int, oversampling: float) -> None:
    """Refuse an oversampling whose periodogram would not fit in MAX_BATCH_BYTES, before any of
    it is allocated (``n_freq`` frequencies of ``rows`` windows at once, ``length`` samples)."""
    need = n_freq * (_BYTES_PER_FREQ + _BYTES_PER_SERIES_FREQ * rows)
    if need > MAX_BATCH_BYTES:
        most = max(1.0, oversampling * MAX_BATCH_BYTES / need)
        raise ParameterError(
            "oversampling",
            f"{oversampling:g} gives {n_freq:,} frequencies for windows of {length:,} samples, "
            f"~{need / 2**30:.1f} GiB; expected at most {MAX_BATCH_BYTES / 2**30:.0f} GiB "
            f"(an oversampling <= {math.floor(most):,} here, or shorter windows)",
        )


def lomb_from_sums(ch, sh, c2, s2, n, var):
    """P_N from the sums Σh cos ωt, Σh sin ωt, Σcos 2ωt, Σsin 2ωt (thesis 5.27 with tau of 5.28).

    tan 2ωτ = S2 / C2, so Σcos²ω(t-τ) = (n + |Z2|)/2 and Σsin²ω(t-τ) = (n - |Z2|)/2 with
    |Z2| = sqrt(C2² + S2²). At zero and at the exact Nyquist frequency on a regular clock
    Σsin² is 0 and so is its numerator: that 0/0 term is set to 0.
    """
    cwt, swt, inv_cc, inv_ss = _tau_terms(c2, s2, n)
    yc = ch * cwt + sh * swt
    ys = sh * cwt - ch * swt
    return (yc**2 * inv_cc + ys**2 * inv_ss) / (2 * var)


def _centre(y, mask):
    n = jnp.sum(mask)
    ybar = jnp.sum(y * mask) / n
    h = (y - ybar) * mask
    var = jnp.sum(h**2) / (n - 1)  # (5.26)
    return h, n, var


def lomb_grid(y, mask, k, n_fft: int, j_lo: int, j_hi: int):
    """P_N at f_j = j / (n_fft dt), j = j_lo..j_hi, for one window on a frame clock.

    Args:
        y, mask, k: (sample,) values, validity and frame index (0 <= k < n_fft).
    Returns:
        (freq,) normalised power.
    """
    h, n, var = _centre(y, mask)
    m = mask.astype(y.dtype)
    fh = jnp.fft.rfft(jnp.zeros(n_fft, y.dtype).at[k].add(h))
    fm = jnp.fft.fft(jnp.zeros(n_fft, y.dtype).at[k].add(m))
    j = np.arange(j_lo, j_hi + 1)
    zh = fh[j]
    z2 = fm[(2 * j) % n_fft]
    # exp(-i x): real part is the cos sum, minus the imaginary part is the sin sum.
    return lomb_from_sums(zh.real, -zh.imag, z2.real, -z2.imag, n, var)


def lomb_direct(t, y, mask, freq_hz):
    """P_N at arbitrary frequencies by direct sums, O(sample x freq), for one window."""
    h, n, var = _centre(y, mask)
    m = mask.astype(y.dtype)
    wt = 2 * jnp.pi * freq_hz[:, None] * t[None, :]
    c, s = jnp.cos(wt), jnp.sin(wt)
    c2 = jnp.sum(m * (c * c - s * s), axis=1)
    s2 = jnp.sum(m * (2 * s * c), axis=1)
    return lomb_from_sums(c @ h, s @ h, c2, s2, n, var)


def _tau_terms(c2, s2, n):
    """cos ωτ, sin ωτ, 1/Σcos²ω(t-τ), 1/Σsin²ω(t-τ) from the τ sums (see `lomb_from_sums`)."""
    r2 = jnp.sqrt(c2**2 + s2**2)
    cos2 = jnp.where(r2 > 0, c2 / jnp.where(r2 > 0, r2, 1.0), 1.0)
    cwt = jnp.sqrt(jnp.clip(0.5 * (1 + cos2), 0.0, 1.0))
    swt = jnp.where(s2 >= 0, 1.0, -1.0) * jnp.sqrt(jnp.clip(0.5 * (1 - cos2), 0.0, 1.0))
    ss = 0.5 * (n - r2)
    ok = ss > 1e-9 * n
    return cwt, swt, 1.0 / (0.5 * (n + r2)), jnp.where(ok, 1.0 / jnp.where(ok, ss, 1.0), 0.0)


@persistent_jit(static_argnames=("n_fft", "j_lo", "j_hi"))
def _mask_terms(masks, *, n_fft, j_lo, j_hi):
    """τ terms of each distinct mask (mask, freq): from bins 2j of the mask's FFT."""
    fm = jnp.fft.rfft(masks, n=n_fft, axis=-1)
    q = (2 * np.arange(j_lo, j_hi + 1)) % n_fft
    # A real signal's FFT bin M - q is the conjugate of bin q: read bins past M/2 from there.
    upper = q > n_fft // 2
    z = fm[:, np.where(upper, n_fft - q, q)]
    z = jnp.where(upper, jnp.conj(z), z)
    n = jnp.sum(masks, axis=-1, keepdims=True)
    return jnp.stack(_tau_terms(z.real, -z.imag, n))


@persistent_jit(static_argnames=("n_fft", "j_lo", "j_hi", "keep", "search_dtype"))
def _grid_batch(h_dense, m_dense, terms, which, var, df_dt, *, n_fft, j_lo, j_hi, keep, search_dtype):
    """Peak search on dense, centred, zero-filled frame grids (window, frame) of one chunk.

    ``terms`` (4, mask, freq) are the τ terms of the distinct masks, ``which`` (window,) the
    mask of each window: the per-window work is one real FFT and a few multiply-adds. The grid
    is searched in ``search_dtype``; the peak bin is then evaluated again exactly, in float64,
    by direct sums (``df_dt`` = df * dt: cycles per bin per frame).
    """
    dtype = jnp.dtype(search_dtype)
    zh = jnp.fft.rfft(h_dense.astype(dtype), n=n_fft, axis=-1)[:, j_lo : j_hi + 1]
    ch, sh = zh.real, -zh.imag
    cwt, swt, inv_cc, inv_ss = (jnp.take(t.astype(dtype), which, axis=0) for t in terms)
    yc = ch * cwt + sh * swt
    ys = sh * cwt - ch * swt
    power = (yc**2 * inv_cc + ys**2 * inv_ss) / (2 * var[:, None].astype(dtype))
    i = jnp.argmax(power, axis=1)
    rows = jnp.arange(power.shape[0])
    last = power.shape[1] - 1
    pm = jnp.where(i > 0, power[rows, jnp.clip(i - 1, 0, last)], 0.0).astype(h_dense.dtype)
    pp = jnp.where(i < last, power[rows, jnp.clip(i + 1, 0, last)], 0.0).astype(h_dense.dtype)
    # Exact float64 P_N at the peak bin (it gives the FAP): t = k dt on the frame grid, so
    # ω t = 2π j df dt k. The neighbours only shape the parabola that seeds the fit.
    theta = 2 * jnp.pi * df_dt * (j_lo + i)
    ch, sh = _dft_at(h_dense, theta)
    c2, s2 = _dft_at(m_dense, 2 * theta)
    p0 = lomb_from_sums(ch, sh, c2, s2, jnp.sum(m_dense, axis=1), var)
    if dtype == jnp.float64:
        p0 = power[rows, i]  # already exact
    return i, p0, pm, pp, (power if keep else None)


@persistent_jit(static_argnames=("n_sub", "stride", "j_lo", "j_hi", "keep", "search_dtype"))
def _grid_batch_strided(h_dense, m_dense, var, df_dt, *, n_sub, stride, j_lo, j_hi, keep, search_dtype):
    """`_grid_batch` for grids too large for one FFT per window: the same bins, searched in
    ``stride`` interleaved sub-grids j = q·stride + r (q < n_sub), one residue r at a time.

    With M = n_sub·stride and frames k < n_sub, Σ_k h_k e^{-2πi k (q·stride + r)/M} is bin q of
    the n_sub-point FFT of h_k e^{-2πi k r/M}; the τ sums at 2j are bin 2q mod n_sub of the FFT
    of m_k e^{-2πi k 2r/M}. The peak memory is that of one sub-grid, whatever the oversampling.
    The peak bin and its neighbours are then evaluated exactly, in float64, by direct sums.
    """
    dtype = jnp.dtype(search_dtype)
    cdtype = jnp.result_type(dtype, jnp.complex64)
    n_fft = n_sub * stride
    k = jnp.arange(h_dense.shape[1])
    q = jnp.arange(n_sub)
    n = jnp.sum(m_dense, axis=1, keepdims=True)
    hv = h_dense.astype(cdtype)
    mv = m_dense.astype(cdtype)
    rows = jnp.arange(h_dense.shape[0])

    def one(carry, r):
        best_p, best_j = carry
        ramp = jnp.exp(-2j * jnp.pi * ((k * r) % n_fft) / n_fft)
        zh = jnp.fft.fft(hv * ramp.astype(cdtype), n=n_sub, axis=-1)
        zm = jnp.fft.fft(mv * (ramp**2).astype(cdtype), n=n_sub, axis=-1)[:, (2 * q) % n_sub]
        cwt, swt, inv_cc, inv_ss = _tau_terms(zm.real, -zm.imag, n.astype(dtype))
        ch, sh = zh.real, -zh.imag
        yc = ch * cwt + sh * swt
        ys = sh * cwt - ch * swt
        j = q * stride + r
        power = (yc**2 * inv_cc + ys**2 * inv_ss) / (2 * var[:, None].astype(dtype))
        power = jnp.where((j >= j_lo) & (j <= j_hi), power, -1.0)
        i = jnp.argmax(power, axis=1)
        p = power[rows, i].astype(best_p.dtype)
        better = p > best_p
        return (jnp.where(better, p, best_p), jnp.where(better, j[i], best_j)), (power if keep else None)

    start = (jnp.full(rows.shape, -2.0, var.dtype), jnp.full(rows.shape, j_lo, jnp.int64))
    (_, j_best), power = jax.lax.scan(one, start, jnp.arange(stride))
    last = j_hi - j_lo

    def exact(j):
        theta = 2 * jnp.pi * df_dt * j
        ch, sh = _dft_at(h_dense, theta)
        c2, s2 = _dft_at(m_dense, 2 * theta)
        return lomb_from_sums(ch, sh, c2, s2, n[:, 0], var)

    i = j_best - j_lo
    p0 = exact(j_best)
    pm = jnp.where(i > 0, exact(j_best - 1), 0.0)
    pp = jnp.where(i < last, exact(j_best + 1), 0.0)
    if keep:  # (residue, window, q) -> (window, j) on the searched band
        power = jnp.transpose(power, (1, 2, 0)).reshape(rows.size, n_fft)[:, j_lo : j_hi + 1]
    return i, p0, pm, pp, power


def _dft_at(x, theta):
    """Σ_k x_k cos θk and Σ_k x_k sin θk over the frames k of each row of ``x`` (window, frame).

    With k = a·n_b + b, e^{iθk} = e^{iθ n_b a} e^{iθb}: sines and cosines of n_a + n_b angles per
    window instead of one pair per frame, then one complex multiply-add per frame.
    """
    length = x.shape[1]
    n_b = min(64, length & -length)  # `bucket` lengths have a power-of-two factor
    xr = x.reshape(x.shape[0], length // n_b, n_b)
    sb, cb = sincos(theta[:, None] * jnp.arange(n_b, dtype=x.dtype))
    sa, ca = sincos(theta[:, None] * (n_b * jnp.arange(length // n_b, dtype=x.dtype)))
    xc = jnp.sum(xr * cb[:, None, :], -1)
    xs = jnp.sum(xr * sb[:, None, :], -1)
    return jnp.sum(ca * xc - sa * xs, -1), jnp.sum(sa * xc + ca * xs, -1)


def _parabola(i, p0, pm, pp, n_freq):
    """Sub-bin offset of the peak from the parabola through bins i-1, i, i+1 (0 at the edges)."""
    den = pm - 2 * p0 + pp
    with np.errstate(divide="ignore", invalid="ignore"):
        d = np.where((i > 0) & (i < n_freq - 1) & (den < 0), 0.5 * (pm - pp) / den, 0.0)
    return np.clip(d, -0.5, 0.5)


@dataclass(frozen=True)
class Periodogram:
    """Peak of the Lomb periodogram of every window (NaN where a window was not searched).

    Attributes:
        freq_hz: (window,) refined peak frequency.
        power: (window,) normalised power P_N of the highest grid bin.
        fap: (window,) false-alarm probability of that peak.
        n_indep: (window,) independent frequencies M used for the FAP.
        fmin_hz, fmax_hz, df_hz: (window,) the searched grid.
        method: (window,) "grid" or "nufft" ("" if not searched).
        spectra: window index -> (freq_hz, power) for the windows asked for with ``keep``.
    """

    freq_hz: np.ndarray
    power: np.ndarray
    fap: np.ndarray
    n_indep: np.ndarray
    fmin_hz: np.ndarray
    fmax_hz: np.ndarray
    df_hz: np.ndarray
    method: np.ndarray
    spectra: dict = field(default_factory=dict)


def _dense_grid(w: Windows, rows: np.ndarray, length: int):
    """Centred values and masks of ``rows`` laid on their frame grids: (window, frame) each."""
    y, m, k = w.y[rows], w.mask[rows], w.k[rows]
    n = m.sum(axis=1).astype(np.float64)
    ybar = np.where(m, y, 0.0).sum(axis=1) / n
    h = np.where(m, y - ybar[:, None], 0.0)
    var = (h**2).sum(axis=1) / (n - 1)  # (5.26)
    # One flat scatter per array; masked samples land in a spare last column, cut off after.
    flat = np.where(m, k, length) + (length + 1) * np.arange(rows.size)[:, None]
    dense_h = np.zeros((rows.size, length + 1))
    dense_m = np.zeros((rows.size, length + 1), bool)
    dense_h.ravel()[flat.ravel()] = h.ravel()
    dense_m.ravel()[flat.ravel()] = m.ravel()
    return dense_h[:, :length], dense_m[:, :length], n, var


def _peaks_grid(w: Windows, rows, out, fmin, fmax, oversampling, keep, search_dtype):
    dt = float(np.mean(w.dt[rows]))
    length = bucket(int(w.k[rows].max()) + 1)  # few distinct shapes: few compilations
    want_fft = int(math.ceil(oversampling * length))
    stride = 1
    if want_fft > _CHUNK_CELLS:  # one window's grid in interleaved sub-grids of <= _SUB_CELLS
        stride = pow2_at_least(-(-want_fft // _SUB_CELLS))
    n_sub = scipy.fft.next_fast_len(max(-(-want_fft // stride), length), real=True)
    n_sub += n_sub % 2
    n_fft = n_sub * stride
    df = 1.0 / (n_fft * dt)
    f_hi = 0.5 / dt if fmax is None else min(fmax, 0.5 / dt)
    f_lo = 1.0 / (length * dt) if fmin is None else fmin
    j_lo = max(1, math.ceil(f_lo / df - 1e-9))
    j_hi = min(n_fft // 2, math.floor(f_hi / df + 1e-9))
    if j_hi - j_lo < 2:
        raise ConfigError(f"--fmin/--fmax: the band {f_lo:g}..{f_hi:g} Hz holds fewer than 3 frequencies")
    n_freq = j_hi - j_lo + 1
    per_chunk = max(1, _CHUNK_CELLS // n_sub)
    chunk = chunk_rows(len(rows), per_chunk)
    _check_memory(n_fft * (chunk if stride == 1 else 1), length, 0, oversampling)
    keep_set = set(keep)
    for c0 in range(0, len(rows), chunk):
        sel = rows[c0 : c0 + chunk]
        pad = np.concatenate([sel, np.repeat(sel[:1], chunk - sel.size)])
        want = bool(keep_set.intersection(sel.tolist()))
        h, m, _, var = _dense_grid(w, pad, length)
        if stride > 1:
            i, p0, pm, pp, power = _grid_batch_strided(
                h,
                m.astype(np.float64),
                var,
                df * dt,
                n_sub=n_sub,
                stride=stride,
                j_lo=j_lo,
                j_hi=j_hi,
                keep=want,
                search_dtype=search_dtype,
            )
            _store_grid_peaks(out, sel, want, keep_set, (i, p0, pm, pp, power), j_lo, n_freq, df)
            continue
        # Frame drop-outs hit every plate and axis of a frame alike: windows of the same span
        # share their mask, so its FFT (the tau sums) is computed once per distinct mask.
        uniq, inverse = unique_rows(np.packbits(m, axis=1))
        u_pad = pow2_at_least(uniq.shape[0])
        masks = np.unpackbits(uniq, axis=1, count=length).astype(np.float64)
        masks = np.concatenate([masks, np.zeros((u_pad - masks.shape[0], length))])
        terms = _mask_terms(masks, n_fft=n_fft, j_lo=j_lo, j_hi=j_hi)
        i, p0, pm, pp, power = _grid_batch(
            h,  # numpy arrays straight into the kernel (no eager JAX op per array)
            m.astype(np.float64),
            terms,
            inverse.ravel(),
            var,
            df * dt,
            n_fft=n_fft,
            j_lo=j_lo,
            j_hi=j_hi,
            keep=want,
            search_dtype=search_dtype,
        )
        _store_grid_peaks(out, sel, want, keep_set, (i, p0, pm, pp, power), j_lo, n_freq, df)


def _store_grid_peaks(out, sel, want, keep_set, found, j_lo, n_freq, df):
    """Write a chunk's peaks (bin, power, neighbours, kept spectra) into ``out`` for rows ``sel``."""
    i, p0, pm, pp = (np.asarray(a)[: sel.size] for a in found[:4])
    out["freq_hz"][sel] = (j_lo + i + _parabola(i, p0, pm, pp, n_freq)) * df
    out["power"][sel] = p0
    out["fmin_hz"][sel] = j_lo * df
    out["fmax_hz"][sel] = (j_lo + n_freq - 1) * df
    out["df_hz"][sel] = df
    out["method"][sel] = "grid"
    if want:
        freqs = (j_lo + np.arange(n_freq)) * df
        power = np.asarray(found[4])
        for pos, r in enumerate(sel.tolist()):
            if r in keep_set:
                out["spectra"][r] = (freqs, power[pos])


def _stamp_groups(w: Windows, rows: np.ndarray) -> list[np.ndarray]:
    """``rows`` grouped by identical valid timestamps (the plates and axes of a window share
    their frames): each group is one batched non-uniform periodogram."""
    keys: dict[bytes, list[int]] = {}
    for r in rows.tolist():
        keys.setdefault(w.t[r, w.mask[r]].tobytes(), []).append(r)
    return [np.asarray(g) for g in keys.values()]


def _peaks_nufft(w: Windows, rows, out, fmin, fmax, oversampling, keep, search_dtype):
    import nifty_ls

    for group in _stamp_groups(w, rows):
        r0 = int(group[0])
        m = w.mask[r0]
        t = w.t[r0, m]
        ys = w.y[group][:, m]
        n = t.size
        span = (t[-1] - t[0]) * n / max(n - 1, 1)
        df = 1.0 / (oversampling * span)
        # Default: the Nyquist frequency of the median sampling interval.
        f_hi = 0.5 / float(np.median(np.diff(t))) if fmax is None else fmax
        f_lo = 1.0 / span if fmin is None else fmin
        f_lo = max(f_lo, df)
        n_freq = int(math.floor((f_hi - f_lo) / df + 1e-9)) + 1
        if n_freq < 3:
            raise ConfigError(f"--fmin/--fmax: the band {f_lo:g}..{f_hi:g} Hz holds fewer than 3 frequencies")
        _check_memory(n_freq, n, group.size, oversampling)
        res = nifty_ls.lombscargle(
            t - t[0],
            ys,
            fmin=f_lo,
            fmax=f_lo + (n_freq - 1) * df,
            Nf=n_freq,
            center_data=True,
            fit_mean=False,
            normalization="standard",
        )
        power = np.atleast_2d(np.asarray(res.power)) * (n - 1) / 2  # astropy "standard" -> thesis P_N
        i = np.argmax(power, axis=1)
        at = np.arange(group.size)
        pm = power[at, np.maximum(i - 1, 0)]
        pp = power[at, np.minimum(i + 1, n_freq - 1)]
        d = _parabola(i, power[at, i], pm, pp, n_freq)
        out["freq_hz"][group] = res.fmin + (i + d) * res.df
        out["power"][group] = power[at, i]
        out["fmin_hz"][group] = res.fmin
        out["fmax_hz"][group] = res.fmin + (n_freq - 1) * res.df
        out["df_hz"][group] = res.df
        out["method"][group] = "nufft"
        for pos, r in enumerate(group.tolist()):
            if r in keep:
                out["spectra"][r] = (res.freq(), power[pos])


METHODS = {"grid": _peaks_grid, "nufft": _peaks_nufft}


def lomb_peaks(
    w: Windows,
    rows: np.ndarray | None = None,
    fmin_hz: float | None = None,
    fmax_hz: float | None = None,
    oversampling: float = 5.0,
    method: Method = "auto",
    keep: tuple[int, ...] = (),
    search_dtype: Literal["float64", "float32"] = "float64",
) -> Periodogram:
    """Periodogram peak, refined frequency and false-alarm probability of every window.

    Args:
        w: the windows.
        rows: the windows to search (default: all with at least 3 valid samples).
        fmin_hz: lowest frequency (default: one cycle per window).
        fmax_hz: highest frequency (default: the Nyquist frequency of the frame interval).
        oversampling: grid points per periodogram peak width 1/T.
        method: "grid" (frame clock, exact FFT), "nufft" (any times) or "auto" (grid where the
            window is on its frame clock, else nufft).
        keep: window indices whose whole spectrum is returned (for figures).
        search_dtype: precision of the grid search on the frame clock. The peak power is
            always re-evaluated exactly in float64, so "float32" (4x faster FFTs) changes only
            the kept spectra and the sub-bin refinement (to ~1e-6 relative), and which of two
            bins equal to ~1e-6 is taken as the peak.
    """
    if method not in ("auto", *METHODS):
        raise ConfigError(f"method: expected one of auto, {', '.join(METHODS)}; got {method!r}")
    if search_dtype not in ("float64", "float32"):
        raise ConfigError(f"search_dtype: expected float64 or float32, got {search_dtype!r}")
    if not oversampling >= 1:
        raise ConfigError(f"--oversampling: expected >= 1, got {oversampling}")
    if fmin_hz is not None and fmax_hz is not None and not fmin_hz < fmax_hz:
        raise ConfigError(f"--fmin/--fmax: expected fmin < fmax, got {fmin_hz} and {fmax_hz}")
    if fmin_hz is not None and fmin_hz < 0:
        raise ConfigError(f"--fmin: expected >= 0 Hz, got {fmin_hz}")
    b = len(w)
    nan = lambda: np.full(b, np.nan)  # noqa: E731
    out = dict(
        freq_hz=nan(),
        power=nan(),
        fmin_hz=nan(),
        fmax_hz=nan(),
        df_hz=nan(),
        method=np.full(b, "", dtype=object),
        spectra={},
    )
    n_valid = w.mask.sum(axis=1)
    if rows is None:
        rows = np.flatnonzero(n_valid >= 3)
    rows = np.asarray(rows, dtype=np.int64)
    use_grid = w.on_clock[rows] if method == "auto" else np.full(rows.size, method == "grid")
    if method == "grid" and not w.on_clock[rows].all():
        raise ConfigError("method 'grid': some windows are not on a regular frame clock; use 'nufft'")
    grid_rows = rows[use_grid]
    if grid_rows.size:
        # One FFT grid per frame interval (equal to 1e-4: the peak is refined afterwards anyway).
        key = np.round(np.log(w.dt[grid_rows]) / 1e-4).astype(np.int64)
        for kv in np.unique(key):
            _peaks_grid(w, grid_rows[key == kv], out, fmin_hz, fmax_hz, oversampling, keep, search_dtype)
    if (~use_grid).any():
        _peaks_nufft(w, rows[~use_grid], out, fmin_hz, fmax_hz, oversampling, keep, search_dtype)
    m_ind = n_independent(_spans(w), out["fmin_hz"], out["fmax_hz"])
    fap = false_alarm_probability(out["power"], m_ind)
    return Periodogram(
        out["freq_hz"],
        out["power"],
        fap,
        m_ind,
        out["fmin_hz"],
        out["fmax_hz"],
        out["df_hz"],
        out["method"],
        out["spectra"],
    )


def _spans(w: Windows) -> np.ndarray:
    """Time span of the valid samples of each window, one frame interval included."""
    n = w.mask.sum(axis=1)
    lo = np.where(w.mask, w.t, np.inf).min(axis=1)
    hi = np.where(w.mask, w.t, -np.inf).max(axis=1)
    return np.where(n > 1, (hi - lo) * n / np.maximum(n - 1, 1), np.nan)
