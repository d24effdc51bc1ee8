"""The stop-path guard in compiled code (numba): a command is kept only if
the robot, braking at its limits from the state it leaves, stops without
coming nearer the static scene than the margin allows.

The damper's rows brake each pair as a point mass along its own
direction. A turning link also closes its distance along a curved path,
and a pair's nearest features change on the way. The guard checks the
whole stop instead: the path that :meth:`SafetyFilter._brake` would
command, update by update, against each near pair's supporting plane
(the plane through the obstacle's witness point, normal to the pair's
closest-point direction, which the convex obstacle lies behind). The
robot side's probe spheres hold its shape's lowest points along any
direction, so their least distance from the plane bounds the pair's
distance from below wherever the link goes.

Between two checked updates the commanded position moves on the straight
line in joint space (the controller's interpolation). A body point then
leaves the chord between its two ends by at most (1/8) sum_jl C_jl
|dq_j| |dq_l| (C the chain's second-derivative bound), and a stretch of
several updates leaves the joints' chord by e_j, which moves a point by
at most sum_j lever_j e_j. So a stretch is kept when the least of its two
ends' plane distances, less those two terms, stays above the threshold;
else it is halved, down to single updates.

If the guard refuses a command, the filter commands the next step of the
stop it last accepted (braking from the last command, which is where that
stop went next): every commanded position lies on a checked stop.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from drake_cfvol.systems.filter.damper_kinematics import _slot_poses
from drake_cfvol.systems.filter.filter_kernel import (
    BRAKE_JERK_SHARE,
    _plane_gap,
    brake_step,
    carry_plane,
    witness_rows,
)

__all__ = ["SPLITS", "brake_path", "check_stop", "stop_guard", "stop_rows"]


@njit(cache=True, inline="always")
def _brake_joint(j, x, vj, aj, limits, max_steps, buf, record):
    """Joint j braked to rest from (x, vj, aj), as :func:`brake_path` does
    it: (x at rest, updates, path length, stopped within ``max_steps``,
    buf), its positions written into column j of ``buf`` (grown as it
    fills) where ``record``."""
    vmax, acceleration, jerk, period = limits
    ja = acceleration[j] * period
    # At full deceleration the step is v - ja (sign v) until the last
    # ramp (brake_step's a' reaches -acceleration while |v| >= ja +
    # acceleration^2 / (2 J)), as long as the velocity limit's jerk term
    # cannot bind: its room near v = 0, x0, is its least (hard_step).
    jj = jerk[j] * period * period
    x0 = jj * (np.sqrt(1.0 + 2.0 * vmax[j] / jj) - 1.0) if np.isfinite(jj) and np.isfinite(vmax[j]) else np.inf
    J = BRAKE_JERK_SHARE * jerk[j]
    steady = x0 >= ja and np.isfinite(J) and np.isfinite(ja) and ja > 0.0
    v_ramp = ja + acceleration[j] ** 2 / (2.0 * J) if steady else np.inf
    if record:
        buf[0, j] = x
    n, length, stopped = 0, 0.0, True
    while not (vj == 0.0 and aj == 0.0):
        if n == max_steps:
            stopped = False
            break
        sign = 1.0 if vj > 0.0 else -1.0
        run = 0
        if steady and sign * aj <= -acceleration[j] * (1.0 - 1e-9) and abs(vj) > v_ramp + 3.0 * ja:
            run = min(int((abs(vj) - v_ramp) / ja) - 2, max_steps - n)  # steps of v - ja, sparing the ramp
        for _ in range(max(run, 1)):
            if run > 0:
                w = vj - sign * ja
            else:
                w = brake_step(vmax[j], period, vj, aj, acceleration[j], jerk[j])
            aj = (w - vj) / period
            vj = w
            x = x + w * period
            length += abs(w) * period
            n += 1
            if record:
                if n >= buf.shape[0]:  # grow the buffer (the joints before keep their rows)
                    more = np.empty((2 * buf.shape[0], buf.shape[1]))
                    more[: buf.shape[0]] = buf
                    buf = more
                buf[n, j] = x
    return x, n, length, stopped, buf


@njit(cache=True)
def brake_path(q, v, a, vmax, acceleration, jerk, period, max_steps):
    """The positions (n + 1, k) the filter's brake commands from the state
    (q, v, a), q first: each update v' by :func:`~.filter_kernel.brake_step`,
    a' = (v' - v) / dt, q' = q + v' dt, as :meth:`SafetyFilter._brake`
    computes it, until every
    joint's velocity and acceleration are 0 (a joint that stops first
    stays). Also each joint's path length (k,) and whether the brake
    stopped within ``max_steps`` (else the path is cut there)."""
    k = len(q)
    buf = np.empty((64, k))
    length = np.zeros(k)
    steps = np.zeros(k, np.int64)
    stopped = True
    limits = (vmax, acceleration, jerk, period)
    for j in range(k):
        _, steps[j], length[j], done, buf = _brake_joint(j, q[j], v[j], a[j], limits, max_steps, buf, True)
        stopped = stopped and done
    n = steps.max() if k else 0
    out = np.empty((n + 1, k))
    for j in range(k):
        out[: steps[j] + 1, j] = buf[: steps[j] + 1, j]
        out[steps[j] + 1 :, j] = buf[steps[j], j]
    return out, length, stopped


@njit(cache=True, inline="always")
def _stop_reach(j, v_last, h_lo, h_hi, limits):
    """A bound of how far joint j moves over the step and the brake after
    it, from any velocity in its hard interval (m or rad): the acceleration
    ramped down at the jerk limit (the velocity growing meanwhile), then
    the velocity shed at the acceleration limit, both ramps and two updates
    at the peak speed. Inf without an acceleration limit's stop."""
    vmax, acceleration, jerk, period = limits
    w = max(abs(h_lo[j]), abs(h_hi[j]))
    acc, J = acceleration[j], BRAKE_JERK_SHARE * jerk[j]
    if not (np.isfinite(acc) and acc > 0.0):
        return np.inf
    if not (np.isfinite(J) and J > 0.0):
        return w * period + w * (w / acc + 2.0 * period)
    a = max(abs(h_lo[j] - v_last[j]), abs(h_hi[j] - v_last[j])) / period
    peak = w + a * a / (2.0 * J)
    return w * period + peak * a / J + peak * (2.0 * acc / J + peak / acc + 2.0 * period)


