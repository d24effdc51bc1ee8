"""Co-manipulation runs: a scenario file -> a Drake diagram -> a recorded run.

A scenario (``diagrams/*.yaml``, loaded with ``yaml_load_typed``) names a
cell and path, the volume's resolution, the admittance gains and the human's
pushes. :func:`build_comanipulation_diagram` plans the path, estimates the
bounds and wires::

    PathProgress -> JointBoundsSource (ahead) -> AdmittanceDeformation <- ScriptedHuman
                              |                       | commanded_position
                              +-----------------> SafetyFilter <- query_object --+
                                                      | commanded_position        |
                              MultibodyPositionToGeometryPose -> SceneGraph ------+-> ClearanceMonitor

The robot follows the safety filter's ``commanded_position`` kinematically
(with ``collision_guard: false``, the admittance's, fed the bounds now). The diagram's own
SceneGraph holds the robot, the obstacles (coloured by category) and the
volume (its columns merged, conservatively, into at most 1500 boxes at any
R), all as proximity geometry; the clearance monitor asks it through its
query port, which the diagram also exports (``query_object``).
"""


import dataclasses
import json
import logging
import subprocess
import time
import typing
from importlib import resources
from pathlib import Path

import numpy as np
import yaml
from pydrake.common.yaml import yaml_load_typed
from pydrake.geometry import (
    IllustrationProperties,
    Meshcat,
    MeshcatParams,
    MeshcatVisualizer,
    MeshcatVisualizerParams,
    Rgba,
    Role,
    RoleAssign,
    SceneGraph,
)
from pydrake.math import RigidTransform
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import ModelInstanceIndex
from pydrake.common import RandomDistribution, RandomGenerator
from pydrake.systems.analysis import ApplySimulatorConfig, Simulator, SimulatorConfig
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import Adder, LogVectorOutput, RandomSource
from pydrake.visualization import VisualizationConfig
from pydrake.systems.rendering import MultibodyPositionToGeometryPose

from drake_cfvol.algorithm.certify import Certify
from drake_cfvol.exceptions import ScenarioError
from drake_cfvol.scene.params import VolumeParams
from drake_cfvol.algorithm.pipeline import estimate_bounds
from drake_cfvol.algorithm.planning import NominalPath, plan_nominal_path
from drake_cfvol.io.plotting import _pyplot
from drake_cfvol.io.progress import Progress
from drake_cfvol.algorithm.reference import register_volume_boxes
from drake_cfvol.io.style import CATEGORY_COLOURS, COLOUR_NAMES, FLOOR_COLOUR, ROBOT_COLOUR, VOLUME_COLOUR
from drake_cfvol.systems import (
    AdmittanceDeformation,
    ClearanceMonitor,
    JointBoundsSource,
    PathProgress,
    Push,
    RandomPushShaper,
    ReactiveCoworker,
    SafetyFilter,
    ScriptedHuman,
    safe_path_rate,
)
from drake_cfvol.comanip.recording import show_tool_path
from drake_cfvol.algorithm.volume import build_volume, height_map_of
from drake_cfvol.scene.workcell import builtin_cells, geometry_key, load_workcell, robot_geometry_ids

__all__ = ["AdmittanceGains", "RandomPushes", "Reactive", "SafetyFilterConfig", "Scenario", "load_scenario", "Comanipulation",
           "build_comanipulation_diagram", "run_scenario", "validate_scenario", "CATEGORY_COLOURS", "diagrams_dir"]

#: Signals also logged at the control update rate (``update_<name>``).
UPDATE_RATE_LOGS = ("commanded_position", "min_distance", "in_collision")

#: Columns registered as proximity geometry up to this count (SceneGraph's
#: cost grows quadratically with the number of proximity geometries).
MAX_PROXIMITY_BOXES = 1500


def diagrams_dir() -> Path:
    """The folder of the bundled scenarios."""
    return Path(str(resources.files("drake_cfvol.diagrams")))


@dataclasses.dataclass
class AdmittanceGains:
    """Admittance parameters, same for every joint.

    Attributes:
        mass: kg m^2 (kg for prismatic joints).
        damping: N m s/rad (N s/m).
        stiffness: N m/rad (N/m), towards the nominal.
        period: update period, s.
    """

    mass: float = 10.0
    damping: float = 200.0
    stiffness: float = 400.0
    period: float = 0.01


@dataclasses.dataclass
class RandomPushes:
    """Random joint-torque pushes (count 0: none), drawn by Drake's
    ``RandomSource`` and seeded through the context: the run calls
    ``diagram.SetRandomContext(context, RandomGenerator(seed))``.

    Attributes:
        count: expected number of pushes over the run.
        seed: the generator's seed (same seed, same pushes).
        max_torque: N m (N), per joint.
        mean_duration: s, the length of one push (the source's sampling
            interval).
    """

    count: int = 0
    seed: int = 0
    max_torque: float = 300.0
    mean_duration: float = 1.0


@dataclasses.dataclass
class Reactive:
    """A co-worker who reacts to the robot's position (gain 0: none): see
    :class:`drake_cfvol.systems.ReactiveCoworker`.

    Attributes:
        gain: N m/rad (N/m), per joint.
        offset: rad (m) per joint from the nominal: the pose the person wants
            (empty: zeros).
        start, duration: the window, s.
        max_torque: N m (N), per joint.
    """

    gain: float = 0.0
    offset: list[float] = dataclasses.field(default_factory=list)
    start: float = 0.0
    duration: float = 1e9
    max_torque: float = 400.0


