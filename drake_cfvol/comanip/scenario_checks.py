"""A scenario's values checked before anything is planned or bounded: each
error names the file, the field (list items counted from 1) and the fix."""

import dataclasses
import typing
from pathlib import Path

import numpy as np

from drake_cfvol.comanip.drivers import TORQUE_SENSING_DRIVERS, FrankaDriver
from drake_cfvol.exceptions import ParameterError, ScenarioError
from drake_cfvol.scene.params import VolumeParams
from drake_cfvol.scene.workcell import builtin_cells

__all__ = ["validate_scenario", "check_scenario_against_cell", "scenario_file_path", "looks_like_path", "cell_file"]


def _check_pushes(human, where) -> None:
    """Each push's window and sizes (items counted from 1): a wrench of 6
    values, joint torques of one length across the pushes."""
    lengths = {}
    for i, p in enumerate(human.pushes, 1):
        name = f"human.pushes item {i}"
        if not p.start >= 0:
            raise ScenarioError(where, f"{name}: start", f"must be >= 0 s, got {p.start!r}")
        if not p.duration >= 0:
            raise ScenarioError(where, f"{name}: duration", f"must be >= 0 s, got {p.duration!r}")
        if len(p.wrench) not in (0, 6):
            raise ScenarioError(
                where,
                f"{name}: wrench",
                f"has {len(p.wrench)} values; give 6, [torque N m; force "
                "N] at the tool in the world frame (or leave it out)",
            )
        for field in ("wrench", "joint_torque", "toward_nearest_obstacle"):
            values = np.atleast_1d(np.asarray(getattr(p, field, None) or [], float))
            if not np.isfinite(values).all():
                raise ScenarioError(where, f"{name}: {field}", f"must be finite numbers, got {values.tolist()}")
        if not np.isfinite(p.start + p.duration):
            raise ScenarioError(where, f"{name}: start, duration", "must be finite seconds")
        if len(p.joint_torque):
            lengths[i] = len(p.joint_torque)
    if len(set(lengths.values())) > 1:
        first, *rest = lengths.items()
        other = next((i, n) for i, n in rest if n != first[1])
        raise ScenarioError(
            where,
            f"human.pushes item {other[0]}: joint_torque",
            f"has {other[1]} values but "
            f"pushes item {first[0]} has {first[1]}; give one torque per robot joint in every push",
        )
    if human.random_pushes.count < 0:
        raise ScenarioError(where, "human.random_pushes.count", f"must be >= 0, got {human.random_pushes.count}")


def check_scenario_against_cell(scenario, workcell, file: Path | None = None) -> None:
    """Checks the sizes that need the robot (k joints) right after the cell
    is loaded, before anything is planned: each push's joint torques, the
    reactive co-worker's offset, the velocity limits.

    Raises:
        ScenarioError: naming the file, the item (counted from 1) and the field.
    """
    where = file if file is not None else "scenario"
    k, names = workcell.num_joints, ", ".join(workcell.joint_names)
    for i, p in enumerate(scenario.human.pushes, 1):
        if len(p.joint_torque) and len(p.joint_torque) != k:
            raise ScenarioError(
                where,
                f"human.pushes item {i}: joint_torque",
                f"has {len(p.joint_torque)} values; the robot of cell '{workcell.name}' has {k} joints ({names})",
            )
    for name, values in (
        ("human.reactive.offset", scenario.human.reactive.offset),
        ("control.velocity_limits", scenario.control.velocity_limits),
        ("control.acceleration_limits", scenario.control.acceleration_limits),
        ("control.jerk_limits", scenario.control.jerk_limits),
    ):
        if len(values) and len(values) != k:
            raise ScenarioError(where, name, f"has {len(values)} values; the robot has {k} joints ({names})")


@typing.overload
def scenario_file_path(name: str, base_dir: Path | None) -> Path: ...
@typing.overload
def scenario_file_path(name: None, base_dir: Path | None) -> None: ...
def scenario_file_path(name: str | None, base_dir: Path | None) -> Path | None:
    """A file named by a scenario (relative: from the scenario's folder)."""
    if name is None:
        return None
    p = Path(name).expanduser()
    return (base_dir / p).resolve() if base_dir is not None and not p.is_absolute() else p


def looks_like_path(cell: str) -> bool:
    """Whether a cell name is a workcell file's path rather than a built-in cell."""
    return cell not in builtin_cells() and (
        Path(cell).suffix.lower() in (".yaml", ".yml") or "/" in cell or "\\" in cell
    )


