"""Bounds that follow a changing cell: the volume and the bounds re-estimated
from an obstacle map, incrementally, over a horizon (docs/spec.md, SPEC 12).

Each update:

1. The map's occupied cells become boxes standing on the floor, added to
   the cell's obstacles (the kernel's arrays), and no-goal footprint on the
   height function's raster: V is grown again (its no-goal distances).
2. A stretch's search depends on the scene only through the boxes its tests
   held against it (the kernel returns each search's footprint). Stretches
   whose footprint meets a box or a column that changed are *dirty*; dirty
   stretches within the horizon are searched again, in order, each chain
   from its previous stretch's bound, and a stretch whose last bound moved
   makes its successor dirty. Within a search, a test the same as the
   one its last run made at that step, whose own footprint no change
   meets, keeps that verdict instead of running again. So the result
   equals a full re-estimation.
3. Publishing: a bound that tightens is published at once. A bound that
   widens waits until the widened box of its stretch is certified: the base
   table's certificate covers the known cell, and the perceived boxes are
   out of the box's reach (a bound on every body's motion over the box) or
   the box's edges and corners are proven free of them by the kernel's
   region tests.

The live bounds never leave the base table's box (the offline, perhaps
certified, bounds of the known cell).
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from drake_cfvol import kernel as K
from drake_cfvol.algorithm.certificate.boundary import colliding_points, failures
from drake_cfvol.algorithm.heightmap import Volume, height_function
from drake_cfvol.algorithm.planning import NominalPath
from drake_cfvol.algorithm.sweep import default_rate, sweep_range, sweep_setup
from drake_cfvol.algorithm.table import BoundsTable, absolute_bounds, box_at, waypoint_boxes
from drake_cfvol.algorithm.volume import column_caps, footprint_masks, lower_along_path
from drake_cfvol.exceptions import ParameterError
from drake_cfvol.kernel import kinds
from drake_cfvol.online.obstacle_map import ObstacleMap
from drake_cfvol.scene.arrays import SceneArrays
from drake_cfvol.scene.params import VolumeParams
from drake_cfvol.scene.workcell import Workcell

__all__ = ["LiveBounds", "OnlineBounds", "BoundsUpdate", "shape_radii", "FrozenLog"]


class FrozenLog(tuple):
    """An append-only log for a Drake abstract state: ``log + (row,)``
    makes a new one; Drake's state copies share it (no deep copy)."""

    def __add__(self, rows) -> "FrozenLog":
        return FrozenLog(tuple.__add__(self, tuple(rows)))

    def __deepcopy__(self, memo) -> "FrozenLog":
        return self


