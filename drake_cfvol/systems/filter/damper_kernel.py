"""The velocity damper's shapes and its rows in compiled code (numba):
each shape's probe points, bounding ball and box and round radius; from Drake's
witness points of the near pairs, each pair's witness row and its probe
rows, and every row's Jacobian row, in one call (:func:`pair_rows`); the
exact signed distance of a point from a box, sphere, capsule or cylinder
(:func:`point_distance`, what Drake's ``ComputeSignedDistanceToPoint``
reports) for a probe against a moving link; the pairs of spheres and
capsules measured in closed form, as Drake measures them
(:func:`round_pairs`); cached witness planes that stand in for Drake's
query (:func:`store_planes`, :func:`plane_gaps`).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from drake_cfvol.kernel import kinds
from drake_cfvol.kernel.kinds import box as _box
from drake_cfvol.kernel.kinds import capsule as _capsule
from drake_cfvol.kernel.kinds import cylinder as _cylinder
from drake_cfvol.kernel.kinds import sphere as _sphere
from drake_cfvol.kernel.types import BOX, CAPSULE, CYLINDER, SPHERE

__all__ = [
    "bounding_gaps",
    "near_pairs",
    "plane_gaps",
    "round_pairs",
    "store_planes",
    "NO_POINT_QUERY",
    "SPHERE",
    "CAPSULE",
    "BOX",
    "CYLINDER",
    "point_distance",
    "pair_rows",
    "probes",
    "support_spheres",
    "ball_radius",
    "local_box",
    "round_radius",
    "point_query_shape",
]

#: The point-query kind of a shape :func:`point_distance` cannot measure
#: (the others are their kernel codes).
NO_POINT_QUERY = -1


def _geometry(shape):
    """The shape's kind geometry, None for one no kind reads (or a mesh
    without a hull) or an unbounded one: the filter measures those with
    Drake alone."""
    g = kinds.geometry(shape, strict=False)
    return None if g is None or g.kind.unbounded else g


def point_query_shape(shape) -> tuple[int, np.ndarray]:
    """(kind, parameters) of a shape for :func:`point_distance`
    (NO_POINT_QUERY for a kind without one): the kind's row sizes."""
    g = _geometry(shape)
    if g is None or not g.kind.point_query:
        return NO_POINT_QUERY, np.zeros(3)
    return g.kind.code, np.asarray(g.sizes, float)


def probes(shape) -> tuple[np.ndarray, np.ndarray]:
    """The kind's probe spheres of a shape (:meth:`ShapeKind.probes`), in
    its frame: centres (3 x m) and radii (m,)."""
    g = _geometry(shape)
    if g is None:
        return np.zeros((3, 0)), np.zeros(0)
    centres, radii = g.kind.probes(g.sizes, g.verts)
    return (centres + g.centre).T, radii


def support_spheres(shape) -> tuple[np.ndarray, np.ndarray]:
    """The kind's spheres that hold a shape's support
    (:meth:`ShapeKind.support_spheres`), in its frame: centres (3 x m) and
    radii (m,) (none for a shape no kind reads)."""
    g = _geometry(shape)
    if g is None:
        return np.zeros((3, 0)), np.zeros(0)
    centres, radii = g.kind.support_spheres(g.sizes, g.verts)
    return (np.asarray(centres, float).reshape(-1, 3) + g.centre).T, np.asarray(radii, float)


def ball_radius(shape) -> float:
    """The radius of a ball about the shape's frame origin that holds the
    shape, m (inf if unknown)."""
    g = _geometry(shape)
    if g is None:
        return np.inf
    return float(np.linalg.norm(g.centre)) + g.kind.radius(g.sizes, g.verts)


def local_box(shape) -> tuple[np.ndarray, np.ndarray]:
    """A box holding the shape, in its frame: (centre, half extents), m
    (a huge box for a shape of unknown extent)."""
    g = _geometry(shape)
    if g is None:
        return np.zeros(3), np.full(3, 1e6)
    return np.asarray(g.centre, float).copy(), g.kind.half_extents(g.sizes, g.verts)


def round_radius(shape) -> float:
    """The radius of the round part of a shape, m: its witness point's
    lever arm grows by it (0 for a polytope, whose probes are its
    vertices)."""
    g = _geometry(shape)
    return 0.0 if g is None else g.kind.round_radius(g.sizes)


