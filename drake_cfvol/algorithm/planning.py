"""Nominal paths: RRT-Connect (OMPL) in joint space, checked by Drake.

SPEC 3: plan within the position limits with Drake's collision checking of
the real scene (obstacles + self, adjacent links filtered), simplify, densify
so that no joint moves more than ``max_step`` between waypoints, verify every
edge with Drake, and reject waypoints near a singularity.
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
import time
from pathlib import Path

import numpy as np
import numpy.typing as npt
from pydrake.multibody.tree import JacobianWrtVariable

from drake_cfvol.algorithm import _ompl
from drake_cfvol.exceptions import (
    CfvolError,
    DimensionError,
    ParameterError,
    PlanningError,
    RecordFormatError,
    SingularityError,
)
from drake_cfvol.io.arguments import instance, names, real_array, real_number, text, whole_number
from drake_cfvol.io.records import load_record, save_record
from drake_cfvol.scene.params import VolumeParams
from drake_cfvol.scene.workcell import Workcell

__all__ = ["NominalPath", "plan_nominal_path", "densify", "min_singular_value"]

FORMAT_VERSION = 1


@dataclasses.dataclass
class NominalPath:
    """A collision-free nominal path Q = [q_1 .. q_g].

    Attributes:
        waypoints: (g, k) array, rad or m.
        joint_names: the k joint names.
        cell: the workcell's name.
        label: e.g. ``"path1"`` (or "" for a custom pair).
        seed: the planner's seed.
        stats: planning statistics (times in ms, counts).
        fingerprint: the cell it was made in
            (:func:`drake_cfvol.algorithm.reuse.fingerprint_of`; empty when
            not recorded), saved with it and checked when it is used again.
    """

    waypoints: np.ndarray
    joint_names: list[str]
    cell: str = ""
    label: str = ""
    seed: int = 0
    stats: dict = dataclasses.field(default_factory=dict)
    fingerprint: dict = dataclasses.field(default_factory=dict, compare=False)

    def __post_init__(self):
        self.waypoints = np.ascontiguousarray(real_array(self.waypoints, "NominalPath: waypoints"))
        if self.waypoints.ndim != 2 or self.waypoints.shape[0] < 2:
            raise DimensionError("path waypoints", "(g >= 2, k)", self.waypoints.shape)
        self.joint_names = names(self.joint_names, "NominalPath: joint_names")
        for name in ("stats", "fingerprint"):
            instance(getattr(self, name), dict, f"NominalPath: {name}")
        if self.waypoints.shape[1] != len(self.joint_names):
            raise DimensionError("path waypoints' columns", len(self.joint_names), self.waypoints.shape[1])
        bad = np.argwhere(~np.isfinite(self.waypoints))
        if len(bad):
            i, j = bad[0]
            raise ParameterError(
                f"NominalPath: waypoint {i + 1}, joint '{self.joint_names[j]}' is {self.waypoints[i, j]}, not a number"
            )

    @property
    def g(self) -> int:
        """Number of waypoints."""
        return self.waypoints.shape[0]

    @property
    def k(self) -> int:
        """Number of joints."""
        return self.waypoints.shape[1]

    @property
    def length(self) -> float:
        """Joint-space length (sum of Euclidean edge lengths)."""
        return float(np.linalg.norm(np.diff(self.waypoints, axis=0), axis=1).sum())

    @property
    def sha256(self) -> str:
        """SHA-256 of the waypoint array's bytes (float64, C order)."""
        return hashlib.sha256(self.waypoints.tobytes()).hexdigest()

    def at(self, s: float) -> np.ndarray:
        """The nominal at path parameter ``s`` in [0, g-1] (linear between
        waypoints)."""
        s = real_number(s, "NominalPath.at: s")
        if not (0.0 <= s <= self.g - 1) or not np.isfinite(s):
            raise ParameterError(f"path index s = {s} is outside [0, {self.g - 1}] (g = {self.g} waypoints).")
        i = min(int(np.floor(s)), self.g - 2)
        t = s - i
        return (1 - t) * self.waypoints[i] + t * self.waypoints[i + 1]

    def to_dict(self) -> dict:
        return {
            "format": "drake_cfvol.NominalPath",
            "version": FORMAT_VERSION,
            "cell": self.cell,
            "label": self.label,
            "seed": self.seed,
            "joint_names": list(self.joint_names),
            "waypoints": self.waypoints.tolist(),
            "sha256": self.sha256,
            "stats": self.stats,
            **({"fingerprint": self.fingerprint} if self.fingerprint else {}),
        }

    def save(self, path: str | Path, *, overwrite: bool = False) -> Path:
        """Saves as ``.npz`` or readable ``.json`` (by the suffix).

        Raises:
            OutputExistsError: (a FileExistsError) the file exists and
                ``overwrite`` is False.
            OutputPathError: the file cannot be written.
        """
        return save_record(path, self.to_dict(), ("waypoints",), "path", overwrite=overwrite)

    @classmethod
    def load(cls, path: str | Path) -> "NominalPath":
        """Loads a path saved by :meth:`save`.

        Raises:
            RecordFormatError: the file is missing, empty, truncated or not a path.
        """
        d, arrays = load_record(path, ("waypoints",), "path", required=("joint_names",))
        try:
            out = cls(
                arrays["waypoints"],
                d["joint_names"],
                str(d.get("cell", "")),
                str(d.get("label", "")),
                d.get("seed", 0),
                d.get("stats", {}),
                d.get("fingerprint") or {},
            )
        except (CfvolError, TypeError, ValueError) as e:
            raise RecordFormatError(path, "path", " ".join(str(e).split()).rstrip(".")) from None
        if "sha256" in d and d["sha256"] != out.sha256:
            raise RecordFormatError(
                path, "path", "its waypoints do not match the sha256 saved with them (the file was edited after saving)"
            )
        return out