@dataclasses.dataclass
class SafetyFilterConfig:
    """The runtime safety filter's settings (see
    :class:`drake_cfvol.systems.safety.SafetyFilter`).

    Attributes:
        clearance: the margin kept from the obstacles and between the
            robot's own links, m; None (the default): the bounds' own
            margin, ``bounds.params["clearance"]`` (0 if the table has none).
        influence_distance: pairs farther apart than this do not constrain
            the motion, m.
        damper_gain: the approach speed allowed at the influence distance,
            m/s; it falls to 0 at the margin.
    """

    clearance: typing.Optional[float] = None
    influence_distance: float = 0.15
    damper_gain: float = 1.0


@dataclasses.dataclass
class Scenario:
    """A co-manipulation run.

    Attributes:
        cell: built-in cell name or workcell YAML path (relative paths are
            taken from the scenario file's folder).
        path: the cell's named start/goal pair.
        seed: planner seed.
        resolution: the volume's R.
        path_duration: seconds to go from start to goal along the path.
        start_time: s before the robot starts moving.
        end_hold: s to hold at the goal after arriving.
        admittance: the gains.
        pushes: scripted pushes.
        random_pushes: seeded random pushes (added to ``pushes``).
        reactive: a co-worker reacting to the robot's position (added).
        log_period: logging and recording period, s.
        params: VolumeParams overrides.
        collision_guard: the runtime safety filter between the admittance
            and the robot (:class:`drake_cfvol.systems.safety.SafetyFilter`): the
            motion closest to the push's that keeps the velocity limits, the
            box and the clearance margin, through the diagram's SceneGraph;
            false: the admittance drives the robot directly.
        safety_filter: the filter's settings.
        simulator_config: Drake's simulator settings (``ApplySimulatorConfig``).
        visualization: Drake's visualization settings for the recording
            (illustration and proximity layers, publish period, colours;
            see :func:`meshcat_params`).
        certify: use certified bounds (``drake_cfvol.Certify()`` at its
            defaults; the default). The first build of a path takes tens of
            seconds more, later ones load the certificate from the cache
            (:func:`drake_cfvol.algorithm.certify.cache_dir`); the safety filter
            then rarely acts. False: the paper's per-joint bounds.
        path_velocity_share: share of each joint's velocity limit that the
            path's own motion (nominal and bounds) may use; the push gets
            the rest. Path progress slows below ``path_duration`` when needed
            (:func:`drake_cfvol.systems.safe_path_rate`); in (0, 1).
    """

    cell: str = "automotive"
    path: str = "path1"
    seed: int = 0
    resolution: int = 1000
    path_duration: float = 8.0
    start_time: float = 0.5
    end_hold: float = 1.0
    admittance: AdmittanceGains = dataclasses.field(default_factory=AdmittanceGains)
    pushes: list[Push] = dataclasses.field(default_factory=list)
    random_pushes: RandomPushes = dataclasses.field(default_factory=RandomPushes)
    reactive: Reactive = dataclasses.field(default_factory=Reactive)
    log_period: float = 0.02
    params: dict[str, float] = dataclasses.field(default_factory=dict)
    collision_guard: bool = True
    safety_filter: SafetyFilterConfig = dataclasses.field(default_factory=SafetyFilterConfig)
    certify: bool = True
    path_velocity_share: float = 0.5
    simulator_config: SimulatorConfig = dataclasses.field(default_factory=SimulatorConfig)
    visualization: VisualizationConfig = dataclasses.field(default_factory=lambda: VisualizationConfig(
        publish_period=0.02, publish_proximity=False, publish_contacts=False, publish_inertia=False))

    @property
    def duration(self) -> float:
        """Total simulated time at the requested path duration, s (a run
        whose path had to slow down lasts longer: ``Comanipulation.duration``)."""
        return self.start_time + self.path_duration + self.end_hold


def _type_name(t) -> str:
    return {int: "an integer", float: "a number", bool: "true or false", str: "a string"}.get(t, str(t))


def _check_fields(raw, schema, where: str, file: Path) -> None:
    """Checks a scenario mapping against its dataclass before Drake reads
    it: unknown keys and scalar fields of the wrong type are named with the
    file, the field and the fix."""
    if raw is None:
        return
    if not isinstance(raw, dict):
        raise ScenarioError(file, where or "the file", f"must be a mapping of fields, got {raw!r}")
    fields = {f.name: f for f in dataclasses.fields(schema)}
    hints = typing.get_type_hints(schema)
    for key, value in raw.items():
        name = f"{where}.{key}" if where else str(key)
        if key not in fields:
            raise ScenarioError(file, name, f"is not a field of {schema.__name__}; known fields: "
                                f"{', '.join(fields)}")
        t = hints[key]
        if dataclasses.is_dataclass(t):
            _check_fields(value, t, name, file)
        elif hasattr(t, "__fields__"):  # a Drake config struct (SimulatorConfig, ...)
            known = [f.name for f in t.__fields__]
            if not isinstance(value, dict):
                raise ScenarioError(file, name, f"must be a mapping of {t.__name__} fields, got {value!r}")
            for sub in value:
                if sub not in known:
                    raise ScenarioError(file, f"{name}.{sub}", f"is not a field of {t.__name__}; known fields: "
                                        f"{', '.join(known)}")
        elif t in (int, float, bool, str):
            ok = (isinstance(value, bool) if t is bool else
                  isinstance(value, int) and not isinstance(value, bool) if t is int else
                  isinstance(value, (int, float)) and not isinstance(value, bool) if t is float else
                  isinstance(value, str))
            if not ok:
                raise ScenarioError(file, name, f"must be {_type_name(t)}, got {value!r}")


