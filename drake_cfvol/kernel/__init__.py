"""The compiled collision kernel (numba, ``@njit(cache=True)``).

One kernel serves joint bounding, the volume test, categorization
distances, the Confidence Factor's pre-filter and certification. It works on
plain arrays extracted from Drake once (:mod:`drake_cfvol.scene.arrays`):

- forward kinematics of the robot's chain (:func:`fk`), tested against
  Drake's poses to 1e-12;
- convex shapes given by exact support functions: boxes, spheres, capsules,
  cylinders, ellipsoids, and convex hulls of meshes (what Drake itself uses
  for a mesh in point-pair queries);
- motion sets folded into the support: a ball of radius ``e_iso`` (any
  motion), a disc of radius ``e_disc`` normal to an axis u (rotation about
  u), a segment of half-length ``e_seg`` along u (translation);
- a boolean GJK whose "separated" answer is a certificate: a direction d
  with h_A(d) + h_B(-d) < 0 computed from the exact supports, so the kernel
  never calls a pose free where the shapes overlap. Where GJK does not
  conclude it answers "may collide" (conservative);
- the height-field volume V: a 2-D range-maximum table, and a shape against
  the columns by recursive halving of its footprint (exact at one cell).

Shape rows (``SHAPE_W`` floats): kind, centre (3), rotation (9, row-major),
size (3), first vertex, end vertex, e_iso, axis u (3), e_disc, e_seg.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit, prange

__all__ = ["Chain", "Model", "HeightField", "Scratch", "RegionScratch", "BOX", "SPHERE", "CAPSULE", "CYLINDER", "ELLIPSOID", "HULL", "SHAPE_W", "fk", "gjk_intersect",
           "range_max_table", "range_max", "object_hits_columns", "configs_may_collide", "sweep_chains",
           "lower_columns_under", "obstacle_distances", "row_aabb", "configs_may_collide_serial", "regions_hit"]

BOX, SPHERE, CAPSULE, CYLINDER, ELLIPSOID, HULL = 0, 1, 2, 3, 4, 5
SHAPE_W = 25
# Offsets in a shape row.
_K, _C, _R, _S, _V0, _V1, _EI, _U, _ED, _ES = 0, 1, 4, 13, 16, 17, 18, 19, 22, 23
#: A separating direction must separate by at least this (m): numerical
#: rounding can never turn an overlap into "free".
SEP_EPS = 1e-9


# -- typed arguments (numba takes named tuples of arrays) ---------------------

class Chain(NamedTuple):
    """The robot's kinematic chain, bodies in topological order (B of them):
    X_WB = X_WP X_PF X_FM(q) X_MB."""

    parent: np.ndarray  #: (B,) int: the parent body's index, -1 the world
    jtype: np.ndarray  #: (B,) int: 0 weld, 1 revolute, 2 prismatic
    qidx: np.ndarray  #: (B,) int: the joint's position index
    axis: np.ndarray  #: (B, 3): the joint's unit axis in F
    R_PF: np.ndarray  #: (B, 3, 3)
    p_PF: np.ndarray  #: (B, 3)
    R_MB: np.ndarray  #: (B, 3, 3)
    p_MB: np.ndarray  #: (B, 3)


class Model(NamedTuple):
    """The robot and its obstacles as the kernel sees them
    (:meth:`drake_cfvol.scene.arrays.SceneArrays.model`)."""

    chain: Chain
    shapes: np.ndarray  #: (S, SHAPE_W) robot shape rows in their body frames
    shape_body: np.ndarray  #: (S,) int
    verts: np.ndarray  #: (V, 3) hull vertices of every mesh shape (robot and obstacles)
    obstacles: np.ndarray  #: (O, SHAPE_W) obstacle rows in the world
    obstacle_aabb: np.ndarray  #: (O, 6)
    body_pairs: np.ndarray  #: (P, 2) int: robot body pairs Drake does not filter
    shape_pairs: np.ndarray  #: (P', 2) int: robot shape pairs of those body pairs
    movable: np.ndarray  #: (B,) bool: moved by some joint
    moved: np.ndarray  #: (k, B) bool: joint j moves body b
    reach: np.ndarray  #: (k, B): body b's shapes' largest distance from joint j's axis
    curvature: np.ndarray  #: (k, k, B): second-derivative bounds of b's points
    revolute: np.ndarray  #: (k,) bool
    joint_body: np.ndarray  #: (k,) int: the body each joint moves first


class HeightField(NamedTuple):
    """The volume V's columns: a range-maximum table and the grid."""

    table: np.ndarray  #: :func:`range_max_table` of the heights; (1, 1, 0, 0): none
    ox: float  #: the grid's corner x, m
    oy: float  #: the grid's corner y, m
    side: float  #: a cell's side, m


class Scratch(NamedTuple):
    """One thread's scratch for the scene tests (:func:`new_scratch`)."""

    ws: np.ndarray
    stack: np.ndarray
    box: np.ndarray
    tmp6: np.ndarray


class RegionScratch(NamedTuple):
    """One thread's scratch for the region tests (:func:`_region_workspace`)."""

    RP: np.ndarray
    pP: np.ndarray
    objs: np.ndarray
    aabbs: np.ndarray
    rel: np.ndarray
    rel_aabb: np.ndarray
    q_c: np.ndarray


# -- forward kinematics ----------------------------------------------------

@njit(cache=True)
def _axis_rotation(u, theta, out):
    """Rotation matrix about unit axis u by theta (Rodrigues), into out."""
    c = np.cos(theta)
    s = np.sin(theta)
    t = 1.0 - c
    x, y, z = u[0], u[1], u[2]
    out[0, 0] = t * x * x + c
    out[0, 1] = t * x * y - s * z
    out[0, 2] = t * x * z + s * y
    out[1, 0] = t * x * y + s * z
    out[1, 1] = t * y * y + c
    out[1, 2] = t * y * z - s * x
    out[2, 0] = t * x * z - s * y
    out[2, 1] = t * y * z + s * x
    out[2, 2] = t * z * z + c


@njit(cache=True, inline="always")
def _mm(A, B, out):
    """out = A B for 3x3 matrices (no BLAS call: these are tiny)."""
    for r in range(3):
        a0 = A[r, 0]
        a1 = A[r, 1]
        a2 = A[r, 2]
        out[r, 0] = a0 * B[0, 0] + a1 * B[1, 0] + a2 * B[2, 0]
        out[r, 1] = a0 * B[0, 1] + a1 * B[1, 1] + a2 * B[2, 1]
        out[r, 2] = a0 * B[0, 2] + a1 * B[1, 2] + a2 * B[2, 2]


@njit(cache=True, inline="always")
def _mv_add(A, v, base, out):
    """out = base + A v (3x3 times 3-vector)."""
    x = A[0, 0] * v[0] + A[0, 1] * v[1] + A[0, 2] * v[2]
    y = A[1, 0] * v[0] + A[1, 1] * v[1] + A[1, 2] * v[2]
    z = A[2, 0] * v[0] + A[2, 1] * v[1] + A[2, 2] * v[2]
    out[0] = base[0] + x
    out[1] = base[1] + y
    out[2] = base[2] + z


