"""Joint bounding (paper Algorithm 2, made sound and safe between waypoints;
docs/spec.md, sections 6-7), on the compiled kernel.

For every stretch [i, i+1] of the path, joint j and each direction, the
bound is (to within delta) the farthest value v towards the joint's limit
such that, for every s in the stretch, moving joint j alone from the
interpolated nominal to v is free against the volume V, the obstacles and
the robot itself.

The paper tests only end values, and only at waypoints: its bisection can
jump over an obstacle, and a box found at two waypoints can collide between
them. Here each step of the search certifies a whole *region*: joint j over
an interval [a, b] while the rest of the robot follows the nominal over the
stretch. The robot is posed at the region's centre and each body grown by
how far its points can move over the region (:func:`kernel._region_hits`);
where the nominal's own motion is what makes a test fail, the stretch is
halved. Each (joint, direction) walks the stretches in order, every search
starting from the previous stretch's bound; the walks run in parallel.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from drake_cfvol import kernel as K
from drake_cfvol.algorithm.heightmap import Volume
from drake_cfvol.scene.arrays import SceneArrays
from drake_cfvol.scene.params import VolumeParams

__all__ = [
    "stretch_bounds",
    "sweep_setup",
    "sweep_range",
    "SweepSetup",
    "volume_table",
    "nominal_growth",
    "default_rate",
    "stretch_margins",
]

#: Poses are sampled along the stretch (up to kernel.MAX_T_SAMPLES) until
#: the nominal's own motion grows a body by at most this much between
#: samples, and along joint j (up to kernel.MAX_V_SAMPLES) until j's motion
#: does (m, second-order bounds).
MOTION_TOLERANCE = 0.01


def volume_table(volume: Volume | None) -> tuple[np.ndarray, float, float, float]:
    """The kernel's view of V: (range-max table, origin x, origin y, side)."""
    if volume is None or volume.n_boxes == 0:
        return np.zeros((1, 1, 0, 0)), 0.0, 0.0, 1.0
    hm = volume.heightmap
    return volume.kernel_table(), float(hm.origin[0]), float(hm.origin[1]), float(hm.side)


def nominal_growth(arrays: SceneArrays, waypoints: np.ndarray) -> np.ndarray:
    """(g-1, k): the most any body is grown over a whole stretch by the
    nominal's own motion when joint j is the one swept, m: max over bodies
    of sum_kl |dq_k| |dq_l| curvature[k, l, b] / 8, k, l != j."""
    dq = np.abs(np.diff(waypoints, axis=0))  # (g-1, k)
    out = np.zeros(dq.shape)
    for j in range(dq.shape[1]):
        d = dq.copy()
        d[:, j] = 0.0
        a = np.einsum("ik,il,klb->ib", d, d, arrays.curvature)
        out[:, j] = a.max(axis=1) / 8.0
    return out


#: Margins tried (as fractions of ``clearance``) when the nominal itself is
#: nearer than the clearance somewhere: the largest the kernel proves free
#: at both waypoints and the midpoint of a stretch is that stretch's margin.
MARGIN_LADDER = (1.0, 0.95, 0.9, 0.85, 0.8, 0.7, 0.6, 0.5, 0.4, 0.3, 0.2, 0.1, 0.0)


def stretch_margins(arrays: SceneArrays, waypoints: np.ndarray, clearance: float) -> np.ndarray:
    """(g-1,) the margin each stretch keeps, m: ``clearance`` where the
    nominal itself keeps it (planning does, except near a start or goal the
    user placed nearer), else the largest rung of MARGIN_LADDER x clearance
    at which the compiled kernel (conservative: its "free" means farther
    than the margin) finds the stretch's two waypoints and its midpoint
    free. So no box comes nearer than min(clearance, about the nominal's
    own clearance). A stretch whose nominal dips below its margin between
    those samples keeps its single-joint bounds at the nominal (the region
    tests fail there): never unsafe, only narrow."""
    W = np.ascontiguousarray(waypoints, dtype=np.float64)
    g = len(W)
    if g < 2:
        return np.zeros(0)
    if clearance <= 0:
        return np.zeros(g - 1)
    Q = np.concatenate([W, 0.5 * (W[:-1] + W[1:])])
    kept = np.zeros(len(Q))
    for rung in MARGIN_LADDER[::-1]:  # from 0 up: a rung that holds at q is kept
        ok = ~arrays.may_collide(Q, rung * clearance)
        kept = np.where(ok, rung * clearance, kept)
    per_wp, mid = kept[:g], kept[g:]
    return np.minimum(np.minimum(per_wp[:-1], per_wp[1:]), mid)


