"""A cylinder along z (row sizes: radius, half length, 0; m)."""

from __future__ import annotations

import numpy as np
from numba import njit

from drake_cfvol.kernel.kinds.base import Geometry, ShapeKind, axial_cover, normalised, round_points
from drake_cfvol.kernel.types import CYLINDER

__all__ = ["Cylinder", "RIM_POINTS"]

#: The filter's probe points on each rim.
RIM_POINTS = 12


@njit(cache=True, inline="always")
def support(s0, s1, s2, l0, l1, l2):
    """The support point along l."""
    x = 0.0
    y = 0.0
    n = np.sqrt(l0 * l0 + l1 * l1)
    z = s1 if l2 >= 0 else -s1
    if n > 0:
        x = s0 * l0 / n
        y = s0 * l1 / n
    return x, y, z


@njit(cache=True, inline="always")
def extent(r0, r1, r2, s0, s1, s2):
    """Half the cylinder's width along a world axis whose components in
    its frame are (r0, r1, r2)."""
    return abs(r2) * s1 + s0 * np.sqrt(max(1.0 - r2 * r2, 0.0))


@njit(cache=True, inline="always")
def core_radius(s0, s1, s2):
    """The radius the core (the cylinder itself) is grown by: none."""
    return 0.0


@njit(cache=True, inline="always")
def excess(l0, l1, l2, s0, s1, s2):
    """The offset of point l from the cylinder, in (radial, 0, axial) terms."""
    return max(np.sqrt(l0 * l0 + l1 * l1) - s0, 0.0), 0.0, max(abs(l2) - s1, 0.0)


@njit(cache=True, inline="always")
def point_distance(prm, q, out_g, out_near):
    """Signed distance of point q from the cylinder (radius prm[0], half
    length prm[1] about z), m; the unit gradient and the nearest surface
    point into out_g, out_near. Inside: the nearer of its side and caps."""
    x, y, z = q[0], q[1], q[2]
    rho = np.sqrt(x * x + y * y)
    rx, ry, _ = normalised(x, y, 0.0, 1.0, 0.0, 0.0)
    zs = 1.0 if z >= 0 else -1.0
    dr, dz = rho - prm[0], abs(z) - prm[1]
    if dr > 0 or dz > 0:
        nr = min(rho, prm[0])
        nx, ny, nz = rx * nr, ry * nr, min(max(z, -prm[1]), prm[1])
        gx, gy, gz = normalised(x - nx, y - ny, z - nz, 1.0, 0.0, 0.0)
        out_g[0], out_g[1], out_g[2] = gx, gy, gz
        out_near[0], out_near[1], out_near[2] = nx, ny, nz
        return np.sqrt((x - nx) ** 2 + (y - ny) ** 2 + (z - nz) ** 2)
    if dr >= dz:
        out_g[0], out_g[1], out_g[2] = rx, ry, 0.0
        out_near[0], out_near[1], out_near[2] = rx * prm[0], ry * prm[0], z
        return dr
    out_g[0], out_g[1], out_g[2] = 0.0, 0.0, zs
    out_near[0], out_near[1], out_near[2] = x, y, zs * prm[1]
    return dz


class Cylinder(ShapeKind):
    """A cylinder along z: sizes are (radius, half length, 0), m."""

    code = CYLINDER
    name = "cylinder"
    drake_names = ("Cylinder",)
    exact_near = True
    point_query = True

    def geometry(self, shape) -> Geometry:
        return Geometry(self, np.array([shape.radius(), shape.length() / 2, 0.0]))

    def radius(self, sizes, verts) -> float:
        return float(np.hypot(sizes[0], sizes[1]))

    def half_extents(self, sizes, verts) -> np.ndarray:
        return np.array([sizes[0], sizes[0], sizes[1]], float)

    def cover(self, sizes, verts, tight=False) -> np.ndarray:
        return axial_cover(float(sizes[0]), float(sizes[1]))

    def points(self, sizes, verts, rings=16) -> np.ndarray:
        return round_points(float(sizes[0]), float(sizes[1]), 0.0, rings, discs=True)

    def probes(self, sizes, verts):
        a = np.linspace(0.0, 2 * np.pi, RIM_POINTS, endpoint=False)
        ring = np.stack([sizes[0] * np.cos(a), sizes[0] * np.sin(a)], axis=1)
        rims = [np.column_stack([ring, np.full(len(a), z)]) for z in (-sizes[1], sizes[1])]
        return np.concatenate(rims), np.zeros(2 * RIM_POINTS)

    def round_radius(self, sizes) -> float:
        return float(sizes[0])

    def support_spheres(self, sizes, verts):
        # The rim's points, each grown by how far the rim bulges past the
        # polygon they make: r (1 - cos(pi / RIM_POINTS)).
        centres, _ = self.probes(sizes, verts)
        return centres, np.full(len(centres), float(sizes[0]) * (1.0 - np.cos(np.pi / RIM_POINTS)))
