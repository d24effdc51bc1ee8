"""Co-manipulation scenarios: the typed file schema in sections (dataclasses,
the systems' own configs among them, read by the package's typed YAML
loader, :mod:`drake_cfvol.io.typed_yaml`, whose errors name the file, the
field and its line), and the bundled scenarios' folder.
"""

import dataclasses
import inspect
import re
import typing
from collections.abc import Callable
from importlib import resources
from pathlib import Path

from pydrake.multibody.parsing import ModelDirective
from pydrake.multibody.plant import MultibodyPlantConfig
from pydrake.systems.analysis import SimulatorConfig
from pydrake.visualization import VisualizationConfig

from drake_cfvol.algorithm.certificate.certify import Certify
from drake_cfvol.comanip.drivers import TORQUE_SENSING_DRIVERS, DriverConfig, FrankaDriver, InverseDynamicsDriver
from drake_cfvol.comanip.scenario_checks import (
    check_scenario_against_cell,
    looks_like_path,
    scenario_file_path,
    validate_scenario,
)
from drake_cfvol.exceptions import ScenarioError
from drake_cfvol.io.typed_yaml import ErrorFactory, load_typed
from drake_cfvol.scene.params import VolumeParams
from drake_cfvol.scene.schema import CfvolSection
from drake_cfvol.systems import (
    CoManipulationConfig,
    MovingObstacle,
    OnlineBoundsConfig,
    PathProgressConfig,
    PerceptionConfig,
    Push,
    RandomPushes,
    Reactive,
)

__all__ = [
    "check_scenario_against_cell",
    "scenario_file_path",
    "InverseDynamicsDriver",
    "FrankaDriver",
    "TORQUE_SENSING_DRIVERS",
    "RandomPushes",
    "Reactive",
    "CellConfig",
    "PathConfig",
    "BoundsConfig",
    "VolumeParamsConfig",
    "CertifyConfig",
    "HumanConfig",
    "ControlConfig",
    "PerceptionSection",
    "SimulationConfig",
    "Scenario",
    "load_scenario",
    "validate_scenario",
    "diagrams_dir",
    "OLD_FIELDS",
]


def diagrams_dir() -> Path:
    """The folder of the bundled scenarios."""
    return Path(str(resources.files("drake_cfvol.diagrams")))


def _loadable(cls, name: str, doc: str, *, optional: bool = False, exclude=()):
    """A plain dataclass with the fields of the frozen dataclass ``cls``
    (Drake's YAML reader sets fields one at a time, which a frozen
    dataclass refuses), read from ``cls`` itself so that its fields and
    defaults stay written once. ``optional``: every field may be null (the
    default), meaning "not given"."""
    hints = typing.get_type_hints(cls)
    fields: list[tuple[str, typing.Any, typing.Any]] = []
    for f in dataclasses.fields(cls):
        if f.name in exclude:
            continue
        t = hints[f.name]
        if optional:
            fields.append((f.name, typing.Optional[t], dataclasses.field(default=None)))
        else:
            fields.append((f.name, t, dataclasses.field(default=f.default)))
    out = dataclasses.make_dataclass(name, fields)
    out.__module__, out.__doc__ = __name__, doc + _attributes_of(cls, exclude)
    return out


def _attributes_of(cls: type, exclude: typing.Iterable[str] = ()) -> str:
    """The ``Attributes:`` section of ``cls``'s docstring without the
    entries of the fields in ``exclude`` ("" if it has none): a
    :func:`_loadable` class's fields keep their descriptions, for help()
    and the configuration reference."""
    _, found, rest = inspect.cleandoc(cls.__doc__ or "").partition("\nAttributes:\n")
    kept: list[str] = []
    keep = True
    for line in rest.splitlines():
        if line.strip() and not line.startswith(" "):
            break  # the section's end: the next unindented paragraph
        entry = re.match(r"    (\w+(?:, \w+)*):", line)
        if entry:
            keep = not set(entry.group(1).split(", ")) <= set(exclude)
        if keep:
            kept.append(line)
    return "\n\nAttributes:\n" + "\n".join(kept).rstrip() if found else ""


if typing.TYPE_CHECKING:  # classes made at import: the type checker takes them as Any
    VolumeParamsConfig = typing.Any
    CertifyConfig = typing.Any
