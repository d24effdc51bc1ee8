"""Object categorization (SPEC 4) and the height-map volume V (SPEC 5)."""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy.spatial import ConvexHull

from drake_cfvol.collision import RobotModel
from drake_cfvol.exceptions import WorkcellError
from drake_cfvol.heightmap import FootprintRaster, HeightMap, Volume, height_function
from drake_cfvol.params import VolumeParams
from drake_cfvol.planning import NominalPath

__all__ = ["Categories", "VolumeBuild", "categorize", "build_volume", "ground_obstacles", "footprint_polygon"]

#: An obstacle whose top is at most this high is ground (the floor).
GROUND_TOP = 1e-3


@dataclasses.dataclass
class Categories:
    """The obstacle sets of SPEC 4 (disjoint; their union is every obstacle).

    Attributes:
        trail: obstacles within ``trail_radius`` of the robot somewhere on the
            path (the robot's own posed geometry is the rest of the trail).
        goal: obstacles, not in the trail, within ``goal_radius`` of the robot
            at the goal.
        no_goal: every other obstacle.
        trail_distance: per obstacle, the smallest signed distance to the
            robot over the path that Drake reported (inf: beyond the radius).
        goal_distance: per obstacle, the signed distance to the robot at the
            goal (inf: beyond the radius).
    """

    trail: list[str]
    goal: list[str]
    no_goal: list[str]
    trail_distance: dict[str, float]
    goal_distance: dict[str, float]

    def of(self, name: str) -> str:
        """The category ("trail", "goal" or "no_goal") of an obstacle."""
        for cat in ("trail", "goal", "no_goal"):
            if name in getattr(self, cat):
                return cat
        raise KeyError(name)


def categorize(workcell, path: NominalPath, params: VolumeParams) -> Categories:
    """Sorts the obstacles into trail, goal and no-goal sets (SPEC 4) with
    Drake's signed-distance queries on the real geometry."""
    trail_d: dict[str, float] = {}
    for q in path.waypoints:
        for name, d in workcell.obstacle_distances(q, params.trail_radius).items():
            trail_d[name] = min(trail_d.get(name, np.inf), d)
    goal_d = workcell.obstacle_distances(path.waypoints[-1], params.goal_radius)
    names = list(workcell.obstacles)
    trail = [n for n in names if trail_d.get(n, np.inf) < params.trail_radius]
    goal = [n for n in names if n not in trail and goal_d.get(n, np.inf) < params.goal_radius]
    no_goal = [n for n in names if n not in trail and n not in goal]
    return Categories(trail, goal, no_goal,
                      {n: float(trail_d.get(n, np.inf)) for n in names},
                      {n: float(goal_d.get(n, np.inf)) for n in names})


def ground_obstacles(workcell) -> set[str]:
    """Obstacles whose top is at floor level (z <= 1 mm): their footprint is
    the whole map, so they take no part in the height function's distances
    (the volume stands on them anyway)."""
    obs = workcell.obstacle_boxes()
    tops = {}
    for name, c, R, h in zip(obs.names, obs.centre, obs.R, obs.half):
        top = c[2] + np.abs(R[2]) @ h
        tops[name] = max(tops.get(name, -np.inf), top)
    return {n for n, t in tops.items() if t <= GROUND_TOP}


def footprint_polygon(centre, R, half) -> np.ndarray:
    """The xy projection of an oriented box: a convex polygon (n, 2)."""
    signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)])
    corners = centre + (signs * half) @ R.T
    xy = corners[:, :2]
    return xy[ConvexHull(xy).vertices]


def reach_activation(workcell, path: NominalPath, hm: HeightMap, reach: float) -> np.ndarray:
    """(m, n) True where the cell centre is within ``reach`` of the robot's
    base (or of the segment its base travels along a linear axis)."""
    X, Y = hm.centres()
    q0 = path.waypoints[0]
    base = workcell.base_frame.CalcPoseInWorld(workcell.plant_context(q0)).translation()[:2]
    if workcell.rail_joint is None:
        return np.hypot(X - base[0], Y - base[1]) <= reach
    j = workcell.joint_names.index(workcell.rail_joint)
    ends = []
    for v in (workcell.position_lower[j], workcell.position_upper[j]):
        q = q0.copy()
        q[j] = v
        ends.append(workcell.base_frame.CalcPoseInWorld(workcell.plant_context(q)).translation()[:2])
    a, b = ends
    ab = b - a
    t = np.clip(((X - a[0]) * ab[0] + (Y - a[1]) * ab[1]) / max(ab @ ab, 1e-12), 0, 1)
    return np.hypot(X - (a[0] + t * ab[0]), Y - (a[1] + t * ab[1])) <= reach


def height_map_of(workcell, params: VolumeParams) -> HeightMap:
    """The workcell's height map at resolution ``params.resolution``."""
    o, size = workcell.height_map_origin, workcell.height_map_size
    if not (np.all(np.isfinite(o)) and np.all(np.isfinite(size))):
        raise WorkcellError(
            f"workcell '{workcell.name}' has no height map extent: set cfvol.height_map: "
            "{origin: [x, y], size: [x_dim, y_dim]} (m).")
    return HeightMap((float(o[0]), float(o[1])), float(size[0]), float(size[1]), params.resolution)


