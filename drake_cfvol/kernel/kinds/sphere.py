"""A sphere (row sizes: radius, 0, 0; m)."""

from __future__ import annotations

import numpy as np
from numba import njit

from drake_cfvol.kernel.kinds.base import Geometry, ShapeKind, normalised, round_points
from drake_cfvol.kernel.types import SPHERE

__all__ = ["Sphere"]


@njit(cache=True, inline="always")
def support(s0, s1, s2, l0, l1, l2):
    """The support point along l."""
    x = 0.0
    y = 0.0
    z = 0.0
    n = np.sqrt(l0 * l0 + l1 * l1 + l2 * l2)
    if n > 0:
        x = s0 * l0 / n
        y = s0 * l1 / n
        z = s0 * l2 / n
    return x, y, z


@njit(cache=True, inline="always")
def extent(r0, r1, r2, s0, s1, s2):
    """Half the sphere's width along any axis."""
    return s0


@njit(cache=True, inline="always")
def core_radius(s0, s1, s2):
    """The radius the core (the centre) is grown by."""
    return s0


@njit(cache=True, inline="always")
def excess(l0, l1, l2, s0, s1, s2):
    """The offset of point l from the core (the centre)."""
    return l0, l1, l2


@njit(cache=True, inline="always")
def point_distance(prm, q, out_g, out_near):
    """Signed distance of point q from the sphere of radius prm[0], m;
    the unit gradient and the nearest surface point into out_g, out_near."""
    x, y, z = q[0], q[1], q[2]
    gx, gy, gz = normalised(x, y, z, 0.0, 0.0, 1.0)
    out_g[0], out_g[1], out_g[2] = gx, gy, gz
    out_near[0], out_near[1], out_near[2] = prm[0] * gx, prm[0] * gy, prm[0] * gz
    return np.sqrt(x * x + y * y + z * z) - prm[0]


class Sphere(ShapeKind):
    """A sphere: sizes are (radius, 0, 0), m."""

    code = SPHERE
    name = "sphere"
    drake_names = ("Sphere",)
    exact_near = True
    point_query = True

    def geometry(self, shape) -> Geometry:
        return Geometry(self, np.array([shape.radius(), 0.0, 0.0]))

    def radius(self, sizes, verts) -> float:
        return float(sizes[0])

    def half_extents(self, sizes, verts) -> np.ndarray:
        return np.full(3, float(sizes[0]))

    def cover(self, sizes, verts, tight=False) -> np.ndarray:
        return np.array([[0.0, 0.0, 0.0, float(sizes[0])]])

    def points(self, sizes, verts, rings=16) -> np.ndarray:
        return round_points(float(sizes[0]), 0.0, float(sizes[0]), rings, discs=False)

    def round_radius(self, sizes) -> float:
        return float(sizes[0])

    def support_spheres(self, sizes, verts):
        return np.zeros((1, 3)), np.array([float(sizes[0])])
