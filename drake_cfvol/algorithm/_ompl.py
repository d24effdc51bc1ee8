"""The only module that talks to OMPL. numpy in, numpy out."""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np


def rrt_connect(
    lower: np.ndarray,
    upper: np.ndarray,
    start: np.ndarray,
    goal: np.ndarray,
    *,
    is_state_valid: Callable[[np.ndarray], bool],
    is_motion_valid: Callable[[np.ndarray, np.ndarray], bool],
    seed: int,
    time_limit: float,
    planner_range: float = 0.0,
) -> tuple[np.ndarray | None, dict]:
    """Plans with OMPL's RRT-Connect in a box of joint space.

    Args:
        lower, upper: (k,) joint limits.
        start, goal: (k,) configurations.
        is_state_valid: returns True if a configuration is free.
        is_motion_valid: returns True if the straight motion between two
            configurations is free (checked by the caller's own resolution).
        seed: OMPL's random seed (same seed, same tree).
        time_limit: seconds for ``solve``.
        planner_range: RRT-Connect's step (0: OMPL's default).

    Returns:
        (vertices (n, k) of the exact solution or None, stats dict)
    """
    from ompl import base as ob
    from ompl import geometric as og
    from ompl import util as ou

    # OMPL reseeds its seed generator even after RNGs exist (it logs an error
    # that we silence); every RNG created afterwards (planner, samplers) is then
    # determined by the seed. OMPL refuses 0, hence the +1.
    ou.setLogLevel(ou.LogLevel.LOG_NONE)
    ou.RNG.setSeed(int(seed) + 1)
    ou.setLogLevel(ou.LogLevel.LOG_WARN)
    k = len(lower)
    space = _space(ob, lower, upper)
    ss = og.SimpleSetup(space)
    si = ss.getSpaceInformation()
    counts = {"states": 0, "motions": 0}

    def to_np(s) -> np.ndarray:
        return np.array([s[i] for i in range(k)])

    def state_valid(s) -> bool:
        counts["states"] += 1
        return bool(is_state_valid(to_np(s)))

    class _Motion(ob.MotionValidator):
        def checkMotion(self, s1, s2, *args):  # noqa: N802 (OMPL's name)
            counts["motions"] += 1
            return bool(is_motion_valid(to_np(s1), to_np(s2)))

    ss.setStateValidityChecker(state_valid)
    motion = _Motion(si)
    si.setMotionValidator(motion)
    ss.setStartAndGoalStates(_state(space, start), _state(space, goal))
    planner = og.RRTConnect(si)
    if planner_range > 0:
        planner.setRange(float(planner_range))
    ss.setPlanner(planner)
    t0 = time.perf_counter()
    ss.solve(float(time_limit))
    elapsed = time.perf_counter() - t0
    stats = {"solve_time_s": elapsed, "state_checks": counts["states"], "motion_checks": counts["motions"]}
    if not ss.haveExactSolutionPath():
        return None, stats
    path = ss.getSolutionPath()
    states = path.getStates()
    verts = np.array([to_np(s) for s in states])
    stats["raw_vertices"] = len(verts)
    return verts, stats


def _space(ob, lower, upper):
    """OMPL's real vector state space over the box [lower, upper]."""
    k = len(lower)
    space = ob.RealVectorStateSpace(k)
    bounds = ob.RealVectorBounds(k)
    for i in range(k):
        bounds.setLow(i, float(lower[i]))
        bounds.setHigh(i, float(upper[i]))
    space.setBounds(bounds)
    return space


def _state(space, q):
    """An OMPL state of ``space`` at q."""
    s = space.allocState()
    for i, x in enumerate(q):
        s[i] = float(x)
    return s
