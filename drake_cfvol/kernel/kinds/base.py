"""What every shape kind knows, in one class per kind (:class:`ShapeKind`),
and the ball-cover constructions the kinds share.

A kind's compiled code (its support point, its extent along an axis, a
point's excess over its core, a point's signed distance) is a set of
``@njit(inline="always")`` functions in the kind's own module; the kernel's
dispatchers (:mod:`drake_cfvol.kernel.shapes`, :mod:`drake_cfvol.kernel.batch`)
and the damper's (:mod:`drake_cfvol.systems.filter.damper_kernel`) call them by
kind. Everything else about a kind is here, in Python: how it is read from a
Drake shape, its bounding radius and box, its ball cover, points on it and
the safety filter's probe points.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numba import njit

__all__ = ["ShapeKind", "Geometry", "MAX_SLABS", "SEGMENT_SLACK", "MAX_SEGMENT_BALLS", "box_vertices"]

#: Most balls per shape in a cover.
MAX_SLABS = 8

#: A capsule's balls for the block check exceed it by at most this (m) ...
SEGMENT_SLACK = 0.01

#: ... unless that takes more balls than this.
MAX_SEGMENT_BALLS = 24


@dataclass(frozen=True)
class Geometry:
    """A Drake shape as a kind sees it.

    Attributes:
        kind: its :class:`ShapeKind`.
        sizes: (3,) the kernel row's size fields (see the kind), m.
        verts: (m, 3) a hull's vertices about its centre, m (empty for
            other kinds).
        centre: (3,) the kind's centre in the Drake shape's own frame, m
            (a hull's bounding-box centre; zero for the primitives).
    """

    kind: "ShapeKind"
    sizes: np.ndarray
    verts: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    centre: np.ndarray = field(default_factory=lambda: np.zeros(3))


class ShapeKind:
    """One kind of convex shape: what the scene, the covers, the online
    re-estimation and the safety filter need to know about it. Everything
    is in the kind's own frame about its centre (a :class:`Geometry`'s
    ``sizes`` and ``verts``).

    Attributes:
        code: the kind's number in a kernel shape row (``kernel.types``).
        name: its name in messages.
        drake_names: the Drake shape classes it reads.
        exact_near: the block check and the region tests have its
            closed-form ball test (the module's ``excess`` and
            ``core_radius``); other kinds are tested by their boxes.
        point_query: the filter's damper has its closed-form signed distance
            of a point (the module's ``point_distance``; its parameters are
            ``sizes``).
        unbounded: the Drake shape is infinite (a half space): the kernel
            holds a large box of it, the filter measures it with Drake only.
    """

    code: int = -1
    name: str = "unknown"
    drake_names: tuple[str, ...] = ()
    exact_near: bool = False
    point_query: bool = False
    unbounded: bool = False

    def geometry(self, shape) -> Geometry:
        """The kind's view of a Drake shape of one of its ``drake_names``."""
        raise NotImplementedError

    def radius(self, sizes: np.ndarray, verts: np.ndarray) -> float:
        """The radius of the smallest ball about the centre that holds the
        shape, m (its lever arm about the centre)."""
        raise NotImplementedError

    def half_extents(self, sizes: np.ndarray, verts: np.ndarray) -> np.ndarray:
        """(3,) half extents of the shape's box in its frame, about the centre, m."""
        raise NotImplementedError

    def cover(self, sizes: np.ndarray, verts: np.ndarray, tight: bool = False) -> np.ndarray:
        """(n, 4) balls (centre, radius; m) whose union holds the shape
        (``tight``: the block check's cover, as close as a few more balls
        make it)."""
        raise NotImplementedError

    def points(self, sizes: np.ndarray, verts: np.ndarray, rings: int = 16) -> np.ndarray:
        """(m, 3) points whose hull holds the shape (a polytope's vertices,
        an ellipsoid's box's corners) or, for a round shape, points of it on
        ``rings`` rings of ``rings`` points (its caps and discs included), m."""
        raise NotImplementedError

    def probes(self, sizes: np.ndarray, verts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The safety filter's probe spheres: centres (m, 3) and radii (m,), m.
        Their lowest points along a direction reach the shape's support
        wherever the support set may be flat (a face, an edge, a rim, a
        capsule's side), so rows at them see a face tilt towards an
        obstacle. A smooth, strictly convex shape needs none."""
        return np.zeros((0, 3)), np.zeros(0)

    def support_spheres(self, sizes: np.ndarray, verts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Spheres that hold the shape's support: centres (m, 3) and radii
        (m,), m, such that along every direction n the least n . c - r over
        them is at most the shape's own least n . x (the stop-path guard's
        lower bounds on a distance from a plane). The probes where they do
        (a polytope's vertices, a capsule's end spheres)."""
        return self.probes(sizes, verts)

    def round_radius(self, sizes: np.ndarray) -> float:
        """The radius of the shape's round part, m: a witness point's lever
        arm grows by it (0 for a polytope, whose probes are its vertices)."""
        return 0.0

    def __repr__(self) -> str:
        return f"<shape kind {self.code}: {self.name}>"


@njit(cache=True, inline="always")
def normalised(x, y, z, fx, fy, fz):
    """(x, y, z) made a unit vector, or (fx, fy, fz) where it is near zero."""
    norm = np.sqrt(x * x + y * y + z * z)
    if norm > 1e-12:
        return x / norm, y / norm, z / norm
    return fx, fy, fz


# The cover constructions the kinds share.


def slab_count(length: float, width: float) -> int:
    """Slabs about as long as the shape is wide, at most MAX_SLABS."""
    if width <= 0:
        return MAX_SLABS
    return int(min(MAX_SLABS, max(1, round(length / width))))


def box_vertices(half: np.ndarray) -> np.ndarray:
    """(8, 3) the corners of a box of half extents ``half``."""
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float)
    return signs * half


def box_cover(half: np.ndarray) -> np.ndarray:
    """Balls covering a box of half extents ``half``: a grid of at most
    MAX_SLABS cells (the longest cell side split while the count allows),
    each cell in the ball through its corners."""
    n = np.ones(3, int)
    while True:  # split the longest cell side while the count allows
        a = int(np.argmax(half / n))
        if n.prod() // n[a] * (n[a] + 1) > MAX_SLABS:
            break
        n[a] += 1
    cell = 2 * half / n
    r = float(np.linalg.norm(cell) / 2)
    axes = [-half[a] + cell[a] * (np.arange(n[a]) + 0.5) for a in range(3)]
    centres = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    return np.concatenate([centres, np.full((len(centres), 1), r)], axis=1)


def axial_cover(radius: float, half_length: float) -> np.ndarray:
    """Balls covering a solid of revolution about z of the given radius,
    z in [-half_length, half_length]."""
    n = slab_count(2 * half_length, 2 * radius)
    cuts = np.linspace(-half_length, half_length, n + 1)
    L = cuts[1] - cuts[0]
    r = float(np.hypot(radius, L / 2))
    return np.array([[0.0, 0.0, (a + b) / 2, r] for a, b in zip(cuts[:-1], cuts[1:])])


def segment_cover(radius: float, half_length: float) -> np.ndarray:
    """Balls of radius r + d centred along a capsule's segment at spacing
    2 d: each holds every ball of radius r centred within d of its centre,
    so together the whole capsule; d is :data:`SEGMENT_SLACK` or what
    :data:`MAX_SEGMENT_BALLS` allows."""
    n = int(min(MAX_SEGMENT_BALLS, max(2, np.ceil(half_length / SEGMENT_SLACK) + 1)))
    d = half_length / (n - 1)
    z = np.linspace(-half_length, half_length, n)
    return np.column_stack([np.zeros(n), np.zeros(n), z, np.full(n, radius + d)])


def round_points(radius: float, half_length: float, cap: float, rings: int, discs: bool) -> np.ndarray:
    """Points of a round shape about z: ``rings`` rings of ``rings`` points
    at heights in [-half_length, half_length], caps of radius ``cap`` beyond
    them (a sphere's poles, a capsule's ends), and with ``discs`` the end
    discs (a cylinder's)."""
    phi = np.linspace(0, 2 * np.pi, rings, endpoint=False)
    r, h = radius, half_length
    pts = []
    for z in np.linspace(-h, h, rings):
        pts.append(np.stack([r * np.cos(phi), r * np.sin(phi), np.full(rings, z)], axis=1))
    for a in np.linspace(0, np.pi / 2, rings // 2 + 1)[1:]:  # the caps (a sphere's poles)
        for sgn in (-1, 1):
            pts.append(
                np.stack(
                    [
                        r * np.cos(a) * np.cos(phi),
                        r * np.cos(a) * np.sin(phi),
                        np.full(rings, sgn * (h + cap * np.sin(a))),
                    ],
                    axis=1,
                )
            )
    if discs:
        for rr in np.linspace(0, r, rings // 2 + 1)[:-1]:
            for sgn in (-1, 1):
                pts.append(np.stack([rr * np.cos(phi), rr * np.sin(phi), np.full(rings, sgn * h)], axis=1))
    return np.concatenate(pts)


#: Vertex pairs handled at once when a plane's crossings are computed (a
#: mesh's hull may have thousands of vertices: memory stays bounded).
_PAIRS_PER_BLOCK = 1 << 18


def _crossings(T: np.ndarray, plane: float):
    """Blocks of the points where the segments between a vertex at or below
    the plane x = plane and one at or above it cross it (T (m, 3))."""
    below = T[T[:, 0] <= plane]
    above = T[T[:, 0] >= plane]
    step = max(1, _PAIRS_PER_BLOCK // max(len(above), 1))
    for s in range(0, len(below), step):
        a = below[s : s + step, None, :]
        da = a[..., 0] - plane
        den = da - (above[None, :, 0] - plane)
        w = np.divide(da, den, out=np.zeros_like(den), where=den != 0.0)
        yield (a + w[..., None] * (above[None, :, :] - a)).reshape(-1, 3)


def _slab_points(T: np.ndarray, lo: float, hi: float):
    """Blocks of points whose hull is conv(T) between the planes x = lo and
    x = hi: the vertices between them and both planes' crossings."""
    yield T[(T[:, 0] >= lo) & (T[:, 0] <= hi)]
    yield from _crossings(T, lo)
    yield from _crossings(T, hi)


def polytope_cover(V: np.ndarray) -> np.ndarray:
    """(n, 4) balls (centre, radius) covering conv(V), V (m, 3): the hull
    cut across its longest principal axis into slabs, each slab's ball
    centred in the box of the slab's points (its vertices and the planes'
    crossings) and reaching the farthest of them."""
    centred = V - V.mean(axis=0)
    # The principal axes of the vertices: the first is the longest.
    _, _, axes = np.linalg.svd(centred, full_matrices=False)
    T = V @ axes.T  # vertices in the principal frame
    ext = T.max(axis=0) - T.min(axis=0)
    n = slab_count(ext[0], max(ext[1], ext[2]))
    cuts = np.linspace(T[:, 0].min(), T[:, 0].max(), n + 1)
    balls = []
    for lo, hi in zip(cuts[:-1], cuts[1:]):
        low, high = np.full(3, np.inf), np.full(3, -np.inf)
        for P in _slab_points(T, lo, hi):
            if len(P):
                low, high = np.minimum(low, P.min(axis=0)), np.maximum(high, P.max(axis=0))
        c = (low + high) / 2
        r = max(float(np.linalg.norm(P - c, axis=1).max()) for P in _slab_points(T, lo, hi) if len(P))
        balls.append(np.concatenate([c @ axes, [r]]))
    return np.array(balls)
