"""The co-manipulation diagram built from a scenario: plant and SceneGraph with
the robot, the obstacles and the volume's proximity boxes; the control chain
(``AddCoManipulation``), the co-worker, monitors and loggers; Meshcat.
"""

import dataclasses
import logging
import time
import typing
from pathlib import Path

import numpy as np
from pydrake.common import RandomDistribution
from pydrake.geometry import (
    IllustrationProperties,
    Meshcat,
    MeshcatVisualizer,
    MeshcatVisualizerParams,
    Rgba,
    Role,
    RoleAssign,
    SceneGraph,
)
from pydrake.lcm import DrakeLcm
from pydrake.manipulation import IiwaDriver
from pydrake.math import RigidTransform
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import ModelInstanceIndex, RigidBody
from pydrake.systems.framework import Diagram, DiagramBuilder
from pydrake.systems.primitives import (
    Adder,
    LogVectorOutput,
    RandomSource,
    StateInterpolatorWithDiscreteDerivative,
    VectorLogSink,
)
from pydrake.systems.rendering import MultibodyPositionToGeometryPose
from pydrake.visualization import VisualizationConfig

from drake_cfvol.algorithm.pipeline import estimate_bounds
from drake_cfvol.algorithm.planning import NominalPath, plan_nominal_path
from drake_cfvol.algorithm.reuse import load_bounds_for, load_path_for
from drake_cfvol.algorithm.table import BoundsTable
from drake_cfvol.algorithm.volume import Categories, build_volume, height_map_of, register_volume_boxes
from drake_cfvol.comanip.dynamics import _control_plant, add_driver, add_simulated_plant, driver_of
from drake_cfvol.comanip.franka import FRANKA_PERIOD, add_franka_controller_interface, add_franka_station
from drake_cfvol.comanip.iiwa import (
    IIWA_STATUS_PERIOD,
    add_hand,
    add_iiwa_controller_interface,
    add_iiwa_station,
    add_iiwa_status_watchdog,
    grip_point,
    tool_radius,
)
from drake_cfvol.comanip.online import OnlineParts, add_online, perceived_overlap_depth
from drake_cfvol.comanip.recording import show_tool_path
from drake_cfvol.comanip.robot_status import add_measured
from drake_cfvol.comanip.scenario import (
    TORQUE_SENSING_DRIVERS,
    FrankaDriver,
    Scenario,
    check_scenario_against_cell,
    scenario_file_path,
    validate_scenario,
)
from drake_cfvol.comanip.scenario_checks import cell_file, looks_like_path
from drake_cfvol.exceptions import ScenarioError
from drake_cfvol.io.style import CATEGORY_COLOURS, COLOUR_NAMES, FLOOR_COLOUR, ROBOT_COLOUR, VOLUME_COLOUR
from drake_cfvol.scene.params import VolumeParams
from drake_cfvol.scene.workcell import Workcell, geometry_key, load_workcell, robot_geometry_ids
from drake_cfvol.systems import (
    AddCoManipulation,
    ClearanceMonitor,
    CoManipulationSystems,
    JointBoundsSource,
    PathProgress,
    Push,
    RandomPushShaper,
    ReactiveCoworker,
    ScriptedHuman,
)
from drake_cfvol.systems.hand import first_push_direction, waiting_point

__all__ = ["CoManipulation", "build_comanipulation_diagram"]


#: Signals also logged at the control update rate (``update_<name>``).
UPDATE_RATE_LOGS = ("commanded_position", "min_distance", "in_collision")


#: Columns registered as proximity geometry up to this count (SceneGraph's
#: cost grows quadratically with the number of proximity geometries).
MAX_PROXIMITY_BOXES = 1500