@njit(cache=True, inline="always")
def _mm_into(out, A, B):
    """out = A B for 3 x 3 matrices, written out (numba's ``@`` calls BLAS,
    which needs scipy at run time) into scratch (an array made per probe
    cost more than the row itself)."""
    for r in range(3):
        for c in range(3):
            out[r, c] = A[r, 0] * B[0, c] + A[r, 1] * B[1, c] + A[r, 2] * B[2, c]


@njit(cache=True, inline="always")
def _affine_into(out, A, x, t):
    """out = A x + t for a 3 x 3 A."""
    for r in range(3):
        out[r] = A[r, 0] * x[0] + A[r, 1] * x[1] + A[r, 2] * x[2] + t[r]


@njit(cache=True, inline="always")
def _rotate_into(out, A, x):
    """out = A x for a 3 x 3 A."""
    for r in range(3):
        out[r] = A[r, 0] * x[0] + A[r, 1] * x[1] + A[r, 2] * x[2]


@njit(cache=True)
def point_distance(kind, prm, q, out_g, out_near):
    """Signed distance of point q (shape frame) from a shape of ``kind``
    (a kernel code of a kind with ``point_query``) with parameters ``prm``
    (its row sizes), m; the unit gradient and the nearest surface point
    written into ``out_g`` and ``out_near`` (shape frame): the kind
    modules' ``point_distance``."""
    if kind == SPHERE:
        return _sphere.point_distance(prm, q, out_g, out_near)
    if kind == CAPSULE:
        return _capsule.point_distance(prm, q, out_g, out_near)
    if kind == BOX:
        return _box.point_distance(prm, q, out_g, out_near)
    return _cylinder.point_distance(prm, q, out_g, out_near)


@njit(cache=True, inline="always")
def _jacobian_row(d, p, slot, o, J_w, J_v, out, sign):
    """out += sign * d . J(p), J(p) the translational Jacobian of point p on
    body ``slot`` (v_P = v_o + w x r, r = p - o: d . v_P = d . J_v v +
    (r x d) . J_w v); nothing on a welded body (slot < 0)."""
    if slot < 0:
        return
    rx, ry, rz = p[0] - o[slot, 0], p[1] - o[slot, 1], p[2] - o[slot, 2]
    cx, cy, cz = ry * d[2] - rz * d[1], rz * d[0] - rx * d[2], rx * d[1] - ry * d[0]
    for j in range(out.shape[0]):
        out[j] += sign * (
            d[0] * J_v[slot, 0, j]
            + d[1] * J_v[slot, 1, j]
            + d[2] * J_v[slot, 2, j]
            + cx * J_w[slot, 0, j]
            + cy * J_w[slot, 1, j]
            + cz * J_w[slot, 2, j]
        )


@njit(cache=True, inline="always")
def _emit(out, m, d, p1, p2, s1, s2, rhs, r1, r2, pair, kin):
    """Writes row m of ``out`` (A, b, dirs, points, slots, rounds, owner):
    direction d, points p1 / p2 on slots s1 / s2, right-hand side, round
    radii, pair; its Jacobian row from ``kin`` (R, o, J_w, J_v)."""
    A, b, dirs, points, slots, rounds, owner = out
    o, J_w, J_v = kin[1], kin[2], kin[3]
    for i in range(3):
        dirs[m, i] = d[i]
        points[m, 0, i] = p1[i]
        points[m, 1, i] = p2[i]
    slots[m, 0], slots[m, 1] = s1, s2
    rounds[m, 0], rounds[m, 1] = r1, r2
    b[m] = rhs
    owner[m] = pair
    A[m, :] = 0.0
    _jacobian_row(d, p1, s1, o, J_w, J_v, A[m], 1.0)
    _jacobian_row(d, p2, s2, o, J_w, J_v, A[m], -1.0)
    return m + 1


