"""Joint bounding (paper Algorithm 2, made sound; SPEC 6-7) and the bounds
table.

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
import time
from pathlib import Path

import numpy as np

from drake_cfvol._records import load_record, save_record
from drake_cfvol.collision import RobotModel, SceneTester, robot_model, workcell_obstacles
from drake_cfvol.exceptions import DimensionError, ParameterError
from drake_cfvol.params import VolumeParams
from drake_cfvol.planning import NominalPath

__all__ = ["BoundsTable", "estimate_bounds", "absolute_bounds", "sweep_bounds", "interpolate_bounds"]

FORMAT_VERSION = 1


def absolute_bounds(workcell, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Algorithm 2's absolute bounds B: the position limits; a joint without
    limits uses nominal +- pi (SPEC 2)."""
    lo = workcell.position_lower.copy()
    hi = workcell.position_upper.copy()
    lo = np.where(np.isfinite(lo), lo, q - np.pi)
    hi = np.where(np.isfinite(hi), hi, q + np.pi)
    return lo, hi


def _rodrigues(u: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """Rotation matrices (N, 3, 3) about unit axes u (N, 3) by theta (N,)."""
    K = np.zeros((len(u), 3, 3))
    K[:, 0, 1], K[:, 0, 2] = -u[:, 2], u[:, 1]
    K[:, 1, 0], K[:, 1, 2] = u[:, 2], -u[:, 0]
    K[:, 2, 0], K[:, 2, 1] = -u[:, 1], u[:, 0]
    s, c = np.sin(theta)[:, None, None], np.cos(theta)[:, None, None]
    return np.eye(3) + s * K + (1 - c) * (K @ K)


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
    for i, wp in enumerate(waypoints[wsel]):
        lo, hi = absolute_bounds(workcell, wp)
        lo_abs[i], hi_abs[i] = lo[j], hi[j]
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
            Rot = _rodrigues(u[s], sign[s] * t_mid)
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


def interpolate_bounds(s: float, lower: np.ndarray, upper: np.ndarray, nominal: np.ndarray):
    """Bounds at path parameter s (SPEC 7).

    At integer s: the waypoint's bounds. Between waypoints i and i+1: the
    intersection of the two boxes, widened where needed to contain the
    linearly interpolated nominal.

    Returns:
        (lower (k,), upper (k,), nominal (k,))
    """
    g = len(nominal)
    if not np.isfinite(s) or s < 0 or s > g - 1:
        raise ParameterError(f"path index s = {s} is outside [0, {g - 1}] (g = {g} waypoints).")
    i = min(int(np.floor(s)), g - 2) if g > 1 else 0
    t = s - i
    if t == 0.0 or g == 1:
        return lower[i].copy(), upper[i].copy(), nominal[i].copy()
    if t == 1.0:
        return lower[i + 1].copy(), upper[i + 1].copy(), nominal[i + 1].copy()
    nom = (1 - t) * nominal[i] + t * nominal[i + 1]
    lo = np.minimum(np.maximum(lower[i], lower[i + 1]), nom)
    hi = np.maximum(np.minimum(upper[i], upper[i + 1]), nom)
    return lo, hi, nom


@dataclasses.dataclass
class BoundsTable:
    """Per-waypoint joint bounds B = [b_1 .. b_g] along a nominal path.

    Attributes:
        lower, upper, nominal: (g, k), rad or m.
        joint_names: the k joints.
        limit_lower, limit_upper: (k,) the absolute bounds used.
        params: the parameters used (a dict).
        timing_ms: categorize / volume / bounding / total, ms.
        info: everything else worth keeping (cell, path label, seed,
            backend, categories, n_boxes, lowered, dropped, test counts).
    """

    lower: np.ndarray
    upper: np.ndarray
    nominal: np.ndarray
    joint_names: list[str]
    limit_lower: np.ndarray
    limit_upper: np.ndarray
    params: dict = dataclasses.field(default_factory=dict)
    timing_ms: dict = dataclasses.field(default_factory=dict)
    info: dict = dataclasses.field(default_factory=dict)

    def __post_init__(self):
        for name in ("lower", "upper", "nominal"):
            setattr(self, name, np.asarray(getattr(self, name), float))
        if not (self.lower.shape == self.upper.shape == self.nominal.shape):
            raise DimensionError("bounds arrays", self.nominal.shape, (self.lower.shape, self.upper.shape))
        if self.nominal.shape[1] != len(self.joint_names):
            raise DimensionError("bounds columns", len(self.joint_names), self.nominal.shape[1])

    @property
    def g(self) -> int:
        return self.nominal.shape[0]

    @property
    def k(self) -> int:
        return self.nominal.shape[1]

    @property
    def s(self) -> np.ndarray:
        """The path parameter of each waypoint: 0 .. g-1."""
        return np.arange(self.g, dtype=float)

    def at(self, s: float):
        """(lower, upper, nominal) at path parameter s in [0, g-1] (SPEC 7)."""
        return interpolate_bounds(float(s), self.lower, self.upper, self.nominal)

    def widths(self) -> np.ndarray:
        """(g, k) upper - lower."""
        return self.upper - self.lower

    def to_json_dict(self) -> dict:
        return {"format": "drake_cfvol.BoundsTable", "version": FORMAT_VERSION,
                "joint_names": list(self.joint_names), "lower": self.lower.tolist(),
                "upper": self.upper.tolist(), "nominal": self.nominal.tolist(),
                "limit_lower": self.limit_lower.tolist(), "limit_upper": self.limit_upper.tolist(),
                "params": self.params, "timing_ms": self.timing_ms, "info": _jsonable(self.info)}

    def save(self, path: str | Path, *, overwrite: bool = False) -> Path:
        """Saves as ``.npz`` (arrays + JSON metadata) or ``.json``."""
        return save_record(path, self.to_json_dict(), _ARRAYS, "bounds", overwrite=overwrite)

    @classmethod
    def load(cls, path: str | Path) -> "BoundsTable":
        """Loads a table saved by :meth:`save`."""
        d, a = load_record(path, _ARRAYS, "bounds")
        return cls(a["lower"], a["upper"], a["nominal"], d["joint_names"],
                   np.array(d["limit_lower"], float), np.array(d["limit_upper"], float),
                   d.get("params", {}), d.get("timing_ms", {}), d.get("info", {}))


_ARRAYS = ("lower", "upper", "nominal")


def _jsonable(obj):
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, (np.floating, np.integer)):
        return obj.item()
    return obj


