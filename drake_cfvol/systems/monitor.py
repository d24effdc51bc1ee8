"""Clearance, collision and volume contact through a SceneGraph's query
port."""

from pydrake.common.value import AbstractValue
from pydrake.geometry import QueryObject
from pydrake.systems.framework import LeafSystem, ValueProducer

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
    penetrates a box of the volume V. The system keeps no state and writes
    nothing outside its context.

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
        self, *, robot_ids, moving_ids, volume_ids, max_distance: float = 2.0, obstacle_ids=None, ignored_pairs=()
    ):
        super().__init__()
        self._robot = frozenset(robot_ids)
        self._moving = frozenset(moving_ids)
        self._volume = frozenset(volume_ids)
        self._obstacles = None if obstacle_ids is None else frozenset(obstacle_ids)
        self._ignored = frozenset((a, b) for a, b in ignored_pairs) | frozenset((b, a) for a, b in ignored_pairs)
        self._pairs = (
            None
            if obstacle_ids is None
            else [
                (a, b)
                for a in sorted(self._moving, key=lambda g: g.get_value())
                for b in sorted(self._obstacles, key=lambda g: g.get_value())
                if (a, b) not in self._ignored
            ]
        )
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

    def min_distance(self, context) -> float:
        """Smallest signed distance, moving links to obstacles, m."""
        query = self.query_object_input.Eval(context)
        best = self._max
        if self._pairs is not None:
            for a, b in self._pairs:
                best = min(best, query.ComputeSignedDistancePairClosestPoints(a, b).distance)
            return best
        for pair in query.ComputeSignedDistancePairwiseClosestPoints(max_distance=self._max):
            a, b = pair.id_A, pair.id_B
            if a in self._volume or b in self._volume or (a, b) in self._ignored:
                continue
            if (a in self._moving and b not in self._robot) or (b in self._moving and a not in self._robot):
                best = min(best, pair.distance)
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
