"""The safety filter's QP rounds in compiled code (numba), one call per
update (:func:`filter_rounds`): the constraints' rows stacked, each
damper row's right-hand side grown by its second-order term at the step
(the robot's chain posed by the kernel's forward kinematics) and, for the
static scene's rows, relaxed towards the nominal; the staged QP
(:func:`~drake_cfvol.systems.filter.qp.staged_solve`) solved again at its own
solution until that solution meets its rows.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from drake_cfvol.systems.filter.damper_kinematics import (
    _budget_moved,
    _levers,
    _pair_speeds,
    _second_order,
    _slot_jacobians,
    _slot_poses,
)
from drake_cfvol.systems.filter.qp import staged_solve

__all__ = [
    "BRAKE_JERK_SHARE",
    "ROW_DECELERATION_SHARE",
    "brake_step",
    "brake_velocity",
    "braking_lead",
    "brake_rows",
    "braked_rows",
    "budget_after",
    "carry_plane",
    "face_speed",
    "filter_rounds",
    "hard_interval",
    "hard_step",
    "outside",
    "plane_bends",
    "request",
    "return_time",
    "stop_distance",
    "stop_steps",
    "witness_rows",
]


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
    limits; see :func:`~drake_cfvol.systems.filter.constraints.solve_rounds`).

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
    first = 0  # the right-hand sides only grow: a stage infeasible at one round is at the next
    for _ in range(rounds):
        stage, n, first = staged_solve(v_t, A, bs, prio, weight, levels, hard, active.copy(), v, active, first)
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
def stop_distance(v, a, acceleration, jerk, period):
    """How far the update q <- q + v' dt carries on after a step that left
    velocity v and acceleration a, braking as hard as the limits allow:
    a' = max(a - jerk dt, -acceleration), v' = v + a' dt, summing the
    positive v' dt until v' <= 0 (0 for v <= 0). Exact for the discrete
    update; the ramp's steps are walked, the constant deceleration summed
    in closed form."""
    if v <= 0.0:
        return 0.0
    if not np.isfinite(acceleration) and not np.isfinite(jerk):
        return 0.0  # no limit: stopped at the next step
    d = 0.0
    for _ in range(1000000):  # the ramp: jerk-limited, until the deceleration is at its limit
        if v <= 0.0 or a <= -acceleration:
            break
        a = max(a - jerk * period, -acceleration)
        v += a * period
        if v > 0.0:
            d += v * period
    if v > 0.0:  # v - i acceleration dt for i = 1 .. n, n = floor(v / (acceleration dt))
        n = np.floor(v / (acceleration * period))
        d += period * (n * v - acceleration * period * n * (n + 1.0) / 2.0)
    return d


@njit(cache=True)
def face_speed(gap, v_last, lo, hi, acceleration, jerk, period):
    """The largest velocity v in [lo, hi] from which the robot, braking at
    its limits after this step, stops within ``gap`` of where it is:
    v dt + :func:`stop_distance` (v, (v - v_last) / dt) <= gap; ``lo``
    where none (the command brakes as hard as the limits allow)."""
    if not np.isfinite(acceleration) and not np.isfinite(jerk):
        return min(max(gap / period, lo), hi)
    if hi * period + stop_distance(hi, (hi - v_last) / period, acceleration, jerk, period) <= gap:
        return hi
    if lo * period + stop_distance(lo, (lo - v_last) / period, acceleration, jerk, period) > gap:
        return lo
    a, b = lo, hi
    for _ in range(60):
        m = 0.5 * (a + b)
        if m <= a or m >= b:
            break
        if m * period + stop_distance(m, (m - v_last) / period, acceleration, jerk, period) <= gap:
            a = m
        else:
            b = m
    return a


@njit(cache=True, inline="always")
def hard_step(vmax, period, v_last, a_last, acceleration, jerk):
    """One joint's :func:`hard_interval`: (lo, hi)."""
    h = period
    ja, jj = acceleration * h, jerk * h * h
    lo_aj = max(v_last - ja, v_last + a_last * h - jj)
    hi_aj = min(v_last + ja, v_last + a_last * h + jj)
    lo_v, hi_v = -vmax, vmax
    if np.isfinite(jj) and np.isfinite(vmax):
        # v + (v - v_last)^2 / (2 jerk dt^2) <= vmax for v > v_last: the largest such step x
        x = jj * (np.sqrt(1.0 + 2.0 * max(vmax - v_last, 0.0) / jj) - 1.0)
        hi_v = min(vmax, max(v_last, v_last + x))
        x = jj * (np.sqrt(1.0 + 2.0 * max(vmax + v_last, 0.0) / jj) - 1.0)
        lo_v = max(-vmax, min(v_last, v_last - x))
    a, b = max(lo_aj, lo_v), min(hi_aj, hi_v)
    if a > b:  # the point of the acceleration and jerk interval nearest the velocity limits'
        if lo_aj > hi_aj:  # the jerk interval misses the acceleration one: the latter's alone
            lo_aj, hi_aj = v_last - ja, v_last + ja
        a = b = min(max(min(max(0.0, lo_v), hi_v), lo_aj), hi_aj)
    return a, b


