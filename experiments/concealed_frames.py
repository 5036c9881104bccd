"""Concealed physics in the FRAMES: the whole chain (simulate -> extract -> diagnose), with a
detection curve against the evidence that reaches the trajectories.

    python experiments/concealed_frames.py [--effects ID ...] [--signals 20 40 80 160]
        [--reps 2] [--controls 0] [--seconds 60] [--seed 71] [--held-out ID] [--out DIR]

Each rep is one ToF recording of the thesis' Experiment II day 1 (`configs/exp2_tof_3hz.toml`,
SR4000-class at 20 Hz, 3 % drop-outs, plates 4-9 in view, four-phase sampling with its motion
artefact, range noise correlated across the pixels of a frame) rendered pixel by pixel. The
effects are `[[effect]]` tables of the simulator's registry (`jaxdefl.simulate.injection`),
injected where the physics acts: ``drift`` and ``level_jump`` on every pixel's range (a camera
warming up, a range offset), the modulations, ``extra_periodic`` and ``harmonic_distortion`` on
the beam's motion (``mode_shape``: the 2nd or 3rd bending mode across the plates). The recording is extracted (`extract_recording`, tracked mode) and diagnosed
blind (the table and the user's hints: sensor and frame rate; no LDS, so the nominal ToF motion
artefact is not a finding).

Evidence. Every recording of a rep has the same seed, so its noise is identical pixel for pixel
to the rep's control (the same recording without an effect). The effect's footprint on the
trajectories is the difference Δ of the two extracted tables, and r is Δ after removing what the
nominal model absorbs (offset, the harmonic at f0 and a small change of its frequency). The
evidence S is the known-form test's noncentrality under the noise as it is: Σ_t r_tᵀ Σ⁻¹ r_t over
the frames, with Σ the covariance across plates and axes of the control's residuals (the ToF
range noise is correlated across the pixels of a frame, so an effect common to the plates carries
less evidence than the same size on independent series). "S_indep" = Σ r²/σ², the plates taken as
independent, is printed next to it. One pilot recording per effect and rep (a unit size) measures
S₁; the grid's sizes scale it (S ∝ size² for these effects), and the S reported is the one
measured on the recording itself.

Controls: each rep's own recording without an effect, plus ``--controls N`` recordings of their
own seeds. Scoring: detected = the injected id is reported on at least half of the plates in view; a
control is flagged when it gets any effect or unnamed term. With ``--held-out ID`` the diagnosis
runs without ID in its vocabulary, and a case counts when it is modelled as unnamed (ΔBIC < −10,
on at least half of the plates) with no vocabulary name claimed. The oracle column is the
known-form likelihood-ratio test's 95 % point at α = 0.05 / (number of effects), as in
`detection_curve.py`.

Writes DIR/cases.csv and DIR/curve.csv (a stopped run resumes from DIR/cases.csv) and prints the
table.
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
import tomllib
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parent))
from detection_curve import oracle_signal  # noqa: E402

from jaxdefl.diagnose import diagnose  # noqa: E402
from jaxdefl.frames import extract_recording  # noqa: E402
from jaxdefl.io.recording import open_recording  # noqa: E402
from jaxdefl.reconcile.engine import effect_tables_toml  # noqa: E402
from jaxdefl.simulate import simulate_to_dir  # noqa: E402
from jaxdefl.simulate.effects import EFFECT_IDS  # noqa: E402
from jaxdefl.simulate.injection import make_spec  # noqa: E402

CONFIG = Path(__file__).resolve().parents[1] / "configs" / "exp2_tof_3hz.toml"
DEFAULT_EFFECTS = (
    "drift",
    "level_jump",
    "amplitude_modulation",
    "frequency_modulation",
    "extra_periodic",
    "harmonic_distortion",
    "mode_shape",
)
F0 = 3.068  # day 1's loading frequency (Hz)


def draw_unit(eid: str, rng: np.random.Generator, seconds: float) -> dict:
    """The effect's parameters at a unit size (the size parameter is scaled later)."""
    sign = rng.choice([-1.0, 1.0])
    if eid == "drift":
        return {"amplitude_mm": sign * 0.3, "tau_s": float(rng.uniform(0.15, 0.5) * seconds)}
    if eid == "level_jump":
        return {"t_jump_s": float(rng.uniform(0.25, 0.75) * seconds), "size_mm": sign * 0.2}
    slow = float(rng.uniform(2.0, 6.0) / seconds)  # 2-6 cycles of the modulation in the record
    psi = float(rng.uniform(0, 2 * math.pi))
    if eid == "amplitude_modulation":
        return {"depth": 0.05, "freq_hz": slow, "phase_rad": psi}
    if eid == "frequency_modulation":
        return {"depth_rad": 0.05, "freq_hz": slow, "phase_rad": psi}
    if eid == "extra_periodic":
        while True:
            f = float(rng.uniform(0.5, 9.0))
            if min(abs(f - k * F0) for k in (1, 2, 3)) > 0.3:
                break
        return {"freq_hz": f, "amplitude_mm": 0.2, "phase_rad": psi}
    if eid == "mode_shape":
        while True:
            f = float(rng.uniform(0.5, 9.0))
            if min(abs(f - k * F0) for k in (1, 2, 3)) > 0.3:
                break
        return {"mode": int(rng.choice([2, 3])), "freq_hz": f, "amplitude_mm": 0.3, "phase_rad": psi}
    if eid == "harmonic_distortion":
        return {"order": int(rng.choice([2, 3])), "amplitude_mm": 0.2, "phase_rad": psi}
    if eid == "camera_shake":  # the camera's slow random motion along its optical axis
        return {"rms_mm": 0.2, "corner_hz": slow}
    if eid == "stiffness_change":  # a crack: amplitude × 1/(1 + s), frequency × √(1 + s)
        return {"t_s": float(rng.uniform(0.25, 0.75) * seconds), "stiffness_change": -2e-4}
    raise SystemExit(f"concealed_frames: no frame-level draw for effect '{eid}'")