@dataclasses.dataclass
class CoManipulation:
    """A built co-manipulation diagram and what it was built from.

    Attributes:
        diagram: the Drake diagram (exported ports: ``path_index``, ``lower``,
            ``upper``, ``nominal``, ``commanded_position`` (the safety
            filter's, or without it the admittance's),
            ``deviation``, ``fault``, ``fault_count``, ``human_torque``,
            ``human_wrench``, ``min_distance``, ``in_collision``,
            ``in_volume``, ``query_object``; with the filter also
            ``filter_active``, ``filter_count``, ``filter_fallbacks``).
        scenario, workcell, path, bounds: the inputs.
        plant, scene_graph: the visual/kinematic plant and its SceneGraph.
        loggers: VectorLogSinks by name, every exported vector port at the
            scenario's ``log_period``, and ``update_<name>`` for
            :data:`UPDATE_RATE_LOGS` at the control period.
        progress: the PathProgress system (its ``rate`` may be below the
            scenario's: see ``control.path_progress.velocity_share``).
        meshcat: the Meshcat instance, if any.
        volume_boxes: the volume's boxes in the diagram's SceneGraph (columns
            merged, :meth:`~drake_cfvol.algorithm.heightmap.Volume.merged_boxes`):
            ``{"count": ..., "block": ..., "height_step_m": ...,
            "added_volume_m3": ..., "column_volume_m3": ...}``.
        build_ms: the build's steps' wall times, ms.
        filter_clearance: the safety filter's margin, m (None without it).
        online: the moving obstacles, their perception and the online
            bounds (:func:`drake_cfvol.comanip.online.add_online`), or None.
        control: what :func:`~drake_cfvol.systems.AddCoManipulation` added.
    """

    diagram: Diagram
    scenario: Scenario
    workcell: Workcell
    path: NominalPath
    bounds: BoundsTable
    plant: MultibodyPlant
    scene_graph: SceneGraph
    loggers: dict[str, VectorLogSink]
    progress: PathProgress
    meshcat: Meshcat | None = None
    volume_boxes: dict = dataclasses.field(default_factory=dict)
    build_ms: dict = dataclasses.field(default_factory=dict)
    filter_clearance: float | None = None
    online: OnlineParts | None = None
    control: CoManipulationSystems | None = None

    @property
    def duration(self) -> float:
        """Simulated time of the run, s: start, the path at its (possibly
        slowed) progress, and the hold at the goal."""
        return self.progress.duration + self.scenario.path.end_hold


def frame_camera(meshcat: Meshcat, workcell: Workcell, path: NominalPath) -> None:
    """Points Meshcat's camera at the robot and its path: at the centre of
    the box holding every link origin and the tool along the path, from a
    distance that fits the box in view (from the front-right, above)."""
    _, p_WB = workcell.scene_arrays().fk(path.waypoints)
    p_WT = np.array([workcell.tool_position(q) for q in path.waypoints])
    pts = np.concatenate([p_WB.reshape(-1, 3), p_WT])
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    centre = (lo + hi) / 2
    radius = max(0.5 * float(np.linalg.norm(hi - lo)), 0.5)
    direction = np.array([0.55, -0.9, 1.1])
    direction /= np.linalg.norm(direction)
    # A 75 degree vertical field of view holds a sphere of this radius at
    # radius / sin(37.5 deg) ~ 1.65 radius; a little margin on top.
    meshcat.SetCameraPose(centre + 1.9 * radius * direction, centre)


def show_category_legend(
    meshcat: Meshcat, workcell: Workcell, categories: Categories, *, prefix: str = "/legend"
) -> None:
    """Names the obstacle categories in Meshcat's scene tree (the controls
    panel of the live view and of a recording): ``legend/goal (blue)/
    pick_table`` and so on, each a small marker in its colour above the
    obstacle's box, and ``legend/robot (violet)``."""
    from pydrake.geometry import Sphere

    arrays = workcell.scene_arrays()
    for name in workcell.obstacles:
        boxes = [b for n, b in zip(arrays.obstacle_names, arrays.obstacle_aabb) if n == name]
        if not boxes:
            continue
        lo, hi = np.min([b[:3] for b in boxes], axis=0), np.max([b[3:] for b in boxes], axis=0)
        cat = categories.of(name)
        key = f"{prefix}/{cat.replace('_', '-')} ({COLOUR_NAMES[cat]})/{name}"
        meshcat.SetObject(key, Sphere(0.04), Rgba(*CATEGORY_COLOURS[cat]))
        meshcat.SetTransform(key, RigidTransform([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, hi[2] + 0.08]))
    meshcat.SetObject(f"{prefix}/robot (violet)", Sphere(0.001), Rgba(*ROBOT_COLOUR))