@njit(cache=True, inline="always")
def _probe_rows(out, m, p, n, w, P, XR, Xt, sides, kin, gains, scratch):
    """Pair p's probe rows (its sides' witnesses w, probes P and geometry
    poses XR, Xt in the world), from row m on; returns the next row.
    ``scratch``: (6, 3), overwritten (made once per call of
    :func:`pair_rows`, not per pair)."""
    side_slot, n_probes, radii, kind, prm = sides[0], sides[4], sides[5], sides[6], sides[7]
    influence, rate, target = gains
    g, near, q_local, gw, nw, neg = scratch[0], scratch[1], scratch[2], scratch[3], scratch[4], scratch[5]
    for s in range(2):
        t = 1 - s
        sign = 1.0 if s == 0 else -1.0
        slot, s_other = side_slot[p, s], side_slot[p, t]
        if slot < 0:
            continue
        for i3 in range(3):
            neg[i3] = sign * n[i3]
        for c in range(n_probes[p, s]):
            gap = (
                sign * ((P[s, c, 0] - w[t, 0]) * n[0] + (P[s, c, 1] - w[t, 1]) * n[1] + (P[s, c, 2] - w[t, 2]) * n[2])
                - radii[p, s, c]
            )
            if gap >= influence:
                continue
            if s_other < 0:  # a static obstacle: the plane through its witness
                m = _emit(out, m, neg, P[s, c], w[t], slot, -1, -rate * (gap - target), 0.0, 0.0, p, kin)
                continue
            if kind[p, t] == NO_POINT_QUERY:
                break  # a moving shape without a point query: the witness row only
            for i3 in range(3):
                q_local[i3] = (
                    XR[t, 0, i3] * (P[s, c, 0] - Xt[t, 0])
                    + XR[t, 1, i3] * (P[s, c, 1] - Xt[t, 1])
                    + XR[t, 2, i3] * (P[s, c, 2] - Xt[t, 2])
                )
            dist_p = point_distance(kind[p, t], prm[p, t], q_local, g, near)
            if dist_p - radii[p, s, c] >= influence:
                continue
            _rotate_into(gw, XR[t], g)
            _affine_into(nw, XR[t], near, Xt[t])
            m = _emit(
                out, m, gw, P[s, c], nw, slot, s_other, -rate * (dist_p - radii[p, s, c] - target), 0.0, 0.0, p, kin
            )
    return m


@njit(cache=True)
def pair_rows(near, sides, kin, gains):
    """Every near pair's rows (SPEC 9; see
    :meth:`~drake_cfvol.systems.filter.damper.VelocityDamper.rows`).

    Args:
        near: (pairs, dist, normal, witness, pose_R, pose_t):
        pairs: (N,) the near pairs' indices; dist (N,), normal (N, 3)
            (Drake's nhat_BA_W), witness (N, 2, 3) (p_ACa, p_BCb in the
            geometry frames), pose_R (P, 2, 3, 3) / pose_t (P, 2, 3): every
            pair side's geometry pose in the world, as the broad phase
            posed it (used for a side on no moving body of the robot).
        sides: (side_slot, side_R, side_t, probes, n_probes, radii, kind,
            prm, round_r): side_slot (P, 2), each pair side's moving body slot (-1: none);
            side_R / side_t (P, 2, ...): X_BG; probes (P, 2, n, 3) in the
            body frame, n_probes (P, 2), radii (P, 2, n); kind / prm
            (P, 2, ...) the side's shape for point queries; round_r (P, 2).
        kin: (R, o, J_w, J_v), the moving bodies' poses and Jacobians (per slot).
        gains: (influence, rate, target): d_inf, the rate, d_t.

    Returns:
        (A, b, dirs, points, slots, rounds, pair), the rows.
    """
    pairs, dist, normal, witness, pose_R, pose_t = near
    side_slot, side_R, side_t, probes, n_probes, radii, kind, prm, round_r = sides
    R, o = kin[0], kin[1]
    influence, rate, target = gains
    N, k = len(pairs), kin[2].shape[2]
    cap = N * (1 + 2 * probes.shape[2])
    # Room for every probe's row (most are not made): not zeroed, _emit
    # writes each field of a row it makes, and only those rows are returned.
    A, b = np.empty((cap, k)), np.empty(cap)
    dirs, points = np.empty((cap, 3)), np.empty((cap, 2, 3))
    slots, rounds, owner = np.empty((cap, 2), np.int64), np.empty((cap, 2)), np.empty(cap, np.int64)
    out = (A, b, dirs, points, slots, rounds, owner)
    w = np.zeros((2, 3))
    P = np.zeros((2, probes.shape[2], 3))
    XR, Xt = np.zeros((2, 3, 3)), np.zeros((2, 3))
    scratch = np.zeros((6, 3))
    m = 0
    for i in range(N):
        p = pairs[i]
        n = normal[i]
        for s in range(2):
            slot = side_slot[p, s]
            if slot < 0:
                XR[s], Xt[s] = pose_R[p, s], pose_t[p, s]
            else:  # the geometry's pose from its body's: R_WB R_BG, R_WB t_BG + o
                _mm_into(XR[s], R[slot], side_R[p, s])
                _affine_into(Xt[s], R[slot], side_t[p, s], o[slot])
            _affine_into(w[s], XR[s], witness[i, s], Xt[s])
            if slot >= 0:
                for c in range(n_probes[p, s]):
                    _affine_into(P[s, c], R[slot], probes[p, s, c], o[slot])
        sa, sb = side_slot[p, 0], side_slot[p, 1]
        m = _emit(
            out,
            m,
            n,
            w[0],
            w[1],
            sa,
            sb,
            -rate * (dist[i] - target),
            round_r[p, 0] if sa >= 0 else 0.0,
            round_r[p, 1] if sb >= 0 else 0.0,
            p,
            kin,
        )
        m = _probe_rows(out, m, p, n, w, P, XR, Xt, sides, kin, gains, scratch)
    return A[:m], b[:m], dirs[:m], points[:m], slots[:m], rounds[:m], owner[:m]


