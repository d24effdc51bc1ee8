"""A Franka arm over drake-franka-driver's LCM: the co-manipulation
controller's side of the interface (Drake's ``PandaCommandSender`` and
``PandaStatusReceiver``, a position or velocity command, the status
watchdog and its hold) and a simulated station that answers it as the
driver does, for runs and tests over an in-memory LCM
(``DrakeLcm("memq://")``, a loopback). On the robot the controller side is
the same and the bus is the robot's network.

Drake has no simulated Panda driver for ``ApplyDriverConfigs``, so the
station is made of small Drake systems here: the command is decoded by
Drake's ``PandaCommandReceiver`` into the plant's desired state (in velocity
mode the commanded velocity is integrated, as Franka's joint impedance
controller tracks it), an ``InverseDynamicsController`` on the robot alone
tracks it, and Drake's ``PandaStatusSender`` reports the plant's state,
the controller's torque and the contact forces on the arm (filtered, as
Franka's ``tau_ext_hat_filtered`` is) at Franka's 1 kHz.

drake-franka-driver refuses a command whose ``control_mode_expected`` is
not its mode, or that carries the other mode's vector; the controller side
sends exactly one of them (``PandaCommandSender`` with one mode bit).
"""

from __future__ import annotations

import typing

import numpy as np
from drake import lcmt_panda_command, lcmt_panda_status
from pydrake.lcm import DrakeLcm
from pydrake.manipulation import (
    PandaCommandReceiver,
    PandaCommandSender,
    PandaControlMode,
    PandaStatusReceiver,
    PandaStatusSender,
)
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import ModelInstanceIndex
from pydrake.systems.controllers import InverseDynamicsController
from pydrake.systems.framework import DiagramBuilder, LeafSystem, OutputPort
from pydrake.systems.lcm import LcmInterfaceSystem, LcmPublisherSystem, LcmSubscriberSystem
from pydrake.systems.primitives import (
    ConstantVectorSource,
    Demultiplexer,
    FirstOrderLowPassFilter,
    MatrixGain,
    StateInterpolatorWithDiscreteDerivative,
)

from drake_cfvol.comanip.drivers import InverseDynamicsDriver
from drake_cfvol.comanip.robot_status import add_lcm_controller, add_status_watchdog, publish_on_lcm, subscribe_on_lcm
from drake_cfvol.exceptions import ParameterError
from drake_cfvol.scene.robot import RobotSlice
from drake_cfvol.systems.station import CoManipulationConfig, CoManipulationSystems
from drake_cfvol.systems.watchdog import StatusWatchdog

__all__ = [
    "FRANKA_PERIOD",
    "PANDA_COMMAND_CHANNEL",
    "PANDA_STATUS_CHANNEL",
    "EXTERNAL_TORQUE_TIME_CONSTANT",
    "FrankaInterface",
    "FrankaStation",
    "VelocityCommandIntegrator",
    "add_franka_controller",
    "add_franka_controller_interface",
    "add_franka_station",
    "panda_control_mode",
]

#: Franka's real-time interface period, s (1 kHz): the status's and the command's.
FRANKA_PERIOD = 0.001

#: drake-franka-driver's default channels.
PANDA_COMMAND_CHANNEL = "PANDA_COMMAND"
PANDA_STATUS_CHANNEL = "PANDA_STATUS"

#: The simulated external torque's low-pass time constant, s (Drake's
#: simulated iiwa driver filters its estimate the same way).
EXTERNAL_TORQUE_TIME_CONSTANT = 0.01

_MODES = {"position": PandaControlMode.kPosition, "velocity": PandaControlMode.kVelocity}


def panda_control_mode(mode: str | int) -> int:
    """Drake's ``PandaControlMode`` bit for ``"position"`` or ``"velocity"``
    (or the bit itself).

    Raises:
        ParameterError: any other mode (torque control is not offered: the
            safety filter commands positions).
    """
    if isinstance(mode, str) and mode in _MODES:
        return _MODES[mode]
    if not isinstance(mode, str) and mode in _MODES.values():
        return int(mode)
    raise ParameterError(
        f"Franka control mode: got {mode!r}; give 'position' or 'velocity' (PandaControlMode.kPosition or kVelocity)."
    )


