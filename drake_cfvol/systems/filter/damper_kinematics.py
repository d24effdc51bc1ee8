"""The damper's kinematics in compiled code (numba), for the filter's
update at the control rate: the moving bodies' poses and Jacobians by the
kernel's forward kinematics of the robot's chain (what Drake's
``EvalBodyPoseInWorld`` and ``CalcJacobianSpatialVelocity`` give, without
a plant context), each row's second-order term and how far a step can move
each body (:class:`SlotKinematics`).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from drake_cfvol.kernel import Chain
from drake_cfvol.kernel.kinematics import fk_into
from drake_cfvol.scene.arrays import chain_curvature, chain_reach, moved_by, robot_chain

__all__ = ["SlotKinematics"]


@njit(cache=True)
def _slot_poses(q, chain, body, R_WB, p_WB, R, o):
    """The chain's poses at q (into R_WB, p_WB), and the slots' bodies' (R, o)."""
    fk_into(q, chain, R_WB, p_WB)
    for s in range(body.shape[0]):
        R[s] = R_WB[body[s]]
        o[s] = p_WB[body[s]]


@njit(cache=True)
def _slot_jacobians(chain, joint_body, moves, R_WB, p_WB, o, J_w, J_v):
    """The slots' Jacobians at their origins o (the chain posed in R_WB,
    p_WB): per robot joint j moving slot s, a revolute joint's world axis a
    gives J_w[s, :, j] = a and J_v[s, :, j] = a x (o_s - its origin), a
    prismatic one J_v[s, :, j] = a."""
    parent, jtype, _, axis, R_PF, p_PF, _, _ = chain
    J_w[:] = 0.0
    J_v[:] = 0.0
    a = np.zeros(3)
    c = np.zeros(3)
    for j in range(joint_body.shape[0]):
        n = joint_body[j]
        if n < 0:
            continue
        par = parent[n]
        for r in range(3):  # R_WF axis and p_WF, F the joint's frame on its parent
            s0 = 0.0
            s1 = 0.0
            for i in range(3):
                if par >= 0:
                    rw = (
                        R_WB[par, r, 0] * R_PF[n, 0, i]
                        + R_WB[par, r, 1] * R_PF[n, 1, i]
                        + R_WB[par, r, 2] * R_PF[n, 2, i]
                    )
                else:
                    rw = R_PF[n, r, i]
                s0 += rw * axis[n, i]
            a[r] = s0
            if par >= 0:
                s1 = (
                    p_WB[par, r]
                    + R_WB[par, r, 0] * p_PF[n, 0]
                    + R_WB[par, r, 1] * p_PF[n, 1]
                    + R_WB[par, r, 2] * p_PF[n, 2]
                )
            else:
                s1 = p_PF[n, r]
            c[r] = s1
        for s in range(moves.shape[0]):
            if not moves[s, j]:
                continue
            if jtype[n] == 1:
                d0, d1, d2 = o[s, 0] - c[0], o[s, 1] - c[1], o[s, 2] - c[2]
                J_w[s, 0, j], J_w[s, 1, j], J_w[s, 2, j] = a[0], a[1], a[2]
                J_v[s, 0, j] = a[1] * d2 - a[2] * d1
                J_v[s, 1, j] = a[2] * d0 - a[0] * d2
                J_v[s, 2, j] = a[0] * d1 - a[1] * d0
            elif jtype[n] == 2:
                J_v[s, 0, j], J_v[s, 1, j], J_v[s, 2, j] = a[0], a[1], a[2]