@njit(cache=True, inline="always")
def _gap(n, slot, centre, half, box_R, box_p, R, o):
    """Pair n's lower bound (:func:`bounding_gaps`), without allocating."""
    s0, s1 = slot[n, 0], slot[n, 1]
    if s0 < 0 and s1 < 0:
        return -np.inf
    c0, c1, c2 = 0.0, 0.0, 0.0  # a ball's centre in the world
    d0, d1, d2 = 0.0, 0.0, 0.0
    for j in range(2):
        s = slot[n, j]
        if s >= 0:
            x, y, z = centre[n, j, 0], centre[n, j, 1], centre[n, j, 2]
            e0 = R[s, 0, 0] * x + R[s, 0, 1] * y + R[s, 0, 2] * z + o[s, 0]
            e1 = R[s, 1, 0] * x + R[s, 1, 1] * y + R[s, 1, 2] * z + o[s, 1]
            e2 = R[s, 2, 0] * x + R[s, 2, 1] * y + R[s, 2, 2] * z + o[s, 2]
            if j == 0:
                c0, c1, c2 = e0, e1, e2
            else:
                d0, d1, d2 = e0, e1, e2
    r0 = np.sqrt(half[n, 0, 0] ** 2 + half[n, 0, 1] ** 2 + half[n, 0, 2] ** 2)
    r1 = np.sqrt(half[n, 1, 0] ** 2 + half[n, 1, 1] ** 2 + half[n, 1, 2] ** 2)
    if s0 >= 0 and s1 >= 0:
        return np.sqrt((c0 - d0) ** 2 + (c1 - d1) ** 2 + (c2 - d2) ** 2) - r0 - r1
    j = 0 if s0 >= 0 else 1
    k = 1 - j
    if j == 1:
        c0, c1, c2 = d0, d1, d2
    u0, u1, u2 = c0 - box_p[n, k, 0], c1 - box_p[n, k, 1], c2 - box_p[n, k, 2]
    gap = 0.0
    for a in range(3):
        local = box_R[n, k, 0, a] * u0 + box_R[n, k, 1, a] * u1 + box_R[n, k, 2, a] * u2 - centre[n, k, a]
        gap += max(abs(local) - half[n, k, a], 0.0) ** 2
    return np.sqrt(gap) - (r0 if j == 0 else r1)