SIZE = {
    "drift": "amplitude_mm",
    "level_jump": "size_mm",
    "amplitude_modulation": "depth",
    "frequency_modulation": "depth_rad",
    "extra_periodic": "amplitude_mm",
    "harmonic_distortion": "amplitude_mm",
    "mode_shape": "amplitude_mm",
    "camera_shake": "rms_mm",
    "stiffness_change": "stiffness_change",
}


def simulate_extract(work: Path, name: str, seed: int, seconds: float, effect: dict | None) -> pd.DataFrame:
    """Render the recording (with ``effect``: {"id", parameters...}) and extract its plates."""
    base = CONFIG.read_text()
    if effect is not None:
        params = {k: v for k, v in effect.items() if k != "id"}
        spec = make_spec(effect["id"], params, (), "concealed_frames", "effect")
        base = base.rstrip("\n") + "\n\n" + effect_tables_toml((spec,))
    cfg = work / f"{name}.toml"
    cfg.write_text(base)
    tomllib.loads(base)  # a bad table fails here, not inside the simulator
    out = work / name
    simulate_to_dir(cfg, out, duration_s=seconds, seed=seed, progress=False, session="day1")
    df = extract_recording(open_recording(out / "recording.zarr"), realtime=True, progress=False)
    return df


def _design(t: np.ndarray) -> np.ndarray:
    """Offset, the harmonic at f0 and its first derivative in frequency (what the fit absorbs)."""
    tc = t - t.mean()
    w = 2 * math.pi * F0 * tc
    return np.column_stack([np.ones_like(tc), np.cos(w), np.sin(w), tc * np.cos(w), tc * np.sin(w)])