@dataclasses.dataclass
class VolumeBuild:
    """What :func:`build_volume` made.

    Attributes:
        volume: the volume V.
        categories: the obstacle sets.
        d_t, d_g, d_ng: (m, n) distances from the cell centres to the
            footprints, m.
        active: (m, n) reach activation.
    """

    volume: Volume
    categories: Categories
    d_t: np.ndarray
    d_g: np.ndarray
    d_ng: np.ndarray
    active: np.ndarray


def build_volume(workcell, path: NominalPath, params: VolumeParams, *,
                 model: RobotModel | None = None, categories: Categories | None = None) -> VolumeBuild:
    """Grows the volume V around a nominal path (SPEC 4-5).

    The trail's footprint is the xy projection of the robot's cover spheres
    at every waypoint (a superset of its geometry) and of the trail
    obstacles. Columns that the robot would touch at a nominal waypoint
    (coarse cells, SPEC 5) are lowered under it, or dropped; the counts are
    in ``volume.lowered`` / ``volume.dropped``.
    """
    model = model or workcell.robot_geometry(params.sphere_tolerance)
    cats = categories or categorize(workcell, path, params)
    hm = height_map_of(workcell, params)
    obs = workcell.obstacle_boxes()
    ground = ground_obstacles(workcell)
    lo = np.array(hm.origin)
    hi = lo + [hm.x_dim, hm.y_dim]
    pad = max(params.d_t_ub, params.d_g_ub, params.d_ng_ub)
    raster = FootprintRaster(lo, hi, params.raster, pad)

    # Robot cover spheres at every waypoint (bodies that never move: once).
    R, p = model.batch_poses(workcell, path.waypoints)
    moving = model.moved_by.any(axis=0)
    centres = model.cover_world(R, p)  # (g, Nc, 3)
    cover_moving = moving[model.cover_body]
    pts = np.concatenate([centres[:, cover_moving].reshape(-1, 3), centres[0, ~cover_moving]])
    rad = np.concatenate([np.tile(model.cover_r[cover_moving], len(path.waypoints)),
                          model.cover_r[~cover_moving]])

    masks = {c: raster.empty() for c in ("trail", "goal", "no_goal")}
    for name, c, Rb, h in zip(obs.names, obs.centre, obs.R, obs.half):
        if name in ground:
            continue
        raster.fill_polygon(masks[cats.of(name)], footprint_polygon(c, Rb, h))
    d_trail_obs = raster.distance(masks["trail"])
    d_trail_robot = raster.disc_distance(pts[:, :2], rad, quantum=0.05)
    X, Y = hm.centres()
    d_t = raster.sample(np.minimum(d_trail_obs, d_trail_robot), X, Y)
    d_g = raster.sample(raster.distance(masks["goal"]), X, Y)
    d_ng = raster.sample(raster.distance(masks["no_goal"]), X, Y)
    reach = params.reach if params.reach is not None else workcell.reach
    active = reach_activation(workcell, path, hm, reach) if reach and reach > 0 else np.ones(hm.shape, bool)
    raw = height_function(d_t, d_g, d_ng, active, params)
    vol = Volume(hm, raw.copy(), raw)
    vol.lower_under(pts, rad, params.column_clearance)
    lower_along_path(vol, workcell.scene_arrays(), path.waypoints, params.column_clearance)
    return VolumeBuild(vol, cats, d_t, d_g, d_ng, active)


#: Between waypoints the robot is posed at points this close in s that each
#: body moves at most about this far between (m): columns are lowered under
#: the whole motion, not only under the waypoints.
LOWERING_MOTION = 0.02


def lower_along_path(vol: Volume, arrays, waypoints: np.ndarray, clearance: float) -> None:
    """Lowers the columns under the robot all along the nominal, waypoints
    and the motion between them (each body grown by how far it can move
    between the samples), so that the nominal is free of V at every s, not
    only at waypoints. Updates the lowered/dropped counts."""
    from drake_cfvol import kernel as K

    W = np.asarray(waypoints, float)
    dq = np.abs(np.diff(W, axis=0))  # (g-1, k)
    rev = arrays.revolute
    motion = np.where(rev[None, :, None], dq[:, :, None] * arrays.reach[None],
                      dq[:, :, None] * arrays.moved_by[None]).sum(axis=1)  # (g-1, B)
    pieces = np.maximum(1, np.ceil(motion.max(axis=1) / (2 * LOWERING_MOTION))).astype(int)
    Q, E = [], []
    for i, n in enumerate(pieces):
        t = (np.arange(n) + 0.5) / n
        Q.append(W[i] + t[:, None] * (W[i + 1] - W[i]))
        E.append(np.repeat(motion[i][None] / (2 * n), n, axis=0))
    if not Q:
        return
    hm = vol.heightmap
    heights = np.ascontiguousarray(vol.heights, dtype=np.float64)
    a = arrays
    K.lower_columns_under(np.ascontiguousarray(np.concatenate(Q)), np.ascontiguousarray(np.concatenate(E)),
                          a.parent, a.jtype, a.qidx, a.axis, a.R_PF, a.p_PF, a.R_MB, a.p_MB, a.shapes,
                          a.shape_body, a.verts, heights, float(hm.origin[0]), float(hm.origin[1]),
                          float(hm.side), float(clearance))
    vol.heights = heights
    vol.changed()
    changed = vol.heights < vol.raw_heights
    vol.dropped = int(np.count_nonzero(changed & (vol.heights <= 0)))
    vol.lowered = int(np.count_nonzero(changed & (vol.heights > 0)))