def meshcat_params(config: VisualizationConfig) -> list[MeshcatVisualizerParams]:
    """Meshcat visualizer settings from Drake's ``VisualizationConfig``, as
    Drake's ``ApplyVisualizationConfig`` makes them (illustration and
    proximity layers). No LCM publishers: the recording is Meshcat's own.
    Contacts and inertia need a simulated plant, which a kinematic run has
    not; the scenario check refuses them."""
    out = []
    for on, role, colour, prefix, alpha in (
        (config.publish_illustration, Role.kIllustration, config.default_illustration_color, "illustration", 1.0),
        (
            config.publish_proximity,
            Role.kProximity,
            config.default_proximity_color,
            "proximity",
            config.initial_proximity_alpha,
        ),
    ):
        if on:
            out.append(
                MeshcatVisualizerParams(
                    role=role,
                    publish_period=config.publish_period,
                    default_color=colour,
                    prefix=prefix,
                    delete_on_initialization_event=config.delete_on_initialization_event,
                    enable_alpha_slider=config.enable_alpha_sliders,
                    initial_alpha_slider_value=alpha,
                    visible_by_default=role == Role.kIllustration,
                )
            )
    return out


def _resolve_pushes(scenario: Scenario, workcell, path, progress) -> list[Push]:
    """The scenario's pushes, with each ``toward_nearest_obstacle`` push
    turned into a tool force towards the obstacle nearest the robot's moving
    links at the nominal when the push starts."""
    out = []
    for i, p in enumerate(scenario.human.pushes):
        if not p.toward_nearest_obstacle:
            out.append(p)
            continue
        q = path.at(progress.index_at(p.start))
        near = workcell.nearest_obstacle(q)
        if near is None:
            raise ScenarioError(
                Path("scenario"),
                f"human.pushes item {i + 1}: toward_nearest_obstacle",
                "has no obstacle within 5 m of the robot at that time",
            )
        _, _, p_WR, p_WO = near
        u = np.asarray(p_WO - p_WR, float)
        u = u / max(np.linalg.norm(u), 1e-12)
        w = np.zeros(6) if not len(p.wrench) else np.asarray(p.wrench, float).copy()
        w[3:] += p.toward_nearest_obstacle * u
        out.append(Push(p.start, p.duration, list(p.joint_torque), w.tolist()))
    return out


def _colour_obstacles(plant, scene_graph, workcell, categories) -> None:
    # Drake warns on every illustration update that it must precede the
    # visualizer's initialization: it does (no visualizer exists yet).
    drake_log = logging.getLogger("drake")
    level = drake_log.level
    drake_log.setLevel(logging.ERROR)
    try:
        _assign_colours(plant, scene_graph, workcell, categories)
    finally:
        drake_log.setLevel(level)


def _assign_colours(plant, scene_graph, workcell, categories):
    inspector = scene_graph.model_inspector()
    robot = plant.GetModelInstanceByName(workcell.robot_name)
    for b in plant.GetBodyIndices(robot):
        frame = plant.GetBodyFrameIdIfExists(b)
        if frame is None:
            continue
        for gid in inspector.GetGeometries(frame, Role.kIllustration):
            props = IllustrationProperties(inspector.GetIllustrationProperties(gid))
            props.UpdateProperty("phong", "diffuse", Rgba(*ROBOT_COLOUR))
            scene_graph.AssignRole(plant.get_source_id(), gid, props, RoleAssign.kReplace)
    for name, obs in workcell.obstacles.items():
        rgba = CATEGORY_COLOURS[categories.of(name)]
        if name in ("floor",):
            rgba = FLOOR_COLOUR
        body = plant.get_body(obs.body_index)
        frame = plant.GetBodyFrameIdIfExists(body.index())
        if frame is None:
            continue
        for gid in inspector.GetGeometries(frame, Role.kIllustration):
            props = IllustrationProperties(inspector.GetIllustrationProperties(gid))
            alpha = props.GetProperty("phong", "diffuse").a() if props.HasProperty("phong", "diffuse") else 1.0
            props.UpdateProperty("phong", "diffuse", Rgba(*rgba[:3], min(rgba[3], alpha)))
            scene_graph.AssignRole(plant.get_source_id(), gid, props, RoleAssign.kReplace)


def _scenario_workcell(scenario: Scenario, base_dir, file):
    """The scenario's cell: the one it holds (its own file), a built-in or a
    workcell file (relative to the scenario's folder)."""
    if scenario.directives:
        if file is None:
            raise ScenarioError(
                Path("scenario"),
                "directives",
                "a scenario that holds its cell must be a file (the cell is read from it): pass scenario_file=",
            )
        return Workcell(file, embedded=True)
    cell = scenario.cell.name
    if looks_like_path(cell):
        cell = str(cell_file(cell, base_dir))
    return load_workcell(cell)


