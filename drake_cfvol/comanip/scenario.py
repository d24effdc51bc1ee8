"""Co-manipulation scenarios: the typed file schema (dataclasses loaded with
``yaml_load_typed``), field checks that name the file and field, and the
bundled scenarios' folder.
"""


import dataclasses
import re
import typing
from importlib import resources
from pathlib import Path
import yaml
from pydrake.common.yaml import yaml_load_typed
from pydrake.manipulation import IiwaDriver
from pydrake.multibody.parsing import ModelDirective
from pydrake.multibody.plant import MultibodyPlantConfig
from pydrake.systems.analysis import SimulatorConfig
from pydrake.visualization import VisualizationConfig

from drake_cfvol.comanip.online_config import OnlineConfig, check_online
from drake_cfvol.exceptions import ScenarioError
from drake_cfvol.scene.params import VolumeParams
from drake_cfvol.systems import MovingObstacle, Push
from drake_cfvol.scene.schema import CfvolSection, read_yaml
from drake_cfvol.scene.workcell import builtin_cells

__all__ = ['OnlineConfig', 'check_scenario_against_cell', 'scenario_file_path', 'InverseDynamicsDriver', 'AdmittanceGains', 'RandomPushes', 'Reactive', 'SafetyFilterConfig', 'Scenario', 'load_scenario', 'validate_scenario', 'diagrams_dir']


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
    ``diagram.SetRandomContext(context, RandomGenerator(random_seed))``
    with the scenario's one ``random_seed``.

    Attributes:
        count: expected number of pushes over the run.
        max_torque: N m (N), per joint.
        mean_duration: s, the length of one push (the source's sampling
            interval).
    """

    count: int = 0
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
class InverseDynamicsDriver:
    """A dynamic run's robot under Drake's ``InverseDynamicsController``
    (``model_drivers: {robot: !InverseDynamicsDriver {...}}``): per joint,
    the desired acceleration is kp (q_d - q) + kd (v_d - v) + ki (its
    integral), mapped through the robot's own inverse dynamics.

    Attributes:
        kp: 1/s^2; kd: 1/s; ki: 1/s^3.
    """

    kp: float = 10000.0
    kd: float = 200.0
    ki: float = 0.0


#: The drivers a scenario's ``model_drivers`` may name (YAML tags).
DriverConfig = typing.Union[InverseDynamicsDriver, IiwaDriver]


@dataclasses.dataclass
class Scenario:
    """A co-manipulation run.

    Attributes:
        cell: built-in cell name or workcell YAML path (relative paths are
            taken from the scenario file's folder). Ignored when the
            scenario holds ``directives`` itself.
        directives: Drake model directives of the cell, held by the
            scenario itself (as in Drake's hardware_sim), with ``cfvol``.
        cfvol: the cell's cfvol settings (robot, tool frame, ...; see
            :mod:`drake_cfvol.scene.schema`), with ``directives``.
        path: the cell's named start/goal pair.
        random_seed: the one seed of the run: the planner, the
            certificate's samples and the random pushes (Drake's random
            context).
        path_file, bounds_file: a saved nominal path or bounds table to use
            instead of planning or bounding (relative to the scenario's
            folder), checked against the cell.
        plant_config: Drake's ``MultibodyPlantConfig``: given, the run is
            dynamic (a time-stepping plant, the robot under its driver,
            the pushes real forces); null (default): kinematic (the plant
            posed from the command).
        model_drivers: the robot's driver in a dynamic run, by model
            instance name: ``!InverseDynamicsDriver`` (default) or Drake's
            ``!IiwaDriver``.
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
        moving_obstacles: boxes moving through the cell
            (:class:`~drake_cfvol.systems.MovingObstacle`: name, box sides,
            [t, x, y, z] waypoints of the centre); the collision and
            clearance figures count them.
        perception: how the bounds and the safety filter learn of moving
            obstacles: ``camera`` (default with moving obstacles: a depth
            camera over the cell, its obstacle map, the bounds re-estimated
            online, the filter measuring the perceived columns) or
            ``truth`` (the boxes' poses given directly); null without
            moving obstacles (fixed bounds).
        online: the perception and re-estimation settings.
        path_velocity_share: share of each joint's velocity limit that the
            path's own motion (nominal and bounds) may use; the push gets
            the rest. Path progress slows below ``path_duration`` when needed
            (:func:`drake_cfvol.systems.safe_path_rate`); in (0, 1).
    """

    cell: str = "automotive"
    directives: list[ModelDirective] = dataclasses.field(default_factory=list)
    cfvol: typing.Optional[CfvolSection] = None
    path: str = "path1"
    random_seed: int = 0
    path_file: typing.Optional[str] = None
    bounds_file: typing.Optional[str] = None
    plant_config: typing.Optional[MultibodyPlantConfig] = None
    model_drivers: dict[str, DriverConfig] = dataclasses.field(default_factory=dict)
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
    moving_obstacles: list[MovingObstacle] = dataclasses.field(default_factory=list)
    perception: typing.Optional[str] = None
    online: OnlineConfig = dataclasses.field(default_factory=OnlineConfig)
    path_velocity_share: float = 0.5
    simulator_config: SimulatorConfig = dataclasses.field(default_factory=SimulatorConfig)
    visualization: VisualizationConfig = dataclasses.field(default_factory=lambda: VisualizationConfig(
        publish_period=0.02, publish_proximity=False, publish_contacts=False, publish_inertia=False))

    @property
    def perception_mode(self) -> str | None:
        """``camera``, ``truth`` or None (fixed bounds): ``perception``, or
        ``camera`` where there are moving obstacles and it is not given."""
        if self.perception is not None:
            return self.perception
        return "camera" if self.moving_obstacles else None

    @property
    def duration(self) -> float:
        """Total simulated time at the requested path duration, s (a run
        whose path had to slow down lasts longer: ``Comanipulation.duration``)."""
        return self.start_time + self.path_duration + self.end_hold


def _type_name(t) -> str:
    return {int: "an integer", float: "a number", bool: "true or false", str: "a string"}.get(t, str(t))


#: Fields a scenario no longer has, and what took their place.
RENAMED = {"seed": "random_seed", "random_pushes.seed": "random_seed"}


def _is_number(value) -> bool:
    """A YAML number, or text Drake's reader takes as one (PyYAML reads
    ``1.0e6`` as text; Drake reads it as a float)."""
    if isinstance(value, bool):
        return False
    if isinstance(value, (int, float)):
        return True
    try:
        float(value)
        return isinstance(value, str)
    except ValueError:
        return False


def _check_scalar(value, t, name, file) -> None:
    ok = (isinstance(value, bool) if t is bool else
          isinstance(value, int) and not isinstance(value, bool) if t is int else
          _is_number(value) if t is float else
          isinstance(value, str))
    if not ok:
        raise ScenarioError(file, name, f"must be {_type_name(t)}, got {value!r}")


def _check_value(value, t, name: str, file: Path) -> None:
    """Checks one value against its type: dataclasses field by field, list
    items by their position (counted from 1), Drake's config structs by
    their field names, scalars by type."""
    origin = typing.get_origin(t)
    if origin is typing.Union:
        args = [a for a in typing.get_args(t) if a is not type(None)]
        if value is not None and len(args) == 1:
            _check_value(value, args[0], name, file)
        return  # None, or a tagged variant: Drake's reader checks it
    if dataclasses.is_dataclass(t):
        _check_fields(value, t, name, file)
    elif origin is list:
        if not isinstance(value, list):
            raise ScenarioError(file, name, f"must be a list, got {value!r}")
        (item,) = typing.get_args(t)
        for i, v in enumerate(value, 1):
            _check_value(v, item, f"{name} item {i}", file)
    elif origin is dict:
        if not isinstance(value, dict):
            raise ScenarioError(file, name, f"must be a mapping, got {value!r}")
        for key, v in value.items():
            _check_value(v, typing.get_args(t)[1], f"{name}.{key}", file)
    elif hasattr(t, "__fields__"):  # a Drake config struct (SimulatorConfig, ModelDirective, ...)
        known = [f.name for f in t.__fields__]
        if not isinstance(value, dict):
            raise ScenarioError(file, name, f"must be a mapping of {t.__name__} fields, got {value!r}")
        for sub in value:
            if sub not in known:
                raise ScenarioError(file, f"{name}.{sub}", f"is not a field of {t.__name__}; known fields: "
                                    f"{', '.join(known)}")
    elif t in (int, float, bool, str):
        _check_scalar(value, t, name, file)


def _check_fields(raw, schema, where: str, file: Path) -> None:
    """Checks a scenario mapping against its dataclass before Drake reads
    it: unknown or renamed keys and values of the wrong type are named with
    the file, the field (list items by position, counted from 1) and the fix."""
    if raw is None:
        return
    if not isinstance(raw, dict):
        raise ScenarioError(file, where or "the file", f"must be a mapping of fields, got {raw!r}")
    fields = {f.name: f for f in dataclasses.fields(schema)}
    hints = typing.get_type_hints(schema)
    for key, value in raw.items():
        name = (f"{where}{': ' if re.search(r'item [0-9]+$', where) else '.'}{key}" if where else str(key))
        if key not in fields:
            if name in RENAMED:
                raise ScenarioError(file, name, f"is now '{RENAMED[name]}' (one seed for the planner, the "
                                    "certificate and the random pushes, as in Drake's hardware_sim); rename it")
            raise ScenarioError(file, name, f"is not a field of {schema.__name__}; known fields: "
                                f"{', '.join(fields)}")
        _check_value(value, hints[key], name, file)


def _check_pushes(scenario: Scenario, where) -> None:
    """Each push's window and sizes (items counted from 1): a wrench of 6
    values, joint torques of one length across the pushes."""
    lengths = {}
    for i, p in enumerate(scenario.pushes, 1):
        name = f"pushes item {i}"
        if not p.start >= 0:
            raise ScenarioError(where, f"{name}: start", f"must be >= 0 s, got {p.start!r}")
        if not p.duration >= 0:
            raise ScenarioError(where, f"{name}: duration", f"must be >= 0 s, got {p.duration!r}")
        if len(p.wrench) not in (0, 6):
            raise ScenarioError(where, f"{name}: wrench", f"has {len(p.wrench)} values; give 6, [torque N m; force "
                                "N] at the tool in the world frame (or leave it out)")
        if len(p.joint_torque):
            lengths[i] = len(p.joint_torque)
    if len(set(lengths.values())) > 1:
        first, *rest = lengths.items()
        other = next((i, n) for i, n in rest if n != first[1])
        raise ScenarioError(where, f"pushes item {other[0]}: joint_torque", f"has {other[1]} values but pushes item "
                            f"{first[0]} has {first[1]}; give one torque per robot joint in every push")


def check_scenario_against_cell(scenario: Scenario, workcell, file: Path | None = None) -> None:
    """Checks the sizes that need the robot (k joints) right after the cell
    is loaded, before anything is planned: each push's joint torques, the
    reactive co-worker's offset.

    Raises:
        ScenarioError: naming the file, the item (counted from 1) and the field.
    """
    where = file if file is not None else "scenario"
    k, names = workcell.num_joints, ", ".join(workcell.joint_names)
    for i, p in enumerate(scenario.pushes, 1):
        if len(p.joint_torque) and len(p.joint_torque) != k:
            raise ScenarioError(where, f"pushes item {i}: joint_torque", f"has {len(p.joint_torque)} values; the "
                                f"robot of cell '{workcell.name}' has {k} joints ({names})")
    offset = scenario.reactive.offset
    if len(offset) and len(offset) != k:
        raise ScenarioError(where, "reactive.offset", f"has {len(offset)} values; the robot has {k} joints ({names})")


def scenario_file_path(name: str | None, base_dir: Path | None) -> Path | None:
    """A file named by a scenario (relative: from the scenario's folder)."""
    if name is None:
        return None
    p = Path(name).expanduser()
    return (base_dir / p).resolve() if base_dir is not None and not p.is_absolute() else p


def _check_sources(scenario: Scenario, where, base_dir) -> None:
    """The files a scenario names, a cell it holds, a dynamic run's settings."""
    for name in ("path_file", "bounds_file"):
        p = scenario_file_path(getattr(scenario, name), base_dir)
        if p is not None and not p.is_file():
            raise ScenarioError(where, name, f"names '{p}', which does not exist (a relative path starts from the "
                                "scenario file's folder)")
    if bool(scenario.directives) != (scenario.cfvol is not None):
        raise ScenarioError(where, "directives" if scenario.cfvol is not None else "cfvol",
                            "is missing: a scenario that holds its cell gives both 'directives' and 'cfvol' (the "
                            "keys of a workcell file)")
    pc = scenario.plant_config
    if pc is not None and not pc.time_step > 0:
        raise ScenarioError(where, "plant_config.time_step", f"must be > 0 s for a dynamic run, got {pc.time_step!r} "
                            "(leave plant_config out for a kinematic run)")
    if scenario.model_drivers and pc is None:
        raise ScenarioError(where, "model_drivers", "needs plant_config: drivers act in a dynamic run only")
    if any(isinstance(d, IiwaDriver) for d in scenario.model_drivers.values()):
        felt = [f"pushes item {i}: joint_torque" for i, p in enumerate(scenario.pushes, 1) if len(p.joint_torque)]
        felt += ["random_pushes.count"] * (scenario.random_pushes.count > 0) + ["reactive.gain"] * (
            scenario.reactive.gain > 0)
        if felt:
            raise ScenarioError(where, felt[0], "is a joint torque, which a torque-sensing arm (IiwaDriver) would "
                                "not feel through contact: give the co-worker's pushes as tool wrenches (the "
                                "hand's force) in this cell")


def validate_scenario(scenario: Scenario, file: Path | None = None, *, base_dir: Path | None = None) -> None:
    """Checks a scenario's values before any planning or bounding: positive
    durations and periods, a resolution whose volume fits in memory, known
    volume parameters, a cell that exists, push sizes, named files.

    Args:
        file: the scenario's file (named in errors; its folder is where
            relative paths start).
        base_dir: where relative paths start when there is no file.

    Raises:
        ScenarioError: naming the file, the field and the fix.
    """
    where = file if file is not None else "scenario"
    base_dir = file.parent if file is not None else base_dir
    _check_pushes(scenario, where)
    _check_sources(scenario, where, base_dir)
    pc = scenario.plant_config
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
        if getattr(vis, name) and pc is None:
            raise ScenarioError(where, f"visualization.{name}", "must be false: the run moves the robot "
                                "kinematically, so there are no contact forces or inertias to show")
    if not vis.publish_period > 0:
        raise ScenarioError(where, "visualization.publish_period", f"must be > 0 s, got {vis.publish_period!r}")
    check_online(scenario, where)
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
    if scenario.directives:
        return  # the scenario holds its cell
    if cell not in builtin_cells() and not _looks_like_path(cell):
        raise ScenarioError(where, "cell", f"is '{cell}', neither a built-in cell "
                            f"({', '.join(sorted(builtin_cells()))}) nor a workcell YAML path")
    if _looks_like_path(cell):
        p = _cell_path(cell, base_dir)
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


def load_scenario(name_or_path: str | Path, *, scenario_text: str | None = None,
                  overrides: dict | None = None) -> tuple[Scenario, Path | None]:
    """Loads a scenario by bundled name (``automotive_push``) or file path,
    and checks it (:func:`validate_scenario`) before anything is planned.

    As in Drake's ``hardware_sim``: the file is read over the defaults
    (``yaml_load_typed(defaults=Scenario())``), and ``scenario_text``, YAML
    text such as ``"{resolution: 2000, simulator_config: {target_realtime_rate:
    1.0}}"``, is read over the file's values; then ``overrides`` (field ->
    value, e.g. the CLI's ``--path-file``).

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
        raw = read_yaml(p.read_text())
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
            extra = read_yaml(scenario_text)
        except yaml.YAMLError as e:
            raise ScenarioError(where, None, f"cannot be read as YAML ({e})") from None
        _check_fields(extra, Scenario, "", where)
        try:
            scenario = yaml_load_typed(schema=Scenario, data=scenario_text, defaults=scenario)
        except Exception as e:
            raise ScenarioError(where, None, f"not a valid scenario override: {e}") from None
    if overrides:
        unknown = sorted(set(overrides) - {f.name for f in dataclasses.fields(Scenario)})
        if unknown:
            raise ScenarioError(p, unknown[0], "is not a field of Scenario")
        scenario = dataclasses.replace(scenario, **overrides)
    validate_scenario(scenario, p.resolve())
    return scenario, p.resolve()
