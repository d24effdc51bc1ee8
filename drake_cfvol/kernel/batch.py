"""The batch collision check on blocks of configurations
(:mod:`drake_cfvol.kernel.blocks`): a broad phase on every lane of a block
at once, the exact test only on the lanes and pairs it leaves undecided.

The broad phase, per block: every shape's bounding ball and cover balls
placed on every lane; against each obstacle, the shape's bounding ball,
then its balls, against the obstacle's exact shape; for each self pair, the
two bounding balls, then one shape's balls against the other's exact shape
and the other way round (a lane is decided when either way is). Every test
is a closed-form distance from a ball's centre to a box, sphere, capsule or
cylinder (an obstacle of another kind: its axis-aligned box; a pair of
shapes neither of which has a closed form: ball against ball).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit, prange

from drake_cfvol.kernel.blocks import NB, _fk_scratch, fk_block
from drake_cfvol.kernel.checks import _pose_padded
from drake_cfvol.kernel.flat_model import flatten_model, model_from_flat
from drake_cfvol.kernel.gjk import _gjk_from
from drake_cfvol.kernel.kinds import box as _box
from drake_cfvol.kernel.kinds import capsule as _capsule
from drake_cfvol.kernel.kinds import cylinder as _cylinder
from drake_cfvol.kernel.kinds import sphere as _sphere
from drake_cfvol.kernel.shapes import _aabb_apart, _obb_apart_inline
from drake_cfvol.kernel.types import (
    _C,
    _ED,
    _EI,
    _ES,
    _K,
    _R,
    _S,
    BOX,
    CAPSULE,
    CYLINDER,
    SEP_EPS,
    SHAPE_W,
    SPHERE,
    Blocks,
    Model,
)

__all__ = ["configs_may_collide", "configs_may_collide_serial"]


@njit(cache=True, fastmath={"contract"}, inline="always")
def _place(Xb, c0, c1, c2, out, n):
    """A body-frame point in the world on every lane, into out (3 NB)."""
    for i in range(n):
        out[i] = Xb[9 * NB + i] + Xb[i] * c0 + Xb[NB + i] * c1 + Xb[2 * NB + i] * c2
        out[NB + i] = Xb[10 * NB + i] + Xb[3 * NB + i] * c0 + Xb[4 * NB + i] * c1 + Xb[5 * NB + i] * c2
        out[2 * NB + i] = Xb[11 * NB + i] + Xb[6 * NB + i] * c0 + Xb[7 * NB + i] * c1 + Xb[8 * NB + i] * c2


@njit(cache=True, fastmath={"contract"})
def _shape_pose(Xb, row, out, n):
    """A shape row's world pose on every lane into out (12 NB): rotation
    rows, then the centre."""
    l0, l1, l2 = row[_C], row[_C + 1], row[_C + 2]
    m00, m01, m02 = row[_R], row[_R + 1], row[_R + 2]
    m10, m11, m12 = row[_R + 3], row[_R + 4], row[_R + 5]
    m20, m21, m22 = row[_R + 6], row[_R + 7], row[_R + 8]
    for r in range(3):
        o = 3 * r * NB
        for i in range(n):
            a0 = Xb[o + i]
            a1 = Xb[o + NB + i]
            a2 = Xb[o + 2 * NB + i]
            out[o + i] = a0 * m00 + a1 * m10 + a2 * m20
            out[o + NB + i] = a0 * m01 + a1 * m11 + a2 * m21
            out[o + 2 * NB + i] = a0 * m02 + a1 * m12 + a2 * m22
            out[(9 + r) * NB + i] = Xb[(9 + r) * NB + i] + a0 * l0 + a1 * l1 + a2 * l2


@njit(cache=True, fastmath={"contract"}, inline="always")
def _near_exact(cb, r, kind, P, Sz, near, n):
    """Keeps near[i] (1 or 0) where the ball on lane i (centre cb, 3 NB;
    radius r, m) may touch the shape of ``kind`` posed at P (12 NB) with
    sizes Sz; zeroes it where it certainly does not. Returns how many lanes
    stay near. A kind without a closed form keeps every lane."""
    s0, s1, s2 = Sz[0], Sz[1], Sz[2]
    count = 0
    if kind == BOX or kind == CYLINDER or kind == SPHERE or kind == CAPSULE:
        core = 0.0
        if kind == SPHERE:
            core = _sphere.core_radius(s0, s1, s2)
        elif kind == CAPSULE:
            core = _capsule.core_radius(s0, s1, s2)
        elif kind == BOX:
            core = _box.core_radius(s0, s1, s2)
        else:
            core = _cylinder.core_radius(s0, s1, s2)
        rr = r + SEP_EPS + core
        rr2 = rr * rr
        for i in range(n):
            dx = cb[i] - P[9 * NB + i]
            dy = cb[NB + i] - P[10 * NB + i]
            dz = cb[2 * NB + i] - P[11 * NB + i]
            l0 = P[i] * dx + P[3 * NB + i] * dy + P[6 * NB + i] * dz
            l1 = P[NB + i] * dx + P[4 * NB + i] * dy + P[7 * NB + i] * dz
            l2 = P[2 * NB + i] * dx + P[5 * NB + i] * dy + P[8 * NB + i] * dz
            if kind == BOX:  # the kind modules' excess over their cores (drake_cfvol.kernel.kinds)
                l0, l1, l2 = _box.excess(l0, l1, l2, s0, s1, s2)
            elif kind == CAPSULE:
                l0, l1, l2 = _capsule.excess(l0, l1, l2, s0, s1, s2)
            elif kind == CYLINDER:
                l0, l1, l2 = _cylinder.excess(l0, l1, l2, s0, s1, s2)
            ok = l0 * l0 + l1 * l1 + l2 * l2 <= rr2
            near[i] = near[i] if ok else 0.0
            count += 1 if ok and near[i] > 0.0 else 0
    else:
        for i in range(n):
            count += 1 if near[i] > 0.0 else 0
    return count


@njit(cache=True, fastmath={"contract"}, inline="always")
def _near_ball(a, b, r, near, n):
    """near[i] = 1 where balls centred at a and b (3 NB each) whose radii
    sum to r (m) may touch, else 0; returns how many lanes are near."""
    rr = r + SEP_EPS
    rr2 = rr * rr
    count = 0
    for i in range(n):
        dx = a[i] - b[i]
        dy = a[NB + i] - b[NB + i]
        dz = a[2 * NB + i] - b[2 * NB + i]
        ok = dx * dx + dy * dy + dz * dz <= rr2
        near[i] = 1.0 if ok else 0.0
        count += 1 if ok else 0
    return count


class _Lanes(NamedTuple):
    """One thread's broad-phase arrays for a block."""

    BC: np.ndarray  #: (balls, 3 NB) cover ball centres
    SC: np.ndarray  #: (S, 3 NB) bounding ball centres
    SP: np.ndarray  #: (S, 12 NB) shape poses (where a pair needs them)
    posed: np.ndarray  #: (S,) bool: SP[s] is this block's
    near: np.ndarray  #: (NB,)
    hit: np.ndarray  #: (NB,)
    u2: np.ndarray  #: (NB,)
    und: np.ndarray  #: (candidates, NB) undecided lanes per candidate
    cand: np.ndarray  #: (candidates, 2) (shape, obstacle) or (-1, pair)
    lane: np.ndarray  #: (NB,) any candidate undecided
    box: np.ndarray  #: (S, 6) each shape's bounding balls over all the block's lanes: an axis-aligned box


