"""Object categorization (SPEC 4), the height-map volume V (SPEC 5) and its
columns as Drake geometry (:func:`register_volume_boxes`)."""

from __future__ import annotations

import dataclasses

import numpy as np
from pydrake.geometry import (
    AddContactMaterial,
    Box,
    GeometryInstance,
    MakePhongIllustrationProperties,
    ProximityProperties,
)
from pydrake.math import RigidTransform
from pydrake.multibody.plant import CoulombFriction

from drake_cfvol import kernel as K
from drake_cfvol.algorithm.heightmap import HeightMap, Volume, height_function
from drake_cfvol.algorithm.planning import NominalPath
from drake_cfvol.exceptions import ParameterError, WorkcellError
from drake_cfvol.scene.params import VolumeParams

__all__ = [
    "Categories",
    "VolumeBuild",
    "Footprints",
    "categorize",
    "build_volume",
    "footprint_masks",
    "volume_from_masks",
    "ground_obstacles",
    "VOLUME_BOX_PREFIX",
    "register_volume_boxes",
]

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
    """Sorts the obstacles into trail, goal and no-goal sets (SPEC 4) by the
    kernel's distances between the robot's and the obstacles' real shapes
    (to within 1e-7 m; shapes welded to the world, like the robot's base,
    take no part, as in Drake)."""
    a = workcell.scene_arrays()
    W = np.ascontiguousarray(path.waypoints, dtype=np.float64)

    def per_obstacle(Q, radius):
        d = K.obstacle_distances(np.ascontiguousarray(Q), float(radius), 1e-7, a.model).min(axis=0)
        out: dict[str, float] = {}
        for name, value in zip(a.obstacle_names, d):
            if value < radius:
                out[name] = min(out.get(name, np.inf), float(value))
        return out

    trail_d = per_obstacle(W, params.trail_radius)
    goal_d = per_obstacle(W[-1:], params.goal_radius)
    names = list(workcell.obstacles)
    trail = [n for n in names if trail_d.get(n, np.inf) < params.trail_radius]
    goal = [n for n in names if n not in trail and goal_d.get(n, np.inf) < params.goal_radius]
    no_goal = [n for n in names if n not in trail and n not in goal]
    return Categories(
        trail,
        goal,
        no_goal,
        {n: float(trail_d.get(n, np.inf)) for n in names},
        {n: float(goal_d.get(n, np.inf)) for n in names},
    )


def ground_obstacles(workcell) -> set[str]:
    """Obstacles whose top is at floor level (z <= 1 mm): their footprint is
    the whole map, so they take no part in the height function's distances
    (the volume stands on them anyway)."""
    a = workcell.scene_arrays()
    tops: dict[str, float] = {}
    for name, box in zip(a.obstacle_names, a.obstacle_aabb):
        tops[name] = max(tops.get(name, -np.inf), box[5])
    return {n for n, t in tops.items() if t <= GROUND_TOP}


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
            "{origin: [x, y], size: [x_dim, y_dim]} (m)."
        )
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


def build_volume(
    workcell, path: NominalPath, params: VolumeParams, *, categories: Categories | None = None
) -> VolumeBuild:
    """Grows the volume V around a nominal path (SPEC 4-5).

    Footprints (xy projections) are drawn on a raster of ``params.raster``
    pixels: the trail's is the robot's shapes at every waypoint and the
    trail obstacles; distances come from an exact distance transform and are
    read at the cell centres, so their cost does not grow with R. Columns
    under the robot anywhere along the nominal (coarse cells, SPEC 5) are
    lowered under it, or dropped; the counts are in ``volume.lowered`` /
    ``volume.dropped``.
    """
    cats = categories or categorize(workcell, path, params)
    fp = footprint_masks(workcell, path, params, cats)
    return volume_from_masks(workcell, path, params, cats, fp)


