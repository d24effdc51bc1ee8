"""A boolean GJK whose "separated" answer is a certificate: a direction d
with h_A(d) + h_B(-d) < 0 from the exact supports, so a pose is never
called free where the shapes overlap.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from drake_cfvol.kernel.shapes import _cross, _dot, support_multi
from drake_cfvol.kernel.types import _C, SEP_EPS

__all__ = ["gjk_intersect"]


@njit(cache=True)
def gjk_intersect(A: np.ndarray, vA: np.ndarray, B: np.ndarray, vB: np.ndarray, max_iter: int = 64) -> bool:
    """True where objects A and B (2-D arrays of shape rows) may overlap.

    False only with a certificate: a direction d along which the support of
    A - B lies below -SEP_EPS |d|. Conservative: an undecided run (touching
    shapes, iteration cap) answers True.
    """
    ws = np.empty((18, 3))
    return _gjk(A, vA, B, vB, max_iter, ws)


@njit(cache=True)
def _gjk(A, vA, B, vB, max_iter, ws):
    """:func:`_gjk_from` without a remembered direction."""
    ws[17, 0] = 0.0
    ws[17, 1] = 0.0
    ws[17, 2] = 0.0
    return _gjk_from(A, vA, B, vB, max_iter, ws, ws[17])


@njit(cache=True)
def _gjk_from(A, vA, B, vB, max_iter, ws, d0):
    """GJK starting from d0 (3,) where it is not zero: the separating
    direction this pair had last time (consecutive tests of a search or a
    batch move the shapes little, so it mostly certifies at once). On a
    certified separation d0 gets the new direction. The certificate is
    checked from the exact supports whichever direction it starts from."""
    # Workspace rows: 0-3 simplex (oldest first), 4 d, 5 a, 6 tA, 7 tB,
    # 8-15 scratch, 16 support scratch, 17 free for callers.
    simplex = ws[0:4]
    d = ws[4]
    a = ws[5]
    tA = ws[6]
    tB = ws[7]
    tmp = ws[16]
    n = 0
    # d always points from the simplex towards the origin; the first
    # simplex point is near cA - cB, so start with d = cB - cA.
    if d0[0] * d0[0] + d0[1] * d0[1] + d0[2] * d0[2] > 1e-24:
        d[0] = d0[0]
        d[1] = d0[1]
        d[2] = d0[2]
    else:
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
            d0[0] = d[0]
            d0[1] = d[1]
            d0[2] = d[2]
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
