"""A dense QP solver for the safety filter's small problems: Goldfarb and
Idnani's dual active-set method (the method of quadprog and eiquadprog)
for a diagonal Hessian, compiled with numba, warm-started from the last
solve's active set (:func:`solve_qp`).

    minimise   1/2 x^T diag(h) x + g^T x
    subject to C x >= c        (row by row)

The dual method starts from the unconstrained minimum and adds violated
constraints one at a time, keeping the dual feasible; when a violated
constraint cannot be added (no primal direction and no dual step that
keeps the multipliers >= 0) the constraints are inconsistent, which is
the solver's infeasibility verdict (exact, not a tolerance on a
residual). A warm start tries the constraints that were active at the
last solve first: the same problem's answer, fewer iterations.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["solve_qp", "QP_OPTIMAL", "QP_INFEASIBLE", "QP_FAILED"]

#: :func:`solve_qp`'s status: solved; constraints inconsistent; the
#: iteration cap or a linear dependence it could not resolve.
QP_OPTIMAL, QP_INFEASIBLE, QP_FAILED = 0, 1, 2


@njit(cache=True)
def _add(J, R, d, iq, n):
    """Adds a constraint with d = J^T n_p to the active set's QR factors
    (Givens rotations on J's columns iq.., R's column iq). False: linearly
    dependent on the active ones."""
    for j in range(n - 1, iq, -1):
        cc, ss = d[j - 1], d[j]
        h = np.hypot(cc, ss)
        if h == 0.0:
            continue
        d[j] = 0.0
        ss, cc = ss / h, cc / h
        if cc < 0.0:
            cc, ss = -cc, -ss
            d[j - 1] = -h
        else:
            d[j - 1] = h
        xny = ss / (1.0 + cc)
        for k in range(n):
            t1, t2 = J[k, j - 1], J[k, j]
            J[k, j - 1] = t1 * cc + t2 * ss
            J[k, j] = xny * (t1 + J[k, j - 1]) - t2
    for i in range(iq + 1):
        R[i, iq] = d[i]
    return abs(d[iq]) > 1e-13 * max(1.0, np.abs(d).max())


@njit(cache=True)
def _drop(J, R, active, u, l, iq, n):
    """Removes the l-th active constraint; restores R's triangular form."""
    for i in range(l, iq - 1):
        active[i] = active[i + 1]
        u[i] = u[i + 1]
        for k in range(n):
            R[k, i] = R[k, i + 1]
    active[iq - 1] = -1
    u[iq - 1] = 0.0
    for k in range(n):
        R[k, iq - 1] = 0.0
    iq -= 1
    for j in range(l, iq):
        cc, ss = R[j, j], R[j + 1, j]
        h = np.hypot(cc, ss)
        if h == 0.0:
            continue
        cc, ss = cc / h, ss / h
        R[j + 1, j] = 0.0
        if cc < 0.0:
            R[j, j] = -h
            cc, ss = -cc, -ss
        else:
            R[j, j] = h
        xny = ss / (1.0 + cc)
        for k in range(j + 1, iq):
            t1, t2 = R[j, k], R[j + 1, k]
            R[j, k] = t1 * cc + t2 * ss
            R[j + 1, k] = xny * (t1 + R[j, k]) - t2
        for k in range(n):
            t1, t2 = J[k, j], J[k, j + 1]
            J[k, j] = t1 * cc + t2 * ss
            J[k, j + 1] = xny * (J[k, j] + t1) - t2
    return iq


@njit(cache=True)
def _pick(C, c, x, scale, is_active, excluded, hint):
    """The most violated constraint not active (-1: none), those active at
    the last solve (``hint``) first."""
    n, p = C.shape[1], C.shape[0]
    ip, worst, ip_hint, worst_hint = -1, 0.0, -1, 0.0
    xmax = np.abs(x).max() if n else 0.0
    for i in range(p):
        if is_active[i] or excluded[i]:
            continue
        s = -c[i]
        for j in range(n):
            s += C[i, j] * x[j]
        if s < -1e-12 * scale[i] * (1.0 + xmax):
            v = s / scale[i]
            if hint[i] and v < worst_hint:
                worst_hint, ip_hint = v, i
            if v < worst:
                worst, ip = v, i
    return ip_hint if ip_hint >= 0 else ip


@njit(cache=True)
def _directions(J, R, row, iq, d, z, r):
    """For the constraint ``row``: d = J^T row, the primal direction z =
    J_2 d_2 and the dual one r = R^-1 d_1 (in place); returns (|z|^2,
    z . row)."""
    n = len(row)
    for j in range(n):
        acc = 0.0
        for k in range(n):
            acc += J[k, j] * row[k]
        d[j] = acc
    zz, zn = 0.0, 0.0
    for k in range(n):
        acc = 0.0
        for j in range(iq, n):
            acc += J[k, j] * d[j]
        z[k] = acc
        zz += acc * acc
        zn += acc * row[k]
    for i in range(iq - 1, -1, -1):
        acc = d[i]
        for j in range(i + 1, iq):
            acc -= R[i, j] * r[j]
        r[i] = acc / R[i, i]
    return zz, zn


