"""An obstacle height map from a depth camera's points (docs/spec.md, SPEC 12).

The camera sees the whole cell: the floor, the cell's known obstacles, the
robot and whatever else came in. A pixel is *new* where the camera sees
something nearer than the cell's model (the known obstacles and the robot
at its known pose, rendered from the same camera) by more than a
tolerance; it *confirms the model* where the two agree. The map keeps, per
cell of a floor grid, the top of what new stands there (0: nothing):

- a cell with new points takes their highest z, rounded up to a height
  step, and lends it to its neighbours (a one-cell dilation, so that edges
  between pixels are covered);
- a cell where the camera saw the known scene (floor, a known obstacle)
  and nothing new is cleared;
- a cell the camera did not see (out of view, in a shadow) keeps what it
  had; one hidden by the robot also takes the height of any cell last seen
  occupied within ``speed`` times the time since (at most ``spread_time``):
  what moves may have moved in under the robot unseen.

The map keeps what was seen (``observed``, with the time each occupied cell
was last seen: ``seen_at``) apart from what it reports (``heights``), so
assumed occupancy never spreads from assumed occupancy.
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np

from drake_cfvol.algorithm.heightmap import _merge_equal
from drake_cfvol.exceptions import ParameterError

__all__ = ["MapGrid", "ObstacleMap", "PerceptionParams", "merged_rectangles"]


@dataclasses.dataclass(frozen=True)
class PerceptionParams:
    """How points become an obstacle map.

    Attributes:
        cell: the map's cell side, m.
        height_step: heights are rounded up to a multiple of this, m.
        depth_tolerance: a pixel is new where it is nearer than the model
            by more than this, m.
        floor: points below this height are the floor, m.
        dilation: cells an occupied cell lends its height to, each way.
        speed: the speed assumed for what the camera sees, m/s: how fast
            occupancy spreads into the cells the robot hides.
        spread_time: occupancy spreads for at most this long, s (what has
            been out of sight longer is held where it was last seen, grown
            by ``speed`` x ``spread_time``).
    """

    cell: float = 0.05
    height_step: float = 0.02
    depth_tolerance: float = 0.02
    floor: float = 0.02
    dilation: int = 1
    speed: float = 0.5
    spread_time: float = 1.0

    def __post_init__(self):
        for name in ("cell", "height_step", "depth_tolerance"):
            if not getattr(self, name) > 0:
                raise ParameterError(f"PerceptionParams.{name} must be > 0 m, got {getattr(self, name)!r}.")
        if not self.floor >= 0:
            raise ParameterError(f"PerceptionParams.floor must be >= 0 m, got {self.floor!r}.")
        if int(self.dilation) != self.dilation or self.dilation < 0:
            raise ParameterError(
                f"PerceptionParams.dilation must be a whole number of cells >= 0, got {self.dilation!r}."
            )
        if not (self.speed >= 0 and self.spread_time >= 0):
            raise ParameterError(
                f"PerceptionParams.speed and spread_time must be >= 0, got {self.speed!r} m/s, {self.spread_time!r} s."
            )


@dataclasses.dataclass(frozen=True)
class MapGrid:
    """A floor grid: corner ``origin`` (x, y), square cells of ``side``,
    ``shape`` = (cells along x, cells along y)."""

    origin: tuple[float, float]
    side: float
    shape: tuple[int, int]

    @classmethod
    def covering(cls, origin, size, side: float) -> "MapGrid":
        """The grid of ``side`` cells covering a rectangle (origin, size), m."""
        if not side > 0:
            raise ParameterError(f"a map cell's side must be > 0 m, got {side!r}.")
        shape = (max(1, int(np.ceil(size[0] / side - 1e-9))), max(1, int(np.ceil(size[1] / side - 1e-9))))
        return cls((float(origin[0]), float(origin[1])), float(side), shape)

    def cells_of(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(i, j, inside) of world points: their cell, and whether it lies on the grid."""
        i = np.floor((np.asarray(x) - self.origin[0]) / self.side).astype(np.int64)
        j = np.floor((np.asarray(y) - self.origin[1]) / self.side).astype(np.int64)
        inside = (i >= 0) & (i < self.shape[0]) & (j >= 0) & (j < self.shape[1])
        return i, j, inside


def _dilate(H: np.ndarray, r: int) -> np.ndarray:
    """Max over the (2r+1) x (2r+1) neighbourhood of each cell (separably:
    along the rows, then the columns)."""
    out = np.asarray(H, float).copy()
    for axis in (0, 1):
        src = out.copy()
        n = src.shape[axis]
        for d in range(1, min(int(r), n - 1) + 1):
            a = [slice(None)] * 2
            b = [slice(None)] * 2
            a[axis], b[axis] = slice(d, None), slice(None, n - d)
            np.maximum(out[tuple(a)], src[tuple(b)], out=out[tuple(a)])
            np.maximum(out[tuple(b)], src[tuple(a)], out=out[tuple(b)])
    return out


def merged_rectangles(H: np.ndarray) -> np.ndarray:
    """(N, 5) rectangles [i0, i1, j0, j1, h] of equal positive height
    covering every positive cell of H exactly once (the heightmap's merge,
    run on the occupied cells' bounding block only)."""
    i, j = np.nonzero(H > 0)
    if not len(i):
        return np.zeros((0, 5))
    i0, j0 = i.min(), j.min()
    rects = np.array(_merge_equal(H[i0 : i.max() + 1, j0 : j.max() + 1]), float).reshape(-1, 5)
    rects[:, :2] += i0
    rects[:, 2:4] += j0
    return rects