#: The share of the jerk limit the brake plans its last ramp with (the
#: rest absorbs the discrete steps, so that it does not overshoot).
BRAKE_JERK_SHARE = 0.9


@njit(cache=True, inline="always")
def brake_step(vmax, period, v_last, a_last, acceleration, jerk):
    """One joint's next velocity braking to rest within its limits: the
    acceleration a' that ramps down to 0 at (a share of) the jerk limit J
    just as the velocity reaches 0 (v + a' dt + a'|a'| / (2 J) = 0),
    within the acceleration limit, then clipped to the hard interval
    (:func:`hard_step`). Full deceleration until the last ramp, which
    ends at rest rather than overshooting into a reversal (a state whose
    acceleration cannot be ramped down in time still overshoots, as
    little as the limits allow). Without a jerk limit: 0 as nearly as the
    hard interval allows."""
    lo, hi = hard_step(vmax, period, v_last, a_last, acceleration, jerk)
    J = BRAKE_JERK_SHARE * jerk
    h = period
    if not np.isfinite(J) or abs(v_last) <= 0.5 * J * h * h:  # within half a jerk step of rest: rest
        t = 0.0
    else:
        if v_last > 0.0:
            ap = J * h - np.sqrt(J * J * h * h + 2.0 * J * v_last)
        else:
            ap = -J * h + np.sqrt(J * J * h * h - 2.0 * J * v_last)
        ap = min(max(ap, -acceleration), acceleration)
        t = v_last + ap * h
        if (t > 0.0) != (v_last > 0.0):
            t = 0.0
    return min(max(t, lo), hi)


@njit(cache=True)
def brake_velocity(vmax, period, v_last, a_last, acceleration, jerk):
    """Per joint :func:`brake_step`: the command's velocity braking to rest."""
    k = len(vmax)
    out = np.empty(k)
    for j in range(k):
        out[j] = brake_step(vmax[j], period, v_last[j], a_last[j], acceleration[j], jerk[j])
    return out


@njit(cache=True)
def hard_interval(vmax, period, v_last, a_last, acceleration, jerk):
    """Per joint the velocity interval [lo, hi] every command keeps: the
    velocity limits, braked in time under the jerk limit (an acceleration
    a' > 0 ramped down to 0 at the jerk limit adds at most a'^2 / (2 jerk)
    to v), |v - v_last| <= acceleration dt and |v - v_last - a_last dt| <=
    jerk dt^2. Where they cannot all hold (a start or a hold that left the
    state outside them), the point of the acceleration and jerk interval
    nearest the velocity limits' (:func:`hard_step`, per joint)."""
    k = len(vmax)
    lo, hi = np.empty(k), np.empty(k)
    for j in range(k):
        lo[j], hi[j] = hard_step(vmax[j], period, v_last[j], a_last[j], acceleration[j], jerk[j])
    return lo, hi


@njit(cache=True, inline="always")
def return_time(vmax, acceleration, jerk, period):
    """A joint's braking time from its velocity limit, its jerk's ramp and
    an update included (s; inf without an acceleration limit): how fast a
    joint returns to the box ahead (:func:`request`). The box ahead looks
    twice the slowest joint's along the path (``AddCoManipulation``'s
    lookahead)."""
    if not (np.isfinite(acceleration) and acceleration > 0.0 and np.isfinite(vmax)):
        return np.inf
    ramp = acceleration / jerk if np.isfinite(jerk) and jerk > 0.0 else 0.0
    return vmax / acceleration + ramp + period


