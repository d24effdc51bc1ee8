"""The safety filter's pairs whose rows cannot bind at an update, proven
from their last measurement and left unmeasured (compiled, numba). With
acceleration and jerk limits the filter makes rows for every pair within
its braking reach, and :func:`~.filter_kernel.braked_rows` drops all but a
handful, those that can bind at this update. A pair of one moving link
and a fixed obstacle whose rows would all be dropped need not be measured
at all. :func:`unbound_pairs` proves that from the pair's last
measurement; :func:`unbound_after` keeps what the next update needs.

Why it is sound, in short (docs/safety.md, "Cost"). Drake measured the
pair at distance d0 with normal n0; the link has moved by at most delta
since (the budget's chain of body displacements), so its distance now is
at least d0 - delta. Both shapes are convex (as Drake measures them), so
the normal now lies within an angle of n0 that grows with delta / d0 (the
two normals support nearby points of the pair's Minkowski difference).
Every row of the pair reads the normal now, at a point of the link's
shape (its witness or a probe), against a fixed point: its closing speed
over the hard interval is at most the cone's largest closing speed of the
corners of the link's box (the rows' terms are affine in the point, so
their largest value over the box is at a corner). The row's stop distance
(:func:`~.filter_kernel.stop_distance`, bounded in closed form: the jerk's
ramp, then the constant deceleration), its second-order bend over the
joints' stop (again at the box's corners) and the step's bound are then
bounded too. Where even these bounds leave the row below its damper rate
and stopping short of its margin, :func:`~.filter_kernel.braked_rows`
would drop it, so the pair is not measured.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["normal_cone", "stop_at_most", "unbound_after", "unbound_pairs"]


@njit(cache=True)
def normal_cone(d0: float, lower: float, tolerance: float = 0.0) -> float:
    """The largest angle between a convex pair's normal when Drake measured
    it at distance d0 and its normal now, when no point of either shape has
    moved by more than d0 - ``lower`` since, rad (inf: no bound). Drake's
    distances and normals taken as exact to ``tolerance`` (m).

    The pair's Minkowski difference C moved by at most delta = d0 - lower.
    Let x be C's point nearest the origin now, |x| <= d1 + eps, d1 Drake's
    distance now. The normal now n1 has n1 . x >= d1 - eps; the normal then
    n0 has n0 . x >= d0 - eps - delta (a point of C then lies within delta
    of x). d1 lies within [d0 - delta - 2 eps, d0 + delta + 2 eps]: each
    normal's angle from x is at most an arccos, and the two add up."""
    eps = tolerance
    if not lower > 3.0 * eps:
        return np.inf
    now = np.arccos(min((lower - 3.0 * eps) / (lower - eps), 1.0))
    then = np.arccos(min((lower - eps) / (2.0 * d0 - lower + 3.0 * eps), 1.0))
    return now + then


@njit(cache=True)
def stop_at_most(top: float, tau_w: float, tau: float, sigma: float, ratio: float, period: float) -> float:
    """A bound of a row's :func:`~.filter_kernel.stop_distance`, m: from
    closing speed s and acceleration alpha, braking at the row's
    deceleration a and jerk j. ``top`` >= s + alpha^2 / (2 j) bounds its
    speed on the jerk's ramp; ``tau_w`` >= alpha / j and ``tau`` >= a / j
    bound the ramp's steps, (alpha + a) / (j dt); ``sigma`` >= s / a and
    ``ratio`` >= alpha / a bound top / a. The discrete update covers at
    most top per step on the ramp, then top^2 / (2 a) at constant
    deceleration: top ((alpha + a) / j + dt) + top (top / a) / 2."""
    return top * (tau_w + tau + period) + 0.5 * top * (sigma + 0.5 * ratio * tau_w)


@njit(cache=True, inline="always")
def _posed(out, R, o, s, point):
    """out = R[s] point + o[s]: a point of slot s's body frame in the world."""
    for r in range(3):
        out[r] = o[s, r] + R[s, r, 0] * point[0] + R[s, r, 1] * point[1] + R[s, r, 2] * point[2]


