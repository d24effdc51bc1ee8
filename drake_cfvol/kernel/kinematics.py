"""Forward kinematics of the robot's chain (tested against Drake's poses to
1e-12).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from drake_cfvol.kernel.types import Chain

__all__ = ['fk']


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
