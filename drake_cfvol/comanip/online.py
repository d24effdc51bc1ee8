"""A co-manipulation run's moving obstacles, their perception and the bounds
re-estimated online (docs/spec.md, SPEC 12): the wiring, and the run's
figures (updates, compute time, latency)."""

from __future__ import annotations

import math
import typing

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.geometry import CollisionFilterDeclaration, GeometrySet, Role
from pydrake.systems.primitives import ZeroOrderHold

from drake_cfvol.algorithm.volume import VOLUME_BOX_PREFIX
from drake_cfvol.comanip.recording import animate_columns, animate_freedom
from drake_cfvol.online import MapGrid, ObstacleMap, OnlineBounds, PerceptionParams
from drake_cfvol.systems import AddCellCamera, MovingBoxes, OnlineBoundsEstimator, PerceivedColumns
from drake_cfvol.systems.perception import AddCellModel, make_renderable

__all__ = [
    "OnlineParts",
    "add_online",
    "perceived_overlap_depth",
    "perception_params",
    "online_figures",
    "map_grid",
    "show_online_freedom",
]


class OnlineParts(typing.NamedTuple):
    """What :func:`add_online` added."""

    mode: str  #: "camera" or "truth"
    grid: MapGrid
    boxes: MovingBoxes | None
    camera: object  # CellCamera or None
    columns: PerceivedColumns | None
    estimator: OnlineBoundsEstimator
    filter_ids: list  #: obstacle geometry the safety filter measures besides the cell's
    monitor_ids: list  #: obstacle geometry the monitor measures besides the cell's (the true boxes)
    map_port: object  #: the obstacle map's output port
    model_position_input: object  #: the cell model's robot position (camera), to connect; else None


def perception_params(scenario) -> PerceptionParams:
    """The map's settings: cells lend their height as far as an obstacle at
    ``perception.obstacle_speed`` moves until newer bounds are in force (an
    image's age, half a camera period to the bounds update, a bounds
    period, and the next image), plus one cell for pixel gaps; occupancy
    spreads into unseen cells as fast as that speed (at least a cell per
    image)."""
    o = scenario.perception
    lag = 2 * o.camera_period + 0.5 * o.camera_period + scenario.bounds.online.period
    return PerceptionParams(
        cell=o.cell, dilation=1 + int(math.ceil(o.obstacle_speed * lag / o.cell - 1e-9)), speed=o.obstacle_speed
    )


def perceived_overlap_depth(scenario) -> float:
    """How deep the perceived columns may overlap the robot while what the
    camera saw does not: the margin the map adds around it (its dilation,
    :func:`perception_params`), m. Deeper, the obstacle as seen overlaps
    the robot, and the safety filter faults (``overlap_depth``)."""
    params = perception_params(scenario)
    return params.dilation * params.cell


def map_grid(workcell, cell: float) -> MapGrid:
    """The obstacle map's grid: the height map's rectangle and everything
    the robot can reach (from its first revolute joint's axis, along the
    rail for a robot on a linear axis: ``reach`` bounds every body's
    distance from that axis point at any configuration), plus half a metre."""
    a = workcell.scene_arrays()
    lo = np.asarray(workcell.height_map_origin, float)
    hi = lo + np.asarray(workcell.height_map_size, float)
    rev = np.nonzero(a.revolute)[0]
    if len(rev):
        j = int(rev[0])
        body = int(a.joint_body[j])
        end_rows = []
        q0 = np.zeros(workcell.num_joints)
        rail = workcell.joint_names.index(workcell.rail_joint) if workcell.rail_joint is not None else None
        for v in (workcell.position_lower[rail], workcell.position_upper[rail]) if rail is not None else (0.0,):
            q = q0.copy()
            if rail is not None:
                q[rail] = v
            _, p_WB = a.fk(q[None])
            end_rows.append(p_WB[0, body, :2])
        ends = np.array(end_rows)
        r = float(a.reach[j].max()) + float(np.linalg.norm(a.p_MB[body]))  # from the body origin
        lo, hi = np.minimum(lo, ends.min(axis=0) - r), np.maximum(hi, ends.max(axis=0) + r)
    return MapGrid.covering(lo - 0.5, hi - lo + 1.0, cell)