@njit(cache=True)
def request(q, desired, lower, upper, ahead, vmax, period, v_last, a_last, acceleration, jerk, nominals):
    """The update's request: (sane, lo, hi, v_t, hard_lo, hard_hi). Per
    joint the hard interval (:func:`hard_interval`) and within it the
    velocity interval [lo, hi] that keeps the box, braked in time: from
    each face the largest velocity from which braking at the limits stops
    inside it (:func:`face_speed`; without acceleration and jerk limits,
    the step that lands in the box). Where the box lies farther than that
    (outside it, or one face too close to brake for), the command moves
    towards it as fast as the limits allow. The faces are taken as moving
    with the nominal (braking means matching its velocity: ``nominals``
    (2, k), the nominal now and at the last update; 0 where either is not
    finite), and
    braked for where ``ahead`` (2, k: the box ahead, inside the box; NaN
    where none) puts them. A joint inside the box but beyond a face of
    the box ahead moves back towards it at least its distance over
    :func:`return_time` faster than the nominal (as far as the limits and
    the far face allow), not as fast as the limits allow. The requested v_t =
    (desired - q) / dt clipped to [lo, hi]. Not sane (a non-finite or
    crossed input): the hold, braked at the limits, as far as the box
    allows where it is usable."""
    k = len(q)
    sane = True
    for j in range(k):
        if not (np.isfinite(desired[j]) and np.isfinite(lower[j]) and np.isfinite(upper[j]) and lower[j] <= upper[j]):
            sane = False
    h_lo, h_hi = hard_interval(vmax, period, v_last, a_last, acceleration, jerk)
    lo, hi, v_t = np.zeros(k), np.zeros(k), np.zeros(k)
    for j in range(k):
        ok = np.isfinite(lower[j]) and np.isfinite(upper[j]) and lower[j] <= upper[j]
        low, up = (lower[j], upper[j]) if ok else (q[j], q[j])
        pull_lo, pull_hi = -np.inf, np.inf  # the return to the box ahead from inside the box
        if ok and np.isfinite(ahead[0, j]) and np.isfinite(ahead[1, j]) and ahead[0, j] <= ahead[1, j]:
            # A joint inside the box but outside the box ahead returns to it
            # within its braking time, not as fast as the limits allow: the
            # box ahead binds only as the path reaches it, and a full-limit
            # return made the QP spend every other joint's request on it.
            T = return_time(vmax[j], acceleration[j], jerk[j], period)
            if q[j] < ahead[0, j] and q[j] >= low and np.isfinite(T):
                pull_lo = (ahead[0, j] - q[j]) / T
            else:
                low = max(low, ahead[0, j])
            if q[j] > ahead[1, j] and q[j] <= up and np.isfinite(T):
                pull_hi = -(q[j] - ahead[1, j]) / T
            else:
                up = min(up, ahead[1, j])
        u = (nominals[0, j] - nominals[1, j]) / period
        if not np.isfinite(u):  # no nominal, or none at the last update
            u = 0.0
        b = u + face_speed(up - q[j], v_last[j] - u, h_lo[j] - u, h_hi[j] - u, acceleration[j], jerk[j], period)
        a = u - face_speed(q[j] - low, u - v_last[j], u - h_hi[j], u - h_lo[j], acceleration[j], jerk[j], period)
        if np.isfinite(pull_lo):
            a = max(a, min(u + pull_lo, h_hi[j], b))
        if np.isfinite(pull_hi):
            b = min(b, max(u + pull_hi, h_lo[j], a))
        if a > b:  # both faces cannot be kept
            if q[j] > up:  # above the box: down to it, fast enough to stop above its lower face
                b = a
            elif q[j] < low:  # below: up to it, slow enough to stop below its upper face
                a = b
            else:  # towards the box's middle, as far as the limits allow
                a = b = min(max(0.5 * (a + b), h_lo[j]), h_hi[j])
        lo[j], hi[j] = a, b
        target = (desired[j] - q[j]) / period if sane else 0.0
        v_t[j] = min(max(target, lo[j]), hi[j])
    return sane, lo, hi, v_t, h_lo, h_hi


#: The share of the arm's deceleration along a row that the row counts on:
#: the rest is left to the other rows and the box, braking at the same time.
ROW_DECELERATION_SHARE = 0.5