@njit(cache=True)
def fk_into(q, chain, R_WB, p_WB):
    """Body poses X_WB at q into (B, 3, 3) / (B, 3) arrays. Bodies are in
    topological order (parents first); parent -1 is the world.
    X_WB = X_WP X_PF X_FM(q) X_MB. ``chain``: a :class:`Chain`."""
    parent, jtype, qidx, axis, R_PF, p_PF, R_MB, p_MB = chain
    B = parent.shape[0]
    M = np.empty((3, 3, 3))  # R_FM, R_PM, R_PB
    V = np.empty((3, 3))  # p_FM, p_PM, p_PB
    for b in range(B):
        R_FM = M[0]
        if jtype[b] == 1:
            _axis_rotation(axis[b], q[qidx[b]], R_FM)
        else:
            R_FM[:, :] = 0.0
            R_FM[0, 0] = 1.0
            R_FM[1, 1] = 1.0
            R_FM[2, 2] = 1.0
        V[0, :] = 0.0
        if jtype[b] == 2:
            qq = q[qidx[b]]
            V[0, 0] = axis[b, 0] * qq
            V[0, 1] = axis[b, 1] * qq
            V[0, 2] = axis[b, 2] * qq
        _mm(R_PF[b], R_FM, M[1])
        _mv_add(R_PF[b], V[0], p_PF[b], V[1])
        _mm(M[1], R_MB[b], M[2])
        _mv_add(M[1], p_MB[b], V[1], V[2])
        par = parent[b]
        if par < 0:
            R_WB[b] = M[2]
            p_WB[b] = V[2]
        else:
            _mm(R_WB[par], M[2], R_WB[b])
            _mv_add(R_WB[par], V[2], p_WB[par], p_WB[b])


@njit(cache=True, parallel=True)
def fk(Q, chain):
    """Body poses for many configurations: (N, B, 3, 3), (N, B, 3)."""
    N = Q.shape[0]
    B = chain.parent.shape[0]
    R = np.empty((N, B, 3, 3))
    p = np.empty((N, B, 3))
    # numba passes no tuples of arrays into a parallel loop: the chain's
    # arrays go in one by one, the chain is rebuilt inside.
    parent, jtype, qidx, axis, R_PF, p_PF, R_MB, p_MB = chain
    for n in prange(N):
        fk_into(Q[n], Chain(parent, jtype, qidx, axis, R_PF, p_PF, R_MB, p_MB), R[n], p[n])
    return R, p


# -- shapes in the world -----------------------------------------------------

@njit(cache=True)
def pose_shape(local, R_WB, p_WB, out):
    """A shape row posed in the world: out = local with the body pose applied
    (centre and rotation); the motion fields are left as in ``local``."""
    out[:] = local
    for i in range(3):
        acc = p_WB[i]
        for j in range(3):
            acc += R_WB[i, j] * local[_C + j]
        out[_C + i] = acc
    for i in range(3):
        for j in range(3):
            acc = 0.0
            for k in range(3):
                acc += R_WB[i, k] * local[_R + 3 * k + j]
            out[_R + 3 * i + j] = acc


@njit(cache=True)
def set_motion(row, e_iso, u0, u1, u2, e_disc, e_seg):
    row[_EI] = e_iso
    row[_U] = u0
    row[_U + 1] = u1
    row[_U + 2] = u2
    row[_ED] = e_disc
    row[_ES] = e_seg


@njit(cache=True, inline="always")
def _local_support(row, verts, l0, l1, l2):
    """The shape's support point along l (its own frame, no motion set)."""
    kind = int(row[_K])
    s0 = row[_S]
    s1 = row[_S + 1]
    s2 = row[_S + 2]
    x = 0.0
    y = 0.0
    z = 0.0
    if kind == 0:  # box: half extents
        x = s0 if l0 >= 0 else -s0
        y = s1 if l1 >= 0 else -s1
        z = s2 if l2 >= 0 else -s2
    elif kind == 1:  # sphere: radius
        n = np.sqrt(l0 * l0 + l1 * l1 + l2 * l2)
        if n > 0:
            x = s0 * l0 / n
            y = s0 * l1 / n
            z = s0 * l2 / n
    elif kind == 2:  # capsule along z: radius, half length
        n = np.sqrt(l0 * l0 + l1 * l1 + l2 * l2)
        z = s1 if l2 >= 0 else -s1
        if n > 0:
            x = s0 * l0 / n
            y = s0 * l1 / n
            z += s0 * l2 / n
    elif kind == 3:  # cylinder along z: radius, half length
        n = np.sqrt(l0 * l0 + l1 * l1)
        z = s1 if l2 >= 0 else -s1
        if n > 0:
            x = s0 * l0 / n
            y = s0 * l1 / n
    elif kind == 4:  # ellipsoid: semi-axes
        a0 = s0 * s0 * l0
        a1 = s1 * s1 * l1
        a2 = s2 * s2 * l2
        n = np.sqrt(a0 * l0 + a1 * l1 + a2 * l2)
        if n > 0:
            x = a0 / n
            y = a1 / n
            z = a2 / n
    else:  # convex hull: its vertices
        best = -1e300
        for v in range(int(row[_V0]), int(row[_V1])):
            h = verts[v, 0] * l0 + verts[v, 1] * l1 + verts[v, 2] * l2
            if h > best:
                best = h
                x = verts[v, 0]
                y = verts[v, 1]
                z = verts[v, 2]
    return x, y, z


@njit(cache=True, inline="always")
def _add_motion(row, d0, d1, d2, out):
    """Adds the support of the row's motion set along d to out."""
    dn = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
    if dn <= 0:
        return
    ei = row[_EI]
    if ei > 0:
        out[0] += ei * d0 / dn
        out[1] += ei * d1 / dn
        out[2] += ei * d2 / dn
    ed = row[_ED]
    es = row[_ES]
    if ed > 0 or es > 0:
        u0 = row[_U]
        u1 = row[_U + 1]
        u2 = row[_U + 2]
        du = d0 * u0 + d1 * u1 + d2 * u2
        if es > 0:
            sg = 1.0 if du >= 0 else -1.0
            out[0] += es * sg * u0
            out[1] += es * sg * u1
            out[2] += es * sg * u2
        if ed > 0:
            w0 = d0 - du * u0
            w1 = d1 - du * u1
            w2 = d2 - du * u2
            wn = np.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
            if wn > 0:
                out[0] += ed * w0 / wn
                out[1] += ed * w1 / wn
                out[2] += ed * w2 / wn


@njit(cache=True)
def support(row, verts, d0, d1, d2, out):
    """The point of the shape (with its motion set) farthest along d, into
    out (3,). Exact for every kind."""
    # Direction in the shape frame: R^T d.
    l0 = row[_R + 0] * d0 + row[_R + 3] * d1 + row[_R + 6] * d2
    l1 = row[_R + 1] * d0 + row[_R + 4] * d1 + row[_R + 7] * d2
    l2 = row[_R + 2] * d0 + row[_R + 5] * d1 + row[_R + 8] * d2
    x, y, z = _local_support(row, verts, l0, l1, l2)
    out[0] = row[_C] + row[_R + 0] * x + row[_R + 1] * y + row[_R + 2] * z
    out[1] = row[_C + 1] + row[_R + 3] * x + row[_R + 4] * y + row[_R + 5] * z
    out[2] = row[_C + 2] + row[_R + 6] * x + row[_R + 7] * y + row[_R + 8] * z
    _add_motion(row, d0, d1, d2, out)


# -- GJK on convex hulls of posed shapes -----------------------------------------
#
# An "object" is a 2-D array of shape rows (P, SHAPE_W): the convex hull of
# the P posed shapes (each with its motion set). P = 1 is a plain shape;
# P > 1 covers a motion by its end poses (see _region_hits).

@njit(cache=True)
def _cross(a, b, out):
    out[0] = a[1] * b[2] - a[2] * b[1]
    out[1] = a[2] * b[0] - a[0] * b[2]
    out[2] = a[0] * b[1] - a[1] * b[0]