@njit(cache=True)
def _second_order(R0, o0, R1, o1, A, dirs, points, slots, rounds, rev, dq):
    """Per row, max(0, A dq - the exact change of dirs . (P1 - P2)) + the
    round shapes' r theta^2 / 2 (see :meth:`SlotKinematics.second_order`)."""
    m, k = A.shape
    S = R0.shape[0]
    Rm = np.zeros((S, 3, 3))  # R1 R0^T
    tm = np.zeros((S, 3))  # o1 - Rm o0
    theta = np.zeros(S)
    for s in range(S):
        for r in range(3):
            for c in range(3):
                Rm[s, r, c] = R1[s, r, 0] * R0[s, c, 0] + R1[s, r, 1] * R0[s, c, 1] + R1[s, r, 2] * R0[s, c, 2]
        for r in range(3):
            tm[s, r] = o1[s, r] - (Rm[s, r, 0] * o0[s, 0] + Rm[s, r, 1] * o0[s, 1] + Rm[s, r, 2] * o0[s, 2])
        t = 0.0
        for j in range(k):
            t += rev[s, j] * abs(dq[j])
        theta[s] = t
    out = np.zeros(m)
    for i in range(m):
        lin = 0.0
        for j in range(k):
            lin += A[i, j] * dq[j]
        actual = 0.0
        bend = 0.0
        for e in range(2):
            s = slots[i, e]
            sign = 1.0 if e == 0 else -1.0
            if s < 0:
                continue  # welded: the point stays
            p = points[i, e]
            for r in range(3):
                moved = Rm[s, r, 0] * p[0] + Rm[s, r, 1] * p[1] + Rm[s, r, 2] * p[2] + tm[s, r] - p[r]
                actual += sign * dirs[i, r] * moved
            bend += rounds[i, e] * theta[s] * theta[s]
        out[i] = max(0.0, lin - actual) + 0.5 * bend
    return out


@njit(cache=True)
def _moved(R0, o0, R1, o1, radius):
    """Per slot, |o1 - o0| + turn x radius: how far any point within
    ``radius`` of the body's origin moved (the turn's angle from the
    relative rotation's skew part and trace)."""
    S = R0.shape[0]
    out = np.zeros(S + 1)  # the last: welded, never moves
    for s in range(S):
        tr = 0.0
        Rr = np.zeros((3, 3))  # R0^T R1
        for r in range(3):
            for c in range(3):
                Rr[r, c] = R0[s, 0, r] * R1[s, 0, c] + R0[s, 1, r] * R1[s, 1, c] + R0[s, 2, r] * R1[s, 2, c]
            tr += Rr[r, r]
        x, y, z = Rr[2, 1] - Rr[1, 2], Rr[0, 2] - Rr[2, 0], Rr[1, 0] - Rr[0, 1]
        turn = np.arctan2(0.5 * np.sqrt(x * x + y * y + z * z), 0.5 * (tr - 1.0))
        d = np.sqrt((o1[s, 0] - o0[s, 0]) ** 2 + (o1[s, 1] - o0[s, 1]) ** 2 + (o1[s, 2] - o0[s, 2]) ** 2)
        out[s] = d + turn * radius[s]
    return out


@njit(cache=True)
def _moved_between(q0, q1, chain, body, R_WB, p_WB, radius):
    """:func:`_moved` between the slots' poses at q0 and at q1."""
    S = body.shape[0]
    R0, o0, R1, o1 = np.zeros((S, 3, 3)), np.zeros((S, 3)), np.zeros((S, 3, 3)), np.zeros((S, 3))
    _slot_poses(q0, chain, body, R_WB, p_WB, R0, o0)
    _slot_poses(q1, chain, body, R_WB, p_WB, R1, o1)
    return _moved(R0, o0, R1, o1, radius)


@njit(cache=True)
def _budget_moved(q0, q1, chain, body, R_WB, p_WB, radius, pair_bodies, budget):
    """Per pair, ``budget`` less how far its two bodies (``pair_bodies``
    (P, 2) slots; -1 or S: welded, the last entry of
    :func:`_moved_between`, 0) moved between q0 and q1."""
    moved = _moved_between(q0, q1, chain, body, R_WB, p_WB, radius)
    welded = len(moved) - 1
    out = np.empty(len(budget))
    for n in range(len(budget)):
        a, b = pair_bodies[n, 0], pair_bodies[n, 1]
        out[n] = budget[n] - moved[a if a >= 0 else welded] - moved[b if b >= 0 else welded]
    return out


