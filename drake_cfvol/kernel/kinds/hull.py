"""The convex hull of a mesh or convex shape (what Drake uses for a mesh in
point-pair queries): its vertices about their bounding box's centre, rows
``[first, end)`` of the kernel's vertex table; row sizes unused."""

from __future__ import annotations

import numpy as np
from numba import njit

from drake_cfvol.exceptions import WorkcellError
from drake_cfvol.kernel.kinds.base import Geometry, ShapeKind, polytope_cover
from drake_cfvol.kernel.types import HULL

__all__ = ["Hull"]


@njit(cache=True, inline="always")
def support(verts, v0, v1, l0, l1, l2):
    """The support point along l: the farthest of vertices [v0, v1)."""
    x = 0.0
    y = 0.0
    z = 0.0
    best = -1e300
    for v in range(v0, v1):
        h = verts[v, 0] * l0 + verts[v, 1] * l1 + verts[v, 2] * l2
        if h > best:
            best = h
            x = verts[v, 0]
            y = verts[v, 1]
            z = verts[v, 2]
    return x, y, z


@njit(cache=True, inline="always")
def extent(verts, v0, v1, r0, r1, r2):
    """(lowest, highest) of vertices [v0, v1) along a world axis whose
    components in the hull's frame are (r0, r1, r2)."""
    lo = np.inf
    hi = -np.inf
    for v in range(v0, v1):
        x = r0 * verts[v, 0] + r1 * verts[v, 1] + r2 * verts[v, 2]
        if x < lo:
            lo = x
        if x > hi:
            hi = x
    return lo, hi


class Hull(ShapeKind):
    """A mesh's or convex shape's convex hull (Drake's ``GetConvexHull``)."""

    code = HULL
    name = "convex hull"
    drake_names = ("Mesh", "Convex")

    def geometry(self, shape) -> Geometry:
        hull = shape.GetConvexHull()
        v = np.array([hull.vertex(i) for i in range(hull.num_vertices())], float).reshape(-1, 3)
        if len(v) < 4:
            raise WorkcellError(
                f"a {type(shape).__name__} shape has a degenerate convex hull ({len(v)} vertices); "
                "give it a closed mesh that encloses a volume."
            )
        centre = (v.min(0) + v.max(0)) / 2
        return Geometry(self, np.zeros(3), v - centre, centre)

    def radius(self, sizes, verts) -> float:
        return float(np.linalg.norm(verts, axis=1).max())

    def half_extents(self, sizes, verts) -> np.ndarray:
        return (verts.max(axis=0) - verts.min(axis=0)) / 2

    def cover(self, sizes, verts, tight=False) -> np.ndarray:
        return polytope_cover(verts)

    def points(self, sizes, verts, rings=16) -> np.ndarray:
        return np.asarray(verts, float)

    def probes(self, sizes, verts):
        return np.asarray(verts, float), np.zeros(len(verts))