@njit(cache=True, inline="always")
def _dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@njit(cache=True)
def support_multi(obj, verts, d0, d1, d2, out, tmp):
    """Support of the convex hull of the object's rows along d, into out."""
    best = -np.inf
    for p in range(obj.shape[0]):
        support(obj[p], verts, d0, d1, d2, tmp)
        h = tmp[0] * d0 + tmp[1] * d1 + tmp[2] * d2
        if h > best:
            best = h
            out[0] = tmp[0]
            out[1] = tmp[1]
            out[2] = tmp[2]


@njit(cache=True)
def gjk_intersect(A, vA, B, vB, max_iter=64):
    """True where objects A and B (2-D arrays of shape rows) may overlap.

    False only with a certificate: a direction d along which the support of
    A - B lies below -SEP_EPS |d|. Conservative: an undecided run (touching
    shapes, iteration cap) answers True.
    """
    ws = np.empty((18, 3))
    return _gjk(A, vA, B, vB, max_iter, ws)


@njit(cache=True)
def _gjk(A, vA, B, vB, max_iter, ws):
    # Workspace rows: 0-3 simplex (oldest first), 4 d, 5 a, 6 tA, 7 tB,
    # 8-15 scratch, 16-17 support scratch.
    simplex = ws[0:4]
    d = ws[4]
    a = ws[5]
    tA = ws[6]
    tB = ws[7]
    tmp = ws[16]
    n = 0
    # d always points from the simplex towards the origin; the first
    # simplex point is near cA - cB, so start with d = cB - cA.
    d[0] = B[0, _C] - A[0, _C]
    d[1] = B[0, _C + 1] - A[0, _C + 1]
    d[2] = B[0, _C + 2] - A[0, _C + 2]
    if _dot(d, d) < 1e-24:
        d[0] = 1.0
        d[1] = 0.0
        d[2] = 0.0
    for _ in range(max_iter):
        dn = np.sqrt(_dot(d, d))
        if dn < 1e-14:
            return True  # the origin lies on the simplex: touching
        support_multi(A, vA, d[0], d[1], d[2], tA, tmp)
        support_multi(B, vB, -d[0], -d[1], -d[2], tB, tmp)
        a[0] = tA[0] - tB[0]
        a[1] = tA[1] - tB[1]
        a[2] = tA[2] - tB[2]
        if _dot(a, d) < -SEP_EPS * dn:
            return False  # certified separating direction
        simplex[n, 0] = a[0]
        simplex[n, 1] = a[1]
        simplex[n, 2] = a[2]
        n += 1
        n = _do_simplex(simplex, n, d, ws)
        if n < 0:
            return True
    return True


@njit(cache=True)
def _do_simplex(simplex, n, d, ws):
    """Reduces the simplex (newest point last) to the feature nearest the
    origin and points d at the origin. Returns the new size, or -1 when the
    origin is enclosed or on the simplex."""
    ao = ws[8]
    ab = ws[9]
    ac = ws[10]
    ad = ws[11]
    t1 = ws[12]
    abc = ws[13]
    acd = ws[14]
    adb = ws[15]
    if n == 1:
        for i in range(3):
            d[i] = -simplex[0, i]
        return 1
    if n == 2:
        return _segment(simplex, 0, 1, d, ao, ab, t1)
    if n == 3:
        return _triangle(simplex, d, ao, ab, ac, abc, t1)
    # Tetrahedron: rows 0..3 = d, c, b, a (a newest).
    for i in range(3):
        ao[i] = -simplex[3, i]
        ab[i] = simplex[2, i] - simplex[3, i]
        ac[i] = simplex[1, i] - simplex[3, i]
        ad[i] = simplex[0, i] - simplex[3, i]
    _cross(ab, ac, abc)
    _cross(ac, ad, acd)
    _cross(ad, ab, adb)
    # Face normals pointing away from the opposite vertex.
    if _dot(abc, ad) > 0:
        for i in range(3):
            abc[i] = -abc[i]
    if _dot(acd, ab) > 0:
        for i in range(3):
            acd[i] = -acd[i]
    if _dot(adb, ac) > 0:
        for i in range(3):
            adb[i] = -adb[i]
    if _dot(abc, ao) > 0:
        keep0, keep1 = 1, 2  # c, b (+ a)
    elif _dot(acd, ao) > 0:
        keep0, keep1 = 0, 1  # d, c (+ a)
    elif _dot(adb, ao) > 0:
        keep0, keep1 = 2, 0  # b, d (+ a)
    else:
        return -1  # the origin is inside the tetrahedron
    for i in range(3):
        x0 = simplex[keep0, i]
        x1 = simplex[keep1, i]
        simplex[2, i] = simplex[3, i]
        simplex[0, i] = x0
        simplex[1, i] = x1
    return _triangle(simplex, d, ao, ab, ac, abc, t1)


@njit(cache=True)
def _segment(simplex, ib, ia, d, ao, ab, t1):
    """Segment case: b = simplex[ib], a = simplex[ia] (newest). Writes the
    kept points to rows 0.. and returns the size."""
    for i in range(3):
        ao[i] = -simplex[ia, i]
        ab[i] = simplex[ib, i] - simplex[ia, i]
    if _dot(ab, ao) > 0:
        _cross(ab, ao, t1)
        _cross(t1, ab, d)
        for i in range(3):
            x_b = simplex[ib, i]
            x_a = simplex[ia, i]
            simplex[0, i] = x_b
            simplex[1, i] = x_a
        if _dot(d, d) < 1e-24:
            return -1  # origin on the segment
        return 2
    for i in range(3):
        simplex[0, i] = simplex[ia, i]
        d[i] = ao[i]
    return 1


@njit(cache=True)
def _triangle(simplex, d, ao, ab, ac, abc, t1):
    """Triangle case, rows 0..2 = c, b, a (a newest)."""
    for i in range(3):
        ao[i] = -simplex[2, i]
        ab[i] = simplex[1, i] - simplex[2, i]
        ac[i] = simplex[0, i] - simplex[2, i]
    _cross(ab, ac, abc)
    _cross(abc, ac, t1)
    if _dot(t1, ao) > 0:
        if _dot(ac, ao) > 0:
            return _segment(simplex, 0, 2, d, ao, ac, t1)
        return _segment(simplex, 1, 2, d, ao, ab, t1)
    _cross(ab, abc, t1)
    if _dot(t1, ao) > 0:
        return _segment(simplex, 1, 2, d, ao, ab, t1)
    h = _dot(abc, ao)
    if abs(h) < 1e-18 * (1.0 + _dot(abc, abc)):
        return -1  # origin in the triangle
    if h > 0:
        for i in range(3):
            d[i] = abc[i]
    else:
        for i in range(3):
            x = simplex[0, i]
            simplex[0, i] = simplex[1, i]
            simplex[1, i] = x
            d[i] = -abc[i]
    return 3


# -- the height-field volume ---------------------------------------------------

@njit(cache=True)
def range_max_table(h):
    """2-D sparse table of maxima over blocks of 2^a x 2^b cells:
    (la, lb, m, n)."""
    m, n = h.shape
    la = 1
    while (1 << la) <= m:
        la += 1
    lb = 1
    while (1 << lb) <= n:
        lb += 1
    t = np.full((la, lb, m, n), -np.inf)
    t[0, 0] = h
    for b in range(1, lb):
        w = 1 << (b - 1)
        for i in range(m):
            for j in range(n - w):
                t[0, b, i, j] = max(t[0, b - 1, i, j], t[0, b - 1, i, j + w])
    for a in range(1, la):
        w = 1 << (a - 1)
        for b in range(lb):
            for i in range(m - w):
                for j in range(n):
                    t[a, b, i, j] = max(t[a - 1, b, i, j], t[a - 1, b, i + w, j])
    return t


