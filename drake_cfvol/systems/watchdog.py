"""A watchdog on a robot's status messages (:class:`StatusWatchdog`): a
fault when none has arrived for a few status periods; and LCM message types
that Drake's Python-valued ports copy cheaply (:func:`cheaply_copied`)."""

from __future__ import annotations

import copy
from typing import Any

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem

from drake_cfvol.exceptions import ParameterError

__all__ = ["StatusWatchdog", "cheaply_copied"]


def _copy_field(value):
    kind = type(value)
    if kind in (int, float, bool, str, bytes, tuple):  # immutable (LCM decodes number arrays as tuples)
        return value
    if kind is list:
        return [_copy_field(v) for v in value]
    return copy.deepcopy(value)  # a nested message


def cheaply_copied(lcm_type: Any) -> type:
    """A subclass of a Python LCM message type whose messages copy field by
    field (numbers and tuples, as LCM decodes number arrays, shared; lists
    copied; nested messages deep-copied): a Python-valued port holding a message (an
    ``LcmSubscriberSystem`` made with the Python serializer) deep-copies it
    several times per message, and for the iiwa's status a generic deep
    copy is the slow part. Its ``decode`` returns the subclass, so pass it
    as the subscriber's ``lcm_type``."""
    names = tuple(lcm_type.__slots__)

    class Copied(lcm_type):
        __slots__ = ()

        @staticmethod
        def decode(data):
            message = lcm_type.decode(data)
            message.__class__ = Copied
            return message

        def __deepcopy__(self, memo):
            out = Copied.__new__(Copied)
            for name in names:
                setattr(out, name, _copy_field(getattr(self, name)))
            return out

    Copied.__name__ = Copied.__qualname__ = f"{lcm_type.__name__}_copied"
    return Copied


class StatusWatchdog(LeafSystem):
    """Raises ``fault`` when the robot's status has been stale for more than
    ``timeout`` seconds: no message with a new ``utime`` (an LCM status
    message's time stamp, e.g. ``lcmt_iiwa_status``) since then. A fault
    clears with the next new message. Before the first message the status
    counts as arrived at time 0 (a robot whose first status never comes is
    stale ``timeout`` after the start). Wire ``fault`` to the safety
    filter's ``hold`` input: the last command is held while the robot's
    state is unknown.

    .. pydrake_system::

        name: StatusWatchdog
        input_ports:
        - status
        output_ports:
        - fault
        - fault_count

    Args:
        model: a message of the status's type (the input port's model value;
            it must have an integer ``utime``).
        period: how often the status is checked, s (the status period).
        timeout: how long without a new message makes a fault, s (default
            three periods).

    Raises:
        ParameterError: a period or timeout that is not positive, or a
            model without ``utime``.
    """

    def __init__(self, model: Any, *, period: float, timeout: float | None = None):
        super().__init__()
        timeout = 3 * period if timeout is None else timeout
        if not (np.isfinite(period) and period > 0 and np.isfinite(timeout) and timeout > 0):
            raise ParameterError(
                f"StatusWatchdog: period and timeout must be finite and > 0 s, got {period} and {timeout}."
            )
        if not hasattr(model, "utime"):
            raise ParameterError(
                f"StatusWatchdog: the status message ({type(model).__name__}) has no utime field; give a "
                "status message type with a time stamp (e.g. drake.lcmt_iiwa_status)."
            )
        self.period, self.timeout = float(period), float(timeout)
        self.status_input = self.DeclareAbstractInputPort(name="status", model_value=AbstractValue.Make(model))
        # [last utime seen, when it changed (s), fault (0/1), faulted checks]
        self._state = self.DeclareDiscreteState(np.array([float(model.utime), 0.0, 0.0, 0.0]))
        self.DeclarePeriodicDiscreteUpdateEvent(period_sec=self.period, offset_sec=0.0, update=self._update)
        self.fault_output = self.DeclareVectorOutputPort(
            name="fault",
            size=1,
            calc=lambda ctx, out: out.SetAtIndex(0, ctx.get_discrete_state(self._state).GetAtIndex(2)),
            prerequisites_of_calc={self.xd_ticket()},
        )
        self.fault_count_output = self.DeclareVectorOutputPort(
            name="fault_count",
            size=1,
            calc=lambda ctx, out: out.SetAtIndex(0, ctx.get_discrete_state(self._state).GetAtIndex(3)),
            prerequisites_of_calc={self.xd_ticket()},
        )

    def _update(self, context, discrete_state) -> None:
        last, since, _, count = context.get_discrete_state(self._state).CopyToVector()
        t = context.get_time()
        utime = float(self.status_input.Eval(context).utime)
        if utime != last:
            last, since = utime, t
        fault = 1.0 if t - since > self.timeout + 1e-9 else 0.0
        discrete_state.get_mutable_vector(self._state).SetFromVector([last, since, fault, count + fault])
