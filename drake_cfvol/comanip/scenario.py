"""Co-manipulation scenarios: the typed file schema (dataclasses loaded with
``yaml_load_typed``), field checks that name the file and field, and the
bundled scenarios' folder.
"""


import dataclasses
import typing
from importlib import resources
from pathlib import Path
import yaml
from pydrake.common.yaml import yaml_load_typed
from pydrake.systems.analysis import SimulatorConfig
from pydrake.visualization import VisualizationConfig

from drake_cfvol.exceptions import ScenarioError
from drake_cfvol.scene.params import VolumeParams
from drake_cfvol.systems import Push
from drake_cfvol.scene.workcell import builtin_cells

__all__ = ['AdmittanceGains', 'RandomPushes', 'Reactive', 'SafetyFilterConfig', 'Scenario', 'load_scenario', 'validate_scenario', 'diagrams_dir']


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
