"""The region test's broad phase: the robot at the region's centre, each
cover ball grown by how far the joints' lever arms can carry it over the
region. Decides most regions free with one forward kinematics and a few
ball tests; what it cannot decide goes to the grid-and-hull test.
"""

from __future__ import annotations

from numba import njit

from drake_cfvol.kernel.kinematics import fk_into
from drake_cfvol.kernel.spheres import ball_apart_row, box_above_columns
from drake_cfvol.kernel.types import SEP_EPS

__all__ = []


@njit(cache=True, inline="always")
def _lever(m, kk, b):
    """How far a point of body b moves per unit of joint kk, at most: its
    distance from kk's axis (revolute) or 1 (prismatic); 0 if kk does not
    move b."""
    if not m.moved[kk, b]:
        return 0.0
    return m.reach[kk, b] if m.revolute[kk] else 1.0


@njit(cache=True)
def _centre_and_half(W, i, j, ts, vs, q_c, half):
    """The region's centre configuration into q_c and each joint's half
    range over the region into half (rad or m)."""
    ta, tb, _ = ts
    va, vb, _ = vs
    tm = 0.5 * (ta + tb)
    for kk in range(W.shape[1]):
        d = W[i + 1, kk] - W[i, kk]
        q_c[kk] = W[i, kk] + tm * d
        half[kk] = 0.5 * (tb - ta) * abs(d)
    q_c[j] = 0.5 * (va + vb)
    half[j] = 0.5 * (vb - va)


@njit(cache=True)
def _ball_clear(x0, x1, x2, r, obs_aabb, obstacles, field, box, fp):
    """A ball against the obstacles (exact for boxes) and V's columns (the
    tallest under its bounding square); its box joins the footprint."""
    box[0], box[1], box[2] = x0 - r, x1 - r, x2 - r
    box[3], box[4], box[5] = x0 + r, x1 + r, x2 + r
    for a in range(3):
        fp[a] = min(fp[a], box[a])
        fp[a + 3] = max(fp[a + 3], box[a + 3])
    for o in range(obstacles.shape[0]):
        if (
            box[0] > obs_aabb[o, 3]
            or obs_aabb[o, 0] > box[3]
            or box[1] > obs_aabb[o, 4]
            or obs_aabb[o, 1] > box[4]
            or box[2] > obs_aabb[o, 5]
            or obs_aabb[o, 2] > box[5]
        ):
            continue
        if not ball_apart_row(x0, x1, x2, r, obstacles[o], obs_aabb[o]):
            return False
    return box_above_columns(box, field)


@njit(cache=True)
def _world_balls(s, R, p, spheres, ranges, out):
    """Shape s's cover balls at body pose (R, p) into out[start:stop, :3]."""
    for q in range(ranges[s, 0], ranges[s, 1]):
        for a in range(3):
            out[q, a] = p[a] + R[a, 0] * spheres[q, 0] + R[a, 1] * spheres[q, 1] + R[a, 2] * spheres[q, 2]


@njit(cache=True)
def region_quick_free(W, i, j, ts, vs, m, field, rs, pad):
    """True if the region (see :func:`drake_cfvol.kernel.regions._region_hits`)
    is certainly free: at its centre configuration q_c, each ball of a shape
    joint j moves, grown by sum_k half_k lever_k (a point moves at most its
    lever arm per unit of each joint along the straight pieces of the
    region) and ``pad``, is clear of the obstacles and V; and each self
    pair j moves apart keeps its balls apart, grown by the joints that move
    one body and not the other, each by its lever arm to the body it moves
    (a joint that moves both moves them rigidly together). False:
    undecided (the exact test decides). The balls' boxes join rs.fp."""
    q_c, half, balls, box = rs.q_c, rs.half, rs.balls, rs.qbox
    _centre_and_half(W, i, j, ts, vs, q_c, half)
    R, p = rs.RP[0], rs.pP[0]  # grid slot 0: the grid is posed after this
    fk_into(q_c, m.chain, R, p)
    spheres, ranges, shape_body = m.spheres, m.shape_spheres, m.shape_body
    k = W.shape[1]
    for s in range(ranges.shape[0]):
        b = shape_body[s]
        if not m.moved[j, b]:
            continue
        g = pad
        for kk in range(k):
            g += half[kk] * _lever(m, kk, b)
        _world_balls(s, R[b], p[b], spheres, ranges, balls)
        for q in range(ranges[s, 0], ranges[s, 1]):
            if not _ball_clear(
                balls[q, 0],
                balls[q, 1],
                balls[q, 2],
                spheres[q, 3] + g,
                m.obstacle_aabb,
                m.obstacles,
                field,
                box,
                rs.fp,
            ):
                return False
    pairs = m.body_pairs
    for pp in range(pairs.shape[0]):
        a = pairs[pp, 0]
        bb = pairs[pp, 1]
        if m.moved[j, a] == m.moved[j, bb]:
            continue
        f = a if not m.moved[j, a] else bb
        mb = bb if f == a else a
        g = pad
        for kk in range(k):  # a joint that moves both moves them rigidly together
            if not m.moved[kk, f]:
                g += half[kk] * _lever(m, kk, mb)
            elif not m.moved[kk, mb]:  # a branch of a tree (a finger): it moves f alone
                g += half[kk] * _lever(m, kk, f)
        for sm in range(ranges.shape[0]):
            if shape_body[sm] != mb:
                continue
            for sf in range(ranges.shape[0]):
                if shape_body[sf] != f:
                    continue
                _world_balls(sf, R[f], p[f], spheres, ranges, balls)
                for qm in range(ranges[sm, 0], ranges[sm, 1]):
                    for qf in range(ranges[sf, 0], ranges[sf, 1]):
                        dx = balls[qm, 0] - balls[qf, 0]
                        dy = balls[qm, 1] - balls[qf, 1]
                        dz = balls[qm, 2] - balls[qf, 2]
                        rr = spheres[qm, 3] + spheres[qf, 3] + g + SEP_EPS
                        if dx * dx + dy * dy + dz * dz <= rr * rr:
                            return False
    return True
