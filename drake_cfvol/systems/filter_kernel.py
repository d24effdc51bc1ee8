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

from drake_cfvol.kernel.kinematics import fk_into
from drake_cfvol.systems.damper_kinematics import _second_order
from drake_cfvol.systems.qp import staged_solve

__all__ = ["filter_rounds"]


@njit(cache=True)
def _poses(q, kin):
    chain, body, R_WB, p_WB = kin
    fk_into(q, chain, R_WB, p_WB)
    S = body.shape[0]
    R, o = np.zeros((S, 3, 3)), np.zeros((S, 3))
    for s in range(S):
        R[s] = R_WB[body[s]]
        o[s] = p_WB[body[s]]
    return R, o


@njit(cache=True)
def _need(v, b, A, so_row, relaxed, relax, damper, base, kin, period):
    """The rows' right-hand sides for the step v: b plus each damper row's
    second-order term at dq = v dt (over dt), then the relaxation
    b' = b + w min(0, A v_ref - b) of the relaxed rows."""
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
def filter_rounds(v_t, lo, hi, rows, damper, base, kin, relax, qp, warm):
    """The velocity commanded for the request v_t (within the box and the
    limits; see :func:`~drake_cfvol.systems.constraints.solve_rounds`).

    Args:
        rows: (A (m, k), b (m,), prio (m,), weight (m,), so_row (m,): the
            damper row whose second-order term the row adds (-1: none),
            relaxed (m,) bools).
        damper: the damper's rows (A, dirs, points, slots, rounds) and the
            slots' revolute masks (S, k).
        base: (q, R0, o0), where the rows were taken and the slots' poses there.
        kin: (chain, slot bodies, scratch R_WB, scratch p_WB).
        relax: (w, v_ref), the relaxation's weight and reference step.
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
    m, k = A.shape
    active = warm.copy()
    bs = _need(v_t, b, A, so_row, relaxed, relax, damper, base, kin, period)
    if not _short(A, v_t, bs, 1e-12, prio, -1).any():
        return v_t.copy(), False, True, active, 0
    v = v_t.copy()
    solves = 0
    for _ in range(rounds):
        stage, n = staged_solve(v_t, A, bs, prio, weight, levels, hard, active.copy(), v, active)
        solves += n
        if stage < 0:
            v = np.minimum(np.maximum(np.zeros(k), lo), hi)
            b_v = _need(v, b, A, so_row, relaxed, relax, damper, base, kin, period)
            return v, _short(A, v, b_v, 1e-6, prio, row_priority).any(), False, active, solves
        b_v = _need(v, b, A, so_row, relaxed, relax, damper, base, kin, period)
        short = _short(A, v, b_v, 1e-9, prio, -1)
        if not short.any():
            return v, _short(A, v, b_v, 1e-6, prio, row_priority).any(), True, active, solves
        for i in range(m):
            bs[i] = max(bs[i], b_v[i]) + (nudge if short[i] else 0.0)
    b_v = _need(v, b, A, so_row, relaxed, relax, damper, base, kin, period)
    return v, _short(A, v, b_v, 1e-6, prio, row_priority).any(), True, active, solves