@njit(cache=True)
def _lanes(S, balls, C):
    return _Lanes(
        np.empty((balls, 3 * NB)),
        np.empty((S, 3 * NB)),
        np.empty((S, 12 * NB)),
        np.zeros(S, np.bool_),
        np.empty(NB),
        np.empty(NB),
        np.empty(NB),
        np.zeros((C, NB)),
        np.empty((C, 2), np.int64),
        np.empty(NB),
        np.empty((S, 6)),
    )


@njit(cache=True)
def _block_boxes(L, bounds, n):
    """Each shape's bounding ball on every lane of the block, as one
    axis-aligned box (a block of nearby configurations gives a small box
    that clears most obstacles and pairs at once)."""
    for s in range(L.SC.shape[0]):
        c = L.SC[s]
        r = bounds[s, 3]
        for a in range(3):
            lo = np.inf
            hi = -np.inf
            for i in range(n):
                v = c[a * NB + i]
                lo = min(lo, v)
                hi = max(hi, v)
            L.box[s, a] = lo - r
            L.box[s, 3 + a] = hi + r


@njit(cache=True, inline="always")
def _boxes_apart(A, i, Bx, j, grow):
    """Boxes A[i] and Bx[j] (min xyz, max xyz) farther apart than ``grow`` (m)."""
    return (
        A[i, 0] > Bx[j, 3] + grow
        or Bx[j, 0] > A[i, 3] + grow
        or A[i, 1] > Bx[j, 4] + grow
        or Bx[j, 1] > A[i, 4] + grow
        or A[i, 2] > Bx[j, 5] + grow
        or Bx[j, 2] > A[i, 5] + grow
    )


