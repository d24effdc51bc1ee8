"""The height-field volume V: a 2-D range-maximum table, and a shape against
the columns by recursive halving of its footprint (exact at one cell).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from drake_cfvol.kernel.gjk import _gjk
from drake_cfvol.kernel.types import _C, _K, _R, _S, BOX, SHAPE_W, HeightField, Scratch

__all__ = ["range_max_table", "range_max", "object_hits_columns"]


@njit(cache=True)
def range_max_table(h: np.ndarray) -> np.ndarray:
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
def range_max(t: np.ndarray, i0: int, i1: int, j0: int, j1: int) -> float:
    """Max over cells [i0, i1] x [j0, j1] (clipped); -inf if empty."""
    i0, i1, j0, j1 = _clip_block(i0, i1, j0, j1, t.shape[2], t.shape[3])
    if i1 < i0 or j1 < j0:
        return -np.inf
    a = _log2floor(i1 - i0 + 1)
    b = _log2floor(j1 - j0 + 1)
    ia = i1 - (1 << a) + 1
    jb = j1 - (1 << b) + 1
    return max(max(t[a, b, i0, j0], t[a, b, ia, j0]), max(t[a, b, i0, jb], t[a, b, ia, jb]))


@njit(cache=True)
def new_workspace() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
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
def new_scratch() -> Scratch:
    """:func:`new_workspace` as a :class:`Scratch`."""
    ws, stack, box, tmp6 = new_workspace()
    return Scratch(ws, stack, box, tmp6)


@njit(cache=True)
def no_height_field() -> HeightField:
    """A :class:`HeightField` without columns (no volume V)."""
    return HeightField(np.zeros((1, 1, 0, 0)), 0.0, 0.0, 1.0)


@njit(cache=True)
def object_hits_columns(
    obj: np.ndarray,
    verts: np.ndarray,
    aabb: np.ndarray,
    table: np.ndarray,
    ox: float,
    oy: float,
    side: float,
    ws: np.ndarray,
    stack: np.ndarray,
    box: np.ndarray,
) -> bool:
    """True where the object (its axis-aligned box ``aabb``) may touch a
    column of V. The footprint's cell block is halved until each half is
    free (its tallest column below the object, or a GJK certificate against
    the block's bounding box) or a single cell, tested exactly against its
    column."""
    zmin = aabb[2]
    i0, i1, j0, j1 = _clip_block(
        int(np.floor((aabb[0] - ox) / side)),
        int(np.floor((aabb[3] - ox) / side)),
        int(np.floor((aabb[1] - oy) / side)),
        int(np.floor((aabb[4] - oy) / side)),
        table.shape[2],
        table.shape[3],
    )
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
