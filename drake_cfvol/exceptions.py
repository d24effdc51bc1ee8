"""Exceptions raised by drake_cfvol.

Every error says what is wrong and how to fix it. Catch :class:`CfvolError`
to catch them all.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Sequence


class CfvolError(Exception):
    """Base class of every error raised by drake_cfvol."""


class WorkcellError(CfvolError):
    """A workcell file or model cannot be loaded or is inconsistent."""


class UnknownCellError(WorkcellError):
    """A cell name is neither built in nor a path to a YAML file."""

    def __init__(self, name: str, known: Iterable[str]):
        self.name = name
        self.known = sorted(known)
        super().__init__(
            f"Unknown cell '{name}'. Built-in cells: {', '.join(self.known)}. "
            "Pass one of those names or the path to your own workcell YAML file."
        )


class WorkcellFileNotFoundError(UnknownCellError):
    """A workcell given as a file path does not exist."""

    def __init__(self, path: str, known: Iterable[str]):
        self.name = str(path)
        self.known = sorted(known)
        CfvolError.__init__(
            self,
            f"workcell file '{path}' does not exist. Check the path (relative paths start from the current "
            f"folder), or use a built-in cell: {', '.join(self.known)}.",
        )


class WorkcellFormatError(WorkcellError):
    """A workcell YAML file is malformed."""

    def __init__(self, path: str, message: str, line: int | None = None):
        self.path = str(path)
        self.line = line
        where = f"{self.path}, line {line}" if line is not None else self.path
        super().__init__(f"{where}: {message}")


class StationError(WorkcellError):
    """A user's RobotDiagram cannot become a workcell
    (:meth:`drake_cfvol.Workcell.FromRobotDiagram`), or a system cannot be
    added to a user's station (:func:`drake_cfvol.systems.AddCoManipulation`)."""


class ConfigurationError(CfvolError):
    """A joint configuration is invalid for the robot."""


class DimensionError(ConfigurationError, ValueError):
    """An array has the wrong length or shape."""

    def __init__(self, what: str, expected: int | Sequence[int] | str, got: object, hint: str = ""):
        self.expected = expected
        self.got = got
        msg = f"{what} has the wrong size: expected {expected}, got {got}."
        if hint:
            msg += " " + hint
        super().__init__(msg)


class JointLimitError(ConfigurationError, ValueError):
    """A configuration lies outside the robot's position limits."""

    def __init__(self, what: str, joint: str, value: float, lower: float, upper: float):
        self.joint = joint
        self.value = value
        self.lower = lower
        self.upper = upper
        super().__init__(
            f"{what}: joint '{joint}' = {value:.6g} is outside its limits "
            f"[{lower:.6g}, {upper:.6g}]. Move it inside the limits (radians for "
            "revolute joints, metres for prismatic ones)."
        )


class MissingJointLimitsError(ConfigurationError):
    """A joint has no finite position limits where limits are needed."""

    def __init__(self, joints: Sequence[str], needed_for: str):
        self.joints = list(joints)
        super().__init__(
            f"{needed_for} needs finite position limits, but joint(s) "
            f"{', '.join(repr(j) for j in self.joints)} have none. Add <limit "
            "lower=... upper=...> to the model, or set them in the workcell's "
            "'cfvol: joint_limits: {joint: [lower, upper]}'."
        )


class CollisionError(ConfigurationError):
    """A configuration that must be free is in collision."""

    def __init__(self, what: str, pairs: Sequence[tuple[str, str]]):
        self.pairs = list(pairs)
        listed = ", ".join(f"{a} <-> {b}" for a, b in self.pairs) or "(unknown bodies)"
        super().__init__(
            f"{what} is in collision: {listed}. Choose a collision-free configuration or move the obstacle."
        )


class SingularityError(ConfigurationError):
    """A configuration is at (or too near) a kinematic singularity."""


class PlanningError(CfvolError):
    """No nominal path could be planned."""


class ParameterError(CfvolError, ValueError):
    """A method parameter is invalid."""


class FileError(CfvolError, OSError):
    """A file cannot be read or written (missing, unreadable, not ours)."""


class RecordFormatError(FileError, ValueError):
    """A saved path or bounds file is empty, truncated or of another kind."""

    def __init__(self, path: str | os.PathLike[str], what: str, reason: str):
        self.path = str(path)
        super().__init__(
            f"cannot read {what} file '{path}': {reason}. Expected a file written by drake_cfvol "
            f"({what} .npz or .json); write it again with its save() or the cfvol command."
        )


class OutputExistsError(FileError, FileExistsError):
    """An output file exists and overwriting was not allowed."""


class OutputPathError(FileError):
    """An output file or folder cannot be created."""

    def __init__(self, path: str | os.PathLike[str], reason: str):
        self.path = str(path)
        super().__init__(f"cannot write '{path}': {reason}. Choose a folder you can write to (--out).")


class ScenarioError(CfvolError, ValueError):
    """A co-manipulation scenario file or value is invalid: the file, the
    field (None: the file as a whole), what is wrong and the fix, and the
    field's line in the file where it is known."""

    def __init__(self, file: str | os.PathLike[str], field: str | None, message: str, line: int | None = None):
        self.file = str(file)
        self.field = field
        self.detail = message
        self.line = line
        if line is not None:
            where = f"{file}, line {line}: " + (f"field '{field}'" if field else f"the {self.what}")
        else:
            where = f"{file}: field '{field}'" if field else f"{self.what} '{file}'"
        super().__init__(f"{where} {message}.")

    what = "scenario"


class BatchError(ScenarioError):
    """A batch's jobs file (``cfvol batch JOBS.yaml``) or a job is invalid,
    or the batch cannot run (no Dask, an unreachable scheduler)."""

    what = "jobs file"
