"""The workcell file: its schema (typed dataclasses read with pydrake's
``yaml_load_typed``, as Drake's hardware_sim reads its scenarios), the
line of every key (for errors that name it), and the built-in cells.

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
import re
from collections.abc import Callable
from importlib import resources
from pathlib import Path
from typing import Any

import yaml
from pydrake.common.yaml import yaml_load_typed
from pydrake.multibody.parsing import ModelDirective

from drake_cfvol.exceptions import FileError, WorkcellError, WorkcellFormatError

__all__ = [
    "WorkcellFile",
    "CfvolSection",
    "HeightMapExtent",
    "NamedConfiguration",
    "builtin_cells",
    "models_dir",
    "read_workcell_file",
    "read_yaml",
    "read_yaml_text",
    "yaml_error_line",
    "DuplicateKeyError",
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


class DuplicateKeyError(yaml.constructor.ConstructorError):
    """A mapping names one key twice (PyYAML and Drake's reader would keep
    the last one without a word)."""

    def __init__(self, key: str, first_line: int, mark):
        super().__init__(
            None,
            None,
            f"duplicate key '{key}' (first on line {first_line}; YAML would keep only the last): "
            "remove or rename one of them",
            mark,
        )


# libyaml's loader where PyYAML was built with it.
_SafeLoader: Any = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


class _UniqueLoader(_SafeLoader):
    """YAML's safe loader that refuses a key given twice in one mapping
    (libyaml's parser where PyYAML has it: faster than PyYAML's own)."""

    def construct_mapping(self, node, deep=False):
        if isinstance(node, yaml.MappingNode):
            seen: dict[str, int] = {}
            for key_node, _ in node.value:
                # A merge key (<<) may be overridden by design; other keys not.
                if not isinstance(key_node, yaml.ScalarNode) or key_node.tag == "tag:yaml.org,2002:merge":
                    continue
                if key_node.value in seen:
                    raise DuplicateKeyError(key_node.value, seen[key_node.value], key_node.start_mark)
                seen[key_node.value] = key_node.start_mark.line + 1
        return super().construct_mapping(node, deep)


class _TagLoader(_UniqueLoader):
    """The unique-key loader, reading a tagged node (``!IiwaDriver {...}``) as
    its plain value (Drake's reader checks the variant)."""


_TagLoader.add_multi_constructor(
    "!",
    lambda loader, suffix, node: (
        loader.construct_mapping(node)
        if isinstance(node, yaml.MappingNode)
        else loader.construct_sequence(node)
        if isinstance(node, yaml.SequenceNode)
        else loader.construct_scalar(node)
    ),
)


def read_yaml(text: str, *, tags: bool = True):
    """A YAML text as plain Python values, Drake's variant tags read as the
    value they tag (``tags=False``: refused, as YAML's safe loader does).

    Raises:
        yaml.YAMLError: not valid YAML, or a key given twice in one mapping
            (:class:`DuplicateKeyError`).
    """
    return yaml.load(text, Loader=_TagLoader if tags else _UniqueLoader)


def yaml_error_line(e: yaml.YAMLError) -> str:
    """A YAML error on one line: where (line, column) and what."""
    if isinstance(e, yaml.MarkedYAMLError):
        mark = e.problem_mark or e.context_mark
        where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark is not None else ""
        what = " ".join(x for x in (e.context, e.problem) if x)
        return where + (what or type(e).__name__)
    return " ".join(str(e).split())


_SAVE_AS_UTF8 = (
    "save it as UTF-8 (an editor's 'Save As' with encoding UTF-8; PowerShell: "
    "Get-Content FILE | Set-Content -Encoding utf8 NEW; or iconv -f {enc} -t UTF-8 FILE > NEW)"
)


def _encoding_found(data: bytes) -> str | None:
    """The encoding of a file's bytes if it is not UTF-8 (with or without
    its byte-order mark): a name for the user, or None for UTF-8."""
    if data.startswith((b"\xff\xfe\x00\x00", b"\x00\x00\xfe\xff")):
        return "UTF-32"
    if data.startswith((b"\xff\xfe", b"\xfe\xff")):
        return "UTF-16"
    if b"\x00" in data:
        head = data[:4096]
        # UTF-16 without a byte-order mark: ASCII text with every other byte 0.
        if len(head) >= 2 and (head[1::2].count(0) > 0.4 * len(head) / 2 or head[0::2].count(0) > 0.4 * len(head) / 2):
            return "UTF-16"
        return "binary"
    try:
        data.decode("utf-8")
    except UnicodeDecodeError:
        # Windows-1252 is Latin-1 with printable characters where Latin-1 has controls.
        text = data.decode("cp1252", errors="replace")
        printable = sum((c.isprintable() and c != "\ufffd") or c in "\t\r\n" for c in text)
        return "Latin-1 (or Windows-1252)" if printable > 0.95 * len(text) else "binary"
    return None


def read_yaml_text(path: Path, what: str = "YAML", error: Callable[[str], Exception] | None = None) -> str:
    """The text of a YAML file, which must be UTF-8 (a UTF-8 byte-order
    mark, as Windows' editors write it, is accepted and dropped).

    Args:
        error: makes the exception from the problem's text (default: a
            :class:`FileError` naming ``path``).

    Raises:
        FileError (or what ``error`` makes): the file cannot be read, or it
            is not UTF-8 text (the encoding found and how to save it as UTF-8
            in the message).
    """
    error = error or (lambda message: FileError(f"{what} file '{path}' {message}"))
    try:
        data = Path(path).read_bytes()
    except OSError as e:
        raise error(f"cannot be read ({e.strerror or e}).") from None
    if data.startswith(b"\xef\xbb\xbf"):
        data = data[3:]
    found = _encoding_found(data)
    if found == "binary":
        raise error(
            "holds binary data, not text (encoding found: binary). Pass the YAML text file itself, saved as UTF-8."
        )
    if found is not None:
        enc = "UTF-16" if found.startswith("UTF-16") else "UTF-32" if found == "UTF-32" else "LATIN1"
        raise error(f"is {found} text, but YAML files are read as UTF-8: " + _SAVE_AS_UTF8.format(enc=enc) + ".")
    return data.decode("utf-8")


def _key_lines(text: str) -> dict[str, int]:
    """First line (1-based) of every mapping key in a YAML text, by key and by
    dotted path."""
    out: dict[str, int] = {}
    try:
        root = yaml.compose(text, Loader=_TagLoader)
    except yaml.YAMLError:
        return out

    def walk(node, prefix):
        if isinstance(node, yaml.MappingNode):
            for k, v in node.value:
                name = str(k.value)
                line = k.start_mark.line + 1
                out.setdefault(name, line)
                out.setdefault(prefix + name, line)
                walk(v, prefix + name + ".")
        elif isinstance(node, yaml.SequenceNode):
            for item in node.value:
                walk(item, prefix)

    walk(root, "")
    return out


def read_workcell_file(path: Path, *, embedded: bool = False) -> tuple[WorkcellFile, dict[str, int]]:
    """Reads and type-checks a workcell file (``embedded``: the
    ``directives`` and ``cfvol`` keys of another file, e.g. a scenario that
    holds its cell; its other keys are left out).

    Returns:
        (the typed file, key -> line)

    Raises:
        WorkcellFormatError: unreadable, not YAML, an unknown key (named, with
            its line), or a value of the wrong type.
    """
    text = read_yaml_text(path, "workcell", lambda message: WorkcellFormatError(str(path), "the file " + message))
    try:
        data = read_yaml(text, tags=embedded)
    except yaml.YAMLError as e:
        mark = (e.problem_mark or e.context_mark) if isinstance(e, yaml.MarkedYAMLError) else None
        what = (e.problem or yaml_error_line(e)) if isinstance(e, yaml.MarkedYAMLError) else yaml_error_line(e)
        line = mark.line + 1 if mark is not None else None
        raise WorkcellFormatError(str(path), f"not valid YAML: {what}. Fix it there.", line) from None
    if not isinstance(data, dict):
        raise WorkcellFormatError(str(path), "expected a mapping with 'directives:' and 'cfvol:' at the top.", 1)
    lines = _key_lines(text)
    if embedded:
        data = {key: data.get(key) for key in ("directives", "cfvol")}
        text = yaml.safe_dump(data, sort_keys=False)
    for key in ("directives", "cfvol"):
        if data.get(key) is None:
            raise WorkcellFormatError(str(path), f"'(top level)' lacks the required key '{key}'.", 1)
    try:
        typed = yaml_load_typed(schema=WorkcellFile, data=text)
    except Exception as e:  # Drake raises RuntimeError / ValueError / TypeError here.
        msg = str(e)
        unknown = re.search(r"fields \[([^\]]*)\] were unknown", msg)
        if unknown:
            names = [n.strip(" '\"") for n in unknown.group(1).split(",")]
            line = lines.get(names[0])
            raise WorkcellFormatError(
                str(path),
                f"unknown key {', '.join(repr(n) for n in names)}: not part of a workcell file. "
                "Check its spelling (see the drake_cfvol.scene.workcell docstring for the keys).",
                line,
            ) from e
        flat = " ".join(msg.split())  # pybind11 lists the signatures it tried over several lines
        tried = re.search(r"self: ([\w.]+).*Invoked with: .*\), (.+)$", flat)
        if tried:  # e.g. a translation of two numbers: "a Transform field got array([1., 2.])"
            flat = f"a {tried.group(1).rsplit('.', 1)[-1]} field got {tried.group(2)}"
        raise WorkcellFormatError(str(path), f"a value has the wrong type or size: {flat}. Fix it there.") from e
    return typed, lines
