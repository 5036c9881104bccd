"""Several cameras into the beam's frame and onto one clock; the plates they share, fused.

For each camera (`register_cameras`):

1. Pose (`_pose`): its plates' mean centroids (camera frame) against their rest positions,
   and the floor and beam-top points of its median frame against their planes, in one weighted
   least squares; every landmark group's σ is its own residual scatter (refitted until the
   groups' weights settle), so the pose's covariance carries what the landmarks disagree by.
2. Clock (`_clock`): the plates' vertical motion in the beam frame against a reference motion:
   the LDS (the true clock; then offsets are absolute) or, without one, the first camera's
   strongest shared plate (offsets relative to that camera). A ToF camera's four correlation
   samples are spread over its frame: the motion it reports belongs to the mean sample time,
   ``sampling_delay`` after the stamp (``tap_offsets`` of the recording); the clock offset
   reported is the stamp's, the delay taken off.
3. Profile: amplitude and phase of every plate's vertical motion at the reference frequency on
   the reference clock, per camera; a plate seen by several cameras is fused by inverse-variance
   weights with a χ² test of their agreement (`_clock.fuse`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pandas as pd

from .._numerics import mad_sigma
from ._clock import fit_clock, fit_reference, fuse, harmonic, sampling_delay_s
from ._pose import PARAMS, rotation_matrix, solve_pose
from ._scene import BeamGeometry, floor_targets, plane_landmarks

__all__ = ["CameraInput", "Registration", "register_cameras", "CONSISTENCY_P_MIN"]

CONSISTENCY_P_MIN = 0.01  # a shared plate's cameras disagree below this χ² p-value
_TOLERANCES_MM = (150.0, 60.0, 30.0, 30.0)  # plane membership, loosest first
_MIN_SIGMA_MM = {"plates": 0.05, "floor": 0.2, "top": 0.2, "targets": 0.2}


@dataclass(frozen=True)
class CameraInput:
    """One camera: its camera-frame trajectory (t, plate, x, y, z), a sample of its frames."""

    name: str
    trajectory: pd.DataFrame
    points: np.ndarray  # (h, w, 3) camera-frame points of its median frame (`scene_points`)
    amplitude: np.ndarray | None = None  # (h, w) its median amplitude image: the floor targets
    # a ToF camera's sampling (`sampling_delay_s`): the recording's tap_offsets, frame rate and
    # non-ambiguity range; None: a measurement belongs to its stamp
    taps: tuple[tuple[float, float, float, float], float, float] | None = None

    def delays_s(self, plate: np.ndarray) -> np.ndarray:
        """(row,) how long after its stamp each plate's measurement was taken."""
        if self.taps is None:
            return np.zeros(len(plate))
        offsets, rate, nar = self.taps
        rng = np.linalg.norm(self.trajectory.groupby("plate")[["x", "y", "z"]].mean(), axis=1)
        per_plate = pd.Series(
            sampling_delay_s(rng, nar, offsets, rate), self.trajectory.groupby("plate").size().index
        )
        return per_plate.reindex(plate).to_numpy()


@dataclass(frozen=True)
class Registration:
    poses: pd.DataFrame  # camera, param, value, sigma
    clocks: pd.DataFrame  # camera, reference, offset_ms, sigma_offset_ms, rate_ppm, ...
    landmarks: pd.DataFrame  # camera, group, n, sigma_mm
    trajectory: pd.DataFrame  # segment (= camera), camera, t (reference clock), plate, x, y, z (beam frame)
    profile: pd.DataFrame  # source, plate, x_mm, amplitude_mm, sigma..., phase_rad, sigma...
    common: pd.DataFrame  # plate, cameras, amplitude_mm, sigma, chi2, p_value, consistent
    reference: dict