def validate_scenario(scenario: Scenario, file: Path | None = None) -> None:
    """Checks a scenario's values before any planning or bounding: positive
    durations and periods, a resolution whose volume fits in memory, known
    volume parameters, a cell that exists.

    Raises:
        ScenarioError: naming the file, the field and the fix.
    """
    where = file if file is not None else "scenario"
    for name in ("path_duration", "log_period"):
        if not getattr(scenario, name) > 0:
            raise ScenarioError(where, name, f"must be > 0 s, got {getattr(scenario, name)!r}")
    for name in ("start_time", "end_hold"):
        if not getattr(scenario, name) >= 0:
            raise ScenarioError(where, name, f"must be >= 0 s, got {getattr(scenario, name)!r}")
    a = scenario.admittance
    for name in ("mass", "damping", "period"):
        if not getattr(a, name) > 0:
            raise ScenarioError(where, f"admittance.{name}", f"must be > 0, got {getattr(a, name)!r}")
    if not a.stiffness >= 0:
        raise ScenarioError(where, "admittance.stiffness", f"must be >= 0, got {a.stiffness!r}")
    f = scenario.safety_filter
    if f.clearance is not None and not f.clearance >= 0:
        raise ScenarioError(where, "safety_filter.clearance", f"must be >= 0 m (or null: the bounds' own), got "
                            f"{f.clearance!r}")
    if not f.influence_distance > (f.clearance or 0.0):
        raise ScenarioError(where, "safety_filter.influence_distance", f"must exceed the clearance, got "
                            f"{f.influence_distance!r}")
    if not f.damper_gain > 0:
        raise ScenarioError(where, "safety_filter.damper_gain", f"must be > 0 m/s, got {f.damper_gain!r}")
    if not 0.0 < scenario.path_velocity_share < 1.0:
        raise ScenarioError(where, "path_velocity_share", f"must lie in (0, 1), got {scenario.path_velocity_share!r}")
    vis = scenario.visualization
    for name in ("publish_contacts", "publish_inertia"):
        if getattr(vis, name):
            raise ScenarioError(where, f"visualization.{name}", "must be false: the run moves the robot "
                                "kinematically, so there are no contact forces or inertias to show")
    if not vis.publish_period > 0:
        raise ScenarioError(where, "visualization.publish_period", f"must be > 0 s, got {vis.publish_period!r}")
    if scenario.random_pushes.count < 0:
        raise ScenarioError(where, "random_pushes.count", f"must be >= 0, got {scenario.random_pushes.count}")
    known = {f.name for f in dataclasses.fields(VolumeParams)}
    unknown = sorted(set(scenario.params) - known)
    if unknown:
        raise ScenarioError(where, f"params.{unknown[0]}", f"is not a VolumeParams field; known: "
                            f"{', '.join(sorted(known))}")
    if not scenario.resolution > 0:
        raise ScenarioError(where, "resolution", f"must be a positive integer, got {scenario.resolution!r}")
    cell = scenario.cell
    if cell not in builtin_cells() and not _looks_like_path(cell):
        raise ScenarioError(where, "cell", f"is '{cell}', neither a built-in cell "
                            f"({', '.join(sorted(builtin_cells()))}) nor a workcell YAML path")
    if _looks_like_path(cell):
        p = _cell_path(cell, file.parent if file is not None else None)
        if not p.is_file():
            raise ScenarioError(where, "cell", f"names the workcell file '{p}', which does not exist (a relative "
                                "path starts from the scenario file's folder)")


def _looks_like_path(cell: str) -> bool:
    return cell not in builtin_cells() and (Path(cell).suffix.lower() in (".yaml", ".yml") or "/" in cell
                                            or "\\" in cell)


def _cell_path(cell: str, base_dir: Path | None) -> Path:
    p = Path(cell)
    if base_dir is not None and not p.is_absolute():
        p = (base_dir / p).resolve()
    return p


def load_scenario(name_or_path: str | Path, *, scenario_text: str | None = None) -> tuple[Scenario, Path | None]:
    """Loads a scenario by bundled name (``automotive_push``) or file path,
    and checks it (:func:`validate_scenario`) before anything is planned.

    As in Drake's ``hardware_sim``: the file is read over the defaults
    (``yaml_load_typed(defaults=Scenario())``), and ``scenario_text``, YAML
    text such as ``"{resolution: 2000, simulator_config: {target_realtime_rate:
    1.0}}"``, is read over the file's values.

    Returns:
        (scenario, its file)

    Raises:
        ScenarioError: an unknown name, a missing file, or a field that is
            unknown, of the wrong type or out of range (named in the message).
    """
    p = Path(name_or_path)
    if not p.is_file():
        cand = diagrams_dir() / f"{name_or_path}.yaml"
        if cand.is_file() and not _looks_like_path(str(name_or_path)):
            p = cand
        else:
            known = sorted(x.stem for x in diagrams_dir().glob("*.yaml"))
            what = "does not exist" if _looks_like_path(str(name_or_path)) else "is not a bundled scenario"
            raise ScenarioError(name_or_path, None, f"{what}. Bundled: {', '.join(known)}; or pass the path of a "
                                "scenario YAML file")
    try:
        raw = yaml.safe_load(p.read_text())
    except (OSError, yaml.YAMLError) as e:
        raise ScenarioError(p, None, f"cannot be read as YAML ({e})") from None
    _check_fields(raw, Scenario, "", p)
    try:
        scenario = yaml_load_typed(schema=Scenario, filename=str(p), defaults=Scenario())
    except Exception as e:
        raise ScenarioError(p, None, f"not a valid scenario: {e}") from None
    if scenario_text:
        where = Path("--scenario-text")
        try:
            extra = yaml.safe_load(scenario_text)
        except yaml.YAMLError as e:
            raise ScenarioError(where, None, f"cannot be read as YAML ({e})") from None
        _check_fields(extra, Scenario, "", where)
        try:
            scenario = yaml_load_typed(schema=Scenario, data=scenario_text, defaults=scenario)
        except Exception as e:
            raise ScenarioError(where, None, f"not a valid scenario override: {e}") from None
    validate_scenario(scenario, p.resolve())
    return scenario, p.resolve()