@njit(cache=True)
def _levers(J_w, J_v, radius):
    """(S, k): |J_v_j| + |J_w_j| r per slot and joint (see
    :meth:`~drake_cfvol.systems.filter.damper.VelocityDamper.levers`)."""
    S, _, k = J_v.shape
    out = np.zeros((S, k))
    for s in range(S):
        for j in range(k):
            lin = np.sqrt(J_v[s, 0, j] ** 2 + J_v[s, 1, j] ** 2 + J_v[s, 2, j] ** 2)
            ang = np.sqrt(J_w[s, 0, j] ** 2 + J_w[s, 1, j] ** 2 + J_w[s, 2, j] ** 2)
            out[s, j] = lin + ang * radius[s]
    return out


@njit(cache=True)
def _pair_speeds(J_w, J_v, radius, levers, pair_bodies, self_pairs, only, v, dv):
    """Per pair, the fastest its distance can shrink at v + e, |e_j| <=
    dv_j (see :meth:`~drake_cfvol.systems.filter.damper.VelocityDamper.pair_speeds`);
    ``only`` (2, n, k): per self pair, the joints that move its first side
    only, its second side only; ``levers`` (S, k): :func:`_levers`."""
    S, _, k = J_v.shape
    slot = np.zeros(S + 1)  # the last entry: a welded side
    for s in range(S):
        lv, av = np.zeros(3), np.zeros(3)
        for j in range(k):
            for r in range(3):
                lv[r] += J_v[s, r, j] * v[j]
                av[r] += J_w[s, r, j] * v[j]
        x = np.sqrt(lv[0] ** 2 + lv[1] ** 2 + lv[2] ** 2) + np.sqrt(av[0] ** 2 + av[1] ** 2 + av[2] ** 2) * radius[s]
        for j in range(k):
            x += levers[s, j] * dv[j]
        slot[s] = x
    P = len(pair_bodies)
    out = np.empty(P)
    for p in range(P):
        out[p] = slot[pair_bodies[p, 0]] + slot[pair_bodies[p, 1]]
    for n in range(len(self_pairs)):
        p = self_pairs[n]
        a, b = pair_bodies[p, 0], pair_bodies[p, 1]
        x = 0.0
        for j in range(k):
            w = abs(v[j]) + dv[j]
            if only[0, n, j]:
                x += levers[a, j] * w
            if only[1, n, j]:
                x += levers[b, j] * w
        out[p] = x
    return out