@njit(cache=True)
def brake_rows(A, b, rate, acceleration, jerk, period, v_last, h_lo, h_hi, bend):
    """The damper's rows braked in time: a row i that lets its distance
    shrink (b_i < 0: the gap -b_i / rate above the target) lets it shrink
    no faster than a point mass on the row can still stop within that gap
    (:func:`face_speed`, exact for the discrete update). The point mass:
    the row's closing speed -A_i v, last -A_i v_last, within [-max A_i v,
    -min A_i v] over the hard interval [h_lo, h_hi], braking at a share
    (:data:`ROW_DECELERATION_SHARE`) of the row's acceleration sum_j
    |A_ij| acceleration_j and jerk sum_j |A_ij| jerk_j (the rest is left
    to the other rows and the box, braking at the same time); where that
    cannot stop it any more, at all of them. The gap is less ``bend`` (m
    per row): how much more the row closes over the joints' own stop than
    its first order says (its points turning on the way). Where the
    damper's own rate (-b_i) asks for a faster slow-down than the hard
    interval allows, the row asks for the slowest closing it allows: no
    room for the rounds' second-order terms, which such a row may then
    miss (``braking_faults``). At 1 ms the jerk-limited interval is
    narrow, and room for them (half of it, before 0.11.2) kept the row's
    acceleration towards its obstacle. A row whose joints have no
    acceleration limit is kept as it is."""
    out = b.copy()
    m, k = A.shape
    for i in range(m):
        if b[i] >= 0.0:
            continue
        acc, jrk, s_last, s_lo, s_hi = 0.0, 0.0, 0.0, 0.0, 0.0
        for j in range(k):
            x = abs(A[i, j])
            if x == 0.0:
                continue
            acc += x * acceleration[j]
            jrk += x * jerk[j]
            s_last -= A[i, j] * v_last[j]
            s_lo -= max(A[i, j] * h_lo[j], A[i, j] * h_hi[j])
            s_hi -= min(A[i, j] * h_lo[j], A[i, j] * h_hi[j])
        if not np.isfinite(acc) or acc <= 0.0:
            continue
        gap = -b[i] / rate - bend[i]
        speed = face_speed(gap, s_last, s_lo, s_hi, ROW_DECELERATION_SHARE * acc, ROW_DECELERATION_SHARE * jrk, period)
        if speed <= s_lo:  # late (the distance fell faster than its first-order row said): all of it
            speed = face_speed(gap, s_last, s_lo, s_hi, acc, jrk, period)
        # The damper's own rule (-b_i) where the limits can keep it, else
        # the slowest closing they allow; never past the stop.
        allowed = -b[i] if -b[i] >= s_lo else s_lo
        cap = speed if speed < s_hi else np.inf  # at s_hi the stop does not bind
        out[i] = -min(cap, allowed)
    return out


@njit(cache=True)
def stop_steps(v, a_last, acceleration, jerk, period):
    """Per joint, where braking at the row's share of its limits from the
    last command (velocity v, acceleration a_last) stops it, relative to
    where it is (:func:`stop_distance`, signed; 0 without a limit)."""
    out = np.zeros(len(v))
    for j in range(len(v)):
        acc, jrk = ROW_DECELERATION_SHARE * acceleration[j], ROW_DECELERATION_SHARE * jerk[j]
        if not (np.isfinite(acc) and acc > 0.0):
            continue
        if v[j] >= 0.0:
            out[j] = stop_distance(v[j], a_last[j], acc, jrk, period)
        else:
            out[j] = -stop_distance(-v[j], -a_last[j], acc, jrk, period)
    return out


@njit(cache=True)
def _sum_as_numpy(x: np.ndarray, n: int) -> float:
    """x[:n].sum() in NumPy's order (its pairwise summation: in sequence
    below 8 terms, else in 8 running sums), so that compiled sums equal
    the ones NumPy took before bit for bit. For n <= 128 (NumPy halves
    longer sums; a joint count never comes near)."""
    if n < 8:
        out = 0.0
        for i in range(n):
            out += x[i]
        return out
    if n > 128:
        raise ValueError("_sum_as_numpy: more than 128 terms")
    r = np.empty(8)
    for j in range(8):
        r[j] = x[j]
    i = 8
    while i < n - n % 8:
        for j in range(8):
            r[j] += x[i + j]
        i += 8
    out = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]))
    while i < n:
        out += x[i]
        i += 1
    return out


@njit(cache=True, inline="always")
def carry_plane(n, w, R0, o0, R1, o1, slot, n1, w1):
    """The plane through w with normal n carried with the body of ``slot``
    from its pose (R0, o0) to (R1, o1), into n1, w1: n' = R1 R0^T n,
    w' = R1 R0^T (w - o0) + o1."""
    for r in range(3):
        n1[r], w1[r] = 0.0, o1[slot, r]
        for c in range(3):
            rot = R1[slot, r, 0] * R0[slot, c, 0] + R1[slot, r, 1] * R0[slot, c, 1] + R1[slot, r, 2] * R0[slot, c, 2]
            n1[r] += rot * n[c]
            w1[r] += rot * (w[c] - o0[slot, c])


@njit(cache=True, inline="always")
def _plane_gap(n, w, sign, probes, count, radii, R, o, slot):
    """The least distance of a side's probe spheres (``probes`` (c, 3) in
    the body frame of ``slot``, posed by R, o; ``radii``) from the plane
    through ``w`` with normal ``sign`` n (world frame)."""
    best = np.inf
    for c in range(count):
        x = 0.0
        for r in range(3):
            p = R[slot, r, 0] * probes[c, 0] + R[slot, r, 1] * probes[c, 1] + R[slot, r, 2] * probes[c, 2] + o[slot, r]
            x += sign * n[r] * (p - w[r])
        best = min(best, x - radii[c])
    return best