@njit(cache=True)
def _obstacle_lanes(m):
    """Each obstacle's pose on every lane (O, 12 NB), the kind tested
    (its own where it has a closed form, else BOX: its axis-aligned box),
    its sizes (O, 3) and what grows it (inflation and motion terms, m)."""
    obstacles, aabb = m.obstacles, m.obstacle_aabb
    O = obstacles.shape[0]
    OP = np.empty((O, 12 * NB))
    kind = np.empty(O, np.int64)
    size = np.empty((O, 3))
    extra = np.zeros(O)
    for o in range(O):
        row = obstacles[o]
        kd = int(row[_K])
        exact = kd == BOX or kd == SPHERE or kd == CAPSULE or kd == CYLINDER  # EXACT_KINDS
        kind[o] = kd if exact else BOX
        for e in range(9):
            OP[o, e * NB : (e + 1) * NB] = row[_R + e] if exact else (1.0 if e % 4 == 0 else 0.0)
        for e in range(3):
            OP[o, (9 + e) * NB : (10 + e) * NB] = row[_C + e] if exact else 0.5 * (aabb[o, e] + aabb[o, 3 + e])
            size[o, e] = row[_S + e] if exact else 0.5 * (aabb[o, 3 + e] - aabb[o, e])
        if exact:
            extra[o] = row[_EI] + row[_ED] + row[_ES]
    return OP, kind, size, extra


@njit(cache=True, inline="always")
def _balls_near(L, balls, q0, q1, grow, kind, P, Sz, out, n):
    """out[i] = 1 where some ball q0..q1 (radius + grow, m) may touch the
    shape (kind, pose P, sizes Sz) on a lane that L.near keeps; returns how
    many lanes."""
    for i in range(n):
        out[i] = 0.0
    for q in range(q0, q1):
        for i in range(n):
            L.hit[i] = L.near[i]
        _near_exact(L.BC[q], balls[q, 3] + grow, kind, P, Sz, L.hit, n)
        for i in range(n):
            out[i] = max(out[i], L.hit[i])
    tot = 0
    for i in range(n):
        tot += 1 if out[i] > 0.0 else 0
    return tot


@njit(cache=True, inline="always")
def _keep(L, nc, a, b, n):
    """Candidate nc = (a, b) with its undecided lanes L.und[nc]; returns nc + 1."""
    for i in range(n):
        L.lane[i] = max(L.lane[i], L.und[nc, i])
    L.cand[nc, 0] = a
    L.cand[nc, 1] = b
    return nc + 1


@njit(cache=True)
def _broad_obstacles(m, blk, obs, pad, L, n):
    """Every moving shape against every obstacle on the block's lanes (each
    ball grown by ``pad``); returns the candidates kept."""
    OP, okind, osize, oextra = obs
    balls, ranges, bounds = blk.balls, blk.ranges, blk.bounds
    nc = 0
    for s in range(m.shapes.shape[0]):
        if not m.movable[m.shape_body[s]]:
            continue
        for o in range(OP.shape[0]):
            # The obstacle's box holds its shape with its inflation and motion terms.
            if _boxes_apart(L.box, s, m.obstacle_aabb, o, pad + SEP_EPS):
                continue
            for i in range(n):
                L.near[i] = 1.0
            if _near_exact(L.SC[s], bounds[s, 3] + pad + oextra[o], okind[o], OP[o], osize[o], L.near, n) == 0:
                continue
            if (
                _balls_near(
                    L, balls, ranges[s, 0], ranges[s, 1], pad + oextra[o], okind[o], OP[o], osize[o], L.und[nc], n
                )
                > 0
            ):
                nc = _keep(L, nc, s, o, n)
    return nc


