"""Fitzgibbon's direct least-squares ellipse fit (thesis eq. 5.10-5.21).

Numerically stable form of Halir and Flusser (1998): the scatter matrix is split into quadratic
and linear blocks, the constraint 4ac - b² = 1 reduces the problem to a 3x3 eigenproblem, and
the eigenvector with positive constraint value is the ellipse.
"""

from __future__ import annotations

import numpy as np

__all__ = ["Ellipse", "fit_ellipse"]


class Ellipse(tuple):
    """(xc, yc, a, b, theta): centre, semi-axes (a >= b) and the angle of the a axis."""

    __slots__ = ()

    def __new__(cls, xc, yc, a, b, theta):
        return super().__new__(cls, (float(xc), float(yc), float(a), float(b), float(theta)))

    xc = property(lambda s: s[0])
    yc = property(lambda s: s[1])
    a = property(lambda s: s[2])
    b = property(lambda s: s[3])
    theta = property(lambda s: s[4])


def fit_ellipse(x: np.ndarray, y: np.ndarray) -> Ellipse | None:
    """Direct least-squares ellipse through points (x, y); None if they define no ellipse."""
    x = np.asarray(x, np.float64)
    y = np.asarray(y, np.float64)
    if x.size < 6:
        return None
    mx, my = x.mean(), y.mean()
    sx, sy = max(x.std(), 1e-12), max(y.std(), 1e-12)
    xs, ys = (x - mx) / sx, (y - my) / sy  # normalise for conditioning
    d1 = np.stack([xs * xs, xs * ys, ys * ys], 1)
    d2 = np.stack([xs, ys, np.ones_like(xs)], 1)
    s1, s2, s3 = d1.T @ d1, d1.T @ d2, d2.T @ d2
    try:
        t = -np.linalg.solve(s3, s2.T)
    except np.linalg.LinAlgError:
        return None
    m = s1 + s2 @ t
    m = np.array([m[2] / 2, -m[1], m[0] / 2])  # C1^-1 M with C1 = [[0,0,2],[0,-1,0],[2,0,0]]
    w, v = np.linalg.eig(m)
    v = np.real(v)
    cond = 4 * v[0] * v[2] - v[1] ** 2
    pos = np.flatnonzero(cond > 0)
    if pos.size == 0:
        return None
    a1 = v[:, pos[0]]
    a, b, c = a1
    d, e, f = t @ a1
    # Undo the normalisation: conic in (x, y).
    A = a / sx**2
    B = b / (sx * sy)
    C = c / sy**2
    D = -2 * A * mx - B * my + d / sx
    E = -2 * C * my - B * mx + e / sy
    F = A * mx**2 + B * mx * my + C * my**2 - d * mx / sx - e * my / sy + f
    den = B * B - 4 * A * C
    if not den < 0:
        return None
    xc = (2 * C * D - B * E) / den
    yc = (2 * A * E - B * D) / den
    num = 2 * (A * E * E + C * D * D - B * D * E + den * F)
    root = np.sqrt((A - C) ** 2 + B * B)
    ax1 = -np.sqrt(num * (A + C + root)) / den
    ax2 = -np.sqrt(num * (A + C - root)) / den
    if not (np.isfinite(ax1) and np.isfinite(ax2)):
        return None
    theta = 0.5 * np.arctan2(-B, C - A)
    if ax1 < ax2:
        ax1, ax2 = ax2, ax1
        theta += np.pi / 2
    return Ellipse(xc, yc, ax1, ax2, (theta + np.pi / 2) % np.pi - np.pi / 2)
