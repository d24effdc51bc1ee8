"""The perceived obstacle map as proximity geometry, for the runtime safety
filter (SPEC 12)."""

from __future__ import annotations

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.geometry import Box, FramePoseVector, GeometryFrame, GeometryInstance, ProximityProperties, SceneGraph
from pydrake.math import RigidTransform
from pydrake.systems.framework import Context, LeafSystem

from drake_cfvol.exceptions import ParameterError
from drake_cfvol.online.obstacle_map import MapGrid, ObstacleMap, merged_rectangles
from drake_cfvol.online.reestimate import FrozenLog

__all__ = ["PerceivedColumns", "PARKED_Z", "tile_rectangles"]

#: An unused tile waits this far below the floor, m; a filter may skip
#: geometry posed below it.
PARKED_Z = -100.0


def tile_rectangles(heights: np.ndarray, levels: int, per_level: int) -> tuple[list, int]:
    """Square tiles covering the occupied cells of a height map.

    The occupied cells form rectangles (cells [i0, i1) x [j0, j1)); each is
    covered by squares of 2^l cells, l the largest level with 2^l at most
    its shorter side: in rows and columns, the last one flush with the
    rectangle's end, so no tile leaves the rectangle. A tile stands as high
    as the highest cell it covers. Where a level runs out of tiles, the next
    larger one takes the tile's place (a larger square from the same corner:
    it covers more, never less).

    Returns:
        (tiles, overflow): tiles as (level, i0, j0, h), and how many could
        not be placed at any level.
    """
    used = [0] * levels
    tiles, overflow = [], 0
    m, n = heights.shape
    for i0, i1, j0, j1, _ in merged_rectangles((heights > 0).astype(float)).astype(int):
        short = min(i1 - i0, j1 - j0)
        lv = min(int(np.floor(np.log2(short))), levels - 1)
        t = 1 << lv
        xs = sorted({min(i0 + a * t, i1 - t) for a in range(-(-(i1 - i0) // t))})
        ys = sorted({min(j0 + b * t, j1 - t) for b in range(-(-(j1 - j0) // t))})
        for x in xs:
            for y in ys:
                level = lv
                while level < levels and used[level] >= per_level:
                    level += 1
                if level == levels:
                    overflow += 1
                    continue
                used[level] += 1
                t_l = 1 << level
                tiles.append((level, x, y, float(heights[x : min(x + t_l, m), y : min(y + t_l, n)].max())))
    return tiles, overflow


class PerceivedColumns(LeafSystem):
    """The obstacle map's occupied cells as boxes in the SceneGraph:
    square columns of 1, 2, 4, ... cells (``levels`` sizes, ``per_level`` of
    each), standing from below the floor up to each cell's height; unused
    ones parked at :data:`PARKED_Z`. Proximity role only (the safety filter
    measures them; the camera does not see them, and a Meshcat recording
    would store every column at every frame: :meth:`tiles_log` keeps what
    it needs, :func:`drake_cfvol.comanip.recording.animate_columns` draws it).

    .. pydrake_system::

        name: PerceivedColumns
        input_ports:
        - obstacle_map
        output_ports:
        - geometry_pose
        - overflow

    Every ``log_period`` s (0: never) the tiles in force are logged in the
    context's state when they changed (:meth:`tiles_log`).

    ``overflow`` counts the tiles no level had room for (0 in a sized
    pool); connect ``geometry_pose`` to
    ``scene_graph.get_source_pose_port(system.source_id)``.

    Args:
        scene_graph: the diagram's SceneGraph.
        grid: the obstacle map's grid.
        levels: tile sizes (1, 2, ... 2^(levels-1) cells).
        per_level: tiles of each size.
        depth: each column's length, m (it reaches this far down from its top).
        log_period: s between looks at the tiles for :meth:`tiles_log`.
    """

    def __init__(
        self,
        scene_graph: SceneGraph,
        grid: MapGrid,
        *,
        levels: int = 5,
        per_level: int = 64,
        depth: float = 6.0,
        log_period: float = 0.0,
    ):
        super().__init__()
        if levels < 1 or per_level < 1:
            raise ParameterError(f"PerceivedColumns: levels and per_level must be >= 1, got {levels}, {per_level}.")
        self.grid, self.levels, self.per_level, self.depth = grid, int(levels), int(per_level), float(depth)
        self.source_id = scene_graph.RegisterSource("perceived_columns")
        self.frame_ids, self.geometry_ids = [], []
        for lv in range(self.levels):
            side = grid.side * (1 << lv)
            for n in range(self.per_level):
                frame = scene_graph.RegisterFrame(self.source_id, GeometryFrame(f"column_{lv}_{n}"))
                gid = scene_graph.RegisterGeometry(
                    self.source_id,
                    frame,
                    GeometryInstance(RigidTransform(), Box(side, side, self.depth), f"column_{lv}_{n}"),
                )
                scene_graph.AssignRole(self.source_id, gid, ProximityProperties())
                self.frame_ids.append(frame)
                self.geometry_ids.append(gid)
        self._last: tuple[ObstacleMap, tuple[list, int]] | None = (
            None  # (map, its tiles): a memo of the last map seen (it says nothing about the context)
        )
        self.obstacle_map_input = self.DeclareAbstractInputPort(
            "obstacle_map", AbstractValue.Make(ObstacleMap.empty(grid))
        )
        self.geometry_pose_output = self.DeclareAbstractOutputPort(
            "geometry_pose",
            lambda: AbstractValue.Make(FramePoseVector()),
            self._calc_poses,
            prerequisites_of_calc={self.obstacle_map_input.ticket()},
        )
        self.overflow_output = self.DeclareVectorOutputPort(
            "overflow",
            1,
            lambda c, o: o.SetAtIndex(0, float(self._tiles(c)[1])),
            prerequisites_of_calc={self.obstacle_map_input.ticket()},
        )
        self._log = self.DeclareAbstractState(AbstractValue.Make(FrozenLog()))
        if log_period > 0:
            self.DeclarePeriodicUnrestrictedUpdateEvent(
                period_sec=float(log_period), offset_sec=0.0, update=self._log_tiles
            )

    def _log_tiles(self, context, state) -> None:
        log = context.get_abstract_state(self._log).get_value()
        tiles = tuple(self._tiles(context)[0])
        if not log or log[-1][1] != tiles:
            state.get_mutable_abstract_state(self._log).set_value(log + ((context.get_time(), tiles),))

    def tiles_log(self, context: Context) -> tuple:
        """((t, tiles), ...): the tiles ((level, i, j, top), ...) in force
        from each time t on (logged every ``log_period`` s, when changed)."""
        return context.get_abstract_state(self._log).get_value()

    def _tiles(self, context):
        m = self.obstacle_map_input.Eval(context)
        if m.grid != self.grid:
            raise ParameterError(
                f"PerceivedColumns: the obstacle map's grid {m.grid} is not this system's "
                f"{self.grid}; build both from one MapGrid."
            )
        if self._last is None or self._last[0] is not m:  # both outputs of one map share the tiling
            self._last = (m, tile_rectangles(m.heights, self.levels, self.per_level))
        return self._last[1]

    def _calc_poses(self, context, output) -> None:
        tiles, _ = self._tiles(context)
        poses = output.get_mutable_value()
        poses.clear()
        next_free = [0] * self.levels
        s, (x0, y0) = self.grid.side, self.grid.origin
        for level, i, j, h in tiles:
            n = level * self.per_level + next_free[level]
            next_free[level] += 1
            half = 0.5 * s * (1 << level)
            poses.set_value(
                self.frame_ids[n], RigidTransform([x0 + i * s + half, y0 + j * s + half, h - 0.5 * self.depth])
            )
        parked = RigidTransform([x0, y0, PARKED_Z - self.depth])  # one pose for every unused tile (copied in)
        for level in range(self.levels):
            for n in range(next_free[level], self.per_level):
                poses.set_value(self.frame_ids[level * self.per_level + n], parked)
