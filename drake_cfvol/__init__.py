"""drake_cfvol: collision-free deformation volumes around a robot's nominal
path, as Drake systems.

Public API (re-exported here): :func:`load_workcell`, :func:`plan_nominal_path`,
:class:`NominalPath`, :func:`estimate_bounds`, :class:`BoundsTable`,
:class:`Certify`, :class:`VolumeParams`, :func:`confidence_factor`,
:func:`freedom`, and the exception hierarchy rooted at :class:`CfvolError`.

Layers (each module imports only from the layers below it; a test checks):

1. data and settings: ``exceptions``, ``params``, ``style``, ``_records``,
   ``kernel`` (the compiled collision kernel, plain arrays only),
   ``heightmap`` (height map, eq. 1, the volume V), ``table`` (BoundsTable,
   the box-at-s rule);
2. geometry and the scene: ``geometry`` (the robot chain and shapes as
   kernel arrays, read from Drake), ``workcell`` (typed workcell files, Drake
   scene, its cached arrays and distance queries);
3. algorithm steps: ``planning`` (RRT-Connect), ``volume`` (categorization,
   growing V), ``sweep`` (joint bounding), ``reference`` (Drake backend),
   ``metrics`` (CF, freedom), ``certify``;
4. the orchestrator: ``pipeline`` (Algorithm 1: ``estimate_bounds``);
5. Drake systems and runs: ``systems``, ``safety`` (the runtime safety
   filter), ``viz``, ``comanip``;
6. front ends: ``demo``, ``bench``, ``cli``.
"""

from drake_cfvol._version import __version__
from drake_cfvol.certify import Certify
from drake_cfvol.exceptions import (
    CfvolError,
    CollisionError,
    ConfigurationError,
    DimensionError,
    FileError,
    JointLimitError,
    MissingJointLimitsError,
    OutputExistsError,
    OutputPathError,
    ParameterError,
    PlanningError,
    RecordFormatError,
    ScenarioError,
    SingularityError,
    UnknownCellError,
    WorkcellError,
    WorkcellFileNotFoundError,
    WorkcellFormatError,
)
from drake_cfvol.metrics import CFResult, Freedom, confidence_factor, freedom
from drake_cfvol.params import VolumeParams
from drake_cfvol.pipeline import estimate_bounds
from drake_cfvol.planning import NominalPath, plan_nominal_path
from drake_cfvol.table import BoundsTable
from drake_cfvol.workcell import Workcell, builtin_cells, load_workcell

__all__ = [
    "__version__",
    "CfvolError", "CollisionError", "ConfigurationError", "DimensionError", "JointLimitError",
    "MissingJointLimitsError", "ParameterError", "PlanningError", "SingularityError",
    "UnknownCellError", "WorkcellError", "WorkcellFileNotFoundError", "WorkcellFormatError", "FileError",
    "RecordFormatError", "OutputExistsError", "OutputPathError", "ScenarioError",
    "NominalPath", "plan_nominal_path", "Workcell", "builtin_cells", "load_workcell",
    "BoundsTable", "estimate_bounds", "Certify", "VolumeParams", "CFResult", "Freedom", "confidence_factor", "freedom",
]
