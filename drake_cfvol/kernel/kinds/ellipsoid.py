"""An ellipsoid (row sizes: its semi-axes, m)."""

from __future__ import annotations

import numpy as np
from numba import njit

from drake_cfvol.kernel.kinds.base import Geometry, ShapeKind, box_cover, box_vertices
from drake_cfvol.kernel.types import ELLIPSOID

__all__ = ["Ellipsoid"]


@njit(cache=True, inline="always")
def support(s0, s1, s2, l0, l1, l2):
    """The support point along l."""
    x = 0.0
    y = 0.0
    z = 0.0
    a0 = s0 * s0 * l0
    a1 = s1 * s1 * l1
    a2 = s2 * s2 * l2
    n = np.sqrt(a0 * l0 + a1 * l1 + a2 * l2)
    if n > 0:
        x = a0 / n
        y = a1 / n
        z = a2 / n
    return x, y, z


@njit(cache=True, inline="always")
def extent(r0, r1, r2, s0, s1, s2):
    """Half the ellipsoid's width along a world axis whose components in
    its frame are (r0, r1, r2)."""
    return np.sqrt((r0 * s0) ** 2 + (r1 * s1) ** 2 + (r2 * s2) ** 2)


class Ellipsoid(ShapeKind):
    """An ellipsoid: sizes are its semi-axes a, b, c (m). Its cover and
    points are its bounding box's; the filter measures it with Drake."""

    code = ELLIPSOID
    name = "ellipsoid"
    drake_names = ("Ellipsoid",)

    def geometry(self, shape) -> Geometry:
        return Geometry(self, np.array([shape.a(), shape.b(), shape.c()], float))

    def radius(self, sizes, verts) -> float:
        return float(np.max(sizes))

    def half_extents(self, sizes, verts) -> np.ndarray:
        return np.asarray(sizes, float).copy()

    def cover(self, sizes, verts, tight=False) -> np.ndarray:
        return box_cover(np.asarray(sizes, float))

    def points(self, sizes, verts, rings=16) -> np.ndarray:
        return box_vertices(np.asarray(sizes, float))

    def round_radius(self, sizes) -> float:
        return float(np.max(sizes))

    def support_spheres(self, sizes, verts):
        return np.zeros((1, 3)), np.array([float(np.max(sizes))])  # the ball about it
