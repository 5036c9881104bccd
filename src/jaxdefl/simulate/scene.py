"""The scene: beam, plates, occluders and floor; beam kinematics; static per-pixel ray casting.

The plates are bonded to the beam's side at its bottom (thesis 4.1), horizontal, sticking out
50 mm from the side face: the nadir camera sees them between the beam top and the floor.

The beam deflects with the elastic two-point-load shape (peak 1 at mid-span) scaled by the
mid-span deflection ``defl(t) = mean + A(N(t)) sin(2 pi f0 (t - t0) + phase)``; the amplitude A
grows with the number of cycles N (fatigue law). Plates move rigidly with the deflection at their
centre plus an in-phase longitudinal and lateral motion.

Everything that does not move (or only slides within its own plane) is ray-cast once per camera
(`pixel_model`): every pixel is split into S x S sub-rays and each sub-ray records what it hits
first, at which range, and how its range changes per millimetre of mid-span deflection. Plates
are handled analytically (`PixelModel.plate_*`): the overlap of the pixel footprint with the
moving plate rectangle gives a continuous coverage fraction, so plate edges are mixed pixels
whose mixture follows the plate's longitudinal and lateral motion.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from .._beam import beam_shape
from .injection import motion_terms

if TYPE_CHECKING:  # the config validates geometry through this module: no import cycle
    from .config import SimConfig

__all__ = [
    "beam_shape",
    "rotation_matrix",
    "Intrinsics",
    "intrinsics",
    "plate_centres_world",
    "plate_image_bounds",
    "camera_rotation",
    "camera_origin",
    "to_camera",
    "midspan_amplitude_mm",
    "kinematics",
    "PixelModel",
    "pixel_model",
    "KIND_STATIC",
    "KIND_BEAM_TOP",
    "KIND_SPREADER",
]

KIND_STATIC, KIND_BEAM_TOP, KIND_SPREADER = 0, 1, 2


@dataclass(frozen=True)
class Intrinsics:
    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    def as_dict(self) -> dict:
        return dict(fx=self.fx, fy=self.fy, cx=self.cx, cy=self.cy, width=self.width, height=self.height)


def intrinsics(cfg: SimConfig) -> Intrinsics:
    """Pinhole intrinsics from the field of view (pixel centres at integer coordinates)."""
    cam = cfg.camera
    fx = (cam.width / 2) / math.tan(math.radians(cam.fov_deg[0]) / 2)
    fy = (cam.height / 2) / math.tan(math.radians(cam.fov_deg[1]) / 2)
    return Intrinsics(fx, fy, (cam.width - 1) / 2, (cam.height - 1) / 2, cam.width, cam.height)


def plate_centres_world(cfg: SimConfig) -> np.ndarray:
    """(plate, 3) plate top-face centres in world coordinates (mm)."""
    p = cfg.plates
    x = np.asarray(cfg.plate_x_mm())
    y = np.full_like(x, cfg.beam.width_mm / 2 + p.width_mm / 2)
    z = np.full_like(x, p.depth_below_top_mm)
    return np.stack([x, y, z], axis=1)


def rotation_matrix(roll, pitch, yaw, xp=np):
    """R = Rz(yaw) Ry(pitch) Rx(roll) (radians), numpy or jax.numpy by ``xp``."""
    ca, sa = xp.cos(roll), xp.sin(roll)
    cb, sb = xp.cos(pitch), xp.sin(pitch)
    cc, sc = xp.cos(yaw), xp.sin(yaw)
    return xp.stack(
        [
            xp.stack([cc * cb, cc * sb * sa - sc * ca, cc * sb * ca + sc * sa]),
            xp.stack([sc * cb, sc * sb * sa + cc * ca, sc * sb * ca - cc * sa]),
            xp.stack([-sb, cb * sa, cb * ca]),
        ]
    )


def camera_rotation(cam) -> np.ndarray | None:
    """(3, 3) rotation R taking camera-frame vectors to the world (beam) frame, or None for a
    camera looking straight down with its columns along the beam (R = I).

    R = Rz(yaw) Ry(pitch) Rx(roll), angles in degrees (``camera.roll_deg`` etc.): roll turns the
    camera about the beam axis, pitch about the lateral axis, yaw about the vertical.
    """
    if cam.roll_deg == 0.0 and cam.pitch_deg == 0.0 and cam.yaw_deg == 0.0:
        return None
    return rotation_matrix(*(math.radians(v) for v in (cam.roll_deg, cam.pitch_deg, cam.yaw_deg)))


def camera_origin(cam) -> np.ndarray:
    """(3,) the camera's projection centre in world (beam-frame) coordinates, mm."""
    return np.array([cam.x_mm, cam.y_mm, -cam.standoff_mm])