@dataclasses.dataclass
class Comanipulation:
    """A built co-manipulation diagram and what it was built from.

    Attributes:
        diagram: the Drake diagram (exported ports: ``path_index``, ``lower``,
            ``upper``, ``nominal``, ``commanded_position`` (the safety
            filter's, or with ``collision_guard`` false the admittance's),
            ``deviation``, ``fault``, ``fault_count``, ``human_torque``,
            ``human_wrench``, ``min_distance``, ``in_collision``,
            ``in_volume``, ``query_object``; with the filter also
            ``filter_active``, ``filter_count``, ``filter_fallbacks``).
        scenario, workcell, path, bounds: the inputs.
        plant, scene_graph: the visual/kinematic plant and its SceneGraph.
        loggers: VectorLogSinks by name, every exported vector port at the
            scenario's ``log_period``, and ``update_<name>`` for
            :data:`UPDATE_RATE_LOGS` at the admittance's period.
        progress: the PathProgress system (its ``rate`` may be below the
            scenario's: see ``Scenario.path_velocity_share``).
        meshcat: the Meshcat instance, if any.
        volume_boxes: the volume's boxes in the diagram's SceneGraph (columns
            merged, :meth:`~drake_cfvol.algorithm.heightmap.Volume.merged_boxes`):
            ``{"count": ..., "block": ..., "height_step_m": ...,
            "added_volume_m3": ..., "column_volume_m3": ...}``.
        build_ms: the build's steps' wall times, ms.
        filter_clearance: the safety filter's margin, m (None without it).
    """

    diagram: object
    scenario: Scenario
    workcell: object
    path: object
    bounds: object
    plant: object
    scene_graph: object
    loggers: dict
    progress: PathProgress
    meshcat: object = None
    volume_boxes: dict = dataclasses.field(default_factory=dict)
    build_ms: dict = dataclasses.field(default_factory=dict)
    filter_clearance: float | None = None

    @property
    def duration(self) -> float:
        """Simulated time of the run, s: start, the path at its (possibly
        slowed) progress, and the hold at the goal."""
        return self.progress.duration + self.scenario.end_hold


def frame_camera(meshcat, workcell, path) -> None:
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


def show_category_legend(meshcat, workcell, categories, *, prefix: str = "/legend") -> None:
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
            (config.publish_proximity, Role.kProximity, config.default_proximity_color, "proximity",
             config.initial_proximity_alpha)):
        if on:
            out.append(MeshcatVisualizerParams(
                role=role, publish_period=config.publish_period, default_color=colour, prefix=prefix,
                delete_on_initialization_event=config.delete_on_initialization_event,
                enable_alpha_slider=config.enable_alpha_sliders, initial_alpha_slider_value=alpha,
                visible_by_default=role == Role.kIllustration))
    return out


def _resolve_pushes(scenario: Scenario, workcell, path, progress) -> list[Push]:
    """The scenario's pushes, with each ``toward_nearest_obstacle`` push
    turned into a tool force towards the obstacle nearest the robot's moving
    links at the nominal when the push starts."""
    out = []
    for i, p in enumerate(scenario.pushes):
        if not p.toward_nearest_obstacle:
            out.append(p)
            continue
        q = path.at(progress.index_at(p.start))
        near = workcell.nearest_obstacle(q)
        if near is None:
            raise ScenarioError(Path("scenario"), f"pushes[{i}].toward_nearest_obstacle",
                                "has no obstacle within 5 m of the robot at that time")
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