class VelocityCommandIntegrator(LeafSystem):
    """The desired state of a velocity-commanded arm: the commanded velocity
    integrated every ``period`` from the measured position at the start,
    beside the velocity itself. Franka's joint impedance controller tracks
    a velocity command this way; a PD tracker of the plant then follows
    ``desired_state``.

    .. pydrake_system::

        name: VelocityCommandIntegrator
        input_ports:
        - velocity
        - position_measured
        output_ports:
        - desired_state

    Args:
        k: number of joints.
        period: the integration step, s (the driver's period).
    """

    def __init__(self, k: int, period: float):
        super().__init__()
        if not (np.isfinite(period) and period > 0):
            raise ParameterError(f"VelocityCommandIntegrator: period must be finite and > 0 s, got {period}.")
        self.period = float(period)
        self.velocity_input = self.DeclareVectorInputPort(name="velocity", size=k)
        self.position_measured_input = self.DeclareVectorInputPort(name="position_measured", size=k)
        self._position = self.DeclareDiscreteState(k)
        self.DeclareInitializationDiscreteUpdateEvent(self._latch)
        self.DeclarePeriodicDiscreteUpdateEvent(period_sec=self.period, offset_sec=0.0, update=self._step)
        self.desired_state_output = self.DeclareVectorOutputPort(
            name="desired_state",
            size=2 * k,
            calc=self._calc,
            prerequisites_of_calc={self.xd_ticket(), self.velocity_input.ticket()},
        )

    def _latch(self, context, discrete_state) -> None:
        discrete_state.get_mutable_vector(self._position).SetFromVector(self.position_measured_input.Eval(context))

    def _step(self, context, discrete_state) -> None:
        q = context.get_discrete_state(self._position).CopyToVector()
        discrete_state.get_mutable_vector(self._position).SetFromVector(
            q + self.period * np.asarray(self.velocity_input.Eval(context))
        )

    def _calc(self, context, output) -> None:
        q = context.get_discrete_state(self._position).CopyToVector()
        output.SetFromVector(np.concatenate([q, self.velocity_input.Eval(context)]))


class FrankaStation(typing.NamedTuple):
    """What :func:`add_franka_station` added."""

    command_subscriber: LcmSubscriberSystem
    command_receiver: PandaCommandReceiver
    desired_state: OutputPort  # (2k) the plant's desired state, decoded from the command
    controller: InverseDynamicsController
    status_sender: PandaStatusSender
    status_publisher: LcmPublisherSystem


def add_franka_station(
    builder: DiagramBuilder,
    *,
    plant: MultibodyPlant,
    robot: ModelInstanceIndex,
    controller_plant: MultibodyPlant,
    lcm: DrakeLcm,
    control_mode: str | int = "position",
    kp: float = InverseDynamicsDriver.kp,
    kd: float = InverseDynamicsDriver.kd,
    command_channel: str = PANDA_COMMAND_CHANNEL,
    status_channel: str = PANDA_STATUS_CHANNEL,
    prefix: str = "",
) -> FrankaStation:
    """The simulated side of drake-franka-driver: the arm ``robot`` of the
    finalized time-stepping ``plant`` commanded over ``lcm`` and reporting
    its status there every :data:`FRANKA_PERIOD`.

    The ``lcmt_panda_command`` on ``command_channel`` is decoded by Drake's
    ``PandaCommandReceiver`` (holding the measured start until the first
    message) into the desired state: the commanded position with its
    discrete derivative, or the commanded velocity integrated
    (:class:`VelocityCommandIntegrator`). An ``InverseDynamicsController``
    on ``controller_plant`` (the robot alone, every joint actuated) tracks
    it, applied as generalized forces on the robot's joints. The
    ``lcmt_panda_status`` (Drake's ``PandaStatusSender``) holds the plant's
    position and velocity, the desired state, the controller's torque and
    the contact forces on the arm's joints, low-pass filtered
    (:data:`EXTERNAL_TORQUE_TIME_CONSTANT`), as its external torque. An
    ``LcmInterfaceSystem`` on ``lcm`` is added (``{prefix}lcm_interface``)
    unless the builder has one of that name.

    Args:
        kp, kd: the tracking gains per joint, 1/s^2 and 1/s (by default
            :class:`~drake_cfvol.comanip.scenario.InverseDynamicsDriver`'s,
            critically damped; a stand-in for Franka's joint impedance).
        control_mode: ``"position"`` or ``"velocity"`` (the driver's
            ``--control_mode``), or Drake's ``PandaControlMode`` bit.
        prefix: prefix of the added systems' names.

    Returns:
        The :class:`FrankaStation`.
    """
    mode = panda_control_mode(control_mode)
    rs = RobotSlice(plant, robot)
    k = rs.k
    if not builder.HasSubsystemNamed(f"{prefix}lcm_interface"):
        builder.AddNamedSystem(f"{prefix}lcm_interface", LcmInterfaceSystem(lcm))
    measured = builder.AddNamedSystem(f"{prefix}franka_measured_state", Demultiplexer([k, k]))
    builder.Connect(plant.get_state_output_port(robot), measured.get_input_port())
    receiver = builder.AddNamedSystem(f"{prefix}panda_command_receiver", PandaCommandReceiver(k, mode))
    subscriber = subscribe_on_lcm(
        builder,
        receiver.get_message_input_port(),
        name=f"{prefix}panda_command_subscriber",
        channel=command_channel,
        lcm_type=lcmt_panda_command,
        lcm=lcm,
    )
    builder.Connect(measured.get_output_port(0), receiver.get_position_measured_input_port())
    if mode == PandaControlMode.kPosition:
        desired = builder.AddNamedSystem(
            f"{prefix}franka_desired_state",
            StateInterpolatorWithDiscreteDerivative(k, FRANKA_PERIOD, suppress_initial_transient=True),
        )
        builder.Connect(receiver.get_commanded_position_output_port(), desired.get_input_port())
    else:
        desired = builder.AddNamedSystem(f"{prefix}franka_desired_state", VelocityCommandIntegrator(k, FRANKA_PERIOD))
        builder.Connect(receiver.get_commanded_velocity_output_port(), desired.velocity_input)
        builder.Connect(measured.get_output_port(0), desired.position_measured_input)
    desired_state = desired.get_output_port()
    controller = builder.AddNamedSystem(
        f"{prefix}franka_controller",
        InverseDynamicsController(
            controller_plant, kp=[kp] * k, ki=[0.0] * k, kd=[kd] * k, has_reference_acceleration=False
        ),
    )
    builder.Connect(desired_state, controller.get_input_port_desired_state())
    builder.Connect(plant.get_state_output_port(robot), controller.get_input_port_estimated_state())
    select = np.zeros((plant.num_velocities(), k))
    select[rs.vidx, np.arange(k)] = 1.0
    to_plant = builder.AddNamedSystem(f"{prefix}franka_joint_forces", MatrixGain(select))
    builder.Connect(controller.get_output_port_control(), to_plant.get_input_port())
    builder.Connect(to_plant.get_output_port(), plant.get_applied_generalized_force_input_port())
    if plant.num_actuated_dofs() > 0:  # the arm is driven by the generalized forces above
        idle = builder.AddNamedSystem(
            f"{prefix}franka_no_actuation", ConstantVectorSource(np.zeros(plant.num_actuated_dofs()))
        )
        builder.Connect(idle.get_output_port(), plant.get_actuation_input_port())
    status = _add_status_sender(builder, plant, robot, k, measured, desired_state, controller, prefix)
    publisher = publish_on_lcm(
        builder,
        status.get_output_port(),
        name=f"{prefix}panda_status_publisher",
        channel=status_channel,
        lcm_type=lcmt_panda_status,
        lcm=lcm,
        period=FRANKA_PERIOD,
    )
    return FrankaStation(subscriber, receiver, desired_state, controller, status, publisher)