@njit(cache=True)
def _log2floor(x):
    r = 0
    while (1 << (r + 1)) <= x:
        r += 1
    return r


@njit(cache=True, inline="always")
def _clip_block(i0, i1, j0, j1, m, n):
    """A cell block [i0, i1] x [j0, j1] clipped to an m x n grid (it may come
    out empty: i1 < i0 or j1 < j0)."""
    return max(i0, 0), min(i1, m - 1), max(j0, 0), min(j1, n - 1)


@njit(cache=True)
def range_max(t, i0, i1, j0, j1):
    """Max over cells [i0, i1] x [j0, j1] (clipped); -inf if empty."""
    i0, i1, j0, j1 = _clip_block(i0, i1, j0, j1, t.shape[2], t.shape[3])
    if i1 < i0 or j1 < j0:
        return -np.inf
    a = _log2floor(i1 - i0 + 1)
    b = _log2floor(j1 - j0 + 1)
    ia = i1 - (1 << a) + 1
    jb = j1 - (1 << b) + 1
    return max(max(t[a, b, i0, j0], t[a, b, ia, j0]), max(t[a, b, i0, jb], t[a, b, ia, jb]))


# -- bounding boxes and the volume test -----------------------------------------

@njit(cache=True)
def row_aabb(row, verts, out):
    """A shape row's (with its motion set) axis-aligned box, closed form:
    out = [xmin, ymin, zmin, xmax, ymax, zmax]."""
    kind = int(row[_K])
    s0 = row[_S]
    s1 = row[_S + 1]
    s2 = row[_S + 2]
    for a in range(3):
        r0 = row[_R + 3 * a]
        r1 = row[_R + 3 * a + 1]
        r2 = row[_R + 3 * a + 2]
        c = row[_C + a]
        lo = 0.0
        hi = 0.0
        if kind == 0:
            h = abs(r0) * s0 + abs(r1) * s1 + abs(r2) * s2
            lo = -h
            hi = h
        elif kind == 1:
            lo = -s0
            hi = s0
        elif kind == 2:
            h = abs(r2) * s1 + s0
            lo = -h
            hi = h
        elif kind == 3:
            h = abs(r2) * s1 + s0 * np.sqrt(max(1.0 - r2 * r2, 0.0))
            lo = -h
            hi = h
        elif kind == 4:
            h = np.sqrt((r0 * s0) ** 2 + (r1 * s1) ** 2 + (r2 * s2) ** 2)
            lo = -h
            hi = h
        else:
            lo = np.inf
            hi = -np.inf
            for v in range(int(row[_V0]), int(row[_V1])):
                x = r0 * verts[v, 0] + r1 * verts[v, 1] + r2 * verts[v, 2]
                if x < lo:
                    lo = x
                if x > hi:
                    hi = x
        ua = row[_U + a]
        m = row[_EI] + row[_ED] * np.sqrt(max(1.0 - ua * ua, 0.0)) + row[_ES] * abs(ua)
        out[a] = c + lo - m
        out[3 + a] = c + hi + m


@njit(cache=True)
def object_aabb(obj, verts, out, tmp6):
    """The axis-aligned box of an object (union over its rows)."""
    row_aabb(obj[0], verts, out)
    for p in range(1, obj.shape[0]):
        row_aabb(obj[p], verts, tmp6)
        for a in range(3):
            if tmp6[a] < out[a]:
                out[a] = tmp6[a]
            if tmp6[3 + a] > out[3 + a]:
                out[3 + a] = tmp6[3 + a]


@njit(cache=True, inline="always")
def _aabb_apart(a, b):
    return (a[0] > b[3] or b[0] > a[3] or a[1] > b[4] or b[1] > a[4] or a[2] > b[5] or b[2] > a[5])


@njit(cache=True)
def new_workspace():
    """Scratch arrays for the scene tests (one per thread): GJK rows, the
    footprint stack, a one-row box object, and a 6-vector."""
    ws = np.empty((18, 3))
    stack = np.empty((64, 4), np.int64)
    box = np.zeros((1, SHAPE_W))
    box[0, _K] = BOX
    box[0, _R + 0] = 1.0
    box[0, _R + 4] = 1.0
    box[0, _R + 8] = 1.0
    tmp6 = np.empty(6)
    return ws, stack, box, tmp6


@njit(cache=True)
def new_scratch():
    """:func:`new_workspace` as a :class:`Scratch`."""
    ws, stack, box, tmp6 = new_workspace()
    return Scratch(ws, stack, box, tmp6)


@njit(cache=True)
def no_height_field():
    """A :class:`HeightField` without columns (no volume V)."""
    return HeightField(np.zeros((1, 1, 0, 0)), 0.0, 0.0, 1.0)


@njit(cache=True)
def object_hits_columns(obj, verts, aabb, table, ox, oy, side, ws, stack, box):
    """True where the object (its axis-aligned box ``aabb``) may touch a
    column of V. The footprint's cell block is halved until each half is
    free (its tallest column below the object, or a GJK certificate against
    the block's bounding box) or a single cell, tested exactly against its
    column."""
    zmin = aabb[2]
    i0, i1, j0, j1 = _clip_block(int(np.floor((aabb[0] - ox) / side)), int(np.floor((aabb[3] - ox) / side)),
                                 int(np.floor((aabb[1] - oy) / side)), int(np.floor((aabb[4] - oy) / side)),
                                 table.shape[2], table.shape[3])
    if i1 < i0 or j1 < j0:
        return False
    stack[0, 0] = i0
    stack[0, 1] = i1
    stack[0, 2] = j0
    stack[0, 3] = j1
    sp = 1
    while sp > 0:
        sp -= 1
        a0 = stack[sp, 0]
        a1 = stack[sp, 1]
        b0 = stack[sp, 2]
        b1 = stack[sp, 3]
        top = range_max(table, a0, a1, b0, b1)
        if not (top > 0.0) or zmin >= top:
            continue
        # The block's bounding box: cells a0..a1 x b0..b1, floor to top.
        box[0, _C] = ox + (a0 + a1 + 1) * 0.5 * side
        box[0, _C + 1] = oy + (b0 + b1 + 1) * 0.5 * side
        box[0, _C + 2] = 0.5 * top
        box[0, _S] = (a1 - a0 + 1) * 0.5 * side
        box[0, _S + 1] = (b1 - b0 + 1) * 0.5 * side
        box[0, _S + 2] = 0.5 * top
        if not _gjk(obj, verts, box, verts, 64, ws):
            continue
        if a0 == a1 and b0 == b1:
            return True  # exact: the object meets this column
        if sp + 2 > stack.shape[0]:
            return True  # conservative on overflow (never at sane sizes)
        if (a1 - a0) >= (b1 - b0):
            mid = (a0 + a1) // 2
            stack[sp, 0] = a0
            stack[sp, 1] = mid
            stack[sp, 2] = b0
            stack[sp, 3] = b1
            stack[sp + 1, 0] = mid + 1
            stack[sp + 1, 1] = a1
            stack[sp + 1, 2] = b0
            stack[sp + 1, 3] = b1
        else:
            mid = (b0 + b1) // 2
            stack[sp, 0] = a0
            stack[sp, 1] = a1
            stack[sp, 2] = b0
            stack[sp, 3] = mid
            stack[sp + 1, 0] = a0
            stack[sp + 1, 1] = a1
            stack[sp + 1, 2] = mid + 1
            stack[sp + 1, 3] = b1
        sp += 2
    return False