def stretch_bounds(
    arrays: SceneArrays,
    waypoints: np.ndarray,
    volume: Volume | None,
    params: VolumeParams,
    lower_limit: np.ndarray,
    upper_limit: np.ndarray,
    margins: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, dict]:
    """Certified per-stretch joint bounds.

    Args:
        arrays: the workcell's kernel arrays.
        waypoints: (g, k) the nominal path.
        volume: V (None: obstacles and self only).
        params: ``delta`` / ``delta_prismatic`` tolerances.
        lower_limit, upper_limit: (g-1, k) absolute bounds per stretch (finite).
        margins: (g-1,) the margin each stretch keeps from the obstacles,
            V and itself, m (None: :func:`stretch_margins` of
            ``params.clearance``).

    Returns:
        (lower (g-1, k), upper (g-1, k), stats). A bound may lie inside the
        nominal's own range over its stretch (``stats["pinned"]`` counts
        them): there the box is held at the nominal.
    """
    W = np.ascontiguousarray(waypoints, dtype=np.float64)
    g, k = W.shape
    n_st = g - 1
    setup = sweep_setup(arrays, W, params, lower_limit, upper_limit, margins)
    margins = setup.margins
    bounds, tests, _ = sweep_range(
        setup, arrays, W, volume_table(volume), 0, n_st - 1, np.full(len(setup.chains), np.nan)
    )
    lo_nom = np.minimum(W[:-1], W[1:])
    hi_nom = np.maximum(W[:-1], W[1:])
    upper = bounds[0::2].T.copy()
    lower = bounds[1::2].T.copy()
    region_tests = int(tests.sum())
    # A bound inside the nominal's own range over the stretch is kept as it
    # is: where the nominal passes it, the box is held at the nominal (the
    # box at s always holds nom(s); see table.box_at).
    stats = {
        "region_tests": region_tests,
        "searches": 2 * n_st * k,
        "pinned": int((upper < hi_nom).sum() + (lower > lo_nom).sum()),
        "max_t_samples": int(setup.nts.max()) if setup.nts.size else 0,
        "motion_tolerance_m": MOTION_TOLERANCE,
        "clearance_m": float(params.clearance),
        "stretches_below_clearance": int((margins < params.clearance).sum()),
        "min_margin_m": float(margins.min()) if len(margins) else float(params.clearance),
    }
    return lower, upper, stats


@dataclasses.dataclass
class SweepSetup:
    """What the sweep of a path needs besides the scene: the chains (joint,
    sign), per-joint tolerance ``delta``, the pose samples per stretch along
    t (``nts`` (g-1, k)) and the step along v (``v_steps`` (k,)), the
    absolute bounds per stretch and each stretch's margin, m."""

    chains: np.ndarray
    delta: np.ndarray
    nts: np.ndarray
    v_steps: np.ndarray
    lim_lo: np.ndarray
    lim_hi: np.ndarray
    margins: np.ndarray


def sweep_setup(
    arrays: SceneArrays,
    W: np.ndarray,
    params: VolumeParams,
    lower_limit: np.ndarray,
    upper_limit: np.ndarray,
    margins: np.ndarray | None = None,
) -> SweepSetup:
    """The sweep's inputs for a path (see :func:`stretch_bounds`)."""
    W = np.ascontiguousarray(W, dtype=np.float64)
    k = W.shape[1]
    delta = np.where(arrays.revolute, params.delta, params.delta_prismatic).astype(np.float64)
    growth = nominal_growth(arrays, W)  # (g-1, k); it scales with the sample spacing squared
    nts = np.clip(1 + np.ceil(np.sqrt(growth / MOTION_TOLERANCE)), 2, K.MAX_T_SAMPLES).astype(np.int64)
    # Along v: growth = reach L^2 / 8 <= tolerance for a step L.
    reach_j = np.where(arrays.revolute, arrays.reach.max(axis=1), 0.0)
    v_steps = np.where(reach_j > 0, np.sqrt(8 * MOTION_TOLERANCE / np.maximum(reach_j, 1e-9)), np.inf)
    if margins is None:
        margins = stretch_margins(arrays, W, params.clearance)
    chains = np.array([(j, sgn) for j in range(k) for sgn in (1, -1)], np.int64)
    return SweepSetup(
        chains,
        delta,
        nts,
        v_steps,
        np.ascontiguousarray(lower_limit, dtype=np.float64),
        np.ascontiguousarray(upper_limit, dtype=np.float64),
        np.ascontiguousarray(margins, dtype=np.float64),
    )


