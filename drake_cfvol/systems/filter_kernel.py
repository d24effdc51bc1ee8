"""The safety filter's QP rounds in compiled code (numba), one call per
update (:func:`filter_rounds`): the constraints' rows stacked, each
damper row's right-hand side grown by its second-order term at the step
(the robot's chain posed by the kernel's forward kinematics) and, for the
static scene's rows, relaxed towards the nominal; the staged QP
(:func:`~drake_cfvol.systems.qp.staged_solve`) solved again at its own
solution until that solution meets its rows.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from drake_cfvol.systems.damper_kinematics import _second_order, _slot_poses
from drake_cfvol.systems.qp import staged_solve

__all__ = ["budget_after", "filter_rounds"]


@njit(cache=True)
def _poses(q, kin):
    """The slots' poses (R, o) at q (:func:`~.damper_kinematics._slot_poses`)."""
    chain, body, R_WB, p_WB = kin
    S = body.shape[0]
    R, o = np.zeros((S, 3, 3)), np.zeros((S, 3))
    _slot_poses(q, chain, body, R_WB, p_WB, R, o)
    return R, o


@njit(cache=True)
def relaxation(q, q_c, nominal, lo, hi, vmax, period):
    """(w, v_ref): the damper's rows are relaxed so that following the
    nominal stays admissible near it, b_i' = b_i + w min(0, a_i v_ref -
    b_i), v_ref the robot's step to the nominal (from q, where the rows are
    taken: the measured position, else the command; clipped to the limits
    and the box), w = 1 where both the command q_c and q lie within one
    step at the velocity limits of the nominal, fading to 0 at two steps (a
    deviated robot gets no relaxation: the rows' linearisation says nothing
    reliable about the nominal's distances there); w = 0 without a (finite)
    nominal (NaN). A robot pushed off a command on the nominal is relaxed
    only as far as its own way back to the nominal shrinks a row, not as far
    as the command's."""
    k = len(q_c)
    v_ref = np.zeros(k)
    far = 0.0
    for j in range(k):
        if not np.isfinite(nominal[j]):
            return 0.0, v_ref
        if np.isfinite(vmax[j]):
            far = max(far, max(abs(nominal[j] - q_c[j]), abs(nominal[j] - q[j])) / (vmax[j] * period))
        v_ref[j] = min(max((nominal[j] - q[j]) / period, lo[j]), hi[j])
    return min(max(2.0 - far, 0.0), 1.0), v_ref


@njit(cache=True)
def _need(v, b, A, so_row, relaxed, relax, damper, base, kin, period, drift):
    """The rows' right-hand sides for the step v: b plus each damper row's
    second-order term at dq = v dt (over dt), then the relaxation
    b' = b + w min(0, A v_ref - b) of the relaxed rows (:func:`relaxation`),
    then each damper row's share of the robot's drift (its velocity beyond
    the command's) where that share approaches: b'' = b' - min(0, A drift),
    so the rows hold for the robot's own velocity v + drift."""
    q, R0, o0 = base
    Ad, dirs, points, slots, rounds, rev = damper
    w, v_ref = relax
    out = b.copy()
    if Ad.shape[0]:
        dq = v * period
        R1, o1 = _poses(q + dq, kin)
        e = _second_order(R0, o0, R1, o1, Ad, dirs, points, slots, rounds, rev, dq)
        for i in range(len(b)):
            if so_row[i] >= 0:
                out[i] += e[so_row[i]] / period
    if w > 0.0:
        for i in range(len(b)):
            if relaxed[i]:
                a = 0.0
                for j in range(len(v_ref)):
                    a += A[i, j] * v_ref[j]
                out[i] += w * min(0.0, a - out[i])
    for i in range(len(b)):
        if so_row[i] >= 0:
            a = 0.0
            for j in range(len(drift)):
                a += A[i, j] * drift[j]
            out[i] -= min(0.0, a)
    return out


@njit(cache=True)
def _short(A, v, need, tol, prio, only):
    """Per row, A_i v < need_i - tol (rows of priority ``only``; -1: all)."""
    out = np.zeros(len(need), np.bool_)
    for i in range(len(need)):
        if only >= 0 and prio[i] != only:
            continue
        a = 0.0
        for j in range(len(v)):
            a += A[i, j] * v[j]
        out[i] = a < need[i] - tol
    return out