# -- scene tests -----------------------------------------------------------------

@njit(cache=True)
def _pose_objects(R_WB, p_WB, shapes, shape_body, pose, objs):
    """Pose every robot shape into objs[s, pose] for the body poses given."""
    for s in range(shapes.shape[0]):
        b = shape_body[s]
        pose_shape(shapes[s], R_WB[b], p_WB[b], objs[s, pose])


@njit(cache=True)
def _object_vs_scene(obj, aabb, m, field, sc):
    """An object against the obstacles of model ``m`` and the height field
    (an empty table: no V)."""
    verts, obstacles, obs_aabb = m.verts, m.obstacles, m.obstacle_aabb
    table, ox, oy, side = field
    ws, stack, box = sc.ws, sc.stack, sc.box
    for o in range(obstacles.shape[0]):
        if _aabb_apart(aabb, obs_aabb[o]):
            continue
        if _gjk(obj, verts, obstacles[o:o + 1], verts, 64, ws):
            return True
    if table.shape[2] > 0:
        if object_hits_columns(obj, verts, aabb, table, ox, oy, side, ws, stack, box):
            return True
    return False


@njit(cache=True)
def _may_collide_range(Q, start, stop, m, pad, out):
    """configs_may_collide for Q[start:stop], into out, on one thread."""
    shapes, shape_body, verts = m.shapes, m.shape_body, m.verts
    shape_pairs, movable = m.shape_pairs, m.movable
    B = m.chain.parent.shape[0]
    S = shapes.shape[0]
    no_field = no_height_field()
    sc = new_scratch()
    ws = sc.ws
    R_WB = np.empty((B, 3, 3))
    p_WB = np.empty((B, 3))
    objs = np.empty((S, 1, SHAPE_W))
    aabbs = np.empty((S, 6))
    for n in range(start, stop):
        fk_into(Q[n], m.chain, R_WB, p_WB)
        _pose_objects(R_WB, p_WB, shapes, shape_body, 0, objs)
        for s in range(S):
            objs[s, 0, _EI] = shapes[s, _EI] + pad  # the margin against the scene
            row_aabb(objs[s, 0], verts, aabbs[s])
        hit = False
        for s in range(S):
            if not movable[shape_body[s]]:
                continue
            if _object_vs_scene(objs[s], aabbs[s], m, no_field, sc):
                hit = True
                break
        if not hit:
            if pad > 0.0:  # half the margin on each shape of a pair
                for s in range(S):
                    objs[s, 0, _EI] = shapes[s, _EI] + 0.5 * pad
            for p in range(shape_pairs.shape[0]):
                sa = shape_pairs[p, 0]
                sb = shape_pairs[p, 1]
                if _aabb_apart(aabbs[sa], aabbs[sb]):
                    continue
                if _gjk(objs[sa], verts, objs[sb], verts, 64, ws):
                    hit = True
                    break
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
     curvature_, revolute_, joint_body_) = m[1:]
    for c in prange(n_chunks):
        mm = Model(Chain(parent, jtype, qidx, axis, R_PF, p_PF, R_MB, p_MB), shapes_, shape_body_, verts_, obstacles_,
                   obstacle_aabb_, body_pairs_, shape_pairs_, movable_, moved_, reach_, curvature_, revolute_,
                   joint_body_)
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
def _relative_growth(W, i, j, a, b, L_t, L_v, moved, curvature, reach, revolute):
    """Second-order growth of body b's shapes relative to body a over the
    region (joints that move both alike do not count)."""
    k = W.shape[1]
    a_t = 0.0
    for kk in range(k):
        if kk == j or not moved[kk, b] or (a >= 0 and moved[kk, a]):
            continue
        dk = abs(W[i + 1, kk] - W[i, kk])
        if dk == 0.0:
            continue
        for ll in range(k):
            if ll == j or not moved[ll, b] or (a >= 0 and moved[ll, a]):
                continue
            a_t += dk * abs(W[i + 1, ll] - W[i, ll]) * curvature[kk, ll, b]
    grow = a_t * L_t * L_t / 8.0
    if moved[j, b] and revolute[j] and L_v > 0:
        # |d^2 p / dv^2| = distance from j's axis <= reach (any pose).
        grow += reach[j, b] * L_v * L_v / 8.0
    return grow


#: Most poses sampled along t and along v in one region test.
MAX_T_SAMPLES = 5
MAX_V_SAMPLES = 9


@njit(cache=True)
def _region_poses(W, i, j, ts, vs, m, rs, Rot):
    """Body poses at the region's nt x nv grid points into rs.RP, rs.pP:
    forward kinematics at each t (joint j at va), then joint j's motion
    applied about (along) its axis for the other v."""
    ta, tb, nt = ts
    va, vb, nv = vs
    B = m.chain.parent.shape[0]
    R_MB, p_MB, axis = m.chain.R_MB, m.chain.p_MB, m.chain.axis
    moved, revolute = m.moved, m.revolute
    RP, pP, q_c = rs.RP, rs.pP, rs.q_c
    k = W.shape[1]
    jb = m.joint_body[j]
    for ti in range(nt):
        t = ta if nt == 1 else ta + (tb - ta) * ti / (nt - 1)
        for kk in range(k):
            q_c[kk] = W[i, kk] + t * (W[i + 1, kk] - W[i, kk])
        q_c[j] = va
        c0 = ti * nv
        fk_into(q_c, m.chain, RP[c0], pP[c0])
        if nv == 1:
            continue
        # Joint j's axis in the world (through its child frame's origin):
        # p_WM = p_WB - R_WB R_MB^T p_MB, u = R_WB R_MB^T axis.
        RB = RP[c0, jb]
        RM = R_MB[jb]
        pm = p_MB[jb]
        ax = axis[jb]
        cw0 = pP[c0, jb, 0]
        cw1 = pP[c0, jb, 1]
        cw2 = pP[c0, jb, 2]
        u0 = 0.0
        u1 = 0.0
        u2 = 0.0
        for r in range(3):
            tr = RM[0, r] * pm[0] + RM[1, r] * pm[1] + RM[2, r] * pm[2]
            ar = RM[0, r] * ax[0] + RM[1, r] * ax[1] + RM[2, r] * ax[2]
            cw0 -= RB[0, r] * tr
            cw1 -= RB[1, r] * tr
            cw2 -= RB[2, r] * tr
            u0 += RB[0, r] * ar
            u1 += RB[1, r] * ar
            u2 += RB[2, r] * ar
        un = np.array([u0, u1, u2])
        for vi in range(1, nv):
            c = c0 + vi
            dv = (vb - va) * vi / (nv - 1)
            if revolute[j]:
                _axis_rotation(un, dv, Rot)
            for b in range(B):
                if not moved[j, b]:
                    RP[c, b] = RP[c0, b]
                    pP[c, b] = pP[c0, b]
                elif revolute[j]:
                    _mm(Rot, RP[c0, b], RP[c, b])
                    x0 = pP[c0, b, 0] - cw0
                    x1 = pP[c0, b, 1] - cw1
                    x2 = pP[c0, b, 2] - cw2
                    pP[c, b, 0] = cw0 + Rot[0, 0] * x0 + Rot[0, 1] * x1 + Rot[0, 2] * x2
                    pP[c, b, 1] = cw1 + Rot[1, 0] * x0 + Rot[1, 1] * x1 + Rot[1, 2] * x2
                    pP[c, b, 2] = cw2 + Rot[2, 0] * x0 + Rot[2, 1] * x1 + Rot[2, 2] * x2
                else:
                    RP[c, b] = RP[c0, b]
                    pP[c, b, 0] = pP[c0, b, 0] + u0 * dv
                    pP[c, b, 1] = pP[c0, b, 1] + u1 * dv
                    pP[c, b, 2] = pP[c0, b, 2] + u2 * dv