def cell_file(cell: str, base_dir: Path | None) -> Path:
    """A workcell file's path named by a scenario (relative: from its folder)."""
    p = Path(cell)
    if base_dir is not None and not p.is_absolute():
        p = (base_dir / p).resolve()
    return p


def _check_sources(scenario, where, base_dir) -> None:
    """The files a scenario names, a cell it holds, a dynamic run's settings."""
    for name, value in (("path.file", scenario.path.file), ("bounds.file", scenario.bounds.file)):
        p = scenario_file_path(value, base_dir)
        if p is not None and not p.is_file():
            raise ScenarioError(
                where,
                name,
                f"names '{p}', which does not exist (a relative path starts from the scenario file's folder)",
            )
    if bool(scenario.directives) != (scenario.cfvol is not None):
        raise ScenarioError(
            where,
            "directives" if scenario.cfvol is not None else "cfvol",
            "is missing: a scenario that holds its cell gives both 'directives' and 'cfvol' (the "
            "keys of a workcell file)",
        )
    sim = scenario.simulation
    pc = sim.plant_config
    if pc is not None and not pc.time_step > 0:
        raise ScenarioError(
            where,
            "simulation.plant_config.time_step",
            f"must be > 0 s for a dynamic run, got {pc.time_step!r} (leave plant_config out for a kinematic run)",
        )
    if sim.model_drivers and pc is None:
        raise ScenarioError(where, "simulation.model_drivers", "needs plant_config: drivers act in a dynamic run only")
    for name, d in sim.model_drivers.items():
        if isinstance(d, FrankaDriver):
            _check_franka_driver(d, where, f"simulation.model_drivers.{name}")
    if any(isinstance(d, TORQUE_SENSING_DRIVERS) for d in sim.model_drivers.values()):
        human = scenario.human
        felt = [f"human.pushes item {i}: joint_torque" for i, p in enumerate(human.pushes, 1) if len(p.joint_torque)]
        felt += ["human.random_pushes.count"] * (human.random_pushes.count > 0) + ["human.reactive.gain"] * (
            human.reactive.gain > 0
        )
        if felt:
            raise ScenarioError(
                where,
                felt[0],
                "is a joint torque, which a torque-sensing arm (IiwaDriver, FrankaDriver) would "
                "not feel through contact: give the co-worker's pushes as tool wrenches (the "
                "hand's force) in this cell",
            )


def _check_franka_driver(driver, where, section: str) -> None:
    """A Franka driver's mode and gains."""
    if driver.control_mode not in ("position", "velocity"):
        raise ScenarioError(
            where, f"{section}.control_mode", f"must be 'position' or 'velocity', got {driver.control_mode!r}"
        )
    _positive(where, section, driver, ("kp", "kd"))


def _positive(where, section, obj, names, *, strict: bool = True, unit: str = "") -> None:
    for name in names:
        v = getattr(obj, name)
        if not (v > 0 if strict else v >= 0) or v == float("inf"):
            raise ScenarioError(
                where, f"{section}.{name}", f"must be {'>' if strict else '>='} 0{unit} and finite, got {v!r}"
            )


def _check_control(control, where) -> None:
    """The control chain's gains, margin and rates."""
    _positive(where, "control", control, ("period",), unit=" s")
    _positive(where, "control.admittance", control.admittance, ("mass", "damping"))
    _positive(where, "control.admittance", control.admittance, ("stiffness",), strict=False)
    f = control.safety_filter
    if f is not None:
        if f.clearance is not None and not f.clearance >= 0:
            raise ScenarioError(
                where,
                "control.safety_filter.clearance",
                f"must be >= 0 m (or null: the bounds' own), got {f.clearance!r}",
            )
        _positive(where, "control.safety_filter", f, ("allowance",), strict=False, unit=" m")
        if not f.influence_distance > (f.clearance or 0.0) + f.allowance:
            raise ScenarioError(
                where,
                "control.safety_filter.influence_distance",
                f"must exceed the clearance plus the allowance, got {f.influence_distance!r}",
            )
        _positive(where, "control.safety_filter", f, ("damper_gain",), unit=" m/s")
    pp = control.path_progress
    if not 0.0 < pp.velocity_share < 1.0:
        raise ScenarioError(
            where, "control.path_progress.velocity_share", f"must lie in (0, 1), got {pp.velocity_share!r}"
        )
    _positive(where, "control.path_progress", pp, ("start_time",), strict=False, unit=" s")
    if pp.max_rate is not None:
        _positive(where, "control.path_progress", pp, ("max_rate",), unit=" waypoints/s")
    for key in ("velocity_limits", "acceleration_limits", "jerk_limits"):
        values = getattr(control, key)
        if any(not v > 0 for v in values):
            raise ScenarioError(where, f"control.{key}", f"must be > 0 (or left out: the robot's), got {values}")