def _add_status_sender(builder, plant, robot, k: int, measured, desired_state, controller, prefix: str):
    """Drake's ``PandaStatusSender`` fed the plant's state, the desired
    state, the controller's torque and the filtered contact forces."""
    status = builder.AddNamedSystem(f"{prefix}panda_status_sender", PandaStatusSender(k))
    split = builder.AddNamedSystem(f"{prefix}franka_desired_split", Demultiplexer([k, k]))
    builder.Connect(desired_state, split.get_input_port())
    builder.Connect(split.get_output_port(0), status.get_position_commanded_input_port())
    builder.Connect(split.get_output_port(1), status.get_velocity_commanded_input_port())
    builder.Connect(measured.get_output_port(0), status.get_position_measured_input_port())
    builder.Connect(measured.get_output_port(1), status.get_velocity_measured_input_port())
    builder.Connect(controller.get_output_port_control(), status.get_torque_commanded_input_port())
    external = builder.AddNamedSystem(
        f"{prefix}franka_external_torque", FirstOrderLowPassFilter(EXTERNAL_TORQUE_TIME_CONSTANT, k)
    )
    builder.Connect(plant.get_generalized_contact_forces_output_port(robot), external.get_input_port())
    builder.Connect(external.get_output_port(), status.get_torque_external_input_port())
    return status


class FrankaInterface(typing.NamedTuple):
    """What :func:`add_franka_controller_interface` added."""

    command_sender: PandaCommandSender
    command_publisher: LcmPublisherSystem
    status_receiver: PandaStatusReceiver
    watchdog: StatusWatchdog