def _workcell_path_bounds(scenario: Scenario, base_dir, file, path, bounds, progress: bool):
    """The scenario's workcell, nominal path and bounds (given, loaded from
    the scenario's ``path_file``/``bounds_file`` and checked against the
    cell, or planned and estimated; a table loaded from disk gets its
    volume grown again), and the times (ms) planning and bounding took."""
    t0 = time.perf_counter()
    if file is not None:
        file = Path(file).resolve()
        base_dir = base_dir or file.parent
    validate_scenario(scenario, file, base_dir=base_dir)
    wc = _scenario_workcell(scenario, base_dir, file)
    check_scenario_against_cell(scenario, wc, file)
    wc.require_collision_geometry("a co-manipulation run (its safety filter and clearance)")
    params = VolumeParams.for_workcell(wc, **scenario.bounds.overrides())
    height_map_of(wc, params)
    name = scenario.path.name
    if path is None and scenario.path.file is not None:
        path = load_path_for(wc, scenario_file_path(scenario.path.file, base_dir), label=name, notes=wc.notes)
    if bounds is None and scenario.bounds.file is not None:
        bounds = load_bounds_for(
            wc, scenario_file_path(scenario.bounds.file, base_dir), path, label=name, notes=wc.notes
        )
    if path is None and bounds is not None:
        path = NominalPath(bounds.nominal, list(bounds.joint_names), wc.name, name, scenario.random_seed)
    if path is None:
        wc.configuration(name)  # an unknown path name fails here, before planning
        path = plan_nominal_path(
            wc, *wc.configuration(name), seed=scenario.random_seed, label=name, clearance=params.clearance
        )
    t1 = time.perf_counter()
    if bounds is None:
        bounds = estimate_bounds(wc, path, progress=progress, certify=scenario.certify(), **scenario.bounds.overrides())
    if bounds.volume is None:  # a table loaded from disk: grow its volume again
        known = {f.name for f in dataclasses.fields(VolumeParams)}
        params = VolumeParams(**{k: v for k, v in bounds.params.items() if k in known})
        nominal = NominalPath(bounds.nominal, list(bounds.joint_names), wc.name, name, scenario.random_seed)
        bounds = dataclasses.replace(bounds, volume=build_volume(wc, nominal, params))
    t2 = time.perf_counter()
    return wc, path, bounds, {"plan": (t1 - t0) * 1e3, "bounds": (t2 - t1) * 1e3}


class Scene(typing.NamedTuple):
    """The plant side of a co-manipulation diagram."""

    plant: MultibodyPlant
    scene_graph: SceneGraph
    robot: ModelInstanceIndex
    volume_ids: list
    merge_info: dict
    models: list  # Drake's ModelInstanceInfo of the cell's models (a dynamic run's)
    hand: RigidBody | None  # the co-worker's hand body


def _add_scene(builder, wc, vb, scenario, q0) -> Scene:
    """Plant and SceneGraph with the workcell and the volume's proximity
    boxes (columns merged, conservatively, into at most
    MAX_PROXIMITY_BOXES), obstacles coloured by category. With the
    scenario's ``plant_config`` the plant is a time-stepping one (a dynamic
    run: the volume's boxes are drawn, not proximity geometry that would
    push the robot; the robot starts at ``q0``; a torque-sensing arm's run
    gets the co-worker's hand)."""
    models, hand = [], None
    plant_config = scenario.simulation.plant_config
    if plant_config is None:
        scene_graph = builder.AddNamedSystem("scene_graph", SceneGraph())
        plant = MultibodyPlant(0.0)
        plant.RegisterAsSourceForSceneGraph(scene_graph)
        robot = wc.add_to_plant(plant)
    else:
        plant, scene_graph, robot, models, hand = add_simulated_plant(
            builder, wc, plant_config, hand=isinstance(driver_of(scenario, wc), TORQUE_SENSING_DRIVERS)
        )
    centres, sizes, merge_info = vb.volume.merged_boxes(MAX_PROXIMITY_BOXES)
    volume_ids = register_volume_boxes(
        plant, vb.volume, colour=VOLUME_COLOUR, boxes=(centres, sizes), proximity=plant_config is None
    )
    plant.Finalize()
    if plant_config is not None:
        plant.SetDefaultPositions(robot, q0)
    if hand is not None:  # waiting beside the tool, on the first push's side
        p_WG = wc.tool_frame.body().EvalPoseInWorld(wc.plant_context(q0)).multiply(grip_point(wc))
        plant.SetDefaultFloatingBaseBodyPose(
            hand, RigidTransform(waiting_point(p_WG, first_push_direction(scenario.human.pushes), tool_radius(wc)))
        )
    _colour_obstacles(plant, scene_graph, wc, vb.categories)
    return Scene(plant, scene_graph, robot, volume_ids, merge_info, models, hand)


