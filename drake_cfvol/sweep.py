"""Joint bounding (paper Algorithm 2, made sound; docs/spec.md, section 6).

For waypoint q_i, joint j and each direction, the bound is (to within delta)
the farthest value v towards the joint's limit such that moving joint j alone
from q_i[j] to v is free along the whole motion against the volume V, the
obstacles and the robot itself.

The paper's bisection tests only end values and can jump over an obstacle.
Here each bisection step tests an *interval* [a, b] of the motion: the
moving bodies are posed at the interval's midpoint and grown by how far any
of their points travels over half the interval (distance from the joint axis
times the half-width, or the half-width for a prismatic joint). A free test
certifies the whole interval. All sweeps of one joint (every waypoint, both
directions) are bisected together in one batch.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy.spatial.transform import Rotation

from drake_cfvol.collision import RobotModel, SceneTester
from drake_cfvol.params import VolumeParams
from drake_cfvol.table import absolute_bounds

__all__ = ["sweep_bounds"]


@dataclasses.dataclass
class _Kinematics:
    """Body poses and joint axes at every waypoint."""

    R: np.ndarray  # (g, B, 3, 3)
    p: np.ndarray  # (g, B, 3)
    axis_point: np.ndarray  # (g, k, 3)
    axis_dir: np.ndarray  # (g, k, 3)


def _kinematics(workcell, model: RobotModel, waypoints: np.ndarray) -> _Kinematics:
    plant = workcell.plant
    joints = [plant.GetJointByName(n, workcell.robot) for n in workcell.joint_names]
    local_axes = [np.asarray(j.revolute_axis() if r else j.translation_axis())
                  for j, r in zip(joints, workcell.revolute)]
    g, k, B = len(waypoints), len(joints), model.num_bodies
    R = np.empty((g, B, 3, 3))
    p = np.empty((g, B, 3))
    c = np.empty((g, k, 3))
    u = np.empty((g, k, 3))
    for i, q in enumerate(waypoints):
        R[i], p[i] = model.body_poses(workcell, q)
        ctx = workcell.plant_context()
        for jj, (joint, ax) in enumerate(zip(joints, local_axes)):
            X = joint.frame_on_child().CalcPoseInWorld(ctx)
            c[i, jj] = X.translation()
            u[i, jj] = X.rotation().matrix() @ ax
    return _Kinematics(R, p, c, u)


def _joint_sweeps(workcell, tester, kin, waypoints, j, wsel, guess, delta, counters):
    """Bounds of joint j at the waypoints ``wsel`` (both directions).

    ``guess`` (2 * len(wsel),) or None: expected free extents (from a
    neighbouring waypoint). The first test is then [0, guess]; if free, the
    next probes just past it (2 delta), so a good guess costs ~4 tests.

    Returns:
        F (2 * len(wsel),): certified free extent, upper direction first.
    """
    model = tester.model
    moving = model.moved_by[j]
    pairs = counters.setdefault(("pairs", j), np.array(
        [pr for pr in model.self_pairs if moving[pr[0]] != moving[pr[1]]], int).reshape(-1, 2))
    revolute = bool(workcell.revolute[j])
    n = len(wsel)
    q = waypoints[wsel, j]
    lo_abs = np.empty(n)
    hi_abs = np.empty(n)
    lo_all, hi_all = absolute_bounds(workcell.position_lower, workcell.position_upper, waypoints[wsel])
    lo_abs[:], hi_abs[:] = lo_all[:, j], hi_all[:, j]
    w_idx = np.concatenate([wsel, wsel])
    sign = np.concatenate([np.ones(n), -np.ones(n)])
    T = np.maximum(np.concatenate([hi_abs - q, q - lo_abs]), 0.0)
    c = kin.axis_point[w_idx, j]
    u = kin.axis_dir[w_idx, j]
    R0, p0 = kin.R[w_idx], kin.p[w_idx]
    if revolute:
        # Farthest distance of each body's points from the joint axis.
        bc = np.einsum("sbij,bj->sbi", R0, model.bound_c) + p0
        rel = bc - c[:, None]
        along = np.einsum("sbi,si->sb", rel, u)
        perp = np.linalg.norm(rel - along[..., None] * u[:, None], axis=-1)
        rho = (perp + model.bound_r) * moving
    else:
        rho = np.broadcast_to(moving.astype(float), (2 * n, model.num_bodies))
    # Adaptive stepping: test [F, F + w]; free -> certified, advance and
    # double w; possible collision -> halve w; stop when a possibly
    # colliding interval is narrower than delta.
    F = np.zeros(2 * n)
    if guess is None:
        w = T.copy()
        w_next = np.full(2 * n, np.nan)
    else:
        w = np.clip(guess, delta, None)
        w_next = np.full(2 * n, 2 * delta)
    active = T > 0
    mv = np.flatnonzero(moving)
    while active.any():
        counters["rounds"] = counters.get("rounds", 0) + 1
        s = np.flatnonzero(active)
        counters["interval_tests"] = counters.get("interval_tests", 0) + len(s)
        X = np.minimum(F[s] + w[s], T[s])
        t_mid = (F[s] + X) / 2
        hw = (X - F[s]) / 2
        Rs, ps = R0[s].copy(), p0[s].copy()
        if revolute:
            Rot = Rotation.from_rotvec(u[s] * (sign[s] * t_mid)[:, None]).as_matrix()
            Rs[:, mv] = np.einsum("nij,nbjk->nbik", Rot, Rs[:, mv])
            ps[:, mv] = np.einsum("nij,nbj->nbi", Rot, ps[:, mv] - c[s][:, None]) + c[s][:, None]
        else:
            ps[:, mv] += (sign[s] * t_mid)[:, None, None] * u[s][:, None, :]
        e = rho[s] * hw[:, None]
        hit = tester.hits(Rs, ps, e, moving, pairs, axis=u[s], prismatic=not revolute)
        sf = s[~hit]
        F[sf] = X[~hit]
        first = ~np.isnan(w_next[sf])
        w[sf] = np.where(first, w_next[sf], 2 * w[sf])
        w_next[sf] = np.nan
        active[sf[F[sf] >= T[sf]]] = False
        sb = s[hit]
        w_next[sb] = np.nan
        width = X[hit] - F[sb]
        stop = width < delta
        active[sb[stop]] = False
        w[sb[~stop]] = width[~stop] / 2
    return F


def sweep_bounds(workcell, waypoints: np.ndarray, tester: SceneTester, params: VolumeParams,
                 *, kin: _Kinematics | None = None, stride: int = 8) -> tuple[np.ndarray, np.ndarray, dict]:
    """Sound per-joint bounds at each waypoint by batched interval bisection.

    Every ``stride``-th waypoint (and the last) is bounded from scratch; the
    others start from the nearest such waypoint's result (a guess only: the
    answer is certified the same way).

    Args:
        workcell: the workcell.
        waypoints: (g, k) configurations.
        tester: what counts as a collision (volume, obstacles, self).
        params: ``delta`` / ``delta_prismatic`` tolerances.
        stride: spacing of the cold-started waypoints (1: all cold).

    Returns:
        (lower (g, k), upper (g, k), stats)
    """
    model = tester.model
    waypoints = np.asarray(waypoints, float)
    g, k = waypoints.shape
    kin = kin or _kinematics(workcell, model, waypoints)
    lower = waypoints.copy()
    upper = waypoints.copy()
    counters: dict = {}
    cold = np.unique(np.r_[np.arange(0, g, max(1, stride)), g - 1])
    warm = np.setdiff1d(np.arange(g), cold)
    nearest = cold[np.abs(warm[:, None] - cold[None, :]).argmin(axis=1)] if len(warm) else warm
    for j in range(k):
        delta = params.delta if workcell.revolute[j] else params.delta_prismatic
        Fc = _joint_sweeps(workcell, tester, kin, waypoints, j, cold, None, delta, counters)
        n = len(cold)
        upper[cold, j] += Fc[:n]
        lower[cold, j] -= Fc[n:]
        if len(warm):
            pos = np.searchsorted(cold, nearest)
            guess = np.concatenate([Fc[:n][pos], Fc[n:][pos]])
            Fw = _joint_sweeps(workcell, tester, kin, waypoints, j, warm, guess, delta, counters)
            m = len(warm)
            upper[warm, j] += Fw[:m]
            lower[warm, j] -= Fw[m:]
    stats = {"interval_tests": counters.get("interval_tests", 0), "rounds": counters.get("rounds", 0)}
    return lower, upper, stats
