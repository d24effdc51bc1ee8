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

A stage with soft rows (:func:`staged_solve`) is solved in the joint
velocities alone (:func:`_soft_stage`): a soft row's miss is
max(0, b_i - A_i v), so the stage is the piecewise quadratic |v - v_t|^2
+ sum_i w_i max(0, b_i - A_i v)^2 under the hard rows, minimised by
guessing which soft rows miss and solving that quadratic until the guess
holds. The slack form (one variable per soft row) has the same unique
minimiser; it is the fallback where the guesses cycle (a few per cent of
random instances; a line search along the guesses would end that).
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


#: The guesses of the missing soft rows :func:`_soft_stage` tries before
#: it leaves the stage to the slack form.
SOFT_GUESSES = 30

#: A soft row counts as missed below b_i less this share of its scale
#: (1 + |b_i| + sum_j |A_ij v_j|), and stays counted until it holds by as
#: much: rounding cannot flip a row that sits on its bound.
_SOFT_TOL = 1e-13


@njit(cache=True)
def _soft_stage(v_t, A, b, soft, weight, warm, v_out, active_out):
    """A stage with soft rows (``soft`` (m,) bools; the others hard),
    solved in v alone: argmin |v - v_t|^2 + sum_soft w_i max(0, b_i - A_i
    v)^2 over the hard rows, the slack form's minimiser. For a guess S of
    the soft rows that miss, the stage is the quadratic 1/2 v^T H v - r^T v
    (H = I + sum_S w_i A_i^T A_i, r = v_t + sum_S w_i b_i A_i) under the
    hard rows, solved by :func:`_solve` in y = L^T v (H = L L^T); the next
    guess is the rows that miss at its minimiser. Where a guess repeats,
    its minimiser meets the stage's optimality conditions. Returns the
    status (:data:`QP_FAILED`: the guesses did not settle in
    :data:`SOFT_GUESSES`; QP_INFEASIBLE: the hard rows alone admit no v);
    v into ``v_out``, the active hard rows and the missed soft ones into
    ``active_out``. ``warm``: the rows active at the last solve (its
    missed soft rows are the first guess)."""
    k, m = len(v_t), len(b)
    n_hard = 0
    for i in range(m):
        if not soft[i]:
            n_hard += 1
    hard_rows = np.empty(n_hard, np.int64)
    r = 0
    for i in range(m):
        if not soft[i]:
            hard_rows[r] = i
            r += 1
    guess = np.zeros(m, np.bool_)
    for i in range(m):
        guess[i] = soft[i] and warm[i]
    H, L = np.empty((k, k)), np.zeros((k, k))
    rhs, g, y, v = np.empty(k), np.empty(k), np.empty(k), np.empty(k)
    C, c = np.empty((n_hard, k)), np.empty(n_hard)
    hint, active = np.zeros(n_hard, np.bool_), np.zeros(n_hard, np.bool_)
    for i in range(n_hard):
        hint[i] = warm[hard_rows[i]]
    ones = np.ones(k)
    for _ in range(SOFT_GUESSES):
        for a in range(k):
            rhs[a] = v_t[a]
            for e in range(k):
                H[a, e] = 1.0 if a == e else 0.0
        for i in range(m):
            if guess[i]:
                w = weight[i]
                for a in range(k):
                    rhs[a] += w * b[i] * A[i, a]
                    for e in range(k):
                        H[a, e] += w * A[i, a] * A[i, e]
        # H = L L^T (H >= I: positive definite).
        for a in range(k):
            for e in range(a + 1):
                x = H[a, e]
                for f in range(e):
                    x -= L[a, f] * L[e, f]
                L[a, e] = np.sqrt(x) if a == e else x / L[e, e]
        # g = -L^-1 rhs; each hard row A_j v >= b_j as (L^-1 A_j^T)^T y >= b_j.
        for a in range(k):
            x = rhs[a]
            for f in range(a):
                x += L[a, f] * g[f]  # g holds -L^-1 rhs so far
            g[a] = -x / L[a, a]
        for t in range(n_hard):
            i = hard_rows[t]
            for a in range(k):
                x = A[i, a]
                for f in range(a):
                    x -= L[a, f] * C[t, f]
                C[t, a] = x / L[a, a]
            c[t] = b[i]
        active[:] = False
        status = _solve(ones, g, C, c, hint, y, active)
        if status != QP_OPTIMAL:
            return status
        # v = L^-T y.
        for a in range(k - 1, -1, -1):
            x = y[a]
            for f in range(a + 1, k):
                x -= L[f, a] * v[f]
            v[a] = x / L[a, a]
        settled = True
        for i in range(m):
            if not soft[i]:
                continue
            s, scale = b[i], 1.0 + abs(b[i])
            for a in range(k):
                s -= A[i, a] * v[a]
                scale += abs(A[i, a] * v[a])
            tol = _SOFT_TOL * scale
            missed = s > tol or (guess[i] and s > -tol)
            if missed != guess[i]:
                guess[i] = missed
                settled = False
        if settled:
            v_out[:] = v
            for i in range(m):
                active_out[i] = guess[i]
            for t in range(n_hard):
                active_out[hard_rows[t]] = active[t]
            return QP_OPTIMAL
        hint[:] = active
    return QP_FAILED


@njit(cache=True)
def _slack_stage(v_t, A, b, prio, weight, soft_from, hard, warm, v_out, active_out):
    """A stage in its slack form (:func:`stage_problem`) by :func:`_solve`:
    its status, v into ``v_out`` and the rows active into ``active_out``."""
    k, m = len(v_t), len(b)
    h, g, C, c, soft = stage_problem(v_t, A, b, prio, weight, soft_from, hard)
    hint = np.zeros(len(c), np.bool_)
    hint[:m] = warm
    x = np.zeros(len(g))
    active = np.zeros(len(c), np.bool_)
    status = _solve(h, g, C, c, hint, x, active)
    if status == QP_OPTIMAL:
        v_out[:] = x[:k]
        active_out[:] = active[:m]
    return status


@njit(cache=True)
def staged_solve(v_t, A, b, prio, weight, levels, hard, warm, v_out, active_out, first=0):
    """The first stage from ``first`` on with a solution (0: every row
    hard; stage s: rows of priority >= ``levels[s - 1]`` soft; ``hard``
    rows never), v into ``v_out`` and the rows active there into
    ``active_out``; returns (stage, QP solves, the stages before the first
    one not proven infeasible), stage -1 where none has one. A stage with
    soft rows is solved in v alone (:func:`_soft_stage`), else (or where
    its guesses do not settle) in its slack form. ``warm``: the rows
    active at the last solve, tried first. ``first``: the stages before it
    are known infeasible (an earlier solve of rows no looser)."""
    m = len(b)
    solves, proven = 0, first
    for stage in range(first, len(levels) + 1):
        soft_from = levels[stage - 1] if stage else np.iinfo(np.int64).max
        soft = np.zeros(m, np.bool_)
        for i in range(m):
            soft[i] = prio[i] != hard and prio[i] >= soft_from
        status = QP_FAILED
        if soft.any():
            status = _soft_stage(v_t, A, b, soft, weight, warm, v_out, active_out)
        if status == QP_FAILED:
            status = _slack_stage(v_t, A, b, prio, weight, soft_from, hard, warm, v_out, active_out)
        solves += 1
        if status == QP_OPTIMAL:
            return stage, solves, proven
        if status == QP_INFEASIBLE and proven == stage:
            proven = stage + 1
    return -1, solves, proven