def densify(vertices: np.ndarray, max_step: float) -> np.ndarray:
    """Subdivides each edge evenly so no coordinate moves more than
    ``max_step`` between consecutive waypoints."""
    out = [vertices[0]]
    for a, b in zip(vertices[:-1], vertices[1:]):
        n = max(1, int(np.ceil(np.max(np.abs(b - a)) / max_step - 1e-12)))
        for i in range(1, n):
            out.append(a + (b - a) * (i / n))
        out.append(b.copy())
    return np.array(out)


def kernel_loaded() -> bool:
    """Whether the kernel's configuration check is compiled or loaded in
    this process (after :func:`~drake_cfvol.algorithm.pipeline.warm_up`,
    or any kernel check)."""
    from drake_cfvol import kernel as K

    return bool(K.configs_may_collide_serial.signatures)


def min_singular_value(workcell: Workcell, q: np.ndarray) -> float:
    """Smallest singular value of the tool frame's spatial Jacobian at q."""
    plant = workcell.plant
    ctx = workcell.plant_context(q)
    J = plant.CalcJacobianSpatialVelocity(
        ctx, JacobianWrtVariable.kQDot, workcell.tool_frame, np.zeros(3), plant.world_frame(), plant.world_frame()
    )
    return float(np.linalg.svd(J, compute_uv=False)[-1])


def _shortcut(verts: np.ndarray, edge_free, rng: np.random.Generator, iterations: int) -> np.ndarray:
    """Seeded random shortcutting, then greedy vertex reduction."""
    rows = [v for v in verts]
    for _ in range(iterations):
        if len(rows) <= 2:
            break
        i, j = sorted(rng.choice(len(rows), size=2, replace=False))
        if j - i < 2:
            continue
        if edge_free(rows[i], rows[j]):
            rows = rows[: i + 1] + rows[j:]
    out = [rows[0]]
    i = 0
    while i < len(rows) - 1:
        j = len(rows) - 1
        while j > i + 1 and not edge_free(rows[i], rows[j]):
            j -= 1
        out.append(rows[j])
        i = j
    return np.array(out)


