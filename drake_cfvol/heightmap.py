"""Height map, height function (paper eq. 1) and the volume V (SPEC 5).

Everything is vectorised over cells with numpy. Distances to footprints come
from distance maps on a fine raster (``VolumeParams.raster``, independent of
R), sampled at the cell centres, so their cost does not grow with R.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy.ndimage import distance_transform_edt

from drake_cfvol import kernel as K
from drake_cfvol.exceptions import ParameterError
from drake_cfvol.params import VolumeParams

__all__ = ["HeightMap", "height_function", "FootprintRaster", "RangeMax2D", "Volume"]


@dataclasses.dataclass(frozen=True)
class HeightMap:
    """A height map: origin O_h on the floor, sides x_dim, y_dim, at most R
    cells (SPEC 5): side = sqrt(x_dim y_dim / R), m = floor(x_dim / side),
    n = floor(y_dim / side).

    Attributes:
        origin: (x, y) of the corner, m; the floor is z = 0.
        x_dim, y_dim: side lengths, m.
        resolution: R.
    """

    origin: tuple[float, float]
    x_dim: float
    y_dim: float
    resolution: int

    def __post_init__(self):
        if not (self.x_dim > 0 and self.y_dim > 0):
            raise ParameterError(f"height map sides must be > 0 m, got {self.x_dim} x {self.y_dim}.")
        if int(self.resolution) <= 0:
            raise ParameterError(f"resolution R must be a positive number of cells, got {self.resolution}.")
        if self.m < 1 or self.n < 1:
            raise ParameterError(
                f"R = {self.resolution} gives no whole cell on a {self.x_dim} x {self.y_dim} m map; raise R.")

    @property
    def side(self) -> float:
        """Cell side, m."""
        return float(np.sqrt(self.x_dim * self.y_dim / self.resolution))

    @property
    def m(self) -> int:
        """Rows (along x)."""
        return int(np.floor(self.x_dim / self.side + 1e-9))

    @property
    def n(self) -> int:
        """Columns (along y)."""
        return int(np.floor(self.y_dim / self.side + 1e-9))

    @property
    def shape(self) -> tuple[int, int]:
        return (self.m, self.n)

    def centres(self) -> tuple[np.ndarray, np.ndarray]:
        """(X, Y) of the cell centres, each (m, n), m."""
        s = self.side
        x = self.origin[0] + (np.arange(self.m) + 0.5) * s
        y = self.origin[1] + (np.arange(self.n) + 0.5) * s
        return np.meshgrid(x, y, indexing="ij")


def height_function(d_t, d_g, d_ng, active, params: VolumeParams) -> np.ndarray:
    """Paper eq. 1 with every Delta clamped to [0, 1] (SPEC 5).

    h(c) = A_t(c) h_max (Delta_t^a_t + Delta_g^a_g + Delta_ng^a_ng), with
    A_t(c) = 0 where d_t < d_t,LB or where ``active`` is False.

    Args:
        d_t, d_g, d_ng: horizontal distances from the cell centres to the
            trail, goal and no-goal footprints, m (+inf for an empty set).
        active: False where the cell is out of reach.
        params: the parameters.

    Returns:
        Heights, m, same shape as the inputs.
    """
    p = params
    d_t, d_g, d_ng = (np.asarray(a, float) for a in (d_t, d_g, d_ng))
    with np.errstate(invalid="ignore"):
        delta_t = np.clip((d_t - p.d_t_lb) / (p.d_t_ub - p.d_t_lb), 0.0, 1.0)
        delta_g = np.clip((d_g - p.d_g_lb) / (p.d_g_ub - p.d_g_lb), 0.0, 1.0)
        delta_ng = np.clip((p.d_ng_ub - d_ng) / p.d_ng_ub, 0.0, 1.0)
    # inf - inf never occurs: each Delta uses one distance; clip(inf) = 1 and
    # clip(-inf) = 0 as an empty set requires.
    h = p.h_max * (delta_t ** p.alpha_t + delta_g ** p.alpha_g + delta_ng ** p.alpha_ng)
    on = np.asarray(active, bool) & (d_t >= p.d_t_lb)
    return np.where(on, h, 0.0)


class FootprintRaster:
    """A fine raster of the floor for distances to xy footprints.

    Args:
        lo, hi: (x, y) corners of the area of interest, m.
        pixel: pixel size, m.
        pad: margin added around the area (footprints nearby but outside
            still count), m.
    """

    def __init__(self, lo, hi, pixel: float, pad: float):
        self.pixel = float(pixel)
        self.lo = np.asarray(lo, float) - pad
        hi = np.asarray(hi, float) + pad
        self.shape = tuple(int(np.ceil(v)) for v in (hi - self.lo) / self.pixel)

    def empty(self) -> np.ndarray:
        return np.zeros(self.shape, dtype=bool)

    def _pixel_centres(self, i0, i1, j0, j1):
        x = self.lo[0] + (np.arange(i0, i1) + 0.5) * self.pixel
        y = self.lo[1] + (np.arange(j0, j1) + 0.5) * self.pixel
        return np.meshgrid(x, y, indexing="ij")

    def fill_polygon(self, mask: np.ndarray, poly: np.ndarray) -> None:
        """Marks the pixels whose centre lies in a convex polygon (n, 2),
        plus the pixel under each vertex (so thin shapes are never lost)."""
        poly = np.asarray(poly, float)
        lo = np.floor((poly.min(0) - self.lo) / self.pixel).astype(int)
        hi = np.ceil((poly.max(0) - self.lo) / self.pixel).astype(int) + 1
        i0, j0 = np.maximum(lo, 0)
        i1, j1 = np.minimum(hi, self.shape)
        if i0 < i1 and j0 < j1:
            X, Y = self._pixel_centres(i0, i1, j0, j1)
            inside = np.ones(X.shape, bool)
            c = poly.mean(0)
            for a, b in zip(poly, np.roll(poly, -1, axis=0)):
                e = b - a
                nrm = np.array([e[1], -e[0]])
                if np.dot(nrm, c - a) > 0:
                    nrm = -nrm
                inside &= (X - a[0]) * nrm[0] + (Y - a[1]) * nrm[1] <= 1e-12
            mask[i0:i1, j0:j1] |= inside
        idx = np.floor((poly - self.lo) / self.pixel).astype(int)
        ok = np.all((idx >= 0) & (idx < self.shape), axis=1)
        mask[idx[ok, 0], idx[ok, 1]] = True

    def distance(self, mask: np.ndarray) -> np.ndarray:
        """Distance from each pixel centre to the nearest marked pixel, m (0
        on marked pixels, +inf if none is marked)."""
        if not mask.any():
            return np.full(self.shape, np.inf)
        return distance_transform_edt(~mask, sampling=self.pixel)

    def disc_distance(self, centres: np.ndarray, radii: np.ndarray, quantum: float = 0.02) -> np.ndarray:
        """Distance to the union of discs, max(0, |x - c| - r) minimised over
        discs, with radii rounded up to ``quantum`` classes."""
        out = np.full(self.shape, np.inf)
        if len(centres) == 0:
            return out
        classes = np.ceil(np.asarray(radii) / quantum) * quantum
        for r in np.unique(classes):
            sel = classes == r
            idx = np.floor((centres[sel] - self.lo) / self.pixel).astype(int)
            ok = np.all((idx >= 0) & (idx < self.shape), axis=1)
            if not ok.any():
                continue
            mask = self.empty()
            mask[idx[ok, 0], idx[ok, 1]] = True
            # The pixel centre is within pixel/sqrt(2) of the true centre.
            d = self.distance(mask) - r - self.pixel / np.sqrt(2)
            np.minimum(out, np.maximum(d, 0.0), out=out)
        return out

    def sample(self, field: np.ndarray, X: np.ndarray, Y: np.ndarray) -> np.ndarray:
        """Nearest-pixel values of a field at points (X, Y)."""
        i = np.clip(np.floor((X - self.lo[0]) / self.pixel).astype(int), 0, self.shape[0] - 1)
        j = np.clip(np.floor((Y - self.lo[1]) / self.pixel).astype(int), 0, self.shape[1] - 1)
        return field[i, j]


class RangeMax2D:
    """A 2-D sparse table: the maximum over any axis-aligned block of cells in
    O(1) (four lookups), built in O(m n log m log n)."""

    def __init__(self, values: np.ndarray):
        values = np.asarray(values, float)
        m, n = values.shape
        self.m, self.n = m, n
        la = max(1, int(np.floor(np.log2(m))) + 1)
        lb = max(1, int(np.floor(np.log2(n))) + 1)
        table = np.full((la, lb, m, n), -np.inf)
        table[0, 0] = values
        for b in range(1, lb):
            w = 1 << (b - 1)
            table[0, b, :, : n - w] = np.maximum(table[0, b - 1, :, : n - w], table[0, b - 1, :, w:])
        for a in range(1, la):
            w = 1 << (a - 1)
            table[a, :, : m - w, :] = np.maximum(table[a - 1, :, : m - w, :], table[a - 1, :, w:, :])
        self.table = table

    def query(self, i0, i1, j0, j1) -> np.ndarray:
        """Max over cells [i0, i1] x [j0, j1] (inclusive, clipped to the
        grid); -inf where the block is empty."""
        i0 = np.maximum(np.asarray(i0), 0)
        j0 = np.maximum(np.asarray(j0), 0)
        i1 = np.minimum(np.asarray(i1), self.m - 1)
        j1 = np.minimum(np.asarray(j1), self.n - 1)
        empty = (i1 < i0) | (j1 < j0)
        i0c, i1c = np.where(empty, 0, i0), np.where(empty, 0, i1)
        j0c, j1c = np.where(empty, 0, j0), np.where(empty, 0, j1)
        a = np.floor(np.log2(i1c - i0c + 1)).astype(np.int64)
        b = np.floor(np.log2(j1c - j0c + 1)).astype(np.int64)
        ia = i1c - (1 << a) + 1
        jb = j1c - (1 << b) + 1
        t = self.table
        out = np.maximum(np.maximum(t[a, b, i0c, j0c], t[a, b, ia, j0c]),
                         np.maximum(t[a, b, i0c, jb], t[a, b, ia, jb]))
        return np.where(empty, -np.inf, out)


@dataclasses.dataclass
class Volume:
    """The volume V: a column side x side x h(c) on the floor for each cell
    with h(c) > 0.

    Attributes:
        heightmap: the grid.
        heights: (m, n) column heights after lowering, m.
        raw_heights: (m, n) heights from eq. 1 before lowering, m.
        lowered: number of columns lowered because they touched the robot at
            a nominal waypoint (coarse cells, SPEC 5).
        dropped: number of columns removed for the same reason.
    """

    heightmap: HeightMap
    heights: np.ndarray
    raw_heights: np.ndarray
    lowered: int = 0
    dropped: int = 0

    def __post_init__(self):
        self._rmq = None
        self._kernel_table = None

    def kernel_table(self) -> np.ndarray:
        """The compiled kernel's range-max table of the heights (built once;
        call :meth:`changed` after editing ``heights``)."""
        if self._kernel_table is None:
            self._kernel_table = K.range_max_table(np.ascontiguousarray(self.heights, dtype=np.float64))
        return self._kernel_table

    def changed(self) -> None:
        """Forget cached tables after ``heights`` changed."""
        self._rmq = None
        self._kernel_table = None

    @property
    def n_boxes(self) -> int:
        """Number of columns (cells with h > 0)."""
        return int(np.count_nonzero(self.heights > 0))

    @property
    def range_max(self) -> RangeMax2D:
        if self._rmq is None:
            self._rmq = RangeMax2D(self.heights)
        return self._rmq

    def boxes(self) -> tuple[np.ndarray, np.ndarray]:
        """Centres (N, 3) and sizes (N, 3) of the columns, m."""
        X, Y = self.heightmap.centres()
        on = self.heights > 0
        h = self.heights[on]
        s = self.heightmap.side
        centres = np.stack([X[on], Y[on], h / 2], axis=1)
        sizes = np.stack([np.full_like(h, s), np.full_like(h, s), h], axis=1)
        return centres, sizes

    def sphere_hits(self, p: np.ndarray, r: np.ndarray, e_xy=0.0, e_z=0.0) -> np.ndarray:
        """Conservative test of spheres against the columns.

        A sphere (p, r) is reported if its lowest point is below the tallest
        column over the cells that its xy bounding square touches. Any sphere
        that truly intersects a column is reported.

        Args:
            p: (..., 3) centres, m.
            r: (...) radii, m.
            e_xy, e_z: (...) how far the sphere may move horizontally and
                vertically from p (motion between samples), m.

        Returns:
            (...) bool.
        """
        hm = self.heightmap
        s = hm.side
        r_z = np.asarray(r, float) + e_z
        r = np.asarray(r, float) + e_xy
        i0 = np.floor((p[..., 0] - r - hm.origin[0]) / s).astype(np.int64)
        i1 = np.floor((p[..., 0] + r - hm.origin[0]) / s).astype(np.int64)
        j0 = np.floor((p[..., 1] - r - hm.origin[1]) / s).astype(np.int64)
        j1 = np.floor((p[..., 1] + r - hm.origin[1]) / s).astype(np.int64)
        top = self.range_max.query(i0, i1, j0, j1)
        return (top > 0) & (p[..., 2] - r_z < top)

    def lower_under(self, p: np.ndarray, r: np.ndarray, clearance: float) -> None:
        """Lowers (or drops) every column that :meth:`sphere_hits` would
        report for the given spheres, to ``clearance`` below their bottoms."""
        p = p.reshape(-1, 3)
        r = np.broadcast_to(np.asarray(r, float), p.shape[:1]).reshape(-1)
        for _ in range(3):
            hit = self.sphere_hits(p, r)
            if not hit.any():
                break
            hm = self.heightmap
            s = hm.side
            for c, rr in zip(p[hit], r[hit]):
                i0 = max(int(np.floor((c[0] - rr - hm.origin[0]) / s)), 0)
                i1 = min(int(np.floor((c[0] + rr - hm.origin[0]) / s)), hm.m - 1)
                j0 = max(int(np.floor((c[1] - rr - hm.origin[1]) / s)), 0)
                j1 = min(int(np.floor((c[1] + rr - hm.origin[1]) / s)), hm.n - 1)
                cap = c[2] - rr - clearance
                block = self.heights[i0: i1 + 1, j0: j1 + 1]
                np.minimum(block, max(cap, 0.0), out=block)
            self.changed()
        changed = self.heights < self.raw_heights
        self.dropped = int(np.count_nonzero(changed & (self.heights <= 0)))
        self.lowered = int(np.count_nonzero(changed & (self.heights > 0)))