def build_comanipulation_diagram(scenario: Scenario, *, meshcat=None, base_dir: Path | None = None,
                                 path=None, bounds=None, progress: bool = False) -> Comanipulation:
    """Builds a co-manipulation diagram from a scenario.

    Args:
        scenario: the scenario.
        meshcat: a ``Meshcat`` to visualise into (None: no visualiser).
        base_dir: folder that relative cell paths are taken from.
        path, bounds: a precomputed nominal path and bounds table (otherwise
            planned and estimated here).
        progress: progress bars on a terminal for long steps (the kernel's
            first compile).

    Returns:
        The :class:`Comanipulation`.
    """
    validate_scenario(scenario)
    t0 = time.perf_counter()
    cell = scenario.cell
    if _looks_like_path(cell):
        cell = str(_cell_path(cell, base_dir))
    wc = load_workcell(cell)
    wc.configuration(scenario.path)  # an unknown path name fails here, before planning
    height_map_of(wc, VolumeParams.for_workcell(wc, resolution=scenario.resolution, **dict(scenario.params)))
    if path is None:
        path = plan_nominal_path(wc, *wc.configuration(scenario.path), seed=scenario.seed, label=scenario.path,
                                 clearance=VolumeParams.for_workcell(wc, **dict(scenario.params)).clearance)
    t1 = time.perf_counter()
    if bounds is None:
        bounds = estimate_bounds(wc, path, resolution=scenario.resolution, progress=progress,
                                 certify=Certify(seed=scenario.seed) if scenario.certify else None,
                                 **dict(scenario.params))
    t2 = time.perf_counter()
    vb = bounds.volume
    if vb is None:  # a table loaded from disk: grow its volume again
        known = {f.name for f in dataclasses.fields(VolumeParams)}
        params = VolumeParams(**{k: v for k, v in bounds.params.items() if k in known})
        nominal = NominalPath(bounds.nominal, list(bounds.joint_names), wc.name, scenario.path, scenario.seed)
        vb = build_volume(wc, nominal, params)
        bounds = dataclasses.replace(bounds, volume=vb)
    k, g = wc.num_joints, path.g

    builder = DiagramBuilder()
    scene_graph = builder.AddNamedSystem("scene_graph", SceneGraph())
    plant = MultibodyPlant(0.0)
    plant.RegisterAsSourceForSceneGraph(scene_graph)
    robot = wc.add_to_plant(plant)
    # The volume in the diagram's own scene, as proximity geometry at any R:
    # columns merged (conservatively) into at most MAX_PROXIMITY_BOXES boxes.
    centres, sizes, merge_info = vb.volume.merged_boxes(MAX_PROXIMITY_BOXES)
    volume_ids = register_volume_boxes(plant, vb.volume, colour=VOLUME_COLOUR, boxes=(centres, sizes))
    plant.Finalize()
    assert plant.num_positions() == k and robot is not None
    _colour_obstacles(plant, scene_graph, wc, vb.categories)

    a = scenario.admittance
    share = scenario.path_velocity_share
    rate = min((g - 1) / scenario.path_duration, safe_path_rate(bounds, wc.velocity_limits, share=share))
    progress = builder.AddNamedSystem("path_progress", PathProgress(g, rate=rate, start_time=scenario.start_time,
                                                                    lead=scenario.admittance.period))
    source = builder.AddNamedSystem("joint_bounds", JointBoundsSource(bounds))
    adm = builder.AddNamedSystem("admittance", AdmittanceDeformation(
        k, mass=a.mass, damping=a.damping, stiffness=a.stiffness, period=a.period, plant=plant,
        tool_frame=plant.GetFrameByName(wc.tool_frame.name(), robot), velocity_limits=wc.velocity_limits,
        path_share=share))
    pushes = _resolve_pushes(scenario, wc, path, progress)
    rp = scenario.random_pushes
    human = builder.AddNamedSystem("human", ScriptedHuman(k, pushes))
    robot_ids, moving_ids = robot_geometry_ids(plant, robot)
    inspector = scene_graph.model_inspector()
    obstacle_ids = [g for i in map(ModelInstanceIndex, range(plant.num_model_instances())) if i != robot
                    for b in plant.GetBodyIndices(i) for g in plant.GetCollisionGeometriesForBody(plant.get_body(b))]
    not_obstacles = set(volume_ids) | set(robot_ids)
    obstacle_ids = sorted({g for g in obstacle_ids if g not in not_obstacles
                           and inspector.GetProximityProperties(g) is not None}, key=lambda g: g.get_value())
    # Pairs whose distance no joint motion changes (the workcell's own scene,
    # matched by name): a push cannot bring them closer.
    invariant = wc.invariant_pair_names()
    ignored = [(a, b) for a in moving_ids for b in obstacle_ids
               if (geometry_key(inspector, a), geometry_key(inspector, b)) in invariant]
    monitor = builder.AddNamedSystem("clearance_monitor", ClearanceMonitor(
        robot_ids=robot_ids, moving_ids=moving_ids, volume_ids=volume_ids, obstacle_ids=obstacle_ids,
        ignored_pairs=ignored))
    to_pose = builder.AddNamedSystem("to_pose", MultibodyPositionToGeometryPose(plant))

    builder.Connect(progress.path_index_output, source.path_index_input)
    safety = None
    if scenario.collision_guard:
        # The runtime safety filter between the admittance and the robot. A
        # command computed at an update takes effect until the next one, so
        # the admittance and the filter work on the bounds one period ahead
        # (the filter's output is its state: at the next update it is what
        # the robot holds, inside the box there).
        f = scenario.safety_filter
        margin = f.clearance if f.clearance is not None else float(bounds.params.get("clearance", 0.0))
        source_ahead = builder.AddNamedSystem("joint_bounds_ahead", JointBoundsSource(bounds, clamp=True))
        builder.Connect(progress.path_index_ahead_output, source_ahead.path_index_input)
        safety = builder.AddNamedSystem("safety_filter", SafetyFilter(
            plant, scene_graph, robot, velocity_limits=wc.velocity_limits, obstacle_ids=obstacle_ids,
            clearance=margin, influence_distance=f.influence_distance, damper_gain=f.damper_gain,
            period=a.period, initial_position=path.waypoints[0]))
        for name in ("nominal", "lower", "upper"):
            builder.Connect(source_ahead.GetOutputPort(name), adm.GetInputPort(name))
            builder.Connect(source_ahead.GetOutputPort(name), safety.GetInputPort(name))
        builder.Connect(adm.commanded_position_output, safety.desired_position_input)
        builder.Connect(scene_graph.get_query_output_port(), safety.query_object_input)
        commanded = safety.commanded_position_output
    else:
        for name in ("nominal", "lower", "upper"):
            builder.Connect(source.GetOutputPort(name), adm.GetInputPort(name))
        commanded = adm.commanded_position_output
    torques = [human.human_torque_output]
    if rp.count > 0:
        # Random pushes: Drake's RandomSource (its state is the randomness,
        # seeded with SetRandomContext) shaped into torques.
        noise = builder.AddNamedSystem("random_numbers", RandomSource(
            RandomDistribution.kUniform, k + 1, sampling_interval_sec=rp.mean_duration))
        shaper = builder.AddNamedSystem("random_pushes", RandomPushShaper(
            k, probability=min(1.0, rp.count * rp.mean_duration / (progress.duration + scenario.end_hold)),
            max_torque=rp.max_torque))
        builder.Connect(noise.get_output_port(), shaper.uniform_input)
        torques.append(shaper.human_torque_output)
    re = scenario.reactive
    if re.gain > 0:
        coworker = builder.AddNamedSystem("reactive_coworker", ReactiveCoworker(
            k, gain=re.gain, offset=re.offset or np.zeros(k), start=re.start, duration=re.duration,
            max_torque=re.max_torque))
        builder.Connect(commanded, coworker.commanded_position_input)
        builder.Connect(source.nominal_output, coworker.nominal_input)
        torques.append(coworker.human_torque_output)
    torque_port = torques[0]
    if len(torques) > 1:
        total = builder.AddNamedSystem("push_sum", Adder(len(torques), k))
        for i, port in enumerate(torques):
            builder.Connect(port, total.get_input_port(i))
        torque_port = total.get_output_port()
    builder.Connect(torque_port, adm.human_torque_input)
    builder.Connect(human.human_wrench_output, adm.human_wrench_input)
    builder.Connect(commanded, to_pose.get_input_port())
    builder.Connect(to_pose.get_output_port(), scene_graph.get_source_pose_port(plant.get_source_id()))
    builder.Connect(scene_graph.get_query_output_port(), monitor.query_object_input)

    exported = {
        "path_index": progress.path_index_output, "lower": source.lower_output, "upper": source.upper_output,
        "nominal": source.nominal_output, "commanded_position": commanded,
        "deviation": adm.deviation_output, "fault": adm.fault_output, "fault_count": adm.fault_count_output,
        "human_torque": torque_port, "human_wrench": human.human_wrench_output,
        "min_distance": monitor.min_distance_output, "in_collision": monitor.in_collision_output,
        "in_volume": monitor.in_volume_output,
    }
    if safety is not None:
        exported.update({"filter_active": safety.filter_active_output, "filter_count": safety.filter_count_output,
                         "filter_fallbacks": safety.fallback_count_output,
                         "filter_damper_misses": safety.damper_misses_output,
                         "filter_box_exits": safety.box_exits_output})
    loggers = {}
    for name, port in exported.items():
        builder.ExportOutput(port, name)
        loggers[name] = LogVectorOutput(port, builder, publish_period=scenario.log_period)
        loggers[name].set_name(f"log_{name}")
    if safety is not None:
        # What the admittance asked the filter for, beside what it commanded.
        exported["desired_position"] = adm.commanded_position_output
    # Speed, clearance and collisions at the control update rate too (the
    # log period may be coarser: a step between two updates must not hide).
    for name in UPDATE_RATE_LOGS + (("filter_count", "desired_position") if safety is not None else ()):
        loggers[f"update_{name}"] = LogVectorOutput(exported[name], builder, publish_period=a.period)
        loggers[f"update_{name}"].set_name(f"log_update_{name}")
    builder.ExportOutput(scene_graph.get_query_output_port(), "query_object")

    if meshcat is not None:
        for params in meshcat_params(scenario.visualization):
            MeshcatVisualizer.AddToBuilder(builder, scene_graph, meshcat, params)
        show_tool_path(meshcat, wc, path)
        show_category_legend(meshcat, wc, vb.categories)
        frame_camera(meshcat, wc, path)

    diagram = builder.Build()
    diagram.set_name("comanipulation")
    t3 = time.perf_counter()
    return Comanipulation(diagram, scenario, wc, path, bounds, plant, scene_graph, loggers, progress, meshcat,
                          {"count": len(volume_ids), **merge_info}, {"plan": (t1 - t0) * 1e3, "bounds": (t2 - t1) * 1e3,
                                         "diagram": (t3 - t2) * 1e3},
                          safety.clearance if safety is not None else None)