def _obstacles_and_ignored(wc, plant, scene_graph, robot, volume_ids, hand=None):
    """The real obstacles' proximity geometry (the volume's boxes and the
    robot left out), and the (moving link, obstacle) pairs whose distance no
    joint motion changes (the workcell's own, matched by name): a push
    cannot bring them closer. Returns (robot ids, moving ids, obstacle
    ids, ignored pairs)."""
    robot_ids, moving_ids = robot_geometry_ids(plant, robot)
    inspector = scene_graph.model_inspector()
    obstacle_ids = [
        g
        for i in map(ModelInstanceIndex, range(plant.num_model_instances()))
        if i != robot
        for b in plant.GetBodyIndices(i)
        for g in plant.GetCollisionGeometriesForBody(plant.get_body(b))
    ]
    not_obstacles = set(volume_ids) | set(robot_ids)
    if hand is not None:  # the co-worker's hand touches the tool on purpose
        not_obstacles |= set(plant.GetCollisionGeometriesForBody(hand))
    obstacle_ids = sorted(
        {g for g in obstacle_ids if g not in not_obstacles and inspector.GetProximityProperties(g) is not None},
        key=lambda g: g.get_value(),
    )
    invariant = wc.invariant_pair_names()
    ignored = [
        (a, b)
        for a in moving_ids
        for b in obstacle_ids
        if (geometry_key(inspector, a), geometry_key(inspector, b)) in invariant
    ]
    return robot_ids, moving_ids, obstacle_ids, ignored


def _add_pushes(builder, scenario, k, human, progress, commanded, source):
    """The human's joint torques: the scripted pushes, random pushes
    (Drake's RandomSource, its state the randomness, seeded with
    SetRandomContext, shaped into torques) and the reactive co-worker,
    summed. Returns the torque output port."""
    torques = [human.human_torque_output]
    rp = scenario.human.random_pushes
    if rp.count > 0:
        noise = builder.AddNamedSystem(
            "random_numbers", RandomSource(RandomDistribution.kUniform, k + 1, sampling_interval_sec=rp.mean_duration)
        )
        shaper = builder.AddNamedSystem(
            "random_pushes",
            RandomPushShaper(
                k,
                probability=min(1.0, rp.count * rp.mean_duration / (progress.duration + scenario.path.end_hold)),
                max_torque=rp.max_torque,
            ),
        )
        builder.Connect(noise.get_output_port(), shaper.uniform_input)
        torques.append(shaper.human_torque_output)
    re = scenario.human.reactive
    if re.gain > 0:
        coworker = builder.AddNamedSystem(
            "reactive_coworker",
            ReactiveCoworker(
                k,
                gain=re.gain,
                offset=re.offset or np.zeros(k),
                start=re.start,
                duration=re.duration,
                max_torque=re.max_torque,
            ),
        )
        builder.Connect(commanded, coworker.commanded_position_input)
        builder.Connect(source.nominal_output, coworker.nominal_input)
        torques.append(coworker.human_torque_output)
    if len(torques) == 1:
        return torques[0]
    total = builder.AddNamedSystem("push_sum", Adder(len(torques), k))
    for i, port in enumerate(torques):
        builder.Connect(port, total.get_input_port(i))
    return total.get_output_port()


def _add_meshcat(builder, scene_graph, meshcat, scenario, wc, path, categories) -> None:
    """Meshcat's visualizers (the scenario's layers), the tool path, the
    category legend and the camera."""
    for params in meshcat_params(scenario.simulation.visualization):
        MeshcatVisualizer.AddToBuilder(builder, scene_graph, meshcat, params)
    show_tool_path(meshcat, wc, path)
    show_category_legend(meshcat, wc, categories)
    frame_camera(meshcat, wc, path)


