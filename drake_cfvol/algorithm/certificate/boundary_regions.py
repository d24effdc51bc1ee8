"""The boundary proof's regions: an edge of the box over part of a stretch
(one joint over a range, the others on a corner path) as the kernel's
region test, corners as points, and the shared constants of the proof.
"""

from __future__ import annotations

import functools
import itertools

import numpy as np

from drake_cfvol import kernel as K

__all__ = ["edge_tasks", "regions_may_collide", "corner_points"]


#: Halvings of a failing region before it is cut: along the joint, and in
#: the last S_SPLITS of them in s too.
MAX_SPLITS = 8


S_SPLITS = 3


#: Second-order growth allowed between grid poses, m (as in the sweep).
MOTION_TOLERANCE = 0.01


@functools.lru_cache(maxsize=None)
def _signs(k: int, j: int) -> np.ndarray:
    """(2^(k-1), k) corner patterns of the joints other than j (1 upper,
    0 lower; column j unused); made once per (k, j), read-only."""
    rows = np.array(list(itertools.product((0, 1), repeat=k - 1)), np.int64).reshape(-1, k - 1)
    out = np.insert(rows, j, 0, axis=1)
    out.flags.writeable = False
    return out


def edge_tasks(lo_a, hi_a, lo_b, hi_b):
    """Every edge of a stretch whose box goes linearly from [lo_a, hi_a]
    to [lo_b, hi_b]: (A, B, j, va, vb, sign rows), one row per edge, A and
    B its corner path's ends. A joint of zero width at both ends has no
    edge of its own (its edges are corners of the others')."""
    k = len(lo_a)
    A, B, js, va, vb, sig = [], [], [], [], [], []
    for j in range(k):
        if hi_a[j] <= lo_a[j] and hi_b[j] <= lo_b[j]:
            continue
        S = _signs(k, j)
        A.append(np.where(S == 1, hi_a, lo_a))
        B.append(np.where(S == 1, hi_b, lo_b))
        js.append(np.full(len(S), j))
        va.append(np.full(len(S), min(lo_a[j], lo_b[j])))
        vb.append(np.full(len(S), max(hi_a[j], hi_b[j])))
        sig.append(S)
    if not A:
        k0 = np.zeros((0, k))
        return k0, k0, np.zeros(0, np.int64), np.zeros(0), np.zeros(0), np.zeros((0, k), np.int64)
    return (
        np.concatenate(A),
        np.concatenate(B),
        np.concatenate(js).astype(np.int64),
        np.concatenate(va),
        np.concatenate(vb),
        np.concatenate(sig),
    )


def _grid(arrays, A, B, js, va, vb):
    """Grid sizes along t and v for each task (as the sweep chooses them)."""
    dq = np.abs(B - A)
    dq[np.arange(len(js)), js] = 0.0
    # dq' C dq per body, the inner sum as one matrix product (a tenth of
    # einsum's time over three operands).
    curv = arrays.curvature
    k = curv.shape[0]
    inner = (dq @ curv.reshape(k, -1)).reshape(len(dq), k, -1)
    growth = np.einsum("nl,nlb->nb", dq, inner).max(axis=1) / 8.0
    nts = np.clip(1 + np.ceil(np.sqrt(growth / MOTION_TOLERANCE)), 2, K.MAX_T_SAMPLES).astype(np.int64)
    reach_j = np.where(arrays.revolute, arrays.reach.max(axis=1), 0.0)[js]
    v_step = np.where(reach_j > 0, np.sqrt(8 * MOTION_TOLERANCE / np.maximum(reach_j, 1e-9)), np.inf)
    nvs = np.clip(2 + np.floor((vb - va) / v_step), 2, K.MAX_V_SAMPLES).astype(np.int64)
    return nts, nvs


def regions_may_collide(arrays, A, B, js, va, vb, pads) -> np.ndarray:
    """(n,) True where region n ({c(t) with joint js[n] in [va[n], vb[n]]},
    c from A[n] to B[n]) may come nearer than pads[n] (m) to the obstacles
    or the robot itself; False: proven free."""
    if not len(js):
        return np.zeros(0, bool)
    # C-ordered and writable: a read-only array (a broadcast view) is
    # another signature to numba, compiled again beside the warm-up's.
    A, B, va, vb = (np.require(x, float, ("C", "W")) for x in (A, B, va, vb))
    js = np.require(js, np.int64, ("C", "W"))
    nts, nvs = _grid(arrays, A, B, js, va, vb)
    pads = np.array(np.broadcast_to(pads, js.shape), float)
    return K.regions_hit(A, B, js, va, vb, nts, nvs, pads, arrays.model)


def _box(lower, upper, nominal, i, s):
    """(lo, hi, nom) of the linear rule on stretch i at path parameters s
    (n,); or on stretches i (m, 1) at s (m, n): (m, n, k) each."""
    t = (np.asarray(s, float) - i)[..., None]
    lo = (1 - t) * lower[i] + t * lower[i + 1]
    hi = (1 - t) * upper[i] + t * upper[i + 1]
    nom = (1 - t) * nominal[i] + t * nominal[i + 1]
    return lo, hi, nom


def corner_points(lower, upper, nominal, s):
    """Every corner of the box at each path parameter s (n,) of a linear
    table: (n * 2^k, k) configurations, the n boxes one after the other."""
    g, k = nominal.shape
    s = np.asarray(s, float)
    lo, hi, _ = _box(lower, upper, nominal, np.clip(np.floor(s).astype(int), 0, g - 2), s)
    pat = np.array(list(itertools.product((0, 1), repeat=k)), bool)
    return np.where(pat[None], hi[:, None], lo[:, None]).reshape(-1, k)


class _Item:
    """A region of an edge: s in [sa, sb] of stretch i, joint j in
    [va, vb], the other joints on the bounds of sign row S."""

    __slots__ = ("i", "sa", "sb", "j", "va", "vb", "S", "A", "B", "root", "depth")

    def __init__(self, i, sa, sb, j, va, vb, S, A, B, root=-1, depth=0):
        self.i, self.sa, self.sb, self.j, self.va, self.vb, self.S, self.A, self.B = i, sa, sb, j, va, vb, S, A, B
        self.root = (
            root  # the edge it was halved from (an index of failures' edges), or ("again", n): a remembered failed edge
        )
        self.depth = depth  # halvings from its whole edge


def _test(arrays, items, margins):
    A = np.array([it.A for it in items])
    B = np.array([it.B for it in items])
    js = np.array([it.j for it in items], np.int64)
    va = np.array([it.va for it in items])
    vb = np.array([it.vb for it in items])
    pads = np.array([margins[it.i] for it in items], float)
    return regions_may_collide(arrays, A, B, js, va, vb, pads)
