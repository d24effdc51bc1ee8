"""Queries on a workcell's Drake scene: signed distances per obstacle, the
nearest obstacle, pairs no joint motion changes, Drake's collision checkers,
configuration checks (:class:`WorkcellQueries`, a part of
:class:`~drake_cfvol.scene.workcell.Workcell`).

Every query poses the one diagram context the workcell owns
(``Workcell.context``): a workcell is not for use from two threads at once.
Results computed once are kept in the workcell's ``_cache`` dict (one
idiom: :meth:`WorkcellQueries._memo`).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt
from pydrake.geometry import GeometryId, SceneGraph
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import Frame, ModelInstanceIndex
from pydrake.planning import RobotDiagram, SceneGraphCollisionChecker
from pydrake.systems.framework import Context

from drake_cfvol.exceptions import (
    CollisionError,
    ConfigurationError,
    DimensionError,
    JointLimitError,
    MissingJointLimitsError,
    ParameterError,
    WorkcellError,
)
from drake_cfvol.io.arguments import real_array
from drake_cfvol.scene.robot import RobotSlice, robot_bodies, robot_instances

if TYPE_CHECKING:
    from drake_cfvol.scene.arrays import SceneArrays

__all__ = ["KernelFirstChecker", "RobotChecker", "WorkcellQueries", "geometry_key", "robot_geometry_ids"]


def geometry_key(inspector, geometry_id) -> tuple[str, str]:
    """(frame name, geometry name): a geometry's name that holds across
    plants built from the same models."""
    return inspector.GetName(inspector.GetFrameId(geometry_id)), inspector.GetName(geometry_id)


def robot_geometry_ids(plant, robot) -> tuple[set, set]:
    """Proximity geometry ids of a robot's links in a finalized plant (a
    gripper welded to it included, :func:`~drake_cfvol.scene.robot.robot_bodies`),
    and of those its joints move.

    Returns:
        (every, moving)
    """
    moved = set(plant.GetBodiesKinematicallyAffectedBy(list(plant.GetJointIndices(robot))))
    every, moving = set(), set()
    for b in robot_bodies(plant, robot):
        ids = plant.GetCollisionGeometriesForBody(plant.get_body(b))
        every.update(ids)
        if b in moved:
            moving.update(ids)
    return every, moving


class _RobotClearance:
    """Drake's ``RobotClearance`` with the Jacobians' robot columns only."""

    def __init__(self, rc, robot_slice):
        self._rc, self._slice = rc, robot_slice

    def __getattr__(self, name):
        return getattr(self._rc, name)

    def jacobians(self) -> np.ndarray:
        J = np.asarray(self._rc.jacobians()).reshape(len(self._rc.distances()), -1)
        return self._slice.columns(J, "qdot")


class RobotChecker:
    """A Drake ``SceneGraphCollisionChecker`` that takes the robot's k
    positions where Drake's takes the plant's n (every other degree of
    freedom held at the workcell's default: a gripper's fingers, a free
    part). The robot is its model instance and every instance its joints
    move (a gripper). Drake's checker is :attr:`drake`.

    Args:
        model: a ``RobotDiagram``.
        robot: the robot's model instance in it.
        q_default: (n,) the plant's positions to hold the rest at (default:
            the plant's default context).
        **kwargs: for ``SceneGraphCollisionChecker`` (``edge_step_size``, paddings).
    """

    def __init__(self, model, robot, q_default=None, **kwargs):
        plant = model.plant()
        self.slice = RobotSlice(plant, robot, q_default)
        self.drake = SceneGraphCollisionChecker(
            model=model, robot_model_instances=robot_instances(plant, robot), **kwargs
        )

    def CheckConfigCollisionFree(self, q) -> bool:
        """True if the robot at ``q`` (k,) is free (Drake)."""
        return self.drake.CheckConfigCollisionFree(self.slice.full(q))

    def CheckConfigsCollisionFree(self, Q, parallelize=True) -> list:
        """Per row of ``Q`` (N, k), True where free (Drake)."""
        return self.drake.CheckConfigsCollisionFree(self.slice.full(np.atleast_2d(Q)), parallelize=parallelize)

    def CheckEdgeCollisionFree(self, a, b) -> bool:
        """True if the straight joint-space edge from ``a`` to ``b`` is free
        at Drake's edge step."""
        return self.drake.CheckEdgeCollisionFree(self.slice.full(a), self.slice.full(b))

    def CalcRobotClearance(self, q, influence_distance: float):
        """Drake's ``RobotClearance`` at ``q`` (k,), with the same methods;
        ``jacobians()`` has the robot's k columns."""
        rc = self.drake.CalcRobotClearance(self.slice.full(q), influence_distance)
        return rc if not self.slice.extra else _RobotClearance(rc, self.slice)

    def IsCollisionFilteredBetween(self, a, b) -> bool:
        """Whether Drake's checker ignores the pair of bodies ``a``, ``b``."""
        return self.drake.IsCollisionFilteredBetween(a, b)