def _drive(builder, scenario, wc, scene, torque, human, control: CoManipulationSystems):
    """What moves the robot: a kinematic run poses the plant from the
    command; a dynamic run adds the driver, applies the push as real forces
    and feeds the measured position to the admittance and the safety filter.
    Returns (the measured position's port, the push as the robot senses it
    (a torque-sensing arm's external torque), each None where there is none)."""
    plant, robot = scene.plant, scene.robot
    commanded, safety, period = control.commanded_position_output, control.safety, scenario.control.period
    if scenario.simulation.plant_config is None:
        to_pose = builder.AddNamedSystem("to_pose", MultibodyPositionToGeometryPose(plant))
        builder.Connect(commanded, to_pose.get_input_port())
        builder.Connect(to_pose.get_output_port(), scene.scene_graph.get_source_pose_port(plant.get_source_id()))
        return None, None
    desired = control.desired_state_output
    driver, sensed = driver_of(scenario, wc), None
    if isinstance(driver, IiwaDriver):
        measured, sensed = _drive_iiwa(builder, scenario, wc, scene, driver, commanded, desired, human, safety)
    elif isinstance(driver, FrankaDriver):
        measured, sensed = _drive_franka(builder, scenario, wc, scene, driver, commanded, desired, human, safety)
    else:
        measured = add_driver(
            builder,
            scenario,
            wc,
            plant,
            robot,
            commanded=commanded,
            torque=torque,
            wrench=human.human_wrench_output,
            period=period,
            desired_state=desired,
        )
    builder.Connect(measured, control.admittance.measured_position_input)
    if safety is not None:
        builder.Connect(measured, safety.measured_position_input)
    return measured, sensed


def _drive_iiwa(builder, scenario, wc, scene, driver, commanded, desired, human, safety):
    """The iiwa under Drake's IiwaDriver over an in-memory LCM, the
    co-worker's hand pushing the tool, the safety filter (if any) held by a
    status watchdog. Returns (measured position, external torque) from the
    iiwa's status."""
    desired = _desired_state(builder, scenario, wc, commanded, desired)
    lcm = add_iiwa_station(builder, driver, wc.robot_name, scene.plant, scene.models)
    status = add_iiwa_controller_interface(builder, lcm, desired, wc.num_joints)
    if safety is not None:
        add_iiwa_status_watchdog(builder, lcm=lcm, safety=safety)
    _add_coworker_hand(builder, scenario, wc, scene, human)
    measured = add_measured(builder, status=status, commanded=commanded, k=wc.num_joints, period=IIWA_STATUS_PERIOD)
    return measured, status.get_torque_external_output_port()


def _drive_franka(builder, scenario, wc, scene, driver: FrankaDriver, commanded, desired, human, safety):
    """A Franka arm over drake-franka-driver's LCM (in memory): the
    simulated station (:func:`~drake_cfvol.comanip.franka.add_franka_station`)
    and the controller's side in the driver's mode, the status watchdog
    holding the safety filter (if any), the co-worker's hand pushing the
    tool. Returns (measured position, external torque) from the status."""
    desired = _desired_state(builder, scenario, wc, commanded, desired)
    lcm = DrakeLcm("memq://")
    add_franka_station(
        builder,
        plant=scene.plant,
        robot=scene.robot,
        controller_plant=_control_plant(wc, scene.plant.time_step()),
        lcm=lcm,
        control_mode=driver.control_mode,
        kp=driver.kp,
        kd=driver.kd,
    )
    interface = add_franka_controller_interface(
        builder,
        lcm=lcm,
        desired_state=desired,
        control_mode=driver.control_mode,
        num_joints=wc.num_joints,
        safety=safety,
    )
    _add_coworker_hand(builder, scenario, wc, scene, human)
    status = interface.status_receiver
    measured = add_measured(builder, status=status, commanded=commanded, k=wc.num_joints, period=FRANKA_PERIOD)
    return measured, status.get_torque_external_output_port()


def _desired_state(builder, scenario, wc, commanded, desired):
    """The desired state's port: the safety filter's, or without it the
    command with its discrete derivative."""
    if desired is not None:
        return desired
    interp = builder.AddNamedSystem(
        "desired_state",
        StateInterpolatorWithDiscreteDerivative(
            wc.num_joints, scenario.control.period, suppress_initial_transient=True
        ),
    )
    builder.Connect(commanded, interp.get_input_port())
    return interp.get_output_port()


