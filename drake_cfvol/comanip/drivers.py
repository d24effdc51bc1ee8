"""The drivers a dynamic run's scenario may name for its robot
(``simulation.model_drivers``; YAML tags): Drake's ``IiwaDriver`` and the
package's own, which Drake's driver configs lack."""

import dataclasses
import typing

from pydrake.manipulation import IiwaDriver

# Drake's typed YAML reads these classes' annotations as types (no postponed annotations here).
__all__ = ["DriverConfig", "FrankaDriver", "InverseDynamicsDriver", "TORQUE_SENSING_DRIVERS"]


@dataclasses.dataclass
class InverseDynamicsDriver:
    """A dynamic run's robot under Drake's ``InverseDynamicsController``
    (``simulation: {model_drivers: {robot: !InverseDynamicsDriver {...}}}``):
    per joint, the desired acceleration is kp (q_d - q) + kd (v_d - v) + ki
    (its integral), mapped through the robot's own inverse dynamics.

    Attributes:
        kp: 1/s^2; kd: 1/s; ki: 1/s^3.
    """

    kp: float = 10000.0
    kd: float = 200.0
    ki: float = 0.0


@dataclasses.dataclass
class FrankaDriver:
    """A dynamic run's Franka arm over drake-franka-driver's LCM
    (``simulation: {model_drivers: {robot: !FrankaDriver {...}}}``; Drake's
    driver configs have no Panda entry): the controller talks to a
    simulated station over an in-memory LCM as it would to the driver
    (:mod:`drake_cfvol.comanip.franka`), the co-worker's hand pushes the
    tool through contact, and a status watchdog holds the safety filter's
    command. The command is sent every millisecond (Franka's rate): give
    ``control.period: 0.001``.

    Attributes:
        control_mode: ``position`` or ``velocity`` (the driver's
            ``--control_mode``).
        kp: 1/s^2; kd: 1/s: the simulated arm's tracking gains (its
            ``InverseDynamicsController``'s, standing in for Franka's joint
            impedance).
    """

    control_mode: str = "position"
    kp: float = InverseDynamicsDriver.kp
    kd: float = InverseDynamicsDriver.kd


#: The drivers a scenario's ``model_drivers`` may name (YAML tags).
DriverConfig = typing.Union[InverseDynamicsDriver, IiwaDriver, FrankaDriver]

#: Drivers of arms that sense the co-worker's push as joint torque (through
#: the hand's contact), as a real torque-sensing arm does.
TORQUE_SENSING_DRIVERS = (IiwaDriver, FrankaDriver)
