"""Metrics (SPEC 8): the paper's Confidence Factor, and freedom beside it."""

from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING, cast

import numpy as np
import numpy.typing as npt

from drake_cfvol.algorithm.table import BoundsTable, require_table
from drake_cfvol.exceptions import DimensionError, ParameterError, WorkcellError
from drake_cfvol.io.arguments import instance, real_array, whole_number
from drake_cfvol.io.progress import Progress
from drake_cfvol.scene.workcell import Workcell

if TYPE_CHECKING:
    from pydrake.planning import CollisionChecker

__all__ = [
    "shown_percent",
    "BoundaryCheck",
    "boundary_check",
    "judged_margins",
    "kept_margins",
    "position_margins",
    "CFResult",
    "Freedom",
    "confidence_factor",
    "freedom",
    "box_freedom",
    "sample_boxes",
]


def sample_boxes(bounds: BoundsTable, s: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Configurations drawn uniformly in the box at each path parameter s
    (:func:`drake_cfvol.algorithm.table.box_at`), one per entry of s."""
    lo, hi, _ = bounds.boxes_at(np.asarray(s, float))
    return lo + rng.random(lo.shape) * (hi - lo)


@dataclasses.dataclass
class CFResult:
    """A Confidence Factor measurement.

    Attributes:
        percent: CF, % of samples free of collision with the real scene.
        per_window: (N_tw,) CF per time window, %.
        samples: total number of samples (N_tw N_m).
        colliding: how many collided.
        seed: the seed used.
        drake_checked: how many samples Drake's checker judged (judge
            "drake": those the kernel could not certify free; judge
            "kernel": the cross-checked ones).
        judge: who judged every sample: "kernel" (the compiled kernel,
            conservative: a sample it cannot certify free counts as
            colliding, so the CF is a lower bound of Drake's) or "drake".
        cross_checked: with judge "kernel", how many random samples Drake
            judged as well.
        kernel_only_colliding: of those, how many the kernel counted as
            colliding and Drake found free (its conservative calls; none
            is ever the other way: see :func:`confidence_factor`).
    """

    percent: float
    per_window: np.ndarray
    samples: int
    colliding: int
    seed: int
    drake_checked: int = 0
    judge: str = "drake"
    cross_checked: int = 0
    kernel_only_colliding: int = 0


#: Samples Drake cross-checks when the kernel judges (judge "kernel").
CROSS_CHECK = 10_000


def confidence_factor(
    workcell: Workcell,
    bounds: BoundsTable,
    *,
    windows: int = 30,
    samples: int = 10000,
    seed: int = 0,
    checker: CollisionChecker | None = None,
    judge: str = "drake",
    prefilter: bool = True,
    cross_check: int = CROSS_CHECK,
    progress: bool = False,
) -> CFResult:
    """The paper's Confidence Factor (eq. 3-4, SPEC 8).

    The path parameter s in [0, g-1] is split into ``windows`` equal windows;
    in each, ``samples`` draws of s uniform in the window and q uniform in
    the box at s are checked against the real scene (obstacles + self, not the
    volume).

    Who judges: with ``judge="drake"`` Drake's checker (with ``prefilter``
    the compiled kernel first certifies the samples it can prove free, and
    Drake judges the rest, so the result is Drake's, sample by sample). With
    ``judge="kernel"`` the kernel judges every sample (exact shapes, so it
    differs from Drake only on configurations that graze within rounding,
    always towards colliding: the CF is then a lower bound of Drake's), and
    Drake cross-checks ``cross_check`` random samples: the result says how
    many it counted as colliding that Drake finds free; one it called free
    that Drake finds colliding would be a defect, and raises.

    Args:
        workcell: the workcell.
        bounds: the bounds table.
        windows: N_tw.
        samples: N_m, per window.
        seed: random seed (the samples and the cross-checked ones).
        checker: a Drake collision checker (default: the workcell's).
        judge: "drake" or "kernel".
        prefilter: with judge "drake", let the kernel certify free samples first.
        cross_check: with judge "kernel", how many random samples Drake
            judges as well (all of them, if fewer).
        progress: show a progress bar on a terminal (one unit per window).

    Raises:
        ParameterError: windows or samples below 1, an unknown judge, a
            negative cross_check.
        DimensionError: bounds for another number of joints.
        WorkcellError: (judge "kernel") the kernel called free a sample
            Drake finds colliding.
    """
    instance(workcell, Workcell, "confidence_factor: workcell", "drake_cfvol.load_workcell")
    require_table(bounds, "confidence_factor: bounds")
    for name, value in (("windows", windows), ("samples", samples), ("seed", seed), ("cross_check", cross_check)):
        whole_number(value, f"confidence_factor: {name}")
    if windows < 1 or samples < 1:
        raise ParameterError(f"windows and samples must be >= 1, got {windows} and {samples}.")
    if judge not in ("drake", "kernel"):
        raise ParameterError(f"judge must be 'drake' or 'kernel', got {judge!r}.")
    if cross_check < 0:
        raise ParameterError(f"cross_check must be >= 0 samples, got {cross_check}.")
    if bounds.k != workcell.num_joints:
        raise DimensionError("the bounds' joints", workcell.num_joints, bounds.k)
    checker = checker or workcell.checker
    rng = np.random.default_rng(seed)
    Q = _draw(bounds, windows, samples, rng)
    if judge == "kernel":
        return _kernel_cf(workcell, Q, windows, samples, seed, checker, cross_check, rng, progress)
    arrays = workcell.scene_arrays() if prefilter else None
    per = np.empty(windows)
    colliding = 0
    judged = 0
    bar = Progress(windows, "Confidence Factor", enabled=progress, unit="window")
    for w in range(windows):
        Qw = Q[w * samples : (w + 1) * samples]
        free = np.ones(len(Qw), bool)
        maybe = arrays.may_collide(Qw) if arrays is not None else np.ones(len(Qw), bool)
        if maybe.any():
            free[maybe] = np.array(checker.CheckConfigsCollisionFree(Qw[maybe], parallelize=True), bool)
        judged += int(maybe.sum())
        per[w] = 100.0 * free.mean()
        colliding += int((~free).sum())
        bar.update(1)
    bar.close()
    total = windows * samples
    return CFResult(100.0 * (total - colliding) / total, per, total, colliding, seed, judged)


def _draw(bounds, windows, samples, rng) -> np.ndarray:
    """The CF's samples, window after window: (windows samples, k)."""
    edges = np.linspace(0.0, bounds.g - 1, windows + 1)
    s = np.concatenate([rng.uniform(edges[w], edges[w + 1], samples) for w in range(windows)])
    return sample_boxes(bounds, s, rng)


def _kernel_cf(workcell, Q, windows, samples, seed, checker, cross_check, rng, progress) -> CFResult:
    """:func:`confidence_factor` judged by the kernel, cross-checked by Drake."""
    bar = Progress(windows, "Confidence Factor", enabled=progress, unit="window")
    hit = workcell.scene_arrays().may_collide(Q)
    bar.update(windows)
    bar.close()
    total = windows * samples
    pick = rng.choice(total, size=min(cross_check, total), replace=False) if cross_check else np.zeros(0, int)
    drake_free = (
        np.array(checker.CheckConfigsCollisionFree(Q[pick], parallelize=True), bool) if len(pick) else np.zeros(0, bool)
    )
    missed = int((~hit[pick] & ~drake_free).sum())
    if missed:
        raise WorkcellError(
            f"the collision kernel called {missed} of {len(pick)} cross-checked samples free where "
            "Drake's checker finds a collision; use judge='drake' and please report this with the "
            "robot's model."
        )
    colliding = int(hit.sum())
    per = 100.0 * (1.0 - hit.reshape(windows, samples).mean(axis=1))
    return CFResult(
        100.0 * (total - colliding) / total,
        per,
        total,
        colliding,
        seed,
        len(pick),
        "kernel",
        len(pick),
        int((hit[pick] & drake_free).sum()),
    )


@dataclasses.dataclass
class Freedom:
    """How much room the bounds leave (SPEC 8).

    Attributes:
        mean: mean over waypoints of the geometric mean over joints of
            (upper - lower) / (limit range); 0 .. 1.
        per_waypoint: (g,) that geometric mean.
        median_width: (k,) median width per joint, degrees for revolute
            joints, metres for prismatic ones.
        units: (k,) "deg" or "m".
    """

    mean: float
    per_waypoint: np.ndarray
    median_width: np.ndarray
    units: list[str]


def box_freedom(lo, hi, limit_lower, limit_upper) -> float | np.ndarray:
    """The freedom of boxes: the geometric mean over joints of width / joint
    range, each share clipped to [0, 1] (0 where a joint has no width).

    Args:
        lo, hi: (k,) or (n, k) boxes.
        limit_lower, limit_upper: (k,) the joints' ranges (a table's absolute bounds).

    Returns:
        A float for one box, else (n,).
    """
    frac = np.clip((np.asarray(hi, float) - lo) / (np.asarray(limit_upper, float) - limit_lower), 0.0, 1.0)
    with np.errstate(divide="ignore"):
        gm = np.exp(np.mean(np.log(frac), axis=-1))
    return float(gm) if np.ndim(gm) == 0 else gm


def freedom(bounds: BoundsTable, revolute: npt.ArrayLike | None = None) -> Freedom:
    """Freedom of a bounds table (reported beside every CF: a box of zero
    width has CF 100 %); ``revolute``: (k,) True for a revolute joint (its
    widths in degrees), default all.

    Raises:
        ParameterError: ``bounds`` is not a table, ``revolute`` not a mask.
        DimensionError: ``revolute`` has another length than the joints.
    """
    require_table(bounds, "freedom: bounds")
    if revolute is None:
        revolute = np.ones(bounds.k, bool)
    else:
        mask = real_array(revolute, "freedom: revolute (one flag per joint)")
        if mask.shape != (bounds.k,):
            raise DimensionError(
                "freedom: revolute", bounds.k, mask.shape, f"The joints: {', '.join(bounds.joint_names)}."
            )
        revolute = cast(np.ndarray, mask != 0)  # numpy's stubs type != as Any
    gm = np.asarray(box_freedom(bounds.lower, bounds.upper, bounds.limit_lower, bounds.limit_upper))
    med = np.median(bounds.widths(), axis=0)
    med = np.where(revolute, np.degrees(med), med)
    return Freedom(float(gm.mean()), gm, med, ["deg" if r else "m" for r in revolute])


def shown_percent(percent: float, colliding: int, digits: int = 4) -> float:
    """A percentage rounded for people, never to 100 when a sample
    collided (rounded down then), so "CF 100 %" always means none did."""
    if colliding > 0:
        return math.floor(percent * 10**digits) / 10**digits
    return round(percent, digits)


#: How much nearer than its margin Drake may find a box's boundary before the
#: check calls it colliding, m: the kernel and Drake model the same shapes
#: (meshes as their convex hulls, covers, rounding) a little differently.
JUDGE_SLACK = 1e-3


def kept_margins(workcell, bounds: BoundsTable) -> np.ndarray:
    """(g-1,) the margin each stretch's boxes keep, m: the table's
    clearance, less only where the nominal itself is nearer
    (:func:`~drake_cfvol.algorithm.sweep.stretch_margins`)."""
    from drake_cfvol.algorithm.sweep import stretch_margins

    clearance = float(bounds.params.get("clearance", 0.0))
    return stretch_margins(workcell.scene_arrays(), bounds.nominal, clearance)


def judged_margins(workcell, bounds: BoundsTable) -> np.ndarray:
    """(g-1,) the padding at which Drake judges each stretch's boxes, m:
    :func:`kept_margins` less :data:`JUDGE_SLACK`, never below 0."""
    return np.maximum(kept_margins(workcell, bounds) - JUDGE_SLACK, 0.0)


def position_margins(margins: np.ndarray, s: np.ndarray) -> np.ndarray:
    """The padding at each path position s, from per-stretch ``margins``
    (g-1,): a waypoint ends both stretches beside it, so it keeps the larger
    of their two margins; a position inside a stretch keeps that stretch's."""
    margins = np.asarray(margins, float)
    s = np.asarray(s, float)
    if len(margins) == 0:
        return np.zeros(len(s))
    last = len(margins) - 1
    before = np.clip(np.ceil(s).astype(int) - 1, 0, last)
    after = np.clip(np.floor(s).astype(int), 0, last)
    return np.maximum(margins[before], margins[after])


@dataclasses.dataclass
class BoundaryCheck:
    """Where a clamp lands, judged by Drake: the box's corners, edge points
    and face points at every waypoint and stretch midpoint.

    Attributes:
        positions: path positions checked (waypoints and midpoints).
        corners, corners_colliding: corner configurations (2^k per
            position) and how many Drake finds nearer than the margin.
        edge_points, edges_colliding: edge points (one joint uniform in its
            range, every other joint at a random one of its bounds) and how
            many collide.
        clearance: Drake's padding used, m (0: plain collision; the
            smallest one where it differs by position).
        face_points, faces_colliding: face points (one joint at a random
            one of its bounds, every other joint uniform in its range) and
            how many collide.
        colliding_at: the path positions where anything collided.
    """

    positions: int
    corners: int
    corners_colliding: int
    edge_points: int
    edges_colliding: int
    clearance: float
    face_points: int = 0
    faces_colliding: int = 0
    colliding_at: list[float] = dataclasses.field(default_factory=list)


def boundary_check(
    workcell,
    bounds: BoundsTable,
    *,
    clearance: float | np.ndarray = 0.0,
    edge_points: int = 64,
    face_points: int = 64,
    seed: int = 0,
) -> BoundaryCheck:
    """Checks the box's corners, edge points and face points at every
    waypoint and stretch midpoint with Drake's checker, padded by
    ``clearance`` (m; a configuration nearer than that to an obstacle or to
    the robot itself counts as colliding): one value, or one per stretch
    ((g-1,), e.g. :func:`judged_margins`; see :func:`position_margins`).
    Seeded."""
    rng = np.random.default_rng(seed)
    s = np.arange(0, bounds.g - 0.5, 0.5) if bounds.g > 1 else np.zeros(1)
    pads = np.asarray(clearance, float)
    if pads.ndim == 0:
        pads = np.full(len(s), float(pads))
    elif pads.shape == (bounds.g - 1,):
        pads = position_margins(pads, s)
    else:
        raise DimensionError(
            "boundary_check's clearance",
            (bounds.g - 1,),
            pads.shape,
            "Give one padding (m) or one per stretch of the table.",
        )
    lo, hi, _ = bounds.boxes_at(s)
    k = bounds.k
    pattern = (np.arange(2**k)[:, None] >> np.arange(k)[None, :]) & 1
    corners = bad_c = bad_e = bad_f = 0
    where = []

    def colliding(checker, Q) -> int:
        return int(np.sum(~np.asarray(checker.CheckConfigsCollisionFree(Q, parallelize=True), bool)))

    for a in range(len(s)):
        checker = workcell.padded_checker(float(pads[a]))
        C = np.where(pattern == 1, hi[a], lo[a])
        corners += len(C)
        c = colliding(checker, C)
        E = C[rng.integers(0, len(C), edge_points)]
        j = rng.integers(0, k, edge_points)
        E[np.arange(edge_points), j] = lo[a, j] + rng.random(edge_points) * (hi[a, j] - lo[a, j])
        e = colliding(checker, E)
        F = lo[a] + rng.random((face_points, k)) * (hi[a] - lo[a])
        j = rng.integers(0, k, face_points)
        F[np.arange(face_points), j] = np.where(rng.random(face_points) < 0.5, lo[a, j], hi[a, j])
        f = colliding(checker, F)
        bad_c, bad_e, bad_f = bad_c + c, bad_e + e, bad_f + f
        if c + e + f:
            where.append(float(s[a]))
    return BoundaryCheck(
        len(s),
        corners,
        bad_c,
        edge_points * len(s),
        bad_e,
        float(pads.min()),
        face_points * len(s),
        bad_f,
        where,
    )