@njit(cache=True)
def bounding_gaps(pairs, slot, centre, half, box_R, box_p, R, o):
    """The broad phase's lower bounds of ``pairs``' distances, m: per pair
    side a ball (``slot`` >= 0: on that moving body, its centre in the body
    frame, radius |half|) or a box (centre in the geometry frame, half
    extents ``half``, posed at box_R / box_p in the world); ball to ball:
    their gap; ball to box: the ball centre's distance from the box less
    the radius; box to box: -inf (measure). Bodies posed at R, o."""
    out = np.empty(len(pairs))
    for i in range(len(pairs)):
        out[i] = _gap(pairs[i], slot, centre, half, box_R, box_p, R, o)
    return out


@njit(cache=True)
def near_pairs(measure, slot, centre, half, box_R, box_p, R, o, influence):
    """The broad phase at one update: (per pair its lower bound
    (:func:`bounding_gaps`) where that is at least its ``influence`` (P,)
    (not measured: its distance is at least that), NaN elsewhere; the
    pairs of ``measure`` (P,) bools whose lower bound lies below it, to
    measure)."""
    P = len(measure)
    dists = np.full(P, np.nan)
    near = np.empty(P, np.int64)
    m = 0
    for n in range(P):
        if not measure[n]:
            continue
        lower = _gap(n, slot, centre, half, box_R, box_p, R, o)
        if lower >= influence[n]:
            dists[n] = lower
        else:
            near[m] = n
            m += 1
    return dists, near[:m]


@njit(cache=True, inline="always")
def _geometry_pose(p, s, sides, pose_R, pose_t, R, o, XR, Xt):
    """Pair p's side s's geometry pose in the world into XR, Xt: from its
    body's (``sides``: side_slot, side_R, side_t) or, on no moving body,
    as the broad phase posed it (pose_R, pose_t)."""
    side_slot, side_R, side_t = sides
    slot = side_slot[p, s]
    if slot < 0:
        XR[:, :] = pose_R[p, s]
        Xt[:] = pose_t[p, s]
    else:
        _mm_into(XR, R[slot], side_R[p, s])
        _affine_into(Xt, R[slot], side_t[p, s], o[slot])


@njit(cache=True)
def store_planes(fresh, normal, witness, table, plane_side, hold, sides, pose_R, pose_t, R, o):
    """Keeps Drake's witnesses of the ``fresh`` pairs (N,) (nhat_BA_W
    (N, 3), p_ACa / p_BCb (N, 2, 3) in their geometry frames) as their
    planes in ``table`` (P, 7): age 0, the normal towards the other side
    and a point of the plane, both in the geometry frame of the pair's
    ``plane_side`` (P,) (-1: none kept). The point: the witness, moved
    out along the normal as far as the plane side's support spheres
    (``hold``: centres (P, n, 3) in its geometry frame, counts, radii)
    reach past it (Drake's normal is as exact as its distance: a far
    corner may poke through the plane by its error times its lever). The
    geometries posed as :func:`_geometry_pose` poses them."""
    hold_c, hold_n, hold_r = hold
    XR, Xt = np.zeros((3, 3)), np.zeros(3)
    for i in range(len(fresh)):
        p = fresh[i]
        u = plane_side[p]
        if u < 0:
            continue
        _geometry_pose(p, u, sides, pose_R, pose_t, R, o, XR, Xt)
        sign = 1.0 if u == 1 else -1.0  # nhat_BA_W points from side 1 to side 0
        for r in range(3):
            table[p, 1 + r] = sign * (XR[0, r] * normal[i, 0] + XR[1, r] * normal[i, 1] + XR[2, r] * normal[i, 2])
            table[p, 4 + r] = witness[i, u, r]
        size = np.sqrt(table[p, 1] ** 2 + table[p, 2] ** 2 + table[p, 3] ** 2)  # Drake's may be off unit
        for r in range(3):
            table[p, 1 + r] /= size
        poke = 0.0
        for c in range(hold_n[p]):
            reach = hold_r[p, c]
            for r in range(3):
                reach += table[p, 1 + r] * (hold_c[p, c, r] - table[p, 4 + r])
            poke = max(poke, reach)
        for r in range(3):
            table[p, 4 + r] += poke * table[p, 1 + r]
        table[p, 0] = 0.0