@njit(cache=True, inline="always")
def _cone_closing(u, e, c_cone, s_cone):
    """The largest -n . u over the unit vectors n within the cone about e
    whose half-angle has cosine c_cone and sine s_cone."""
    norm = np.sqrt(u[0] * u[0] + u[1] * u[1] + u[2] * u[2])
    if norm == 0.0:
        return 0.0
    c = -(u[0] * e[0] + u[1] * e[1] + u[2] * e[2]) / norm  # cos of the angle between e and -u
    if c >= c_cone:
        return norm
    s = np.sqrt(max(1.0 - c * c, 0.0))
    return norm * (c * c_cone + s * s_cone)  # cos(angle - half-angle)


@njit(cache=True)
def unbound_pairs(may, measure, last, lower, pairs, kin, after, command, limits, gains):
    """Per pair, whether all its rows would be dropped by
    :func:`~.filter_kernel.braked_rows` at this update, proven without
    measuring it (module docstring; docs/safety.md, "Cost").

    Args:
        may: (P,) bools, the pairs that may be skipped (one link of the
            robot against a fixed convex obstacle).
        measure: (P,) bools, the pairs the budget would measure; only
            these are tried.
        last: (5 P,) per pair Drake's distance when last measured (NaN:
            none to go by), its normal nhat_BA_W then (3 P), the updates
            skipped since (:func:`unbound_after`).
        lower: (P,) the budget's lower bound of each distance now, m.
        pairs: (side (P,) the link's side 0 or 1, slot (P,) its body's
            slot, corners (P, 8, 3) its shape's box corners in the body
            frame).
        kin: (R, o, J_w, J_v), the slots' poses and Jacobians at the base.
        after: (R, o), the slots' poses at the base plus the joints' stop.
        command: (v_last, h_lo, h_hi, stop) (k,) each: the last command,
            the hard interval and the joints' stop
            (:func:`~.filter_kernel.stop_steps`).
        limits: (acceleration, jerk, levers): the limits the rows brake
            at (k,) each and the slots' levers (S, k)
            (:meth:`~.damper.VelocityDamper.levers`).
        gains: (period, rate, target, influence, tolerance, share, every):
            dt, the damper's rate, d_t, d_inf, Drake's tolerance (m), the
            row's share of the deceleration, and how many updates a pair
            goes at most without a measurement.
    """
    side, slot, corners = pairs
    R, o, J_w, J_v = kin
    R1, o1 = after
    v_last, h_lo, h_hi, stop = command
    acceleration, jerk, levers = limits
    h, rate, target, influence, eps, share, every = gains
    P, k = len(may), len(v_last)
    out = np.zeros(P, np.bool_)
    if not may.any():
        return out
    # Per joint: how far the hard interval reaches from the last command
    # (delta) and from rest (w); the ratios that bound a row's stop.
    delta, w = np.empty(k), np.empty(k)
    tau_w, tau, sigma, ratio, theta = 0.0, 0.0, 0.0, 0.0, 0.0
    for j in range(k):
        delta[j] = max(h_hi[j] - v_last[j], v_last[j] - h_lo[j])
        w[j] = max(abs(h_lo[j]), abs(h_hi[j]))
        theta += w[j]
        if np.isfinite(jerk[j]):
            tau_w = max(tau_w, delta[j] / h / (share * jerk[j]))
            tau = max(tau, acceleration[j] / jerk[j])
        sigma = max(sigma, w[j] / (share * acceleration[j]))
        ratio = max(ratio, delta[j] / h / (share * acceleration[j]))
    theta *= h
    J = np.empty((k, 3))
    x, u, moved = np.empty(3), np.empty(3), np.empty(3)
    margin = 1e-6  # m, m/s: the kernel's own rounding, many times over
    for p in range(P):
        d0 = last[p]
        if not (may[p] and measure[p] and d0 == d0 and last[4 * P + p] < every - 1.0):
            continue
        d_lb = lower[p]
        # Drake's distance now is at least d_lb - 2 eps: a pair skipped
        # lies beyond the influence distance, so min_distance below it is
        # always a measured pair's.
        if not d_lb >= influence + 2.0 * eps:
            continue
        gap = d_lb - 3.0 * eps - target  # every row's gap above the target, at least
        # The normal now within angle a of n0 (:func:`normal_cone`).
        a = normal_cone(d0, d_lb, eps)
        if not a < np.pi:
            continue
        c_cone, s_cone, tilt = np.cos(a), np.sin(a), 2.0 * np.sin(0.5 * a)
        sign = 1.0 if side[p] == 0 else -1.0  # e: from the obstacle towards the link
        e = sign * last[P + 3 * p : P + 3 * p + 3]
        s = slot[p]
        closing, accel, bend = -np.inf, 0.0, 0.0
        for c in range(8):
            # The corner in the world and its Jacobian J_j = J_v_j + J_w_j x (x - o).
            _posed(x, R, o, s, corners[p, c])
            rx, ry, rz = x[0] - o[s, 0], x[1] - o[s, 1], x[2] - o[s, 2]
            u[:] = 0.0
            spread, push = 0.0, 0.0
            for j in range(k):
                wx, wy, wz = J_w[s, 0, j], J_w[s, 1, j], J_w[s, 2, j]
                J[j, 0] = J_v[s, 0, j] + wy * rz - wz * ry
                J[j, 1] = J_v[s, 1, j] + wz * rx - wx * rz
                J[j, 2] = J_v[s, 2, j] + wx * ry - wy * rx
                norm = np.sqrt(J[j, 0] ** 2 + J[j, 1] ** 2 + J[j, 2] ** 2)
                for r in range(3):
                    u[r] += J[j, r] * v_last[j]
                spread += norm * delta[j]
                push += (abs(e[0] * J[j, 0] + e[1] * J[j, 1] + e[2] * J[j, 2]) + tilt * norm) * delta[j]
            closing = max(closing, _cone_closing(u, e, c_cone, s_cone) + spread)
            accel = max(accel, push / h)
            # The corner carried to the stop, against its first order J stop.
            _posed(moved, R1, o1, s, corners[p, c])
            for r in range(3):
                moved[r] -= x[r]
                for j in range(k):
                    moved[r] -= J[j, r] * stop[j]
            bend = max(bend, np.sqrt(moved[0] ** 2 + moved[1] ** 2 + moved[2] ** 2))
        lever = 0.0
        for j in range(k):
            lever += levers[s, j] * w[j]
        step = theta * lever  # braked_rows' bound of the rows' second-order term, as a rate
        # The row's stop distance (:func:`stop_at_most`): its speed on the
        # jerk's ramp at most s + alpha^2 / (2 j) <= s + alpha tau_w / 2.
        top = max(closing, 0.0) + 0.5 * accel * tau_w
        braking = stop_at_most(top, tau_w, tau, sigma, ratio, h)
        out[p] = closing + step + margin <= rate * gap and max(closing, 0.0) * h + braking + margin <= gap - bend
    return out