def evidence(effect: pd.DataFrame, control: pd.DataFrame) -> tuple[float, float]:
    """(S, S_cov) of the effect's footprint on the trajectories (module doc).

    S treats every plate and axis as independent; S_cov is the known-form evidence under the
    noise's covariance across plates and axes at a frame (estimated on the control's residuals,
    frames where every plate was found): Σ_t r_tᵀ Σ⁻¹ r_t. The frame-correlated range noise makes
    S_cov smaller than S for an effect common to the plates."""
    m = control.merge(effect, on=["t", "plate"], suffixes=("_c", "_e"))
    t = np.sort(m.t.unique())
    X = _design(t - t[0])
    rc_cols, rd_cols, s = [], [], 0.0
    for _, g in m.groupby("plate"):
        rows = np.searchsorted(t, g.t.to_numpy())
        Xg = X[rows]
        for ax in ("x", "y", "z"):
            c = g[f"{ax}_c"].to_numpy()
            d = g[f"{ax}_e"].to_numpy() - c
            rc = c - Xg @ np.linalg.lstsq(Xg, c, rcond=None)[0]
            rd = d - Xg @ np.linalg.lstsq(Xg, d, rcond=None)[0]
            s += float(np.sum(rd**2) / np.var(rc))
            add_series(rc_cols, rd_cols, len(t), rows, rc, rd)
    return s, covariance_evidence(rc_cols, rd_cols)


def add_series(rc_cols: list, rd_cols: list, n_frames: int, rows, rc, rd) -> None:
    """Append one series' control residual ``rc`` and effect footprint ``rd`` at frame
    positions ``rows`` as full columns (NaN where the plate was not found)."""
    full_c, full_d = np.full(n_frames, np.nan), np.full(n_frames, np.nan)
    full_c[rows], full_d[rows] = rc, rd
    rc_cols.append(full_c)
    rd_cols.append(full_d)


def covariance_evidence(rc_cols: list, rd_cols: list) -> float:
    """Σ_t r_tᵀ Σ⁻¹ r_t of the footprint columns under the control residuals' covariance across
    series (frames where every series was found), scaled to all frames."""
    rc, rd = np.column_stack(rc_cols), np.column_stack(rd_cols)
    ok = np.isfinite(rc).all(axis=1)
    cov = np.cov(rc[ok], rowvar=False)
    s_cov = float(np.einsum("ti,ij,tj->", rd[ok], np.linalg.inv(cov), rd[ok]))
    return s_cov * len(rc) / max(ok.sum(), 1)


def diagnose_blind(df: pd.DataFrame, held_out: str | None) -> dict:
    extra = {"effects": tuple(e for e in EFFECT_IDS if e != held_out)} if held_out else {}
    return diagnose(df, None, sensor="tof", frame_rate_hz=20.0, **extra)


