"""A robot's LCM interface, whatever the arm's driver (the iiwa's,
:mod:`~drake_cfvol.comanip.iiwa`; drake-franka-driver's,
:mod:`~drake_cfvol.comanip.franka`): the watchdog on the status channel and
its hold on the safety filter, the measured position once the first status
has come, the messages' publishers and subscribers, and the controller
that runs beside a real arm (:func:`add_lcm_controller`).
"""

from __future__ import annotations

import typing

from pydrake.geometry import SceneGraph
from pydrake.lcm import DrakeLcm
from pydrake.multibody.plant import MultibodyPlant
from pydrake.systems.framework import DiagramBuilder, InputPort, LeafSystem, OutputPort, System
from pydrake.systems.lcm import LcmPublisherSystem, LcmSubscriberSystem
from pydrake.systems.rendering import MultibodyPositionToGeometryPose

from drake_cfvol.exceptions import StationError
from drake_cfvol.systems.station import AddCoManipulation, CoManipulationConfig, CoManipulationSystems
from drake_cfvol.systems.watchdog import StatusWatchdog, cheaply_copied

__all__ = [
    "UntilFirstStatus",
    "add_lcm_controller",
    "add_measured",
    "add_status_watchdog",
    "publish_on_lcm",
    "subscribe_on_lcm",
]


def publish_on_lcm(
    builder: DiagramBuilder,
    message: OutputPort,
    *,
    name: str,
    channel: str,
    lcm_type: type,
    lcm: DrakeLcm,
    period: float,
) -> LcmPublisherSystem:
    """An ``LcmPublisherSystem`` (``name``, C++ serializer) sending the
    ``message`` port's value on ``channel`` every ``period`` s. Returns it."""
    publisher = builder.AddNamedSystem(
        name,
        LcmPublisherSystem.Make(
            channel=channel, lcm_type=lcm_type, lcm=lcm, publish_period=period, use_cpp_serializer=True
        ),
    )
    builder.Connect(message, publisher.get_input_port())
    return publisher


def subscribe_on_lcm(
    builder: DiagramBuilder, message: InputPort, *, name: str, channel: str, lcm_type: type, lcm: DrakeLcm
) -> LcmSubscriberSystem:
    """An ``LcmSubscriberSystem`` (``name``, C++ serializer) of ``channel``
    feeding the ``message`` input (a Drake receiver's). Returns it."""
    subscriber = builder.AddNamedSystem(
        name, LcmSubscriberSystem.Make(channel=channel, lcm_type=lcm_type, lcm=lcm, use_cpp_serializer=True)
    )
    builder.Connect(subscriber.get_output_port(), message)
    return subscriber


def add_status_watchdog(
    builder: DiagramBuilder,
    *,
    lcm: DrakeLcm,
    safety,
    status_type: type,
    status_channel: str,
    period: float,
    timeout: float | None = None,
    prefix: str = "",
) -> StatusWatchdog:
    """A :class:`~drake_cfvol.systems.StatusWatchdog` (``{prefix}status_watchdog``)
    on a robot's status channel, its fault holding the safety filter's last
    command (its ``hold`` input) where one is given.

    Args:
        lcm: the LCM instance the status arrives on.
        safety: the :class:`~drake_cfvol.systems.SafetyFilter` to hold, or
            None (the fault is only reported).
        status_type: the status's Python LCM type (e.g. ``drake.lcmt_iiwa_status``,
            ``drake.lcmt_panda_status``), with an integer ``utime``.
        status_channel: the status's LCM channel.
        period: the status period, s (how often the watchdog checks).
        timeout: how long without a new status holds the command, s
            (None: the watchdog's default, three periods).
        prefix: prefix of the added systems' names.

    Returns:
        The watchdog.
    """
    watchdog = builder.AddNamedSystem(
        f"{prefix}status_watchdog", StatusWatchdog(status_type(), period=period, timeout=timeout)
    )
    stamps = builder.AddNamedSystem(  # the status as a Python message (the receiver's subscriber is C++'s)
        f"{prefix}status_stamp_subscriber",
        LcmSubscriberSystem.Make(channel=status_channel, lcm_type=cheaply_copied(status_type), lcm=lcm),
    )
    builder.Connect(stamps.get_output_port(), watchdog.status_input)
    if safety is not None:
        builder.Connect(watchdog.fault_output, safety.hold_input)
    return watchdog