@njit(cache=True)
def stop_rows(rows, rate, slack, command, limits, max_steps):
    """The damper's rows over the guard's stop: per row i of a link and
    the static scene, its first-order closing over this update's step and
    the brake after it (:func:`brake_path`, each joint to rest at its own
    limits) at most its distance above the damper's target less ``slack``
    (a row already below that may close no further). The brake's
    displacement of a joint is linear in its velocity v over the hard
    interval to first order: its secant between the interval's ends,
    S_j(v) = S0_j + sigma_j v. So the row is linear in v: sum_j A_ij (dt +
    sigma_j) v_j >= -max(g_i + slack, 0) - sum_j A_ij (S0_j + e_j), g_i =
    -b_i / rate the row's distance above the damper's target, e the
    command's lead over where the rows were made. The damper's own
    rows brake each pair as a point mass along its direction; braked
    joint by joint, a joint that opens the row may stop before one that
    closes it, and the row closes on (the guard then brakes every joint:
    docs/safety.md, "The stop-path guard"). Only rows that can bind in the
    hard interval are returned; the brake is walked only where a row's
    bound of its closing (:func:`_stop_reach`) reaches past its gap.

    Args:
        rows: (A (m, k), b (m,), slots (m, 2), pair (m,)) the damper's
            rows, first order, unbraked, and (P,) per pair whether its
            geometry is static (not moving on its own).
        rate: the damper's rate, 1/s.
        slack: how far below the damper's target a row's stop may end, m.
        command: (v_last, h_lo, h_hi, lead) (k,) each: the last command,
            the hard interval and how far the command lies ahead of where
            the rows were made (q_c - q_m with a measured position: the
            guard brakes from the command).
        limits: (vmax, acceleration, jerk, period).
        max_steps: the brake's longest stop, updates (a stop cut there
            counts as far as it got; the guard refuses such a command).

    Returns:
        (A_s (n, k), b_s (n,), the rows' indices (n,)).
    """
    A, b, slots, pair, static = rows
    v_last, h_lo, h_hi, lead = command
    period = limits[3]
    m, k = A.shape
    reach = np.empty(k)
    for j in range(k):
        reach[j] = _stop_reach(j, v_last, h_lo, h_hi, limits)
    near = np.zeros(m, np.bool_)
    for i in range(m):
        if static[pair[i]] and (slots[i, 0] < 0 or slots[i, 1] < 0):
            bound = 0.0
            for j in range(k):
                if A[i, j] != 0.0:
                    bound += abs(A[i, j]) * (reach[j] + abs(lead[j]))
            near[i] = bound > max(-b[i] / rate + slack, 0.0)  # NaN: not near
    rows_near = np.flatnonzero(near)
    if len(rows_near) == 0:
        return np.zeros((0, k)), np.zeros(0), rows_near
    sigma, S0 = np.zeros(k), np.zeros(k)
    none = np.empty((1, k))
    for j in range(k):
        if not (np.isfinite(h_lo[j]) and np.isfinite(h_hi[j])):
            continue  # no limit to brake at: the joint stops with the step
        lo = _brake_joint(j, 0.0, h_lo[j], (h_lo[j] - v_last[j]) / period, limits, max_steps, none, False)[0]
        if h_hi[j] > h_lo[j]:
            hi = _brake_joint(j, 0.0, h_hi[j], (h_hi[j] - v_last[j]) / period, limits, max_steps, none, False)[0]
            sigma[j] = (hi - lo) / (h_hi[j] - h_lo[j])
        S0[j] = lo - sigma[j] * h_lo[j]
    n = len(rows_near)
    As, bs = np.zeros((n, k)), np.empty(n)
    keep = np.zeros(n, np.bool_)
    for r in range(n):
        i = rows_near[r]
        least, shift = 0.0, 0.0
        for j in range(k):
            if A[i, j] == 0.0:
                continue  # a joint that does not move the row (its interval may be unbounded)
            As[r, j] = A[i, j] * (period + sigma[j])
            shift += A[i, j] * (S0[j] + lead[j])
            least += min(As[r, j] * h_lo[j], As[r, j] * h_hi[j])
        bs[r] = -max(-b[i] / rate + slack, 0.0) - shift
        keep[r] = least < bs[r]
    idx = np.flatnonzero(keep)
    return As[idx], bs[idx], rows_near[idx]