def _filter_from_all_but_the_robot(scene_graph, plant, robot, ids: list) -> None:
    """Collision filters: the moving boxes and perceived columns meet only
    the robot (not each other, the floor, the cell or the volume), so
    SceneGraph's contact queries never pair them with anything else."""
    inspector = scene_graph.model_inspector()
    robot_ids = {g for b in plant.GetBodyIndices(robot) for g in plant.GetCollisionGeometriesForBody(plant.get_body(b))}
    others = [g for g in inspector.GetAllGeometryIds(Role.kProximity) if g not in robot_ids]
    scene_graph.collision_filter_manager().Apply(
        CollisionFilterDeclaration()
        .ExcludeBetween(GeometrySet(list(ids)), GeometrySet(others))
        .ExcludeWithin(GeometrySet(list(ids)))
    )


def _hide_volume_from_cameras(plant, scene_graph) -> None:
    """The volume V is virtual: no camera sees (or is blocked by) its boxes."""
    inspector = scene_graph.model_inspector()
    for gid in inspector.GetAllGeometryIds(Role.kPerception):
        if VOLUME_BOX_PREFIX in inspector.GetName(gid):
            scene_graph.RemoveRole(plant.get_source_id(), gid, Role.kPerception)


def add_online(builder, scenario, workcell, plant, scene_graph, robot, bounds) -> OnlineParts:
    """Adds the scenario's moving boxes, their perception (``camera``: the
    cell camera, its obstacle map and the perceived columns; ``truth``: the
    boxes' own map) and the online bounds estimator (its ``path_index``
    input left for the caller to connect)."""
    o = scenario.perception
    mode = scenario.perception_mode
    obstacles = scenario.cell.moving_obstacles
    grid = map_grid(workcell, o.cell)
    params = perception_params(scenario)
    boxes = None
    if obstacles:
        boxes = builder.AddNamedSystem(
            "moving_obstacles", MovingBoxes(scene_graph, obstacles, grid=grid, params=params)
        )
        builder.Connect(boxes.geometry_pose_output, scene_graph.get_source_pose_port(boxes.source_id))
    camera = model_input = None
    if mode == "camera":
        _hide_volume_from_cameras(plant, scene_graph)
        make_renderable(scene_graph, plant)
        model = AddCellModel(builder, workcell=workcell)
        camera = AddCellCamera(
            builder,
            scene_graph=scene_graph,
            model=model,
            grid=grid,
            params=params,
            width=o.width,
            height=o.height,
            period=o.camera_period,
        )
        model_input = model.position_input
        map_port = camera.mapper.obstacle_map_output
    else:
        if boxes is None:
            raise ValueError("perception truth needs moving_obstacles")
        # A perfect camera: the boxes' own map, sampled at the camera's rate.
        hold = builder.AddNamedSystem(
            "true_obstacle_map",
            ZeroOrderHold(period_sec=o.camera_period, abstract_model_value=AbstractValue.Make(ObstacleMap.empty(grid))),
        )
        builder.Connect(boxes.obstacle_map_output, hold.get_input_port())
        map_port = hold.get_output_port()
    # The filter measures the map's columns in both modes: its dilation covers
    # the obstacles' motion between maps (the damper knows no obstacle speed).
    columns = builder.AddNamedSystem(
        "perceived_columns", PerceivedColumns(scene_graph, grid, log_period=o.camera_period)
    )
    builder.Connect(map_port, columns.obstacle_map_input)
    builder.Connect(columns.geometry_pose_output, scene_graph.get_source_pose_port(columns.source_id))
    filter_ids = list(columns.geometry_ids)
    ob = scenario.bounds.online
    estimator = builder.AddNamedSystem(
        "online_bounds",
        OnlineBoundsEstimator(
            OnlineBounds(workcell, bounds, horizon=ob.horizon), grid, period=ob.period, offset=0.5 * o.camera_period
        ),
    )
    _filter_from_all_but_the_robot(scene_graph, plant, robot, filter_ids + (list(boxes.geometry_ids) if boxes else []))
    builder.Connect(map_port, estimator.obstacle_map_input)
    return OnlineParts(
        mode,
        grid,
        boxes,
        camera,
        columns,
        estimator,
        filter_ids,
        list(boxes.geometry_ids) if boxes is not None else [],
        map_port,
        model_input,
    )