class LiveBounds:
    """The bounds in force: the published stretch bounds (SPEC 7's stretch
    rule, rate-limited) within the base table's box, holding the nominal.
    Duck-types the parts of :class:`~drake_cfvol.algorithm.table.BoundsTable`
    that the systems read (``at``, ``g``, ``k``, ``nominal``, ``params``).

    Attributes:
        base: the base table.
        stretch_lower, stretch_upper: (g-1, k) the published stretch bounds.
        version: how many times the published bounds changed.
    """

    def __init__(
        self,
        base: BoundsTable,
        stretch_lower: np.ndarray,
        stretch_upper: np.ndarray,
        rate: np.ndarray,
        version: int = 0,
    ):
        self.base = base
        self.stretch_lower = np.asarray(stretch_lower, float)
        self.stretch_upper = np.asarray(stretch_upper, float)
        self.rate = np.asarray(rate, float)
        self.version = version
        self._wl, self._wu = waypoint_boxes(self.stretch_lower, self.stretch_upper, base.nominal, self.rate)

    @property
    def g(self) -> int:
        """The base table's number of waypoints."""
        return self.base.g

    @property
    def k(self) -> int:
        """The base table's number of joints."""
        return self.base.k

    @property
    def nominal(self) -> np.ndarray:
        """(g, k) the base table's nominal waypoints."""
        return self.base.nominal

    @property
    def params(self) -> dict:
        """The base table's parameters."""
        return self.base.params

    @property
    def joint_names(self) -> list[str]:
        """The base table's k joints."""
        return self.base.joint_names

    def __deepcopy__(self, memo) -> "LiveBounds":
        return self  # never changed once made: Drake's state copies share it

    def at(self, s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(lower, upper, nominal) at path parameter s in [0, g-1]."""
        lo, hi, nom = box_at(
            self._wl,
            self._wu,
            self.base.nominal,
            s,
            stretch_lower=self.stretch_lower,
            stretch_upper=self.stretch_upper,
            rate=self.rate,
        )
        lo_b, hi_b, _ = self.base.at(s)
        return np.minimum(np.maximum(lo, lo_b), nom), np.maximum(np.minimum(hi, hi_b), nom), nom

    def boxes_at(self, s: np.ndarray) -> tuple[np.ndarray, ...]:
        """:meth:`at` for many s: three (n, k) arrays."""
        out = [self.at(float(v)) for v in np.atleast_1d(s)]
        return tuple(np.array([o[i] for o in out]) for i in range(3))


@dataclasses.dataclass
class BoundsUpdate:
    """What one update did.

    Attributes:
        time_ms: its compute time, ms.
        changed_cells: columns of V that changed; changed_boxes: perceived
            boxes added or removed.
        recomputed: stretches searched again; searches: (joint, side)
            searches run (at most 2 k per stretch); dirty: stretches still
            waiting (beyond the horizon).
        tests: region tests run (a test kept from the last search of its
            stretch, whose footprint no change met, is not run again).
        tightened, widened: stretches whose published bounds tightened /
            widened; pending: stretches whose widening waits for a
            certificate.
        version: the live bounds' version after the update.
    """

    time_ms: float
    changed_cells: int
    changed_boxes: int
    recomputed: int
    searches: int
    dirty: int
    tests: int
    tightened: int
    widened: int
    pending: int
    version: int


def shape_radii(arrays) -> np.ndarray:
    """(B,) for each robot body, the radius about its origin of a ball
    holding all its shapes, m."""
    out = np.zeros(arrays.num_bodies)
    for row, b in zip(arrays.shapes, arrays.shape_body):
        k = kinds.kind(row[K.ROW_KIND])
        r = k.radius(
            row[K.ROW_SIZE : K.ROW_SIZE + 3], arrays.verts[int(row[K.ROW_FIRST_VERTEX]) : int(row[K.ROW_END_VERTEX])]
        )
        out[b] = max(out[b], float(np.linalg.norm(row[K.ROW_CENTRE : K.ROW_CENTRE + 3])) + r)
    return out


def _overlap(fp: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """(...,) whether each footprint (..., 6) meets any of the boxes (N, 6)."""
    if not len(boxes):
        return np.zeros(fp.shape[:-1], bool)
    f = fp[..., None, :]
    hit = (
        (f[..., 0] <= boxes[:, 3])
        & (boxes[:, 0] <= f[..., 3])
        & (f[..., 1] <= boxes[:, 4])
        & (boxes[:, 1] <= f[..., 4])
        & (f[..., 2] <= boxes[:, 5])
        & (boxes[:, 2] <= f[..., 5])
    ).any(axis=-1)
    return np.asarray(hit)  # numpy's stub: any() may give a scalar


class OnlineBounds:
    """Re-estimates a path's bounds as an obstacle map changes.

    Args:
        workcell: the workcell.
        base: the path's bounds table with its volume
            (:func:`~drake_cfvol.estimate_bounds`' result, certified or not).
        horizon: stretches ahead of the path index searched at an update
            (None: to the end of the path).
        max_proofs: most boundary proofs (a stretch's widening near a
            perceived box) per update.

    Raises:
        ParameterError: a table without its volume, or bad settings.
    """

    def __init__(self, workcell: Workcell, base: BoundsTable, *, horizon: int | None = None, max_proofs: int = 1):
        if base.volume is None:
            raise ParameterError(
                "OnlineBounds needs the table's volume: a table loaded from disk has none; grow "
                "it with dataclasses.replace(table, volume=build_volume(workcell, path, params))."
            )
        if horizon is not None and not int(horizon) >= 1:
            raise ParameterError(f"horizon must be >= 1 stretch (or None: the whole path), got {horizon!r}.")
        if not int(max_proofs) >= 0:
            raise ParameterError(f"max_proofs must be >= 0 per update, got {max_proofs!r}.")
        self.workcell, self.base, self.horizon = workcell, base, horizon
        self.max_proofs = int(max_proofs)
        self._proven_map: dict = {}  # stretch -> the map its last boundary proof was run on
        # stretch -> (lower, upper, points): the box its last boundary proof
        # failed on and configurations of that box's edges that may collide
        self._failed_at: dict = {}
        known = {f.name for f in dataclasses.fields(VolumeParams)}
        self.params = VolumeParams(**{k: v for k, v in base.params.items() if k in known})
        W = np.ascontiguousarray(base.nominal, dtype=np.float64)
        self._W = W
        path = NominalPath(W, list(base.joint_names), workcell.name, str(base.info.get("path", "path")), 0)
        self._vb = base.volume
        self._fp = footprint_masks(workcell, path, self.params, self._vb.categories)
        self._arrays0 = self._arrays = workcell.scene_arrays()
        self._robot_only = self._arrays0.robot_only()  # the perceived boxes are tested against it
        lo_w, hi_w = absolute_bounds(workcell.position_lower, workcell.position_upper, W)
        self._setup = sweep_setup(
            self._arrays0, W, self.params, np.maximum(lo_w[:-1], lo_w[1:]), np.minimum(hi_w[:-1], hi_w[1:])
        )
        self._sign = self._setup.chains[:, 1].astype(float)
        self._heights = np.array(self._vb.volume.heights, float)
        self._table: np.ndarray | None = None  # V's range-max table, built when first needed after a change
        self._caps: np.ndarray | None = (
            None  # V's columns' caps under the nominal (column_caps), made at the first change
        )
        # The cell's no-goal distance at V's columns (_no_goal_distance), made at the first change.
        self._static_ng: np.ndarray | None = None
        self._boxes = np.zeros((0, 6))
        self._map: ObstacleMap | None = None
        self._perceived_only: SceneArrays | None = None
        n_st = len(W) - 1
        # Each search's tests as last run (kept for the next update: a test
        # whose footprint no change meets keeps its verdict).
        self._memo = np.zeros((len(self._sign), n_st, K.MEMO_T, K.MEMO_W))
        self._memo_n = np.zeros((len(self._sign), n_st), np.int64)
        bounds, tests, fps = sweep_range(
            self._setup,
            self._arrays0,
            W,
            self._field(),
            0,
            n_st - 1,
            np.full(len(self._sign), np.nan),
            memo=(self._memo, self._memo_n, np.zeros((0, 6))),
        )
        self._cand, self._fps = bounds, fps
        self._pub = bounds.copy()
        self._dirty = np.zeros((len(self._sign), n_st), bool)  # per chain and stretch
        rate = (
            base.rate
            if base.rate is not None and np.isfinite(base.rate).any()
            else default_rate(W, workcell.velocity_limits, self.params.waypoint_time)
        )
        self._rate = np.asarray(rate, float)
        self._radii = shape_radii(self._arrays0)
        self._p_WB = self._arrays0.fk(W)[1]  # (g, B, 3) each body's origin at each waypoint, m
        # Per joint and body: how far a unit of the joint moves the body's points (m/rad, or 1 m/m).
        self._body_reach = np.where(
            self._arrays0.revolute[:, None], self._arrays0.reach, self._arrays0.moved_by.astype(float)
        )
        self.live = self._live(0)

    # -- views ---------------------------------------------------------------

    def _field(self):
        """The kernel's view of V now (its range-max table built once per change of V)."""
        hm = self._vb.volume.heightmap
        if not (self._heights > 0).any():
            return np.zeros((1, 1, 0, 0)), 0.0, 0.0, 1.0
        if self._table is None:
            self._table = K.range_max_table(np.ascontiguousarray(self._heights))
        return self._table, hm.origin[0], hm.origin[1], hm.side

    def _split(self, chains: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(lower, upper) (g-1, k) from chain-form bounds (n, g-1)."""
        return chains[1::2].T.copy(), chains[0::2].T.copy()

    def _live(self, version: int) -> LiveBounds:
        lower, upper = self._split(self._pub)
        return LiveBounds(self.base, lower, upper, self._rate, version)

    @property
    def candidate(self) -> tuple[np.ndarray, np.ndarray]:
        """(lower, upper) (g-1, k): the latest estimate of every stretch's
        bounds (before publishing rules)."""
        return self._split(self._cand)

    @property
    def heights(self) -> np.ndarray:
        """(m, n) V's columns now, m."""
        return self._heights.copy()

    @property
    def arrays(self) -> SceneArrays:
        """The kernel's scene now: the cell's obstacles and the perceived boxes."""
        return self._arrays

    # -- the update ----------------------------------------------------------

    def _volume(self, centres: np.ndarray, sizes: np.ndarray) -> np.ndarray:
        """V's heights with the perceived boxes in the no-goal footprint."""
        vb = self._vb
        hm = vb.volume.heightmap
        d_ng = self._no_goal_distance(centres, sizes)
        raw = height_function(vb.d_t, vb.d_g, d_ng, vb.active, self.params)
        vol = Volume(hm, raw.copy(), raw)
        if self._caps is None:  # the path's caps on V, the same at every update
            self._caps = column_caps(hm, self._arrays0, self._W, self.params.column_clearance)
        lower_along_path(vol, self._arrays0, self._W, self.params.column_clearance, self._caps)
        return np.asarray(vol.heights, float)

    def _no_goal_distance(self, centres: np.ndarray, sizes: np.ndarray) -> np.ndarray:
        """(m, n) distance from each column of V to the no-goal footprint
        with the perceived boxes rasterised into it, m: what the exact
        distance transform of that raster gives at the columns' pixels
        (pixel centre to the nearest marked pixel centre). The cell's own
        part is transformed once; a box's pixels form a rectangle of the
        raster, whose nearest pixel centre to a column's pixel is the
        clamped one, so its distance is sqrt(dx^2 + dy^2) in whole pixels
        (the same integers the transform adds up; the minimum of correctly
        rounded square roots is the root of the minimum)."""
        fp = self._fp
        if self._static_ng is None:
            X, Y = self._vb.volume.heightmap.centres()
            self._column_px = fp.indices(X, Y)
            mask = fp.masks["no_goal"]
            self._static_ng = K.distance_map(mask)[self._column_px] if mask.any() else np.full(X.shape, np.inf)
        ix, iy = self._column_px
        shape = fp.masks["no_goal"].shape
        d = self._static_ng
        for c, s in zip(centres, sizes):
            i0, j0 = np.floor((c[:2] - s[:2] / 2 - (fp.x0, fp.y0)) / fp.pixel).astype(int)
            i1, j1 = np.ceil((c[:2] + s[:2] / 2 - (fp.x0, fp.y0)) / fp.pixel).astype(int)
            i0, j0, i1, j1 = max(i0, 0), max(j0, 0), min(i1, shape[0]), min(j1, shape[1])
            if i0 >= i1 or j0 >= j1:
                continue  # outside the raster: nothing marked
            dx = np.maximum(np.maximum(i0 - ix, ix - (i1 - 1)), 0)
            dy = np.maximum(np.maximum(j0 - iy, iy - (j1 - 1)), 0)
            d = np.minimum(d, np.sqrt((dx * dx + dy * dy).astype(float)))
        return d * fp.pixel

    def _changed(self, heights: np.ndarray, boxes: np.ndarray) -> tuple[np.ndarray, np.ndarray, int, int]:
        """((n, n_st) searches whose footprint meets a changed column or box,
        the changed boxes and columns (C, 6), how many columns and boxes)."""
        hm = self._vb.volume.heightmap
        ci, cj = np.nonzero(heights != self._heights)
        old = {tuple(b) for b in np.round(self._boxes, 9)}
        new = {tuple(b) for b in np.round(boxes, 9)}
        moved = np.array(sorted(old ^ new), float).reshape(-1, 6)
        hit = _overlap(self._fps, moved)  # (n, g-1)
        changed = moved
        if len(ci):
            top = np.maximum(heights[ci, cj], self._heights[ci, cj])
            cols = np.stack(
                [
                    hm.origin[0] + ci * hm.side,
                    hm.origin[1] + cj * hm.side,
                    np.zeros(len(ci)),
                    hm.origin[0] + (ci + 1) * hm.side,
                    hm.origin[1] + (cj + 1) * hm.side,
                    top,
                ],
                axis=1,
            )
            hit |= _overlap(self._fps, cols)
            changed = np.concatenate([moved, cols])
        return hit, np.ascontiguousarray(changed, float), len(ci), len(moved)

    def _recompute(self, lo: int, hi: int, changed: np.ndarray) -> tuple[int, int, int]:
        """Searches the dirty stretches in [lo, hi] again, in order, each run
        of them with the chains dirty there (cascading: a chain whose last
        bound moved makes its next stretch dirty); a test whose footprint
        none of ``changed`` (C, 6) meets keeps its last verdict. Returns
        (stretches, searches, tests run)."""
        n_st, done, searches, tests, i = self._dirty.shape[1], 0, 0, 0, lo
        field = self._field()
        any_dirty = np.asarray(self._dirty.any(axis=0))  # numpy's stub: any() may give a scalar
        while i <= hi:
            if not any_dirty[i]:
                i += 1
                continue
            b = i
            while b + 1 <= hi and any_dirty[b + 1]:
                b += 1
            sel = np.nonzero(self._dirty[:, i : b + 1].any(axis=1))[0]
            guesses = self._cand[sel, i - 1] if i > 0 else np.full(len(sel), np.nan)
            memo = (
                np.ascontiguousarray(self._memo[sel, i : b + 1]),
                np.ascontiguousarray(self._memo_n[sel, i : b + 1]),
                changed,
            )
            bounds, t, fps = sweep_range(
                self._setup, self._arrays, self._W, field, i, b, guesses, self._setup.chains[sel], memo
            )
            self._memo[sel, i : b + 1], self._memo_n[sel, i : b + 1] = memo[0], memo[1]
            moved = sel[bounds[:, -1] != self._cand[sel, b]]
            self._cand[sel, i : b + 1], self._fps[sel, i : b + 1] = bounds, fps
            self._dirty[sel, i : b + 1] = False
            done, tests = done + (b - i + 1), tests + int(t.sum())
            searches += len(sel) * (b - i + 1)
            if b + 1 < n_st and len(moved):
                self._dirty[moved, b + 1] = True  # their searches start from these bounds
                any_dirty[b + 1] = True
            i = b + 1
        return done, searches, tests

    def update(self, obstacle_map: ObstacleMap, s_now: float = 0.0, *, full: bool = False) -> BoundsUpdate:
        """Takes a new obstacle map: re-estimates V and the dirty stretches
        within the horizon from ``s_now``, then publishes (tightening at
        once, widening once certified).

        Args:
            obstacle_map: the perceived obstacles.
            s_now: the path index now.
            full: search every stretch again (a full re-estimation).
        """
        t0 = time.perf_counter()
        centres, sizes = obstacle_map.boxes()
        boxes = np.concatenate([centres - sizes / 2, centres + sizes / 2], axis=1)
        same = obstacle_map.same_as(self._map)
        heights = self._heights if same else self._volume(centres, sizes)
        changed = np.zeros((0, 6))
        if full:
            dirty, n_cells, n_boxes = (
                np.ones(self._dirty.shape, bool),
                int((heights != self._heights).sum()),
                len(boxes),
            )
            self._memo_n[:] = 0  # every test run again
        elif same:
            dirty, n_cells, n_boxes = np.zeros(self._dirty.shape, bool), 0, 0
        else:
            dirty, changed, n_cells, n_boxes = self._changed(heights, boxes)
        self._dirty |= dirty
        if not same:  # the scene the kernel sees changes only with the map
            self._heights, self._boxes, self._table = heights, boxes, None
            self._arrays = self._arrays0.with_boxes(centres, sizes) if len(centres) else self._arrays0
            self._perceived_only = self._robot_only.with_boxes(centres, sizes)
        self._map = obstacle_map
        n_st = self._dirty.shape[1]
        lo = int(np.clip(np.floor(s_now), 0, n_st - 1))
        hi = n_st - 1 if self.horizon is None else min(n_st - 1, lo + int(self.horizon))
        done, searches, tests = self._recompute(0 if full else lo, hi, changed)
        # A search left dirty (beyond the horizon) may meet this change and
        # later ones: its memo is dropped (it runs every test when searched).
        self._memo_n[self._dirty] = 0
        tightened, widened, pending = self._publish(lo, hi)
        if tightened or widened:
            self.live = self._live(self.live.version + 1)
        return BoundsUpdate(
            (time.perf_counter() - t0) * 1e3,
            n_cells,
            n_boxes,
            done,
            searches,
            int(self._dirty.any(axis=0).sum()),
            tests,
            tightened,
            widened,
            pending,
            self.live.version,
        )

    # -- publishing ----------------------------------------------------------

    def _publish(self, lo: int, hi: int) -> tuple[int, int, int]:
        """Tightening at once, widening once certified (every clean stretch;
        boundary proofs only for those in [lo, hi])."""
        s = self._sign[:, None]
        clean = ~self._dirty
        tighter = (s * (self._cand - self._pub) < 0) & clean
        tightened = int(tighter.any(axis=0).sum())
        self._pub = np.where(tighter, self._cand, self._pub)
        wider = ((s * (self._cand - self._pub) > 0).any(axis=0)) & clean.all(axis=0)
        # Ahead first (a proof is spent where the robot is going); the
        # stretches behind widen by the cheap test only.
        idx = np.nonzero(wider)[0]
        todo = [i for i in idx if lo <= i <= hi] + [i for i in idx if i < lo or i > hi]
        widened = 0
        proofs = [None] * self.max_proofs
        for i in todo:
            if self._certified(int(i), self._cand[:, i], proofs if lo <= i <= hi else []):
                self._pub[:, i] = self._cand[:, i]
                widened += 1
        return tightened, widened, int(wider.sum()) - widened

    def _outer_box(self, i: int, chains: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(lower, upper) (2, k) at waypoints i, i+1: a linear box holding
        stretch i's box at every s (its bounds and the nominal)."""
        lower, upper = chains[1::2], chains[0::2]
        W = self._W[i : i + 2]
        return np.minimum(lower[None, :], W), np.maximum(upper[None, :], W)

    def _certified(self, i: int, chains: np.ndarray, proofs: list) -> bool:
        """Whether stretch i's box with these bounds is certified free.

        The live box never leaves the base table's, whose guarantee covers
        the known cell; what is left is the perceived boxes. (a) None comes
        within reach of the box: each body stays within its radius plus
        sum_j reach[j, b] |q_j - W_i[j]| (up to the box's deviation) plus
        the margin of where it is at waypoint i. (b) Else, at most once per
        map and stretch while ``proofs`` (a shared budget) lasts: every edge
        and corner of a linear box holding the live box is proven free of
        the perceived boxes by the kernel's region tests (the boundary
        proof, :mod:`drake_cfvol.algorithm.certificate.boundary`), with the margin."""
        if not len(self._boxes):
            return True
        # Boxes perceived: update set the map and its scene with them.
        assert self._perceived_only is not None and self._map is not None
        lo, up = self._outer_box(i, chains)
        dev = np.maximum(np.abs(up - self._W[i]), np.abs(self._W[i] - lo)).max(axis=0)  # (k,)
        p_WB = self._p_WB[i]
        grow = self._radii + dev @ self._body_reach + float(self._setup.margins[i])  # (B,)
        balls = np.concatenate([p_WB - grow[:, None], p_WB + grow[:, None]], axis=1)
        if not _overlap(balls, self._boxes).any():
            return True
        lo, up = self._tighter_linear(i, lo, up)
        margin = np.array([float(self._setup.margins[i])])
        known = self._failed_at.get(i)
        if known is not None and np.array_equal(known[0], lo) and np.array_equal(known[1], up):
            # A configuration on an edge of this very box that may still
            # collide fails its proof (every region holding it may collide),
            # without running it: no proof spent.
            if self._perceived_only.may_collide(known[2], float(margin[0])).any():
                return False
        if not proofs or self._map.same_as(self._proven_map.get(i)):
            return False
        proofs.pop()
        self._proven_map[i] = self._map
        W = self._W[i : i + 2]
        failed, _ = failures(self._perceived_only, lo, up, W, [0], margin)
        hits = colliding_points(self._perceived_only, lo, up, W, failed, margin, np.zeros(1)) if failed else []
        points = [q for hit in hits if hit is not None for q in (hit[1],)]
        if points:
            self._failed_at[i] = (lo, up, np.array(points))
        else:
            self._failed_at.pop(i, None)
        return not failed

    def _tighter_linear(self, i: int, lo: np.ndarray, up: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per joint and side, the smaller of two linear boxes that hold the
        live box over stretch i: the published one (``lo``, ``up``) and the
        base table's (linear between its waypoint boxes, or its stretch box
        for a stretch-rule table)."""
        b = self.base
        if b.interpolation == "linear":
            bl, bu = b.lower[i : i + 2], b.upper[i : i + 2]
        else:
            assert b.stretch_lower is not None and b.stretch_upper is not None  # BoundsTable.__post_init__
            bl = np.minimum(b.stretch_lower[i][None, :], self._W[i : i + 2])
            bu = np.maximum(b.stretch_upper[i][None, :], self._W[i : i + 2])
        use_b_lo = bl.min(axis=0) >= lo.min(axis=0)
        use_b_up = bu.max(axis=0) <= up.max(axis=0)
        return np.where(use_b_lo, bl, lo), np.where(use_b_up, bu, up)