@njit(cache=True)
def _planes(rows, skip, distances, margin, slack, counts, moves, rounds):
    """The guarded pairs' planes from the damper's rows (each pair's witness
    row first): per guarded pair its witness row, the side u whose probes
    meet the plane through the other side's witness, the threshold (the
    margin less ``slack``, or the pair's distance now where it is nearer:
    inside that band a pair may not come nearer at all, else it would
    creep in by the slack at every update; :func:`check_stop` lowers it
    to the plane's own bound there) and the joints that move side u relative to the plane's
    side (G, k). Guarded: pairs not in ``skip`` of a moving side and a
    welded one (a static obstacle: the plane stays), or of two links one
    of which is the other's ancestor in the chain (the plane is carried
    with the ancestor: only the joints between them move the pair), the
    ancestor's shape not round (``rounds`` (P, 2), its round radius)."""
    dirs, points, slots, pair = rows
    m, k = len(pair), moves.shape[1]
    keep = np.empty(m, np.int64)
    side = np.empty(m, np.int64)
    thr = np.empty(m)
    mask = np.zeros((m, k), np.bool_)
    g = 0
    for i in witness_rows(pair, len(skip)):
        p = pair[i]
        s0, s1 = slots[i, 0], slots[i, 1]
        if skip[p] or (s0 < 0 and s1 < 0):
            continue
        if s0 < 0 or s1 < 0:
            u = 0 if s0 >= 0 else 1
        else:
            below0, below1 = True, True  # moves[s1] within moves[s0]; moves[s0] within moves[s1]
            for j in range(k):
                below0 = below0 and (moves[s0, j] or not moves[s1, j])
                below1 = below1 and (moves[s1, j] or not moves[s0, j])
            if below1:
                u = 1  # side 0 is side 1's ancestor: its plane, side 1's probes
            elif below0:
                u = 0
            else:
                continue  # two branches: left to the rows
            if rounds[p, 1 - u] > 0.0:
                # A round ancestor's tangent plane bounds a link sliding
                # round it loosely (a wrist's tool round a capsule): left
                # to the rows.
                continue
        if counts[p, u] == 0:
            continue
        su, st = slots[i, u], slots[i, 1 - u]
        for j in range(k):
            mask[g, j] = moves[su, j] and not (st >= 0 and moves[st, j])
        keep[g], side[g] = i, u
        thr[g] = min(margin - slack, distances[p])
        g += 1
    return keep[:g], side[:g], thr[:g], mask[:g]


