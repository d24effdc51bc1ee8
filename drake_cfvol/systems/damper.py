"""The velocity damper's geometry for the runtime safety filter: which
geometry pairs it watches, the probe points of each shape, and at a
configuration the rows A v >= b of the damper (Faverjon and Tournassoud)
from the SceneGraph's signed distances, with the second-order term of each
row (:class:`VelocityDamper`).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from pydrake.geometry import Box, Capsule, Convex, Cylinder, Ellipsoid, Mesh, Sphere
from pydrake.multibody.tree import JacobianWrtVariable

from drake_cfvol.scene.robot import RobotSlice, robot_bodies

__all__ = ["DamperRows", "VelocityDamper"]

#: The Levi-Civita symbol arranged so that (r @ _EPS).reshape(3, 3) is the
#: cross-product matrix [r]x of a vector r.
_EPS = np.zeros((3, 3, 3))
_EPS[0, 1, 2] = _EPS[1, 2, 0] = _EPS[2, 0, 1] = 1.0
_EPS[0, 2, 1] = _EPS[2, 1, 0] = _EPS[1, 0, 2] = -1.0
_EPS = _EPS.transpose(1, 0, 2).reshape(3, 9)

#: Points sampled on each rim of a cylinder (probe points).
_RIM_POINTS = 12


def _probes(shape) -> tuple[np.ndarray, np.ndarray]:
    """Probe spheres of a shape, in its frame: centres (3 x m) and radii
    (m,). Their lowest points along a direction reach the shape's support
    there wherever the support set may be flat (a face, an edge, a rim, a
    capsule's side), so rows at them see a face tilt towards an obstacle;
    smooth, strictly convex shapes (sphere, ellipsoid) need none."""
    if isinstance(shape, Box):
        half = np.array([shape.width(), shape.depth(), shape.height()]) / 2
        corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) * half
        return corners.T, np.zeros(8)
    if isinstance(shape, Cylinder):
        a = np.linspace(0.0, 2 * np.pi, _RIM_POINTS, endpoint=False)
        ring = np.stack([shape.radius() * np.cos(a), shape.radius() * np.sin(a)], axis=1)
        rims = [np.column_stack([ring, np.full(len(a), z)]) for z in (-shape.length() / 2, shape.length() / 2)]
        return np.concatenate(rims).T, np.zeros(2 * _RIM_POINTS)
    if isinstance(shape, Capsule):
        ends = np.array([[0.0, 0.0, -shape.length() / 2], [0.0, 0.0, shape.length() / 2]])
        return ends.T, np.full(2, shape.radius())
    if isinstance(shape, (Convex, Mesh)):
        try:
            hull = shape.GetConvexHull()
            pts = np.array([hull.vertex(i) for i in range(hull.num_vertices())], float).reshape(-1, 3)
            return pts.T, np.zeros(len(pts))
        except Exception:  # no hull: the witness row alone
            return np.zeros((3, 0)), np.zeros(0)
    return np.zeros((3, 0)), np.zeros(0)  # smooth (sphere, ellipsoid): the witness row suffices


def _radius(shape) -> float:
    """The radius of a ball about the shape's frame origin that holds the
    shape, m (inf if unknown)."""
    if isinstance(shape, Box):
        return 0.5 * float(np.linalg.norm([shape.width(), shape.depth(), shape.height()]))
    if isinstance(shape, Sphere):
        return shape.radius()
    if isinstance(shape, Capsule):
        return shape.radius() + shape.length() / 2
    if isinstance(shape, Cylinder):
        return float(np.hypot(shape.radius(), shape.length() / 2))
    if isinstance(shape, Ellipsoid):
        return max(shape.a(), shape.b(), shape.c())
    if isinstance(shape, (Convex, Mesh)):
        try:
            hull = shape.GetConvexHull()
            return max(float(np.linalg.norm(hull.vertex(i))) for i in range(hull.num_vertices()))
        except Exception:
            return np.inf
    return np.inf


class DamperRows(NamedTuple):
    """The damper's rows at one configuration (:meth:`SafetyFilter.damper_rows`).
    Row i reads dirs_i . (v_P1 - v_P2) for its two points P1, P2 (on the two
    geometries; a point on a welded body does not move)."""

    #: (m, k): each row's rate of its distance per unit joint velocity, m/rad (m/m).
    A: np.ndarray
    #: (m,): the rows' right-hand sides, A v >= b, m/s.
    b: np.ndarray
    #: (pairs,): every watched pair's signed distance, m (NaN: not measured).
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


def dynamic_pairs(damper, dynamic_ids) -> list[tuple]:
    """(pair index, its moving geometry) of a damper's pairs with geometry
    that moves on its own."""
    dynamic = set(dynamic_ids)
    return [(n, b if b in dynamic else a) for n, (a, b, _, _) in enumerate(damper._pairs)
            if a in dynamic or b in dynamic]


def measure_dynamic(dynamic: list, query, measure: np.ndarray) -> None:
    """Marks the pairs with moving geometry to be measured, except where it
    is parked below :data:`~drake_cfvol.systems.columns.PARKED_Z` (unused):
    one pose look-up per geometry."""
    from drake_cfvol.systems.columns import PARKED_Z

    if not dynamic:
        return
    pairs, gids = zip(*dynamic)
    ids = list(dict.fromkeys(gids))
    active = {g: query.GetPoseInWorld(g).translation()[2] > 0.5 * PARKED_Z for g in ids}
    measure[list(pairs)] = [active[g] for g in gids]


def _round_radius(shape) -> float:
    """The radius of the round part of a shape, m: its witness point's
    lever arm grows by it (0 for a polytope, whose probes are its
    vertices)."""
    if isinstance(shape, (Sphere, Capsule, Cylinder)):
        return float(shape.radius())
    if isinstance(shape, Ellipsoid):
        return float(max(shape.a(), shape.b(), shape.c()))
    return 0.0


class VelocityDamper:
    """The velocity damper's geometry: the watched pairs, their probe
    points, and at a configuration the damper's rows and their second-order
    term (see :class:`~drake_cfvol.systems.safety.SafetyFilter`).

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

    def __init__(self, plant, scene_graph, robot, *, obstacle_ids, target_distance: float,
                 influence_distance: float, rate: float):
        self._slice = RobotSlice(plant, robot)
        self.k = self._slice.k
        self.target_distance = float(target_distance)
        self.influence_distance = float(influence_distance)
        self.rate = float(rate)
        self._plant = plant
        self._pairs = self._make_pairs(plant, scene_graph, robot, obstacle_ids)
        inspector = scene_graph.model_inspector()
        #: Geometries Drake's point query measures (ComputeSignedDistanceToPoint).
        self._point_query = {g: isinstance(inspector.GetShape(g), (Box, Capsule, Cylinder, Sphere, Ellipsoid))
                             for a, b, _, _ in self._pairs for g in (a, b)}
        #: Per geometry, the radius of its round part (see second_order).
        self._round = {g: _round_radius(inspector.GetShape(g)) for a, b, _, _ in self._pairs for g in (a, b)}
        # The moving bodies, the radius of a ball about each one's origin
        # holding its geometry, and each pair's bodies (-1: welded).
        bodies = sorted({side[0].index(): side[0] for _, _, sa, sb in self._pairs for side in (sa, sb)
                         if side[0] is not None}.items())
        self._bodies = [b for _, b in bodies]
        self._slot = {i: n for n, (i, _) in enumerate(bodies)}
        self._body_radius = np.zeros(len(self._bodies))
        for a, b, sa, sb in self._pairs:
            for gid, side in ((a, sa), (b, sb)):
                if side[0] is not None:
                    n = self._slot[side[0].index()]
                    r = float(np.linalg.norm(side[1].translation())) + _radius(inspector.GetShape(gid))
                    self._body_radius[n] = max(self._body_radius[n], r)
        self._pair_bodies = np.array([[self._slot[sa[0].index()] if sa[0] is not None else -1,
                                       self._slot[sb[0].index()] if sb[0] is not None else -1]
                                      for _, _, sa, sb in self._pairs], dtype=int).reshape(-1, 2)
        self._chain_masks(plant, robot)

    @property
    def num_pairs(self) -> int:
        """How many geometry pairs the damper watches."""
        return len(self._pairs)

    def empty(self) -> DamperRows:
        """No rows, no distances measured."""
        return DamperRows(np.zeros((0, self.k)), np.zeros(0), np.full(len(self._pairs), np.nan), np.zeros((0, 3)),
                          np.zeros((0, 2, 3)), np.full((0, 2), -1, dtype=int), np.zeros((0, 2)), np.zeros(0, int))

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
            obstacle_ids = [g for g in inspector.GetAllGeometryIds() if g not in robot_set
                            and inspector.GetProximityProperties(g) is not None]
        obstacles = sorted(set(obstacle_ids) - robot_set, key=lambda g: g.get_value())
        ordered = sorted(robot_set, key=lambda g: g.get_value())
        pairs = [(a, b) for a in ordered if a in moving for b in obstacles]
        pairs += [(a, b) for i, a in enumerate(ordered) for b in ordered[i + 1:]
                  if (a in moving or b in moving) and not inspector.CollisionFiltered(a, b)]

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
                    centres, radii = _probes(inspector.GetShape(gid))
                    P_B = X_BG.multiply(centres).T if centres.shape[1] else np.zeros((0, 3))
                    sides[gid] = (body, X_BG, P_B, radii)
            return sides[gid]

        return [(a, b, side(a), side(b)) for a, b in pairs]

    def _chain_masks(self, plant, robot) -> None:
        """Per moving body slot, the revolute joints that turn it (``_rev``,
        (S, k) 0/1, by velocity index): a body turns by at most the sum of
        their |dq_j| in a step dq."""
        self._rev = np.zeros((len(self._bodies), self.k))
        for j in plant.GetJointIndices(robot):
            joint = plant.get_joint(j)
            if joint.num_velocities() != 1 or joint.type_name() != "revolute":
                continue
            moved = set(plant.GetBodiesKinematicallyAffectedBy([j]))
            for n, body in enumerate(self._bodies):
                if body.index() in moved:
                    self._rev[n, self._slice.velocity_index(joint)] = 1.0

    def rows(self, pctx, query, q, measure=None) -> DamperRows:
        """The damper's rows at q (``pctx``: a plant context to pose; ``query``:
        the SceneGraph's query object, posed at q): for
        the pairs closer than the influence distance, A (m x k) and b (m,)
        with the constraint A v >= b (first order; before the second-order
        term and the relaxation towards the nominal), every watched pair's
        signed distance, and the rows' points' lever arms for
        :meth:`second_order`.

        Args:
            measure: (pairs,) bools, the pairs to measure (default all);
                the others' distances are NaN.
        """
        plant = self._plant
        self._slice.set_positions(pctx, q)
        world = plant.world_frame()
        rows, rhs = [], []
        ends = []  # per row: ((slot, p_W) of side A, of side B); slot -1: welded
        dists = np.full(len(self._pairs), np.nan)
        owner = []  # per row: its pair
        kin = {}  # per moving body at q: (R_WB, p_WBo, J_w, J_v), its Jacobian at Bo

        def points(side, P_B):
            """World positions (m x 3) and translational Jacobians
            (m x 3 x k) of points given in a moving body's frame."""
            body = side[0]
            if body.index() not in kin:
                X_WB = plant.EvalBodyPoseInWorld(pctx, body)
                J = self._slice.columns(plant.CalcJacobianSpatialVelocity(
                    pctx, JacobianWrtVariable.kV, body.body_frame(), np.zeros(3), world, world))
                kin[body.index()] = (X_WB.rotation().matrix(), X_WB.translation(), J[:3], J[3:])
            R, o, J_w, J_v = kin[body.index()]
            # v_P = v_Bo + w x r, r = p_P - p_Bo: J_P = J_v - [r]x J_w, with
            # [r]x = r . eps (the Levi-Civita symbol) for all points at once.
            r = P_B @ R.T
            p_W = r + o
            J = J_v[None] - (r @ _EPS).reshape(-1, 3, 3) @ J_w
            return p_W, J

        def witness(side, p_GC, X_WG, probes: bool = False):
            """A witness point (in the geometry frame G, posed at X_WG) and,
            if asked, the side's probe centres: world positions (m x 3) and
            translational Jacobians (m x 3 x k; zero on a welded body),
            the witness first."""
            body, X_BG = side[0], side[1]
            p_GC = np.asarray(p_GC, float).reshape(1, 3)
            if body is None:
                return X_WG.multiply(p_GC.T).T, np.zeros((1, 3, self.k))
            P_B = X_BG.multiply(p_GC.T).T
            return points(side, np.vstack([P_B, side[2]]) if probes and len(side[2]) else P_B)

        for index, (id_a, id_b, side_a, side_b) in enumerate(self._pairs):
            if measure is not None and not measure[index]:
                continue
            try:
                pair = query.ComputeSignedDistancePairClosestPoints(id_a, id_b)
            except RuntimeError:  # a shape pair Drake cannot measure: not watched
                continue
            d = pair.distance
            dists[index] = d
            if d >= self.influence_distance:
                continue
            n = np.asarray(pair.nhat_BA_W, float).reshape(3)
            P_a, J_a = witness(side_a, pair.p_ACa, query.GetPoseInWorld(id_a), probes=True)
            P_b, J_b = witness(side_b, pair.p_BCb, query.GetPoseInWorld(id_b), probes=True)
            rows.append(n @ (J_a[0] - J_b[0]))
            rhs.append(-self.rate * (d - self.target_distance))
            ends.append((n, self._end(side_a, P_a[0], self._round[id_a]), self._end(side_b, P_b[0], self._round[id_b])))
            self._probe_rows(query, n, (id_a, side_a, P_a, J_a), (id_b, side_b, P_b, J_b), witness,
                             rows, rhs, ends)
            owner.extend([index] * (len(rows) - len(owner)))
        A = np.array(rows).reshape(-1, self.k)
        m = len(ends)
        return DamperRows(A, np.array(rhs, float), dists,
                          dirs=np.array([e[0] for e in ends], float).reshape(m, 3),
                          points=np.array([[e[1][1], e[2][1]] for e in ends], float).reshape(m, 2, 3),
                          slots=np.array([[e[1][0], e[2][0]] for e in ends], int).reshape(m, 2),
                          rounds=np.array([[e[1][2], e[2][2]] for e in ends], float).reshape(m, 2),
                          pair=np.array(owner, int))

    def _probe_rows(self, query, n, a, b, witness, rows, rhs, ends) -> None:
        """Appends the rows of A's probes against B and of B's against A
        (a = (id, side, points, Jacobians) of A, the witness first; b the
        same of B) to ``rows``, ``rhs`` and ``ends``."""
        (id_a, side_a, P_a, J_a), (id_b, side_b, P_b, J_b) = a, b
        # A's probes against B, and B's against A: a face tilting
        # towards the other shape shows at its corners. The plane
        # through the other's witness (normal n, resp. -n) bounds from
        # below the distance of every point of a probing shape from a
        # static shape (an obstacle), to first order in the motion:
        # those rows are the plane's. Against a moving shape (a robot
        # link) the plane moves too, so a probe gets its own distance
        # from Drake's point query and its gradient instead; a probe
        # whose plane gap exceeds the influence distance is skipped
        # either way (the plane gap is a lower bound).
        for side, sign, id_other, side_other, P, J_P, other, J_other in (
                (side_a, 1.0, id_b, side_b, P_a, J_a, P_b[0], J_b[0]),
                (side_b, -1.0, id_a, side_a, P_b, J_b, P_a[0], J_a[0])):
            if len(P) < 2:
                continue
            radii = side[3]
            gaps = sign * (P[1:] - other) @ n - radii
            near = np.flatnonzero(gaps < self.influence_distance)
            if not len(near):
                continue
            if side_other[0] is None:  # a static obstacle: the plane's rows
                rows.extend((sign * n) @ (J_P[1 + near] - J_other))
                rhs.extend(-self.rate * (gaps[near] - self.target_distance))
                ends.extend((sign * n, self._end(side, P[1 + i]), self._end(side_other, other)) for i in near)
                continue
            if not self._point_query[id_other]:
                continue  # a moving shape without a point query: the witness row only
            X_WO = query.GetPoseInWorld(id_other)
            for i in near:
                found = [r for r in query.ComputeSignedDistanceToPoint(P[1 + i], self.influence_distance + radii[i])
                         if r.id_G == id_other]
                if not found or found[0].distance - radii[i] >= self.influence_distance:
                    continue
                p_near, J_near = witness(side_other, found[0].p_GN, X_WO)
                grad = np.asarray(found[0].grad_W, float).reshape(3)
                rows.append(grad @ (J_P[1 + i] - J_near[0]))
                rhs.append(-self.rate * (found[0].distance - radii[i] - self.target_distance))
                ends.append((grad, self._end(side, P[1 + i]), self._end(side_other, p_near[0])))

    def _end(self, side, p_W, round_radius: float = 0.0) -> tuple:
        """A row's point on one side: (the moving body's slot, p_W, the
        round shape's radius), slot -1 and radius 0 on a welded body."""
        p_W = np.asarray(p_W, float).reshape(3)
        return (-1, p_W, 0.0) if side[0] is None else (self._slot[side[0].index()], p_W, round_radius)

    def second_order(self, pctx, q, rows: DamperRows, dq: np.ndarray) -> np.ndarray:
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
        m = len(rows.b)
        if not m:
            return np.zeros(0)
        plant = self._plant
        used = np.unique(rows.slots[rows.slots >= 0])
        moved = np.zeros((len(self._bodies) + 1, 3, 4))  # per slot: [R | t] of X_WB(q + dq) X_WB(q)^-1
        moved[-1, :, :3] = np.eye(3)  # slot -1: welded
        self._slice.set_positions(pctx, q)
        before = {n: plant.EvalBodyPoseInWorld(pctx, self._bodies[n]) for n in used}
        self._slice.set_positions(pctx, q + dq)
        for n in used:
            X = plant.EvalBodyPoseInWorld(pctx, self._bodies[n]).multiply(before[n].inverse())
            moved[n, :, :3], moved[n, :, 3] = X.rotation().matrix(), X.translation()
        T = moved[rows.slots]  # (m, 2, 3, 4)
        after = np.einsum("msij,msj->msi", T[..., :3], rows.points) + T[..., 3]
        delta = after - rows.points
        actual = np.einsum("mi,mi->m", rows.dirs, delta[:, 0] - delta[:, 1])
        theta = np.append(self._rev @ np.abs(dq), 0.0)[rows.slots]
        return np.maximum(0.0, rows.A @ dq - actual) + 0.5 * np.sum(rows.rounds * theta ** 2, axis=1)

    def budget_after(self, pctx, q, q_next, budget, dists):
        """Each pair's distance beyond the influence distance that is still
        certain after this step: the measured one (or the last budget) less
        how far the step can have moved the pair's bodies, every point of a
        body's geometry within its radius r of the body's origin o:
        |o' - o| + theta r for a turn by theta. Distances are asked for only
        at updates, so the poses at both ends bound it. Negative: measure
        at the next update. (Valid while the SceneGraph is posed from the
        configurations the steps go through.)"""
        plant = self._plant
        moved = np.zeros(len(self._bodies) + 1)  # the last slot: welded, 0
        self._slice.set_positions(pctx, q)
        before = [plant.EvalBodyPoseInWorld(pctx, body) for body in self._bodies]
        self._slice.set_positions(pctx, q_next)
        for n, body in enumerate(self._bodies):
            after = plant.EvalBodyPoseInWorld(pctx, body)
            turn = before[n].rotation().InvertAndCompose(after.rotation()).ToAngleAxis().angle()
            moved[n] = np.linalg.norm(after.translation() - before[n].translation()) + turn * self._body_radius[n]
        left = np.where(np.isnan(dists), budget, dists - self.influence_distance)
        return left - moved[self._pair_bodies[:, 0]] - moved[self._pair_bodies[:, 1]]