else:
    #: The volume's parameters a scenario sets (``bounds.params``): the fields of
    #: :class:`~drake_cfvol.VolumeParams` but ``resolution`` (``bounds.resolution``),
    #: each null (not given: the cell's ``cfvol.params``, else the default).
    VolumeParamsConfig = _loadable(
        VolumeParams,
        "VolumeParamsConfig",
        "The fields of VolumeParams a scenario overrides (null: not given).",
        optional=True,
        exclude=("resolution",),
    )
    #: The certificate's settings (``bounds.certify``): the fields of
    #: :class:`~drake_cfvol.Certify` but ``seed`` (the scenario's ``random_seed``).
    CertifyConfig = _loadable(
        Certify, "CertifyConfig", "The fields of Certify but seed (the scenario's random_seed).", exclude=("seed",)
    )


@dataclasses.dataclass
class CellConfig:
    """The cell.

    Attributes:
        name: a built-in cell or a workcell YAML path (relative paths are
            taken from the scenario file's folder). Ignored when the
            scenario holds ``directives`` and ``cfvol`` itself.
        moving_obstacles: boxes moving through the cell
            (:class:`~drake_cfvol.systems.MovingObstacle`: name, box sides,
            [t, x, y, z] waypoints of the centre); the collision and
            clearance figures count them.
    """

    name: str = "automotive"
    moving_obstacles: list[MovingObstacle] = dataclasses.field(default_factory=list)


@dataclasses.dataclass
class PathConfig:
    """The nominal path and its timing.

    Attributes:
        name: the cell's named start/goal pair.
        file: a saved nominal path to use instead of planning (relative to
            the scenario's folder), checked against the cell.
        duration: seconds to go from start to goal; the path slows below it
            when the velocity limits need (``control.path_progress``).
        end_hold: s to hold at the goal after arriving.
    """

    name: str = "path1"
    file: typing.Optional[str] = None
    duration: float = 8.0
    end_hold: float = 1.0


@dataclasses.dataclass
class BoundsConfig:
    """The bounds.

    Attributes:
        resolution: the volume's R.
        params: :class:`~drake_cfvol.VolumeParams` fields (null: the cell's).
        certify: the certificate's settings (:class:`~drake_cfvol.Certify`;
            the default: certified bounds at Certify's defaults, the first
            build of a path tens of seconds more, later ones from the cache);
            null: the paper's per-joint bounds.
        file: a saved bounds table to use instead of bounding (relative to
            the scenario's folder), checked against the cell.
        online: the online re-estimation (with moving obstacles).
    """

    resolution: int = 1000
    params: VolumeParamsConfig = dataclasses.field(default_factory=VolumeParamsConfig)
    certify: typing.Optional[CertifyConfig] = dataclasses.field(default_factory=CertifyConfig)
    file: typing.Optional[str] = None
    online: OnlineBoundsConfig = dataclasses.field(default_factory=OnlineBoundsConfig)

    def overrides(self) -> dict:
        """The :class:`~drake_cfvol.VolumeParams` fields given, resolution
        included (for ``VolumeParams.for_workcell`` and ``estimate_bounds``)."""
        given = {k: v for k, v in dataclasses.asdict(self.params).items() if v is not None}
        return {"resolution": self.resolution, **given}


@dataclasses.dataclass
class HumanConfig:
    """The co-worker.

    Attributes:
        pushes: scripted pushes.
        random_pushes: seeded random pushes (added to ``pushes``).
        reactive: a co-worker reacting to the robot's position (added).
    """

    pushes: list[Push] = dataclasses.field(default_factory=list)
    random_pushes: RandomPushes = dataclasses.field(default_factory=RandomPushes)
    reactive: Reactive = dataclasses.field(default_factory=Reactive)


@dataclasses.dataclass
class ControlConfig(CoManipulationConfig):
    """The control chain: :class:`~drake_cfvol.systems.CoManipulationConfig`
    (its fields described there: the admittance, the safety filter, the
    path's progress and the joints' limits) and its update period.

    Attributes:
        period: the control period, s.
    """

    path_progress: PathProgressConfig = dataclasses.field(default_factory=lambda: PathProgressConfig(start_time=0.5))
    period: float = 0.01


@dataclasses.dataclass
class PerceptionSection(PerceptionConfig):
    """How the bounds and the safety filter learn of moving obstacles: the
    camera's :class:`~drake_cfvol.systems.PerceptionConfig` and

    Attributes:
        mode: ``camera`` (default with moving obstacles: a depth camera over
            the cell, its obstacle map, the bounds re-estimated online, the
            filter measuring the perceived columns) or ``truth`` (the boxes'
            poses given directly); null without moving obstacles (fixed
            bounds).
    """

    mode: typing.Optional[str] = None