def _pose_of(cam: CameraInput, geo: BeamGeometry) -> tuple[np.ndarray, np.ndarray, dict, bool]:
    mean = cam.trajectory.groupby("plate")[["x", "y", "z"]].mean()
    mean = mean[(mean.index >= 1) & (mean.index <= len(geo.plate_centres_mm))]
    pc = mean.to_numpy()
    pw = geo.plate_centres_mm[mean.index.to_numpy() - 1]
    theta = np.concatenate([np.zeros(3), (pw - pc).mean(axis=0), np.zeros(2)])
    sig = {"plates": np.array([3.0, 3.0, 1.0]), "floor": 5.0, "top": 5.0, "targets": 5.0}
    counts = {}
    xy_ok = np.ones(len(pc), bool)  # a plate cut by the image's edge: its x, y left out
    for tol in _TOLERANCES_MM:
        rot = rotation_matrix(*(theta[:3] * 1e-3))
        lp, lz = plane_landmarks(cam.points, rot, theta[3:6], geo, tol)
        is_floor = lz != 0.0
        groups = {"plates": slice(0, len(pc))}
        w_planes = np.zeros((len(lp), 3))
        w_planes[is_floor, 2] = 1 / sig["floor"]
        w_planes[~is_floor, 2] = 1 / sig["top"]
        if cam.amplitude is not None:
            tc, tw = floor_targets(cam.points, cam.amplitude, rot, theta[3:6], geo, tol)
        else:
            tc, tw = np.zeros((0, 3)), np.zeros((0, 3))
        pts = np.concatenate([pc, lp, tc])
        target = np.concatenate([pw, np.stack([np.zeros_like(lz), np.zeros_like(lz), lz], 1), tw])
        w_plates = np.broadcast_to(1 / sig["plates"], pc.shape).copy()
        w_plates[~xy_ok, :2] = 0.0
        w_targets = np.zeros_like(tc)
        w_targets[:, :2] = 1 / sig["targets"]
        weight = np.concatenate([w_plates, w_planes, w_targets])
        plane = np.concatenate([np.full(len(pc), -1), np.where(is_floor, 0, 1), np.full(len(tc), -1)])
        theta, cov, ok, resid = solve_pose(pts, target, weight, plane, theta)
        # each group's σ from its own residuals (6 parameters shared out by the group's size)
        n_all = len(pc) * 3 + len(lp) + 2 * len(tc)
        inflate = math.sqrt(n_all / max(n_all - len(theta), 1))
        rp = resid[groups["plates"]]
        sig["plates"] = np.maximum(
            np.sqrt(np.mean(rp[xy_ok] ** 2, axis=0)) * inflate, _MIN_SIGMA_MM["plates"]
        )
        sig["plates"][2] = max(np.sqrt(np.mean(rp[:, 2] ** 2)) * inflate, _MIN_SIGMA_MM["plates"])
        # x, y outliers against the median plate (robust scale), never below 5 mm
        scale = mad_sigma(rp[:, :2], axis=0)
        far = np.abs(rp[:, :2] - np.median(rp[:, :2], axis=0)) > np.maximum(4 * scale, 5.0)
        xy_ok = ~far.any(axis=1) if (~far.any(axis=1)).sum() >= 2 else xy_ok
        rl = resid[len(pc) : len(pc) + len(lp), 2]
        rt = resid[len(pc) + len(lp) :, :2]
        if len(tc) >= 3:
            sig["targets"] = max(float(np.sqrt(np.mean(rt**2))) * inflate, _MIN_SIGMA_MM["targets"])
        for g, m in (("floor", is_floor), ("top", ~is_floor)):
            if m.sum() >= 3:
                sig[g] = max(float(np.sqrt(np.mean(rl[m] ** 2))) * inflate, _MIN_SIGMA_MM[g])
        counts = {
            "plates": int(xy_ok.sum()),
            "floor": int(is_floor.sum()),
            "top": int((~is_floor).sum()),
            "targets": len(tc),
        }
    cov = cov + _group_jackknife(pts, target, weight, plane, theta, len(pc), is_floor, len(tc))
    info = {g: (counts[g], sig[g]) for g in counts}
    info["floor_offset_mm"], info["top_offset_mm"] = float(theta[6]), float(theta[7])
    info["inliers"] = mean.index[xy_ok].tolist()
    return theta[:6], cov[:6, :6], info, ok


def _group_jackknife(pts, target, weight, plane, theta, n_plates, is_floor, n_targets) -> np.ndarray:
    """Delete-one-group jackknife covariance of the pose over the landmark groups (the plates' x
    and y, the floor, the beam top, the floor targets): what the groups disagree by beyond their
    scatter (a range bias smooth across a surface, an extraction's bias) enters the σ's.

    Returns (6 + planes, 6 + planes) (G - 1) / G sum (theta_-g - mean)(theta_-g - mean)^T, zero
    where a group is missing."""
    n_lp = len(is_floor)
    rows = {
        "plates": (np.arange(n_plates), [0, 1]),
        "floor": (n_plates + np.flatnonzero(is_floor), [2]),
        "top": (n_plates + np.flatnonzero(~is_floor), [2]),
        "targets": (n_plates + n_lp + np.arange(n_targets), [0, 1]),
    }
    out = []
    for idx, axes in rows.values():
        if len(idx) < 3:
            continue
        w = weight.copy()
        w[np.ix_(idx, axes)] = 0.0
        th, _, ok, _ = solve_pose(pts, target, w, plane, theta)
        if ok:
            out.append(th)
    if len(out) < 2:
        return np.zeros((len(theta), len(theta)))
    d = np.asarray(out) - np.mean(out, axis=0)
    return (len(out) - 1) / len(out) * d.T @ d


