"""Build the diagnosis context: series on the frame clock, nominal harmonics (the engine's
Gauss-Newton fits), the reference's harmonics and the tied nominal of plates with an LDS."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from .._errors import ConfigError, InputError, ParameterError
from .._numerics import harmonic_design, wls
from ..fit import estimate_windows
from ..fit.estimate import MAX_ABS_VALUE_MM
from ..io import layout_note, timestamp_note, validate_trajectory
from ..series import make_windows
from ..series.windows import frame_clock, windows_like
from ..settings import DiagnoseSettings
from ..spectral import lomb_peaks
from ..status import Status
from ._base import Context, Harmonic, Series, State
from .detectors.shared_fits import quadrature_weight, tap_response

__all__ = ["build_context"]

MIN_SAMPLES = 64


def _harmonic_rows(est: pd.DataFrame, t0: float) -> dict[tuple[int, str], Harmonic]:
    out = {}
    for row in est.itertuples():
        if row.status != Status.CONVERGED:
            continue
        om = 2 * math.pi * row.f0_hz
        out[(int(row.plate), row.axis)] = Harmonic(
            omega=om,
            C=row.amplitude_mm * math.cos(row.phase_rad),
            D=row.amplitude_mm * math.sin(row.phase_rad),
            offset=row.offset_mm,
            t_ref=0.5 * (row.t_start + row.t_end) - t0,
            sigma_omega=2 * math.pi * row.sigma_f0_hz,
            sigma_amplitude=row.sigma_amplitude_mm,
        )
    return out


def _linear_harmonic(t: np.ndarray, y: np.ndarray, omega: float, t_ref: float) -> Harmonic:
    """Offset, C, D at a given frequency (a series whose own peak was not significant)."""
    offset, c, d = wls(harmonic_design(omega * (t - t_ref)), y, cov=False)[0]
    return Harmonic(omega, float(c), float(d), float(offset), t_ref)


def _tied_offset(s: Series, h: Harmonic) -> Harmonic:
    return Harmonic(h.omega, h.C, h.D, float(np.mean(s.y - h.motion(s.t))), h.t_ref, h.sigma_omega)


def _through_taps(
    h: Harmonic, tap_spread_s: float, offsets: tuple[float, ...], quadrature: float = 0.5
) -> Harmonic:
    """The reference's harmonic as the camera's taps see it: Z = C − iD times H(ω; T) of the
    four taps at offsets·T after the frame stamp (`tap_response`, its tap pairs weighted by the
    plate's modulation phase, ``quadrature``): a ToF camera's gain loss and lead, part of its
    nominal physics when its taps are known (thesis Section 5.3)."""
    if tap_spread_s <= 0:
        return h
    z = complex(h.C, -h.D) * complex(tap_response(h.omega, tap_spread_s, offsets, quadrature=quadrature))
    return Harmonic(h.omega, z.real, -z.imag, h.offset, h.t_ref, h.sigma_omega, h.sigma_amplitude)


def _quadrature_weights(df: pd.DataFrame, settings: DiagnoseSettings) -> dict[int, float]:
    """Per plate, the (1, 3) tap pair's weight in its phase (`quadrature_weight`) from the plate's
    mean range (its centroid's distance from the camera) and the modulation frequency; empty
    when either is not known (the pairs then count alike, `tap_response`'s default).

    A ToF camera's lag behind its frame stamp depends on where the plate's range falls in the
    modulation period: at 29 MHz and 2.2-2.3 m the (1, 3) pair carries 80-90 % of the motion,
    so the lag is 0.45 of the frame period, not the 0.375 of equal pairs (4.3 ms at 20 Hz)."""
    if settings.sensor != "tof" or not settings.modulation_mhz or not {"x", "y", "z"} <= set(df.columns):
        return {}
    mean = df.groupby("plate")[["x", "y", "z"]].mean()
    r = np.sqrt((mean**2).sum(axis=1))
    fm = settings.modulation_mhz
    return {int(p): quadrature_weight(float(v), fm) for p, v in r.items() if np.isfinite(v)}


def nominal_tap_spread(settings: DiagnoseSettings) -> float:
    """The configured sensor's tap spread (s): a ToF camera whose tap offsets are known (a
    simulation config's) samples its four taps over one frame period; 0 when not known."""
    if settings.sensor != "tof" or settings.tap_offsets is None or not settings.frame_rate_hz:
        return 0.0
    return 1.0 / float(settings.frame_rate_hz)


def build_context(
    traj: pd.DataFrame,
    reference: pd.DataFrame | None = None,
    settings: DiagnoseSettings | None = None,
    source: str = "<table>",
    reference_source: str = "--reference",
    allow_no_motion: bool = False,
    f0_hint_hz: float | None = None,
) -> tuple[Context, list[State], list[str]]:
    """Validate the tables, fit the nominal model and return (context, nominal states, notes).

    ``settings`` (validated when made; default: none known) say what is known of the camera,
    the segment and the axes. ``source`` and ``reference_source`` name the tables in error
    messages (their files, for the CLI, which hands the tables over unvalidated: validation
    sorts millions of rows, once is enough).

    Raises:
        ParameterError: several segments without ``segment`` or an unknown one.
        InputError: a table that breaks the trajectory contract (see `validate_trajectory`).
    """
    settings = settings if settings is not None else DiagnoseSettings()
    segment, axes, timestamps = settings.segment, settings.axes, settings.timestamps
    frame_rate_hz = settings.frame_rate_hz
    df = validate_trajectory(traj.reset_index(drop=True), source, timestamps=timestamps)
    notes: list[str] = [n for n in [layout_note(df.attrs.get("layout"), source)] if n is not None]
    segs = [str(s) for s in df["segment"].unique()]
    if segment is None and len(segs) > 1:
        raise ParameterError(
            "segment",
            f"{source} has {len(segs)} segments ({', '.join(map(str, segs[:5]))}"
            f"{', ...' if len(segs) > 5 else ''}); choose one",
        )
    if segment is not None:
        if segment not in segs:
            raise ParameterError(
                "segment", f"{segment!r} is not in {source} (it has {', '.join(map(str, segs))})"
            )
        df = df[df["segment"] == segment]
    axes = tuple(a for a in ("z", "x", "y") if a in df.columns) if axes is None else axes
    if (note := timestamp_note(df.attrs.get("timestamps"))) is not None:
        notes.append(f"{source}: {note}")
    t0 = float(df["t"].min())
    t_all = np.unique(df["t"].to_numpy() - t0)
    if t_all.size < MIN_SAMPLES:
        raise InputError(f"{source}: {t_all.size} timestamps, the diagnosis needs at least {MIN_SAMPLES}")
    # the frame grid of every spectrum: the recovered clock (robust to jitter, drop-outs and a
    # logger's rounding), started from --frame-rate when it is given
    dt, k_all, on_clock = frame_clock(t_all, hint=1.0 / frame_rate_hz if frame_rate_hz else None)
    if not on_clock:
        notes.append("timestamps are not on a regular frame clock; spectra use the nearest frame")
    if frame_rate_hz and abs(dt * frame_rate_hz - 1.0) > 0.01:
        notes.append(
            f"the timestamps' frame interval {dt:.6g} s differs from 1/--frame-rate "
            f"({1.0 / frame_rate_hz:.6g} s) by more than 1 %; the grids follow the timestamps"
        )
    duration = float(t_all[-1] - t_all[0])
    n_frames = int(k_all.max()) + 1

    w = make_windows(df, axes=axes, window_s=None)
    est = estimate_windows(w).table
    free = _harmonic_rows(est, t0)
    # A significant peak whose harmonic fit did not converge (a motion dying away within the
    # record: a hammer hit's free vibration) keeps its periodogram peak; its harmonic is linear
    # at that frequency and the decay is left to the open-world envelope (`unnamed`).
    stuck = np.flatnonzero(
        (est["status"].to_numpy() == Status.DID_NOT_CONVERGE) & (est["peak_fap"].to_numpy() <= 0.01)
    )
    if stuck.size:
        peaks = lomb_peaks(w, rows=stuck)
        for row in stuck:
            r = est.iloc[row]
            key = (int(r["plate"]), r["axis"])
            g = df[df["plate"] == key[0]]
            t, y = g["t"].to_numpy() - t0, g[key[1]].to_numpy()
            ok = np.isfinite(y)
            free[key] = _linear_harmonic(
                t[ok], y[ok], 2 * math.pi * float(peaks.freq_hz[row]), 0.5 * duration
            )
            notes.append(
                f"plate {key[0]} {key[1]}: the harmonic fit did not converge (a decaying motion?); "
                f"harmonic at its periodogram peak {peaks.freq_hz[row]:.6g} Hz"
            )
    if not free and f0_hint_hz:
        # the record's line, found once its level path was out (`record_kind`): a level path
        # that holds the variance hides the line from each series' own periodogram
        for key, g in df.groupby("plate"):
            t = g["t"].to_numpy() - t0
            for axis in axes:
                y = g[axis].to_numpy()
                ok = np.isfinite(y)
                if ok.sum() >= 8:
                    free[(int(key), axis)] = _linear_harmonic(
                        t[ok], y[ok], 2 * math.pi * f0_hint_hz, 0.5 * duration
                    )
        notes.append(
            f"no series' own periodogram shows its line over the level path: harmonic at the record's "
            f"{f0_hint_hz:.6g}-Hz line (record kind)"
        )
    if not free and not allow_no_motion:
        raise InputError(f"{source}: no plate and axis shows a significant periodic motion to diagnose")
    if not free:  # a load path, not a vibration (`record_kind`): one cycle over the record
        notes.append("no plate and axis shows a significant periodic motion")
        free = {(-1, ""): Harmonic(2 * math.pi / max(duration, 1e-9), 0.0, 0.0, 0.0, 0.5 * duration)}
    f0 = float(
        np.median([h.f0_hz for (p, a), h in free.items() if a == "z"] or [h.f0_hz for h in free.values()])
    )

    series: list[Series] = []
    frees: list[Harmonic] = []
    left_out: list[dict] = []
    for plate, g in df.groupby("plate", sort=True):
        t = g["t"].to_numpy() - t0
        k = k_all[np.searchsorted(t_all, t)]  # the frame of each stamp on the recovered clock
        for axis in axes:
            y = g[axis].to_numpy()
            ok = np.isfinite(y)
            if (np.abs(y[ok]) > MAX_ABS_VALUE_MM).any():
                notes.append(f"plate {plate} {axis}: values beyond {MAX_ABS_VALUE_MM:g} mm, left out")
                left_out.append(
                    dict(plate=int(plate), axis=axis, status=Status.VALUE_OUT_OF_RANGE, n=int(ok.sum()))
                )
                continue
            if ok.sum() < MIN_SAMPLES:
                notes.append(f"plate {plate} {axis}: {int(ok.sum())} samples, left out")
                left_out.append(
                    dict(plate=int(plate), axis=axis, status=Status.TOO_FEW_SAMPLES, n=int(ok.sum()))
                )
                continue
            s = Series(int(plate), axis, t[ok], y[ok], k[ok])
            h = free.get((int(plate), axis))
            # a plate at a support barely moves: its own strongest line may be another one (2 f0)
            if h is None or abs(h.f0_hz / f0 - 1.0) > 0.1:
                why = "no significant peak of its own" if h is None else f"its peak is at {h.f0_hz:.4f} Hz"
                h = _linear_harmonic(s.t, s.y, 2 * math.pi * f0, 0.5 * duration)
                notes.append(f"plate {plate} {axis}: {why}; harmonic at f0 = {f0:.4f} Hz")
            series.append(s)
            frees.append(h)

    ref_series: dict[int, Series] = {}
    ref_harm: dict[int, Harmonic] = {}
    if reference is not None:
        ref = validate_trajectory(
            reference.reset_index(drop=True),
            reference_source,
            required=("t", "plate", "z"),
            timestamps=timestamps,
        )
        if (note := layout_note(ref.attrs.get("layout"), reference_source)) is not None:
            notes.append(note)
        if (note := timestamp_note(ref.attrs.get("timestamps"))) is not None:
            notes.append(f"{reference_source}: {note}")
        if not np.isin(ref["plate"].unique(), df["plate"].unique()).any():
            raise ConfigError(
                f"{reference_source}: no plate of the reference "
                f"({', '.join(map(str, sorted(ref['plate'].unique())[:8]))}) is in {source}"
            )
        ref = ref[(ref["t"] >= t0 + t_all[0]) & (ref["t"] <= t0 + t_all[-1])]
        cam_plates = {s.plate for s in series if s.axis == "z"}
        ref = ref[ref["plate"].isin(cam_plates)]
        # The LDS samples far faster than the camera (300 Hz, 2 µm): every m-th sample keeps
        # ~8 samples per loading cycle at full precision and costs a fraction of the fit.
        if len(ref) > 1:
            dt_ref = float(np.median(np.diff(ref["t"].to_numpy()[: min(len(ref), 10000)])))
            step = max(1, int(1.0 / (8 * f0 * dt_ref))) if dt_ref > 0 else 1
            ref = ref[ref.groupby("plate").cumcount().to_numpy() % step == 0]
        if ref.empty:
            notes.append("the reference has no plate of the camera table within its time span")
        else:
            like = w.table[w.table["axis"] == "z"]
            rw = windows_like(ref, like)
            rest = estimate_windows(rw).table
            for (plate, _), h in _harmonic_rows(rest, t0).items():
                g = ref[ref["plate"] == plate]
                tr = g["t"].to_numpy() - t0
                ref_series[plate] = Series(
                    plate, "z", tr, g["z"].to_numpy(), np.rint(tr / dt).astype(np.int64)
                )
                ref_harm[plate] = h
            for plate in sorted(set(ref["plate"].unique()) - set(ref_harm)):
                notes.append(f"reference plate {plate}: no significant motion in the LDS; not used")

    taps = settings.tap_offsets if settings.tap_offsets is not None else (0.0, 0.25, 0.5, 0.75)
    tap_spread = nominal_tap_spread(settings)
    quadrature = _quadrature_weights(df, settings) if tap_spread > 0 else {}
    nominal: list[Harmonic] = []
    states: list[State] = []
    for i, (s, h) in enumerate(zip(series, frees, strict=True)):
        if s.axis == "z" and s.plate in ref_harm:
            hr = ref_harm[s.plate]
            if math.cos(hr.phase - h.phase - hr.omega * (h.t_ref - hr.t_ref)) < 0:
                notes.append(
                    f"reference plate {s.plate}: the LDS moves against the camera's z; its sign is flipped"
                )
                hr = Harmonic(
                    hr.omega, -hr.C, -hr.D, -hr.offset, hr.t_ref, hr.sigma_omega, hr.sigma_amplitude
                )
                ref_harm[s.plate] = hr
            series[i] = s = Series(s.plate, s.axis, s.t, s.y, s.k, tied=True)
            # the camera's modelled lag is nominal: what `timing_error` and `motion_artefact`
            # find is what remains after it
            h_nom = _tied_offset(s, _through_taps(hr, tap_spread, taps, quadrature.get(s.plate, 0.5)))
            n_params = 1
        else:
            h_nom = h
            n_params = 4
        nominal.append(h_nom)
        states.append(
            State(
                mean=h_nom(s.t),
                scale=np.ones(s.n),
                inlier=np.ones(s.n, bool),
                n_params=n_params,
            )
        )
    ctx = Context(
        series=series,
        nominal=nominal,
        free=frees,
        reference=ref_series,
        reference_harmonic=ref_harm,
        t0=t0,
        duration_s=duration,
        dt_s=float(dt),
        n_frames=n_frames,
        f0_hz=f0,
        sensor=settings.sensor,
        frame_rate_hz=float(frame_rate_hz) if frame_rate_hz else 1.0 / float(dt),
        modulation_mhz=settings.modulation_mhz,
        tap_offsets=taps,
        tap_spread_s=tap_spread,
        left_out=tuple(left_out),
        **(
            {k: getattr(settings, k) for k in ("depth_step_mm_at_2m", "jumps_per_minute", "jump_mm")}
            if settings.sensor == "structured_light"
            else {}
        ),
    )
    return ctx, states, notes