@dataclasses.dataclass
class SimulationConfig:
    """The simulation.

    Attributes:
        log_period: logging and recording period, s.
        simulator_config: Drake's simulator settings (``ApplySimulatorConfig``).
        plant_config: Drake's ``MultibodyPlantConfig``: given, the run is
            dynamic (a time-stepping plant, the robot under its driver, the
            pushes real forces); null (default): kinematic (the plant posed
            from the command).
        model_drivers: the robot's driver in a dynamic run, by model
            instance name: ``!InverseDynamicsDriver`` (default), Drake's
            ``!IiwaDriver`` or ``!FrankaDriver`` (a Franka arm over
            drake-franka-driver's LCM).
        visualization: Drake's visualization settings for the recording
            (illustration and proximity layers, publish period, colours;
            see :func:`meshcat_params`).
    """

    log_period: float = 0.02
    simulator_config: SimulatorConfig = dataclasses.field(default_factory=SimulatorConfig)
    plant_config: typing.Optional[MultibodyPlantConfig] = None
    model_drivers: dict[str, DriverConfig] = dataclasses.field(default_factory=dict)
    visualization: VisualizationConfig = dataclasses.field(
        default_factory=lambda: VisualizationConfig(
            publish_period=0.02, publish_proximity=False, publish_contacts=False, publish_inertia=False
        )
    )


@dataclasses.dataclass
class Scenario:
    """A co-manipulation run, in sections (each loaded with
    ``yaml_load_typed`` and checked field by field).

    Attributes:
        random_seed: the one seed of the run: the planner, the
            certificate's samples and the random pushes (Drake's random
            context).
        directives, cfvol: a cell held by the scenario itself (Drake model
            directives and the cfvol settings: the keys of a workcell file,
            as in Drake's hardware_sim); ``cell.name`` is then ignored.
        cell: :class:`CellConfig`.
        path: :class:`PathConfig`.
        bounds: :class:`BoundsConfig`.
        human: :class:`HumanConfig`.
        control: :class:`ControlConfig`.
        perception: :class:`PerceptionSection`.
        simulation: :class:`SimulationConfig`.
    """

    random_seed: int = 0
    directives: list[ModelDirective] = dataclasses.field(default_factory=list)
    cfvol: typing.Optional[CfvolSection] = None
    cell: CellConfig = dataclasses.field(default_factory=CellConfig)
    path: PathConfig = dataclasses.field(default_factory=PathConfig)
    bounds: BoundsConfig = dataclasses.field(default_factory=BoundsConfig)
    human: HumanConfig = dataclasses.field(default_factory=HumanConfig)
    control: ControlConfig = dataclasses.field(default_factory=ControlConfig)
    perception: PerceptionSection = dataclasses.field(default_factory=PerceptionSection)
    simulation: SimulationConfig = dataclasses.field(default_factory=SimulationConfig)

    @property
    def perception_mode(self) -> str | None:
        """``camera``, ``truth`` or None (fixed bounds): ``perception.mode``,
        or ``camera`` where there are moving obstacles and it is not given."""
        if self.perception.mode is not None:
            return self.perception.mode
        return "camera" if self.cell.moving_obstacles else None

    @property
    def duration(self) -> float:
        """Total simulated time at the requested path duration, s (a run
        whose path had to slow down lasts longer: ``CoManipulation.duration``)."""
        return self.control.path_progress.start_time + self.path.duration + self.path.end_hold

    def certify(self) -> Certify | None:
        """The bounds' :class:`~drake_cfvol.Certify` (seeded with
        ``random_seed``), or None for the paper's bounds."""
        c = self.bounds.certify
        return None if c is None else Certify(**dataclasses.asdict(c), seed=self.random_seed)


#: Fields a scenario no longer has, and what took their place.
RENAMED = {"seed": "random_seed", "human.random_pushes.seed": "random_seed", "bounds.certify.seed": "random_seed"}
_RENAMED = {
    old: f"is now '{new}' (one seed for the planner, the certificate and the random pushes, as in Drake's "
    "hardware_sim); rename it"
    for old, new in RENAMED.items()
}

#: The top-level fields of the scenario form before 0.3 (flat), and where
#: each went in the sections.
OLD_FIELDS = {
    "path_file": "path.file",
    "bounds_file": "bounds.file",
    "resolution": "bounds.resolution",
    "params": "bounds.params",
    "certify": "bounds.certify (null: the paper's bounds; {}: certified)",
    "online": "perception (camera_period, width, height, cell, obstacle_speed) and bounds.online (period: was "
    "bounds_period; horizon)",
    "path_duration": "path.duration",
    "end_hold": "path.end_hold",
    "start_time": "control.path_progress.start_time",
    "path_velocity_share": "control.path_progress.velocity_share",
    "admittance": "control.admittance (mass, damping, stiffness) and control.period (was admittance.period)",
    "collision_guard": "control.safety_filter (null: no filter)",
    "safety_filter": "control.safety_filter",
    "pushes": "human.pushes",
    "random_pushes": "human.random_pushes",
    "reactive": "human.reactive",
    "moving_obstacles": "cell.moving_obstacles",
    "log_period": "simulation.log_period",
    "simulator_config": "simulation.simulator_config",
    "plant_config": "simulation.plant_config",
    "model_drivers": "simulation.model_drivers",
    "visualization": "simulation.visualization",
}