def sweep_range(
    setup: SweepSetup,
    arrays: SceneArrays,
    W: np.ndarray,
    field: tuple,
    a: int,
    b: int,
    guesses: np.ndarray,
    chains: np.ndarray | None = None,
    memo: tuple | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The sweep over stretches a..b (inclusive), each chain starting from
    ``guesses`` (n,) (NaN: cold; a full sweep starts cold at stretch 0).

    Args:
        field: :func:`volume_table`'s (table, ox, oy, side).
        chains: (n, 2) the chains (joint, sign) to walk (default: all of
            ``setup.chains``).
        memo: (tests (n, b-a+1, MEMO_T, MEMO_W), counts (n, b-a+1),
            changed (C, 6)): each search's tests as run last time, read and
            rewritten in place, and the boxes where the scene changed since
            (:func:`drake_cfvol.kernel.sweep_chains`); None: none kept.

    Returns:
        (bounds (n, b-a+1), tests (n,), footprints (n, b-a+1, 6)): chain n
        is ``setup.chains[n]``; a footprint is the box (min xyz, max xyz)
        holding every body the search tested against the scene, m
        (obstacles and columns outside it cannot change that search).
    """
    table, ox, oy, side = field
    sl = slice(a, b + 1)
    chains = setup.chains if chains is None else np.ascontiguousarray(chains, dtype=np.int64)
    return K.sweep_chains(
        chains,
        (setup.lim_lo[sl], setup.lim_hi[sl], setup.delta),
        np.ascontiguousarray(setup.nts[sl]),
        setup.v_steps,
        np.ascontiguousarray(W[a : b + 2]),
        arrays.model,
        K.HeightField(table, float(ox), float(oy), float(side)),
        setup.margins[sl],
        np.ascontiguousarray(guesses, dtype=np.float64),
        *(memo if memo is not None else no_memo()),
    )


def no_memo() -> tuple:
    """A memo argument of :func:`drake_cfvol.kernel.sweep_chains` that keeps
    nothing."""
    return np.zeros((0, 0, 0, K.MEMO_W)), np.zeros((0, 0), np.int64), np.zeros((0, 6))


#: Without a given time per waypoint, the nominal is taken to run at this
#: fraction of the joints' velocity limits (a collaborative speed).
NOMINAL_SPEED_FRACTION = 0.25


def default_rate(waypoints: np.ndarray, velocity_limits: np.ndarray, waypoint_time: float | None) -> np.ndarray:
    """The bounds' Lipschitz rate per unit s (docs/spec.md, section 7): each
    joint's velocity limit times the nominal time per waypoint, so that a
    clamp following the nominal never has to move a joint faster than its
    limit. Without a given ``waypoint_time``: the time per waypoint of the
    nominal at NOMINAL_SPEED_FRACTION of the limits (its slowest joint sets
    it: max over steps and joints of |dq_j| / (fraction vmax_j)). A joint
    without a velocity limit gets no rate limit (inf)."""
    vmax = np.asarray(velocity_limits, float)
    ok = np.isfinite(vmax) & (vmax > 0)
    if waypoint_time is None:
        step = np.abs(np.diff(waypoints, axis=0)).max(axis=0) if len(waypoints) > 1 else np.zeros(len(vmax))
        per = np.where(ok, step / np.where(ok, NOMINAL_SPEED_FRACTION * vmax, 1.0), 0.0)
        waypoint_time = float(per.max()) if per.size else 0.0
    rate = np.where(ok, vmax * waypoint_time, math.inf)
    # A rate below the nominal's own motion could not hold the nominal.
    if len(waypoints) > 1:
        rate = np.maximum(rate, np.abs(np.diff(waypoints, axis=0)).max(axis=0))
    return rate
