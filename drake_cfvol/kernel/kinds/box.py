"""A box (row sizes: its half extents, m), and a half space read as a big box."""

from __future__ import annotations

import numpy as np
from numba import njit

from drake_cfvol.kernel.kinds.base import Geometry, ShapeKind, box_cover, box_vertices, normalised
from drake_cfvol.kernel.types import BOX

__all__ = ["Box", "HalfSpace", "HALF_SPACE_SIZE"]

#: A half space (an infinite floor) is modelled as a box this deep and wide, m.
HALF_SPACE_SIZE = 1000.0


@njit(cache=True, inline="always")
def support(s0, s1, s2, l0, l1, l2):
    """The support point along l (the box's frame)."""
    x = s0 if l0 >= 0 else -s0
    y = s1 if l1 >= 0 else -s1
    z = s2 if l2 >= 0 else -s2
    return x, y, z


@njit(cache=True, inline="always")
def extent(r0, r1, r2, s0, s1, s2):
    """Half the box's width along a world axis whose components in the
    box's frame are (r0, r1, r2)."""
    return abs(r0) * s0 + abs(r1) * s1 + abs(r2) * s2


@njit(cache=True, inline="always")
def core_radius(s0, s1, s2):
    """The radius the box's core (itself) is grown by: none."""
    return 0.0


@njit(cache=True, inline="always")
def excess(l0, l1, l2, s0, s1, s2):
    """The offset of point l (the box's frame) from the nearest point of the box."""
    return max(abs(l0) - s0, 0.0), max(abs(l1) - s1, 0.0), max(abs(l2) - s2, 0.0)


@njit(cache=True, inline="always")
def point_distance(prm, q, out_g, out_near):
    """Signed distance of point q from the box of half extents ``prm``
    (its frame), m; the unit gradient and the nearest surface point into
    ``out_g`` and ``out_near``. Inside: the nearest face."""
    x, y, z = q[0], q[1], q[2]
    outside = abs(x) > prm[0] or abs(y) > prm[1] or abs(z) > prm[2]
    if outside:
        cx, cy, cz = min(max(x, -prm[0]), prm[0]), min(max(y, -prm[1]), prm[1]), min(max(z, -prm[2]), prm[2])
        gx, gy, gz = normalised(x - cx, y - cy, z - cz, 0.0, 0.0, 1.0)
        out_g[0], out_g[1], out_g[2] = gx, gy, gz
        out_near[0], out_near[1], out_near[2] = cx, cy, cz
        return np.sqrt((x - cx) ** 2 + (y - cy) ** 2 + (z - cz) ** 2)
    face, best = 0, abs(x) - prm[0]
    for i in range(1, 3):
        if abs(q[i]) - prm[i] > best:
            face, best = i, abs(q[i]) - prm[i]
    sign = 1.0 if q[face] >= 0 else -1.0
    for i in range(3):
        out_g[i] = 0.0
        out_near[i] = q[i]
    out_g[face] = sign
    out_near[face] = sign * prm[face]
    return best


class Box(ShapeKind):
    """A box: sizes are its half extents (m)."""

    code = BOX
    name = "box"
    drake_names = ("Box",)
    exact_near = True
    point_query = True

    def geometry(self, shape) -> Geometry:
        return Geometry(self, np.asarray(shape.size(), float) / 2)

    def radius(self, sizes, verts) -> float:
        return float(np.linalg.norm(sizes))

    def half_extents(self, sizes, verts) -> np.ndarray:
        return np.asarray(sizes, float).copy()

    def cover(self, sizes, verts, tight=False) -> np.ndarray:
        return box_cover(np.asarray(sizes, float))

    def points(self, sizes, verts, rings=16) -> np.ndarray:
        return box_vertices(np.asarray(sizes, float))

    def probes(self, sizes, verts):
        return box_vertices(np.asarray(sizes, float)), np.zeros(8)


class HalfSpace(Box):
    """Drake's half space z <= 0 of its frame, held by the kernel as a box
    :data:`HALF_SPACE_SIZE` deep and wide below the plane (its centre that
    far down); the filter measures it with Drake alone."""

    name = "half space"
    drake_names = ("HalfSpace",)
    point_query = False
    unbounded = True

    def geometry(self, shape) -> Geometry:
        return Geometry(self, np.full(3, HALF_SPACE_SIZE / 2), centre=np.array([0.0, 0.0, -HALF_SPACE_SIZE / 2]))

    def probes(self, sizes, verts):
        return np.zeros((0, 3)), np.zeros(0)