class KernelFirstChecker:
    """Drake's padded checker's answers, the compiled kernel asked first.

    The kernel is conservative (a configuration it certifies free is free
    by Drake's checker at the same padding), so Drake checks only the
    configurations the kernel cannot certify. An edge is checked at
    Drake's own samples (its distance, edge step and interpolation, in its
    order: the end first, then from the start), so every answer is the one
    :class:`RobotChecker` gives, only sooner. Used by the planner.

    Args:
        queries: the workcell (its kernel check, :meth:`WorkcellQueries.collision_free`).
        checker: the workcell's :class:`RobotChecker` at this padding.
        clearance: its padding, m.
    """

    #: Samples of an edge the kernel takes at once (an edge that collides
    #: stops at the first chunk holding a sample Drake finds colliding).
    CHUNK = 32

    def __init__(self, queries, checker: RobotChecker, clearance: float):
        self._queries, self._checker, self._clearance = queries, checker, float(clearance)
        self.drake, self.slice = checker.drake, checker.slice
        self._linear = self._interpolation_is_linear()

    def _interpolation_is_linear(self) -> bool:
        """Whether Drake interpolates the robot's positions as (1 - r) q1 +
        r q2, bit for bit (its linear provider does; a user's may not:
        then each sample is Drake's own, one call each)."""
        rng = np.random.default_rng(0)
        for _ in range(16):
            a, b, r = rng.normal(size=self.slice.k), rng.normal(size=self.slice.k), rng.integers(1, 99) / 99
            q = self.drake.InterpolateBetweenConfigurations(self.slice.full(a), self.slice.full(b), r)
            if not np.array_equal(q[self.slice.qidx], (1 - r) * a + r * b):
                return False
        return True

    def CheckConfigCollisionFree(self, q) -> bool:
        """True if the robot at ``q`` (k,) is free (Drake's answer)."""
        return bool(self._queries.collision_free(q, clearance=self._clearance)[0]) or bool(
            self._checker.CheckConfigCollisionFree(q)
        )

    def CheckEdgeCollisionFree(self, a, b) -> bool:
        """True if the straight joint-space edge from ``a`` to ``b`` is free
        at Drake's edge step (Drake's answer)."""
        a, b = np.asarray(a, float), np.asarray(b, float)
        fa, fb = self.slice.full(a), self.slice.full(b)
        n = int(max(1.0, math.ceil(self.drake.ComputeConfigurationDistance(fa, fb) / self.drake.edge_step_size())))
        r = np.arange(n) / n
        if self._linear:
            Q = np.vstack([b, (1 - r)[:, None] * a + r[:, None] * b])
        else:
            Q = np.vstack([b] + [self.drake.InterpolateBetweenConfigurations(fa, fb, x)[self.slice.qidx] for x in r])
        for at in range(0, len(Q), self.CHUNK):
            chunk = Q[at : at + self.CHUNK]
            free = self._queries.collision_free(chunk, clearance=self._clearance)
            for i in np.flatnonzero(~free):
                if not self._checker.CheckConfigCollisionFree(chunk[i]):
                    return False
        return True