@njit(cache=True)
def witness_rows(pair, num_pairs):
    """The index of each pair's first row (its witness row), in order."""
    seen = np.zeros(max(num_pairs, 1), np.bool_)
    out = np.empty(len(pair), np.int64)
    n = 0
    for i in range(len(pair)):
        if not seen[pair[i]]:
            seen[pair[i]] = True
            out[n] = i
            n += 1
    return out[:n]


@njit(cache=True)
def plane_bends(before, after, A, dirs, points, slots, pair, stop, sides):
    """Per row, how much more its pair closes over the joints' ``stop``
    than the row's first order says, by the pair's supporting planes (m):
    for the witness row (the first row of its pair) of a pair of two
    moving bodies, the least over the two sides of B_t(before) + A_i stop
    - B_t(after), B_t the least distance of one side's probe spheres from
    the plane through the other side's witness (normal towards them),
    that plane carried with its own body; 0 for the other rows. The
    witness plane supports its side wherever the body goes, so B_t(after)
    bounds the pair's distance at the stop from below when the probes
    hold their shape's lowest points along any direction (a polytope's
    vertices, a capsule's end spheres), however far the closest points
    slide. The rows' own points carried to the stop (``_second_order``)
    do not: two boxes crossing edge to edge close without either's
    witness point closing.

    Args:
        before, after: (R, o), the slots' poses at the base and at the stop.
        A, dirs, points, slots, pair: the damper's rows (each pair's
            witness row first, P1 on the pair's side 0, dirs from side 1
            towards side 0).
        stop: (k,) the joints' stop (:func:`stop_steps`).
        sides: (probes (P, 2, n, 3) in the body frames, their counts (P,
            2), radii (P, 2, n)), per pair and side.
    """
    probes, counts, radii = sides
    R0, o0 = before
    R1, o1 = after
    m, k = A.shape
    out = np.zeros(m)
    w1, n1 = np.zeros(3), np.zeros(3)
    for i in witness_rows(pair, counts.shape[0]):
        p = pair[i]
        s0, s1 = slots[i, 0], slots[i, 1]
        if s0 < 0 or s1 < 0:
            continue  # a welded side: its rows are planes fixed in the world, carried exactly
        lin = 0.0
        for j in range(k):
            lin += A[i, j] * stop[j]
        extra = np.inf
        for t in range(2):  # the plane on side t, side 1 - t's probes
            u = 1 - t
            if counts[p, u] == 0:
                continue
            st, su = slots[i, t], slots[i, u]
            sign = 1.0 if t == 1 else -1.0
            gap0 = _plane_gap(dirs[i], points[i, t], sign, probes[p, u], counts[p, u], radii[p, u], R0, o0, su)
            carry_plane(dirs[i], points[i, t], R0, o0, R1, o1, st, n1, w1)
            gap1 = _plane_gap(n1, w1, sign, probes[p, u], counts[p, u], radii[p, u], R1, o1, su)
            extra = min(extra, gap0 + lin - gap1)
        if np.isfinite(extra):
            out[i] = max(extra, 0.0)
    return out