@njit(cache=True)
def _gaps(q, kin, before, rows, sides, keep, side, out):
    """Each guarded pair's least probe distance from its plane at q, into
    out: the plane through the witness of side 1 - u, carried with its
    body from its pose ``before`` (R0, o0, where the rows were made) where
    it moves."""
    chain, body, R_WB, p_WB, R, o = kin
    R0, o0 = before
    dirs, points, slots, pair = rows
    probes, counts, radii = sides[0], sides[1], sides[2]
    _slot_poses(q, chain, body, R_WB, p_WB, R, o)
    n1, w1 = np.zeros(3), np.zeros(3)
    for g in range(len(keep)):
        i, u = keep[g], side[g]
        p, t = pair[i], 1 - u
        sign = 1.0 if u == 0 else -1.0  # dirs point from side 1 towards side 0
        st = slots[i, t]
        if st < 0:
            n1[:] = dirs[i]
            w1[:] = points[i, t]
        else:
            carry_plane(dirs[i], points[i, t], R0, o0, R, o, st, n1, w1)
        out[g] = _plane_gap(n1, w1, sign, probes[p, u], counts[p, u], radii[p, u], R, o, slots[i, u])


#: How finely the guard splits an update's straight line when it must: into
#: 2^SPLITS pieces (each halving quarters the chord's bound).
SPLITS = 3


@njit(cache=True, inline="always")
def _at(path, x, scale, out):
    """The commanded path at sub-step x (``scale`` sub-steps per update: on
    the straight line between two updates), into out."""
    i, f = x // scale, (x % scale) / scale
    if f == 0.0:
        out[:] = path[i]
    else:
        for j in range(path.shape[1]):
            out[j] = path[i, j] + f * (path[i + 1, j] - path[i, j])