def _log(sim_context, logger):
    log = logger.FindLog(sim_context)
    return log.sample_times().copy(), log.data().T.copy()


def run_scenario(scenario_name_or_path, out_dir: str | Path, *, record: bool = True, plot: bool = True,
                 svg: bool = True, path=None, bounds=None, progress: bool = False,
                 scenario_text: str | None = None) -> dict:
    """Loads a scenario, builds its diagram, simulates it and writes the
    recording (self-contained HTML), plots and a summary.

    With ``progress``, a bar on a terminal counts simulated seconds.
    ``scenario_text`` overrides fields (see :func:`load_scenario`).

    Returns:
        The summary dict (also written as ``summary.json``).
    """
    scenario, file = load_scenario(scenario_name_or_path, scenario_text=scenario_text)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    meshcat = None
    if record:
        meshcat = Meshcat(MeshcatParams(host="localhost"))
    cm = build_comanipulation_diagram(scenario, meshcat=meshcat, base_dir=file.parent if file else None,
                                      path=path, bounds=bounds, progress=progress)
    sim = Simulator(cm.diagram)
    ApplySimulatorConfig(scenario.simulator_config, sim)
    ctx = sim.get_mutable_context()
    # The random pushes' numbers live in the context: seed them (Drake's way).
    cm.diagram.SetRandomContext(ctx, RandomGenerator(scenario.random_pushes.seed))
    if meshcat is not None:
        meshcat.StartRecording(frames_per_second=1.0 / scenario.visualization.publish_period,
                               set_visualizations_while_recording=False)
    t0 = time.perf_counter()
    duration = cm.duration
    with Progress(duration, "Simulating", enabled=progress, unit="simulated s") as bar:
        steps = 100
        for n in range(1, steps + 1):
            t_next = duration * n / steps
            sim.AdvanceTo(t_next)
            bar.update(duration / steps)
    sim_s = time.perf_counter() - t0
    logs = {name: _log(ctx, lg) for name, lg in cm.loggers.items()}
    t, q = logs["commanded_position"]
    _, lo = logs["lower"]
    _, hi = logs["upper"]
    _, nom = logs["nominal"]
    violation = float(np.max(np.maximum(np.maximum(lo - q, q - hi), 0.0))) if len(q) else 0.0
    rates = update_rate_figures(logs, cm)
    penetrations = int(logs["in_volume"][1].sum())
    files = {}
    if meshcat is not None:
        meshcat.StopRecording()
        meshcat.PublishRecording()
        html = out / "recording.html"
        html.write_text(meshcat.StaticHtml())
        files["recording_html"] = str(html)
    if plot:
        files["plot_png"] = str(plot_run(logs, cm, out / "run.png"))
    if svg:
        files.update(write_diagram_svg(cm.diagram, out / "diagram"))
    np.savez(out / "logs.npz", **{f"{k}_t": v[0] for k, v in logs.items()}, **{k: v[1] for k, v in logs.items()})
    summary = {
        "scenario": str(file) if file else str(scenario_name_or_path), "cell": cm.workcell.name,
        "path": scenario.path, "resolution": scenario.resolution, "g": cm.path.g, "steps": int(len(t)),
        "duration_s": duration, "path_duration_s": cm.progress.duration - scenario.start_time,
        "sim_wall_s": sim_s,
        "min_clearance_m": rates["min_clearance_m"],
        "max_velocity_ratio": rates["max_velocity_ratio"], "volume_penetrations": penetrations,
        "collisions": rates["collisions"], "max_bound_violation": violation,
        "filter_steps": _count(cm, ctx, "filter_count"), "guard_steps": _count(cm, ctx, "filter_count"),
        "filter_fallbacks": _count(cm, ctx, "filter_fallbacks"),
        "filter_damper_misses": _count(cm, ctx, "filter_damper_misses"),
        "filter_box_exits": _count(cm, ctx, "filter_box_exits"), "faults": _count(cm, ctx, "fault_count"),
        "collision_guard": scenario.collision_guard, "filter_clearance_m": cm.filter_clearance,
        "max_deviation": float(np.max(np.abs(q - nom))) if len(q) else 0.0,
        "n_boxes": cm.bounds.info["n_boxes"], "volume_boxes_in_scene": cm.volume_boxes["count"],
        "bounds_time_ms": cm.bounds.timing_ms["total"], "build_ms": cm.build_ms,
        "recording_html": files.get("recording_html"), "plot_png": files.get("plot_png"),
        "diagram_svg": files.get("diagram_svg"), "diagram_dot": files.get("diagram_dot"),
        "notices": [],
    }
    # The margin in force, and the nominal's own clearance (moving links
    # against the obstacles, Drake, at every waypoint): a run keeps the
    # margin if it never comes nearer than min(margin, the nominal's own).
    margin = cm.filter_clearance if scenario.collision_guard else float(cm.bounds.params.get("clearance", 0.0) or 0.0)
    nominal_own = min((min(d.values(), default=1.0) for d in
                       (cm.workcell.obstacle_distances(qn, 1.0, changeable_only=True) for qn in cm.path.waypoints)),
                      default=1.0)
    summary["clearance_m"] = margin
    summary["nominal_min_clearance_m"] = float(nominal_own)
    summary["problems"] = run_problems(summary)
    if svg and files.get("diagram_svg") is None:
        summary["notices"].append(missing_dot_notice(out / "diagram"))
    (out / "summary.json").write_text(json.dumps(summary, indent=1))
    return summary


