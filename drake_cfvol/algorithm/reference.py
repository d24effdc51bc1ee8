"""The reference backend: the volume as one SceneGraph box per column, and
Drake's own collision checker (the paper's design, literally).

Drake's SceneGraph cost grows about quadratically with the number of
proximity geometries (its collision-filter table), so this backend is for R
up to ~1000-2000. It is the ground truth the fast backend is tested against.
"""

from __future__ import annotations

import time

import numpy as np

from drake_cfvol.algorithm.heightmap import Volume
from drake_cfvol.algorithm.table import absolute_bounds
from drake_cfvol.algorithm.volume import register_volume_boxes
from drake_cfvol.exceptions import ParameterError
from drake_cfvol.io.progress import Progress
from drake_cfvol.scene.params import VolumeParams
from drake_cfvol.scene.queries import RobotChecker

__all__ = ["ReferenceScene", "drake_sweep_bounds"]

#: Above this many columns the reference refuses (cost: see module docs).
MAX_REFERENCE_BOXES = 3000


class ReferenceScene:
    """The workcell plus the volume's boxes in one Drake scene.

    Args:
        workcell: the workcell.
        volume: the volume V.
        edge_step: Drake's edge-check step, rad or m.
        max_boxes: refuse volumes with more columns than this (Drake's
            scene grows in time and memory with every box).
        clearance: Drake's collision padding, m: a configuration nearer than
            this to the volume, an obstacle or itself counts as colliding.
    """

    def __init__(
        self,
        workcell,
        volume: Volume,
        *,
        edge_step: float = 0.01,
        max_boxes: int = MAX_REFERENCE_BOXES,
        clearance: float = 0.0,
    ):
        if volume.n_boxes > max_boxes:
            raise ParameterError(
                f"the reference backend holds one SceneGraph box per column; {volume.n_boxes} columns "
                f"exceed its practical limit of {max_boxes} (Drake's cost grows quadratically). "
                "Use backend='fast' or a lower resolution."
            )
        t0 = time.perf_counter()
        holder = {}

        def add(plant, scene_graph):
            holder["ids"] = register_volume_boxes(plant, volume, visual=False, scene_graph=scene_graph)

        self.diagram, self.robot = workcell.build_scene(add)
        self.box_ids = set(holder["ids"])
        self.build_s = time.perf_counter() - t0
        t1 = time.perf_counter()
        self.checker = RobotChecker(
            self.diagram,
            self.robot,
            workcell.slice.q_default,
            edge_step_size=edge_step,
            env_collision_padding=clearance,
            self_collision_padding=clearance,
        )
        self.checker_s = time.perf_counter() - t1
        self._context = self.diagram.CreateDefaultContext()

    def configs_free(self, Q) -> np.ndarray:
        """(N,) True where the robot is free of the volume, the obstacles and
        itself (Drake)."""
        return np.array(self.checker.CheckConfigsCollisionFree(np.atleast_2d(Q), parallelize=True), bool)

    def volume_hits(self, Q) -> np.ndarray:
        """(N,) True where the robot touches a volume column (Drake's
        penetration query, real robot geometry)."""
        plant = self.diagram.plant()
        sg = self.diagram.scene_graph()
        pctx = plant.GetMyMutableContextFromRoot(self._context)
        sctx = sg.GetMyContextFromRoot(self._context)
        out = np.zeros(len(Q), bool)
        for n, q in enumerate(np.atleast_2d(Q)):
            self.checker.slice.set_positions(pctx, q)
            query = sg.get_query_output_port().Eval(sctx)
            for pp in query.ComputePointPairPenetration():
                if pp.id_A in self.box_ids or pp.id_B in self.box_ids:
                    out[n] = True
                    break
        return out


def drake_sweep_bounds(
    workcell,
    waypoints: np.ndarray,
    volume: Volume,
    params: VolumeParams,
    *,
    scene: ReferenceScene | None = None,
    progress: bool = False,
) -> tuple[np.ndarray, np.ndarray, dict]:
    """Joint bounds by Drake alone: each single-joint motion is sampled every
    ``delta`` (the checker's resolution) from the nominal outwards; the bound
    is the last free sample before the first collision (a sample nearer
    than ``params.clearance`` counts as one).

    With ``progress``, a bar on a terminal counts the waypoints (the
    sampling, not building the scene, takes the time)."""
    waypoints = np.asarray(waypoints, float)
    g, k = waypoints.shape
    scene = scene or ReferenceScene(workcell, volume, clearance=params.clearance)
    bar = Progress(g, "Reference bounds (Drake)", enabled=progress, unit="waypoint")
    lower = waypoints.copy()
    upper = waypoints.copy()
    checks = 0
    chunk = 64
    for i, q in enumerate(waypoints):
        lo_abs, hi_abs = absolute_bounds(workcell.position_lower, workcell.position_upper, q)
        for j in range(k):
            delta = params.delta if workcell.revolute[j] else params.delta_prismatic
            for sign, limit in ((+1, hi_abs[j]), (-1, lo_abs[j])):
                span = max(sign * (limit - q[j]), 0.0)
                steps = np.r_[np.arange(delta, span, delta), span] if span > 0 else np.zeros(0)
                best = 0.0
                for start in range(0, len(steps), chunk):
                    part = steps[start : start + chunk]
                    Q = np.repeat(q[None], len(part), axis=0)
                    Q[:, j] = q[j] + sign * part
                    free = scene.configs_free(Q)
                    checks += len(part)
                    if not free.all():
                        first = int(np.argmin(free))
                        best = part[first - 1] if first > 0 else best
                        break
                    best = part[-1]
                if sign > 0:
                    upper[i, j] = q[j] + best
                else:
                    lower[i, j] = q[j] - best
        bar.update(1)
    bar.close()
    return lower, upper, {"drake_checks": checks, "scene_build_s": scene.build_s, "checker_build_s": scene.checker_s}
