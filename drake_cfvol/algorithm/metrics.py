"""Metrics (SPEC 8): the paper's Confidence Factor, and freedom beside it."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from drake_cfvol.exceptions import DimensionError, ParameterError
from drake_cfvol.io.progress import Progress
from drake_cfvol.algorithm.table import BoundsTable

__all__ = ["shown_percent", "BoundaryCheck", "boundary_check", "CFResult", "Freedom", "confidence_factor", "freedom", "sample_boxes"]


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
        drake_checked: how many samples Drake's checker judged (the rest the
            kernel certified free).
    """

    percent: float
    per_window: np.ndarray
    samples: int
    colliding: int
    seed: int
    drake_checked: int = 0


def confidence_factor(workcell, bounds: BoundsTable, *, windows: int = 30, samples: int = 10000,
                      seed: int = 0, checker=None, prefilter: bool = True, progress: bool = False) -> CFResult:
    """The paper's Confidence Factor (eq. 3-4, SPEC 8).

    The path parameter s in [0, g-1] is split into ``windows`` equal windows;
    in each, ``samples`` draws of s uniform in the window and q uniform in
    the box at s are checked against the real scene (obstacles + self, not the
    volume). Drake's checker is the judge: with ``prefilter`` the compiled
    kernel first certifies the samples it can prove free (it never calls a
    colliding configuration free), and Drake judges the rest, so the result
    is Drake's, sample by sample, at a fraction of the cost.

    Args:
        workcell: the workcell.
        bounds: the bounds table.
        windows: N_tw.
        samples: N_m, per window.
        seed: random seed.
        checker: a Drake collision checker (default: the workcell's).
        prefilter: let the kernel certify free samples first.
        progress: show a progress bar on a terminal (one unit per window).
    """
    if windows < 1 or samples < 1:
        raise ParameterError(f"windows and samples must be >= 1, got {windows} and {samples}.")
    if bounds.k != workcell.num_joints:
        raise DimensionError("the bounds' joints", workcell.num_joints, bounds.k)
    checker = checker or workcell.checker
    arrays = workcell.scene_arrays() if prefilter else None
    rng = np.random.default_rng(seed)
    edges = np.linspace(0.0, bounds.g - 1, windows + 1)
    per = np.empty(windows)
    colliding = 0
    judged = 0
    bar = Progress(windows, "Confidence Factor", enabled=progress, unit="window")
    for w in range(windows):
        s = rng.uniform(edges[w], edges[w + 1], samples)
        Q = sample_boxes(bounds, s, rng)
        free = np.ones(len(Q), bool)
        maybe = arrays.may_collide(Q) if arrays is not None else np.ones(len(Q), bool)
        if maybe.any():
            free[maybe] = np.array(checker.CheckConfigsCollisionFree(Q[maybe], parallelize=True), bool)
        judged += int(maybe.sum())
        per[w] = 100.0 * free.mean()
        colliding += int((~free).sum())
        bar.update(1)
    bar.close()
    total = windows * samples
    return CFResult(100.0 * (total - colliding) / total, per, total, colliding, seed, judged)


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


def freedom(bounds: BoundsTable, revolute=None) -> Freedom:
    """Freedom of a bounds table (reported beside every CF: a box of zero
    width has CF 100 %)."""
    rng = bounds.limit_upper - bounds.limit_lower
    frac = np.clip(bounds.widths() / rng, 0.0, 1.0)
    with np.errstate(divide="ignore"):
        gm = np.exp(np.mean(np.log(frac), axis=1))
    revolute = np.ones(bounds.k, bool) if revolute is None else np.asarray(revolute, bool)
    med = np.median(bounds.widths(), axis=0)
    med = np.where(revolute, np.degrees(med), med)
    return Freedom(float(gm.mean()), gm, med, ["deg" if r else "m" for r in revolute])


def shown_percent(percent: float, colliding: int, digits: int = 4) -> float:
    """A percentage rounded for people, never to 100 when a sample
    collided (rounded down then), so "CF 100 %" always means none did."""
    if colliding > 0:
        return math.floor(percent * 10 ** digits) / 10 ** digits
    return round(percent, digits)


@dataclasses.dataclass
class BoundaryCheck:
    """Where a clamp lands, judged by Drake: the box's corners and edge
    points at every waypoint and stretch midpoint.

    Attributes:
        positions: path positions checked (waypoints and midpoints).
        corners, corners_colliding: corner configurations (2^k per
            position) and how many Drake finds nearer than the margin.
        edge_points, edges_colliding: edge points (one joint uniform in its
            range, every other joint at a random one of its bounds) and how
            many collide.
        clearance: Drake's padding used, m (0: plain collision).
    """

    positions: int
    corners: int
    corners_colliding: int
    edge_points: int
    edges_colliding: int
    clearance: float


def boundary_check(workcell, bounds: BoundsTable, *, clearance: float = 0.0, edge_points: int = 64,
                   seed: int = 0) -> BoundaryCheck:
    """Checks the box's corners and edge points at every waypoint and
    stretch midpoint with Drake's checker, padded by ``clearance`` (m; a
    configuration nearer than that to an obstacle or to the robot itself
    counts as colliding). Seeded."""
    rng = np.random.default_rng(seed)
    checker = workcell.padded_checker(clearance)
    s = np.arange(0, bounds.g - 0.5, 0.5) if bounds.g > 1 else np.zeros(1)
    lo, hi, _ = bounds.boxes_at(s)
    k = bounds.k
    pattern = (np.arange(2 ** k)[:, None] >> np.arange(k)[None, :]) & 1
    corners = bad_c = bad_e = 0
    for a in range(len(s)):
        C = np.where(pattern == 1, hi[a], lo[a])
        corners += len(C)
        bad_c += int(np.sum(~np.asarray(checker.CheckConfigsCollisionFree(C, parallelize=True), bool)))
        E = C[rng.integers(0, len(C), edge_points)]
        j = rng.integers(0, k, edge_points)
        E[np.arange(edge_points), j] = lo[a, j] + rng.random(edge_points) * (hi[a, j] - lo[a, j])
        bad_e += int(np.sum(~np.asarray(checker.CheckConfigsCollisionFree(E, parallelize=True), bool)))
    return BoundaryCheck(len(s), corners, bad_c, edge_points * len(s), bad_e, float(clearance))