@dataclasses.dataclass(frozen=True)
class ObstacleMap:
    """What a depth camera found in the cell beyond its model: per cell, the
    top of what stands there, m (0: nothing seen).

    Attributes:
        grid: the floor grid.
        heights: (m, n) heights, m: what the map reports.
        stamp: the time of the image it was made from, s (-inf: none yet).
        observed: (m, n) the heights last seen, m (None: ``heights``).
        seen_at: (m, n) when each occupied cell of ``observed`` was last
            seen, s (None: at ``stamp``).
    """

    grid: MapGrid
    heights: np.ndarray
    stamp: float = -np.inf
    observed: np.ndarray | None = None
    seen_at: np.ndarray | None = None

    @classmethod
    def empty(cls, grid: MapGrid) -> "ObstacleMap":
        """A map with nothing on it."""
        return cls(grid, np.zeros(grid.shape))

    def __deepcopy__(self, memo) -> "ObstacleMap":
        # Never changed once made (every update makes a new map): Drake's
        # state copies (an abstract state is deep-copied at every
        # unrestricted update) share it.
        return self

    @property
    def occupied(self) -> int:
        """Number of cells with something on them."""
        return int(np.count_nonzero(self.heights > 0))

    def same_as(self, other: "ObstacleMap | None") -> bool:
        """Whether two maps have the same grid and heights."""
        return other is not None and other.grid == self.grid and np.array_equal(other.heights, self.heights)

    def integrate(
        self,
        new_points: np.ndarray,
        seen_points: np.ndarray,
        stamp: float,
        params: PerceptionParams,
        hidden_points: np.ndarray | None = None,
    ) -> "ObstacleMap":
        """The map after one image (see the module's rules).

        Args:
            new_points: (3, N) world points of the new pixels, m.
            seen_points: (3, M) world points where the camera saw the model
                (the floor or a known obstacle, not the robot), m.
            stamp: the image's time, s.
            params: the perception settings.
            hidden_points: (3, H) points whose cells the robot hides (where
                the camera's rays through the robot meet it and the floor),
                m; their cells and those next to them are hidden.
        """
        new_points = np.asarray(new_points, float).reshape(3, -1)
        seen_points = np.asarray(seen_points, float).reshape(3, -1)
        g = self.grid
        occ = np.zeros(g.shape)
        keep = np.isfinite(new_points).all(axis=0) & (new_points[2] > params.floor)
        i, j, inside = g.cells_of(new_points[0, keep], new_points[1, keep])
        z = np.ceil(new_points[2, keep][inside] / params.height_step - 1e-9) * params.height_step
        np.maximum.at(occ, (i[inside], j[inside]), z)
        seen = np.zeros(g.shape, bool)
        ok = np.isfinite(seen_points).all(axis=0)
        i, j, inside = g.cells_of(seen_points[0, ok], seen_points[1, ok])
        seen[i[inside], j[inside]] = True
        hidden = np.zeros(g.shape, bool)
        if hidden_points is not None:
            hp = np.asarray(hidden_points, float).reshape(3, -1)
            ok = np.isfinite(hp).all(axis=0)
            i, j, inside = g.cells_of(hp[0, ok], hp[1, ok])
            hidden[i[inside], j[inside]] = True
            hidden = _dilate(hidden.astype(float), 1) > 0
        prev = self.heights if self.observed is None else self.observed
        prev_at = np.full(g.shape, self.stamp) if self.seen_at is None else self.seen_at
        now = occ > 0
        observed = np.where(now, occ, np.where(seen, 0.0, prev))
        seen_at = np.where(now, float(stamp), prev_at)
        heights = _dilate(observed, int(params.dilation))
        under = hidden & ~seen & ~now
        if under.any() and params.speed > 0:
            held = (observed > 0) & ~now
            age = np.minimum(np.where(held, float(stamp) - seen_at, 0.0), params.spread_time)
            radius = np.ceil(params.speed * age / g.side - 1e-9).astype(int)
            for r in np.unique(radius[held]):
                grown = _dilate(np.where(held & (radius == r), observed, 0.0), int(r) + int(params.dilation))
                heights[under] = np.maximum(heights[under], grown[under])
        return ObstacleMap(g, heights, float(stamp), observed, seen_at)

    @functools.cached_property
    def rectangles(self) -> np.ndarray:
        """(N, 5) equal-height rectangles [i0, i1, j0, j1, h] (cells [i0, i1)
        x [j0, j1)) covering exactly the occupied cells (computed once)."""
        return merged_rectangles(self.heights)

    def boxes(self) -> tuple[np.ndarray, np.ndarray]:
        """The occupied cells as few boxes standing on the floor, exactly
        covering them (equal-height runs merged): centres (N, 3), full sizes
        (N, 3), m."""
        rects = self.rectangles
        s, (x0, y0) = self.grid.side, self.grid.origin
        centres = np.stack(
            [x0 + (rects[:, 0] + rects[:, 1]) / 2 * s, y0 + (rects[:, 2] + rects[:, 3]) / 2 * s, rects[:, 4] / 2],
            axis=1,
        )
        sizes = np.stack([(rects[:, 1] - rects[:, 0]) * s, (rects[:, 3] - rects[:, 2]) * s, rects[:, 4]], axis=1)
        return centres, sizes

    def columns(self) -> tuple[np.ndarray, np.ndarray]:
        """(centres (N, 2) of the occupied cells, their heights (N,)), m."""
        i, j = np.nonzero(self.heights > 0)
        s, (x0, y0) = self.grid.side, self.grid.origin
        return np.stack([x0 + (i + 0.5) * s, y0 + (j + 0.5) * s], axis=1), self.heights[i, j]
