"""Clearance, collision and volume contact through a SceneGraph's query
port."""

from collections.abc import Collection, Iterable
from typing import Any

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.geometry import GeometryId, QueryObject, Role
from pydrake.systems.framework import Context, LeafSystem, ValueProducer

from drake_cfvol.exceptions import ParameterError

__all__ = ["ClearanceMonitor"]


class ClearanceMonitor(LeafSystem):
    """Clearance, collision and volume contact of the robot, queried from
    the diagram's own SceneGraph through its ``query_object`` port.

    .. pydrake_system::

        name: ClearanceMonitor
        input_ports:
        - query_object
        output_ports:
        - min_distance
        - in_collision
        - in_volume

    ``min_distance`` is the smallest signed distance from the robot's moving
    links to the real obstacles (not the volume; a fixed base resting on its
    pedestal says nothing about a push, nor do ``ignored_pairs``), capped at
    ``max_distance``.
    ``in_collision`` is 1 where the robot penetrates an obstacle or itself
    (the plant's collision filters apply), ``in_volume`` 1 where it
    penetrates a box of the volume V. The system keeps no state; its
    outputs are functions of its context alone.

    With ``obstacle_ids``, ``min_distance`` remembers each pair's last
    distance and the two geometries' poses then (facts about the shapes,
    true in any context): a pair whose distance can have shrunk since by at
    most how far each geometry's points moved (translation plus rotation
    times the geometry's radius about its origin) and that still cannot
    come below the smallest distance found, nor below 0, is not queried
    again. The minimum is the same as querying every pair; a
    pair near the robot is queried at every evaluation.

    Args:
        robot_ids: proximity geometry ids of the robot (all links).
        moving_ids: the subset on links the joints move.
        volume_ids: the volume's boxes; every other proximity geometry is an
            obstacle, unless ``obstacle_ids`` names them.
        max_distance: distances beyond this are reported as this, m.
        obstacle_ids: the obstacles, if known: ``min_distance`` then asks
            for the moving links' distance to each of them only (cheaper in
            a scene holding other geometry, such as the volume V's boxes);
            ``in_collision`` ignores any other geometry.
        ignored_pairs: (moving link geometry, obstacle geometry) pairs left
            out of ``min_distance``: those whose distance no joint motion
            changes (:meth:`drake_cfvol.scene.workcell.Workcell.invariant_pairs`),
            which a push cannot bring closer. ``in_collision`` still counts them.
    """

    def __init__(
        self,
        *,
        robot_ids: Iterable[GeometryId],
        moving_ids: Iterable[GeometryId],
        volume_ids: Iterable[GeometryId],
        max_distance: float = 2.0,
        obstacle_ids: Iterable[GeometryId] | None = None,
        ignored_pairs: Collection[tuple[GeometryId, GeometryId]] = (),
    ):
        super().__init__()
        self._robot = frozenset(robot_ids)
        self._moving = frozenset(moving_ids)
        self._volume = frozenset(volume_ids)
        obstacles = None if obstacle_ids is None else frozenset(obstacle_ids)
        self._obstacles = obstacles
        self._ignored = frozenset((a, b) for a, b in ignored_pairs) | frozenset((b, a) for a, b in ignored_pairs)
        self._pairs = (
            None
            if obstacles is None
            else [
                (a, b)
                for a in sorted(self._moving, key=lambda g: g.get_value())
                for b in sorted(obstacles, key=lambda g: g.get_value())
                if (a, b) not in self._ignored
            ]
        )
        self._memo: dict[str, Any] | None = None  # min_distance's pair memo (see the class docs)
        #: Signed-distance queries of single pairs made so far (for tests and benchmarks).
        self.pair_queries = 0
        if not self._moving <= self._robot:
            raise ParameterError("ClearanceMonitor: moving_ids must be a subset of robot_ids.")
        self._max = float(max_distance)
        self.query_object_input = self.DeclareAbstractInputPort(
            name="query_object", model_value=AbstractValue.Make(QueryObject())
        )
        self.min_distance_output = self.DeclareVectorOutputPort(
            name="min_distance", size=1, calc=lambda c, o: o.SetAtIndex(0, self.min_distance(c))
        )
        # One penetration query serves both contact outputs (a cache entry).
        self._contact_cache = self.DeclareCacheEntry(
            description="(robot collides, robot touches V)",
            value_producer=ValueProducer(
                allocate=lambda: AbstractValue.Make(object()), calc=lambda c, value: value.set_value(self._contacts(c))
            ),
            prerequisites_of_calc={self.query_object_input.ticket()},
        )
        self.in_collision_output = self.DeclareVectorOutputPort(
            name="in_collision",
            size=1,
            calc=lambda c, o: o.SetAtIndex(0, float(self._contact_cache.Eval(c)[0])),
            prerequisites_of_calc={self.query_object_input.ticket()},
        )
        self.in_volume_output = self.DeclareVectorOutputPort(
            name="in_volume",
            size=1,
            calc=lambda c, o: o.SetAtIndex(0, float(self._contact_cache.Eval(c)[1])),
            prerequisites_of_calc={self.query_object_input.ticket()},
        )

    def min_distance(self, context: Context) -> float:
        """Smallest signed distance, moving links to obstacles, m."""
        query = self.query_object_input.Eval(context)
        best = self._max
        if self._pairs is not None:
            return self._pairs_min(query)
        for pair in query.ComputeSignedDistancePairwiseClosestPoints(max_distance=self._max):
            a, b = pair.id_A, pair.id_B
            if a in self._volume or b in self._volume or (a, b) in self._ignored:
                continue
            if (a in self._moving and b not in self._robot) or (b in self._moving and a not in self._robot):
                best = min(best, pair.distance)
        return best

    def _pair_memo(self, query):
        """The pair memo, made anew when the scene's proximity shapes
        changed: the geometries' poses as flat rows (the anchored ones
        filled in for good, the others' rows listed in ``posed``), each
        pair's two rows, each end's radius about its origin (m; 1e300 where
        Drake gives no bounding box), the pairs' last distances (-inf: none
        yet) and the two poses they were measured at."""
        assert self._pairs is not None  # min_distance asks only with the pairs named
        inspector = query.inspector()
        version = inspector.geometry_version()
        memo = self._memo
        if memo is not None and memo["version"].IsSameAs(version, Role.kProximity):
            return memo
        ids = sorted({g for pair in self._pairs for g in pair}, key=lambda g: g.get_value())
        at = {g: n for n, g in enumerate(ids)}
        X = np.array([query.GetPoseInWorld(g).GetAsMatrix34().ravel() for g in ids]).reshape(len(ids), 12)
        radius = np.full(len(ids), 1e300)
        for n, g in enumerate(ids):
            obb = query.ComputeObbInWorld(g)
            if obb is not None:
                radius[n] = np.linalg.norm(obb.center() - X[n, _POSITION]) + np.linalg.norm(obb.half_width())
        ends = np.array([[at[a], at[b]] for a, b in self._pairs], np.int64).reshape(-1, 2)
        world = inspector.world_frame_id()
        self._memo = memo = {
            "version": version,
            "X": X,
            "posed": [(n, g) for n, g in enumerate(ids) if inspector.GetFrameId(g) != world],
            "ends": ends,
            "radius": radius[ends],
            "distance": np.full(len(ends), -np.inf),
            "X0": np.zeros((len(ends), 2, 12)),
        }
        return memo

    def _pairs_min(self, query) -> float:
        """The named pairs' smallest distance, skipping those the memo
        shows cannot be the smallest (see the class docs): each end's
        points moved at most the origin's displacement plus the rotation's
        change (Frobenius norm, >= its spectral norm) times its radius."""
        assert self._pairs is not None  # min_distance asks only with the pairs named
        memo = self._pair_memo(query)
        X = memo["X"]
        for n, g in memo["posed"]:
            X[n] = query.GetPoseInWorld(g).GetAsMatrix34().ravel()
        now = X[memo["ends"]]  # (P, 2, 12)
        sq = np.square(now - memo["X0"])
        moved = np.sqrt(sq[..., _POSITION].sum(axis=-1)) + np.sqrt(sq[..., _ROTATION].sum(axis=-1)) * memo["radius"]
        lower = memo["distance"] - moved.sum(axis=1)
        best = self._max
        for n in np.argsort(lower, kind="stable").tolist():
            if lower[n] > 0.0 and lower[n] >= best:
                break  # this pair and every later one stay at least this far apart
            ga, gb = self._pairs[n]
            d = query.ComputeSignedDistancePairClosestPoints(ga, gb).distance
            self.pair_queries += 1
            memo["distance"][n] = d
            memo["X0"][n] = now[n]
            best = min(best, d)
        return best

    def _contacts(self, context) -> tuple[bool, bool]:
        query = self.query_object_input.Eval(context)
        collides = touches_volume = False
        for pp in query.ComputePointPairPenetration():
            a, b = pp.id_A, pp.id_B
            if a in self._volume or b in self._volume:
                touches_volume |= a in self._robot or b in self._robot
            elif a in self._robot or b in self._robot:
                other = b if a in self._robot else a
                if self._obstacles is None or other in self._robot or other in self._obstacles:
                    collides = True
        return collides, touches_volume


#: Where a pose's rotation and translation sit in its 3 x 4 matrix's flat row.
_ROTATION = [0, 1, 2, 4, 5, 6, 8, 9, 10]
_POSITION = [3, 7, 11]