class WorkcellQueries:
    """The queries of :class:`~drake_cfvol.scene.workcell.Workcell` (a mixin:
    it uses the workcell's plant, scene graph, context, robot, joints and
    obstacles)."""

    # The workcell's state, for the type checker: set by Workcell._setup
    # (name ... _geometry_owner) and WorkcellSetup (joints, frames, settings);
    # described in Workcell's docstring.
    name: str
    path: Path | None
    diagram: RobotDiagram
    plant: MultibodyPlant
    scene_graph: SceneGraph
    robot: ModelInstanceIndex
    robot_name: str
    slice: RobotSlice
    notes: list[str]
    joint_names: list[str]
    revolute: np.ndarray
    position_lower: np.ndarray
    position_upper: np.ndarray
    velocity_limits: np.ndarray
    acceleration_limits: np.ndarray
    jerk_limits: np.ndarray
    tool_frame: Frame
    base_frame: Frame
    rail_joint: str | None
    params: dict[str, Any]
    configurations: dict[str, tuple[np.ndarray, np.ndarray]]
    _lines: dict[str, int]
    _edge_step: float
    _cache: dict[Any, Any]
    _context: Context
    _geometry_owner: dict[GeometryId, str]

    if TYPE_CHECKING:  # Workcell's own

        def _fail(self, message: str, key: str | None = None) -> WorkcellError: ...

        def scene_arrays(self) -> SceneArrays: ...

    def _memo(self, key, make):
        """The value kept under ``key`` in the workcell's cache, made once by ``make()``."""
        if key not in self._cache:
            self._cache[key] = make()
        return self._cache[key]

    def obstacle_distances(
        self, q: npt.ArrayLike, max_distance: float, *, moving_only: bool = False, changeable_only: bool = False
    ) -> dict[str, float]:
        """Smallest signed distance per obstacle to the robot at ``q`` (real
        geometry, Drake), for the obstacles within ``max_distance``, m. With
        ``moving_only``, only the robot's links that its joints move count
        (a fixed base resting on its pedestal says nothing about a push);
        with ``changeable_only``, moreover only the pairs whose distance a
        joint motion changes (:meth:`invariant_pairs`: a turret turning above
        its round pedestal, a rail carriage gliding above the floor)."""
        invariant = self.invariant_pairs() if changeable_only else frozenset()  # poses the context: first
        self.plant_context(q)
        sg = self.scene_graph
        query = sg.get_query_output_port().Eval(sg.GetMyContextFromRoot(self._context))
        owner = self._geometry_owner
        fixed = self.fixed_robot_geometries() if (moving_only or changeable_only) else frozenset()
        out: dict[str, float] = {}
        for pair in query.ComputeSignedDistancePairwiseClosestPoints(max_distance=max_distance):
            a, b = owner.get(pair.id_A), owner.get(pair.id_B)
            if (a is None) == (b is None):
                continue  # robot-robot or obstacle-obstacle
            r, o = (pair.id_B, pair.id_A) if a is not None else (pair.id_A, pair.id_B)
            if r in fixed or (r, o) in invariant:
                continue
            name = a if a is not None else b
            assert name is not None  # one of the two is an obstacle (checked above)
            out[name] = min(out.get(name, np.inf), pair.distance)
        return out

    def nearest_obstacle(
        self, q: npt.ArrayLike, max_distance: float = 5.0
    ) -> tuple[str, float, np.ndarray, np.ndarray] | None:
        """The obstacle nearest to the robot's moving links at ``q`` (Drake,
        real geometry), among the pairs whose distance a joint motion
        changes (:meth:`invariant_pairs`).

        Returns:
            (name, distance m, p_WR, p_WO): the witness points on the robot and
            on the obstacle, world frame; None if nothing is within
            ``max_distance``.
        """
        invariant = self.invariant_pairs()  # poses the context: first
        self.plant_context(q)
        sg = self.scene_graph
        query = sg.get_query_output_port().Eval(sg.GetMyContextFromRoot(self._context))
        owner, fixed = self._geometry_owner, self.fixed_robot_geometries()
        best = None
        for pair in query.ComputeSignedDistancePairwiseClosestPoints(max_distance=max_distance):
            a, b = owner.get(pair.id_A), owner.get(pair.id_B)
            if (a is None) == (b is None):
                continue
            robot_id, p_R, name, obs_id, p_O = (
                (pair.id_B, pair.p_BCb, a, pair.id_A, pair.p_ACa)
                if a is not None
                else (pair.id_A, pair.p_ACa, b, pair.id_B, pair.p_BCb)
            )
            if robot_id in fixed or (robot_id, obs_id) in invariant:
                continue
            assert name is not None  # one of the two is an obstacle (checked above)
            if best is None or pair.distance < best[1]:
                best = (name, pair.distance, query.GetPoseInWorld(robot_id) @ p_R, query.GetPoseInWorld(obs_id) @ p_O)
        return best

    def invariant_pairs(self, *, samples: int = 12, seed: int = 0, tol: float = 1e-6) -> frozenset:
        """(robot geometry id, obstacle geometry id) pairs, moving links only,
        whose signed distance no joint motion changes: equal within ``tol``
        (m) at the default configuration and ``samples`` seeded uniform
        configurations within the position limits (nominal +- pi for a joint
        without limits). A push cannot bring such a pair closer, so a run's
        clearance leaves them out (:meth:`obstacle_distances`). Computed once."""
        return self._memo(("invariant_pairs", samples, seed, tol), lambda: self._invariant_pairs(samples, seed, tol))

    def _invariant_pairs(self, samples: int, seed: int, tol: float) -> frozenset:
        k = self.num_joints
        q0 = self.slice.q_default[self.slice.qidx]
        lo = np.where(np.isfinite(self.position_lower), self.position_lower, q0 - np.pi)
        hi = np.where(np.isfinite(self.position_upper), self.position_upper, q0 + np.pi)
        Q = np.vstack([q0, np.random.default_rng(seed).uniform(lo, hi, (samples, k))])
        _, moving = robot_geometry_ids(self.plant, self.robot)
        pairs = [
            (r, o)
            for r in sorted(moving, key=lambda g: g.get_value())
            for o in sorted(self._geometry_owner, key=lambda g: g.get_value())
        ]
        sg = self.scene_graph
        D = np.full((len(Q), len(pairs)), np.nan)
        for n, q in enumerate(Q):
            self.plant_context(q)
            query = sg.get_query_output_port().Eval(sg.GetMyContextFromRoot(self._context))
            for m, (r, o) in enumerate(pairs):
                try:
                    D[n, m] = query.ComputeSignedDistancePairClosestPoints(r, o).distance
                except RuntimeError:
                    pass  # a shape pair Drake cannot measure: never called invariant
        spread = np.nanmax(D, axis=0) - np.nanmin(D, axis=0) if len(Q) else np.zeros(len(pairs))
        ok = np.all(np.isfinite(D), axis=0) & (spread <= tol)
        return frozenset(p for p, keep in zip(pairs, ok) if keep)

    def invariant_pair_names(self) -> frozenset:
        """:meth:`invariant_pairs` as ((frame name, geometry name) of the
        robot's geometry, same of the obstacle's): names that hold in any
        plant the workcell was added to (:meth:`add_to_plant`)."""
        inspector = self.scene_graph.model_inspector()
        return frozenset((geometry_key(inspector, r), geometry_key(inspector, o)) for r, o in self.invariant_pairs())

    def fixed_robot_geometries(self) -> frozenset:
        """Proximity geometry ids of the robot's bodies that no joint moves
        (e.g. a base welded to its pedestal)."""

        def make():
            every, moving = robot_geometry_ids(self.plant, self.robot)
            return frozenset(every - moving)

        return self._memo("fixed_robot_geometries", make)

    @property
    def num_joints(self) -> int:
        """k, the robot's number of joints."""
        return len(self.joint_names)

    @property
    def context(self) -> Context:
        """A diagram context owned by the workcell (do not keep references)."""
        return self._context

    def plant_context(self, q: npt.ArrayLike | None = None) -> Context:
        """Returns the workcell's plant context, set to ``q`` if given."""
        ctx = self.plant.GetMyMutableContextFromRoot(self._context)
        if q is not None:
            self.slice.set_positions(ctx, real_array(q, "q"))
        return ctx

    @property
    def checker(self) -> SceneGraphCollisionChecker:
        """A Drake ``SceneGraphCollisionChecker`` of the real scene (obstacles
        + self-collision, adjacent links filtered)."""
        return self.padded_checker(0.0)

    def padded_checker(self, clearance: float) -> SceneGraphCollisionChecker:
        """A ``SceneGraphCollisionChecker`` that calls a configuration nearer
        than ``clearance`` (m) to an obstacle or to the robot itself
        colliding (Drake's collision padding); one per distinct value."""
        clearance = float(clearance)
        return self._memo(
            ("checker", clearance),
            lambda: RobotChecker(
                self.diagram,
                self.robot,
                self.slice.q_default,
                edge_step_size=self._edge_step,
                env_collision_padding=clearance,
                self_collision_padding=clearance,
            ),
        )

    def planning_checker(self, clearance: float) -> KernelFirstChecker:
        """:meth:`padded_checker`'s answers, the kernel asked first
        (:class:`KernelFirstChecker`); one per distinct value."""
        clearance = float(clearance)
        return self._memo(
            ("planning_checker", clearance),
            lambda: KernelFirstChecker(self, self.padded_checker(clearance), clearance),
        )

    def clearance(self, q: npt.ArrayLike, influence: float = 1.0) -> float:
        """The robot's signed distance to the obstacles and to itself at
        ``q`` (m; the smallest pair, by Drake; ``influence`` if none is
        nearer)."""
        d = np.asarray(self.checker.CalcRobotClearance(real_array(q, "q"), influence).distances())
        return float(d.min()) if d.size else float(influence)

    def finite_limits(self, needed_for: str) -> tuple[np.ndarray, np.ndarray]:
        """Returns the position limits, raising if any is infinite."""
        bad = [
            n
            for n, lo, hi in zip(self.joint_names, self.position_lower, self.position_upper)
            if not (np.isfinite(lo) and np.isfinite(hi))
        ]
        if bad:
            raise MissingJointLimitsError(bad, needed_for)
        return self.position_lower.copy(), self.position_upper.copy()

    def validate_configuration(
        self, q: npt.ArrayLike, what: str = "configuration", *, check_limits: bool = True, tolerance: float = 1e-9
    ) -> np.ndarray:
        """Checks a configuration's size and limits; returns it as an array.

        Raises:
            ParameterError: ``q`` does not hold numbers (a dict, say).
            DimensionError: ``q`` is not (k,).
            JointLimitError: a joint lies outside its limits.
        """
        q = real_array(q, what)
        if q.shape != (self.num_joints,):
            raise DimensionError(
                what,
                self.num_joints,
                q.shape[0] if q.ndim == 1 else q.shape,
                f"The robot's joints are {', '.join(self.joint_names)}.",
            )
        if not np.all(np.isfinite(q)):
            bad = [f"{n} = {v}" for n, v in zip(self.joint_names, q) if not np.isfinite(v)]
            raise ConfigurationError(
                f"{what} has a value that is not a finite number: {', '.join(bad)}. Give every "
                "joint a finite position (rad or m)."
            )
        if check_limits:
            for n, v, lo, hi in zip(self.joint_names, q, self.position_lower, self.position_upper):
                if v < lo - tolerance or v > hi + tolerance:
                    raise JointLimitError(what, n, float(v), float(lo), float(hi))
        return q

    def colliding_pairs(self, q: npt.ArrayLike) -> list[tuple[str, str]]:
        """Names the pairs of bodies in collision at ``q`` (real scene)."""
        self.plant_context(q)
        sg_context = self.scene_graph.GetMyContextFromRoot(self._context)
        query = self.scene_graph.get_query_output_port().Eval(sg_context)
        inspector = query.inspector()
        pairs = set()
        for pp in query.ComputePointPairPenetration():
            a = self.plant.GetBodyFromFrameId(inspector.GetFrameId(pp.id_A)).name()
            b = self.plant.GetBodyFromFrameId(inspector.GetFrameId(pp.id_B)).name()
            pairs.add(tuple(sorted((a, b))))
        return sorted(pairs)

    def collision_free(self, Q: npt.ArrayLike, *, clearance: float = 0.0) -> np.ndarray:
        """Which configurations are certainly free: the compiled kernel's
        batch check, for your own sampling and planners.

        Every robot shape against every obstacle and the robot's own
        unfiltered pairs, exactly (meshes as their convex hulls, as Drake's
        point queries take them), in parallel over the rows. Conservative:
        never True where Drake's checker finds a collision (tested on every
        built-in robot and the mesh test robot); it may say False for a free
        configuration that grazes a shape within rounding. Joint limits are
        not checked (as Drake's checker does not).

        Args:
            Q: (N, k) or (k,) configurations, rad (m for prismatic joints).
            clearance: a configuration nearer than this (m) to an obstacle or
                to itself counts as colliding (Drake's collision padding).

        Returns:
            (N,) bool, True: certainly free.

        Raises:
            DimensionError: ``Q`` does not have k columns.
            ConfigurationError: a value that is not finite.
            ParameterError: a negative clearance.
        """
        Q = real_array(Q, "Q")
        if Q.ndim not in (1, 2) or Q.shape[-1] != self.num_joints:
            raise DimensionError(
                "Q", f"(N, {self.num_joints})", Q.shape, f"The robot's joints are {', '.join(self.joint_names)}."
            )
        if not np.all(np.isfinite(Q)):
            raise ConfigurationError("Q holds a value that is not a finite number; give every joint a finite position.")
        if not clearance >= 0:
            raise ParameterError(f"clearance must be >= 0 m, got {clearance}.")
        return ~self.scene_arrays().may_collide(np.atleast_2d(Q), float(clearance))

    def is_free(self, q: npt.ArrayLike) -> bool:
        """True if ``q`` is free of collision with the real scene."""
        return bool(self.checker.CheckConfigCollisionFree(real_array(q, "q")))

    def require_free(self, q: npt.ArrayLike, what: str) -> None:
        """Raises :class:`CollisionError` naming the bodies if ``q`` collides."""
        if not self.is_free(q):
            raise CollisionError(what, self.colliding_pairs(q))

    def require_collision_geometry(self, needed_for: str) -> None:
        """Raises :class:`WorkcellError` if no link the robot's joints move
        has collision (proximity) geometry: every check would then call any
        configuration free, and a path or a box would go through walls.
        Planning, the bounds and a co-manipulation run all ask this first."""
        _, moving = robot_geometry_ids(self.plant, self.robot)
        if not moving:
            where = f" (workcell {self.path})" if self.path is not None else ""
            raise WorkcellError(
                f"robot '{self.robot_name}'{where} has no collision geometry on the links its joints move, so "
                f"{needed_for} would take every configuration as free. Add <collision> elements to its links "
                "(URDF or SDFormat), or use a model of the robot that has them."
            )

    def configuration(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """Returns the named (start, goal) pair."""
        if not isinstance(name, str) or name not in self.configurations:
            raise WorkcellError(
                f"Cell '{self.name}' has no configuration '{name}'. It has: "
                f"{', '.join(self.configurations) or '(none)'}; add it under cfvol.configurations."
            )
        s, g = self.configurations[name]
        return s.copy(), g.copy()

    def tool_position(self, q: npt.ArrayLike) -> np.ndarray:
        """p_WT: the tool frame's origin in the world at ``q``, m."""
        ctx = self.plant_context(q)
        return self.tool_frame.CalcPoseInWorld(ctx).translation().copy()
