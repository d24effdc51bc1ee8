"""Forward kinematics of the robot's chain (tested against Drake's poses to
1e-12).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from drake_cfvol.kernel.types import Chain

__all__ = ["fk"]


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


@njit(cache=True)
def fk_into(q: np.ndarray, chain: Chain, R_WB: np.ndarray, p_WB: np.ndarray) -> None:
    """Body poses X_WB at q into (B, 3, 3) / (B, 3) arrays. Bodies are in
    topological order (parents first); parent -1 is the world.
    X_WB = X_WP X_PF X_FM(q) X_MB. ``chain``: a :class:`Chain`. Written out
    in scalars: no scratch arrays, no slices (1.5x the array version)."""
    parent, jtype, qidx, axis, R_PF, p_PF, R_MB, p_MB = chain
    for b in range(parent.shape[0]):
        F = R_PF[b]
        jt = jtype[b]
        # X_PM = X_PF X_FM(q): R_PM in a.., p_PM in t..
        t0 = p_PF[b, 0]
        t1 = p_PF[b, 1]
        t2 = p_PF[b, 2]
        if jt == 1:  # revolute: R_FM by Rodrigues
            th = q[qidx[b]]
            c = np.cos(th)
            s = np.sin(th)
            v = 1.0 - c
            x, y, z = axis[b, 0], axis[b, 1], axis[b, 2]
            f00, f01, f02 = v * x * x + c, v * x * y - s * z, v * x * z + s * y
            f10, f11, f12 = v * x * y + s * z, v * y * y + c, v * y * z - s * x
            f20, f21, f22 = v * x * z - s * y, v * y * z + s * x, v * z * z + c
            a00 = F[0, 0] * f00 + F[0, 1] * f10 + F[0, 2] * f20
            a01 = F[0, 0] * f01 + F[0, 1] * f11 + F[0, 2] * f21
            a02 = F[0, 0] * f02 + F[0, 1] * f12 + F[0, 2] * f22
            a10 = F[1, 0] * f00 + F[1, 1] * f10 + F[1, 2] * f20
            a11 = F[1, 0] * f01 + F[1, 1] * f11 + F[1, 2] * f21
            a12 = F[1, 0] * f02 + F[1, 1] * f12 + F[1, 2] * f22
            a20 = F[2, 0] * f00 + F[2, 1] * f10 + F[2, 2] * f20
            a21 = F[2, 0] * f01 + F[2, 1] * f11 + F[2, 2] * f21
            a22 = F[2, 0] * f02 + F[2, 1] * f12 + F[2, 2] * f22
        else:
            a00, a01, a02 = F[0, 0], F[0, 1], F[0, 2]
            a10, a11, a12 = F[1, 0], F[1, 1], F[1, 2]
            a20, a21, a22 = F[2, 0], F[2, 1], F[2, 2]
            if jt == 2:  # prismatic: p_FM = axis q
                qq = q[qidx[b]]
                d0, d1, d2 = axis[b, 0] * qq, axis[b, 1] * qq, axis[b, 2] * qq
                t0 += a00 * d0 + a01 * d1 + a02 * d2
                t1 += a10 * d0 + a11 * d1 + a12 * d2
                t2 += a20 * d0 + a21 * d1 + a22 * d2
        # X_PB = X_PM X_MB
        M = R_MB[b]
        m0, m1, m2 = p_MB[b, 0], p_MB[b, 1], p_MB[b, 2]
        b00 = a00 * M[0, 0] + a01 * M[1, 0] + a02 * M[2, 0]
        b01 = a00 * M[0, 1] + a01 * M[1, 1] + a02 * M[2, 1]
        b02 = a00 * M[0, 2] + a01 * M[1, 2] + a02 * M[2, 2]
        b10 = a10 * M[0, 0] + a11 * M[1, 0] + a12 * M[2, 0]
        b11 = a10 * M[0, 1] + a11 * M[1, 1] + a12 * M[2, 1]
        b12 = a10 * M[0, 2] + a11 * M[1, 2] + a12 * M[2, 2]
        b20 = a20 * M[0, 0] + a21 * M[1, 0] + a22 * M[2, 0]
        b21 = a20 * M[0, 1] + a21 * M[1, 1] + a22 * M[2, 1]
        b22 = a20 * M[0, 2] + a21 * M[1, 2] + a22 * M[2, 2]
        e0 = t0 + a00 * m0 + a01 * m1 + a02 * m2
        e1 = t1 + a10 * m0 + a11 * m1 + a12 * m2
        e2 = t2 + a20 * m0 + a21 * m1 + a22 * m2
        par = parent[b]
        R = R_WB[b]
        if par < 0:
            R[0, 0], R[0, 1], R[0, 2] = b00, b01, b02
            R[1, 0], R[1, 1], R[1, 2] = b10, b11, b12
            R[2, 0], R[2, 1], R[2, 2] = b20, b21, b22
            p_WB[b, 0], p_WB[b, 1], p_WB[b, 2] = e0, e1, e2
        else:  # X_WB = X_WP X_PB
            P = R_WB[par]
            for r in range(3):
                c0, c1, c2 = P[r, 0], P[r, 1], P[r, 2]
                R[r, 0] = c0 * b00 + c1 * b10 + c2 * b20
                R[r, 1] = c0 * b01 + c1 * b11 + c2 * b21
                R[r, 2] = c0 * b02 + c1 * b12 + c2 * b22
                p_WB[b, r] = p_WB[par, r] + c0 * e0 + c1 * e1 + c2 * e2


@njit(cache=True, parallel=True)
def fk(Q: np.ndarray, chain: Chain) -> tuple[np.ndarray, np.ndarray]:
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
