"""Configurations against the scene: may a configuration collide (or come
nearer than a pad), distances to the obstacles, and columns of V lowered
under the robot.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from drake_cfvol.kernel.types import HULL, Chain, Model, SHAPE_W, _C, _EI, _K
from drake_cfvol.kernel.kinematics import fk_into
from drake_cfvol.kernel.shapes import (_aabb_apart, _obb_apart, _obb_apart_inline, pose_shape, pose_shape_inline,
                                      row_aabb, row_aabb_inline, set_motion)
from drake_cfvol.kernel.gjk import _gjk, _gjk_from
from drake_cfvol.kernel.heightfield import _clip_block, new_scratch, object_hits_columns
from drake_cfvol.kernel.spheres import balls_apart, balls_apart_row, place_balls

__all__ = ['configs_may_collide', 'lower_columns_under', 'obstacle_distances', 'configs_may_collide_serial']


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
        if _gjk_from(obj, verts, obstacles[o:o + 1], verts, 64, ws, dirs[o]):
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


@njit(cache=True, inline="always")
def _boxes_apart_at(A, i, Bx, j):
    """Axis-aligned boxes A[i] and Bx[j] apart (by index: a row view per
    test costs its parent's reference count in the hot loops)."""
    return (A[i, 0] > Bx[j, 3] or Bx[j, 0] > A[i, 3] or A[i, 1] > Bx[j, 4] or Bx[j, 1] > A[i, 4]
            or A[i, 2] > Bx[j, 5] or Bx[j, 2] > A[i, 5])


@njit(cache=True, inline="always")
def _undecided_obstacles(s, ball_box, balls, ranges, hull, obstacles, obs_aabb, near):
    """The obstacles shape s's balls leave undecided, into near[:count];
    returns count."""
    count = 0
    for o in range(obstacles.shape[0]):
        if _boxes_apart_at(ball_box, s, obs_aabb, o):
            continue
        if hull and balls_apart_row(balls, ranges[s, 0], ranges[s, 1], obstacles[o], obs_aabb[o]):
            continue
        near[count] = o
        count += 1
    return count


@njit(cache=True, inline="always")
def _hits_obstacles(obj, aabb, verts, obstacles, obs_aabb, near, count, ws, dirs):
    """The exact test of a posed shape against obstacles near[:count]:
    axis-aligned boxes, oriented boxes, GJK from the pair's last
    separating direction (dirs (O, 3))."""
    for c in range(count):
        o = near[c]
        if _aabb_apart(aabb, obs_aabb[o]) or _obb_apart_inline(obj[0], obstacles[o], ws[8:17]):
            continue
        if _gjk_from(obj, verts, obstacles[o:o + 1], verts, 64, ws, dirs[o]):
            return True
    return False


@njit(cache=True, inline="always")
def _undecided_pairs(ball_box, balls, ranges, hull, shape_pairs, shrink, near):
    """The shape pairs the balls leave undecided (radii less ``shrink``
    each), into near[:count]; returns count."""
    count = 0
    for p in range(shape_pairs.shape[0]):
        sa = shape_pairs[p, 0]
        sb = shape_pairs[p, 1]
        if _boxes_apart_at(ball_box, sa, ball_box, sb):
            continue
        if (hull[sa] or hull[sb]) and balls_apart(balls, ranges[sa, 0], ranges[sa, 1], ranges[sb, 0],
                                                  ranges[sb, 1], shrink):
            continue
        near[count] = p
        count += 1
    return count


@njit(cache=True, inline="always")
def _hits_pairs(objs, aabbs, verts, shape_pairs, near, count, ws, pair_dirs):
    """The exact test of shape pairs near[:count] (posed in objs, half the
    margin each): axis-aligned boxes, oriented boxes, GJK from the pair's
    last separating direction."""
    for c in range(count):
        p = near[c]
        sa = shape_pairs[p, 0]
        sb = shape_pairs[p, 1]
        if _aabb_apart(aabbs[sa], aabbs[sb]) or _obb_apart_inline(objs[sa, 0], objs[sb, 0], ws[8:17]):
            continue
        if _gjk_from(objs[sa], verts, objs[sb], verts, 64, ws, pair_dirs[p]):
            return True
    return False


@njit(cache=True)
def _may_collide_range(Q, start, stop, m, pad, out):
    """configs_may_collide for Q[start:stop], into out, on one thread.

    The broad phase places each shape's cover balls (grown by ``pad``): their
    axis-aligned box against the obstacles' and each other's, then, for a
    mesh's hull, each ball (exact against boxes). A shape is posed, and a
    pair goes to the oriented boxes and GJK, only where that is undecided."""
    shapes, verts = m.shapes, m.verts
    shape_pairs, movable, shape_body, ranges = m.shape_pairs, m.movable, m.shape_body, m.shape_spheres
    obstacles, obs_aabb = m.obstacles, m.obstacle_aabb
    chain = m.chain
    B = chain.parent.shape[0]
    S = shapes.shape[0]
    sc = new_scratch()
    ws = sc.ws
    R_WB = np.empty((B, 3, 3))
    p_WB = np.empty((B, 3))
    objs = np.empty((S, 1, SHAPE_W))
    aabbs = np.empty((S, 6))
    balls = np.empty((m.spheres.shape[0], 4))
    ball_box = np.empty((S, 6))
    posed = np.zeros(S, np.bool_)
    near = np.empty(max(obstacles.shape[0], shape_pairs.shape[0]), np.int64)
    # The balls decide before the exact test for hulls only: the other
    # shapes' oriented boxes (exact for two boxes) are tighter and cheaper.
    hull = np.empty(S, np.bool_)
    for s in range(S):
        hull[s] = shapes[s, _K] == HULL
    # Each pair's last separating direction (consecutive configurations of
    # a batch are often near each other): shape x obstacle, shape pair.
    dirs = np.zeros((S, obstacles.shape[0], 3))
    pair_dirs = np.zeros((shape_pairs.shape[0], 3))
    for n in range(start, stop):
        fk_into(Q[n], chain, R_WB, p_WB)
        place_balls(R_WB, p_WB, shape_body, m.spheres, ranges, pad, balls, ball_box)
        posed[:] = False
        hit = False
        for s in range(S):
            if not movable[shape_body[s]]:
                continue
            count = _undecided_obstacles(s, ball_box, balls, ranges, hull[s], obstacles, obs_aabb, near)
            if count == 0:
                continue
            _pose_padded(s, R_WB, p_WB, shapes, shape_body, verts, pad, objs, aabbs)
            posed[s] = True
            if _hits_obstacles(objs[s], aabbs[s], verts, obstacles, obs_aabb, near, count, ws, dirs[s]):
                hit = True
                break
        if not hit:
            # Half the margin on each shape of a pair.
            count = _undecided_pairs(ball_box, balls, ranges, hull, shape_pairs, 0.5 * pad, near)
            for c in range(count):
                for e in range(2):
                    s = shape_pairs[near[c], e]
                    if not posed[s]:
                        _pose_padded(s, R_WB, p_WB, shapes, shape_body, verts, pad, objs, aabbs)
                        posed[s] = True
                    objs[s, 0, _EI] = shapes[s, _EI] + 0.5 * pad
            hit = _hits_pairs(objs, aabbs, verts, shape_pairs, near, count, ws, pair_dirs)
        out[n] = hit


@njit(cache=True, parallel=True)
def configs_may_collide(Q, m, pad):
    """(N,) True where a configuration may collide with the obstacles or
    itself, or come closer to them than ``pad`` (m); False is certified free
    (farther than ``pad`` from everything). ``m``: a :class:`Model`; its
    ``shape_pairs`` (P, 2) are the robot shape pairs to test (those of body pairs Drake does not filter). Bodies
    that no joint moves (``movable`` False) are welded to the world, like
    the obstacles: Drake filters those pairs, and so does this."""
    N = Q.shape[0]
    out = np.zeros(N, np.bool_)
    chunk = 256
    n_chunks = (N + chunk - 1) // chunk
    # numba passes no tuples of arrays into a parallel loop: the model's
    # arrays go in one by one, the model is rebuilt inside.
    parent, jtype, qidx, axis, R_PF, p_PF, R_MB, p_MB = m.chain
    (shapes_, shape_body_, verts_, obstacles_, obstacle_aabb_, body_pairs_, shape_pairs_, movable_, moved_, reach_,
     curvature_, revolute_, joint_body_, spheres_, shape_spheres_) = m[1:]
    for c in prange(n_chunks):
        mm = Model(Chain(parent, jtype, qidx, axis, R_PF, p_PF, R_MB, p_MB), shapes_, shape_body_, verts_, obstacles_,
                   obstacle_aabb_, body_pairs_, shape_pairs_, movable_, moved_, reach_, curvature_, revolute_,
                   joint_body_, spheres_, shape_spheres_)
        _may_collide_range(Q, c * chunk, min(N, (c + 1) * chunk), mm, pad, out)
    return out


@njit(cache=True)
def configs_may_collide_serial(Q, m, pad):
    """:func:`configs_may_collide` on the calling thread: for a few
    configurations (a collision guard's checks), where waking the thread
    pool costs more than the work."""
    out = np.zeros(Q.shape[0], np.bool_)
    _may_collide_range(Q, 0, Q.shape[0], m, pad, out)
    return out


@njit(cache=True)
def lower_columns_under(Q, e_body, m, heights, grid, clearance):
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
            i0, i1, j0, j1 = _clip_block(int(np.floor((box[0] - ox) / side)), int(np.floor((box[3] - ox) / side)),
                                         int(np.floor((box[1] - oy) / side)), int(np.floor((box[4] - oy) / side)),
                                         nx, ny)
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
def obstacle_distances(Q, hi, tol, m):
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
            ob = obstacles[o:o + 1]
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