def estimate_bounds(workcell, path: NominalPath, params: VolumeParams | None = None, *,
                    backend: str = "fast", certify=None, **overrides) -> BoundsTable:
    """Algorithm 1: categorize, grow the volume, bound every joint at every
    waypoint.

    Args:
        workcell: the workcell.
        path: a nominal path of this workcell's robot.
        params: the parameters (default: the workcell's, see
            :meth:`VolumeParams.for_workcell`); ``overrides`` replace fields.
        backend: ``"fast"`` (primitives + height-field queries, any R) or
            ``"drake"`` (one SceneGraph box per column and Drake's checker;
            the reference, practical up to R ~ 1000-2000).
        certify: a :class:`drake_cfvol.certify.Certify` to shrink the boxes
            until every stretch holds a sampled safety certificate (beyond the
            paper); its report is in ``info["certificate"]`` and its time in
            ``timing_ms["certify"]`` (not part of the paper's ``total``).

    Returns:
        The bounds table; ``timing_ms["total"]`` is the paper's "time to
        compute the boundaries" (categorization + volume + bounding).
    """
    from drake_cfvol.volume import build_volume, categorize

    if params is None:
        params = VolumeParams.for_workcell(workcell, **overrides)
    elif overrides:
        params = params.replace(**overrides)
    if not isinstance(path, NominalPath):
        raise ParameterError(f"path must be a NominalPath, got {type(path).__name__}.")
    if path.k != workcell.num_joints:
        raise DimensionError("the path's configurations", workcell.num_joints, path.k,
                             f"The workcell's robot has joints {', '.join(workcell.joint_names)}.")
    if backend not in ("fast", "drake"):
        raise ParameterError(f"backend must be 'fast' or 'drake', got {backend!r}.")
    t0 = time.perf_counter()
    model = robot_model(workcell, params.sphere_tolerance)
    cats = categorize(workcell, path, params)
    t1 = time.perf_counter()
    vb = build_volume(workcell, path, params, model=model, categories=cats)
    t2 = time.perf_counter()
    if backend == "fast":
        tester = SceneTester(model, workcell_obstacles(workcell), vb.volume)
        lower, upper, stats = sweep_bounds(workcell, path.waypoints, tester, params)
    else:
        from drake_cfvol.reference import drake_sweep_bounds

        lower, upper, stats = drake_sweep_bounds(workcell, path.waypoints, vb.volume, params)
    t3 = time.perf_counter()
    lim_lo, lim_hi = absolute_bounds(workcell, path.waypoints[0])
    info = {"cell": workcell.name, "path": path.label, "seed": path.seed, "backend": backend,
            "resolution": params.resolution, "n_boxes": vb.volume.n_boxes,
            "lowered_columns": vb.volume.lowered, "dropped_columns": vb.volume.dropped,
            "categories": {"trail": cats.trail, "goal": cats.goal, "no_goal": cats.no_goal},
            "cell_side_m": vb.volume.heightmap.side, "grid": list(vb.volume.heightmap.shape), **stats}
    timing = {"categorize": (t1 - t0) * 1e3, "volume": (t2 - t1) * 1e3, "bounding": (t3 - t2) * 1e3,
              "total": (t3 - t0) * 1e3}
    table = BoundsTable(lower, upper, path.waypoints.copy(), list(workcell.joint_names), lim_lo, lim_hi,
                        params.to_dict(), timing, info)
    if certify is not None:
        from drake_cfvol.certify import certify_bounds

        info["uncertified_lower"], info["uncertified_upper"] = lower, upper
        c_lower, c_upper, report = certify_bounds(workcell, table, certify)
        table = dataclasses.replace(table, lower=c_lower, upper=c_upper)
        table.info["certificate"] = report.to_dict()
        table.timing_ms["certify"] = report.time_ms
    table.volume = vb  # not saved; for plots and the systems
    return table
