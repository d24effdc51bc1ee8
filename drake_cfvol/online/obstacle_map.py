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
import math
from collections.abc import Iterable, Sequence

import numpy as np
import numpy.typing as npt
from numba import njit

from drake_cfvol.algorithm.heightmap import merge_equal
from drake_cfvol.exceptions import ParameterError

__all__ = ["MapGrid", "ObstacleMap", "PerceptionParams", "dilate", "merged_rectangles"]

#: A source of points for :meth:`ObstacleMap.integrate_sources`: points
#: (3, N), and a mask (N,) of those to take (None: all).
PointSource = tuple[npt.ArrayLike, npt.ArrayLike | None]


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
    def covering(
        cls, origin: Sequence[float] | np.ndarray, size: Sequence[float] | np.ndarray, side: float
    ) -> "MapGrid":
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


def dilate(H: np.ndarray, r: int) -> np.ndarray:
    """Max over the (2r+1) x (2r+1) neighbourhood of each cell (separably:
    along the rows, then the columns). A map of heights (no negative cell)
    is dilated only around its occupied block: elsewhere every
    neighbourhood holds zeros only."""
    H = np.ascontiguousarray(H, dtype=np.float64)
    r = int(r)
    if H.size and H.min() >= 0.0:
        rows, cols = np.flatnonzero(H.any(axis=1)), np.flatnonzero(H.any(axis=0))
        if not len(rows):
            return H.copy()
        i0, i1 = max(rows[0] - r, 0), min(rows[-1] + r + 1, H.shape[0])
        j0, j1 = max(cols[0] - r, 0), min(cols[-1] + r + 1, H.shape[1])
        out = np.zeros_like(H)
        out[i0:i1, j0:j1] = _dilate_max(np.ascontiguousarray(H[i0:i1, j0:j1]), r)
        return out
    return _dilate_max(H, r)


@njit(cache=True)
def _dilate_max(H, r):
    """:func:`dilate` in compiled code: each axis in turn, the max over
    the cells within r along it (exact: a max of the same values), by van
    Herk and Gil-Werman's block prefix and suffix maxima (three
    comparisons per cell whatever r)."""
    out = H.copy()
    m, n = out.shape
    w = 2 * r + 1
    for axis in range(2):
        lines, length = (n, m) if axis == 0 else (m, n)
        L = length + 2 * r
        a, g, h = np.empty(L), np.empty(L), np.empty(L)
        for line in range(lines):
            for k in range(L):
                i = k - r
                if 0 <= i < length:
                    a[k] = out[i, line] if axis == 0 else out[line, i]
                else:
                    a[k] = -np.inf
            for k in range(L):
                g[k] = a[k] if k % w == 0 else max(g[k - 1], a[k])
            for k in range(L - 1, -1, -1):
                h[k] = a[k] if (k % w == w - 1 or k == L - 1) else max(h[k + 1], a[k])
            for i in range(length):
                v = max(h[i], g[i + w - 1])
                if axis == 0:
                    out[i, line] = v
                else:
                    out[line, i] = v
    return out


@njit(cache=True)
def _cell(x, y, ox, oy, side, m, n):
    """A point's cell (i, j), (-1, -1) off the grid (x, y finite)."""
    i, j = math.floor((x - ox) / side), math.floor((y - oy) / side)
    if 0 <= i < m and 0 <= j < n:
        return int(i), int(j)
    return -1, -1


@njit(cache=True)
def _occupy(P, use, ox, oy, side, floor, step, occ):
    """occ = max(occ, each used point's z rounded up to ``step``) in its
    cell, over the points (3, N) that are finite, above ``floor`` and on
    the grid (``use``: (N,) bools, or empty for all)."""
    m, n = occ.shape
    for k in range(P.shape[1]):
        if use.size and not use[k]:
            continue
        x, y, z = P[0, k], P[1, k], P[2, k]
        if not (np.isfinite(x) and np.isfinite(y) and np.isfinite(z) and z > floor):
            continue
        i, j = _cell(x, y, ox, oy, side, m, n)
        if i >= 0:
            occ[i, j] = max(occ[i, j], math.ceil(z / step - 1e-9) * step)


@njit(cache=True)
def _mark(P, use, ox, oy, side, out):
    """out[cell] = True for each used finite point (3, N) on the grid."""
    m, n = out.shape
    for k in range(P.shape[1]):
        if use.size and not use[k]:
            continue
        x, y, z = P[0, k], P[1, k], P[2, k]
        if not (np.isfinite(x) and np.isfinite(y) and np.isfinite(z)):
            continue
        i, j = _cell(x, y, ox, oy, side, m, n)
        if i >= 0:
            out[i, j] = True


