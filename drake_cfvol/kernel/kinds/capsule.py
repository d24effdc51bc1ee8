"""A capsule along z (row sizes: radius, half length of its segment, 0; m)."""

from __future__ import annotations

import numpy as np
from numba import njit

from drake_cfvol.kernel.kinds.base import Geometry, ShapeKind, axial_cover, normalised, round_points, segment_cover
from drake_cfvol.kernel.types import CAPSULE

__all__ = ["Capsule"]


@njit(cache=True, inline="always")
def support(s0, s1, s2, l0, l1, l2):
    """The support point along l."""
    x = 0.0
    y = 0.0
    n = np.sqrt(l0 * l0 + l1 * l1 + l2 * l2)
    z = s1 if l2 >= 0 else -s1
    if n > 0:
        x = s0 * l0 / n
        y = s0 * l1 / n
        z += s0 * l2 / n
    return x, y, z


@njit(cache=True, inline="always")
def extent(r0, r1, r2, s0, s1, s2):
    """Half the capsule's width along a world axis whose components in its
    frame are (r0, r1, r2)."""
    return abs(r2) * s1 + s0


@njit(cache=True, inline="always")
def core_radius(s0, s1, s2):
    """The radius the core (the segment) is grown by."""
    return s0


@njit(cache=True, inline="always")
def excess(l0, l1, l2, s0, s1, s2):
    """The offset of point l from the core (the segment)."""
    return l0, l1, max(abs(l2) - s1, 0.0)


@njit(cache=True, inline="always")
def point_distance(prm, q, out_g, out_near):
    """Signed distance of point q from the capsule (radius prm[0], half
    length prm[1] about z), m; the unit gradient and the nearest surface
    point into out_g, out_near."""
    x, y, z = q[0], q[1], q[2]
    cz = min(max(z, -prm[1]), prm[1])
    gx, gy, gz = normalised(x, y, z - cz, 1.0, 0.0, 0.0)
    out_g[0], out_g[1], out_g[2] = gx, gy, gz
    out_near[0], out_near[1], out_near[2] = prm[0] * gx, prm[0] * gy, cz + prm[0] * gz
    return np.sqrt(x * x + y * y + (z - cz) ** 2) - prm[0]


class Capsule(ShapeKind):
    """A capsule along z: sizes are (radius, half length of the segment, 0), m."""

    code = CAPSULE
    name = "capsule"
    drake_names = ("Capsule",)
    exact_near = True
    point_query = True

    def geometry(self, shape) -> Geometry:
        return Geometry(self, np.array([shape.radius(), shape.length() / 2, 0.0]))

    def radius(self, sizes, verts) -> float:
        return float(sizes[0] + sizes[1])

    def half_extents(self, sizes, verts) -> np.ndarray:
        return np.array([sizes[0], sizes[0], sizes[1] + sizes[0]], float)

    def cover(self, sizes, verts, tight=False) -> np.ndarray:
        if tight:
            return segment_cover(float(sizes[0]), float(sizes[1]))
        return axial_cover(float(sizes[0]), float(sizes[1] + sizes[0]))

    def points(self, sizes, verts, rings=16) -> np.ndarray:
        return round_points(float(sizes[0]), float(sizes[1]), float(sizes[0]), rings, discs=False)

    def probes(self, sizes, verts):
        return np.array([[0.0, 0.0, -sizes[1]], [0.0, 0.0, sizes[1]]], float), np.full(2, float(sizes[0]))

    def round_radius(self, sizes) -> float:
        return float(sizes[0])