def _checked_request(workcell, q_start, q_goal, seed, time_limit, max_step, singular_threshold, clearance):
    """Checks a planning request; returns (start, goal, lower, upper, the
    margin the path keeps: the clearance, lowered to 0.9 x the start's or
    goal's own clearance where that is nearer)."""
    instance(workcell, Workcell, "workcell", "drake_cfvol.load_workcell")
    whole_number(seed, "seed")
    time_limit = real_number(time_limit, "time_limit")
    if not 0 < time_limit < math.inf:
        raise ParameterError(
            f"time_limit must be a finite number of seconds > 0, got {time_limit} (CLI: --time-limit 10): "
            "the planner stops only at it when the goal cannot be reached."
        )
    if not 0 < real_number(max_step, "max_step") < math.inf:
        raise ParameterError(f"max_step must be a finite number > 0, got {max_step}.")
    if not 0 <= real_number(singular_threshold, "singular_threshold") < math.inf:
        raise ParameterError(f"singular_threshold must be a finite number >= 0, got {singular_threshold}.")
    workcell.require_collision_geometry("planning a path")
    lower, upper = workcell.finite_limits("Planning a nominal path")
    start = workcell.validate_configuration(q_start, "start configuration")
    goal = workcell.validate_configuration(q_goal, "goal configuration")
    workcell.require_free(start, "The start configuration")
    workcell.require_free(goal, "The goal configuration")
    for what, q in (("start", start), ("goal", goal)):
        sv = min_singular_value(workcell, q)
        if sv <= singular_threshold:
            raise SingularityError(
                f"The {what} configuration is singular: the tool Jacobian's smallest singular value is "
                f"{sv:.2e} <= {singular_threshold:.1e}. Move the wrist off the singularity (e.g. a "
                "non-zero wrist bend)."
            )
    if clearance is None:
        clearance = VolumeParams.for_workcell(workcell).clearance
    if not (np.isfinite(real_number(clearance, "clearance")) and 0.0 <= clearance <= 0.5):
        raise ParameterError(f"clearance must be in [0, 0.5] m, got {clearance!r}.")
    margin = float(clearance)
    if margin > 0:
        ends = min(workcell.clearance(start, margin), workcell.clearance(goal, margin))
        margin = min(margin, 0.9 * ends)
    return start, goal, lower, upper, margin


def _attempt(
    workcell,
    lower,
    upper,
    start,
    goal,
    checker,
    attempt_seed,
    time_left,
    max_step,
    shortcut_iterations,
    singular_threshold,
):
    """One planning attempt: RRT-Connect, seeded shortcuts, densified and
    verified (every edge by Drake's padded checker's answer, which the
    kernel gives where it can certify a sample free,
    :class:`~drake_cfvol.scene.queries.KernelFirstChecker`; every waypoint
    off the singularities). Returns (waypoints, stats) or why it failed (str)."""
    edge_free = checker.CheckEdgeCollisionFree
    t0 = time.perf_counter()
    verts, ostats = _ompl.rrt_connect(
        lower,
        upper,
        start,
        goal,
        is_state_valid=checker.CheckConfigCollisionFree,
        is_motion_valid=edge_free,
        seed=attempt_seed,
        time_limit=time_left,
    )
    plan_ms = (time.perf_counter() - t0) * 1e3
    if verts is None:
        return "no solution"
    t1 = time.perf_counter()
    verts = _shortcut(verts, edge_free, np.random.default_rng(attempt_seed), shortcut_iterations)
    simplify_ms = (time.perf_counter() - t1) * 1e3
    verts[0], verts[-1] = start, goal
    wp = densify(verts, max_step)
    t2 = time.perf_counter()
    bad_edge = next((i for i in range(len(wp) - 1) if not edge_free(wp[i], wp[i + 1])), None)
    if bad_edge is not None:
        return f"densified edge {bad_edge} collides"
    sv = np.array([min_singular_value(workcell, q) for q in wp])
    verify_ms = (time.perf_counter() - t2) * 1e3
    if sv.min() <= singular_threshold:
        return f"waypoint {int(sv.argmin())} singular ({sv.min():.1e})"
    return wp, {
        "plan_time_ms": plan_ms,
        "simplify_time_ms": simplify_ms,
        "verify_time_ms": verify_ms,
        "raw_vertices": int(ostats.get("raw_vertices", 0)),
        "simplified_vertices": len(verts),
        "state_checks": ostats["state_checks"],
        "motion_checks": ostats["motion_checks"],
        "min_singular_value": float(sv.min()),
    }