def add_franka_controller_interface(
    builder: DiagramBuilder,
    *,
    lcm: DrakeLcm,
    desired_state: OutputPort,
    control_mode: str | int = "position",
    num_joints: int = 7,
    safety=None,
    status_timeout: float | None = None,
    command_channel: str = PANDA_COMMAND_CHANNEL,
    status_channel: str = PANDA_STATUS_CHANNEL,
    prefix: str = "",
) -> FrankaInterface:
    """The controller's side of drake-franka-driver's LCM interface: the
    desired state's position (position mode) or velocity (velocity mode)
    sent as ``lcmt_panda_command`` on ``command_channel`` every
    :data:`FRANKA_PERIOD`, with the matching ``control_mode_expected``; the
    ``lcmt_panda_status`` received on ``status_channel`` (Drake's
    ``PandaStatusReceiver``: ``position_measured``, ``velocity_measured``,
    ``torque_external``, ...). A :class:`~drake_cfvol.systems.StatusWatchdog`
    (``{prefix}status_watchdog``) on the status raises its fault while no
    new status has come for ``status_timeout`` (default three periods),
    which holds the ``safety`` filter's last command; the held command's
    velocity is zero, so a velocity-mode arm stops.

    The command holds the desired state between the controller's updates:
    give the controller Franka's period (1 ms), since the arm's interface
    refuses a position command that jumps.

    Args:
        lcm: the LCM instance (a ``LcmInterfaceSystem`` on it must be in
            the diagram, as :func:`add_franka_station` adds).
        desired_state: the desired state's port (2 ``num_joints``; the
            safety filter's ``desired_state``).
        control_mode: ``"position"`` or ``"velocity"``, or Drake's
            ``PandaControlMode`` bit.
        safety: the :class:`~drake_cfvol.systems.SafetyFilter` the watchdog
            holds, or None (its fault only reported).
        prefix: prefix of the added systems' names.

    Returns:
        The :class:`FrankaInterface`.
    """
    mode = panda_control_mode(control_mode)
    k = num_joints
    split = builder.AddNamedSystem(f"{prefix}franka_desired_command", Demultiplexer([k, k]))
    builder.Connect(desired_state, split.get_input_port(0))
    sender = builder.AddNamedSystem(f"{prefix}panda_command_sender", PandaCommandSender(k, mode))
    if mode == PandaControlMode.kPosition:
        builder.Connect(split.get_output_port(0), sender.get_position_input_port())
    else:
        builder.Connect(split.get_output_port(1), sender.get_velocity_input_port())
    publisher = publish_on_lcm(
        builder,
        sender.get_output_port(),
        name=f"{prefix}panda_command_publisher",
        channel=command_channel,
        lcm_type=lcmt_panda_command,
        lcm=lcm,
        period=FRANKA_PERIOD,
    )
    receiver = builder.AddNamedSystem(f"{prefix}panda_status_receiver", PandaStatusReceiver(k))
    subscribe_on_lcm(
        builder,
        receiver.get_input_port(),
        name=f"{prefix}panda_status_subscriber",
        channel=status_channel,
        lcm_type=lcmt_panda_status,
        lcm=lcm,
    )
    watchdog = add_status_watchdog(
        builder,
        lcm=lcm,
        safety=safety,
        status_type=lcmt_panda_status,
        status_channel=status_channel,
        period=FRANKA_PERIOD,
        timeout=status_timeout,
        prefix=prefix,
    )
    return FrankaInterface(sender, publisher, receiver, watchdog)


def add_franka_controller(
    builder: DiagramBuilder,
    *,
    workcell,
    table,
    lcm: DrakeLcm,
    control_mode: str | int = "position",
    period: float = FRANKA_PERIOD,
    config: CoManipulationConfig = CoManipulationConfig(),
    name: str = "controller",
    command_channel: str = PANDA_COMMAND_CHANNEL,
    status_channel: str = PANDA_STATUS_CHANNEL,
    status_timeout: float | None = None,
) -> tuple[CoManipulationSystems, PandaStatusReceiver]:
    """The co-manipulation controller of a Franka arm, talking to
    drake-franka-driver over LCM only: what runs beside the real robot
    (:func:`~drake_cfvol.comanip.robot_status.add_lcm_controller`), its
    desired state sent in ``control_mode`` by
    :func:`add_franka_controller_interface`, whose status watchdog
    (``{name}_status_watchdog``) holds the command while no new status has
    come for ``status_timeout``. On the robot, ``lcm`` is the robot's
    network; in a test, ``DrakeLcm("memq://")`` shared with a simulated
    station (:func:`add_franka_station`).

    Args:
        period: the control period, s (Franka's 1 ms by default: the
            command is sent every millisecond).

    Returns:
        (the :class:`~drake_cfvol.systems.CoManipulationSystems`, the
        ``PandaStatusReceiver``)
    """

    def interface(cm: CoManipulationSystems) -> PandaStatusReceiver:
        return add_franka_controller_interface(
            builder,
            lcm=lcm,
            desired_state=cm.desired_state_output,
            control_mode=control_mode,
            num_joints=workcell.num_joints,
            safety=cm.safety,
            status_timeout=status_timeout,
            command_channel=command_channel,
            status_channel=status_channel,
            prefix=f"{name}_",
        ).status_receiver

    return add_lcm_controller(
        builder,
        workcell=workcell,
        table=table,
        period=period,
        config=config,
        name=name,
        status_period=FRANKA_PERIOD,
        add_interface=interface,
        who="add_franka_controller: the Franka arm",
    )
