"""Outer sphere covers of the robot's shapes: a few balls per shape whose
union contains the shape (with its inflation), in the shape's body frame.

The kernel's broad phase tests these balls first (a ball against a box or a
column is a handful of flops) and runs the exact test only where a ball is
near something. A cover is built once per workcell and checked when built
(:func:`check_cover`): every vertex of the shape's bounding polytope lies in
it.

How a cover is built: the shape is cut by planes across its longest axis
into slabs about as long as the shape is wide. For a polytope (a box, an
ellipsoid's bounding box, a mesh's convex hull) the slab is itself a
polytope whose vertices are the shape's vertices between the planes and
the points where segments between two vertices on either side cross a plane
(every point of the hull on a plane is a convex combination of such
crossings); the slab's ball is centred in the box bounding those points and
reaches the farthest. So the ball contains the slab, and the union of the
balls the shape. A capsule's or cylinder's slab lies in a cylinder of the
shape's radius as long as the slab: its ball has radius sqrt(r^2 + (L/2)^2).
"""

from __future__ import annotations

import numpy as np

from drake_cfvol import kernel as K
from drake_cfvol.exceptions import WorkcellError
from drake_cfvol.kernel.types import _ED, _EI, _ES

__all__ = ["shape_cover", "robot_covers", "check_cover", "MAX_SLABS", "SEGMENT_SLACK", "MAX_SEGMENT_BALLS"]

#: Most balls per shape.
MAX_SLABS = 8

#: A cover's radii are grown by this much (m) against rounding in the check.
_ROUNDING = 1e-9


def _slab_count(length: float, width: float) -> int:
    if width <= 0:
        return MAX_SLABS
    return int(min(MAX_SLABS, max(1, round(length / width))))


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


def _polytope_cover(V: np.ndarray) -> np.ndarray:
    """(n, 4) balls (centre, radius) covering conv(V), V (m, 3)."""
    centred = V - V.mean(axis=0)
    # The principal axes of the vertices: the first is the longest.
    _, _, axes = np.linalg.svd(centred, full_matrices=False)
    T = V @ axes.T  # vertices in the principal frame
    ext = T.max(axis=0) - T.min(axis=0)
    n = _slab_count(ext[0], max(ext[1], ext[2]))
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


def _box_vertices(half: np.ndarray) -> np.ndarray:
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float)
    return signs * half


def _box_cover(half: np.ndarray) -> np.ndarray:
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


def _axial_cover(radius: float, half_length: float) -> np.ndarray:
    """Balls covering a solid of revolution about z of the given radius,
    z in [-half_length, half_length]."""
    n = _slab_count(2 * half_length, 2 * radius)
    cuts = np.linspace(-half_length, half_length, n + 1)
    L = cuts[1] - cuts[0]
    r = float(np.hypot(radius, L / 2))
    return np.array([[0.0, 0.0, (a + b) / 2, r] for a, b in zip(cuts[:-1], cuts[1:])])


#: A capsule's balls for the block check exceed it by at most this (m) ...
SEGMENT_SLACK = 0.01

#: ... unless that takes more balls than this.
MAX_SEGMENT_BALLS = 24


def _segment_cover(radius: float, half_length: float) -> np.ndarray:
    """Balls of radius r + d centred along a capsule's segment at spacing
    2 d: each holds every ball of radius r centred within d of its centre,
    so together the whole capsule; d is :data:`SEGMENT_SLACK` or what
    :data:`MAX_SEGMENT_BALLS` allows."""
    n = int(min(MAX_SEGMENT_BALLS, max(2, np.ceil(half_length / SEGMENT_SLACK) + 1)))
    d = half_length / (n - 1)
    z = np.linspace(-half_length, half_length, n)
    return np.column_stack([np.zeros(n), np.zeros(n), z, np.full(n, radius + d)])


