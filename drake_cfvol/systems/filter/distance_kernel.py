"""Signed distances of the damper's convex pairs in compiled code (numba),
for the pairs Drake's query would otherwise measure one call at a time:
two spheres or capsules in closed form, others by GJK on the two shapes'
exact support functions (a box, sphere, capsule, cylinder or a mesh's
convex hull), and what it reports made conservative.
The distance reported is the supporting planes' bound along GJK's last
direction, a lower bound of the true distance whatever GJK's accuracy
(:func:`gjk_pairs`); GJK's own closest points bound it from above, and
the two meet within :data:`GJK_TOLERANCE`. Shapes that touch or overlap
are left to Drake.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from drake_cfvol.kernel.kinds import box as _box
from drake_cfvol.kernel.kinds import capsule as _capsule
from drake_cfvol.kernel.kinds import cylinder as _cylinder
from drake_cfvol.kernel.kinds import hull as _hull
from drake_cfvol.kernel.kinds import sphere as _sphere
from drake_cfvol.kernel.types import BOX, CAPSULE, CYLINDER, HULL, SPHERE
from drake_cfvol.systems.filter.damper_kernel import _geometry_pose, pair_rows

__all__ = ["GJK_KINDS", "GJK_TOLERANCE", "convex_rows", "gjk_pairs"]

#: The kinds :func:`gjk_pairs` measures (their support functions are exact).
GJK_KINDS = (BOX, SPHERE, CAPSULE, CYLINDER, HULL)

#: GJK stops once its closest points (an upper bound of the distance) lie
#: within this of its supporting planes' bound (a lower bound), m. Tight:
#: the filter compares distances from update to update (a pair inside the
#: margin's band may come no nearer), and 10 um made those comparisons
#: noisy (the runs drifted from Drake's: the mesh robot's pushes passed
#: less, one 0.559 of its share where Drake's passed 0.610). GJK converges
#: in a few iterations from the last normal.
GJK_TOLERANCE = 1e-8

#: Shapes nearer than this are left to Drake (GJK's simplex degenerates
#: as the distance vanishes; Drake measures penetration), m.
GJK_CONTACT = 1e-6

#: Most GJK iterations per pair (a pair that needs more is left to Drake).
GJK_ITERATIONS = 64


@njit(cache=True, inline="always")
def _local_support(kind, prm, centre, verts, nv, l0, l1, l2):
    """The support point along l of a shape (its kind, sizes, centre in
    the geometry frame, hull vertices about the centre), geometry frame."""
    if kind == BOX:
        x, y, z = _box.support(prm[0], prm[1], prm[2], l0, l1, l2)
    elif kind == SPHERE:
        x, y, z = _sphere.support(prm[0], prm[1], prm[2], l0, l1, l2)
    elif kind == CAPSULE:
        x, y, z = _capsule.support(prm[0], prm[1], prm[2], l0, l1, l2)
    elif kind == CYLINDER:
        x, y, z = _cylinder.support(prm[0], prm[1], prm[2], l0, l1, l2)
    else:
        x, y, z = _hull.support(verts, 0, nv, l0, l1, l2)
    return x + centre[0], y + centre[1], z + centre[2]


@njit(cache=True, inline="always")
def _support(XR, Xt, kind, prm, centre, verts, nv, d, out):
    """The world support point along d (world) of a shape posed at XR, Xt, into out."""
    l0 = XR[0, 0] * d[0] + XR[1, 0] * d[1] + XR[2, 0] * d[2]
    l1 = XR[0, 1] * d[0] + XR[1, 1] * d[1] + XR[2, 1] * d[2]
    l2 = XR[0, 2] * d[0] + XR[1, 2] * d[1] + XR[2, 2] * d[2]
    x, y, z = _local_support(kind, prm, centre, verts, nv, l0, l1, l2)
    for r in range(3):
        out[r] = XR[r, 0] * x + XR[r, 1] * y + XR[r, 2] * z + Xt[r]


@njit(cache=True, inline="always")
def _dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@njit(cache=True, inline="always")
def _sub(W, i, j, out):
    """out = W[i] - W[j]."""
    out[0], out[1], out[2] = W[i, 0] - W[j, 0], W[i, 1] - W[j, 1], W[i, 2] - W[j, 2]


@njit(cache=True)
def _closest_triangle(W, i, j, m, keep, lam, t1, t2):
    """The point of triangle W[i], W[j], W[m] nearest the origin (Ericson,
    Real-Time Collision Detection, 5.1.5): the indices it keeps into keep,
    their barycentric weights into lam; returns how many (1-3). t1, t2:
    scratch (3,)."""
    _sub(W, j, i, t1)  # ab
    _sub(W, m, i, t2)  # ac
    d1 = -(t1[0] * W[i, 0] + t1[1] * W[i, 1] + t1[2] * W[i, 2])
    d2 = -(t2[0] * W[i, 0] + t2[1] * W[i, 1] + t2[2] * W[i, 2])
    if d1 <= 0.0 and d2 <= 0.0:
        keep[0], lam[0] = i, 1.0
        return 1
    d3 = -(t1[0] * W[j, 0] + t1[1] * W[j, 1] + t1[2] * W[j, 2])
    d4 = -(t2[0] * W[j, 0] + t2[1] * W[j, 1] + t2[2] * W[j, 2])
    if d3 >= 0.0 and d4 <= d3:
        keep[0], lam[0] = j, 1.0
        return 1
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        t = d1 / (d1 - d3)
        keep[0], keep[1], lam[0], lam[1] = i, j, 1.0 - t, t
        return 2
    d5 = -(t1[0] * W[m, 0] + t1[1] * W[m, 1] + t1[2] * W[m, 2])
    d6 = -(t2[0] * W[m, 0] + t2[1] * W[m, 1] + t2[2] * W[m, 2])
    if d6 >= 0.0 and d5 <= d6:
        keep[0], lam[0] = m, 1.0
        return 1
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        t = d2 / (d2 - d6)
        keep[0], keep[1], lam[0], lam[1] = i, m, 1.0 - t, t
        return 2
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
        t = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        keep[0], keep[1], lam[0], lam[1] = j, m, 1.0 - t, t
        return 2
    den = va + vb + vc
    if not den > 0.0:  # flat: its first vertex (GJK then does not converge and leaves the pair to Drake)
        keep[0], lam[0] = i, 1.0
        return 1
    v, w = vb / den, vc / den
    keep[0], keep[1], keep[2] = i, j, m
    lam[0], lam[1], lam[2] = 1.0 - v - w, v, w
    return 3


@njit(cache=True)
def _closest(W, n, keep, lam, scratch):
    """The point of the simplex W[:n] (n <= 4 points of A - B) nearest the
    origin: the indices it keeps into keep, their barycentric weights into
    lam; returns how many (0: the origin lies inside the tetrahedron).
    scratch: (6, 3)."""
    if n == 1:
        keep[0], lam[0] = 0, 1.0
        return 1
    t1, t2 = scratch[0], scratch[1]
    if n == 2:
        _sub(W, 1, 0, t1)
        den = t1[0] * t1[0] + t1[1] * t1[1] + t1[2] * t1[2]
        t = -(W[0, 0] * t1[0] + W[0, 1] * t1[1] + W[0, 2] * t1[2]) / den if den > 0.0 else 0.0
        if t <= 0.0:
            keep[0], lam[0] = 0, 1.0
            return 1
        if t >= 1.0:
            keep[0], lam[0] = 1, 1.0
            return 1
        keep[0], keep[1], lam[0], lam[1] = 0, 1, 1.0 - t, t
        return 2
    if n == 3:
        return _closest_triangle(W, 0, 1, 2, keep, lam, t1, t2)
    # A tetrahedron: the nearest of the faces with the origin on their outer side.
    best, kept = np.inf, 0
    fk, fl = keep[4:7], lam[4:7]
    nrm, e = scratch[2], scratch[3]
    for f in range(4):
        i, j, m, o = (0, 1, 2, 3) if f == 0 else (0, 1, 3, 2) if f == 1 else (0, 2, 3, 1) if f == 2 else (1, 2, 3, 0)
        _sub(W, j, i, t1)
        _sub(W, m, i, t2)
        nrm[0] = t1[1] * t2[2] - t1[2] * t2[1]
        nrm[1] = t1[2] * t2[0] - t1[0] * t2[2]
        nrm[2] = t1[0] * t2[1] - t1[1] * t2[0]
        _sub(W, o, i, e)
        sa = -(nrm[0] * W[i, 0] + nrm[1] * W[i, 1] + nrm[2] * W[i, 2])
        sd = nrm[0] * e[0] + nrm[1] * e[1] + nrm[2] * e[2]
        if sa * sd >= 0.0:  # the origin on the fourth vertex's side (or on the plane)
            continue
        c = _closest_triangle(W, i, j, m, fk, fl, t1, t2)
        x = y = z = 0.0
        for r in range(c):
            x += fl[r] * W[fk[r], 0]
            y += fl[r] * W[fk[r], 1]
            z += fl[r] * W[fk[r], 2]
        dist = x * x + y * y + z * z
        if dist < best:
            best, kept = dist, c
            for r in range(c):
                keep[r], lam[r] = fk[r], fl[r]
    return kept


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


@njit(cache=True, inline="always")
def _segment(X, t, kind, prm, end, axis):
    """A sphere's or capsule's segment posed at X, t: its first end and
    its axis (zero for a sphere) into end, axis."""
    h = prm[1] if kind == CAPSULE else 0.0  # the segment's half length along z
    for r in range(3):
        end[r] = t[r] - h * X[r, 2]
        axis[r] = 2.0 * h * X[r, 2]


@njit(cache=True)
def _round_pair(XA, tA, XB, tB, shape_a, shape_b, out, ends, axes, closest):
    """:func:`_gjk` for two spheres or capsules, in closed form: their
    segments' distance less their radii (exact; Drake's GJK reports up to
    0.2 mm more). False where the segments meet (no normal). ``ends``,
    ``axes``, ``closest``: scratch (2, 3)."""
    _segment(XA, tA, shape_a[0], shape_a[1], ends[0], axes[0])
    _segment(XB, tB, shape_b[0], shape_b[1], ends[1], axes[1])
    _segment_closest(ends[0], axes[0], ends[1], axes[1], closest[0], closest[1])
    g0, g1, g2 = closest[0, 0] - closest[1, 0], closest[0, 1] - closest[1, 1], closest[0, 2] - closest[1, 2]
    apart = np.sqrt(g0 * g0 + g1 * g1 + g2 * g2)
    if apart <= GJK_CONTACT:
        return False
    n = (g0 / apart, g1 / apart, g2 / apart)
    ra, rb = shape_a[1][0], shape_b[1][0]
    out[0] = out[1] = apart - ra - rb
    for r in range(3):
        out[2 + r] = n[r]
        out[5 + r] = closest[0, r] - ra * n[r]  # on A's surface
        out[8 + r] = closest[1, r] + rb * n[r]  # on B's surface
    return True


@njit(cache=True)
def _workspace():
    """GJK's scratch, made once per :func:`gjk_pairs` call: 40 rows of 3,
    barycentric weights and kept indices (7 each: a simplex's 4, a face's 3)."""
    return np.empty((40, 3)), np.empty(7), np.empty(7, np.int64)


@njit(cache=True)
def _gjk(XA, tA, XB, tB, shape_a, shape_b, d0, out, work):
    """GJK between shapes A and B (each (kind, sizes, centre, hull
    vertices, count) posed at X, t), from direction d0 (A - B; any if
    zero). Writes out = [lower bound, upper bound, n (3, from B to A),
    p_A (3), p_B (3)] (world): the supporting planes' bound along n and
    points of A and B on those planes near GJK's closest points. Returns
    False where the shapes touch or overlap (or GJK did not converge).
    ``work``: scratch from :func:`_workspace`."""
    kA, prmA, cA, vA, nA = shape_a
    kB, prmB, cB, vB, nB = shape_b
    rows, lam, keep = work
    W, PA, PB, TW, TA, TB = rows[0:4], rows[4:8], rows[8:12], rows[12:16], rows[16:20], rows[20:24]
    sa, sb, d, neg, v, w = rows[24], rows[25], rows[26], rows[27], rows[28], rows[29]
    best_a, best_b, ca, cb = rows[30], rows[31], rows[32], rows[33]
    scratch = rows[34:40]
    for r in range(3):
        v[r] = d0[r]
    if _dot(v, v) == 0.0:
        for r in range(3):
            v[r] = tA[r] - tB[r]
        if _dot(v, v) == 0.0:
            v[0] = 1.0
    n = 0
    lower = -np.inf
    for _ in range(GJK_ITERATIONS):
        for r in range(3):
            neg[r] = -v[r]
        _support(XA, tA, kA, prmA, cA, vA, nA, neg, sa)
        _support(XB, tB, kB, prmB, cB, vB, nB, v, sb)
        vv = np.sqrt(_dot(v, v))
        if vv < GJK_CONTACT:
            return False
        for r in range(3):
            w[r] = sa[r] - sb[r]
        bound = _dot(v, w) / vv  # n . (a* - b*): the planes' bound along n = v / |v|
        if bound > lower:
            lower = bound
            best_a[:] = sa
            best_b[:] = sb
            for r in range(3):
                d[r] = v[r] / vv
        if n > 0 and vv - lower <= GJK_TOLERANCE:
            break
        W[n], PA[n], PB[n] = w, sa, sb
        n += 1
        m = _closest(W, n, keep, lam, scratch)
        if m == 0:
            return False
        # Keep the points the closest point uses, in keep's order (W, PA, PB alike).
        for i in range(m):
            TW[i], TA[i], TB[i] = W[keep[i]], PA[keep[i]], PB[keep[i]]
        n = m
        v[:] = 0.0
        for i in range(n):
            W[i], PA[i], PB[i] = TW[i], TA[i], TB[i]
            for r in range(3):
                v[r] += lam[i] * W[i, r]
    else:
        return False
    if not lower > GJK_CONTACT:
        return False
    upper = np.sqrt(_dot(v, v))
    if upper - lower > 10.0 * GJK_TOLERANCE:
        return False
    ca[:], cb[:] = 0.0, 0.0
    for i in range(n):
        for r in range(3):
            ca[r] += lam[i] * PA[i, r]
            cb[r] += lam[i] * PB[i, r]
    # Onto the supporting planes along d: n . (p_A - p_B) is the lower bound.
    ha, hb = _dot(d, best_a), _dot(d, best_b)
    ea, eb = _dot(d, ca) - ha, _dot(d, cb) - hb
    out[0], out[1] = lower, upper
    for r in range(3):
        out[2 + r] = d[r]
        out[5 + r] = ca[r] - ea * d[r]
        out[8 + r] = cb[r] - eb * d[r]
    return True


@njit(cache=True, inline="always")
def _round(kind):
    """Whether a kind is a sphere or a capsule (a segment grown by a radius)."""
    return kind == SPHERE or kind == CAPSULE


@njit(cache=True)
def _scratch():
    """The per-call scratch of :func:`_measure`: GJK's (:func:`_workspace`),
    two poses, a result and three (2, 3) rows for :func:`_round_pair`."""
    return _workspace(), np.zeros((2, 3, 3)), np.zeros((2, 3)), np.empty(11), np.zeros((3, 2, 3))


@njit(cache=True)
def _measure(p, sides, shapes, pose_R, pose_t, R, o, hint, scratch, normal, witness):
    """Pair p's signed distance, measured here (:func:`gjk_pairs`), or NaN
    where it is left to Drake; its nhat_BA_W and witnesses in the geometry
    frames into normal (3,) and witness (2, 3); its hint updated."""
    kind, prm, centre, verts, nverts = shapes
    work, XR, Xt, out, seg = scratch
    for s in range(2):
        _geometry_pose(p, s, sides, pose_R, pose_t, R, o, XR[s], Xt[s])
    shape_a = (kind[p, 0], prm[p, 0], centre[p, 0], verts[p, 0], nverts[p, 0])
    shape_b = (kind[p, 1], prm[p, 1], centre[p, 1], verts[p, 1], nverts[p, 1])
    if _round(kind[p, 0]) and _round(kind[p, 1]):
        ok = _round_pair(XR[0], Xt[0], XR[1], Xt[1], shape_a, shape_b, out, seg[0], seg[1], seg[2])
    else:
        ok = _gjk(XR[0], Xt[0], XR[1], Xt[1], shape_a, shape_b, hint[p], out, work)
    if not ok:
        hint[p, :] = 0.0
        return np.nan
    for r in range(3):
        hint[p, r] = out[2 + r]
        normal[r] = out[2 + r]
    for s in range(2):
        for r in range(3):  # into the geometry frame: R^T (point - t)
            x = out[5 + 3 * s] - Xt[s, 0]
            y = out[6 + 3 * s] - Xt[s, 1]
            z = out[7 + 3 * s] - Xt[s, 2]
            witness[s, r] = XR[s, 0, r] * x + XR[s, 1, r] * y + XR[s, 2, r] * z
    return out[0]


@njit(cache=True)
def gjk_pairs(look, usable, sides, shapes, pose_R, pose_t, R, o, hint):
    """Splits the pairs to measure, ``look`` (N,), into those of two
    convex shapes measured here (``usable`` (P,): two spheres or capsules
    in closed form, :func:`_round_pair`, others by GJK; their shapes
    ``shapes``: kind (P, 2), sizes (P, 2, 3), centre (P, 2, 3), hull
    vertices (P, 2, V, 3) and their counts (P, 2)), apart by more than
    :data:`GJK_CONTACT`, and the others. ``sides``: (slot, X_BG rotation,
    translation) per pair side (:func:`~.damper_kernel._geometry_pose`).
    ``hint`` (P, 3): each pair's last normal, GJK's first direction (zero:
    none), updated in place.

    Returns:
        (pairs, distances, normal, witness, left): the measured pairs with
        what Drake's query reports, made conservative: the supporting
        planes' lower bound of the distance; nhat_BA_W; p_ACa, p_BCb on
        those planes, in the geometry frames. The pairs left for Drake.
    """
    N = len(look)
    done, dist, left = np.empty(N, np.int64), np.empty(N), np.empty(N, np.int64)
    normal, witness = np.empty((N, 3)), np.empty((N, 2, 3))
    scratch = _scratch()
    nd = nl = 0
    for i in range(N):
        p = look[i]
        d = np.nan
        if usable[p]:
            d = _measure(p, sides, shapes, pose_R, pose_t, R, o, hint, scratch, normal[nd], witness[nd])
        if np.isnan(d):
            left[nl] = p
            nl += 1
            continue
        done[nd], dist[nd] = p, d
        nd += 1
    return done[:nd], dist[:nd], normal[:nd], witness[:nd], left[:nl]


@njit(cache=True)
def convex_rows(look, usable, hint, shapes, reach, dists, measured, given, sides, kin, gains, pose_R, pose_t):
    """The damper's rows of the pairs ``look`` (N,) in one call: those
    ``usable`` measured here (:func:`gjk_pairs`; their distances into
    ``dists``, ``measured`` set), and with the near pairs Drake measured,
    ``given`` (pairs, distances, nhat_BA_W, witnesses), every pair nearer
    than its ``reach`` (P,) made into rows (:func:`~.damper_kernel.pair_rows`,
    ``sides``, ``kin``, ``gains`` its).

    Returns:
        ((A, b, dirs, points, slots, rounds, pair), failed): the rows, and
        the usable pairs left for Drake (touching, or GJK did not converge).
    """
    g_pairs, g_dist, g_normal, g_witness = given
    N, G = len(look), len(g_pairs)
    pairs, dist = np.empty(N + G, np.int64), np.empty(N + G)
    normal, witness = np.empty((N + G, 3)), np.empty((N + G, 2, 3))
    pairs[:G], dist[:G], normal[:G], witness[:G] = g_pairs, g_dist, g_normal, g_witness
    failed = np.empty(N, np.int64)
    scratch = _scratch()
    at = (sides[0], sides[1], sides[2])
    m, nf = G, 0
    for i in range(N):
        p = look[i]
        if not usable[p]:
            continue
        d = _measure(p, at, shapes, pose_R, pose_t, kin[0], kin[1], hint, scratch, normal[m], witness[m])
        if np.isnan(d):
            failed[nf] = p
            nf += 1
            continue
        dists[p], measured[p] = d, True
        if d < reach[p]:
            pairs[m], dist[m] = p, d
            m += 1
    rows = pair_rows((pairs[:m], dist[:m], normal[:m], witness[:m], pose_R, pose_t), sides, kin, gains)
    return rows, failed[:nf]