def _add_coworker_hand(builder, scenario, wc, scene, human) -> None:
    """The co-worker's hand (the scene's body) pushing the tool with the
    scripted wrench, through contact."""
    add_hand(
        builder,
        scene.plant,
        scene.hand,
        scene.plant.GetFrameByName(wc.tool_frame.name(), scene.robot),
        human.human_wrench_output,
        tool_radius=tool_radius(wc),
        initial_direction=first_push_direction(scenario.human.pushes),
        p_BG=grip_point(wc),
    )


def _export_and_log(builder, exported: dict, scenario, safety, adm) -> dict:
    """Exports the named ports and logs them at the log period, and the
    update-rate signals (speed, clearance, collisions; the log period may
    be coarser: a step between two updates must not hide) at the control
    period. Returns the loggers by name."""
    if safety is not None:
        exported.update(
            {
                "filter_active": safety.filter_active_output,
                "filter_count": safety.filter_count_output,
                "filter_fallbacks": safety.fallback_count_output,
                "filter_damper_misses": safety.damper_misses_output,
                "filter_braking_faults": safety.braking_faults_output,
                "filter_guard_stops": safety.guard_stops_output,
                "filter_box_exits": safety.box_exits_output,
                "filter_holds": safety.hold_count_output,
                "tracking_faults": safety.tracking_faults_output,
                "filter_fault": safety.filter_fault_output,
            }
        )
    loggers = {}
    for name, port in exported.items():
        builder.ExportOutput(port, name)
        loggers[name] = LogVectorOutput(port, builder, publish_period=scenario.simulation.log_period)
        loggers[name].set_name(f"log_{name}")
    if safety is not None:
        # What the admittance asked the filter for, beside what it commanded.
        exported["desired_position"] = adm.commanded_position_output
    extra = (("filter_count", "desired_position") if safety is not None else ()) + (
        ("measured_position",) if "measured_position" in exported else ()
    )
    for name in UPDATE_RATE_LOGS + extra:
        loggers[f"update_{name}"] = LogVectorOutput(exported[name], builder, publish_period=scenario.control.period)
        loggers[f"update_{name}"].set_name(f"log_update_{name}")
    return loggers


