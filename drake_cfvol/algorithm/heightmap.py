"""Height map, height function (paper eq. 1) and the volume V (SPEC 5).

Data and the height function, vectorised over cells with numpy; the
footprint distances that feed it are computed in :mod:`drake_cfvol.algorithm.volume`.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from drake_cfvol import kernel as K
from drake_cfvol.exceptions import ParameterError
from drake_cfvol.scene.params import VolumeParams

__all__ = ["HeightMap", "height_function", "merge_equal", "Volume"]


#: The volume's tables may take at most this much memory (bytes).
MAX_VOLUME_BYTES = 2 * 1024**3


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
                f"R = {self.resolution} gives no whole cell on a {self.x_dim} x {self.y_dim} m map; raise R."
            )
        if self.memory_bytes > MAX_VOLUME_BYTES:
            raise ParameterError(
                f"R = {self.resolution} would need about {self.memory_bytes / 1e9:.1f} GB for the volume's tables "
                f"(at most {MAX_VOLUME_BYTES / 1e9:.1f} GB allowed); lower R (the paper uses up to 20000)."
            )

    @property
    def memory_bytes(self) -> float:
        """Memory the volume's tables need at this R: the heights (twice),
        three distance maps and the range-maximum table, 8 bytes a cell."""
        m = self.x_dim / self.side
        n = self.y_dim / self.side
        levels = (np.floor(np.log2(max(m, 1.0))) + 1) * (np.floor(np.log2(max(n, 1.0))) + 1)
        return float(8.0 * m * n * (5 + levels))

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
    h = p.h_max * (delta_t**p.alpha_t + delta_g**p.alpha_g + delta_ng**p.alpha_ng)
    on = np.asarray(active, bool) & (d_t >= p.d_t_lb)
    return np.where(on, h, 0.0)


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
        self._kernel_table = None

    def kernel_table(self) -> np.ndarray:
        """The compiled kernel's range-max table of the heights (built once;
        call :meth:`changed` after editing ``heights``)."""
        if self._kernel_table is None:
            self._kernel_table = K.range_max_table(np.ascontiguousarray(self.heights, dtype=np.float64))
        return self._kernel_table

    def changed(self) -> None:
        """Forget cached tables after ``heights`` changed."""
        self._kernel_table = None

    @property
    def n_boxes(self) -> int:
        """Number of columns (cells with h > 0)."""
        return int(np.count_nonzero(self.heights > 0))

    def boxes(self) -> tuple[np.ndarray, np.ndarray]:
        """Centres (N, 3) and sizes (N, 3) of the columns, m."""
        X, Y = self.heightmap.centres()
        on = self.heights > 0
        h = self.heights[on]
        s = self.heightmap.side
        centres = np.stack([X[on], Y[on], h / 2], axis=1)
        sizes = np.stack([np.full_like(h, s), np.full_like(h, s), h], axis=1)
        return centres, sizes

    def merged_boxes(self, max_boxes: int = 1500) -> tuple[np.ndarray, np.ndarray, dict]:
        """The columns merged into at most ``max_boxes`` boxes,
        conservatively: every merged box contains each of its columns.

        Two coarsenings, each conservative: blocks of b x b cells become one
        cell of their largest height, and heights are rounded up to a step q
        (0: exact). Then equal-height runs of cells along x merge, and equal
        runs in neighbouring rows along y. Of the (b, q) that fit in
        ``max_boxes``, the one adding the least volume is kept.

        Returns:
            (centres (N, 3), sizes (N, 3), info): boxes standing on the floor,
            m, and ``{"block": b, "height_step_m": q, "added_volume_m3": ...,
            "column_volume_m3": ...}``.

        Raises:
            ValueError: ``max_boxes`` < 1.
        """
        if max_boxes < 1:
            raise ValueError(f"max_boxes must be >= 1, got {max_boxes}.")
        H = np.asarray(self.heights, float)
        m, n = H.shape
        side = self.heightmap.side
        base = float(H.sum()) * side * side
        steps = [0.0] + [f * 10.0**e for e in range(-3, 2) for f in (1, 2, 5)]
        best = None
        for blk in (1, 2, 3, 4, 6, 8, 12, 16):
            mb, nb = -(-m // blk), -(-n // blk)
            P = np.zeros((mb * blk, nb * blk))
            P[:m, :n] = H
            Hb = P.reshape(mb, blk, nb, blk).max(axis=(1, 3))
            for q in steps:
                Hq = Hb if q == 0 else np.where(Hb > 0, np.ceil(Hb / q - 1e-12) * q, 0.0)
                rects = merge_equal(Hq)
                if len(rects) > max_boxes:
                    continue
                r = np.array(rects, float).reshape(-1, 5) * [blk, blk, blk, blk, 1]
                r[:, 1] = np.minimum(r[:, 1], m)  # a partial block at the edge covers only real cells
                r[:, 3] = np.minimum(r[:, 3], n)
                vol = float(np.sum((r[:, 1] - r[:, 0]) * (r[:, 3] - r[:, 2]) * r[:, 4])) * side * side
                if best is None or vol < best[0]:
                    best = (vol, r, blk, q)
                break  # a larger q only adds volume at this block size
            if best is not None and blk > 1 and len(merge_equal(Hb)) <= max_boxes:
                break  # exact heights fit: coarser blocks only add volume
        if best is None:
            raise ValueError(f"the volume cannot be merged into {max_boxes} boxes; raise max_boxes.")
        vol, r, blk, q = best
        x0, y0 = self.heightmap.origin[0], self.heightmap.origin[1]
        centres = np.stack(
            [x0 + (r[:, 0] + r[:, 1]) / 2 * side, y0 + (r[:, 2] + r[:, 3]) / 2 * side, r[:, 4] / 2], axis=1
        )
        sizes = np.stack([(r[:, 1] - r[:, 0]) * side, (r[:, 3] - r[:, 2]) * side, r[:, 4]], axis=1)
        return (
            centres,
            sizes,
            {"block": blk, "height_step_m": q, "added_volume_m3": vol - base, "column_volume_m3": base},
        )


def merge_equal(H: np.ndarray) -> list[tuple[int, int, int, int, float]]:
    """Rectangles [i0, i1) x [j0, j1) of equal positive value covering every
    positive cell of H exactly once: runs along the first axis per column j,
    extended over consecutive j with the same run."""
    m, n = H.shape
    open_: dict = {}  # (i0, i1, h) -> j0 of the rectangle growing in j
    out = []
    for j in range(n + 1):
        runs = set()
        if j < n:
            col = H[:, j]
            i = 0
            while i < m:
                h = col[i]
                if h > 0:
                    i1 = i + 1
                    while i1 < m and col[i1] == h:
                        i1 += 1
                    runs.add((i, i1, float(h)))
                    i = i1
                else:
                    i += 1
        for key in list(open_):
            if key not in runs:
                i0, i1, h = key
                out.append((i0, i1, open_.pop(key), j, h))
        for key in runs:
            open_.setdefault(key, j)
    return out
