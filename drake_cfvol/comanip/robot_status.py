"""A robot's LCM interface, whatever the arm's driver (the iiwa's,
:mod:`~drake_cfvol.comanip.iiwa`; drake-franka-driver's,
:mod:`~drake_cfvol.comanip.franka`): the watchdog on the status channel and
its hold on the safety filter, the measured position once the first status
has come, and the messages' publishers and subscribers.
"""

from __future__ import annotations

from pydrake.lcm import DrakeLcm
from pydrake.systems.framework import DiagramBuilder, InputPort, LeafSystem, OutputPort
from pydrake.systems.lcm import LcmPublisherSystem, LcmSubscriberSystem

from drake_cfvol.systems.watchdog import StatusWatchdog, cheaply_copied

__all__ = ["UntilFirstStatus", "add_measured", "add_status_watchdog", "publish_on_lcm", "subscribe_on_lcm"]


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
