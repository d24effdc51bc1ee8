"""The runtime safety filter between the admittance and the robot (SPEC 9; its theory: docs/safety.md).

- :mod:`.safety`: the system, :class:`SafetyFilter`, and its settings (:class:`SafetyFilterConfig`).
- :mod:`.constraints`: the constraint interface (:class:`FilterConstraint`: rows A v >= b with a
  priority) and the filter's constraints, and the staged QP over them (:class:`PriorityQP`).
- :mod:`.damper`: the velocity damper's geometry (:class:`VelocityDamper`); its compiled rows
  (:mod:`.damper_kernel`), kinematics (:mod:`.damper_kinematics`) and parts (:mod:`.damper_parts`).
- :mod:`.qp`: the dense QP solver (:func:`solve_qp`).
- :mod:`.filter_kernel`: the compiled update, one call per step.
- :mod:`.compile_ahead`: its compiled parts compiled before a run needs them (:func:`~.compile_ahead.warm_up`).

The compiled modules' names (shape kinds, row kinds) stay in their modules. Imports the
systems' shared helpers (``_util``, ``columns``), ``scene``, ``kernel`` and the base only.
"""

from drake_cfvol.systems.filter.constraints import (
    BOX,
    HARD,
    ROW,
    STOP,
    ConstraintRows,
    DamperConstraint,
    FilterConstraint,
    FilterStep,
    JointBox,
    PriorityQP,
    StopRows,
    ToolSpeedLimit,
    VelocityLimits,
    solve_rounds,
)
from drake_cfvol.systems.filter.damper import DamperRows, VelocityDamper
from drake_cfvol.systems.filter.qp import QP_FAILED, QP_INFEASIBLE, QP_OPTIMAL, solve_qp
from drake_cfvol.systems.filter.safety import FAULTS, SafetyFilter, SafetyFilterConfig

# The system, the constraint interface and its constraints, the damper, the QP.
__all__ = [
    "SafetyFilter",
    "SafetyFilterConfig",
    "FAULTS",
    "FilterConstraint",
    "ConstraintRows",
    "FilterStep",
    "VelocityLimits",
    "JointBox",
    "DamperConstraint",
    "StopRows",
    "ToolSpeedLimit",
    "HARD",
    "ROW",
    "STOP",
    "BOX",
    "PriorityQP",
    "solve_rounds",
    "DamperRows",
    "VelocityDamper",
    "solve_qp",
    "QP_OPTIMAL",
    "QP_INFEASIBLE",
    "QP_FAILED",
]
