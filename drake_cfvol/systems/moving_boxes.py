"""Boxes that move through the cell on their own: a cart, a fixture, a
passer-by (SPEC 12)."""

import dataclasses
from collections.abc import Sequence

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.geometry import (
    Box,
    FramePoseVector,
    GeometryFrame,
    GeometryInstance,
    IllustrationProperties,
    PerceptionProperties,
    ProximityProperties,
    RenderLabel,
    Rgba,
    SceneGraph,
)
from pydrake.math import RigidTransform
from pydrake.systems.framework import LeafSystem

from drake_cfvol.exceptions import ParameterError
from drake_cfvol.online.obstacle_map import MapGrid, ObstacleMap, PerceptionParams, dilate

__all__ = ["MovingObstacle", "MovingBoxes", "MOVING_LABEL_BASE"]

#: Render labels of the moving boxes start here (robot and cell bodies use
#: their body index).
MOVING_LABEL_BASE = 30000


@dataclasses.dataclass
class MovingObstacle:
    """A box whose centre moves piecewise-linearly in the world frame.

    Attributes:
        name: its name (unique).
        box: full sides [sx, sy, sz], m.
        waypoints: [[t, x, y, z], ...] in increasing t (s, m): the centre at
            those times; held at the first before it and at the last after.
    """

    name: str = "obstacle"
    box: list[float] = dataclasses.field(default_factory=lambda: [0.5, 0.5, 1.0])
    waypoints: list[list[float]] = dataclasses.field(default_factory=list)

    def check(self) -> None:
        """Raises ParameterError naming what is wrong with the box or its waypoints."""
        if len(self.box) != 3 or not all(np.isfinite(self.box)) or min(self.box) <= 0:
            raise ParameterError(f"moving obstacle '{self.name}': box must be 3 sides > 0 m, got {self.box!r}.")
        if not self.waypoints:
            raise ParameterError(f"moving obstacle '{self.name}': give at least one waypoint [t, x, y, z].")
        W = np.asarray(self.waypoints, float)
        if W.ndim != 2 or W.shape[1] != 4 or not np.all(np.isfinite(W)):
            raise ParameterError(
                f"moving obstacle '{self.name}': each waypoint is [t, x, y, z] (s, m), got {self.waypoints!r}."
            )
        if np.any(np.diff(W[:, 0]) <= 0):
            raise ParameterError(
                f"moving obstacle '{self.name}': waypoint times must increase, got {W[:, 0].tolist()}."
            )

    def position(self, t: float) -> np.ndarray:
        """The centre at time t, m."""
        W = np.asarray(self.waypoints, float)
        return np.array([np.interp(t, W[:, 0], W[:, c]) for c in (1, 2, 3)])

    def first_motion(self) -> float | None:
        """The time it first moves, s (None: it never moves)."""
        W = np.asarray(self.waypoints, float)
        for a, b in zip(W[:-1], W[1:]):
            if np.any(a[1:] != b[1:]):
                return float(a[0])
        return None


class MovingBoxes(LeafSystem):
    """Moving boxes as a SceneGraph geometry source: proximity (the monitor
    and, when perception is ``truth``, the safety filter measure them),
    illustration and perception (the cell camera sees them).

    .. pydrake_system::

        name: MovingBoxes
        output_ports:
        - geometry_pose
        - obstacle_map

    Connect ``geometry_pose`` to ``scene_graph.get_source_pose_port(system.source_id)``.
    ``obstacle_map`` (with ``grid``) is the boxes' true obstacle map now
    (:meth:`obstacle_map`): perception ``truth``.

    Args:
        scene_graph: the diagram's SceneGraph.
        obstacles: the boxes.
        rgba: their colour.
        grid, params: the grid and settings of ``obstacle_map`` (None: no
            such port).
    """

    def __init__(
        self,
        scene_graph: SceneGraph,
        obstacles: list[MovingObstacle],
        *,
        rgba: Sequence[float] = (0.85, 0.45, 0.1, 1.0),
        grid: MapGrid | None = None,
        params: PerceptionParams = PerceptionParams(),
    ):
        super().__init__()
        names = [o.name for o in obstacles]
        if len(set(names)) != len(names):
            raise ParameterError(f"moving obstacles need distinct names, got {names}.")
        for o in obstacles:
            o.check()
        self.obstacles = list(obstacles)
        self.source_id = scene_graph.RegisterSource("moving_obstacles")
        self.frame_ids, self.geometry_ids = [], []
        for n, o in enumerate(self.obstacles):
            frame = scene_graph.RegisterFrame(self.source_id, GeometryFrame(f"moving_{o.name}"))
            gid = scene_graph.RegisterGeometry(
                self.source_id, frame, GeometryInstance(RigidTransform(), Box(*o.box), o.name)
            )
            scene_graph.AssignRole(self.source_id, gid, ProximityProperties())
            ill = IllustrationProperties()
            ill.AddProperty("phong", "diffuse", Rgba(*rgba))
            scene_graph.AssignRole(self.source_id, gid, ill)
            per = PerceptionProperties()
            per.AddProperty("phong", "diffuse", Rgba(*rgba))
            per.AddProperty("label", "id", RenderLabel(MOVING_LABEL_BASE + n))
            scene_graph.AssignRole(self.source_id, gid, per)
            self.frame_ids.append(frame)
            self.geometry_ids.append(gid)
        self.geometry_pose_output = self.DeclareAbstractOutputPort(
            "geometry_pose",
            lambda: AbstractValue.Make(FramePoseVector()),
            self._calc_poses,
            prerequisites_of_calc={self.time_ticket()},
        )
        self.grid, self.params = grid, params
        if grid is not None:
            self.obstacle_map_output = self.DeclareAbstractOutputPort(
                "obstacle_map",
                lambda: AbstractValue.Make(ObstacleMap.empty(grid)),
                lambda c, o: o.set_value(self.obstacle_map(c.get_time())),
                prerequisites_of_calc={self.time_ticket()},
            )

    def obstacle_map(self, t: float) -> ObstacleMap:
        """The boxes at time t on the grid: every cell a box's footprint
        touches, at its top (rounded up to the height step), lent to the
        neighbours as the camera's map is (``params.dilation``)."""
        g, p = self.grid, self.params
        if g is None:
            raise ParameterError("MovingBoxes.obstacle_map needs the grid: give MovingBoxes(grid=..., params=...).")
        H = np.zeros(g.shape)
        for o in self.obstacles:
            c, half = o.position(t), np.asarray(o.box, float) / 2
            i, j, _ = g.cells_of(np.array([c[0] - half[0], c[0] + half[0]]), np.array([c[1] - half[1], c[1] + half[1]]))
            i0, i1 = max(int(i[0]), 0), min(int(i[1]), g.shape[0] - 1)
            j0, j1 = max(int(j[0]), 0), min(int(j[1]), g.shape[1] - 1)
            top = np.ceil((c[2] + half[2]) / p.height_step - 1e-9) * p.height_step
            if i0 <= i1 and j0 <= j1 and top > p.floor:
                H[i0 : i1 + 1, j0 : j1 + 1] = np.maximum(H[i0 : i1 + 1, j0 : j1 + 1], top)
        return ObstacleMap(g, dilate(H, int(p.dilation)), float(t))

    def _calc_poses(self, context, output) -> None:
        poses = output.get_mutable_value()
        poses.clear()
        t = context.get_time()
        for frame, o in zip(self.frame_ids, self.obstacles):
            poses.set_value(frame, RigidTransform(o.position(t)))