@njit(cache=True)
def braked_rows(
    rows: tuple, before: tuple, after: tuple, motion: tuple, limits: tuple, command: tuple, sides: tuple
) -> tuple[np.ndarray, ...]:
    """The damper's rows braked in time, less those that cannot bind at
    this update (:meth:`~drake_cfvol.systems.filter.safety.SafetyFilter._braked_rows`),
    in one call: (A, b, dirs, points, slots, rounds, pair) of the rows kept.

    Args:
        rows: (A, b, dirs, points, slots, rounds, pair), the damper's rows.
        before, after: (R, o), the slots' poses at the base and carried by
            the joints' stop from it.
        motion: (rev, stop, lever_speed, w): rev (S, k) the slots'
            revolute joints (:attr:`SlotKinematics.rev`); stop (k,) the
            joints' stop (:func:`stop_steps`); lever_speed (S,) per slot
            its levers times w, m/s; w (k,) the joints' largest speeds in
            the hard interval (a row's bound: the step's turn, sum_j w_j
            dt, times its two slots' lever speeds).
        limits: (acceleration, jerk, period, rate): the limits (k,) each,
            dt (s) and the damper's rate (1/s).
        command: (v_last, h_lo, h_hi) (k,) each: the last command and the
            hard interval.
        sides: the pairs' probe spheres (:func:`plane_bends`).
    """
    A, b, dirs, points, slots, rounds, pair = rows
    rev, stop, lever_speed, w = motion
    acceleration, jerk, period, rate = limits
    v_last, h_lo, h_hi = command
    m, k = A.shape
    theta = _sum_as_numpy(w, k) * period
    # The least A v in [h_lo, h_hi] and twice the second-order bound, per row.
    worst, bound = np.empty(m), np.empty(m)
    low = np.empty(k)
    for i in range(m):
        for j in range(k):
            x, y = A[i, j] * h_lo[j], A[i, j] * h_hi[j]
            low[j] = np.nan if x != x or y != y else (x if x <= y else y)
        worst[i] = _sum_as_numpy(low, k)
        s0, s1 = slots[i, 0], slots[i, 1]  # a welded side (-1) does not move
        bound[i] = theta * ((0.0 if s0 < 0 else lever_speed[s0]) + (0.0 if s1 < 0 else lever_speed[s1]))
    # The rows' points carried to the stop (a round shape's sliding witness,
    # which the rounds bound per step, is not motion towards the pair).
    bend = _second_order(before[0], before[1], after[0], after[1], A, dirs, points, slots, np.zeros((m, 2)), rev, stop)
    # A pair of two moving bodies: its witness row closes as its supporting planes say, when more.
    bend = np.maximum(bend, plane_bends(before, after, A, dirs, points, slots, pair, stop, sides))
    # A row that opens now (closing speed <= 0) has no stop of its own on
    # the point mass, yet its first order may open it over the joints' stop
    # (f = A stop, less the step the point mass counts): its points'
    # motion there is f less the bend, so only the bend past f closes it.
    # Counted as closing, the whole bend made a row that opens (a turning
    # wrist's pair) ask to open as fast as the limits allow, which moved
    # its stop and its bend further still.
    for i in range(m):
        f, s_last = 0.0, 0.0
        for j in range(k):
            f += A[i, j] * stop[j]
            s_last -= A[i, j] * v_last[j]
        f += s_last * period
        if s_last <= 0.0 and f > 0.0:
            bend[i] = max(bend[i] - f, 0.0)
    out = brake_rows(A, b, rate, acceleration, jerk, period, v_last, h_lo, h_hi, bend)
    keep = np.flatnonzero(worst < out + bound)
    n = len(keep)
    kA, kb, kdirs, kpoints = np.empty((n, k)), np.empty(n), np.empty((n, 3)), np.empty((n, 2, 3))
    kslots, krounds, kpair = np.empty((n, 2), slots.dtype), np.empty((n, 2)), np.empty(n, pair.dtype)
    for r in range(n):
        i = keep[r]
        kA[r], kb[r], kdirs[r], kpoints[r] = A[i], out[i], dirs[i], points[i]
        kslots[r], krounds[r], kpair[r] = slots[i], rounds[i], pair[i]
    return kA, kb, kdirs, kpoints, kslots, krounds, kpair


@njit(cache=True)
def braking_lead(v, a_last, vmax, acceleration, jerk, period):
    """How far ahead the damper must make a pair's row for :func:`brake_rows`
    to stop it in time: (lead, s; ramp, s): a pair whose distance shrinks
    at most at ``speed`` (m/s) up to the next update, and whose closing
    acceleration is at most ``c`` (m/s^2), needs its row from the target
    distance plus (speed + ramp c) lead + speed dt on (v, a_last: the last
    command's velocity and acceleration).

    On the row (a_row = share sum_j |A_ij| a_j, j_row = share sum_j |A_ij|
    j_j, u_j = min(|v_j| + a_j dt, vmax_j), w_j = |a_last_j| + j_j dt): its
    closing acceleration c falls to -a_row at j_row within t <= c / j_row
    + a_row / j_row <= tau_w + tau (tau_w = max_j w_j / (share j_j), tau =
    max_j a_j / j_j), its speed growing meanwhile by at most c^2 / (2
    j_row) <= ramp c (ramp = tau_w / 2); from s' = speed + ramp c it stops
    within s'^2 / (2 a_row) <= s' (T + ramp max_j w_j / (share a_j)) / 2
    (T = max_j u_j / (share a_j)), plus a step's travel for the discrete
    update. The damper's own rule (closing at most rate x gap) needs no
    lead: a row that comes later than that rule would start asks for the
    slowest closing the limits allow (:func:`brake_rows`), and its stop
    alone keeps the margin. Joints without an acceleration limit do not
    count (a row that moves them is not braked); without a jerk limit there
    is no ramp."""
    T, tau, tau_w, ratio = 0.0, 0.0, 0.0, 0.0
    for j in range(len(v)):
        a = acceleration[j]
        if not (np.isfinite(a) and a > 0.0):
            continue
        u = min(abs(v[j]) + a * period, vmax[j])
        T = max(T, u / (ROW_DECELERATION_SHARE * a))
        if np.isfinite(jerk[j]) and jerk[j] > 0.0:
            w = abs(a_last[j]) + jerk[j] * period
            tau = max(tau, a / jerk[j])
            tau_w = max(tau_w, w / (ROW_DECELERATION_SHARE * jerk[j]))
            ratio = max(ratio, w / (ROW_DECELERATION_SHARE * a))
    ramp = 0.5 * tau_w
    lead = tau_w + tau + 0.5 * (T + ramp * ratio) + period
    return lead, ramp