def score(diag: dict, eid: str | None, plates: list[int], held_out: str | None) -> dict:
    names = sorted({e["id"] for e in diag.get("effects", [])})
    unnamed = diag.get("unnamed", [])
    if eid is None:
        return {"flagged": bool(names or unnamed), "names": ",".join(names), "detected": False}
    if held_out:
        rep = {int(p) for u in unnamed if u.get("delta_bic", 0) < -10 for p in (u.get("plates") or [])}
        ok = eid not in names and len(rep & set(plates)) >= len(plates) / 2
        return {"flagged": bool(names or unnamed), "names": ",".join(names), "detected": ok}
    rep = {int(p) for e in diag.get("effects", []) if e["id"] == eid for p in (e.get("plates") or [])}
    return {
        "flagged": True,
        "names": ",".join(names),
        "detected": len(rep & set(plates)) >= len(plates) / 2,
    }


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--effects", nargs="+", default=list(DEFAULT_EFFECTS))
    ap.add_argument("--signals", type=float, nargs="+", default=[20, 40, 80, 160])
    ap.add_argument("--reps", type=int, default=2)
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--seed", type=int, default=71)
    ap.add_argument("--controls", type=int, default=0, help="extra controls (own seeds) besides each rep's")
    ap.add_argument("--held-out", default=None, help="diagnose without this id; score unnamed modelling")
    ap.add_argument("--out", type=Path, default=Path("concealed_frames_out"))
    args = ap.parse_args(argv)
    for e in args.effects:
        if e not in SIZE:
            ap.error(f"--effects: no frame-level draw for '{e}' (expected one of {', '.join(SIZE)})")
    if args.held_out:
        args.effects = [args.held_out]
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / "cases.csv"
    done = pd.read_csv(path) if path.exists() else pd.DataFrame()
    rows = done.to_dict("records")
    seen = {(str(r["rep"]), r["effect"], float(r["target_s"])) for r in rows}
    t_start = time.perf_counter()

    def record(row):
        rows.append(row)
        pd.DataFrame(rows).to_csv(path, index=False)
        print(
            f"rep {row['rep']} {row['effect']:>22} S {row['target_s']:>6g} -> {row['signal']:8.1f}"
            f" (independent plates: {row['signal_indep']:8.1f})"
            f"  detected {row['detected']!s:5}  names [{row['names']}]  {row['seconds']:.0f} s",
            flush=True,
        )

    for rep in range(args.reps):
        seed = args.seed * 1000 + rep
        rng = np.random.default_rng([args.seed, rep])
        keys = [(str(rep), e, float(x)) for e in args.effects for x in args.signals]
        if all(k in seen for k in keys) and (args.held_out or (str(rep), "control", 0.0) in seen):
            continue
        with tempfile.TemporaryDirectory(prefix="concealed_frames_") as tmp:
            work = Path(tmp)
            t0 = time.perf_counter()
            control = simulate_extract(work, "control", seed, args.seconds, None)
            plates = sorted(int(p) for p in control.plate.unique())
            if (str(rep), "control", 0.0) not in seen and not args.held_out:
                sc = score(diagnose_blind(control, None), None, plates, None)
                record(dict(rep=rep, effect="control", target_s=0.0, signal=0.0, signal_indep=0.0, size=0.0,
                            seconds=time.perf_counter() - t0, **sc))
            for eid in args.effects:
                unit = draw_unit(eid, rng, args.seconds)
                todo = [s for s in args.signals if (str(rep), eid, float(s)) not in seen]
                if not todo:
                    continue
                pilot = simulate_extract(work, f"{eid}_pilot", seed, args.seconds, {"id": eid, **unit})
                s1 = evidence(pilot, control)[1]
                for target in todo:
                    t0 = time.perf_counter()
                    size = unit[SIZE[eid]] * math.sqrt(target / s1)
                    eff = {"id": eid, **unit, SIZE[eid]: size}
                    df = simulate_extract(work, f"{eid}_{target:g}", seed, args.seconds, eff)
                    s_ind, sig = evidence(df, control)
                    try:
                        sc = score(diagnose_blind(df, args.held_out), eid, plates, args.held_out)
                    except Exception as err:  # a failure is a result, not the end of the run
                        sc = {"flagged": False, "names": f"error: {type(err).__name__}", "detected": False}
                    record(dict(rep=rep, effect=eid, target_s=float(target), signal=sig, signal_indep=s_ind, size=size,
                                seconds=time.perf_counter() - t0, **sc))
    for k in range(args.controls):
        if (f"c{k}", "control", 0.0) in seen:
            continue
        with tempfile.TemporaryDirectory(prefix="concealed_frames_") as tmp:
            t0 = time.perf_counter()
            control = simulate_extract(Path(tmp), "control", args.seed * 1000 + 500 + k, args.seconds, None)
            plates = sorted(int(p) for p in control.plate.unique())
            sc = score(diagnose_blind(control, None), None, plates, None)
            record(dict(rep=f"c{k}", effect="control", target_s=0.0, signal=0.0, signal_indep=0.0, size=0.0,
                        seconds=time.perf_counter() - t0, **sc))
    cases = pd.DataFrame(rows)
    alpha = 0.05 / len(EFFECT_IDS)
    s95 = oracle_signal(0.95, alpha)
    eff = cases[cases.effect != "control"]
    curve = (
        eff.pivot_table(index="effect", columns="target_s", values="detected", aggfunc="mean")
        if len(eff)
        else pd.DataFrame()
    )
    curve.to_csv(args.out / "curve.csv")
    ctl = cases[cases.effect == "control"]
    print(f"\nframe-level detection ({'held out: ' + args.held_out if args.held_out else 'named and located'}),"
          f" {args.reps} rep(s), {args.seconds:g}-s recordings, seed {args.seed}; oracle S95 = {s95:.1f}")
    print(curve.round(2).to_string())
    if len(ctl):
        print(f"controls flagged: {int(ctl.flagged.sum())}/{len(ctl)} [{'; '.join(ctl.names.astype(str))}]")
    print(f"{time.perf_counter() - t_start:.0f} s")


if __name__ == "__main__":
    main()