@njit(cache=True)
def stop_guard(path, kin, before, bounds, rows, sides, planes):
    """Whether the stop ``path`` (:func:`brake_path`) keeps every guarded
    pair above its threshold, and the first update (index into ``path``)
    found below it (-1: none). Stretches are halved down to pieces of an
    update's straight line (:data:`SPLITS`).

    Args:
        path: (n + 1, k) commanded positions, one per update.
        kin: (chain, slot bodies, scratch R_WB, p_WB, R, o) to pose the slots.
        before: (R0, o0), the slots' poses where the rows were made.
        bounds: (lever (S, k), curvature (S, k, k)): per slot, bounds on
            how fast its points move per unit of each joint and on their
            second derivatives (:meth:`SlotKinematics.path_bounds`).
        rows: (dirs, points, slots, pair) of the damper's rows.
        sides: the pairs' support spheres (:attr:`VelocityDamper.support_spheres`).
        planes: (keep, side, thr, mask) from :func:`_planes`.
    """
    keep, side, thr, mask = planes
    G = len(keep)
    n1, k = path.shape
    if G == 0:
        return True, -1
    lever, curv = bounds
    slots = rows[2]
    scale = 1 << SPLITS
    last = (n1 - 1) * scale
    gaps = np.empty((last + 1, G))
    done = np.zeros(last + 1, np.bool_)
    stack = np.empty((2 * (last + 1) + 8, 2), np.int64)
    stack[0, 0], stack[0, 1] = 0, last
    top = 1
    e = np.zeros(k)
    dq = np.zeros(k)
    qa, qb, qx = np.zeros(k), np.zeros(k), np.zeros(k)
    while top > 0:
        top -= 1
        a, b = stack[top, 0], stack[top, 1]
        for x in (a, b):
            if not done[x]:
                _at(path, x, scale, qx)
                _gaps(qx, kin, before, rows, sides, keep, side, gaps[x])
                done[x] = True
        # The joints' chord and how far the path leaves it in between (at
        # the updates inside: the path is straight between them).
        _at(path, a, scale, qa)
        _at(path, b, scale, qb)
        for j in range(k):
            dq[j] = qb[j] - qa[j]
            e[j] = 0.0
        for i in range(a // scale + 1, (b + scale - 1) // scale):
            t = (i * scale - a) / (b - a)
            for j in range(k):
                e[j] = max(e[j], abs(path[i, j] - (qa[j] + t * dq[j])))
        bad = -1
        for g in range(G):
            s = slots[keep[g], side[g]]
            dev = 0.0
            for j in range(k):
                if not mask[g, j]:
                    continue
                c = 0.0
                for m in range(k):
                    if mask[g, m]:
                        c += curv[s, j, m] * abs(dq[m])
                dev += lever[s, j] * e[j] + 0.125 * c * abs(dq[j])
            if min(gaps[a, g], gaps[b, g]) - dev < thr[g]:
                bad = g
                break
        if bad < 0:
            continue
        if b - a <= 1:
            x = a if gaps[a, bad] < thr[bad] else b
            return False, x // scale
        mid = (a + b) // 2
        stack[top, 0], stack[top, 1] = mid, b  # the later half after the earlier one
        stack[top + 1, 0], stack[top + 1, 1] = a, mid
        top += 2
    return True, -1


@njit(cache=True)
def check_stop(state, limits, kin, bounds, rows, sides, guarded, max_steps):
    """One compiled call: whether braking from ``state`` keeps the guarded
    pairs above their thresholds (:func:`brake_path`, :func:`stop_guard`):
    (ok, the first update found below (-1: none), the stop's updates).

    Args:
        state: (q, v, a), the command's position, velocity, acceleration.
        limits: (vmax, acceleration, jerk, period).
        kin: (chain, slot bodies, scratch R_WB, p_WB) to pose the slots,
            (R0, o0), their poses where the rows were made, and that
            configuration (k,).
        bounds: (lever, curvature, moves (S, k) bools) per slot.
        rows: (dirs, points, slots, pair) of the damper's rows.
        sides: the pairs' support spheres (centres, counts, radii) and
            each side's round radius (P, 2).
        guarded: (skip (P,) pairs not guarded, distances (P,) now,
            margin, slack) (:func:`_planes`).
        max_steps: a stop longer than this many updates is refused.
    """
    q, v, a = state
    vmax, acceleration, jerk, period = limits
    skip, distances, margin, slack = guarded
    lever, curv, moves = bounds
    keep, side, thr, mask = _planes(rows, skip, distances, margin, slack, sides[1], moves, sides[3])
    path, length, stopped = brake_path(q, v, a, vmax, acceleration, jerk, period, max_steps)
    n = len(path) - 1
    if not stopped:
        return False, n, n
    if len(keep) == 0:
        return True, -1, n
    (chain, body, R_WB, p_WB), before, base = kin
    S = body.shape[0]
    posed = (chain, body, R_WB, p_WB, np.zeros((S, 3, 3)), np.zeros((S, 3)))
    # The bound is below the distance where the support spheres bulge past
    # the shape (a cylinder's rim): no pair need keep more than its bound
    # where the rows were made.
    gaps = np.empty(len(keep))
    _gaps(base, posed, before, rows, sides, keep, side, gaps)
    for g in range(len(keep)):
        thr[g] = min(thr[g], gaps[g])
    # A pair whose probing side cannot move by the distance it has to spare
    # over the whole stop (its joints' path lengths times their levers) is
    # kept without walking the path.
    _gaps(q, posed, before, rows, sides, keep, side, gaps)
    near = np.zeros(len(keep), np.bool_)
    slots = rows[2]
    for g in range(len(keep)):
        s = slots[keep[g], side[g]]
        travel = 0.0
        for j in range(len(q)):
            if mask[g, j]:
                travel += lever[s, j] * length[j]
        near[g] = gaps[g] - travel < thr[g]
    if not near.any():
        return True, -1, n
    idx = np.flatnonzero(near)
    ok, first = stop_guard(path, posed, before, (lever, curv), rows, sides, (keep[idx], side[idx], thr[idx], mask[idx]))
    return ok, first, n