def _check_online(scenario, where) -> None:
    """Moving obstacles (items counted from 1), the perception mode and the
    online settings."""
    obstacles = scenario.cell.moving_obstacles
    for i, o in enumerate(obstacles, 1):
        try:
            o.check()
        except ParameterError as e:
            raise ScenarioError(where, f"cell.moving_obstacles item {i}", str(e)) from None
    names = [o.name for o in obstacles]
    if len(set(names)) != len(names):
        raise ScenarioError(where, "cell.moving_obstacles", f"need distinct names, got {names}")
    p = scenario.perception
    if p.mode not in (None, "camera", "truth"):
        raise ScenarioError(where, "perception.mode", f"must be camera or truth (or left out), got {p.mode!r}")
    if scenario.perception_mode is not None and scenario.simulation.plant_config is not None:
        raise ScenarioError(
            where,
            "cell.moving_obstacles" if p.mode is None else "perception.mode",
            "work in kinematic runs only: leave simulation.plant_config out",
        )
    if p.mode == "truth" and not obstacles:
        raise ScenarioError(
            where,
            "perception.mode",
            "is truth, which gives the moving obstacles' poses: add cell.moving_obstacles (or use camera)",
        )
    _positive(where, "perception", p, ("camera_period", "cell"))
    _positive(where, "perception", p, ("obstacle_speed",), strict=False, unit=" m/s")
    if not (p.width >= 16 and p.height >= 16):
        raise ScenarioError(
            where, "perception.width", f"the camera needs at least 16 x 16 px, got {p.width} x {p.height}"
        )
    o = scenario.bounds.online
    _positive(where, "bounds.online", o, ("period",), unit=" s")
    if not o.horizon >= 1:
        raise ScenarioError(where, "bounds.online.horizon", f"must be >= 1 stretch, got {o.horizon!r}")


def _check_bounds(bounds, where) -> None:
    """The resolution and the volume's parameters (VolumeParams' own checks)."""
    if not bounds.resolution > 0:
        raise ScenarioError(where, "bounds.resolution", f"must be a positive integer, got {bounds.resolution!r}")
    try:
        VolumeParams(**bounds.overrides())
    except ParameterError as e:
        field = next((f.name for f in dataclasses.fields(VolumeParams) if f"{f.name} " in str(e)), None)
        raise ScenarioError(where, f"bounds.params.{field}" if field else "bounds.params", str(e).rstrip(".")) from None


# ``scenario``: a Scenario, typed Any: scenario.py imports this module, so
# naming its class here would make an import cycle.
def validate_scenario(scenario: typing.Any, file: Path | None = None, *, base_dir: Path | None = None) -> None:
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
    _check_pushes(scenario.human, where)
    _check_sources(scenario, where, base_dir)
    _positive(where, "path", scenario.path, ("duration",), unit=" s")
    if scenario.control.period >= scenario.path.duration:
        raise ScenarioError(
            where,
            "control.period",
            f"is {scenario.control.period:g} s, not shorter than the path's duration ({scenario.path.duration:g} s): "
            "the controller would update once or never along the path; use a period of a few ms (0.01)",
        )
    _positive(where, "path", scenario.path, ("end_hold",), strict=False, unit=" s")
    _positive(where, "simulation", scenario.simulation, ("log_period",), unit=" s")
    _check_control(scenario.control, where)
    vis = scenario.simulation.visualization
    for name in ("publish_contacts", "publish_inertia"):
        if getattr(vis, name) and scenario.simulation.plant_config is None:
            raise ScenarioError(
                where,
                f"simulation.visualization.{name}",
                "must be false: the run moves the robot "
                "kinematically, so there are no contact forces or inertias to show",
            )
    _positive(where, "simulation.visualization", vis, ("publish_period",), unit=" s")
    _check_online(scenario, where)
    _check_bounds(scenario.bounds, where)
    if scenario.directives:
        return  # the scenario holds its cell
    cell = scenario.cell.name
    if not looks_like_path(cell) and cell not in builtin_cells():
        raise ScenarioError(
            where,
            "cell.name",
            f"is '{cell}', neither a built-in cell ({', '.join(sorted(builtin_cells()))}) nor a workcell YAML path",
        )
    if looks_like_path(cell) and not cell_file(cell, base_dir).is_file():
        raise ScenarioError(
            where,
            "cell.name",
            f"names the workcell file '{cell_file(cell, base_dir)}', which does "
            "not exist (a relative path starts from the scenario file's folder)",
        )
