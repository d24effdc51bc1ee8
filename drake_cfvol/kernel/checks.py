"""Configurations against the scene, one at a time: a posed shape against
the obstacles and V, distances to the obstacles, and columns of V lowered
under the robot (the batch check on blocks is :mod:`~drake_cfvol.kernel.batch`).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from drake_cfvol.kernel.gjk import _gjk, _gjk_from
from drake_cfvol.kernel.heightfield import _clip_block, object_hits_columns
from drake_cfvol.kernel.kinematics import fk_into
from drake_cfvol.kernel.shapes import (
    _aabb_apart,
    _obb_apart,
    pose_shape,
    pose_shape_inline,
    row_aabb,
    row_aabb_inline,
    set_motion,
)
from drake_cfvol.kernel.types import _C, _EI, SHAPE_W, Chain, Model

__all__ = ["lower_columns_under", "obstacle_distances"]


@njit(cache=True)
def _pose_objects(R_WB, p_WB, shapes, shape_body, pose, objs):
    """Pose every robot shape into objs[s, pose] for the body poses given."""
    for s in range(shapes.shape[0]):
        b = shape_body[s]
        pose_shape(shapes[s], R_WB[b], p_WB[b], objs[s, pose])


@njit(cache=True)
def _object_vs_obstacles(obj, aabb, verts, obstacles, obs_aabb, ws, dirs):
    """An object against the obstacles (no V): the boxes, a one-row
    object's separating axes, then GJK from the pair's last separating
    direction (``dirs`` (O, 3), updated). Takes the arrays themselves: a
    model tuple passed per call costs a reference count per array."""
    single = obj.shape[0] == 1
    for o in range(obstacles.shape[0]):
        if _aabb_apart(aabb, obs_aabb[o]) or (single and _obb_apart(obj[0], obstacles[o], ws[8:17])):
            continue
        if _gjk_from(obj, verts, obstacles[o : o + 1], verts, 64, ws, dirs[o]):
            return True
    return False


@njit(cache=True)
def _object_vs_scene(obj, aabb, m, field, sc, dirs):
    """An object against the obstacles of model ``m`` (GJK from ``dirs``,
    see :func:`_object_vs_obstacles`) and the height field (an empty
    table: no V)."""
    verts = m.verts
    table, ox, oy, side = field
    ws, stack, box = sc.ws, sc.stack, sc.box
    if _object_vs_obstacles(obj, aabb, verts, m.obstacles, m.obstacle_aabb, ws, dirs):
        return True
    if table.shape[2] > 0:
        if object_hits_columns(obj, verts, aabb, table, ox, oy, side, ws, stack, box):
            return True
    return False


@njit(cache=True, inline="always")
def _pose_padded(s, R_WB, p_WB, shapes, shape_body, verts, pad, objs, aabbs):
    """Robot shape s posed at X_WB, its inflation grown by ``pad``, with its
    axis-aligned box (the arrays, not the model: a tuple passed per call
    costs a reference count per array)."""
    b = shape_body[s]
    pose_shape_inline(shapes[s], R_WB[b], p_WB[b], objs[s, 0])
    objs[s, 0, _EI] = shapes[s, _EI] + pad
    row_aabb_inline(objs[s, 0], verts, aabbs[s])


@njit(cache=True)
def lower_columns_under(
    Q: np.ndarray,
    e_body: np.ndarray,
    m: Model,
    heights: np.ndarray,
    grid: tuple[float, float, float],
    clearance: float,
) -> None:
    """Lowers every column under the robot at configurations Q (each body
    grown by e_body[n, b], a ball) to ``clearance`` below the lowest point of
    any shape whose footprint's bounding rectangle covers it (bodies that
    never move: once). In place. ``grid`` = (ox, oy, side) of ``heights``."""
    shapes, shape_body, verts, movable = m.shapes, m.shape_body, m.verts, m.movable
    ox, oy, side = grid
    B = m.chain.parent.shape[0]
    S = shapes.shape[0]
    nx, ny = heights.shape
    R_WB = np.empty((B, 3, 3))
    p_WB = np.empty((B, 3))
    row = np.empty(SHAPE_W)
    box = np.empty(6)
    for n in range(Q.shape[0]):
        fk_into(Q[n], m.chain, R_WB, p_WB)
        for s in range(S):
            b = shape_body[s]
            if n > 0 and not movable[b]:
                continue
            pose_shape(shapes[s], R_WB[b], p_WB[b], row)
            set_motion(row, e_body[n, b], 0.0, 0.0, 1.0, 0.0, 0.0)
            row_aabb(row, verts, box)
            cap = box[2] - clearance
            if cap < 0:
                cap = 0.0
            i0, i1, j0, j1 = _clip_block(
                int(np.floor((box[0] - ox) / side)),
                int(np.floor((box[3] - ox) / side)),
                int(np.floor((box[1] - oy) / side)),
                int(np.floor((box[4] - oy) / side)),
                nx,
                ny,
            )
            for a in range(i0, i1 + 1):
                for c in range(j0, j1 + 1):
                    if heights[a, c] > cap:
                        heights[a, c] = cap


@njit(cache=True)
def _touches(objs, S, e, verts, obstacle, ws):
    for s in range(S):
        set_motion(objs[s, 0], e, 0.0, 0.0, 1.0, 0.0, 0.0)
        if _gjk(objs[s], verts, obstacle, verts, 64, ws):
            return True
    return False


@njit(cache=True, parallel=True)
def obstacle_distances(Q: np.ndarray, hi: float, tol: float, m: Model) -> np.ndarray:
    """(N, O) distance from the robot at Q[n] (its shapes on bodies some
    joint moves) to obstacle shape o, by bisection on the radius of a ball
    grown around every robot shape: within ``tol`` below the true distance;
    0 when touching; ``hi`` for anything farther than hi. ``m``: a :class:`Model`."""
    shapes, shape_body, verts, movable = m.shapes, m.shape_body, m.verts, m.movable
    obstacles, obs_aabb = m.obstacles, m.obstacle_aabb
    # numba passes no tuples of arrays into a parallel loop: the chain's
    # arrays go in one by one, the chain is rebuilt inside.
    parent, jtype, qidx, axis, R_PF, p_PF, R_MB, p_MB = m.chain
    N = Q.shape[0]
    O = obstacles.shape[0]
    B = parent.shape[0]
    S = shapes.shape[0]
    out = np.full((N, O), hi)
    for n in prange(N):
        ws = np.empty((18, 3))
        R_WB = np.empty((B, 3, 3))
        p_WB = np.empty((B, 3))
        objs = np.empty((S, 1, SHAPE_W))
        aabb = np.empty(6)
        fk_into(Q[n], Chain(parent, jtype, qidx, axis, R_PF, p_PF, R_MB, p_MB), R_WB, p_WB)
        _pose_objects(R_WB, p_WB, shapes, shape_body, 0, objs)
        # Shapes that never move are welded like the obstacles: park them far away.
        for s in range(S):
            if not movable[shape_body[s]]:
                objs[s, 0, _C + 2] = -1e9
        for o in range(O):
            # Any robot shape near enough to matter?
            near = False
            for s in range(S):
                set_motion(objs[s, 0], hi, 0.0, 0.0, 1.0, 0.0, 0.0)
                row_aabb(objs[s, 0], verts, aabb)
                if not _aabb_apart(aabb, obs_aabb[o]):
                    near = True
                    break
            if not near:
                continue
            ob = obstacles[o : o + 1]
            if not _touches(objs, S, hi, verts, ob, ws):
                continue
            if _touches(objs, S, 0.0, verts, ob, ws):
                out[n, o] = 0.0
                continue
            lo_e = 0.0
            hi_e = hi
            while hi_e - lo_e > tol:
                mid = 0.5 * (lo_e + hi_e)
                if _touches(objs, S, mid, verts, ob, ws):
                    hi_e = mid
                else:
                    lo_e = mid
            out[n, o] = lo_e
    return out