#: A run may come this much nearer than min(margin, the nominal's own
#: clearance) before it counts as below the margin, m.
MARGIN_TOLERANCE = 0.002


def run_problems(summary: dict) -> list[str]:
    """What went wrong in a run, one sentence each (empty: nothing): it
    collided, came nearer than min(margin, the nominal's own clearance) -
    MARGIN_TOLERANCE, or moved a joint faster than its limit (measured at
    the control update rate)."""
    out = []
    if summary.get("collisions", 0) > 0:
        out.append(f"the robot collided at {summary['collisions']} update(s)")
    need = min(summary.get("clearance_m", 0.0), summary.get("nominal_min_clearance_m", 0.0))
    low = summary.get("min_clearance_m")
    if low is not None and low < need - MARGIN_TOLERANCE:
        out.append(f"the clearance fell to {low * 1e3:.1f} mm, below the margin of {need * 1e3:.1f} mm")
    if summary.get("max_velocity_ratio", 0.0) > 1.0 + 1e-9:
        out.append(f"a joint moved at {summary['max_velocity_ratio']:.2f} x its velocity limit")
    return out


def _count(cm: Comanipulation, context, name: str) -> int:
    """A counter exported by the diagram, at the end of the run (0 if the
    diagram has no such port: the filter is off)."""
    if not cm.diagram.HasOutputPort(name):
        return 0
    return int(cm.diagram.GetOutputPort(name).Eval(context)[0])