@njit(cache=True)
def _region_vs_scene(W, i, j, ts, vs, m, field, sc, rs, pad):
    """The shapes joint j moves, over the region's grid (grown by the
    second-order bound and ``pad``), against the obstacles and V."""
    ta, tb, nt = ts
    va, vb, nv = vs
    P = nt * nv
    S = m.shapes.shape[0]
    shapes, shape_body, verts = m.shapes, m.shape_body, m.verts
    moved, reach, curvature, revolute = m.moved, m.reach, m.curvature, m.revolute
    RP, pP, objs, aabbs = rs.RP, rs.pP, rs.objs, rs.aabbs
    tmp6 = sc.tmp6
    L_t = (tb - ta) / max(nt - 1, 1)
    L_v = (vb - va) / max(nv - 1, 1)
    for s in range(S):
        b = shape_body[s]
        if not moved[j, b]:
            continue
        grow = _relative_growth(W, i, j, -1, b, L_t, L_v, moved, curvature, reach, revolute)
        for c in range(P):
            pose_shape(shapes[s], RP[c, b], pP[c, b], objs[s, c])
            set_motion(objs[s, c], grow + pad, 0.0, 0.0, 1.0, 0.0, 0.0)
        obj = objs[s, :P]
        object_aabb(obj, verts, aabbs[s], tmp6)
        if _object_vs_scene(obj, aabbs[s], m, field, sc):
            return True
    return False


@njit(cache=True)
def _region_self_pairs(W, i, j, ts, vs, m, sc, rs, pad):
    """The robot's self pairs that joint j moves apart, over the region's
    grid, in the frame of the body j does not move."""
    ta, tb, nt = ts
    va, vb, nv = vs
    P = nt * nv
    S = m.shapes.shape[0]
    shapes, shape_body, verts, pairs = m.shapes, m.shape_body, m.verts, m.body_pairs
    moved, reach, curvature, revolute = m.moved, m.reach, m.curvature, m.revolute
    RP, pP, rel, rel_aabb = rs.RP, rs.pP, rs.rel, rs.rel_aabb
    ws, tmp6 = sc.ws, sc.tmp6
    L_t = (tb - ta) / max(nt - 1, 1)
    L_v = (vb - va) / max(nv - 1, 1)
    R_fm = np.empty((3, 3))
    p_fm = np.empty(3)
    dp = np.empty(3)
    relP = rel[:P]
    for p in range(pairs.shape[0]):
        a = pairs[p, 0]
        bb = pairs[p, 1]
        if moved[j, a] == moved[j, bb]:
            continue
        f = a if not moved[j, a] else bb  # the body j does not move
        mb = bb if f == a else a
        grow = _relative_growth(W, i, j, f, mb, L_t, L_v, moved, curvature, reach, revolute)
        for sm in range(S):
            if shape_body[sm] != mb:
                continue
            for c in range(P):
                # X_fm = X_Wf^-1 X_Wm at grid point c.
                Rf = RP[c, f]
                Rm = RP[c, mb]
                for r in range(3):
                    for cc in range(3):
                        R_fm[r, cc] = Rf[0, r] * Rm[0, cc] + Rf[1, r] * Rm[1, cc] + Rf[2, r] * Rm[2, cc]
                    dp[r] = pP[c, mb, r] - pP[c, f, r]
                for r in range(3):
                    p_fm[r] = Rf[0, r] * dp[0] + Rf[1, r] * dp[1] + Rf[2, r] * dp[2]
                pose_shape(shapes[sm], R_fm, p_fm, relP[c])
                set_motion(relP[c], grow + pad, 0.0, 0.0, 1.0, 0.0, 0.0)
            object_aabb(relP, verts, rel_aabb, tmp6)
            for sf in range(S):
                if shape_body[sf] != f:
                    continue
                # Body f's shape in its own frame: the local row as it is.
                row_aabb(shapes[sf], verts, tmp6)
                if _aabb_apart(rel_aabb, tmp6):
                    continue
                if _gjk(relP, verts, shapes[sf:sf + 1], verts, 64, ws):
                    return True
    return False




@njit(cache=True)
def _region_hits(W, i, j, ts, vs, m, field, sc, rs, pad):
    """May the robot collide (or come closer than ``pad``, m) anywhere in the region R = {nom(i + t) with
    joint j replaced by v : t in [ta, tb], v in [va, vb]}?

    R is the image of a rectangle under an affine map into configuration
    space. The rectangle is sampled on an nt x nv grid; each shape's
    positions over R lie in the convex hull of its poses at the grid points
    grown by a ball (a second-order bound): along a segment of length L
    where |d^2 p / ds^2| <= A, a point stays within A L^2 / 8 of the chord,
    and the chord lies in the hull of its ends. For the nominal's direction
    dq' (dq without joint j), A = sum_kl |dq'_k| |dq'_l| curvature[k, l, b];
    for joint j's direction, A = the shape's distance from j's axis <= reach
    (revolute) or 0 (prismatic).

    Shapes that joint j moves are tested in the world against the obstacles
    and V. A self-collision pair that joint j moves apart is tested in the
    frame of its body that j does not move, where only the joints between
    the two bodies move anything: a common motion would smear both hulls
    over each other. Everything else keeps its pose relative to the nominal,
    which is free.

    ``ts`` = (ta, tb, nt), ``vs`` = (va, vb, nv); ``m`` a :class:`Model`,
    ``field`` a :class:`HeightField`, ``sc`` and ``rs`` the thread's
    :class:`Scratch` and :class:`RegionScratch`.
    """
    _region_poses(W, i, j, ts, vs, m, rs, sc.ws[8:11])  # ws rows 8-10 as a 3x3 (free outside GJK)
    if _region_vs_scene(W, i, j, ts, vs, m, field, sc, rs, pad):
        return True
    return _region_self_pairs(W, i, j, ts, vs, m, sc, rs, pad)


@njit(cache=True)
def _search(i, j, sgn, guess, W, lims, grid, m, field, sc, rs, pad):
    """The bound v of joint j over stretch i (upper for sgn +1, lower for
    -1): for every t in [0, 1], moving joint j alone from nom(i + t) to v is
    free. An adaptive search from the stretch's nominal range outwards:
    test [F, F + w]; free -> certified, advance and double w; possible
    collision -> halve w; stop once a possibly colliding interval is
    narrower than delta[j]. Each test samples nt poses along t and one pose
    per ``v_step`` along v (at most MAX_V_SAMPLES). ``guess`` is an
    absolute bound to start from (the previous stretch's; NaN: cold).
    ``lims`` = (lim_lo, lim_hi, delta), ``grid`` = (nt, v_step).

    Returns:
        (bound, tests)
    """
    lim_lo, lim_hi, delta = lims
    nt, v_step = grid
    bound = lim_hi[i, j] if sgn > 0 else lim_lo[i, j]
    dj = delta[j]
    if sgn > 0:
        v0 = min(W[i, j], W[i + 1, j])
        T = bound - v0
    else:
        v0 = max(W[i, j], W[i + 1, j])
        T = v0 - bound
    if T <= 0:
        return v0, 0
    count = 0
    F = 0.0
    start = T
    if not np.isnan(guess):
        start = sgn * (guess - v0) - dj  # just short of the neighbour's bound
    if start >= dj and start < T:
        w = start
        w_next = 2.0 * dj
    else:
        w = T
        w_next = -1.0
    while True:
        X = min(F + w, T)
        if sgn > 0:
            va = v0 + F
            vb = v0 + X
        else:
            va = v0 - X
            vb = v0 - F
        nv = 2 + int((X - F) / v_step)
        if nv > MAX_V_SAMPLES:
            nv = MAX_V_SAMPLES
        count += 1
        hit = _region_hits(W, i, j, (0.0, 1.0, nt), (va, vb, nv), m, field, sc, rs, pad)
        if not hit:
            F = X
            if F >= T:
                break
            if w_next > 0:
                w = w_next
                w_next = -1.0
            else:
                w = 2.0 * w
        else:
            width = X - F
            w_next = -1.0
            if width < dj:
                break
            w = 0.5 * width
    return v0 + sgn * F, count


