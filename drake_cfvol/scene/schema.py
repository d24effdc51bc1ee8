"""The workcell file: its schema (typed dataclasses read by the package's
typed YAML loader, :mod:`drake_cfvol.io.typed_yaml`, as Drake's
hardware_sim reads its scenarios) and the built-in cells.

Workcells: a robot and its obstacles, loaded from one YAML file.

A workcell file holds Drake model directives (``directives:``) for the robot
and the obstacles, and a ``cfvol:`` section::

    directives:
    - add_model: {name: abb, file: package://drake_cfvol_models/...urdf}
    - add_weld: {parent: world, child: abb::base_link}
    - add_model: {name: cell, file: package://drake_cfvol_models/cells/...sdf}
    cfvol:
      robot: abb                 # model instance of the robot
      tool_frame: tcp            # frame of the robot (Jacobian, tool path)
      base_frame: base_link      # reach is measured from here ...
      rail_joint: null           # ... or along this prismatic joint's travel
      reach: 2.8                 # m, the activation radius of the volume
      height_map: {origin: [x, y], size: [x_dim, y_dim]}   # m, on the floor
      package_paths: {my_pkg: relative/or/absolute/dir}     # optional
      joint_limits: {joint: [lower, upper]}                 # optional overrides
      acceleration_limits: [...]                            # rad/s^2 (m/s^2) per joint, optional
      jerk_limits: [...]                                    # rad/s^3 (m/s^3) per joint, optional
      params: {h_max: 1.5, ...}                             # VolumeParams overrides
      configurations:
        path1: {start: [...], goal: [...]}                  # rad / m
"""

import dataclasses
import os
from importlib import resources
from pathlib import Path

from pydrake.multibody.parsing import ModelDirective

from drake_cfvol.exceptions import WorkcellError, WorkcellFormatError
from drake_cfvol.io.typed_yaml import load_typed

__all__ = [
    "WorkcellFile",
    "CfvolSection",
    "HeightMapExtent",
    "NamedConfiguration",
    "builtin_cells",
    "models_dir",
    "read_workcell_file",
    "DEFAULT_EDGE_STEP",
]

#: Distance between configurations at which Drake's edge checks sample (rad or
#: m, Euclidean in joint space).
DEFAULT_EDGE_STEP = 0.01


def models_dir() -> Path:
    """Returns the folder of the bundled models (holds ``package.xml``):
    ``$DRAKE_CFVOL_MODELS`` if set, else the ``drake_cfvol.models`` package
    data (the repository's ``models/``, shipped inside the wheel).

    Raises:
        WorkcellError: the folder is missing.
    """
    env = os.environ.get("DRAKE_CFVOL_MODELS")
    folder = Path(env) if env else Path(str(resources.files("drake_cfvol.models")))
    if not (folder / "package.xml").is_file():
        raise WorkcellError(
            f"drake_cfvol's models folder is missing ({folder}/package.xml not found). Reinstall the "
            "package (`pip install drake-cfvol` or `pip install .` from a checkout), or point "
            "$DRAKE_CFVOL_MODELS at a folder holding the models' package.xml."
        )
    return folder


def builtin_cells() -> dict[str, Path]:
    """Returns the built-in workcells, by name."""
    return {p.stem: p for p in sorted((models_dir() / "cells").glob("*.yaml"))}


@dataclasses.dataclass
class HeightMapExtent:
    """The height map's extent on the floor.

    Attributes:
        origin: (x, y) of its corner, m.
        size: (x_dim, y_dim), m.
    """

    origin: list[float] = dataclasses.field(default_factory=list)
    size: list[float] = dataclasses.field(default_factory=list)


@dataclasses.dataclass
class NamedConfiguration:
    """A named start/goal pair.

    Attributes:
        start, goal: one value per robot joint, rad (m for prismatic joints).
    """

    start: list[float] = dataclasses.field(default_factory=list)
    goal: list[float] = dataclasses.field(default_factory=list)


@dataclasses.dataclass
class CfvolSection:
    """The ``cfvol:`` section of a workcell file.

    Attributes:
        robot: the robot's model instance.
        tool_frame: a frame of the robot (Jacobian, tool path).
        base_frame: the reach is measured from here (default: the robot's root body).
        rail_joint: a prismatic joint whose travel the reach follows, or None.
        reach: the activation radius of the volume, m.
        height_map: the height map's extent.
        package_paths: package name -> folder (relative to the file).
        joint_limits: joint -> [lower, upper] overrides, rad or m.
        acceleration_limits: per joint, rad/s^2 (m/s^2); empty: the model's
            (``drake:acceleration`` in a URDF), else none.
        jerk_limits: per joint, rad/s^3 (m/s^3); empty: none.
        params: :class:`drake_cfvol.VolumeParams` overrides.
        configurations: named start/goal pairs.
    """

    robot: str = ""
    tool_frame: str = ""
    base_frame: str | None = None
    rail_joint: str | None = None
    reach: float = 0.0
    height_map: HeightMapExtent | None = None
    package_paths: dict[str, str] = dataclasses.field(default_factory=dict)
    joint_limits: dict[str, list[float]] = dataclasses.field(default_factory=dict)
    acceleration_limits: list[float] = dataclasses.field(default_factory=list)
    jerk_limits: list[float] = dataclasses.field(default_factory=list)
    params: dict[str, float] = dataclasses.field(default_factory=dict)
    configurations: dict[str, NamedConfiguration] = dataclasses.field(default_factory=dict)


@dataclasses.dataclass
class WorkcellFile:
    """A workcell file: Drake model directives plus the ``cfvol:`` section
    (loaded with ``yaml_load_typed``, as Drake's hardware_sim scenarios).

    Attributes:
        directives: Drake model directives: the robot and the obstacles.
        cfvol: which model is the robot, and the method's settings.
    """

    directives: list[ModelDirective] = dataclasses.field(default_factory=list)
    cfvol: CfvolSection = dataclasses.field(default_factory=CfvolSection)


def read_workcell_file(path: Path, *, embedded: bool = False) -> tuple[WorkcellFile, dict[str, int]]:
    """Reads and type-checks a workcell file (``embedded``: the
    ``directives`` and ``cfvol`` keys of another file, e.g. a scenario that
    holds its cell; its other keys are left out) with the package's typed
    YAML loader (:func:`drake_cfvol.io.typed_yaml.load_typed`).

    Returns:
        (the typed file, key -> line)

    Raises:
        WorkcellFormatError: unreadable, not YAML, a required key missing,
            an unknown key or a value of the wrong type (named, with its
            line and the fix).
    """

    def error(field: str | None, message: str, line: int | None) -> WorkcellFormatError:
        return WorkcellFormatError(str(path), f"field '{field}' {message}." if field else f"the file {message}.", line)

    def required(raw: dict) -> None:
        for key in ("directives", "cfvol"):
            if raw.get(key) is None:
                raise WorkcellFormatError(str(path), f"'(top level)' lacks the required key '{key}'.", 1)

    keep = ("directives", "cfvol") if embedded else None
    return load_typed(WorkcellFile, path, error, tags=embedded, keep=keep, check_raw=required)
