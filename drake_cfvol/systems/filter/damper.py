"""The velocity damper's geometry for the runtime safety filter: which
geometry pairs it watches, the probe points of each shape, and at a
configuration the rows A v >= b of the damper (Faverjon and Tournassoud)
from the SceneGraph's signed distances, with the second-order term of each
row (:class:`VelocityDamper`).
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
from pydrake.geometry import Box, Capsule, Cylinder, Ellipsoid, Sphere

from drake_cfvol.scene.robot import RobotSlice, robot_bodies
from drake_cfvol.systems.filter.damper_kernel import (
    ball_radius,
    pair_rows,
    probes,
    round_radius,
    support_spheres,
)
from drake_cfvol.systems.filter.damper_kinematics import SlotKinematics, _levers, _pair_speeds
from drake_cfvol.systems.filter.damper_parts import BroadPhase, RowList, convex_arrays, drake_pair_rows, side_arrays
from drake_cfvol.systems.filter.distance_kernel import convex_rows
from drake_cfvol.systems.filter.filter_kernel import update_kinematics

__all__ = ["DamperRows", "VelocityDamper"]


class DamperRows(NamedTuple):
    """The damper's rows at one configuration (:meth:`SafetyFilter.damper_rows`).
    Row i reads dirs_i . (v_P1 - v_P2) for its two points P1, P2 (on the two
    geometries; a point on a welded body does not move)."""

    #: (m, k): each row's rate of its distance per unit joint velocity, m/rad (m/m).
    A: np.ndarray
    #: (m,): the rows' right-hand sides, A v >= b, m/s.
    b: np.ndarray
    #: (pairs,): every watched pair's signed distance, m; for a pair the
    #: broad phase found beyond the influence distance, a lower bound of it
    #: (>= the influence distance); for a pair GJK measured, its lower bound
    #: (:meth:`VelocityDamper.rows`' ``convex``); NaN: not looked at.
    distances: np.ndarray
    #: (m, 3): each row's direction (unit) in the world frame.
    dirs: np.ndarray
    #: (m, 2, 3): each row's two points in the world frame, m.
    points: np.ndarray
    #: (m, 2): the moving body slot of each point (-1: welded).
    slots: np.ndarray
    #: (m, 2): the radius of a round shape whose witness the point is, m
    #: (0: a vertex, a probe centre, or welded).
    rounds: np.ndarray
    #: (m,): the watched pair each row belongs to.
    pair: np.ndarray
    #: (pairs,): the pairs whose distance Drake measured at this update.
    measured: np.ndarray = np.zeros(0, bool)


class DynamicPairs:
    """A damper's pairs with geometry that moves on its own, and which of
    them to measure at an update (:meth:`mark`).

    Attributes:
        pairs: (n,) the pairs' indices among the damper's.
        ids: the moving geometries, each once.
    """

    def __init__(self, damper, dynamic_ids):
        dynamic = set(dynamic_ids)
        found = [
            (n, b if b in dynamic else a)
            for n, (a, b, _, _) in enumerate(damper._pairs)
            if a in dynamic or b in dynamic
        ]
        self.pairs = np.array([n for n, _ in found], np.int64)
        self.ids = list(dict.fromkeys(g for _, g in found))
        index = {g: i for i, g in enumerate(self.ids)}
        self._geometry = np.array([index[g] for _, g in found], np.int64)  # per pair: its moving geometry
        self._z = np.zeros(len(self.ids))

    def __len__(self) -> int:
        return len(self.pairs)

    def mark(self, query, measure: np.ndarray) -> dict:
        """Marks the pairs to be measured in ``measure`` ((pairs,) bools),
        except where their moving geometry is parked below
        :data:`~drake_cfvol.systems.columns.PARKED_Z` (unused): one pose
        look-up per geometry. Returns the poses looked up, by geometry id
        (for :meth:`VelocityDamper.rows`)."""
        if not len(self.pairs):
            return {}
        from drake_cfvol.systems.columns import PARKED_Z

        z, poses = self._z, {}
        for i, g in enumerate(self.ids):
            X = poses[g] = query.GetPoseInWorld(g)
            z[i] = X.translation()[2]
        measure[self.pairs] = (z > 0.5 * PARKED_Z)[self._geometry]
        return poses


class VelocityDamper:
    """The velocity damper's geometry: the watched pairs, their probe
    points, and at a configuration the damper's rows and their second-order
    term (see :class:`~drake_cfvol.systems.filter.safety.SafetyFilter`).

    Args:
        plant: the finalized MultibodyPlant (the robot's k joints, and any
            other degrees of freedom: held at their default in the scratch
            context the Jacobians are taken in).
        scene_graph: its SceneGraph.
        robot: the robot's model instance.
        obstacle_ids: the obstacles' geometry ids (None: every proximity
            geometry not on the robot).
        target_distance: d_t, m: the distance the rows aim at.
        influence_distance: d_inf, m: pairs farther apart do not constrain.
        rate: the damper's rate, 1/s.
    """

    def __init__(
        self, plant, scene_graph, robot, *, obstacle_ids, target_distance: float, influence_distance: float, rate: float
    ):
        self._slice = RobotSlice(plant, robot)
        self._robot = robot
        self.k = self._slice.k
        self.target_distance = float(target_distance)
        self.influence_distance = float(influence_distance)
        #: The distance within which the last :meth:`rows` made rows, m (the
        #: influence distance, or farther where braking needs it).
        self.reach = self.influence_distance
        self.rate = float(rate)
        self._plant = plant
        self._pairs = self._make_pairs(plant, scene_graph, robot, obstacle_ids)
        inspector = scene_graph.model_inspector()
        #: Geometries Drake's point query measures (ComputeSignedDistanceToPoint).
        self._point_query = {
            g: isinstance(inspector.GetShape(g), (Box, Capsule, Cylinder, Sphere, Ellipsoid))
            for a, b, _, _ in self._pairs
            for g in (a, b)
        }
        #: Per geometry, the radius of its round part (see second_order).
        self._round = {g: round_radius(inspector.GetShape(g)) for a, b, _, _ in self._pairs for g in (a, b)}
        # The moving bodies, the radius of a ball about each one's origin
        # holding its geometry, and each pair's bodies (-1: welded).
        bodies = sorted(
            {
                side[0].index(): side[0] for _, _, sa, sb in self._pairs for side in (sa, sb) if side[0] is not None
            }.items()
        )
        self._bodies = [b for _, b in bodies]
        self._slot = {i: n for n, (i, _) in enumerate(bodies)}
        self._body_radius = np.zeros(len(self._bodies))
        for a, b, sa, sb in self._pairs:
            for gid, side in ((a, sa), (b, sb)):
                if side[0] is not None:
                    n = self._slot[side[0].index()]
                    r = float(np.linalg.norm(side[1].translation())) + ball_radius(inspector.GetShape(gid))
                    self._body_radius[n] = max(self._body_radius[n], r)
        self._broad = BroadPhase(self, inspector)
        self._pair_bodies = np.array(
            [
                [
                    self._slot[sa[0].index()] if sa[0] is not None else -1,
                    self._slot[sb[0].index()] if sb[0] is not None else -1,
                ]
                for _, _, sa, sb in self._pairs
            ],
            dtype=int,
        ).reshape(-1, 2)
        self._kin = SlotKinematics(plant, robot, self._slice, self._bodies)
        #: Per pair and side, spheres that hold its shape's support, in its
        #: body's frame: centres (P, 2, n, 3), counts (P, 2), radii (P, 2, n)
        #: (none on a side no joint moves), for the stop-path guard.
        self.support_spheres = self._support_arrays(inspector)
        #: Per slot, (lever (S, k), curvature (S, k, k)): bounds on how fast
        #: its geometry's points move and bend along any joint path
        #: (:meth:`SlotKinematics.path_bounds`), for the stop-path guard.
        self.path_bounds = self._kin.path_bounds(
            self._body_radius,
            plant.GetPositionLowerLimits()[self._slice.qidx],
            plant.GetPositionUpperLimits()[self._slice.qidx],
        )
        # The pairs of two moving bodies, and per such pair the joints that
        # move one side and not the other (a joint moving both moves the
        # pair rigidly: its distance does not change).
        self._self_pairs = np.flatnonzero((self._pair_bodies >= 0).all(axis=1))
        moves = self._kin.moves
        one, two = self._pair_bodies[self._self_pairs, 0], self._pair_bodies[self._self_pairs, 1]
        self._only = np.array([moves[one] & ~moves[two], moves[two] & ~moves[one]]).reshape(2, len(one), self.k)
        self._sides, self._drake_rows = side_arrays(self, inspector)
        # Per pair side, its shape as the compiled distances read it (kind -1: none).
        self._convex = convex_arrays(self._pairs, inspector)
        #: (P,) bools: the pairs of two convex shapes measured in compiled
        #: code (a box, sphere, capsule, cylinder or mesh's hull each),
        #: neither moving on its own, whose rows the kernel makes (``convex``).
        self.convex_shapes = (self._convex[0] >= 0).all(axis=1) & ~self.self_moving & ~self._drake_rows
        # Each pair's two ids, for the per-pair loop of rows.
        self._pair_ids = [(a, b) for a, b, _, _ in self._pairs]

    def _support_arrays(self, inspector) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:attr:`support_spheres` from each moving side's shape."""
        found = []
        for a, b, sa, sb in self._pairs:
            for gid, side in ((a, sa), (b, sb)):
                if side[0] is None:
                    found.append((np.zeros((0, 3)), np.zeros(0)))
                    continue
                centres, radii = support_spheres(inspector.GetShape(gid))
                found.append((side[1].multiply(centres).T if centres.shape[1] else np.zeros((0, 3)), radii))
        P, most = len(self._pairs), max([len(r) for _, r in found] + [0])
        centres, counts, radii = np.zeros((P, 2, most, 3)), np.zeros((P, 2), np.int64), np.zeros((P, 2, most))
        for n, (c, r) in enumerate(found):
            p, j = divmod(n, 2)
            centres[p, j, : len(r)], radii[p, j, : len(r)], counts[p, j] = c, r, len(r)
        return centres, counts, radii

    def poses(self, q) -> tuple[np.ndarray, np.ndarray]:
        """The moving bodies' rotations (S, 3, 3) and origins (S, 3) at q
        (the kernel's forward kinematics)."""
        return self._kin.poses(q)

    @property
    def kinematics(self) -> SlotKinematics:
        """The moving bodies' kinematics (one slot per body)."""
        return self._kin

    @property
    def probe_spheres(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per pair and side, its probe spheres in its body's frame: centres
        (P, 2, n, 3), counts (P, 2) and radii (P, 2, n) (none on a side no
        joint moves)."""
        return self._sides[3], self._sides[4], self._sides[5]

    @property
    def round_radii(self) -> np.ndarray:
        """(P, 2): per pair and side, the radius of its shape's round part (0: none)."""
        return self._sides[8]

    @property
    def num_pairs(self) -> int:
        """How many geometry pairs the damper watches."""
        return len(self._pairs)

    def empty(self) -> DamperRows:
        """No rows, no distances measured."""
        return DamperRows(
            np.zeros((0, self.k)),
            np.zeros(0),
            np.full(len(self._pairs), np.nan),
            np.zeros((0, 3)),
            np.zeros((0, 2, 3)),
            np.full((0, 2), -1, dtype=int),
            np.zeros((0, 2)),
            np.zeros(0, int),
            np.zeros(len(self._pairs), bool),
        )

    @staticmethod
    def _make_pairs(plant, scene_graph, robot, obstacle_ids) -> list[tuple]:
        """The geometry pairs the damper watches: the robot's moving links
        against every obstacle, and the robot's own unfiltered pairs with at
        least one moving link. Each: (id_A, id_B, side_A, side_B), a side
        (body or None where no joint moves it, X_BG, probe centres in the
        body frame, probe radii)."""
        inspector = scene_graph.model_inspector()
        moved = set(plant.GetBodiesKinematicallyAffectedBy(list(plant.GetJointIndices(robot))))
        robot_ids, moving = [], set()
        for b in robot_bodies(plant, robot):
            ids = plant.GetCollisionGeometriesForBody(plant.get_body(b))
            robot_ids.extend(ids)
            if b in moved:
                moving.update(ids)
        robot_set = set(robot_ids)
        if obstacle_ids is None:
            obstacle_ids = [
                g
                for g in inspector.GetAllGeometryIds()
                if g not in robot_set and inspector.GetProximityProperties(g) is not None
            ]
        obstacles = sorted(set(obstacle_ids) - robot_set, key=lambda g: g.get_value())
        ordered = sorted(robot_set, key=lambda g: g.get_value())
        pairs = [(a, b) for a in ordered if a in moving for b in obstacles]
        pairs += [
            (a, b)
            for i, a in enumerate(ordered)
            for b in ordered[i + 1 :]
            if (a in moving or b in moving) and not inspector.CollisionFiltered(a, b)
        ]

        sides = {}

        def side(gid):
            """(moving body or None, X_BG, probe centres in the body frame
            (m x 3), probe radii)."""
            if gid not in sides:
                body = plant.GetBodyFromFrameId(inspector.GetFrameId(gid))
                X_BG = inspector.GetPoseInFrame(gid)
                if body is None or body.index() not in moved:
                    sides[gid] = (None, X_BG, np.zeros((0, 3)), np.zeros(0))
                else:
                    centres, radii = probes(inspector.GetShape(gid))
                    P_B = X_BG.multiply(centres).T if centres.shape[1] else np.zeros((0, 3))
                    sides[gid] = (body, X_BG, P_B, radii)
            return sides[gid]

        return [(a, b, side(a), side(b)) for a, b in pairs]

    def rows(self, query, q, measure=None, poses=None, *, reach=None, kin=None, convex=None) -> DamperRows:
        """The damper's rows at q (``query``: the SceneGraph's query object,
        posed at q): for
        the pairs closer than the influence distance, A (m x k) and b (m,)
        with the constraint A v >= b (first order; before the second-order
        term and the relaxation towards the nominal), every watched pair's
        signed distance, and the rows' points' lever arms for
        :meth:`second_order`. Each row is kept as its direction, its two
        points and their bodies; A is computed from them at the end, every
        row's Jacobian in one array operation.

        Args:
            measure: (pairs,) bools, the pairs to measure (default all);
                the others' distances are NaN.
            poses: {geometry id: its pose in the world} already looked up
                in ``query`` at this update (:meth:`DynamicPairs.mark`'s).
            reach: m, a scalar or per pair (P,) (>= the influence
                distance): rows for the pairs closer than this (a robot
                braking at its limits needs them from farther away:
                :func:`~.filter_kernel.update_kinematics`); None: the influence
                distance.
            kin: (R, o, J_w, J_v) at q, already computed
                (:meth:`SlotKinematics.poses_and_jacobians`).
            convex: (usable, hint): (P,) bools, pairs of :attr:`convex_shapes`
                measured in compiled code (:func:`~.distance_kernel.gjk_pairs`:
                two spheres or capsules exactly, others GJK's lower bound,
                within :data:`~.distance_kernel.GJK_TOLERANCE`) instead of by
                Drake, and (P, 3) each pair's last normal (GJK's first
                direction), updated in place; None: by Drake.
        """
        measured = np.zeros(len(self._pairs), bool)
        R, o, J_w, J_v = self._kin.poses_and_jacobians(q) if kin is None else kin
        P = len(self._pairs)
        pair_reach = np.full(P, self.influence_distance)
        if reach is not None:
            np.maximum(pair_reach, np.asarray(reach, float), out=pair_reach)  # a scalar or (P,), else ValueError
        self.reach = float(pair_reach.max()) if P else self.influence_distance
        # Broad phase: a pair whose bounding balls lie apart by its reach or
        # more is not measured (its distance is at least that).
        if measure is None:
            measure = np.ones(P, bool)
        dists, look = self._broad.near(query, R, o, np.asarray(measure, bool), pair_reach, poses)
        by_drake = look if convex is None else look[~convex[0][look]]
        near, dist, normal, witness, slow = self._drake_near(query, by_drake, dists, measured, pair_reach)
        parts = []
        if convex is not None and len(look) > len(by_drake):
            usable, hint = convex
            rows, failed = convex_rows(
                look,
                usable,
                hint,
                self._convex,
                pair_reach,
                dists,
                measured,
                (near, dist, normal, witness),
                self._sides,
                (R, o, J_w, J_v),
                (self.reach, self.rate, self.target_distance),
                self._broad.box_R,
                self._broad.box_p,
            )
            parts.append(rows[:2] + (None,) + rows[2:])
            if len(failed):  # touching, or GJK did not converge: Drake's
                near, dist, normal, witness, more = self._drake_near(query, failed, dists, measured, pair_reach)
                slow += more
            else:
                near = near[:0]
        if len(near):
            parts.append(self._kernel_rows(near, dist, normal, witness, R, o, J_w, J_v))
        if slow:
            out = RowList()
            for index, pair in slow:
                drake_pair_rows(self, query, index, pair, R, o, out)
            parts.append(out.build(o, J_w, J_v, self.k))
        if not parts:
            return self.empty()._replace(distances=dists, measured=measured)
        if len(parts) == 1:
            A, b, _, dirs, points, slots, rounds, pair = parts[0]
        else:
            A, b, dirs, points, slots, rounds, pair = [np.concatenate(x) for x in zip(*(p[:2] + p[3:8] for p in parts))]
        return DamperRows(A, b, dists, dirs, points, slots, rounds, pair, measured)

    def _drake_near(self, query, look, dists, measured, reach) -> tuple:
        """Drake's query of the pairs ``look`` (their distances into
        ``dists``, ``measured`` set): (the pairs nearer than their reach
        whose rows the kernel makes, their distances, nhat_BA_W and
        witnesses p_ACa, p_BCb; the near pairs whose rows need Drake's point
        queries, as (index, Drake's result))."""
        if not len(look):
            return np.zeros(0, np.int64), np.zeros(0), np.zeros((0, 3)), np.zeros((0, 2, 3)), []
        measured[look] = True
        # Plain lists in the loop: a NumPy scalar or row access per pair cost
        # more than Drake's query.
        near: list[int] = []
        found: list[Any] = []
        near_distance: list[float] = []
        slow: list[tuple[int, Any]] = []
        ids, drake_rows, limit = self._pair_ids, self._drake_rows, reach
        measured_distance = query.ComputeSignedDistancePairClosestPoints
        for index in look.tolist():
            try:
                pair = measured_distance(*ids[index])
            except RuntimeError:  # a shape pair Drake cannot measure: not watched
                continue
            d = dists[index] = pair.distance
            if d < limit[index]:
                if drake_rows[index]:
                    slow.append((index, pair))
                    continue
                near.append(index)
                found.append(pair)
                near_distance.append(d)
        # The witnesses' arrays built once (one array of the three vectors per
        # pair: the property reads cost most).
        vectors = np.array([x for pair in found for x in (pair.nhat_BA_W, pair.p_ACa, pair.p_BCb)], float)
        vectors = vectors.reshape(-1, 3, 3)
        normal, witness = np.ascontiguousarray(vectors[:, 0]), np.ascontiguousarray(vectors[:, 1:])
        return np.array(near, np.int64), np.array(near_distance, float), normal, witness, slow

    def _kernel_rows(self, near, dist, normal, witness, R, o, J_w, J_v) -> tuple:
        """The rows of the ``near`` pairs (indices; Drake's distances,
        normals nhat_BA_W and witnesses p_ACa, p_BCb) by
        :func:`~.damper_kernel.pair_rows`: (A, b, None, dirs, points, slots,
        rounds, pair). A side on no moving body of the robot is posed as the
        broad phase posed it at this update (fixed, or by the query)."""
        A, b, dirs, points, slots, rounds, owner = pair_rows(
            (np.asarray(near, np.int64), dist, normal, witness, self._broad.box_R, self._broad.box_p),
            self._sides,
            (R, o, J_w, J_v),
            (self.reach, self.rate, self.target_distance),
        )
        return A, b, None, dirs, points, slots, rounds, owner

    def second_order(self, q, rows: DamperRows, dq: np.ndarray) -> np.ndarray:
        """Per row, how far a joint step ``dq`` (k,) from q falls short of the row's first-order change
        A dq, m (>= 0): the rows' points are carried to q + dq by the bodies'
        poses there (forward kinematics), so the change of dirs . (P1 - P2)
        is exact for body-fixed points; a round shape's witness point
        (radius r) may slide on it as the body turns by at most theta (the
        sum of |dq_j| over the revolute joints that move it), which the term
        r theta^2 / 2 covers. Against a static obstacle the row is the plane
        through the obstacle's witness, so this bounds the distance at
        q + dq; between two moving links it is an estimate (the other link's
        turn tilts its surface too)."""
        dq = np.asarray(dq, float)
        if not len(rows.b):
            return np.zeros(0)
        return self._kin.second_order(self.poses(q), self.poses(q + dq), rows, self._kin.rev, dq)

    def budget_moved(self, q0, q1, budget):
        """Each pair's distance beyond the influence distance that is still
        certain at q1, known to be ``budget`` (P,) at q0: less how far the
        robot's motion from q0 to q1 can have moved the pair's bodies, every
        point of a body's geometry within its radius r of the body's origin
        o: |o' - o| + theta r for a turn by theta (the distance at q1 is
        bounded by the poses at both ends, whatever the path between).
        Negative: measure it. (Geometry that moves on its own, see
        :attr:`self_moving`, is not covered.)"""
        return self._kin.budget_moved(q0, q1, self._body_radius, self._pair_bodies, np.asarray(budget, float))

    def update_kinematics(self, base, kept, command, limits, skip) -> tuple:
        """An update's kinematics at ``base`` in one compiled call
        (:func:`~.filter_kernel.update_kinematics`): (R, o, J_w, J_v,
        :meth:`levers`, each pair's reach (farther than the influence
        distance where braking at the limits needs it), the budgets
        ``kept`` = (last base, budgets there) still hold here
        (:meth:`budget_moved`), the pairs to measure). ``command``: (v_last,
        a_last, one update's velocity and acceleration change at the
        limits); ``limits``: (vmax, acceleration, jerk, period, braked);
        ``skip``: (skip far pairs, the pairs always measured)."""
        return update_kinematics(
            np.asarray(base, float),
            kept,
            self._kin.jacobian_args(),
            (self._body_radius, self._pair_bodies, self._self_pairs, self._only),
            command,
            limits,
            (self.target_distance, self.influence_distance),
            skip,
        )

    def levers(self, J_w, J_v) -> np.ndarray:
        """(S, k): per slot and joint, the fastest any point of the body's
        geometry moves per unit of the joint's velocity, |J_v_j| + |J_w_j|
        r (r the body's radius about its origin; the Jacobians at the
        origins, :meth:`SlotKinematics.poses_and_jacobians`)."""
        return _levers(J_w, J_v, self._body_radius)

    def pair_speeds(self, J_w, J_v, v, dv, levers=None) -> np.ndarray:
        """(P,): per pair, the fastest its distance can shrink at the joint
        velocity v + e for any |e_j| <= dv_j, m/s. Against a side that
        does not move: its body's fastest point, |J_v v| + |J_w v| r plus
        sum_j (|J_v_j| + |J_w_j| r) dv_j (r its radius about its origin;
        the Jacobians at the origins, :meth:`SlotKinematics.poses_and_jacobians`).
        Between two moving bodies: sum_j (|v_j| + dv_j) times the lever
        (:meth:`levers`) of the side joint j moves, over the joints that
        move only one side. Geometry that moves on its own
        (:attr:`self_moving`) adds its own speed, not counted. ``levers``:
        :meth:`levers` at these Jacobians, if already computed."""
        if levers is None:
            levers = self.levers(J_w, J_v)
        return _pair_speeds(
            J_w,
            J_v,
            self._body_radius,
            levers,
            self._pair_bodies,
            self._self_pairs,
            self._only,
            np.asarray(v, float),
            dv,
        )

    @property
    def pair_bodies(self) -> np.ndarray:
        """(P, 2): per pair and side, its moving body's slot (-1: none moves it)."""
        return self._pair_bodies

    @property
    def self_moving(self) -> np.ndarray:
        """(P,) bools: the pairs with geometry that moves other than with the
        robot's joints (a free body, a gripper's finger, perceived geometry)."""
        out = np.zeros(len(self._pairs), bool)
        out[[n for n, _, _ in self._broad.query_posed]] = True
        return out