@dataclasses.dataclass
class Footprints:
    """The footprint rasters the height function's distances come from.

    Attributes:
        masks: ``{"trail", "goal", "no_goal"}`` -> (a, b) bool rasters.
        x0, y0: the raster's corner, m; pixel: its pixel side, m.
    """

    masks: dict
    x0: float
    y0: float
    pixel: float

    def indices(self, X: np.ndarray, Y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Raster indices (clipped) of world points (X, Y), m."""
        shape = self.masks["trail"].shape
        return (
            np.clip(np.floor((X - self.x0) / self.pixel).astype(int), 0, shape[0] - 1),
            np.clip(np.floor((Y - self.y0) / self.pixel).astype(int), 0, shape[1] - 1),
        )


def footprint_masks(workcell, path: NominalPath, params: VolumeParams, cats: Categories) -> Footprints:
    """The trail (the robot's shapes at every waypoint and the trail
    obstacles), goal and no-goal footprints on a raster of ``params.raster``
    pixels reaching past the height map by the largest distance the height
    function reads."""
    hm = height_map_of(workcell, params)
    a = workcell.scene_arrays()
    ground = ground_obstacles(workcell)
    pad = max(params.d_t_ub, params.d_g_ub, params.d_ng_ub)
    pixel = float(params.raster)
    x0, y0 = hm.origin[0] - pad, hm.origin[1] - pad
    shape = (int(np.ceil((hm.x_dim + 2 * pad) / pixel)), int(np.ceil((hm.y_dim + 2 * pad) / pixel)))
    masks = {c: np.zeros(shape, bool) for c in ("trail", "goal", "no_goal")}
    poly = np.empty((K.FOOTPRINT_DIRECTIONS, 2))
    for name, row in zip(a.obstacle_names, a.obstacles):
        if name in ground:
            continue
        K.shape_footprint(row, a.verts, poly)
        K.fill_convex_polygon(masks[cats.of(name)], poly, x0, y0, pixel)
    K.robot_footprint(np.ascontiguousarray(path.waypoints, dtype=np.float64), a.model, masks["trail"], x0, y0, pixel)
    return Footprints(masks, float(x0), float(y0), pixel)


def volume_from_masks(
    workcell, path: NominalPath, params: VolumeParams, cats: Categories, fp: Footprints
) -> VolumeBuild:
    """V from footprint rasters: exact distance transforms read at the cell
    centres, the height function, and the columns lowered under the
    nominal."""
    hm = height_map_of(workcell, params)
    X, Y = hm.centres()
    ix, iy = fp.indices(X, Y)
    d = {
        c: (K.distance_map(m)[ix, iy] * fp.pixel if m.any() else np.full(hm.shape, np.inf)) for c, m in fp.masks.items()
    }
    reach = params.reach if params.reach is not None else workcell.reach
    active = reach_activation(workcell, path, hm, reach) if reach and reach > 0 else np.ones(hm.shape, bool)
    raw = height_function(d["trail"], d["goal"], d["no_goal"], active, params)
    vol = Volume(hm, raw.copy(), raw)
    lower_along_path(vol, workcell.scene_arrays(), path.waypoints, params.column_clearance)
    return VolumeBuild(vol, cats, d["trail"], d["goal"], d["no_goal"], active)


#: Between waypoints the robot is posed at points this close in s that each
#: body moves at most about this far between (m): columns are lowered under
#: the whole motion, not only under the waypoints.
LOWERING_MOTION = 0.02


def column_caps(heightmap, arrays, waypoints: np.ndarray, clearance: float) -> np.ndarray:
    """(m, n) per column of ``heightmap``, the height it is lowered to
    under the robot all along the nominal, waypoints and the motion between
    them (each body grown by how far it can move between the samples), so
    that the nominal is free of V at every s, not only at waypoints; inf
    where the robot never passes over it. The caps depend on the path and
    the robot alone: :func:`lower_along_path` takes each column's height
    down to its cap."""
    caps = np.full(heightmap.shape, np.inf)
    W = np.asarray(waypoints, float)
    dq = np.abs(np.diff(W, axis=0))  # (g-1, k)
    if not len(dq):
        return caps
    rev = arrays.revolute
    motion = np.where(
        rev[None, :, None], dq[:, :, None] * arrays.reach[None], dq[:, :, None] * arrays.moved_by[None]
    ).sum(axis=1)  # (g-1, B)
    pieces = np.maximum(1, np.ceil(motion.max(axis=1) / (2 * LOWERING_MOTION))).astype(int)
    # Piece centres t = (m + 0.5) / n of every stretch, all at once.
    stretch = np.repeat(np.arange(len(pieces)), pieces)
    m = np.arange(len(stretch)) - np.repeat(np.cumsum(pieces) - pieces, pieces)
    t = (m + 0.5) / pieces[stretch]
    Q = W[stretch] + t[:, None] * (W[stretch + 1] - W[stretch])
    E = motion[stretch] / (2 * pieces[stretch])[:, None]
    K.lower_columns_under(
        np.ascontiguousarray(Q),
        np.ascontiguousarray(E),
        arrays.model,
        caps,
        (float(heightmap.origin[0]), float(heightmap.origin[1]), float(heightmap.side)),
        float(clearance),
    )
    return caps


def lower_along_path(vol: Volume, arrays, waypoints: np.ndarray, clearance: float, caps=None) -> None:
    """Lowers the columns under the robot all along the nominal to their
    :func:`column_caps` (``caps``: those already computed for the same
    path, robot, clearance and grid). Updates the lowered/dropped counts."""
    if caps is None:
        caps = column_caps(vol.heightmap, arrays, waypoints, clearance)
    vol.heights = np.minimum(np.asarray(vol.heights, dtype=np.float64), caps)
    vol.changed()
    changed = vol.heights < vol.raw_heights
    vol.dropped = int(np.count_nonzero(changed & (vol.heights <= 0)))
    vol.lowered = int(np.count_nonzero(changed & (vol.heights > 0)))


#: Names of the volume's geometries in SceneGraph.
VOLUME_BOX_PREFIX = "cfvol_volume_"


def register_volume_boxes(
    plant,
    volume: Volume,
    *,
    colour=(0.2, 0.75, 0.3, 0.35),
    visual: bool = True,
    boxes=None,
    scene_graph=None,
    proximity: bool = True,
) -> list:
    """Registers the volume's columns on the world body of a plant (before
    ``Finalize``): proximity geometry, and an illustration if ``visual``.
    A finalized plant's are registered on its SceneGraph instead, as
    anchored geometry of the plant's source (``scene_graph`` needed).

    Args:
        boxes: (centres, sizes) to register instead of one box per column
            (e.g. :meth:`Volume.merged_boxes`).
        scene_graph: the plant's SceneGraph (needed for a finalized plant).
        proximity: register proximity geometry (False: an illustration
            only, e.g. in a simulated plant, where the boxes must not push).

    Returns:
        The proximity ``GeometryId`` of each box.
    """
    centres, sizes = volume.boxes() if boxes is None else boxes[:2]
    if plant.is_finalized():
        return _register_anchored(plant, scene_graph, centres, sizes, colour, visual)
    world = plant.world_body()
    ids = []
    for i, (c, s) in enumerate(zip(centres, sizes)):
        X_WC = RigidTransform(c)
        if proximity:
            ids.append(
                plant.RegisterCollisionGeometry(
                    world, X_WC, Box(*s), f"{VOLUME_BOX_PREFIX}{i}", CoulombFriction(0.5, 0.5)
                )
            )
        if visual:
            plant.RegisterVisualGeometry(world, X_WC, Box(*s), f"{VOLUME_BOX_PREFIX}visual_{i}", np.asarray(colour))
    return ids


def _register_anchored(plant, scene_graph, centres, sizes, colour, visual) -> list:
    """The volume's boxes as anchored geometry of a finalized plant's source."""
    if scene_graph is None:
        raise ParameterError(
            "register_volume_boxes: the plant is finalized; pass its scene_graph to register the "
            "boxes as anchored geometry."
        )
    source, ids = plant.get_source_id(), []
    for i, (c, s) in enumerate(zip(centres, sizes)):
        gid = scene_graph.RegisterAnchoredGeometry(
            source, GeometryInstance(RigidTransform(c), Box(*s), f"{VOLUME_BOX_PREFIX}{i}")
        )
        props = ProximityProperties()
        AddContactMaterial(friction=CoulombFriction(0.5, 0.5), properties=props)
        scene_graph.AssignRole(source, gid, props)
        if visual:
            scene_graph.AssignRole(source, gid, MakePhongIllustrationProperties(np.asarray(colour)))
        ids.append(gid)
    return ids