@njit(cache=True)
def finish(q, v, lo, hi, h_lo, h_hi, limits, desired, period, sane, changed):
    """The update's command from the velocity v: (v clipped to the hard
    interval [h_lo, h_hi] (:func:`hard_interval`),
    q_next = q + v dt, whether v left the interval [lo, hi] (by > 1e-9),
    max_j |v_j| / limit_j over the finite limits, whether the command
    differs from the request by more than ``changed`` (or the input was
    not sane))."""
    k = len(q)
    out, q_next = np.zeros(k), np.zeros(k)
    exited, acted, ratio = False, not sane, 0.0
    for j in range(k):
        x = min(max(v[j], h_lo[j]), h_hi[j])
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
def outside(q: np.ndarray, lower: np.ndarray, upper: np.ndarray, tol: float) -> bool:
    """Whether q lies outside [lower, upper] by more than ``tol`` in some
    joint (q < lower - tol or q > upper + tol)."""
    for j in range(len(q)):
        if q[j] < lower[j] - tol or q[j] > upper[j] + tol:
            return True
    return False


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
LIMIT_ROWS, BOX_ROWS, DAMPER_ROWS, STOP_ROWS = 0, 1, 2, 3


@njit(cache=True)
def stack_rows(kinds, weights, prios, relaxed, pairs, v_lo, v_hi, lo, hi, dA, db, dpair, sA, sb):
    """The rows of the filter's own constraints, stacked block after block
    in one call: (A (m, k), b, priority, weight, second-order row (the damper
    row a row is; -1: none), relaxed per row, rows per block).

    Args:
        kinds: (n,) per block :data:`LIMIT_ROWS` (v_j >= v_lo_j and -v_j >=
            -v_hi_j over the joints with finite limits), :data:`BOX_ROWS`
            (v >= lo, -v >= -hi), :data:`DAMPER_ROWS` (the damper's rows
            of the pairs the block's ``pairs`` row holds) or
            :data:`STOP_ROWS` (the rows sA v >= sb, no second-order term).
        weights, prios, relaxed: (n,) the blocks' weight, priority and
            relaxation.
        pairs: (n, P) bools, per damper block its pairs.
        v_lo, v_hi, lo, hi: (k,) the hard velocity interval (the velocity,
            acceleration and jerk limits: :func:`hard_interval`) and the
            box's.
        dA, db, dpair: the damper's rows (m_d, k), (m_d,) and their pairs.
        sA, sb: the damper's rows over the stop (m_s, k), (m_s,)
            (:func:`~.stop_guard.stop_rows`).
    """
    n, k, md = len(kinds), len(lo), len(db)
    finite = 0
    for j in range(k):
        if np.isfinite(v_lo[j]) and np.isfinite(v_hi[j]):
            finite += 1
    counts = np.zeros(n, np.int64)
    for i in range(n):
        if kinds[i] == LIMIT_ROWS:
            counts[i] = 2 * finite
        elif kinds[i] == BOX_ROWS:
            counts[i] = 2 * k
        elif kinds[i] == STOP_ROWS:
            counts[i] = len(sb)
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
        elif kinds[i] == STOP_ROWS:
            for r in range(len(sb)):
                for j in range(k):
                    A[at + r, j] = sA[r, j]
                b[at + r] = sb[r]
        else:  # [I; -I] over the block's joints (the lower half's zeros negative, as -I's)
            half = counts[i] // 2
            r = at
            for j in range(k):
                if kinds[i] == BOX_ROWS or (np.isfinite(v_lo[j]) and np.isfinite(v_hi[j])):
                    for c in range(k):
                        A[r + half, c] = -0.0
                    A[r, j], A[r + half, j] = 1.0, -1.0
                    if kinds[i] == BOX_ROWS:
                        b[r], b[r + half] = lo[j], -hi[j]
                    else:
                        b[r], b[r + half] = v_lo[j], -v_hi[j]
                    r += 1
        for r in range(at, at + counts[i]):
            prio[r], weight[r], rel[r] = prios[i], weights[i], relaxed[i]
        at += counts[i]
    return A, b, prio, weight, so_row, rel, counts


