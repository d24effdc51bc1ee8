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
from drake_cfvol.kernel import kinds
from drake_cfvol.kernel.kinds import MAX_SEGMENT_BALLS, MAX_SLABS, SEGMENT_SLACK
from drake_cfvol.kernel.types import ROW_E_DISC, ROW_E_ISO, ROW_E_SEG

__all__ = ["shape_cover", "robot_covers", "check_cover", "MAX_SLABS", "SEGMENT_SLACK", "MAX_SEGMENT_BALLS"]

#: A cover's radii are grown by this much (m) against rounding in the check.
_ROUNDING = 1e-9


def _local(row: np.ndarray, verts: np.ndarray) -> tuple:
    """A row's kind, sizes and hull vertices (its own frame)."""
    k = kinds.kind(row[K.ROW_KIND])
    return (
        k,
        row[K.ROW_SIZE : K.ROW_SIZE + 3],
        verts[int(row[K.ROW_FIRST_VERTEX]) : int(row[K.ROW_END_VERTEX])] if k.code == K.HULL else verts[:0],
    )


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
    k, sizes, v = _local(row, verts)
    local = k.cover(sizes, v, tight)
    R = row[K.ROW_ROTATION : K.ROW_ROTATION + 9].reshape(3, 3)
    out = np.empty_like(local)
    out[:, :3] = row[K.ROW_CENTRE : K.ROW_CENTRE + 3] + local[:, :3] @ R.T
    out[:, 3] = local[:, 3] + row[ROW_E_ISO] + row[ROW_E_DISC] + row[ROW_E_SEG] + _ROUNDING
    return out


def shape_points(row: np.ndarray, verts: np.ndarray, rings: int = 16) -> np.ndarray:
    """Points of the shape (without its inflation), in the row's parent
    frame: a polytope's vertices (a box's, a hull's, an ellipsoid's bounding
    box's), or rings of ``rings`` points around a round shape's axis at
    ``rings`` heights (and its caps)."""
    k, sizes, v = _local(row, verts)
    local = k.points(sizes, v, rings)
    R = row[K.ROW_ROTATION : K.ROW_ROTATION + 9].reshape(3, 3)
    return row[K.ROW_CENTRE : K.ROW_CENTRE + 3] + local @ R.T


def check_cover(row: np.ndarray, verts: np.ndarray, cover: np.ndarray) -> None:
    """Checks that the cover contains the shape's points
    (:func:`shape_points`: every vertex of a polytope), grown by the row's
    inflation and motion terms.

    Raises:
        WorkcellError: a point outside the cover (a bug, never expected).
    """
    grow = row[ROW_E_ISO] + row[ROW_E_DISC] + row[ROW_E_SEG]
    P = shape_points(row, verts)
    d = np.linalg.norm(P[:, None, :] - cover[None, :, :3], axis=2) + grow - cover[None, :, 3]
    worst = float(d.min(axis=1).max())
    if worst > 0.0:
        raise WorkcellError(
            f"a sphere cover misses a point of its shape (kind {int(row[K.ROW_KIND])}) by {worst:.3g} m; "
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