@njit(cache=True)
def _region_workspace(B, S, k):
    """Scratch arrays of one thread's region tests (:func:`_region_hits`)
    for B bodies, S shapes and k joints."""
    P = MAX_T_SAMPLES * MAX_V_SAMPLES
    return RegionScratch(np.empty((P, B, 3, 3)), np.empty((P, B, 3)), np.empty((S, P, SHAPE_W)), np.empty((S, 6)),
                         np.empty((P, SHAPE_W)), np.empty(6), np.empty(k))


@njit(cache=True, parallel=True)
def sweep_chains(chains, lims, nts, v_steps, W, m, field, pads):
    """Certified single-joint bounds of every stretch (:func:`_search`),
    keeping stretch i at least ``pads[i]`` (m) from the scene and itself.
    Chain n = (j, sign) walks the stretches in order, each search starting
    from the previous stretch's bound; the chains run in parallel.
    ``lims`` = (lim_lo (g-1, k), lim_hi, delta (k,)); ``m`` a
    :class:`Model`; ``field`` a :class:`HeightField`.

    Returns:
        (bounds (n, g-1), tests (n,))
    """
    n_chains = chains.shape[0]
    n_st = W.shape[0] - 1
    out = np.zeros((n_chains, n_st))
    tests = np.zeros(n_chains, np.int64)
    B = m.chain.parent.shape[0]
    S = m.shapes.shape[0]
    k = W.shape[1]
    # numba passes no tuples of arrays into a parallel loop: the model's
    # arrays go in one by one, the model is rebuilt inside.
    parent, jtype, qidx, axis, R_PF, p_PF, R_MB, p_MB = m.chain
    (shapes_, shape_body_, verts_, obstacles_, obstacle_aabb_, body_pairs_, shape_pairs_, movable_, moved_, reach_,
     curvature_, revolute_, joint_body_) = m[1:]
    lim_lo, lim_hi, delta = lims
    table, ox, oy, side = field
    for n in prange(n_chains):
        mm = Model(Chain(parent, jtype, qidx, axis, R_PF, p_PF, R_MB, p_MB), shapes_, shape_body_, verts_, obstacles_,
                   obstacle_aabb_, body_pairs_, shape_pairs_, movable_, moved_, reach_, curvature_, revolute_,
                   joint_body_)
        fld = HeightField(table, ox, oy, side)
        lm = (lim_lo, lim_hi, delta)
        j = chains[n, 0]
        sgn = chains[n, 1]
        sc = new_scratch()
        rs = _region_workspace(B, S, k)
        guess = np.nan
        count = 0
        for i in range(n_st):
            bound, c = _search(i, j, sgn, guess, W, lm, (nts[i, j], v_steps[j]), mm, fld, sc, rs, pads[i])
            out[n, i] = bound
            count += c
            guess = bound
        tests[n] = count
    return out, tests


@njit(cache=True, parallel=True)
def regions_hit(A, B, js, va, vb, nts, nvs, pads, m):
    """Region tests of many straight pieces (the certificate's box edges).

    Task n is the region {c(t) with joint js[n] replaced by v : t in [0, 1],
    v in [va[n], vb[n]]}, where c(t) = A[n] + t (B[n] - A[n]), tested as in
    :func:`_region_hits` (nts[n] x nvs[n] grid poses, second-order growth)
    against the obstacles and the robot itself, kept ``pads[n]`` (m) away;
    no volume V. As there, only what joint js[n] moves relative to the rest
    is tested: the rest is the pose at c(t), proven by the other joints'
    tasks.

    Returns:
        (n,) True where the region may collide (False: proven free).
    """
    n_tasks = A.shape[0]
    out = np.zeros(n_tasks, np.bool_)
    B_n = m.chain.parent.shape[0]
    S = m.shapes.shape[0]
    k = A.shape[1]
    n_chunks = (n_tasks + 63) // 64
    # numba passes no tuples of arrays into a parallel loop: the model's
    # arrays go in one by one, the model is rebuilt inside.
    parent, jtype, qidx, axis, R_PF, p_PF, R_MB, p_MB = m.chain
    (shapes_, shape_body_, verts_, obstacles_, obstacle_aabb_, body_pairs_, shape_pairs_, movable_, moved_, reach_,
     curvature_, revolute_, joint_body_) = m[1:]
    for c in prange(n_chunks):
        mm = Model(Chain(parent, jtype, qidx, axis, R_PF, p_PF, R_MB, p_MB), shapes_, shape_body_, verts_, obstacles_,
                   obstacle_aabb_, body_pairs_, shape_pairs_, movable_, moved_, reach_, curvature_, revolute_,
                   joint_body_)
        no_field = no_height_field()
        sc = new_scratch()
        rs = _region_workspace(B_n, S, k)
        W = np.empty((2, k))
        for n in range(c * 64, min(n_tasks, (c + 1) * 64)):
            W[0] = A[n]
            W[1] = B[n]
            out[n] = _region_hits(W, 0, js[n], (0.0, 1.0, min(nts[n], MAX_T_SAMPLES)),
                                  (va[n], vb[n], min(nvs[n], MAX_V_SAMPLES)), mm, no_field, sc, rs, pads[n])
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


# -- footprints and distance maps for the height function -------------------------

#: Directions sampled around a shape for its xy footprint polygon.
FOOTPRINT_DIRECTIONS = 8


@njit(cache=True)
def shape_footprint(row, verts, out):
    """The xy footprint of a shape as a convex polygon: its support points
    along FOOTPRINT_DIRECTIONS horizontal directions, in order (exact at
    the vertices it reaches; never outside the true footprint). out: (n, 2)."""
    tmp = np.empty(3)
    n = out.shape[0]
    for a in range(n):
        ang = 2.0 * np.pi * a / n
        support(row, verts, np.cos(ang), np.sin(ang), 0.0, tmp)
        out[a, 0] = tmp[0]
        out[a, 1] = tmp[1]