class UntilFirstStatus(LeafSystem):
    """The measured position once the driver's status has arrived: before
    ``wait`` seconds (two status periods) it passes ``fallback`` (the
    command, where the robot starts), since a status receiver reports zeros
    until its first message.

    .. pydrake_system::

        name: UntilFirstStatus
        input_ports:
        - measured
        - fallback
        output_ports:
        - position
    """

    def __init__(self, k: int, wait: float):
        super().__init__()
        self._wait = float(wait)
        self.measured_input = self.DeclareVectorInputPort(name="measured", size=k)
        self.fallback_input = self.DeclareVectorInputPort(name="fallback", size=k)
        self.position_output = self.DeclareVectorOutputPort(name="position", size=k, calc=self._calc)

    def _calc(self, context, output) -> None:
        source = self.fallback_input if context.get_time() < self._wait else self.measured_input
        output.SetFromVector(source.Eval(context))


def add_measured(
    builder: DiagramBuilder, *, status, commanded: OutputPort, k: int, period: float, prefix: str = ""
) -> OutputPort:
    """The measured position from a status receiver (its
    ``get_position_measured_output_port()``: Drake's ``IiwaStatusReceiver``
    or ``PandaStatusReceiver``), the command standing in for the first two
    status ``period``'s. Returns the port."""
    gate = builder.AddNamedSystem(f"{prefix}measured_position", UntilFirstStatus(k, wait=2 * period))
    builder.Connect(status.get_position_measured_output_port(), gate.measured_input)
    builder.Connect(commanded, gate.fallback_input)
    return gate.position_output


def add_lcm_controller(
    builder: DiagramBuilder,
    *,
    workcell,
    table,
    period: float,
    config: CoManipulationConfig,
    name: str,
    status_period: float,
    add_interface: typing.Callable[[CoManipulationSystems], System],
    who: str,
) -> tuple[CoManipulationSystems, System]:
    """The co-manipulation controller of a torque-sensing arm that talks to
    it over LCM only: its own SceneGraph with the workcell (a plant posed
    from the status's measured positions, never simulated),
    :func:`~drake_cfvol.systems.AddCoManipulation` on it fed the measured
    position and the status's external torque. ``add_interface(cm)`` adds
    the arm's LCM interface on the safety filter's desired state (and its
    status watchdog) and returns the status receiver (Drake's, with
    ``get_position_measured_output_port`` and
    ``get_torque_external_output_port``), whose status comes every
    ``status_period`` s. ``who`` names the caller in errors.

    Returns:
        (the :class:`~drake_cfvol.systems.CoManipulationSystems`, the
        status receiver)

    Raises:
        StationError: no safety filter in ``config`` (the arm is commanded
            its desired state).
    """
    if config.safety_filter is None:
        raise StationError(
            f"{who} is commanded the safety filter's desired state; give config.safety_filter (not None)."
        )
    scene_graph = builder.AddNamedSystem(f"{name}_scene_graph", SceneGraph())
    plant = MultibodyPlant(0.0)
    plant.RegisterAsSourceForSceneGraph(scene_graph)
    robot = workcell.add_to_plant(plant)
    plant.Finalize()
    cm = AddCoManipulation(
        builder,
        plant=plant,
        scene_graph=scene_graph,
        robot=robot,
        table=table,
        tool_frame=workcell.tool_frame.name(),
        period=period,
        measured_state=False,
        config=config,
        name=name,
    )
    status = add_interface(cm)
    measured = add_measured(
        builder,
        status=status,
        commanded=cm.commanded_position_output,
        k=workcell.num_joints,
        period=status_period,
        prefix=f"{name}_",
    )
    to_pose = builder.AddNamedSystem(f"{name}_to_pose", MultibodyPositionToGeometryPose(plant))
    builder.Connect(measured, to_pose.get_input_port())
    builder.Connect(to_pose.get_output_port(), scene_graph.get_source_pose_port(plant.get_source_id()))
    builder.Connect(measured, cm.admittance.measured_position_input)
    assert cm.safety is not None  # config.safety_filter given (checked above)
    builder.Connect(measured, cm.safety.measured_position_input)
    builder.Connect(status.get_torque_external_output_port(), cm.human_torque_input)
    return cm, status
