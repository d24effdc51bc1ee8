"""The velocity damper's shapes and its rows in compiled code (numba):
each shape's probe points, bounding ball and box and round radius; from Drake's
witness points of the near pairs, each pair's witness row and its probe
rows, and every row's Jacobian row, in one call (:func:`pair_rows`); the
exact signed distance of a point from a box, sphere, capsule or cylinder
(:func:`point_distance`, what Drake's ``ComputeSignedDistanceToPoint``
reports) for a probe against a moving link; the pairs of spheres and
capsules measured in closed form (:func:`round_pairs`: their segments'
distance less their radii, which Drake's GJK reports up to 0.2 mm above).
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