def plan_nominal_path(
    workcell: Workcell,
    q_start: npt.ArrayLike,
    q_goal: npt.ArrayLike,
    *,
    seed: int,
    time_limit: float = 10.0,
    max_step: float = 0.05,
    singular_threshold: float = 1e-3,
    shortcut_iterations: int = 60,
    label: str = "",
    clearance: float | None = None,
) -> NominalPath:
    """Plans a collision-free nominal path with RRT-Connect.

    Args:
        workcell: the workcell.
        q_start, q_goal: (k,) configurations, rad or m.
        seed: random seed; the same seed gives byte-identical waypoints.
        time_limit: total seconds for all attempts.
        max_step: densification step, rad or m per joint.
        singular_threshold: smallest allowed singular value of the tool
            Jacobian at any waypoint.
        shortcut_iterations: random shortcut attempts (seeded).
        label: stored on the path (e.g. ``"path1"``).
        clearance: the margin every waypoint and edge keeps from the
            obstacles and the robot itself, m (None: the workcell's
            ``VolumeParams`` value, 0.02 by default). A start or goal nearer
            than that lowers it for this path to 0.9 x its own clearance;
            ``stats["clearance_m"]`` is the margin the path keeps.

    Raises:
        DimensionError, JointLimitError: bad start/goal.
        CollisionError: start or goal collides (names the bodies).
        SingularityError: start or goal is singular.
        MissingJointLimitsError: a joint has no finite limits.
        PlanningError: no path within the time limit.
    """
    start, goal, lower, upper, margin = _checked_request(
        workcell, q_start, q_goal, seed, time_limit, max_step, singular_threshold, clearance
    )
    whole_number(shortcut_iterations, "shortcut_iterations")
    text(label, "label")
    # Drake's answers either way; the kernel asked first where it is loaded
    # in this process already (a fresh environment would compile it inside
    # the planning's time limit).
    checker = workcell.planning_checker(margin) if kernel_loaded() else workcell.padded_checker(margin)

    t_total = time.perf_counter()
    deadline = t_total + time_limit
    attempts = 0
    failures: list[str] = []
    while deadline - time.perf_counter() > 0:
        attempt_seed = int(seed) * 1009 + attempts
        attempts += 1
        found = _attempt(
            workcell,
            lower,
            upper,
            start,
            goal,
            checker,
            attempt_seed,
            deadline - time.perf_counter(),
            max_step,
            shortcut_iterations,
            singular_threshold,
        )
        if isinstance(found, str):
            failures.append(found)
            continue
        wp, stats = found
        stats.update(
            {
                "total_time_ms": (time.perf_counter() - t_total) * 1e3,
                "attempts": attempts,
                "max_step": max_step,
                "rejected": list(failures),
                "clearance_m": margin,
            }
        )
        return NominalPath(wp, list(workcell.joint_names), workcell.name, label, int(seed), stats)
    why = "; ".join(failures[-3:]) or "no attempt could start"
    raise PlanningError(
        f"No collision-free path from start to goal in {time_limit:g} s ({attempts} attempt(s); last: "
        f"{why}). Raise time_limit (CLI: --time-limit), or check that the goal is reachable."
    )
