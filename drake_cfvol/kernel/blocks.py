"""Configurations in blocks: forward kinematics and the batch collision check
on ``NB`` configurations at a time, as structure-of-arrays lanes that LLVM
turns into SIMD loops.

A block's body poses are 12 rows of ``NB`` lanes each (the rotation
row-major, then the translation), every joint's sine and cosine computed
once per configuration by a branch-free polynomial (:func:`sincos`, within
an ulp or two of libm's, and vectorised where libm's calls are not). A
revolute joint's body pose is affine in (cos q, sin q): X_PB = K0 + cos q Kc
+ sin q Ks, the three constant terms folded from the joint's frames and
axis once per robot (:func:`block_chain`).

The batch check (:func:`configs_may_collide`) runs the broad phase on
whole blocks: each shape's bounding ball, then its cover balls against the
exact shape of an obstacle (box, sphere, capsule, cylinder; any other
shape: its axis-aligned box), and for a self pair one shape's balls against
the other's exact shape, both ways. A lane that some test leaves undecided
goes to the exact test (oriented boxes, then GJK), lane by lane, for the
undecided pairs only. Balls contain their shapes, so a lane the balls
decide is free; the exact test is the same as the configuration-at-a-time
check's, so the answers are too.

Lanes are rows of flat arrays at offsets that are multiples of the
compile-time constant ``NB``: LLVM then sees one array per loop where it
would otherwise need a run-time alias check per row, and vectorises.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from drake_cfvol.kernel.kinds import KINDS
from drake_cfvol.kernel.types import Chain

__all__ = [
    "NB",
    "sincos",
    "block_chain",
    "shape_bounds",
    "EXACT_KINDS",
    "fk_blocks",
    "fk_block",
    "coherent_order",
    "COHERENT_DIMS",
    "COHERENT_BITS",
]

#: Configurations per block (lanes).
NB = 64

#: Shape kinds whose distance to a point has a closed form here (the
#: kinds' ``exact_near``; the rest are taken as their axis-aligned boxes
#: against a ball, or as their balls).
EXACT_KINDS = tuple(sorted(code for code, k in KINDS.items() if k.exact_near))

# fdlibm's kernel coefficients (|r| <= pi/4) and pi/2 in three parts.
_S1, _S2, _S3 = -1.66666666666666324348e-01, 8.33333333332248946124e-03, -1.98412698298579493134e-04
_S4, _S5, _S6 = 2.75573137070700676789e-06, -2.50507602534068634195e-08, 1.58969099521155010221e-10
_C1, _C2, _C3 = 4.16666666666666019037e-02, -1.38888888888741095749e-03, 2.48015872894767294178e-05
_C4, _C5, _C6 = -2.75573143513906633035e-07, 2.08757232129817482790e-09, -1.13596475577881948265e-11
_PIO2_1, _PIO2_2, _PIO2_3 = 1.57079632673412561417e00, 6.07710050630396597660e-11, 2.02226624871116645580e-21
_INV_PIO2 = 6.36619772367581382433e-01


@njit(cache=True, inline="always")
def sincos(x):
    """(sin x, cos x) without a library call: x reduced by multiples of
    pi/2 (three-part Cody-Waite, exact for the joint angles a robot has),
    fdlibm's polynomials on [-pi/4, pi/4], the quadrant by selects."""
    k = np.floor(x * _INV_PIO2 + 0.5)
    r = ((x - k * _PIO2_1) - k * _PIO2_2) - k * _PIO2_3
    z = r * r
    s = r + r * z * (_S1 + z * (_S2 + z * (_S3 + z * (_S4 + z * (_S5 + z * _S6)))))
    c = 1.0 - 0.5 * z + z * z * (_C1 + z * (_C2 + z * (_C3 + z * (_C4 + z * (_C5 + z * _C6)))))
    q = int(k) & 3
    ss = c if q & 1 else s
    cc = s if q & 1 else c
    if q == 1 or q == 2:
        cc = -cc
    if q >= 2:
        ss = -ss
    return ss, cc


def block_chain(chain: Chain) -> tuple[np.ndarray, np.ndarray]:
    """Each body's pose in its parent as affine in (cos q, sin q), or in q
    for a prismatic joint: KR (B, 3, 9) the rotation's constant, cosine and
    sine terms (row-major), Kp (B, 3, 3) the translation's (for a prismatic
    joint: constant, q). Rodrigues: R(u, q) = u u^T + cos q (I - u u^T) +
    sin q [u]x, so R_PB = R_PF R(u, q) R_MB splits into three constants."""
    parent, jtype, qidx, axis, R_PF, p_PF, R_MB, p_MB = chain
    B = len(parent)
    KR = np.zeros((B, 3, 9))
    Kp = np.zeros((B, 3, 3))
    for b in range(B):
        F, M, u = R_PF[b], R_MB[b], axis[b]
        if jtype[b] == 1:
            uu = np.outer(u, u)
            ux = np.array([[0.0, -u[2], u[1]], [u[2], 0.0, -u[0]], [-u[1], u[0], 0.0]])
            for t, P in enumerate((F @ uu, F @ (np.eye(3) - uu), F @ ux)):
                KR[b, t] = (P @ M).ravel()
                Kp[b, t] = P @ p_MB[b]
            Kp[b, 0] += p_PF[b]
        else:
            KR[b, 0] = (F @ M).ravel()
            Kp[b, 0] = p_PF[b] + F @ p_MB[b]
            if jtype[b] == 2:
                Kp[b, 1] = F @ u
    return KR, Kp