def update_rate_figures(logs: dict, cm: Comanipulation) -> dict:
    """Speed, clearance and collisions from the logs at the control update
    rate (``update_*``): the largest |dq_j| / (period x velocity_limit_j)
    between consecutive updates (one update period apart by construction,
    so the period is the time step, not the difference of two rounded
    sample times), the smallest clearance (moving links to the obstacles,
    m) and the number of updates in collision."""
    _, q = logs["update_commanded_position"]
    _, dist = logs["update_min_distance"]
    _, coll = logs["update_in_collision"]
    h = cm.scenario.admittance.period
    vmax = np.asarray(cm.workcell.velocity_limits, float)
    ratio = 0.0
    if len(q) > 1:
        speed = np.abs(np.diff(q, axis=0)) / h
        ratio = float(np.max(np.where(np.isfinite(vmax), speed / vmax, 0.0)))
    return {"max_velocity_ratio": ratio, "min_clearance_m": float(dist.min()) if len(dist) else None,
            "collisions": int(coll.sum())}


def plot_run(logs: dict, cm: Comanipulation, path: Path) -> Path:
    """Per joint over time: nominal, bounds, commanded; and the clearance.
    Shaded in every panel: when the co-worker pushes (joint torque or tool
    wrench not zero); ticks on the clearance panel: when the safety filter
    acted (at the logged samples)."""
    plt = _pyplot()
    t, q = logs["commanded_position"]
    pushing = np.zeros(len(t), bool)
    for name in ("human_torque", "human_wrench"):
        if name in logs and len(logs[name][1]) == len(t):
            pushing |= np.any(logs[name][1] != 0, axis=1)
    spans = _runs(t, pushing)
    _, lo = logs["lower"]
    _, hi = logs["upper"]
    _, nom = logs["nominal"]
    td, dist = logs["min_distance"]
    k = q.shape[1]
    rev = cm.workcell.revolute
    fig, axes = plt.subplots(k + 1, 1, figsize=(8, 1.6 * (k + 1)), sharex=True)
    for j in range(k):
        f = np.degrees if rev[j] else (lambda x: x)
        ax = axes[j]
        ax.fill_between(t, f(lo[:, j]), f(hi[:, j]), color="tab:green", alpha=0.25, label="bounds")
        ax.plot(t, f(nom[:, j]), "k--", lw=1, label="nominal")
        ax.plot(t, f(q[:, j]), color="tab:blue", lw=1.4, label="commanded")
        ax.set_ylabel(f"{cm.workcell.joint_names[j]}\n[{'deg' if rev[j] else 'm'}]", fontsize=8)
        ax.grid(alpha=0.3)
    for ax in axes:
        for n, (a, b) in enumerate(spans):
            ax.axvspan(a, b, color="tab:orange", alpha=0.15, lw=0, label="push" if n == 0 else None)
    axes[0].legend(loc="upper right", fontsize=7, ncol=4)
    axes[-1].plot(td, dist[:, 0], color="tab:red")
    if "filter_active" in logs:
        tg, g = logs["filter_active"]
        acted = tg[g[:, 0] > 0]
        if len(acted):
            axes[-1].plot(acted, np.full(len(acted), float(dist[:, 0].min())), "|", color="k", ms=8,
                          label="filter acted")
            axes[-1].legend(loc="upper right", fontsize=7)
    axes[-1].set_ylabel("clearance\n[m]", fontsize=8)
    axes[-1].set_xlabel("time [s]")
    axes[-1].grid(alpha=0.3)
    fig.suptitle(f"{cm.workcell.name} {cm.scenario.path}: co-manipulation run")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def _runs(t: np.ndarray, on: np.ndarray) -> list[tuple[float, float]]:
    """[start, end) times of the runs where ``on`` holds (logged samples)."""
    out, start = [], None
    for i, flag in enumerate(on):
        if flag and start is None:
            start = t[i]
        if not flag and start is not None:
            out.append((start, t[i]))
            start = None
    if start is not None:
        out.append((start, t[-1]))
    return out


def missing_dot_notice(stem: Path) -> str:
    """The one-line notice when Graphviz is missing: what was skipped, where
    the source is, how to get the SVG."""
    return (f"Graphviz 'dot' was not found, so {stem.with_suffix('.svg')} was not drawn (its source is in "
            f"{stem.with_suffix('.dot')}). Install Graphviz to get it (Debian/Ubuntu: sudo apt install graphviz).")


def write_diagram_svg(diagram, stem: Path) -> dict:
    """Writes the diagram's GraphViz source and, if ``dot`` is installed,
    an SVG. Returns the written files."""
    dot = diagram.GetGraphvizString(max_depth=1)
    files = {}
    dot_path = stem.with_suffix(".dot")
    dot_path.write_text(dot)
    files["diagram_dot"] = str(dot_path)
    try:
        svg = subprocess.run(["dot", "-Tsvg"], input=dot.encode(), capture_output=True, check=True, timeout=60)
        stem.with_suffix(".svg").write_bytes(svg.stdout)
        files["diagram_svg"] = str(stem.with_suffix(".svg"))
    except (OSError, subprocess.SubprocessError):
        pass
    return files
