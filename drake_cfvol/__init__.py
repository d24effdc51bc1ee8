"""drake_cfvol: collision-free deformation volumes around a robot's nominal
path, as Drake systems.

Public API (re-exported here): :func:`load_workcell`, :func:`plan_nominal_path`,
:class:`NominalPath`, :func:`estimate_bounds`, :class:`BoundsTable`,
:class:`VolumeParams`, :func:`confidence_factor`, :func:`freedom`, and the
exception hierarchy rooted at :class:`CfvolError`.
"""

from drake_cfvol.exceptions import (
    CfvolError,
    CollisionError,
    ConfigurationError,
    DimensionError,
    JointLimitError,
    MissingJointLimitsError,
    ParameterError,
    PlanningError,
    SingularityError,
    UnknownCellError,
    WorkcellError,
    WorkcellFormatError,
)
from drake_cfvol.bounds import BoundsTable, estimate_bounds
from drake_cfvol.metrics import CFResult, Freedom, confidence_factor, freedom
from drake_cfvol.params import VolumeParams
from drake_cfvol.planning import NominalPath, plan_nominal_path
from drake_cfvol.workcell import Workcell, builtin_cells, load_workcell

__version__ = "0.1.0"

__all__ = [
    "CfvolError", "CollisionError", "ConfigurationError", "DimensionError", "JointLimitError",
    "MissingJointLimitsError", "ParameterError", "PlanningError", "SingularityError",
    "UnknownCellError", "WorkcellError", "WorkcellFormatError",
    "NominalPath", "plan_nominal_path", "Workcell", "builtin_cells", "load_workcell",
    "BoundsTable", "estimate_bounds", "VolumeParams", "CFResult", "Freedom", "confidence_factor", "freedom",
]
