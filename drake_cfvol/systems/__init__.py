"""Drake systems for co-manipulation runs (SPEC 9).

- :class:`JointBoundsSource`: the bounds table as a system of the path index.
- :class:`AdmittanceDeformation`: the human's push -> a deviation from the
  nominal, clamped inside the bounds without wind-up.
- :class:`HumanInputCheck`: the sensed push checked for plausibility; a
  fault holds the admittance's last safe command.
- :class:`SafetyFilter` (the subpackage :mod:`drake_cfvol.systems.filter`): between the
  admittance and the robot, the motion closest to the one asked for that
  keeps the velocity limits, the box ahead and a clearance margin (a
  velocity damper on the SceneGraph's signed distances); its constraints
  (:class:`FilterConstraint`: rows with a priority; :class:`ToolSpeedLimit`
  for the tool's Cartesian speed).
- :class:`PathProgress`: the path index over time.
- :class:`ScriptedHuman`: pushes with set magnitude, direction and timing.
- :class:`RandomPushShaper`: random pushes from Drake's ``RandomSource``
  (seeded through the context).
- :class:`ReactiveCoworker`: a person reacting to the robot's position.
- :class:`ClearanceMonitor`: clearance, collision and volume contact, through
  a SceneGraph's query port.
- :class:`MovingBoxes`: boxes moving through the cell (a SceneGraph source).
- :func:`AddCellCamera`: an overhead depth camera and its
  :class:`ObstacleMapper` (points -> an obstacle height map, the robot and
  the known cell filtered out); :class:`PerceivedColumns`: the map as
  proximity geometry for the safety filter.
- :class:`OnlineBoundsEstimator`: the bounds re-estimated from the map,
  published to :class:`JointBoundsSource`'s ``bounds`` input.
- :func:`AddCoManipulation`: all of the above a station needs, added to a
  user's own builder and wired to its plant and SceneGraph, its gains and
  limits a :class:`CoManipulationConfig` (each system's own config:
  :class:`AdmittanceConfig`, :class:`SafetyFilterConfig`,
  :class:`PathProgressConfig`; the camera's :class:`PerceptionConfig`, the
  online bounds' :class:`OnlineBoundsConfig`);
  :class:`ToolPushForce`: a push at the tool as a real force on a plant.
- :class:`StatusWatchdog`: a fault when the robot's status goes stale
  (wired to the safety filter's ``hold``).

One system per module. Imports ``online``, ``algorithm`` (the bounds table), ``scene``,
``kernel`` and ``io`` only.
"""

from drake_cfvol.systems.admittance import AdmittanceConfig, AdmittanceDeformation, AdmittanceDeformation_
from drake_cfvol.systems.bounds_source import JointBoundsSource, JointBoundsSource_
from drake_cfvol.systems.columns import PerceivedColumns
from drake_cfvol.systems.filter import FilterConstraint, SafetyFilter, SafetyFilterConfig, ToolSpeedLimit
from drake_cfvol.systems.human_input import HumanInputCheck, HumanInputCheck_
from drake_cfvol.systems.humans import Push, RandomPushes, RandomPushShaper, Reactive, ReactiveCoworker, ScriptedHuman
from drake_cfvol.systems.monitor import ClearanceMonitor
from drake_cfvol.systems.moving_boxes import MovingBoxes, MovingObstacle
from drake_cfvol.systems.online_bounds import OnlineBoundsConfig, OnlineBoundsEstimator
from drake_cfvol.systems.path import PathProgress, PathProgressConfig, path_ramp, safe_path_rate
from drake_cfvol.systems.perception import (
    AddCellCamera,
    AddCellModel,
    CellCamera,
    CellModel,
    ObstacleMapper,
    PerceptionConfig,
)
from drake_cfvol.systems.station import AddCoManipulation, CoManipulationConfig, CoManipulationSystems, ToolPushForce
from drake_cfvol.systems.watchdog import StatusWatchdog

__all__ = [
    "JointBoundsSource",
    "JointBoundsSource_",
    "AdmittanceDeformation",
    "AdmittanceDeformation_",
    "PathProgress",
    "Push",
    "ScriptedHuman",
    "ClearanceMonitor",
    "HumanInputCheck",
    "HumanInputCheck_",
    "RandomPushShaper",
    "ReactiveCoworker",
    "SafetyFilter",
    "path_ramp",
    "safe_path_rate",
    "AddCoManipulation",
    "CoManipulationSystems",
    "ToolPushForce",
    "MovingBoxes",
    "MovingObstacle",
    "PerceivedColumns",
    "OnlineBoundsEstimator",
    "AddCellCamera",
    "AddCellModel",
    "CellCamera",
    "CellModel",
    "ObstacleMapper",
    "RandomPushes",
    "Reactive",
    "AdmittanceConfig",
    "SafetyFilterConfig",
    "PathProgressConfig",
    "PerceptionConfig",
    "OnlineBoundsConfig",
    "CoManipulationConfig",
    "FilterConstraint",
    "ToolSpeedLimit",
    "StatusWatchdog",
]