@njit(cache=True)
def _solve(h, g, C, c, hint, x, was_active):
    n, p = len(g), C.shape[0]
    J = np.zeros((n, n))
    R = np.zeros((n, n))
    for i in range(n):
        J[i, i] = 1.0 / np.sqrt(h[i])
        x[i] = -g[i] / h[i]
    active = np.full(n, -1, np.int64)
    u = np.zeros(n)
    is_active = np.zeros(p, np.bool_)
    excluded = np.zeros(p, np.bool_)
    d = np.zeros(n)
    z = np.zeros(n)
    r = np.zeros(n)
    scale = np.zeros(p)
    for i in range(p):
        scale[i] = 1.0 + abs(c[i])
        for j in range(n):
            scale[i] += abs(C[i, j])
    iq = 0
    for _ in range(20 * (n + p) + 100):
        ip = _pick(C, c, x, scale, is_active, excluded, hint)
        if ip < 0:
            for i in range(iq):
                was_active[active[i]] = True
            return QP_OPTIMAL
        uplus = 0.0
        added = False
        while not added:
            # Step 2: the primal and dual directions for constraint ip.
            zz, zn = _directions(J, R, C[ip], iq, d, z, r)
            t1, l = np.inf, -1
            for i in range(iq):
                if r[i] > 0.0 and u[i] / r[i] < t1:
                    t1, l = u[i] / r[i], i
            s = -c[ip]
            for j in range(n):
                s += C[ip, j] * x[j]
            t2 = -s / zn if zz > 1e-24 * scale[ip] ** 2 and zn > 0.0 else np.inf
            t = min(t1, t2)
            if t == np.inf:
                return QP_INFEASIBLE
            for i in range(iq):
                u[i] -= t * r[i]
            uplus += t
            if t2 == np.inf:  # a step in the dual only
                is_active[active[l]] = False
                iq = _drop(J, R, active, u, l, iq, n)
                continue
            for k in range(n):
                x[k] += t * z[k]
            if t == t2:  # d = J^T n_p still (J unchanged since)
                if iq >= n or not _add(J, R, d, iq, n):
                    excluded[ip] = True  # dependent: leave it (it holds with equality)
                    break
                active[iq] = ip
                u[iq] = uplus
                is_active[ip] = True
                iq += 1
                added = True
            else:
                is_active[active[l]] = False
                iq = _drop(J, R, active, u, l, iq, n)
    return QP_FAILED


def solve_qp(h, g, C, c, *, warm=None):
    """argmin 1/2 x^T diag(h) x + g^T x subject to C x >= c.

    Args:
        h: (n,) the Hessian's diagonal, > 0.
        g: (n,) the linear term.
        C: (p, n), c: (p,) the constraints, row by row.
        warm: (p,) bools, the constraints active at a related earlier
            solve (tried first), or None.

    Returns:
        (status, x, active): :data:`QP_OPTIMAL` (x the minimiser),
        :data:`QP_INFEASIBLE` (no x meets the constraints) or
        :data:`QP_FAILED`; ``active`` (p,) bools, the constraints active at
        the solution.
    """
    h = np.ascontiguousarray(h, float)
    g = np.ascontiguousarray(g, float)
    C = np.ascontiguousarray(C, float).reshape(-1, len(g))
    c = np.ascontiguousarray(c, float)
    hint = np.zeros(len(c), np.bool_) if warm is None else np.ascontiguousarray(warm, np.bool_)
    x = np.zeros(len(g))
    active = np.zeros(len(c), np.bool_)
    status = _solve(h, g, C, c, hint, x, active)
    return status, x, active


@njit(cache=True)
def stage_problem(v_t, A, b, prio, weight, soft_from, hard):
    """The staged QP's stage (see :class:`~drake_cfvol.systems.filter.constraints.PriorityQP`)
    over x = [v; one slack per soft row], as (h, g, C, c, soft): rows of
    priority >= ``soft_from`` (and not ``hard``) soft (``soft_from`` past
    every priority: none), each soft row i as A_i v + s_i >= b_i with
    s_i >= 0 (the slack rows after the others) and cost weight_i s_i^2."""
    k, m = len(v_t), len(b)
    soft = np.zeros(m, np.bool_)
    n_s = 0
    for i in range(m):
        if prio[i] != hard and prio[i] >= soft_from:
            soft[i] = True
            n_s += 1
    n = k + n_s
    h = np.full(n, 2.0)
    g = np.zeros(n)
    C = np.zeros((m + n_s, n))
    c = np.zeros(m + n_s)
    for j in range(k):
        g[j] = -2.0 * v_t[j]
    col = k
    for i in range(m):
        for j in range(k):
            C[i, j] = A[i, j]
        c[i] = b[i]
        if soft[i]:
            h[col] = 2.0 * weight[i]
            C[i, col] = 1.0
            C[m + col - k, col] = 1.0
            col += 1
    return h, g, C, c, soft


@njit(cache=True)
def staged_solve(v_t, A, b, prio, weight, levels, hard, warm, v_out, active_out):
    """The first stage with a solution (0: every row hard; stage s: rows of
    priority >= ``levels[s - 1]`` soft; ``hard`` rows never), v into
    ``v_out`` and the rows active there into ``active_out``; returns
    (stage, QP solves), stage -1 where none has one. ``warm``: the rows
    active at the last solve, tried first."""
    k, m = len(v_t), len(b)
    solves = 0
    for stage in range(len(levels) + 1):
        soft_from = levels[stage - 1] if stage else np.iinfo(np.int64).max
        h, g, C, c, soft = stage_problem(v_t, A, b, prio, weight, soft_from, hard)
        hint = np.zeros(len(c), np.bool_)
        hint[:m] = warm
        x = np.zeros(len(g))
        active = np.zeros(len(c), np.bool_)
        status = _solve(h, g, C, c, hint, x, active)
        solves += 1
        if status == QP_OPTIMAL:
            v_out[:] = x[:k]
            active_out[:] = active[:m]
            return stage, solves
    return -1, solves
