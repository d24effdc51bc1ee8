"""Convex shapes given by exact support functions (boxes, spheres, capsules,
cylinders, ellipsoids, convex hulls), with motion sets folded in, posed in
the world, and their axis-aligned bounding boxes.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from drake_cfvol.kernel.kinds import box as _box
from drake_cfvol.kernel.kinds import capsule as _capsule
from drake_cfvol.kernel.kinds import cylinder as _cylinder
from drake_cfvol.kernel.kinds import ellipsoid as _ellipsoid
from drake_cfvol.kernel.kinds import hull as _hull
from drake_cfvol.kernel.kinds import sphere as _sphere
from drake_cfvol.kernel.types import (
    _C,
    _ED,
    _EI,
    _ES,
    _K,
    _R,
    _S,
    _U,
    _V0,
    _V1,
    BOX,
    CAPSULE,
    CYLINDER,
    ELLIPSOID,
    HULL,
    SEP_EPS,
    SHAPE_W,
    SPHERE,
)

#: The support of a shape of a kind this kernel does not know, m: far
#: beyond any cell along every direction, so nothing is ever separated from
#: it ("may collide"), never a silent "free".
_UNKNOWN_REACH = 1e12

__all__ = ["row_aabb"]


def _pose_shape(local: np.ndarray, R_WB: np.ndarray, p_WB: np.ndarray, out: np.ndarray) -> None:
    """A shape row posed in the world: out = local with the body pose applied
    (centre and rotation); the motion fields are left as in ``local``.
    Element by element (a slice copy and nested sums cost twice as much)."""
    for f in range(SHAPE_W):
        out[f] = local[f]
    l0 = local[_C]
    l1 = local[_C + 1]
    l2 = local[_C + 2]
    for i in range(3):
        r0 = R_WB[i, 0]
        r1 = R_WB[i, 1]
        r2 = R_WB[i, 2]
        out[_C + i] = p_WB[i] + r0 * l0 + r1 * l1 + r2 * l2
        for j in range(3):
            out[_R + 3 * i + j] = r0 * local[_R + j] + r1 * local[_R + 3 + j] + r2 * local[_R + 6 + j]


pose_shape = njit(cache=True)(_pose_shape)
#: :func:`pose_shape` inlined into the batch check's loop: a call with row
#: views there costs more than the posing itself.
pose_shape_inline = njit(inline="always")(_pose_shape)


@njit(cache=True, inline="always")
def set_motion(row: np.ndarray, e_iso: float, u0: float, u1: float, u2: float, e_disc: float, e_seg: float) -> None:
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
    if kind == BOX:  # the kind modules' supports (drake_cfvol.kernel.kinds)
        x, y, z = _box.support(s0, s1, s2, l0, l1, l2)
    elif kind == SPHERE:
        x, y, z = _sphere.support(s0, s1, s2, l0, l1, l2)
    elif kind == CAPSULE:
        x, y, z = _capsule.support(s0, s1, s2, l0, l1, l2)
    elif kind == CYLINDER:
        x, y, z = _cylinder.support(s0, s1, s2, l0, l1, l2)
    elif kind == ELLIPSOID:
        x, y, z = _ellipsoid.support(s0, s1, s2, l0, l1, l2)
    elif kind == HULL and int(row[_V1]) > int(row[_V0]):
        x, y, z = _hull.support(verts, int(row[_V0]), int(row[_V1]), l0, l1, l2)
    else:  # an unknown kind (or a hull without vertices): reaches everywhere
        x = _UNKNOWN_REACH if l0 >= 0 else -_UNKNOWN_REACH
        y = _UNKNOWN_REACH if l1 >= 0 else -_UNKNOWN_REACH
        z = _UNKNOWN_REACH if l2 >= 0 else -_UNKNOWN_REACH
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
def support(row: np.ndarray, verts: np.ndarray, d0: float, d1: float, d2: float, out: np.ndarray) -> None:
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


def _row_aabb(row: np.ndarray, verts: np.ndarray, out: np.ndarray) -> None:
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
        if kind == HULL and int(row[_V1]) > int(row[_V0]):
            lo, hi = _hull.extent(verts, int(row[_V0]), int(row[_V1]), r0, r1, r2)
        else:  # a symmetric kind: half its width along the axis
            if kind == BOX:
                h = _box.extent(r0, r1, r2, s0, s1, s2)
            elif kind == SPHERE:
                h = _sphere.extent(r0, r1, r2, s0, s1, s2)
            elif kind == CAPSULE:
                h = _capsule.extent(r0, r1, r2, s0, s1, s2)
            elif kind == CYLINDER:
                h = _cylinder.extent(r0, r1, r2, s0, s1, s2)
            elif kind == ELLIPSOID:
                h = _ellipsoid.extent(r0, r1, r2, s0, s1, s2)
            else:  # unknown, or a hull without vertices: everywhere
                h = np.inf
            lo = -h
            hi = h
        ua = row[_U + a]
        m = row[_EI] + row[_ED] * np.sqrt(max(1.0 - ua * ua, 0.0)) + row[_ES] * abs(ua)
        out[a] = c + lo - m
        out[3 + a] = c + hi + m


row_aabb = njit(cache=True)(_row_aabb)
#: :func:`row_aabb` inlined into the batch check's loop (see pose_shape_inline).
row_aabb_inline = njit(inline="always")(_row_aabb)


@njit(cache=True)
def object_aabb(obj: np.ndarray, verts: np.ndarray, out: np.ndarray, tmp6: np.ndarray) -> None:
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
def _obb_half(row, out):
    """A shape row's oriented bounding box: half extents along its own axes
    (its inflation and motion terms added), into ``out``; False for a hull
    row (no box without its vertices)."""
    kind = int(row[_K])
    s0 = row[_S]
    s1 = row[_S + 1]
    s2 = row[_S + 2]
    if kind == BOX or kind == ELLIPSOID:
        out[0], out[1], out[2] = s0, s1, s2
    elif kind == SPHERE:
        out[0], out[1], out[2] = s0, s0, s0
    elif kind == CAPSULE:
        out[0], out[1], out[2] = s0, s0, s1 + s0
    elif kind == CYLINDER:
        out[0], out[1], out[2] = s0, s0, s1
    else:  # a hull, or a kind not known here: no box
        return False
    e = row[_EI] + row[_ED] + row[_ES]
    for i in range(3):
        out[i] += e
    return True


@njit(cache=True)
def obb_apart(a, b):
    """True if two shape rows are certainly apart: their oriented bounding
    boxes (inflations and motion terms included) are separated, by more
    than SEP_EPS, along one of the 15 axes of the separating-axis theorem.
    False decides nothing (near, overlapping, or a hull row). Exact for two
    boxes; conservative for the other shapes (each inside its box)."""
    return _obb_apart(a, b, np.empty((9, 3)))


def _obb_apart_py(a, b, w):
    """:func:`obb_apart` with scratch ``w`` (9, 3) (the batch loops call it
    millions of times: no allocation per call)."""
    ha = w[0]
    hb = w[1]
    if not (_obb_half(a, ha) and _obb_half(b, hb)):
        return False
    # C[i, j] = a_i . b_j, with a_i, b_j the boxes' axes (columns of R).
    C = w[3:6]
    t = w[2]  # the centres' offset in a's frame
    for i in range(3):
        acc = 0.0
        for k in range(3):
            acc += a[_R + 3 * k + i] * (b[_C + k] - a[_C + k])
        t[i] = acc
        for j in range(3):
            acc = 0.0
            for k in range(3):
                acc += a[_R + 3 * k + i] * b[_R + 3 * k + j]
            C[i, j] = acc
    A = w[6:9]  # |C|, grown a little against rounding (near-parallel edges)
    for i in range(3):
        for j in range(3):
            A[i, j] = abs(C[i, j]) + 1e-9
    for i in range(3):  # a's axes
        rb = hb[0] * A[i, 0] + hb[1] * A[i, 1] + hb[2] * A[i, 2]
        if abs(t[i]) > ha[i] + rb + SEP_EPS:
            return True
    for j in range(3):  # b's axes
        ra = ha[0] * A[0, j] + ha[1] * A[1, j] + ha[2] * A[2, j]
        if abs(t[0] * C[0, j] + t[1] * C[1, j] + t[2] * C[2, j]) > ra + hb[j] + SEP_EPS:
            return True
    for i in range(3):  # a_i x b_j
        i1 = (i + 1) % 3
        i2 = (i + 2) % 3
        for j in range(3):
            j1 = (j + 1) % 3
            j2 = (j + 2) % 3
            n2 = 1.0 - C[i, j] * C[i, j]  # |a_i x b_j|^2
            if n2 < 1e-12:
                continue  # parallel axes: covered by the face axes
            ra = ha[i1] * A[i2, j] + ha[i2] * A[i1, j]
            rb = hb[j1] * A[i, j2] + hb[j2] * A[i, j1]
            d = abs(t[i2] * C[i1, j] - t[i1] * C[i2, j])
            if d > ra + rb + SEP_EPS * np.sqrt(n2):
                return True
    return False


_obb_apart = njit(cache=True)(_obb_apart_py)
#: :func:`_obb_apart` inlined into the batch check's loops (see pose_shape_inline).
_obb_apart_inline = njit(inline="always")(_obb_apart_py)


@njit(cache=True, inline="always")
def _aabb_apart(a, b):
    return a[0] > b[3] or b[0] > a[3] or a[1] > b[4] or b[1] > a[4] or a[2] > b[5] or b[2] > a[5]