@njit(cache=True)
def plane_gaps(look, table, age, plane_side, spheres, sides, pose_R, pose_t, R, o, floor, reach):
    """Splits the pairs to measure, ``look`` (N,), into those whose cached
    plane still keeps them at least their ``floor`` (P,) apart and the
    others. A pair's
    plane (``table``, :func:`store_planes`; used while younger than ``age``
    updates) goes through its ``plane_side``'s witness and is carried with
    that geometry: the geometry stays behind it however both sides move
    (Drake measures a convex shape, or a mesh's convex hull), so the other
    side's support spheres' (``spheres``: centres (P, 2, n, 3) in the body
    frame, counts, radii) least distance from it bounds the pair's
    distance from below.

    Returns:
        (pairs, bounds, normal, witness, left, far): the cached pairs
        (their ages counted up) nearer than their ``reach`` (P,) with
        their bounds, as Drake's witnesses would read (nhat_BA_W; p_ACa,
        p_BCb in the geometry frames: the point of the support sphere
        nearest the plane and its foot on the plane, so the row's
        direction is the plane's normal at both points); the pairs left
        for Drake; the cached pairs at their reach or beyond with their
        bounds (no rows), as (pairs, bounds).
    """
    centres, counts, radii = spheres
    N = len(look)
    cached, gaps, left = np.empty(N, np.int64), np.empty(N), np.empty(N, np.int64)
    far, far_gaps = np.empty(N, np.int64), np.empty(N)
    normal, witness = np.empty((N, 3)), np.empty((N, 2, 3))
    XR, Xt, YR, Yt = np.zeros((3, 3)), np.zeros(3), np.zeros((3, 3)), np.zeros(3)
    n, w, x, best = np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3)
    nc = nl = nf = 0
    for i in range(N):
        p = look[i]
        u = plane_side[p]
        if u < 0 or not 0.0 <= table[p, 0] < age:
            left[nl] = p
            nl += 1
            continue
        v = 1 - u
        _geometry_pose(p, u, sides, pose_R, pose_t, R, o, XR, Xt)
        for r in range(3):
            n[r] = XR[r, 0] * table[p, 1] + XR[r, 1] * table[p, 2] + XR[r, 2] * table[p, 3]
            w[r] = XR[r, 0] * table[p, 4] + XR[r, 1] * table[p, 5] + XR[r, 2] * table[p, 6] + Xt[r]
        slot = sides[0][p, v]
        least, radius = np.inf, 0.0
        for c in range(counts[p, v]):
            _affine_into(x, R[slot], centres[p, v, c], o[slot])
            gap = n[0] * (x[0] - w[0]) + n[1] * (x[1] - w[1]) + n[2] * (x[2] - w[2]) - radii[p, v, c]
            if gap < least:
                least, radius = gap, radii[p, v, c]
                best[:] = x
        if not least >= floor[p]:
            left[nl] = p
            nl += 1
            continue
        table[p, 0] += 1.0
        if least >= reach[p]:
            far[nf], far_gaps[nf] = p, least
            nf += 1
            continue
        _geometry_pose(p, v, sides, pose_R, pose_t, R, o, YR, Yt)
        sign = 1.0 if v == 0 else -1.0
        for r in range(3):
            normal[nc, r] = sign * n[r]
            x[r] = best[r] - radius * n[r]  # on the support sphere, nearest the plane
            w[r] = x[r] - least * n[r]  # its foot on the plane
        for r in range(3):  # into the geometry frames: R^T (point - t)
            witness[nc, v, r] = YR[0, r] * (x[0] - Yt[0]) + YR[1, r] * (x[1] - Yt[1]) + YR[2, r] * (x[2] - Yt[2])
            witness[nc, u, r] = XR[0, r] * (w[0] - Xt[0]) + XR[1, r] * (w[1] - Xt[1]) + XR[2, r] * (w[2] - Xt[2])
        cached[nc], gaps[nc] = p, least
        nc += 1
    return cached[:nc], gaps[:nc], normal[:nc], witness[:nc], left[:nl], (far[:nf], far_gaps[:nf])


@njit(cache=True, inline="always")
def _clamp01(x):
    return min(max(x, 0.0), 1.0)