def shape_cover(row: np.ndarray, verts: np.ndarray, tight: bool = False) -> np.ndarray:
    """The balls covering a shape row, in the row's own (parent) frame.

    Args:
        row: a kernel shape row (SHAPE_W,).
        verts: the kernel's hull vertices (V, 3).
        tight: a capsule as balls along its segment, within
            :data:`SEGMENT_SLACK` of it (the block check's cover), instead
            of a few slabs' balls.

    Returns:
        (n, 4): ball centres (m, in the frame the row is posed in) and radii
        (m), the row's inflation and motion terms included.
    """
    kind = int(row[K._K])
    s = row[K._S : K._S + 3]
    if kind == K.SPHERE:
        local = np.array([[0.0, 0.0, 0.0, s[0]]])
    elif kind == K.CAPSULE:
        local = _segment_cover(s[0], s[1]) if tight else _axial_cover(s[0], s[1] + s[0])
    elif kind == K.CYLINDER:
        local = _axial_cover(s[0], s[1])
    elif kind in (K.BOX, K.ELLIPSOID):
        local = _box_cover(s)
    else:
        local = _polytope_cover(verts[int(row[K._V0]) : int(row[K._V1])])
    R = row[K._R : K._R + 9].reshape(3, 3)
    out = np.empty_like(local)
    out[:, :3] = row[K._C : K._C + 3] + local[:, :3] @ R.T
    out[:, 3] = local[:, 3] + row[_EI] + row[_ED] + row[_ES] + _ROUNDING
    return out


def shape_points(row: np.ndarray, verts: np.ndarray, rings: int = 16) -> np.ndarray:
    """Points of the shape (without its inflation), in the row's parent
    frame: a polytope's vertices (a box's, a hull's, an ellipsoid's bounding
    box's), or rings of ``rings`` points around a round shape's axis at
    ``rings`` heights (and its caps)."""
    kind = int(row[K._K])
    s = row[K._S : K._S + 3]
    if kind == K.HULL:
        local = verts[int(row[K._V0]) : int(row[K._V1])]
    elif kind in (K.SPHERE, K.CAPSULE, K.CYLINDER):
        phi = np.linspace(0, 2 * np.pi, rings, endpoint=False)
        if kind == K.SPHERE:
            r, h, cap = s[0], 0.0, s[0]
        else:
            r, h, cap = s[0], s[1], (s[0] if kind == K.CAPSULE else 0.0)
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
        if kind == K.CYLINDER:  # the end discs
            for rr in np.linspace(0, r, rings // 2 + 1)[:-1]:
                for sgn in (-1, 1):
                    pts.append(np.stack([rr * np.cos(phi), rr * np.sin(phi), np.full(rings, sgn * h)], axis=1))
        local = np.concatenate(pts)
    else:
        local = _box_vertices(s)
    R = row[K._R : K._R + 9].reshape(3, 3)
    return row[K._C : K._C + 3] + local @ R.T


def check_cover(row: np.ndarray, verts: np.ndarray, cover: np.ndarray) -> None:
    """Checks that the cover contains the shape's points
    (:func:`shape_points`: every vertex of a polytope), grown by the row's
    inflation and motion terms.

    Raises:
        WorkcellError: a point outside the cover (a bug, never expected).
    """
    grow = row[_EI] + row[_ED] + row[_ES]
    P = shape_points(row, verts)
    d = np.linalg.norm(P[:, None, :] - cover[None, :, :3], axis=2) + grow - cover[None, :, 3]
    worst = float(d.min(axis=1).max())
    if worst > 0.0:
        raise WorkcellError(
            f"a sphere cover misses a point of its shape (kind {int(row[K._K])}) by {worst:.3g} m; "
            "please report this with the robot's model."
        )


def robot_covers(shapes: np.ndarray, verts: np.ndarray, tight: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Every robot shape's cover (``tight``: see :func:`shape_cover`), checked.

    Returns:
        (spheres (N, 4) in body frames, shape_spheres (S, 2) int: the rows
        [start, stop) of each shape's balls)
    """
    balls, ranges, start = [], [], 0
    for row in shapes:
        cover = shape_cover(row, verts, tight)
        check_cover(row, verts, cover)
        balls.append(cover)
        ranges.append((start, start + len(cover)))
        start += len(cover)
    spheres = np.concatenate(balls) if balls else np.zeros((0, 4))
    return np.ascontiguousarray(spheres), np.array(ranges, np.int64).reshape(-1, 2)
