"""drake_cfvol: collision-free deformation volumes around a robot's nominal
path, as Drake systems.

Public API (re-exported here): :func:`load_workcell`, :func:`plan_nominal_path`,
:class:`NominalPath`, :func:`estimate_bounds`, :class:`BoundsTable`,
:class:`Certify`, :class:`VolumeParams`, :func:`confidence_factor`,
:func:`freedom`, and the exception hierarchy rooted at :class:`CfvolError`.

Subpackages, in pipeline order; each imports only from those before it (and
from ``exceptions`` and ``_version``, which import nothing of the package);
``tests/test_architecture.py`` checks the directions:

1. ``io``: records on disk, progress bars, plotting, colours;
2. ``kernel``: the compiled collision kernel (plain arrays only);
3. ``scene``: workcell files, the Drake scene, its arrays for the kernel,
   meshes, the method's parameters;
4. ``algorithm``: planning (RRT-Connect), the height map and the volume V,
   the sweep (joint bounding), the bounds table, the Drake reference
   backend, CF and freedom, and the pipeline (Algorithm 1:
   ``estimate_bounds``); beyond the paper, the certificate and its
   boundary proof (``algorithm.certificate``);
5. ``online``: bounds that follow a changing cell: the obstacle map from a
   depth camera's points and the volume and bounds re-estimated from it,
   incrementally (SPEC 12);
6. ``systems``: the Drake systems (bounds source, path progress, admittance,
   the runtime safety filter, moving boxes, the cell camera, the online
   estimator) and their builder helpers;
7. ``comanip``: co-manipulation scenarios, diagrams, runs, recordings and
   the adversarial runs;
8. ``apps``: the ``cfvol`` command line and the demo.

The benchmark harness (the paper's tables) lives outside the library, in
``benchmarks/`` of a development checkout.
"""

import importlib

from drake_cfvol._version import __version__
from drake_cfvol.exceptions import (
    BatchError,
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
    StationError,
    UnknownCellError,
    WorkcellError,
    WorkcellFileNotFoundError,
    WorkcellFormatError,
)

#: The public names that need Drake, each with its module: imported on first
#: use (PEP 562), so ``import drake_cfvol`` and ``cfvol --help`` load no pydrake.
_LAZY = {
    "Certify": "drake_cfvol.algorithm.certificate.certify",
    "CFResult": "drake_cfvol.algorithm.metrics",
    "Freedom": "drake_cfvol.algorithm.metrics",
    "confidence_factor": "drake_cfvol.algorithm.metrics",
    "freedom": "drake_cfvol.algorithm.metrics",
    "estimate_bounds": "drake_cfvol.algorithm.pipeline",
    "NominalPath": "drake_cfvol.algorithm.planning",
    "plan_nominal_path": "drake_cfvol.algorithm.planning",
    "BoundsTable": "drake_cfvol.algorithm.table",
    "VolumeParams": "drake_cfvol.scene.params",
    "AddModels": "drake_cfvol.scene.urdf",
    "Workcell": "drake_cfvol.scene.workcell",
    "builtin_cells": "drake_cfvol.scene.workcell",
    "load_workcell": "drake_cfvol.scene.workcell",
}

#: The subpackages, reachable as attributes as before (imported on first use).
_SUBPACKAGES = ("io", "kernel", "scene", "algorithm", "online", "systems", "comanip", "apps")


def __getattr__(name: str):
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value  # later lookups skip this function
        return value
    if name in _SUBPACKAGES:
        return importlib.import_module(f"drake_cfvol.{name}")
    raise AttributeError(f"module 'drake_cfvol' has no attribute {name!r}")


def __dir__() -> list:
    return sorted(set(globals()) | set(_LAZY) | set(_SUBPACKAGES))


__all__ = [
    "__version__",
    "CfvolError",
    "CollisionError",
    "ConfigurationError",
    "DimensionError",
    "JointLimitError",
    "MissingJointLimitsError",
    "ParameterError",
    "PlanningError",
    "SingularityError",
    "UnknownCellError",
    "WorkcellError",
    "WorkcellFileNotFoundError",
    "WorkcellFormatError",
    "FileError",
    "RecordFormatError",
    "OutputExistsError",
    "OutputPathError",
    "ScenarioError",
    "BatchError",
    "StationError",
    "NominalPath",
    "plan_nominal_path",
    "Workcell",
    "AddModels",
    "builtin_cells",
    "load_workcell",
    "BoundsTable",
    "estimate_bounds",
    "Certify",
    "VolumeParams",
    "CFResult",
    "Freedom",
    "confidence_factor",
    "freedom",
]