@njit(cache=True)
def unbound_after(skipped, pair, dirs, distances, last):
    """The last measurement each pair keeps for :func:`unbound_pairs` after
    an update, laid out as ``last`` (5 P,). A pair skipped keeps its own and
    counts one more update skipped; a pair with rows takes Drake's distance
    and its witness row's direction (its first row: the normal
    nhat_BA_W); any other is forgotten (NaN: measured before it is
    skipped again).

    Args:
        skipped: (P,) bools, the pairs :func:`unbound_pairs` skipped.
        pair, dirs: the damper's rows' pairs (m,) and directions (m, 3), as made.
        distances: (P,) the distances measured (NaN: not measured).
        last: (5 P,) before the update.
    """
    P = len(skipped)
    out = np.zeros(5 * P)
    out[:P] = np.nan
    for p in range(P):
        if skipped[p]:
            out[p] = last[p]
            out[P + 3 * p : P + 3 * p + 3] = last[P + 3 * p : P + 3 * p + 3]
            out[4 * P + p] = last[4 * P + p] + 1.0
    seen = np.zeros(P, np.bool_)
    for i in range(len(pair)):
        p = pair[i]
        if seen[p] or skipped[p]:
            continue
        seen[p] = True
        out[p] = distances[p]
        out[P + 3 * p : P + 3 * p + 3] = dirs[i]
    return out