def to_camera(cfg: SimConfig, xyz_world: np.ndarray) -> np.ndarray:
    """(..., 3) world points -> the camera frame of ``cfg.camera``: R^T (p - C)."""
    d = np.asarray(xyz_world, float) - camera_origin(cfg.camera)
    rot = camera_rotation(cfg.camera)
    return d if rot is None else d @ rot


def plate_image_bounds(cfg: SimConfig, plate: int) -> tuple[float, float, float, float]:
    """Image extent (u0, u1, v0, v1) of a plate's top face, pixel edges (0..width)."""
    k = intrinsics(cfg)
    hl, hw = cfg.plates.length_mm / 2, cfg.plates.width_mm / 2
    centre = plate_centres_world(cfg)[plate - 1]
    corners = np.array([centre + [sx * hl, sy * hw, 0.0] for sx in (-1, 1) for sy in (-1, 1)])
    c = to_camera(cfg, corners)
    u = k.fx * c[:, 0] / c[:, 2] + k.cx + 0.5
    v = k.fy * c[:, 1] / c[:, 2] + k.cy + 0.5
    return float(u.min()), float(u.max()), float(v.min()), float(v.max())


def _fatigue_factor(cfg: SimConfig, cycles):
    f = cfg.fatigue
    n = np.maximum(np.asarray(cycles, float), 1.0)
    if f.law == "none":
        return np.ones_like(n)
    (n0, n1), (a0, a1) = f.cycles, f.amplitude_mm
    if f.law == "log":
        b = (a1 - a0) / (math.log(n1) - math.log(n0))
        return a0 + b * (np.log(n) - math.log(n0))
    b = (a1 - a0) / (n1 - n0)
    return a0 + b * (n - n0)


def midspan_amplitude_mm(cfg: SimConfig, cycles):
    """Mid-span amplitude after ``cycles`` load cycles: the configured amplitude at the start of
    the recording, growing as the fatigue law (through the two anchors of ``[fatigue]``)."""
    start = _fatigue_factor(cfg, cfg.recording.cycles_at_start)
    return cfg.loading.amplitude_mm * _fatigue_factor(cfg, cycles) / start