def shape_bounds(balls: np.ndarray, ranges: np.ndarray) -> np.ndarray:
    """(S, 4): a ball around each shape's cover balls, in its body frame
    (radius -inf for a shape without balls)."""
    out = np.zeros((len(ranges), 4))
    for s, (a, b) in enumerate(ranges):
        cover = balls[a:b]
        if len(cover) == 0:
            out[s, 3] = -np.inf
            continue
        c = 0.5 * ((cover[:, :3] - cover[:, 3:]).min(0) + (cover[:, :3] + cover[:, 3:]).max(0))
        out[s, :3] = c
        out[s, 3] = (np.linalg.norm(cover[:, :3] - c, axis=1) + cover[:, 3]).max() * (1 + 1e-12) + 1e-12
    return out


@njit(cache=True, fastmath={"contract"}, inline="always")
def _compose(XP, Xb, n, cs, sn, K, kp):
    """Xb = XP (K0 + c Kc + s Ks, k0 + c kc + s ks) on lanes [0, n)."""
    K00, K01, K02, K03, K04, K05, K06, K07, K08 = (
        K[0, 0],
        K[0, 1],
        K[0, 2],
        K[0, 3],
        K[0, 4],
        K[0, 5],
        K[0, 6],
        K[0, 7],
        K[0, 8],
    )
    C00, C01, C02, C03, C04, C05, C06, C07, C08 = (
        K[1, 0],
        K[1, 1],
        K[1, 2],
        K[1, 3],
        K[1, 4],
        K[1, 5],
        K[1, 6],
        K[1, 7],
        K[1, 8],
    )
    S00, S01, S02, S03, S04, S05, S06, S07, S08 = (
        K[2, 0],
        K[2, 1],
        K[2, 2],
        K[2, 3],
        K[2, 4],
        K[2, 5],
        K[2, 6],
        K[2, 7],
        K[2, 8],
    )
    k0x, k0y, k0z = kp[0, 0], kp[0, 1], kp[0, 2]
    kcx, kcy, kcz = kp[1, 0], kp[1, 1], kp[1, 2]
    ksx, ksy, ksz = kp[2, 0], kp[2, 1], kp[2, 2]
    for i in range(n):
        c = cs[i]
        s = sn[i]
        b00 = K00 + c * C00 + s * S00
        b01 = K01 + c * C01 + s * S01
        b02 = K02 + c * C02 + s * S02
        b10 = K03 + c * C03 + s * S03
        b11 = K04 + c * C04 + s * S04
        b12 = K05 + c * C05 + s * S05
        b20 = K06 + c * C06 + s * S06
        b21 = K07 + c * C07 + s * S07
        b22 = K08 + c * C08 + s * S08
        e0 = k0x + c * kcx + s * ksx
        e1 = k0y + c * kcy + s * ksy
        e2 = k0z + c * kcz + s * ksz
        P00, P01, P02 = XP[i], XP[NB + i], XP[2 * NB + i]
        P10, P11, P12 = XP[3 * NB + i], XP[4 * NB + i], XP[5 * NB + i]
        P20, P21, P22 = XP[6 * NB + i], XP[7 * NB + i], XP[8 * NB + i]
        t0, t1, t2 = XP[9 * NB + i], XP[10 * NB + i], XP[11 * NB + i]
        Xb[i] = P00 * b00 + P01 * b10 + P02 * b20
        Xb[NB + i] = P00 * b01 + P01 * b11 + P02 * b21
        Xb[2 * NB + i] = P00 * b02 + P01 * b12 + P02 * b22
        Xb[3 * NB + i] = P10 * b00 + P11 * b10 + P12 * b20
        Xb[4 * NB + i] = P10 * b01 + P11 * b11 + P12 * b21
        Xb[5 * NB + i] = P10 * b02 + P11 * b12 + P12 * b22
        Xb[6 * NB + i] = P20 * b00 + P21 * b10 + P22 * b20
        Xb[7 * NB + i] = P20 * b01 + P21 * b11 + P22 * b21
        Xb[8 * NB + i] = P20 * b02 + P21 * b12 + P22 * b22
        Xb[9 * NB + i] = t0 + P00 * e0 + P01 * e1 + P02 * e2
        Xb[10 * NB + i] = t1 + P10 * e0 + P11 * e1 + P12 * e2
        Xb[11 * NB + i] = t2 + P20 * e0 + P21 * e1 + P22 * e2