@njit(cache=True)
def _broad_pairs(m, blk, X, pad, L, nc, n):
    """The robot's own pairs on the block's lanes (each shape grown by half
    the pad); returns the candidates kept."""
    shapes, pairs, balls, ranges, bounds = m.shapes, m.shape_pairs, blk.balls, blk.ranges, blk.bounds
    hp = 0.5 * pad
    for p in range(pairs.shape[0]):
        sa = pairs[p, 0]
        sb = pairs[p, 1]
        if _boxes_apart(L.box, sa, L.box, sb, pad + SEP_EPS):
            continue
        if _near_ball(L.SC[sa], L.SC[sb], bounds[sa, 3] + bounds[sb, 3] + pad, L.near, n) == 0:
            continue
        u = L.und[nc]
        for i in range(n):
            u[i] = L.near[i]
        tot = n
        for e in range(2):
            sx = pairs[p, e]  # the exact shape
            sy = pairs[p, 1 - e]  # the balls
            if blk.kind[sx] < 0:
                continue
            if not L.posed[sx]:
                _shape_pose(X[m.shape_body[sx]], shapes[sx], L.SP[sx], n)
                L.posed[sx] = True
            _balls_near(
                L,
                balls,
                ranges[sy, 0],
                ranges[sy, 1],
                hp + shapes[sx, _EI] + hp,
                blk.kind[sx],
                L.SP[sx],
                shapes[sx, _S : _S + 3],
                L.u2,
                n,
            )
            tot = 0
            for i in range(n):
                u[i] = min(u[i], L.u2[i])
                tot += 1 if u[i] > 0.0 else 0
            if tot == 0:
                break
        if blk.kind[sa] < 0 and blk.kind[sb] < 0:  # ball against ball
            tot = 0
            for i in range(n):
                u[i] = 0.0
            for qa in range(ranges[sa, 0], ranges[sa, 1]):
                for qb in range(ranges[sb, 0], ranges[sb, 1]):
                    _near_ball(L.BC[qa], L.BC[qb], balls[qa, 3] + balls[qb, 3] + pad, L.hit, n)
                    for i in range(n):
                        u[i] = max(u[i], L.hit[i] * L.near[i])
            for i in range(n):
                tot += 1 if u[i] > 0.0 else 0
        if tot > 0:
            nc = _keep(L, nc, -1, p, n)
    return nc


class _Exact(NamedTuple):
    """One thread's arrays for the exact test of single lanes."""

    ws: np.ndarray  #: (18, 3) GJK's workspace
    R_WB: np.ndarray  #: (B, 3, 3)
    p_WB: np.ndarray  #: (B, 3)
    objs: np.ndarray  #: (S, 1, SHAPE_W) posed shapes
    aabbs: np.ndarray  #: (S, 6)
    posed: np.ndarray  #: (S,) bool
    dirs: np.ndarray  #: (S, O, 3) last separating direction per shape and obstacle
    pair_dirs: np.ndarray  #: (P, 3) per pair


@njit(cache=True)
def _exact(B, S, O, P):
    return _Exact(
        np.empty((18, 3)),
        np.empty((B, 3, 3)),
        np.empty((B, 3)),
        np.empty((S, 1, SHAPE_W)),
        np.empty((S, 6)),
        np.zeros(S, np.bool_),
        np.zeros((S, O, 3)),
        np.zeros((P, 3)),
    )


