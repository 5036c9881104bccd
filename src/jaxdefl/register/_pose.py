"""A camera's pose in the beam frame: one weighted least squares over every landmark at once.

The pose maps camera-frame points to the beam frame, ``p_beam = R p_cam + C``, with
R = Rz(yaw) Ry(pitch) Rx(roll) (the simulator's convention, `jaxdefl.simulate.scene`). Every
landmark is a camera-frame point, its beam-frame target and a weight per beam axis (1/σ, 0 where
the axis is free): a plate's rest centroid is pinned on all three axes; a point on the floor or
on the beam top only on z (its plane's height). Collinear plates alone leave the roll about the
beam free; the planes fix it. Solved by Levenberg-Marquardt (optimistix) from the nadir pose;
the covariance is (J^T J)^-1 of the weighted residuals at the solution (Gauss-Newton, e.g.
Hartley & Zisserman, Multiple View Geometry, 2nd ed., 5.2.3).
"""

from __future__ import annotations

import numpy as np

from .._jax import float64
from ..simulate.scene import rotation_matrix

__all__ = ["rotation_matrix", "solve_pose", "PARAMS"]

PARAMS = ("roll_mrad", "pitch_mrad", "yaw_mrad", "x_mm", "y_mm", "z_mm")


def _residuals(theta, args):
    import jax.numpy as jnp

    pts, target, weight, plane = args
    rot = rotation_matrix(theta[0] * 1e-3, theta[1] * 1e-3, theta[2] * 1e-3, jnp)
    # a plane's height is a nuisance (theta[6 + k]): a range bias common to a surface (its
    # reflectivity, scattered light) must not move the camera; the plane fixes the orientation
    shift = jnp.where(plane >= 0, theta[6:][jnp.maximum(plane, 0)], 0.0)
    moved = target + jnp.stack([jnp.zeros_like(shift), jnp.zeros_like(shift), shift], axis=-1)
    return (weight * (pts @ rot.T + theta[3:6] - moved)).ravel()


_SOLVERS: dict = {}


def _solver():
    if "pose" not in _SOLVERS:
        import jax
        import optimistix as optx

        def solve(theta0, pts, target, weight, plane):
            sol = optx.least_squares(
                _residuals,
                optx.LevenbergMarquardt(rtol=1e-10, atol=1e-10),
                theta0,
                args=(pts, target, weight, plane),
                max_steps=200,
                throw=False,
            )
            jac = jax.jacfwd(_residuals)(sol.value, (pts, target, weight, plane))
            return sol.value, jac, sol.result == optx.RESULTS.successful

        _SOLVERS["pose"] = jax.jit(solve)
    return _SOLVERS["pose"]


def solve_pose(
    pts_cam: np.ndarray,
    target_beam: np.ndarray,
    weight: np.ndarray,
    plane: np.ndarray,
    theta0: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, bool, np.ndarray]:
    """Weighted least-squares pose of one camera.

    Args:
        pts_cam: (point, 3) camera-frame landmarks, mm. target_beam: (point, 3) their beam-frame
            targets. weight: (point, 3) 1/σ per beam axis (0: that axis is free).
        plane: (point,) the plane (0, 1, ...) whose height offset a point shares, -1 for none.
        theta0: (6 + plane,) start: roll, pitch, yaw (mrad), C (mm), the planes' offsets (mm).
    Returns:
        theta, its covariance from the weighted Jacobian, converged, and the (point, 3)
        unweighted residuals R p + C - target (plane offsets included).
    """
    n = len(pts_cam)
    size = max(64, 1 << (n - 1).bit_length())  # a few shape buckets: one compilation each

    def pad(a, fill=0.0):
        a = np.asarray(a)
        return np.concatenate([a, np.full((size - n, *a.shape[1:]), fill, a.dtype)])

    with float64():
        import jax.numpy as jnp

        theta, jac, ok = _solver()(
            jnp.asarray(theta0, jnp.float64),
            jnp.asarray(pad(np.asarray(pts_cam, float)), jnp.float64),
            jnp.asarray(pad(np.asarray(target_beam, float)), jnp.float64),
            jnp.asarray(pad(np.asarray(weight, float)), jnp.float64),  # padded rows weigh 0
            jnp.asarray(pad(np.asarray(plane, np.int32), -1), jnp.int32),
        )
        theta, jac, ok = np.asarray(theta), np.asarray(jac), bool(ok)
    cov = np.linalg.pinv(jac.T @ jac)
    rot = rotation_matrix(*(theta[:3] * 1e-3))
    offsets = np.where(plane >= 0, theta[6:][np.maximum(plane, 0)] if len(theta) > 6 else 0.0, 0.0)
    resid = pts_cam @ rot.T + theta[3:6] - target_beam
    resid[:, 2] -= offsets
    return theta, cov, ok, resid