@njit(cache=True)
def braked_rows_at(rows, before, base, kin, levers, rev, limits, command, sides):
    """:func:`braked_rows` with its motion worked out here, in the same
    call: the joints' stop (:func:`stop_steps`), the slots posed at the
    base plus that stop, the joints' largest speeds w in the hard
    interval and the slots' lever speeds ``levers`` (S, k) times w.

    Args:
        rows, before, sides: as :func:`braked_rows`.
        base: (k,) where the rows were made.
        kin: (chain, slot bodies, scratch R_WB, p_WB) to pose the slots
            (:meth:`SlotKinematics.compiled`).
        levers, rev: (S, k) the slots' levers and revolute joints.
        limits: (acceleration, jerk, period, rate).
        command: (v_last, a_last, h_lo, h_hi) (k,) each.
    """
    acceleration, jerk, period, rate = limits
    v_last, a_last, h_lo, h_hi = command
    stop = stop_steps(v_last, a_last, acceleration, jerk, period)
    chain, body, R_WB, p_WB = kin
    S, k = len(body), len(base)
    R1, o1 = np.zeros((S, 3, 3)), np.zeros((S, 3))
    _slot_poses(base + stop, chain, body, R_WB, p_WB, R1, o1)
    w = np.empty(k)
    for j in range(k):
        w[j] = max(abs(h_lo[j]), abs(h_hi[j]))
    speed = np.zeros(S)
    for s in range(S):
        for j in range(k):
            speed[s] += levers[s, j] * w[j]
    return braked_rows(rows, before, (R1, o1), (rev, stop, speed, w), limits, (v_last, h_lo, h_hi), sides)


@njit(cache=True)
def update_kinematics(base, kept, chain, pairs, command, limits, gains, skip):
    """The update's kinematics in one compiled call: the slots'
    poses and Jacobians at ``base`` (R, o, J_w, J_v), their levers, each
    pair's reach (the influence distance, or, braked, farther where its closing
    speed and acceleration by the next update need its row earlier to stop
    it in time: :func:`braking_lead`), and what the pairs' budgets kept at
    the last base still hold here, with the pairs to measure (those whose
    budget lies below their reach beyond the influence distance, and
    ``skip``'s second entry, those always measured).

    Args:
        base: (k,) where the rows are made.
        kept: (the last base (k,), the budgets kept there (P,)).
        chain: (chain, slot bodies, joint bodies, moves, scratch R_WB, p_WB).
        pairs: (radius (S,), pair bodies (P, 2), self pairs, only) of the damper.
        command: (v_last, a_last, dv, da): the last command and one update's
            change of the velocity and acceleration at the limits.
        limits: (vmax, acceleration, jerk, period, braked): without
            ``braked`` every reach is the influence distance.
        gains: (target, influence): the damper's distances.
        skip: (skip_far_pairs, always (P,) bools).

    Returns:
        (R, o, J_w, J_v, levers, reach, budget, measure).
    """
    chain_, body, joint_body, moves, R_WB, p_WB = chain
    radius, pair_bodies, self_pairs, only = pairs
    v_last, a_last, dv, da = command
    vmax, acceleration, jerk, period, braked = limits
    target, influence = gains
    skip_far, always = skip
    S, k, P = len(body), len(base), len(pair_bodies)
    R, o = np.zeros((S, 3, 3)), np.zeros((S, 3))
    _slot_poses(base, chain_, body, R_WB, p_WB, R, o)
    J_w, J_v = np.zeros((S, 3, k)), np.zeros((S, 3, k))
    _slot_jacobians(chain_, joint_body, moves, R_WB, p_WB, o, J_w, J_v)
    levers = _levers(J_w, J_v, radius)
    reach = np.full(P, influence)
    if braked:
        speed = _pair_speeds(J_w, J_v, radius, levers, pair_bodies, self_pairs, only, v_last, dv)
        closing = _pair_speeds(J_w, J_v, radius, levers, pair_bodies, self_pairs, only, a_last, da)
        lead, ramp = braking_lead(v_last, a_last, vmax, acceleration, jerk, period)
        for p in range(P):
            reach[p] = max(target + (speed[p] + ramp * closing[p]) * lead + speed[p] * period, influence)
    measure = np.ones(P, np.bool_)
    budget = np.full(P, -1.0)
    if skip_far:
        budget = _budget_moved(kept[0], base, chain_, body, R_WB, p_WB, radius, pair_bodies, kept[1])
        for p in range(P):
            measure[p] = budget[p] < reach[p] - influence or always[p]
    return R, o, J_w, J_v, levers, reach, budget, measure