class SlotKinematics:
    """Forward kinematics of the damper's moving bodies ("slots") by the
    kernel's chain: poses and Jacobians at their origins, in the robot's k
    velocities, every other degree of freedom held where ``robot_slice``
    holds it.

    Args:
        plant: the finalized MultibodyPlant.
        robot: the robot's model instance.
        robot_slice: its :class:`~drake_cfvol.scene.robot.RobotSlice`.
        bodies: the moving bodies, one per slot (bodies of the robot's chain).
    """

    def __init__(self, plant, robot, robot_slice, bodies):
        order, self._chain, self._joint_body = robot_chain(plant, robot, robot_slice)
        index = {int(b.index()): n for n, b in enumerate(order)}
        self._body = np.array([index[int(b.index())] for b in bodies], np.int64)
        parent = self._chain.parent
        B, k = len(order), robot_slice.k
        # moves[s, j]: joint j's body is the slot's body or one of its ancestors.
        self._moves = np.zeros((len(bodies), k), np.bool_)
        for s, n in enumerate(self._body):
            while n >= 0:
                self._moves[s, self._joint_body == n] = True
                n = parent[n]
        self._R_WB, self._p_WB = np.zeros((B, 3, 3)), np.zeros((B, 3))
        self.k = k
        revolute = np.array([n >= 0 and self._chain.jtype[n] == 1 for n in self._joint_body])
        #: (S, k): 1 where a revolute joint turns the slot's body (a body
        #: turns by at most the sum of their |dq_j| in a step dq).
        self.rev = (self._moves & revolute).astype(float)

    def path_bounds(self, radius, lower, upper) -> tuple[np.ndarray, np.ndarray]:
        """Configuration-independent bounds for a path in joint space:
        (lever (S, k), curvature (S, k, k)). lever[s, j]: how fast any
        point within ``radius[s]`` of slot s's origin moves per unit of
        joint j's velocity (its greatest distance from a revolute joint's
        axis; 1 for a prismatic joint); curvature[s]: bounds on the
        points' second derivatives in the joints
        (:func:`~drake_cfvol.scene.arrays.chain_curvature`). ``lower``,
        ``upper``: the robot's position limits (a prismatic joint's
        travel lengthens the chain below it)."""
        chain, body = self._chain, self._body
        B = len(chain.parent)
        own = np.zeros(B)
        for s, n in enumerate(body):
            anchor = -chain.R_MB[n].T @ chain.p_MB[n]  # the joint frame's origin in the body's frame
            own[n] = max(own[n], float(np.linalg.norm(anchor)) + float(radius[s]))
        moved = moved_by(chain.parent, self._joint_body, B)
        reach = chain_reach(chain, self._joint_body, moved, own, np.asarray(lower, float), np.asarray(upper, float))
        revolute = np.array([n >= 0 and chain.jtype[n] == 1 for n in self._joint_body], bool)
        curvature = chain_curvature(reach, moved, revolute)
        lever = np.where(revolute[None, :], reach[:, body].T, 1.0) * self._moves
        return np.ascontiguousarray(lever), np.ascontiguousarray(curvature[:, :, body].transpose(2, 0, 1))

    @property
    def moves(self) -> np.ndarray:
        """(S, k) bools: joint j moves the slot's body (it is the body's joint or an ancestor's)."""
        return self._moves

    def compiled(self) -> tuple[Chain, np.ndarray, np.ndarray, np.ndarray]:
        """(chain, the slots' bodies in it, scratch poses): the arguments of
        the compiled code that poses the slots."""
        return self._chain, self._body, self._R_WB, self._p_WB

    def jacobian_args(self) -> tuple:
        """(chain, the slots' bodies, the joints' bodies, moves, scratch
        poses): the arguments of the compiled code that poses the slots and
        takes their Jacobians."""
        return self._chain, self._body, self._joint_body, self._moves, self._R_WB, self._p_WB

    def poses(self, q) -> tuple[np.ndarray, np.ndarray]:
        """The slots' rotations (S, 3, 3) and origins (S, 3) at q (k,)."""
        S = len(self._body)
        R, o = np.zeros((S, 3, 3)), np.zeros((S, 3))
        _slot_poses(np.asarray(q, float), self._chain, self._body, self._R_WB, self._p_WB, R, o)
        return R, o

    def poses_and_jacobians(self, q) -> tuple[np.ndarray, ...]:
        """(R, o, J_w, J_v) at q: the slots' poses and their Jacobians
        (S, 3, k) (angular; translational at the body's origin; world
        frame)."""
        R, o = self.poses(q)
        S = len(self._body)
        J_w, J_v = np.zeros((S, 3, self.k)), np.zeros((S, 3, self.k))
        _slot_jacobians(self._chain, self._joint_body, self._moves, self._R_WB, self._p_WB, o, J_w, J_v)
        return R, o, J_w, J_v

    @staticmethod
    def second_order(before, after, rows, rev, dq) -> np.ndarray:
        """Per row, how far the step dq falls short of the row's first-order
        change (see :meth:`~drake_cfvol.systems.filter.damper.VelocityDamper.second_order`),
        from the slots' poses ``before`` and ``after`` it."""
        return _second_order(
            before[0], before[1], after[0], after[1], rows.A, rows.dirs, rows.points, rows.slots, rows.rounds, rev, dq
        )

    def moved(self, q0, q1, radius) -> np.ndarray:
        """(S + 1,): per slot, how far any point within ``radius`` (S,) of
        its origin moved between the configurations q0 and q1, m (the last
        entry, for welded sides, 0)."""
        return _moved_between(np.asarray(q0, float), np.asarray(q1, float), *self.compiled()[:4], radius)

    def budget_moved(self, q0, q1, radius, pair_bodies, budget) -> np.ndarray:
        """Per pair, ``budget`` (P,) less how far each of its two bodies
        (``pair_bodies`` (P, 2) slots, S for a welded side) moved between
        q0 and q1 (:meth:`moved`), in one compiled call."""
        return _budget_moved(
            np.asarray(q0, float), np.asarray(q1, float), *self.compiled()[:4], radius, pair_bodies, budget
        )