def build_comanipulation_diagram(
    scenario: Scenario,
    *,
    meshcat: Meshcat | None = None,
    base_dir: Path | None = None,
    path: NominalPath | None = None,
    bounds: BoundsTable | None = None,
    progress: bool = False,
    scenario_file: Path | None = None,
) -> CoManipulation:
    """Builds a co-manipulation diagram from a scenario, composing its parts
    as Drake's ``hardware_sim`` composes its ``Apply*Config`` calls: the
    scene (plant, SceneGraph, the volume's boxes), the perception (moving
    obstacles, camera, online bounds), the control chain
    (:func:`~drake_cfvol.systems.AddCoManipulation` with ``scenario.control``:
    the same call as in a user's station), the co-worker, what moves the
    robot (its pose from the command, or a driver), the monitor, the loggers
    and Meshcat.

    Args:
        scenario: the scenario.
        meshcat: a ``Meshcat`` to visualise into (None: no visualiser).
        base_dir: folder that relative cell paths are taken from (default: the scenario file's).
        scenario_file: the scenario's file (errors name it; a scenario that
            holds its cell is read from it).
        path, bounds: a precomputed nominal path and bounds table (otherwise
            planned and estimated here).
        progress: progress bars on a terminal for long steps (the kernel's first compile).

    Returns:
        The :class:`CoManipulation`.
    """
    wc, path, bounds, times = _workcell_path_bounds(scenario, base_dir, scenario_file, path, bounds, progress)
    t2 = time.perf_counter()
    vb, k = bounds.volume, wc.num_joints
    builder = DiagramBuilder()
    scene = _add_scene(builder, wc, vb, scenario, path.waypoints[0])
    plant, scene_graph, robot, volume_ids = scene.plant, scene.scene_graph, scene.robot, scene.volume_ids
    robot_ids, moving_ids, obstacle_ids, ignored = _obstacles_and_ignored(
        wc, plant, scene_graph, robot, volume_ids, scene.hand
    )
    online = None
    if scenario.perception_mode is not None:
        online = add_online(builder, scenario, wc, plant, scene_graph, robot, bounds)
    control = AddCoManipulation(
        builder,
        plant=plant,
        scene_graph=scene_graph,
        robot=robot,
        table=bounds,
        tool_frame=plant.GetFrameByName(wc.tool_frame.name(), robot),
        period=scenario.control.period,
        measured_state=False,
        config=_control_config(scenario, wc, path),
        obstacle_ids=obstacle_ids,
        dynamic_ids=online.filter_ids if online is not None else (),
        name="",
        overlap_depth=perceived_overlap_depth(scenario) if online is not None else None,
    )
    progress, adm, safety = control.progress, control.admittance, control.safety
    commanded = control.commanded_position_output
    # The bounds at the path index now, for the logs and the reactive co-worker.
    source = builder.AddNamedSystem("joint_bounds_now", JointBoundsSource(bounds))
    builder.Connect(progress.path_index_output, source.path_index_input)
    if online is not None:
        builder.Connect(progress.path_index_output, online.estimator.path_index_input)
        builder.Connect(online.estimator.bounds_output, source.bounds_input)
        builder.Connect(online.estimator.bounds_output, control.bounds.bounds_input)
        if online.model_position_input is not None:
            builder.Connect(commanded, online.model_position_input)  # the camera's model of the cell
    human = builder.AddNamedSystem("human", ScriptedHuman(k, _resolve_pushes(scenario, wc, path, progress)))
    monitor = builder.AddNamedSystem(
        "clearance_monitor",
        ClearanceMonitor(
            robot_ids=robot_ids,
            moving_ids=moving_ids,
            volume_ids=volume_ids,
            obstacle_ids=obstacle_ids + (online.monitor_ids if online else []),
            ignored_pairs=ignored,
        ),
    )
    builder.Connect(scene_graph.get_query_output_port(), monitor.query_object_input)
    torque_port = _add_pushes(builder, scenario, k, human, progress, commanded, source)
    measured, sensed = _drive(builder, scenario, wc, scene, torque_port, human, control)
    builder.Connect(sensed or torque_port, control.human_torque_input)
    if sensed is None:
        builder.Connect(human.human_wrench_output, control.human_wrench_input)
    check = control.check
    loggers = _export_and_log(
        builder,
        {
            **({"measured_position": measured} if measured is not None else {}),
            "path_index": progress.path_index_output,
            "lower": source.lower_output,
            "upper": source.upper_output,
            "nominal": source.nominal_output,
            "commanded_position": commanded,
            "deviation": adm.deviation_output,
            "fault": check.fault_output,
            "fault_count": check.fault_count_output,
            "human_torque": sensed or torque_port,
            "human_wrench": human.human_wrench_output,
            "min_distance": monitor.min_distance_output,
            "in_collision": monitor.in_collision_output,
            "in_volume": monitor.in_volume_output,
            **_online_exports(online),
        },
        scenario,
        safety,
        adm,
    )
    builder.ExportOutput(scene_graph.get_query_output_port(), "query_object")
    if meshcat is not None:
        _add_meshcat(builder, scene_graph, meshcat, scenario, wc, path, vb.categories)
    diagram = builder.Build()
    diagram.set_name("comanipulation")
    times["diagram"] = (time.perf_counter() - t2) * 1e3
    return CoManipulation(
        diagram,
        scenario,
        wc,
        path,
        bounds,
        plant,
        scene_graph,
        loggers,
        progress,
        meshcat,
        {"count": len(volume_ids), **scene.merge_info},
        times,
        safety.clearance if safety is not None else None,
        online,
        control,
    )


def _control_config(scenario: Scenario, wc, path):
    """The scenario's control section for AddCoManipulation: the cell's
    velocity, acceleration and jerk limits unless given, and the path no faster than its
    ``path.duration``."""
    c = scenario.control
    pp = c.path_progress
    rate = (path.g - 1) / scenario.path.duration
    return dataclasses.replace(
        c,
        velocity_limits=list(c.velocity_limits) or list(wc.velocity_limits),
        acceleration_limits=list(c.acceleration_limits) or list(wc.acceleration_limits),
        jerk_limits=list(c.jerk_limits) or list(wc.jerk_limits),
        path_progress=dataclasses.replace(pp, max_rate=rate if pp.max_rate is None else min(pp.max_rate, rate)),
    )


def _online_exports(online) -> dict:
    """The online parts' ports exported and logged."""
    if online is None:
        return {}
    out = {"bounds_version": online.estimator.bounds_version_output}
    if online.camera is not None:
        out["occupied_cells"] = online.camera.mapper.occupied_cells_output
    out["column_overflow"] = online.columns.overflow_output
    return out