def _frequency(t: np.ndarray, z: np.ndarray, fmax_hz: float) -> float:
    """The strongest line of a series (Hz) up to ``fmax_hz`` (the cameras' Nyquist frequency):
    the best single sinusoid over a grid of frequencies."""
    t = np.asarray(t, float) - t[0]
    z = np.asarray(z, float) - np.mean(z)
    span = t[-1]
    dt = np.median(np.diff(t))
    grid = np.arange(2.0 / span, min(0.5 / dt, fmax_hz), 0.2 / span)
    w = 2 * np.pi * grid[:, None] * t[None, :]
    c, s = np.cos(w) @ z, np.sin(w) @ z
    return float(grid[np.argmax(c * c + s * s)])


def _strong_plates(tz: pd.DataFrame) -> list[int]:
    """Plates whose vertical motion is at least a quarter of the strongest one's."""
    spread = tz.groupby("plate")["z"].std()
    return spread.index[spread >= 0.25 * spread.max()].tolist()


def register_cameras(
    cams: list[CameraInput], geo: BeamGeometry, lds: pd.DataFrame | None = None
) -> Registration:
    """Pose, clock and profile of every camera (see module doc).

    Args:
        cams: the cameras; the first is the clock reference when there is no ``lds``.
        geo: the beam frame's landmarks.
        lds: optional reference table (t, plate, z), true clock, z down.
    """
    pose_rows, land_rows, beam = [], [], {}
    for cam in cams:
        theta, cov, info, ok = _pose_of(cam, geo)
        sig = np.sqrt(np.diag(cov))
        for name, v, s in zip(PARAMS, theta, sig, strict=True):
            pose_rows.append(dict(camera=cam.name, param=name, value=float(v), sigma=float(s), converged=ok))
        for g in ("plates", "floor", "top", "targets"):
            n, s = info[g]
            land_rows.append(
                dict(
                    camera=cam.name,
                    group=g,
                    n=n,
                    sigma_mm=float(np.mean(s)) if np.ndim(s) else float(s),
                    offset_mm=info.get(f"{g}_offset_mm", 0.0),
                )
            )
        rot = rotation_matrix(*(theta[:3] * 1e-3))
        tr = cam.trajectory
        xyz = tr[["x", "y", "z"]].to_numpy(float) @ rot.T + theta[3:]
        beam[cam.name] = pd.DataFrame(
            {
                "t": tr["t"].to_numpy(float),
                "plate": tr["plate"].to_numpy(),
                "x": xyz[:, 0],
                "y": xyz[:, 1],
                "z": xyz[:, 2],
            }
        )

    t0 = float(math.floor(min(b["t"].min() for b in beam.values())))
    shared = _shared_plates(beam)
    if lds is not None and len(lds):
        ref_name = "lds"
        lp = lds.groupby("plate")["z"].std()
        ref_plate = next((p for p in shared if p in lp.index), int(lp.idxmax()))
        rs = lds[lds["plate"] == ref_plate].sort_values("t")
        ref_t, ref_z = rs["t"].to_numpy(float), rs["z"].to_numpy(float)
    else:
        first = cams[0]
        ref_name = first.name
        b = beam[first.name]
        ref_plate = next(
            (p for p in shared if p in set(b["plate"])), int(b.groupby("plate")["z"].std().idxmax())
        )
        rs = b[b["plate"] == ref_plate].sort_values("t")
        ref_t = rs["t"].to_numpy(float) + first.delays_s(rs["plate"].to_numpy())
        ref_z = rs["z"].to_numpy(float)
    nyquist = min(0.5 / np.median(np.diff(np.unique(b["t"].to_numpy()))) for b in beam.values())
    ref = fit_reference(ref_t, ref_z, t0, _frequency(ref_t, ref_z, nyquist))
    ref.update(source=ref_name, plate=int(ref_plate), t0_s=t0)

    clock_rows, traj_rows = [], []
    for cam in cams:
        b = beam[cam.name]
        if cam.name == ref_name:
            clk = dict(
                offset_ms=0.0,
                sigma_offset_ms=0.0,
                rate_ppm=0.0,
                sigma_rate_ppm=0.0,
                t_mid_s=float(b["t"].mean()),
                offset_mid_ms=0.0,
                sigma_offset_mid_ms=0.0,
                rms_mm=np.nan,
                ok=True,
            )
        else:
            use = b[b["plate"].isin(_strong_plates(b))]
            plate = use["plate"].to_numpy()
            clk = fit_clock(use["t"].to_numpy(), use["z"].to_numpy(), plate, t0, ref, cam.delays_s(plate))
        delays = cam.delays_s(np.unique(b["plate"].to_numpy()))
        clock_rows.append(
            dict(
                camera=cam.name,
                reference=ref_name,
                offset_ms=clk["offset_ms"],
                sigma_offset_ms=clk["sigma_offset_ms"],
                rate_ppm=clk["rate_ppm"],
                sigma_rate_ppm=clk["sigma_rate_ppm"],
                t_mid_s=clk["t_mid_s"],
                offset_mid_ms=clk["offset_mid_ms"],
                sigma_offset_mid_ms=clk["sigma_offset_mid_ms"],
                sampling_delay_ms=float(np.mean(delays)) * 1e3,
                rms_mm=clk["rms_mm"],
                converged=clk["ok"],
            )
        )
        # the instant each measurement stands for, on the reference clock
        stamp = b["t"].to_numpy() + cam.delays_s(b["plate"].to_numpy())
        tau = t0 + (stamp - t0 - clk["offset_ms"] * 1e-3) / (1 + clk["rate_ppm"] * 1e-6)
        traj_rows.append(b.assign(t=tau).assign(camera=cam.name))
    # each camera a segment of its own: `jaxdefl fit` reads the table as it is
    traj = pd.concat(traj_rows, ignore_index=True)[["camera", "t", "plate", "x", "y", "z"]]
    traj.insert(0, "segment", traj["camera"])

    prof = []
    f = ref["f_hz"]
    for (name, plate), g in traj.groupby(["camera", "plate"], sort=False):
        h = harmonic(g["t"].to_numpy(), g["z"].to_numpy(), f, t0)
        prof.append(dict(source=name, plate=int(plate), x_mm=float(g["x"].mean()), **h))
    if lds is not None and len(lds):
        for plate, g in lds.groupby("plate"):
            h = harmonic(g["t"].to_numpy(float), g["z"].to_numpy(float), f, t0)
            prof.append(dict(source="lds", plate=int(plate), x_mm=float(geo.plate_x_mm()[plate - 1]), **h))
    profile = pd.DataFrame(prof)
    common = []
    cam_prof = profile[profile["source"].isin([c.name for c in cams])]
    for plate in shared:
        g = cam_prof[cam_prof["plate"] == plate]
        fa = fuse(g["amplitude_mm"], g["sigma_amplitude_mm"])
        fp = fuse(np.unwrap(g["phase_rad"].to_numpy()), g["sigma_phase_rad"])
        common.append(
            dict(
                plate=int(plate),
                cameras=",".join(g["source"]),
                amplitude_mm=fa["value"],
                sigma_amplitude_mm=fa["sigma"],
                chi2_amplitude=fa["chi2"],
                p_amplitude=fa["p_value"],
                phase_rad=fp["value"],
                sigma_phase_rad=fp["sigma"],
                chi2_phase=fp["chi2"],
                p_phase=fp["p_value"],
                consistent=bool(min(fa["p_value"], fp["p_value"]) >= CONSISTENCY_P_MIN),
            )
        )
    return Registration(
        poses=pd.DataFrame(pose_rows),
        clocks=pd.DataFrame(clock_rows),
        landmarks=pd.DataFrame(land_rows),
        trajectory=traj,
        profile=profile,
        common=pd.DataFrame(common, columns=_COMMON_COLUMNS),
        reference=ref,
    )


_COMMON_COLUMNS = [
    "plate",
    "cameras",
    "amplitude_mm",
    "sigma_amplitude_mm",
    "chi2_amplitude",
    "p_amplitude",
    "phase_rad",
    "sigma_phase_rad",
    "chi2_phase",
    "p_phase",
    "consistent",
]


def _shared_plates(beam: dict[str, pd.DataFrame]) -> list[int]:
    """Plates seen by more than one camera."""
    seen: dict[int, int] = {}
    for b in beam.values():
        for p in set(b["plate"].tolist()):
            seen[p] = seen.get(p, 0) + 1
    return sorted(p for p, n in seen.items() if n > 1)