@njit(cache=True)
def _segment_closest(p1, d1, p2, d2, c1, c2):
    """The closest points c1 = p1 + s d1, c2 = p2 + t d2 (s, t in [0, 1])
    of two segments, into c1, c2 (Ericson, Real-Time Collision Detection,
    5.1.9; a zero-length segment is its point)."""
    r0, r1, r2 = p1[0] - p2[0], p1[1] - p2[1], p1[2] - p2[2]
    a = d1[0] * d1[0] + d1[1] * d1[1] + d1[2] * d1[2]
    e = d2[0] * d2[0] + d2[1] * d2[1] + d2[2] * d2[2]
    f = d2[0] * r0 + d2[1] * r1 + d2[2] * r2
    tiny = 1e-24
    if a <= tiny and e <= tiny:
        s = t = 0.0
    elif a <= tiny:
        s, t = 0.0, _clamp01(f / e)
    else:
        c = d1[0] * r0 + d1[1] * r1 + d1[2] * r2
        if e <= tiny:
            s, t = _clamp01(-c / a), 0.0
        else:
            b = d1[0] * d2[0] + d1[1] * d2[1] + d1[2] * d2[2]
            denom = a * e - b * b
            s = _clamp01((b * f - c * e) / denom) if denom > 0.0 else 0.0
            t = (b * s + f) / e
            if t < 0.0:
                s, t = _clamp01(-c / a), 0.0
            elif t > 1.0:
                s, t = _clamp01((b - c) / a), 1.0
    for i in range(3):
        c1[i] = p1[i] + s * d1[i]
        c2[i] = p2[i] + t * d2[i]


@njit(cache=True)
def round_pairs(look, analytic, sides, kind, prm, pose_R, pose_t, R, o):
    """Splits the pairs to measure, ``look`` (N,), into those of two
    spheres or capsules (``analytic`` (P,)), measured here in closed form
    (the distance of their segments less their radii, as Drake measures
    them), and the others. A pair whose segments meet (no normal) is left
    for Drake.

    Returns:
        (pairs, distances, normal, witness, left): the measured pairs with
        what Drake's query reports (signed distance; nhat_BA_W; p_ACa,
        p_BCb in the geometry frames), and the pairs left for Drake.
    """
    N = len(look)
    done, dist, left = np.empty(N, np.int64), np.empty(N), np.empty(N, np.int64)
    normal, witness = np.empty((N, 3)), np.empty((N, 2, 3))
    XR, Xt = np.zeros((2, 3, 3)), np.zeros((2, 3))
    ends, axes, closest = np.zeros((2, 3)), np.zeros((2, 3)), np.zeros((2, 3))
    nd = nl = 0
    for i in range(N):
        p = look[i]
        if not analytic[p]:
            left[nl] = p
            nl += 1
            continue
        for s in range(2):
            _geometry_pose(p, s, sides, pose_R, pose_t, R, o, XR[s], Xt[s])
            h = prm[p, s, 1] if kind[p, s] == CAPSULE else 0.0  # the segment's half length along z
            for r in range(3):
                ends[s, r] = Xt[s, r] - h * XR[s, r, 2]
                axes[s, r] = 2.0 * h * XR[s, r, 2]
        _segment_closest(ends[0], axes[0], ends[1], axes[1], closest[0], closest[1])
        g0, g1, g2 = closest[0, 0] - closest[1, 0], closest[0, 1] - closest[1, 1], closest[0, 2] - closest[1, 2]
        apart = np.sqrt(g0 * g0 + g1 * g1 + g2 * g2)
        if apart <= 1e-9:
            left[nl] = p
            nl += 1
            continue
        n = (g0 / apart, g1 / apart, g2 / apart)
        ra, rb = prm[p, 0, 0], prm[p, 1, 0]
        for r in range(3):
            normal[nd, r] = n[r]
        for s in range(2):
            reach = -ra if s == 0 else rb
            for r in range(3):  # the witness on side s's surface, into its geometry frame
                x = closest[s, 0] + reach * n[0] - Xt[s, 0]
                y = closest[s, 1] + reach * n[1] - Xt[s, 1]
                z = closest[s, 2] + reach * n[2] - Xt[s, 2]
                witness[nd, s, r] = XR[s, 0, r] * x + XR[s, 1, r] * y + XR[s, 2, r] * z
        done[nd], dist[nd] = p, apart - ra - rb
        nd += 1
    return done[:nd], dist[:nd], normal[:nd], witness[:nd], left[:nl]