#: Sections that were a name before 0.3, and the field the name went to.
_OLD_NAMES = {"cell": "cell.name", "path": "path.name", "perception": "perception.mode"}


def _errors(file: Path) -> ErrorFactory:
    """The typed YAML loader's errors for a scenario (or its override text)."""
    return lambda field, message, line: ScenarioError(file, field, message, line)


def _checked_form(file: Path) -> Callable[[dict], None]:
    """:func:`_check_form` of the file's mapping, for the loader."""
    return lambda raw: _check_form(raw, file)


def _check_form(raw, file) -> None:
    """Refuses a scenario of the form before 0.3 (flat fields) with one
    error naming the first old field, where it went and where to read the
    rest (CHANGELOG.md)."""
    if not isinstance(raw, dict):
        return
    for key, value in raw.items():
        if key in OLD_FIELDS:
            new = OLD_FIELDS[key]
        elif key in _OLD_NAMES and not isinstance(value, dict) and value is not None:
            new, value = _OLD_NAMES[key], f"{{{_OLD_NAMES[key].split('.')[1]}: {value}}}"
            raise ScenarioError(
                file,
                key,
                f"is a section since drake_cfvol 0.3: write '{key}: {value}' "
                f"({new}). CHANGELOG.md lists where every field of the old form went",
            )
        else:
            continue
        raise ScenarioError(
            file,
            key,
            f"is a field of the scenario form before drake_cfvol 0.3; it is now "
            f"'{new}'. CHANGELOG.md lists where every field of the old form went",
        )


def load_scenario(
    name_or_path: str | Path, *, scenario_text: str | None = None, overrides: dict | None = None
) -> tuple[Scenario, Path | None]:
    """Loads a scenario by bundled name (``automotive_push``) or file path,
    and checks it (:func:`validate_scenario`) before anything is planned.

    As in Drake's ``hardware_sim``: the file is read over the defaults
    (``yaml_load_typed(defaults=Scenario())``), and ``scenario_text``, YAML
    text such as ``"{bounds: {resolution: 2000}, simulation: {simulator_config:
    {target_realtime_rate: 1.0}}}"``, is read over the file's values; then
    ``overrides`` (dotted field -> value, e.g. ``{"path.file": ...}`` from the
    CLI's ``--path-file``).

    A file of the form before 0.3 (flat fields such as ``resolution`` or
    ``collision_guard``) is refused with one error naming the new field.

    Returns:
        (scenario, its file)

    Raises:
        ScenarioError: an unknown name, a missing file, or a field that is
            unknown, of the wrong type or out of range (named in the message).
    """
    p = Path(name_or_path)
    if not p.is_file():
        cand = diagrams_dir() / f"{name_or_path}.yaml"
        if cand.is_file() and not looks_like_path(str(name_or_path)):
            p = cand
        else:
            known = sorted(x.stem for x in diagrams_dir().glob("*.yaml"))
            what = "does not exist" if looks_like_path(str(name_or_path)) else "is not a bundled scenario"
            raise ScenarioError(
                name_or_path, None, f"{what}. Bundled: {', '.join(known)}; or pass the path of a scenario YAML file"
            )
    scenario, _ = load_typed(Scenario, p, _errors(p), defaults=Scenario(), check_raw=_checked_form(p), renamed=_RENAMED)
    if scenario_text:
        where = Path("--scenario-text")
        scenario, _ = load_typed(
            Scenario,
            where,
            _errors(where),
            text=scenario_text,
            defaults=scenario,
            check_raw=_checked_form(where),
            renamed=_RENAMED,
        )
    for key, value in (overrides or {}).items():
        scenario = _replace(scenario, key.split("."), value, p, key)
    validate_scenario(scenario, p.resolve())
    return scenario, p.resolve()


def _replace(obj, names: list[str], value, file, key: str):
    """A copy of ``obj`` with the dotted field ``names`` set to ``value``."""
    if (
        not dataclasses.is_dataclass(obj)
        or isinstance(obj, type)
        or names[0] not in {f.name for f in dataclasses.fields(obj)}
    ):
        raise ScenarioError(file, key, "is not a field of Scenario")
    if len(names) == 1:
        return dataclasses.replace(obj, **{names[0]: value})
    return dataclasses.replace(obj, **{names[0]: _replace(getattr(obj, names[0]), names[1:], value, file, key)})