@njit(cache=True)
def filter_rounds(v_t, rows, damper, kin, at, qp, warm):
    """The velocity commanded for the request v_t (within the box and the
    limits; see :func:`~drake_cfvol.systems.constraints.solve_rounds`).

    Args:
        rows: (A (m, k), b (m,), prio (m,), weight (m,), so_row (m,): the
            damper row whose second-order term the row adds (-1: none),
            relaxed (m,) bools).
        damper: the damper's rows (A, dirs, points, slots, rounds) and the
            slots' revolute masks (S, k).
        kin: (chain, slot bodies, scratch R_WB, scratch p_WB).
        at: (q, q_c, nominal, lo, hi, vmax, drift): where the rows were
            taken, the command before the update, the nominal (NaN: none),
            the velocity interval of the limits and the box, the limits,
            the robot's velocity beyond the command's (:func:`_need`).
        qp: (levels, hard, row, rounds, nudge, period): the priorities
            made soft stage by stage, the hard priority, the priority whose
            miss counts (``missed``), the most QP rounds, what a row still
            short asks for more at the next round (m/s), dt (s).
        warm: (m,) the rows active at the last solve.

    Returns:
        (v, missed: a ROW row missed at v, solved: False where the QP
        failed (v holds as far as the box allows), the rows active at the
        last solve (m,), QP solves).
    """
    A, b, prio, weight, so_row, relaxed = rows
    levels, hard, row_priority, rounds, nudge, period = qp
    q, q_c, nominal, lo, hi, vmax, drift = at
    base = (q,) + _poses(q, kin)
    relax = relaxation(q, q_c, nominal, lo, hi, vmax, period)
    m, k = A.shape
    active = warm.copy()
    bs = _need(v_t, b, A, so_row, relaxed, relax, damper, base, kin, period, drift)
    if not _short(A, v_t, bs, 1e-12, prio, -1).any():
        return v_t.copy(), False, True, active, 0
    v = v_t.copy()
    solves = 0
    for _ in range(rounds):
        stage, n = staged_solve(v_t, A, bs, prio, weight, levels, hard, active.copy(), v, active)
        solves += n
        if stage < 0:
            v = np.minimum(np.maximum(np.zeros(k), lo), hi)
            b_v = _need(v, b, A, so_row, relaxed, relax, damper, base, kin, period, drift)
            return v, _short(A, v, b_v, 1e-6, prio, row_priority).any(), False, active, solves
        b_v = _need(v, b, A, so_row, relaxed, relax, damper, base, kin, period, drift)
        short = _short(A, v, b_v, 1e-9, prio, -1)
        if not short.any():
            return v, _short(A, v, b_v, 1e-6, prio, row_priority).any(), True, active, solves
        for i in range(m):
            bs[i] = max(bs[i], b_v[i]) + (nudge if short[i] else 0.0)
    b_v = _need(v, b, A, so_row, relaxed, relax, damper, base, kin, period, drift)
    return v, _short(A, v, b_v, 1e-6, prio, row_priority).any(), True, active, solves


@njit(cache=True)
def request(q, desired, lower, upper, vmax, period, v_last, acceleration):
    """The update's request: (sane, lo, hi, v_t). Per joint the velocity
    interval [lo, hi] within the limits that lands in the box (where the
    box lies farther than one step, the step towards it at the limit), and
    the requested v_t = (desired - q) / dt, held within ``acceleration`` dt
    of the last velocity, clipped to it. Not sane (a non-finite or crossed
    input): the hold, as far as the box allows where it is usable (v_t 0
    clipped to the interval of the usable joints' box)."""
    k = len(q)
    sane = True
    for j in range(k):
        if not (np.isfinite(desired[j]) and np.isfinite(lower[j]) and np.isfinite(upper[j]) and lower[j] <= upper[j]):
            sane = False
    lo, hi, v_t = np.zeros(k), np.zeros(k), np.zeros(k)
    for j in range(k):
        ok = np.isfinite(lower[j]) and np.isfinite(upper[j]) and lower[j] <= upper[j]
        low, up = (lower[j], upper[j]) if ok else (q[j], q[j])
        to_lo, to_hi = (low - q[j]) / period, (up - q[j]) / period
        a, b = max(-vmax[j], to_lo), min(vmax[j], to_hi)
        if to_lo > vmax[j]:
            a = vmax[j]
        if to_hi < -vmax[j]:
            b = -vmax[j]
        lo[j], hi[j] = a, max(a, b)
        if sane:
            target = (desired[j] - q[j]) / period
            target = min(max(target, v_last[j] - acceleration[j] * period), v_last[j] + acceleration[j] * period)
        else:
            target = 0.0
        v_t[j] = min(max(target, lo[j]), hi[j])
    return sane, lo, hi, v_t