@njit(cache=True)
def _lane_hits(m, X, i, pad, L, nc, E):
    """The exact test of lane i's undecided candidates (the same oriented
    boxes and GJK as one configuration at a time): True on a hit."""
    shapes, verts, shape_body, pairs = m.shapes, m.verts, m.shape_body, m.shape_pairs
    for b in range(X.shape[0]):
        for e in range(9):
            E.R_WB[b, e // 3, e % 3] = X[b, e * NB + i]
        for e in range(3):
            E.p_WB[b, e] = X[b, (9 + e) * NB + i]
    E.posed[:] = False
    for c in range(nc):
        if L.und[c, i] == 0.0:
            continue
        s = L.cand[c, 0]
        for e in range(1 if s >= 0 else 2):
            t = s if s >= 0 else pairs[L.cand[c, 1], e]
            if not E.posed[t]:
                _pose_padded(t, E.R_WB, E.p_WB, shapes, shape_body, verts, pad, E.objs, E.aabbs)
                E.posed[t] = True
            E.objs[t, 0, _EI] = shapes[t, _EI] + (pad if s >= 0 else 0.5 * pad)
        if s >= 0:
            o = L.cand[c, 1]
            if _aabb_apart(E.aabbs[s], m.obstacle_aabb[o]) or _obb_apart_inline(
                E.objs[s, 0], m.obstacles[o], E.ws[8:17]
            ):
                continue
            if _gjk_from(E.objs[s], verts, m.obstacles[o : o + 1], verts, 64, E.ws, E.dirs[s, o]):
                return True
        else:
            p = L.cand[c, 1]
            sa = pairs[p, 0]
            sb = pairs[p, 1]
            if _aabb_apart(E.aabbs[sa], E.aabbs[sb]) or _obb_apart_inline(E.objs[sa, 0], E.objs[sb, 0], E.ws[8:17]):
                continue
            if _gjk_from(E.objs[sa], verts, E.objs[sb], verts, 64, E.ws, E.pair_dirs[p]):
                return True
    return False


@njit(cache=True)
def _check_blocks(Q, order, b0, b1, m, blk, pad, out):
    """The batch check of blocks b0 .. b1 - 1 on one thread, into out: lane
    i of block b is configuration order[b NB + i] (``order`` empty: Q's
    own order), its answer written to its own place in out."""
    N, k = Q.shape
    B = m.chain.parent.shape[0]
    S = m.shapes.shape[0]
    O = m.obstacles.shape[0]
    P = m.shape_pairs.shape[0]
    ws = _fk_scratch(B, k)
    X = ws[0]
    L = _lanes(S, blk.balls.shape[0], S * O + P)
    E = _exact(B, S, O, P)
    obs = _obstacle_lanes(m)
    Qb = np.empty((NB, k))
    rows = np.empty(NB, np.int64)
    for b in range(b0, b1):
        start = b * NB
        n = min(NB, N - start)
        for i in range(n):
            rows[i] = order[start + i] if order.shape[0] > 0 else start + i
            for j in range(k):
                Qb[i, j] = Q[rows[i], j]
        fk_block(Qb, 0, n, m.chain, blk.KR, blk.Kp, ws)
        for s in range(S):
            Xb = X[m.shape_body[s]]
            _place(Xb, blk.bounds[s, 0], blk.bounds[s, 1], blk.bounds[s, 2], L.SC[s], n)
            for q in range(blk.ranges[s, 0], blk.ranges[s, 1]):
                _place(Xb, blk.balls[q, 0], blk.balls[q, 1], blk.balls[q, 2], L.BC[q], n)
        L.posed[:] = False
        L.lane[:] = 0.0
        _block_boxes(L, blk.bounds, n)
        nc = _broad_obstacles(m, blk, obs, pad, L, n)
        nc = _broad_pairs(m, blk, X, pad, L, nc, n)
        for i in range(n):
            out[rows[i]] = L.lane[i] > 0.0 and _lane_hits(m, X, i, pad, L, nc, E)


@njit(cache=True, parallel=True)
def configs_may_collide(
    Q: np.ndarray, order: np.ndarray, m: Model, blk: Blocks, pad: float, per: int = 4
) -> np.ndarray:
    """(N,) True where a configuration may collide with the obstacles or
    itself, or come closer to them than ``pad`` (m); False is certified
    free (farther than ``pad`` from everything). ``m``: a :class:`Model`
    (its ``shape_pairs`` the robot shape pairs Drake does not filter);
    ``blk``: its :class:`Blocks`. Bodies no joint moves are welded to the
    world, like the obstacles, and not tested against them. ``order``:
    the order in which the configurations fill the blocks
    (:func:`~drake_cfvol.kernel.blocks.coherent_order`; empty: as given);
    the answers are in Q's order either way. ``per``: blocks per task (a
    task's scratch, the obstacles on every lane, the candidate table and
    the separating directions, is made once and serves them all;
    :meth:`SceneArrays.may_collide` gives about two tasks per thread)."""
    N = Q.shape[0]
    out = np.zeros(N, np.bool_)
    n_blocks = (N + NB - 1) // NB
    per = max(1, per)
    # numba passes no named tuples into a parallel loop: the model goes in
    # as a plain tuple of its arrays, the blocks' arrays one by one; both
    # are rebuilt inside.
    flat = flatten_model(m)
    KR, Kp, balls, ranges, bounds, kind = blk
    for t in prange((n_blocks + per - 1) // per):
        mm = model_from_flat(flat)
        _check_blocks(
            Q, order, t * per, min(n_blocks, (t + 1) * per), mm, Blocks(KR, Kp, balls, ranges, bounds, kind), pad, out
        )
    return out


@njit(cache=True)
def configs_may_collide_serial(Q: np.ndarray, m: Model, blk: Blocks, pad: float) -> np.ndarray:
    """:func:`configs_may_collide` on the calling thread: for a few
    configurations (a guard's checks), where waking the thread pool costs
    more than the work."""
    out = np.zeros(Q.shape[0], np.bool_)
    _check_blocks(Q, np.zeros(0, np.int64), 0, (Q.shape[0] + NB - 1) // NB, m, blk, pad, out)
    return out