def kinematics(cfg: SimConfig, t_s) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mid-span deflection (downward +), longitudinal and lateral motion (mm) at epoch times t."""
    ld = cfg.loading
    t_s = np.asarray(t_s, np.float64)
    tau = t_s - cfg.t0_s
    # the registry's motion effects ([[effect]] and [[change]] tables): a stiffness change's
    # phase (continuous, counted in load cycles) and amplitude, the load's AM / FM, its
    # harmonics, a second motion
    m = motion_terms(cfg.effects, tau, ld.frequency_hz)
    cycles = cfg.recording.cycles_at_start + ld.frequency_hz * tau + m.load_phase / (2 * np.pi)
    theta = 2 * np.pi * ld.frequency_hz * tau + m.load_phase + ld.phase_rad
    amp = midspan_amplitude_mm(cfg, cycles) * m.amplitude
    s = np.sin(theta + m.shift)
    defl = ld.mean_mm + amp * m.gain * s + sum((f(theta) for f in m.extra), np.zeros_like(tau))
    return defl, ld.longitudinal_mm * m.gain * s, ld.lateral_mm * s


@dataclass(frozen=True)
class PixelModel:
    """Static ray-cast of one camera; arrays are per pixel (p = row * width + col) and sub-ray."""

    intr: Intrinsics
    sub_range_mm: np.ndarray  # (p, s) range of the first hit, plates excluded
    sub_depth_mm: np.ndarray  # (p, s) camera-frame Z of the hit
    sub_kind: np.ndarray  # (p, s) KIND_*
    sub_gain: np.ndarray  # (p, s) d range / d mid-span deflection
    sub_gain_depth: np.ndarray  # (p, s) d depth / d mid-span deflection
    sub_bright: np.ndarray  # (p, s) reflectivity x cos^3 / range_m^2
    plate_idx: np.ndarray  # (p,) plate under the pixel footprint (0-based) or -1
    plate_foot: np.ndarray  # (p, 4) footprint X0, X1, Y0, Y1 (world mm) at the plate plane
    plate_range_mm: np.ndarray  # (p,) static range of the plate plane along the pixel ray
    plate_depth_mm: np.ndarray  # (p,) camera Z of the plate plane
    plate_gain: np.ndarray  # (p,) d range / d plate deflection (1 / cos)
    plate_bright: np.ndarray  # (p,)
    plate_occ: np.ndarray  # (p,) fraction of the footprint hidden by nearer objects
    plate_edges: np.ndarray  # (plate, 4) xa, xb, ya, yb (world mm) at rest
    plate_shape: np.ndarray  # (plate,) deflection / mid-span deflection
    plate_drop_mm: float = 0.0  # vertical distance from the camera down to the plates' top faces


def _boxes(cfg: SimConfig) -> list[tuple[np.ndarray, np.ndarray, float, str]]:
    """(lo, hi, reflectivity, role) world boxes; role 'beam', 'spreader' or 'static'."""
    b, sc, cam = cfg.beam, cfg.scene, cfg.camera
    hw = b.width_mm / 2
    boxes = [
        (
            np.array([-b.overhang_mm, -hw, 0.0]),
            np.array([b.span_mm + b.overhang_mm, hw, b.height_mm]),
            b.reflectivity,
            "beam",
        ),
    ]
    for xs in (0.0, b.span_mm):  # supports under the beam ends
        boxes.append(
            (
                np.array([xs - 75, -150, b.height_mm]),
                np.array([xs + 75, 150, sc.floor_below_top_mm]),
                0.3,
                "static",
            )
        )
    if sc.occluders:
        a = b.load_a_mm
        boxes.append(
            (np.array([a - 100, -75, -150.0]), np.array([b.span_mm - a + 100, 75, 0.0]), 0.35, "spreader")
        )
        mid = b.span_mm / 2
        top = -cam.standoff_mm - 800.0
        boxes.append((np.array([mid - 120, -120, top]), np.array([mid + 120, 120, -150.0]), 0.3, "static"))
    return boxes


def _ray_grid(intr: Intrinsics, s: int, rows: slice) -> np.ndarray:
    """(p, s*s, 3) ray directions (camera frame, z = 1) through a sub-pixel grid."""
    v = np.arange(intr.height)[rows].astype(np.float64)
    u = np.arange(intr.width, dtype=np.float64)
    off = (np.arange(s) + 0.5) / s - 0.5
    vv = v[:, None, None, None] + off[None, None, :, None]
    uu = u[None, :, None, None] + off[None, None, None, :]
    vv, uu = np.broadcast_arrays(vv, uu)
    x = (uu - intr.cx) / intr.fx
    y = (vv - intr.cy) / intr.fy
    d = np.stack([x, y, np.ones_like(x)], axis=-1)
    return d.reshape(-1, s * s, 3)


def pixel_model(cfg: SimConfig, supersample: int | None = None) -> PixelModel:
    """Ray-cast the static scene for the configured camera (plates handled analytically)."""
    intr = intrinsics(cfg)
    cam, b, sc, pl = cfg.camera, cfg.beam, cfg.scene, cfg.plates
    s = supersample or cam.supersample
    origin = camera_origin(cam)
    rot = camera_rotation(cam)  # None: nadir, the rays' world directions are their camera ones
    boxes = _boxes(cfg)
    shape_spreader = float(beam_shape(b.load_a_mm, b.span_mm, b.load_a_mm))
    centres = plate_centres_world(cfg)
    depth_p = float(cam.standoff_mm + pl.depth_below_top_mm)  # camera Z of the plates' top faces
    edges = np.stack(
        [
            centres[:, 0] - pl.length_mm / 2,
            centres[:, 0] + pl.length_mm / 2,
            centres[:, 1] - pl.width_mm / 2,
            centres[:, 1] + pl.width_mm / 2,
        ],
        axis=1,
    )
    outs = {k: [] for k in ("range", "depth", "kind", "gain", "gdepth", "bright", "occ")}
    rows_per = max(1, 2_000_000 // (intr.width * s * s * 8))
    for r0 in range(0, intr.height, rows_per):
        dc = _ray_grid(intr, s, slice(r0, r0 + rows_per))  # (p, s2, 3), camera z component 1
        norm = np.linalg.norm(dc, axis=-1)
        d = dc if rot is None else dc @ rot.T  # world directions; the ray parameter is camera Z
        # floor plane
        t_best = (sc.floor_below_top_mm - origin[2]) / d[..., 2]
        hit = origin + t_best[..., None] * d
        gx = np.mod(hit[..., 0], sc.target_spacing_mm) - sc.target_spacing_mm / 2
        gy = np.mod(hit[..., 1], sc.target_spacing_mm) - sc.target_spacing_mm / 2
        on_target = gx**2 + gy**2 < sc.target_radius_mm**2
        refl = np.where(on_target, sc.target_reflectivity, sc.floor_reflectivity)
        kind = np.full(t_best.shape, KIND_STATIC, np.int8)
        gain_z = np.zeros_like(t_best)
        cos_inc = d[..., 2] / norm  # Lambert: cosine between the ray and the face normal
        with np.errstate(divide="ignore", invalid="ignore"):
            for lo, hi, rf, role in boxes:
                t1 = (lo - origin) / d
                t2 = (hi - origin) / d
                tmin_ax = np.minimum(t1, t2)
                tmax_ax = np.maximum(t1, t2)
                tmin = tmin_ax.max(axis=-1)
                tmax = tmax_ax.min(axis=-1)
                entry_axis = tmin_ax.argmax(axis=-1)
                ok = (tmax >= tmin) & (tmin > 0) & (tmin < t_best)
                t_best = np.where(ok, tmin, t_best)
                refl = np.where(ok, rf, refl)
                top = entry_axis == 2
                if role == "beam":
                    xh = origin[0] + tmin * d[..., 0]
                    k_new = np.where(top, KIND_BEAM_TOP, KIND_STATIC)
                    g_new = np.where(top, beam_shape(xh, b.span_mm, b.load_a_mm), 0.0)
                elif role == "spreader":
                    k_new = np.where(top, KIND_SPREADER, KIND_STATIC)
                    g_new = np.where(top, shape_spreader, 0.0)
                else:
                    k_new, g_new = KIND_STATIC, 0.0
                kind = np.where(ok, k_new, kind).astype(np.int8)
                gain_z = np.where(ok, g_new, gain_z)
                c_new = np.abs(np.take_along_axis(d, entry_axis[..., None], axis=-1)[..., 0]) / norm
                cos_inc = np.where(ok, c_new, cos_inc)
        depth = t_best * dc[..., 2] + 0.0  # camera-frame Z (origin at the camera)
        rng = t_best * norm
        cosz = dc[..., 2] / norm  # off the optical axis
        cosv = cosz if rot is None else d[..., 2] / norm  # off the vertical
        outs["range"].append(rng)
        outs["depth"].append(depth)
        outs["kind"].append(kind)
        outs["gain"].append(gain_z / cosv)  # vertical move dz of a horizontal face: d range = dz/cos
        outs["gdepth"].append(gain_z if rot is None else gain_z / d[..., 2])
        # Lambertian face (cos of incidence) seen through the optics (cos^2 off axis): the top
        # faces and the floor get cos^3, the vertical sides of the beam and spreader much less
        outs["bright"].append(refl * cos_inc * cosz**2 / (rng / 1000.0) ** 2)
        # sub-rays that would meet a plate (at rest) but hit something nearer first
        t_p = depth_p if rot is None else depth_p / d[..., 2]  # ray parameter at the plates' plane
        hp = origin + (t_p * d if rot is None else t_p[..., None] * d)  # (d has z = 1 at nadir)
        on_plate = np.zeros(t_best.shape, bool)
        for xa, xb, ya, yb in edges:
            on_plate |= (hp[..., 0] >= xa) & (hp[..., 0] <= xb) & (hp[..., 1] >= ya) & (hp[..., 1] <= yb)
        hidden = on_plate & (t_best < t_p - 1e-6)
        outs["occ"].append(hidden.sum(axis=1) / np.maximum(on_plate.sum(axis=1), 1))
    cat = {k: np.concatenate(v, axis=0) for k, v in outs.items()}

    # plates, analytically
    v, u = np.meshgrid(np.arange(intr.height, dtype=float), np.arange(intr.width, dtype=float), indexing="ij")
    u, v = u.ravel(), v.ravel()
    if rot is None:
        x0 = origin[0] + depth_p * (u - 0.5 - intr.cx) / intr.fx
        x1 = origin[0] + depth_p * (u + 0.5 - intr.cx) / intr.fx
        y0 = origin[1] + depth_p * (v - 0.5 - intr.cy) / intr.fy
        y1 = origin[1] + depth_p * (v + 0.5 - intr.cy) / intr.fy
    else:
        # a turned pixel's footprint on the plates' plane is a quadrilateral: its bounding
        # rectangle stands for it (the coverage of a plate edge stays continuous in its motion)
        hits = []
        for du, dv in ((-0.5, -0.5), (0.5, -0.5), (-0.5, 0.5), (0.5, 0.5)):
            w = np.stack([(u + du - intr.cx) / intr.fx, (v + dv - intr.cy) / intr.fy, np.ones_like(u)], -1)
            w = w @ rot.T
            hits.append(origin[:2] + (depth_p / w[:, 2])[:, None] * w[:, :2])
        hits = np.stack(hits)  # (corner, p, 2)
        x0, x1 = hits[..., 0].min(axis=0), hits[..., 0].max(axis=0)
        y0, y1 = hits[..., 1].min(axis=0), hits[..., 1].max(axis=0)
    xc = (x0 + x1) / 2
    idx = np.argmin(np.abs(xc[:, None] - centres[None, :, 0]), axis=1)
    margin = 5.0  # mm: pixels farther than this from any plate never see one
    near = (
        (x1 > edges[idx, 0] - margin)
        & (x0 < edges[idx, 1] + margin)
        & (y1 > edges[idx, 2] - margin)
        & (y0 < edges[idx, 3] + margin)
    )
    idx = np.where(near, idx, -1)
    dx = (u - intr.cx) / intr.fx
    dy = (v - intr.cy) / intr.fy
    norm = np.sqrt(dx * dx + dy * dy + 1)
    cosz = 1 / norm
    # vertical component of the (camera z = 1) ray in the world: 1 at nadir
    dz = 1.0 if rot is None else np.stack([dx, dy, np.ones_like(dx)], -1) @ rot[2]
    t_plate = depth_p / dz  # camera Z of the plates' plane along each pixel's ray
    rng_p = t_plate * norm
    occ = cat["occ"]
    shape_p = beam_shape(centres[:, 0], b.span_mm, b.load_a_mm)
    return PixelModel(
        intr=intr,
        sub_range_mm=cat["range"],
        sub_depth_mm=cat["depth"],
        sub_kind=cat["kind"],
        sub_gain=cat["gain"],
        sub_gain_depth=cat["gdepth"],
        sub_bright=cat["bright"],
        plate_idx=idx.astype(np.int32),
        plate_foot=np.stack([x0, x1, y0, y1], axis=1),
        plate_range_mm=rng_p,
        plate_depth_mm=np.full_like(rng_p, depth_p) if rot is None else t_plate,
        plate_gain=norm / dz,
        plate_bright=pl.reflectivity
        * (cosz**3 if rot is None else dz / norm * cosz**2)
        / (rng_p / 1000.0) ** 2,
        plate_occ=occ,
        plate_edges=edges,
        plate_shape=np.asarray(shape_p, float),
        plate_drop_mm=depth_p,
    )