@njit(cache=True)
def finish(q, v, lo, hi, vmax, limits, desired, period, sane, changed):
    """The update's command from the velocity v: (v clipped to the limits,
    q_next = q + v dt, whether v left the interval [lo, hi] (by > 1e-9),
    max_j |v_j| / limit_j over the finite limits, whether the command
    differs from the request by more than ``changed`` (or the input was
    not sane))."""
    k = len(q)
    out, q_next = np.zeros(k), np.zeros(k)
    exited, acted, ratio = False, not sane, 0.0
    for j in range(k):
        x = min(max(v[j], -vmax[j]), vmax[j])
        out[j] = x
        q_next[j] = q[j] + x * period
        if x < lo[j] - 1e-9 or x > hi[j] + 1e-9:
            exited = True
        if np.isfinite(limits[j]):
            ratio = max(ratio, abs(x) / limits[j])
        if abs(q_next[j] - desired[j]) > changed:
            acted = True
    return out, q_next, exited, ratio, acted


@njit(cache=True)
def budget_after(dists, budget, influence, base):
    """After an update's measurement: (the smallest known distance, m: a
    measured pair's distance, a skipped pair's influence distance plus its
    budget; the budget to keep: per pair its distance beyond the influence
    distance, measured, or its budget, skipped (``dists`` NaN), then the
    base position it holds at)."""
    n = len(dists)
    out = np.empty(n + len(base))
    dmin = np.inf
    for i in range(n):
        if np.isnan(dists[i]):
            known = influence + max(budget[i], 0.0)
            out[i] = budget[i]
        else:
            known = dists[i]
            out[i] = dists[i] - influence
        dmin = min(dmin, known)
    out[n:] = base
    return dmin, out


#: Kinds of the constraints whose rows :func:`stack_rows` makes.
LIMIT_ROWS, BOX_ROWS, DAMPER_ROWS = 0, 1, 2


@njit(cache=True)
def stack_rows(kinds, weights, prios, relaxed, pairs, vmax, lo, hi, dA, db, dpair):
    """The rows of the filter's own constraints, stacked block after block
    in one call: (A (m, k), b, priority, weight, second-order row (the damper
    row a row is; -1: none), relaxed per row, rows per block).

    Args:
        kinds: (n,) per block :data:`LIMIT_ROWS` (v_j >= -vmax_j and -v_j >=
            -vmax_j over the joints with a finite limit), :data:`BOX_ROWS`
            (v >= lo, -v >= -hi) or :data:`DAMPER_ROWS` (the damper's rows
            of the pairs the block's ``pairs`` row holds).
        weights, prios, relaxed: (n,) the blocks' weight, priority and
            relaxation.
        pairs: (n, P) bools, per damper block its pairs.
        vmax, lo, hi: (k,) the velocity limits and the box's velocity
            interval.
        dA, db, dpair: the damper's rows (m_d, k), (m_d,) and their pairs.
    """
    n, k, md = len(kinds), len(lo), len(db)
    finite = 0
    for j in range(k):
        if np.isfinite(vmax[j]):
            finite += 1
    counts = np.zeros(n, np.int64)
    for i in range(n):
        if kinds[i] == LIMIT_ROWS:
            counts[i] = 2 * finite
        elif kinds[i] == BOX_ROWS:
            counts[i] = 2 * k
        else:
            for r in range(md):
                if pairs[i, dpair[r]]:
                    counts[i] += 1
    m = 0
    for i in range(n):
        m += counts[i]
    A, b = np.zeros((m, k)), np.empty(m)
    prio, weight = np.empty(m, np.int64), np.empty(m)
    so_row, rel = np.full(m, -1, np.int64), np.zeros(m, np.bool_)
    at = 0
    for i in range(n):
        if kinds[i] == DAMPER_ROWS:
            r = at
            for d in range(md):
                if pairs[i, dpair[d]]:
                    for j in range(k):
                        A[r, j] = dA[d, j]
                    b[r], so_row[r] = db[d], d
                    r += 1
        else:  # [I; -I] over the block's joints (the lower half's zeros negative, as -I's)
            half = counts[i] // 2
            r = at
            for j in range(k):
                if kinds[i] == BOX_ROWS or np.isfinite(vmax[j]):
                    for c in range(k):
                        A[r + half, c] = -0.0
                    A[r, j], A[r + half, j] = 1.0, -1.0
                    if kinds[i] == BOX_ROWS:
                        b[r], b[r + half] = lo[j], -hi[j]
                    else:
                        b[r], b[r + half] = -vmax[j], -vmax[j]
                    r += 1
        for r in range(at, at + counts[i]):
            prio[r], weight[r], rel[r] = prios[i], weights[i], relaxed[i]
        at += counts[i]
    return A, b, prio, weight, so_row, rel, counts
