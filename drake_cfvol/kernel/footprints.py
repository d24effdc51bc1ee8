"""Footprints of shapes and of the robot on the floor, and exact Euclidean
distance maps, for the height function.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from drake_cfvol.kernel.kinematics import fk_into
from drake_cfvol.kernel.shapes import pose_shape, support
from drake_cfvol.kernel.types import FOOTPRINT_DIRECTIONS, SHAPE_W, Model


@njit(cache=True)
def shape_footprint(row: np.ndarray, verts: np.ndarray, out: np.ndarray) -> None:
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
def fill_convex_polygon(mask: np.ndarray, poly: np.ndarray, x0: float, y0: float, pixel: float) -> None:
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
def robot_footprint(Q: np.ndarray, m: Model, mask: np.ndarray, x0: float, y0: float, pixel: float) -> None:
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
def distance_map(mask: np.ndarray) -> np.ndarray:
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