@njit(cache=True)
def fill_convex_polygon(mask, poly, x0, y0, pixel):
    """Marks the pixels of ``mask`` (indexed [ix, iy], pixel centres at
    x0 + (ix + 0.5) pixel) whose centre lies in the convex polygon (vertices
    in order, either orientation), plus the pixel under each vertex, so a
    thin shape is never lost. Scan lines along y."""
    nx, ny = mask.shape
    n = poly.shape[0]
    ymin = poly[0, 1]
    ymax = poly[0, 1]
    for a in range(n):
        ix = int(np.floor((poly[a, 0] - x0) / pixel))
        iy = int(np.floor((poly[a, 1] - y0) / pixel))
        if 0 <= ix < nx and 0 <= iy < ny:
            mask[ix, iy] = True
        ymin = min(ymin, poly[a, 1])
        ymax = max(ymax, poly[a, 1])
    iy0 = max(int(np.ceil((ymin - y0) / pixel - 0.5)), 0)
    iy1 = min(int(np.floor((ymax - y0) / pixel - 0.5)), ny - 1)
    for iy in range(iy0, iy1 + 1):
        y = y0 + (iy + 0.5) * pixel
        xl = np.inf
        xr = -np.inf
        for a in range(n):
            b = (a + 1) % n
            ya = poly[a, 1]
            yb = poly[b, 1]
            if (ya <= y <= yb) or (yb <= y <= ya):
                if ya == yb:
                    xa = min(poly[a, 0], poly[b, 0])
                    xb = max(poly[a, 0], poly[b, 0])
                else:
                    xa = poly[a, 0] + (y - ya) * (poly[b, 0] - poly[a, 0]) / (yb - ya)
                    xb = xa
                xl = min(xl, xa)
                xr = max(xr, xb)
        if xl > xr:
            continue
        ix0 = max(int(np.ceil((xl - x0) / pixel - 0.5)), 0)
        ix1 = min(int(np.floor((xr - x0) / pixel - 0.5)), nx - 1)
        for ix in range(ix0, ix1 + 1):
            mask[ix, iy] = True


@njit(cache=True)
def robot_footprint(Q, m, mask, x0, y0, pixel):
    """Marks the robot's xy footprint at every configuration of Q (bodies
    that never move: once) in ``mask``. ``m``: a :class:`Model`."""
    shapes, shape_body, verts, movable = m.shapes, m.shape_body, m.verts, m.movable
    B = m.chain.parent.shape[0]
    S = shapes.shape[0]
    R_WB = np.empty((B, 3, 3))
    p_WB = np.empty((B, 3))
    row = np.empty(SHAPE_W)
    poly = np.empty((FOOTPRINT_DIRECTIONS, 2))
    for n in range(Q.shape[0]):
        fk_into(Q[n], m.chain, R_WB, p_WB)
        for s in range(S):
            b = shape_body[s]
            if n > 0 and not movable[b]:
                continue
            pose_shape(shapes[s], R_WB[b], p_WB[b], row)
            shape_footprint(row, verts, poly)
            fill_convex_polygon(mask, poly, x0, y0, pixel)


@njit(cache=True)
def _edt_1d(f, n, d, v, z):
    """Squared distance transform of a sampled function (Felzenszwalb and
    Huttenlocher): d[q] = min_p (q - p)^2 + f[p]."""
    k = 0
    v[0] = 0
    z[0] = -np.inf
    z[1] = np.inf
    for q in range(1, n):
        if f[q] == np.inf:
            continue
        if f[v[k]] == np.inf:
            v[k] = q
            continue
        s = ((f[q] + q * q) - (f[v[k]] + v[k] * v[k])) / (2.0 * q - 2.0 * v[k])
        while s <= z[k]:
            k -= 1
            s = ((f[q] + q * q) - (f[v[k]] + v[k] * v[k])) / (2.0 * q - 2.0 * v[k])
        k += 1
        v[k] = q
        z[k] = s
        z[k + 1] = np.inf
    if f[v[0]] == np.inf:
        for q in range(n):
            d[q] = np.inf
        return
    k = 0
    for q in range(n):
        while z[k + 1] < q:
            k += 1
        d[q] = (q - v[k]) * (q - v[k]) + f[v[k]]


@njit(cache=True)
def distance_map(mask):
    """Exact Euclidean distance (in pixels) from each pixel centre to the
    nearest marked pixel centre; inf where nothing is marked."""
    nx, ny = mask.shape
    m = max(nx, ny)
    g = np.empty((nx, ny))
    f = np.empty(m)
    d = np.empty(m)
    v = np.empty(m, np.int64)
    z = np.empty(m + 1)
    for ix in range(nx):
        for iy in range(ny):
            f[iy] = 0.0 if mask[ix, iy] else np.inf
        _edt_1d(f, ny, d, v, z)
        for iy in range(ny):
            g[ix, iy] = d[iy]
    out = np.empty((nx, ny))
    for iy in range(ny):
        for ix in range(nx):
            f[ix] = g[ix, iy]
        _edt_1d(f, nx, d, v, z)
        for ix in range(nx):
            out[ix, iy] = np.sqrt(d[ix])
    return out


def warm_up() -> float:
    """Compiles (or loads from numba's cache) every kernel by running it
    once on a tiny made-up scene: a one-joint arm with one box link, one
    obstacle and a 2 x 2 height field. Returns the seconds it took; the
    paper's timing never includes this."""
    import time

    t0 = time.perf_counter()
    eye = np.eye(3)
    parent = np.array([-1], np.int64)
    jtype = np.array([1], np.int64)
    qidx = np.array([0], np.int64)
    axis = np.array([[0.0, 0.0, 1.0]])
    R_PF = eye[None].copy()
    p_PF = np.array([[0.0, 0.0, 0.5]])
    R_MB = eye[None].copy()
    p_MB = np.zeros((1, 3))
    chain = Chain(parent, jtype, qidx, axis, R_PF, p_PF, R_MB, p_MB)
    shapes = np.zeros((1, SHAPE_W))
    shapes[0, _K] = BOX
    shapes[0, _C:_C + 3] = (0.5, 0.0, 0.0)
    shapes[0, _R:_R + 9] = eye.ravel()
    shapes[0, _S:_S + 3] = (0.5, 0.05, 0.05)
    verts = np.zeros((0, 3))
    obstacles = shapes.copy()
    obstacles[0, _C:_C + 3] = (0.0, 1.5, 0.5)
    obs_aabb = np.empty((1, 6))
    row_aabb(obstacles[0], verts, obs_aabb[0])
    no_pairs = np.zeros((0, 2), np.int64)
    m = Model(chain, shapes, np.array([0], np.int64), verts, obstacles, obs_aabb, no_pairs, no_pairs,
              np.array([True]), np.array([[True]]), np.array([[1.01]]), np.array([[[1.01]]]), np.array([True]),
              np.array([0], np.int64))
    W = np.array([[0.0], [0.1]])
    Q = np.ascontiguousarray(W)
    fk(Q, chain)
    configs_may_collide(Q, m, 0.0)
    configs_may_collide_serial(Q, m, 0.0)
    heights = np.array([[0.0, 0.3], [0.2, 0.0]])
    field = HeightField(range_max_table(heights), -1.0, -1.0, 1.0)
    sweep_chains(np.array([[0, 1], [0, -1]], np.int64), (np.array([[-3.0]]), np.array([[3.0]]), np.array([0.01])),
                 np.array([[2]], np.int64), np.array([0.2]), W, m, field, np.zeros(1))
    regions_hit(W[:1].copy(), W[1:].copy(), np.array([0], np.int64), np.array([-0.1]), np.array([0.1]),
                np.array([2], np.int64), np.array([2], np.int64), np.array([0.01]), m)
    lower_columns_under(Q, np.zeros((2, 1)), m, heights.copy(), (-1.0, -1.0, 1.0), 0.0)
    obstacle_distances(Q, 0.5, 1e-3, m)
    mask = np.zeros((8, 8), np.bool_)
    robot_footprint(Q, m, mask, -2.0, -2.0, 0.5)
    poly = np.empty((FOOTPRINT_DIRECTIONS, 2))
    shape_footprint(obstacles[0], verts, poly)
    fill_convex_polygon(mask, poly, -2.0, -2.0, 0.5)
    distance_map(mask)
    gjk_intersect(shapes, verts, obstacles, verts)
    row_aabb(obstacles[0], verts, np.empty(6))
    return time.perf_counter() - t0