@njit(cache=True)
def _fk_scratch(B, k):
    """One thread's block poses (B, 12 NB), sines, cosines, joint values
    (k, NB), a row of zeros and the identity pose (12 NB)."""
    X = np.empty((B, 12 * NB))
    sn = np.empty((k, NB))
    cs = np.empty((k, NB))
    qt = np.empty((k, NB))
    zero = np.zeros(NB)
    eye = np.zeros(12 * NB)
    for e in (0, 4, 8):
        eye[e * NB : (e + 1) * NB] = 1.0
    return X, sn, cs, qt, zero, eye


@njit(cache=True, fastmath={"contract"})
def fk_block(Q, start, n, chain, KR, Kp, ws):
    """Body poses of Q[start:start + n] into ws[0] (B, 12 NB); ``ws`` from
    :func:`_fk_scratch`, KR and Kp from :func:`block_chain`."""
    X, sn, cs, qt, zero, eye = ws
    parent, jtype, qidx = chain.parent, chain.jtype, chain.qidx
    k = Q.shape[1]
    for i in range(n):
        for j in range(k):
            qt[j, i] = Q[start + i, j]
    for j in range(k):
        snj = sn[j]
        csj = cs[j]
        qj = qt[j]
        for i in range(n):
            snj[i], csj[i] = sincos(qj[i])
    for b in range(parent.shape[0]):
        jt = jtype[b]
        j = qidx[b]
        c = cs[j] if jt == 1 else (qt[j] if jt == 2 else zero)
        s = sn[j] if jt == 1 else zero
        _compose(eye if parent[b] < 0 else X[parent[b]], X[b], n, c, s, KR[b], Kp[b])


@njit(cache=True, parallel=True)
def fk_blocks(Q: np.ndarray, chain: Chain, KR: np.ndarray, Kp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Body poses for many configurations, in blocks: (N, B, 3, 3), (N, B, 3)."""
    N = Q.shape[0]
    parent, jtype, qidx, axis, R_PF, p_PF, R_MB, p_MB = chain
    B = parent.shape[0]
    R = np.empty((N, B, 3, 3))
    p = np.empty((N, B, 3))
    for blk in prange((N + NB - 1) // NB):
        ws = _fk_scratch(B, Q.shape[1])
        start = blk * NB
        n = min(NB, N - start)
        fk_block(Q, start, n, Chain(parent, jtype, qidx, axis, R_PF, p_PF, R_MB, p_MB), KR, Kp, ws)
        X = ws[0]
        for i in range(n):
            for b in range(B):
                for e in range(9):
                    R[start + i, b, e // 3, e % 3] = X[b, e * NB + i]
                for e in range(3):
                    p[start + i, b, e] = X[b, (9 + e) * NB + i]
    return R, p


#: The batch check's order (:func:`coherent_order`): the Morton code of the
#: first COHERENT_DIMS joints, COHERENT_BITS each.
COHERENT_DIMS = 4
COHERENT_BITS = 8


@njit(cache=True)
def coherent_order(Q: np.ndarray, dims: int, bits: int) -> np.ndarray:
    """(N,) an order of the configurations Q (N, k) in which neighbours are
    near: by the Morton code of their first ``dims`` joints, ``bits`` each
    over the batch's range (dims x bits <= 32), sorted stably (two 16-bit
    radix passes). A block of neighbours makes small boxes that clear most
    obstacles and self pairs at once."""
    N, k = Q.shape
    d = min(dims, k)
    lo = np.full(d, np.inf)
    hi = np.full(d, -np.inf)
    for i in range(N):
        for a in range(d):
            lo[a] = min(lo[a], Q[i, a])
            hi[a] = max(hi[a], Q[i, a])
    top = (1 << bits) - 1
    spread = np.zeros(top + 1, np.int64)  # a value's bits moved to every d-th place
    for u in range(top + 1):
        for b in range(bits):
            spread[u] |= ((u >> b) & 1) << (b * d)
    scale = np.zeros(d)
    for a in range(d):
        if hi[a] > lo[a]:
            scale[a] = top / (hi[a] - lo[a])
    key = np.empty(N, np.int64)
    for i in range(N):
        kk = 0
        for a in range(d):
            x = (Q[i, a] - lo[a]) * scale[a]
            u = 0 if not x > 0.0 else (top if x >= top else int(x))  # (NaN: 0)
            kk |= spread[u] << (d - 1 - a)
        key[i] = kk
    order = np.arange(N)
    key2 = np.empty(N, np.int64)
    order2 = np.empty(N, np.int64)
    count = np.empty(65537, np.int64)
    for shift in (0, 16):  # keys and indices move together: reads in order
        count[:] = 0
        for i in range(N):
            count[((key[i] >> shift) & 0xFFFF) + 1] += 1
        for c in range(65536):
            count[c + 1] += count[c]
        for i in range(N):
            b = (key[i] >> shift) & 0xFFFF
            key2[count[b]] = key[i]
            order2[count[b]] = order[i]
            count[b] += 1
        key, key2 = key2, key
        order, order2 = order2, order
    return order