def online_figures(parts: OnlineParts | None, context, scenario) -> dict:
    """The run's online figures: ``bounds_updates`` (re-estimations, i.e.
    updates whose map had changed), ``bounds_update_ms`` (their median
    compute time), ``bounds_update_ms_max``, ``bounds_latency_s`` (worst over
    the moving obstacles: from its first motion to the first bounds in
    force that were computed from an image taken after it; None if none
    moves), ``bounds_versions`` and ``freedom_end_ratio``: at the end of the
    run, where the robot is on its path, the live box's width over the
    known cell's (the first bounds), joint by joint, averaged (1.0: the
    freedom came back; stretches behind the robot are not searched again)."""
    if parts is None:
        return {}
    est = parts.estimator
    log = est.log(est.GetMyContextFromRoot(context))
    t, ms, stamp, _, version, changed = log.T if len(log) else (np.zeros(0),) * 6
    re = changed > 0
    out = {
        "perception": parts.mode,
        "bounds_updates": int(re.sum()),
        "bounds_update_ms": float(np.median(ms[re])) if re.any() else 0.0,
        "bounds_update_ms_max": float(ms[re].max()) if re.any() else 0.0,
        "bounds_versions": int(version.max()) if len(version) else 0,
        "bounds_latency_s": None,
    }
    late = []
    for ob in scenario.cell.moving_obstacles:
        t0 = ob.first_motion()
        if t0 is None:
            continue
        # Row n publishes what row n-1 computed: its map stamp is row n-1's.
        ok = [n for n in range(1, len(t)) if stamp[n - 1] > t0]
        late.append(float(t[ok[0]] - t0) if ok else math.inf)
    if late:
        out["bounds_latency_s"] = max(late)
    first = est.initial_bounds
    e_ctx = est.GetMyContextFromRoot(context)
    last = est.bounds_output.Eval(e_ctx)
    s_end = float(np.clip(est.path_index_input.Eval(e_ctx)[0], 0.0, first.g - 1.0))
    w0 = np.subtract(*first.at(s_end)[1::-1])
    w1 = np.subtract(*last.at(s_end)[1::-1])
    keep = w0 > 1e-9
    out["freedom_end_ratio"] = float(np.mean(w1[keep] / w0[keep])) if keep.any() else 1.0
    return out


def show_online_freedom(meshcat, cm, logs: dict, context) -> None:
    """The recording's freedom bars (:func:`~drake_cfvol.comanip.recording.animate_freedom`):
    per joint, the logged box's width over the known cell's at the logged
    path index, beside the robot's base; and the perceived columns
    (:func:`~drake_cfvol.comanip.recording.animate_columns`)."""
    first = cm.online.estimator.initial_bounds
    t, s = logs["path_index"][0], np.clip(logs["path_index"][1][:, 0], 0.0, first.g - 1.0)
    lo, hi = logs["lower"][1], logs["upper"][1]
    w0 = np.array([np.subtract(*first.at(v)[1::-1]) for v in s])
    ratios = np.where(w0 > 1e-9, (hi - lo) / np.maximum(w0, 1e-9), 1.0)
    _, p_WB = cm.workcell.scene_arrays().fk(cm.path.waypoints[:1])
    animate_freedom(meshcat, t, ratios, p_WB[0, 0] + [0.0, -1.5, 1.0])
    if cm.online.columns is not None:
        cols = cm.online.columns
        animate_columns(meshcat, cols.tiles_log(cols.GetMyContextFromRoot(context)), cols)