@njit(cache=True)
def _observe(occ, seen, prev, prev_at, stamp):
    """(observed, seen_at): a cell with new points takes them (seen now),
    one where the known scene was seen is cleared, any other keeps what it
    had."""
    observed, seen_at = np.empty_like(occ), np.empty_like(occ)
    for i in range(occ.shape[0]):
        for j in range(occ.shape[1]):
            now = occ[i, j] > 0
            observed[i, j] = occ[i, j] if now else (0.0 if seen[i, j] else prev[i, j])
            seen_at[i, j] = stamp if now else prev_at[i, j]
    return observed, seen_at


@njit(cache=True)
def _spread(heights, hidden, seen, occ, observed, seen_at, when, dilation):
    """Under the robot (a hidden cell neither seen nor new), heights takes
    the height of each cell last seen occupied (held: occupied, not seen
    now) within its radius plus ``dilation`` cells (Chebyshev), its
    radius ceil(speed x age / side) cells, age = min(stamp - its last
    sight, spread_time): what moves may have moved in under it unseen.
    ``when``: (stamp, speed, spread_time, side)."""
    stamp, speed, spread_time, side = when
    m, n = heights.shape
    for a in range(m):
        for b in range(n):
            if not (observed[a, b] > 0 and not occ[a, b] > 0):
                continue
            age = min(stamp - seen_at[a, b], spread_time)
            R = int(math.ceil(speed * age / side - 1e-9)) + dilation
            for i in range(max(0, a - R), min(m - 1, a + R) + 1):
                for j in range(max(0, b - R), min(n - 1, b + R) + 1):
                    if hidden[i, j] and not seen[i, j] and not occ[i, j] > 0:
                        heights[i, j] = max(heights[i, j], observed[a, b])


def _sources(sources):
    """Each (points (3, N), mask (N,) bools or None) as the compiled
    marking's arrays: a (3, N) float array as it is (float32 or float64,
    any layout: each coordinate is widened to float64 as it is read, so
    no copy of an image's points is made), anything else converted."""
    for points, mask in sources:
        P = points
        if not (isinstance(P, np.ndarray) and P.ndim == 2 and P.shape[0] == 3 and P.dtype in (np.float32, np.float64)):
            P = np.ascontiguousarray(np.asarray(points, float).reshape(3, -1))
        yield P, np.zeros(0, bool) if mask is None else np.ascontiguousarray(mask, dtype=bool).reshape(-1)


def merged_rectangles(H: np.ndarray) -> np.ndarray:
    """(N, 5) rectangles [i0, i1, j0, j1, h] of equal positive height
    covering every positive cell of H exactly once (the heightmap's merge,
    run on the occupied cells' bounding block only)."""
    i, j = np.nonzero(H > 0)
    if not len(i):
        return np.zeros((0, 5))
    i0, j0 = i.min(), j.min()
    rects = np.array(merge_equal(H[i0 : i.max() + 1, j0 : j.max() + 1]), float).reshape(-1, 5)
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
        hidden = None if hidden_points is None else [(hidden_points, None)]
        return self.integrate_sources([(new_points, None)], [(seen_points, None)], stamp, params, hidden)

    def integrate_sources(
        self,
        new: Iterable[PointSource],
        seen: Iterable[PointSource],
        stamp: float,
        params: PerceptionParams,
        hidden: Iterable[PointSource] | None = None,
    ) -> "ObstacleMap":
        """:meth:`integrate` with each kind of point given as sources
        ((points (3, N), mask (N,) bools or None: all), ...), so that an
        image's pixels are taken where they lie, never gathered."""
        g = self.grid
        ox, oy = g.origin
        occ = np.zeros(g.shape)
        for P, use in _sources(new):
            _occupy(P, use, ox, oy, g.side, float(params.floor), float(params.height_step), occ)
        seen_cells = np.zeros(g.shape, bool)
        for P, use in _sources(seen):
            _mark(P, use, ox, oy, g.side, seen_cells)
        hidden_cells = np.zeros(g.shape, bool)
        if hidden is not None:
            for P, use in _sources(hidden):
                _mark(P, use, ox, oy, g.side, hidden_cells)
            hidden_cells = dilate(hidden_cells.astype(float), 1) > 0
        prev = self.heights if self.observed is None else self.observed
        prev_at = np.full(g.shape, self.stamp) if self.seen_at is None else self.seen_at
        observed, seen_at = _observe(
            occ, seen_cells, np.ascontiguousarray(prev, dtype=np.float64), prev_at, float(stamp)
        )
        heights = dilate(observed, int(params.dilation))
        if params.speed > 0:
            _spread(
                heights,
                hidden_cells,
                seen_cells,
                occ,
                observed,
                seen_at,
                (float(stamp), float(params.speed), float(params.spread_time), float(g.side)),
                int(params.dilation),
            )
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
