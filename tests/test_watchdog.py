"""The status watchdog against a scripted status stream, and its input checks."""

import numpy as np
import pytest
from drake import lcmt_iiwa_status
from pydrake.common.value import AbstractValue
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder, LeafSystem
from pydrake.systems.primitives import LogVectorOutput

from drake_cfvol.exceptions import ParameterError
from drake_cfvol.systems import StatusWatchdog


class _Stream(LeafSystem):
    """A status whose utime advances every ``period`` until ``stop`` s, then freezes."""

    def __init__(self, period, stop):
        super().__init__()
        self._period, self._stop = period, stop
        self.DeclareAbstractOutputPort("status", lambda: AbstractValue.Make(lcmt_iiwa_status()), self._calc)

    def _calc(self, context, out):
        msg = lcmt_iiwa_status()
        t = min(context.get_time(), self._stop)
        msg.utime = int(np.floor(t / self._period + 1e-9) * self._period * 1e6)
        out.set_value(msg)


def test_the_fault_comes_a_timeout_after_the_last_new_status():
    period, stop = 0.005, 0.1
    builder = DiagramBuilder()
    stream = builder.AddSystem(_Stream(period, stop))
    dog = builder.AddSystem(StatusWatchdog(lcmt_iiwa_status(), period=period))
    builder.Connect(stream.get_output_port(), dog.status_input)
    log = LogVectorOutput(dog.fault_output, builder, publish_period=period)
    diagram = builder.Build()
    sim = Simulator(diagram)
    sim.AdvanceTo(0.2)
    ctx = sim.get_context()
    t, fault = log.FindLog(ctx).sample_times(), log.FindLog(ctx).data()[0]
    # The last new stamp is seen at 0.1 s: a fault from the first check more
    # than 3 periods later (a log sample at t shows the check before t).
    np.testing.assert_array_equal(fault, (t - period > stop + 3 * period + 1e-9).astype(float))
    count = dog.fault_count_output.Eval(dog.GetMyContextFromRoot(ctx))[0]
    checks = np.arange(0.0, 0.2 - 1e-9, period)  # the updates before the end (one at 0.2 s comes with the next step)
    assert count == np.sum(checks > stop + 3 * period + 1e-9)


def test_the_watchdog_refuses_bad_settings():
    with pytest.raises(ParameterError, match="period and timeout must be finite and > 0"):
        StatusWatchdog(lcmt_iiwa_status(), period=0.0)
    with pytest.raises(ParameterError, match="has no utime field"):
        StatusWatchdog(object(), period=0.005)


def test_a_cheaply_copied_message_copies_to_an_equal_independent_one():
    """cheaply_copied(lcmt_iiwa_status): decode returns the subclass; a
    deep copy encodes to the same bytes as the original (every field
    equal), a list field of the copy is a new list (changing it leaves the
    original as it was), and a Python-valued port's AbstractValue holding
    one copies it the same way."""
    import copy

    from drake_cfvol.systems.watchdog import cheaply_copied

    Copied = cheaply_copied(lcmt_iiwa_status)
    msg = lcmt_iiwa_status()
    msg.utime, msg.num_joints = 123456, 7
    rng = np.random.default_rng(0)
    for name in lcmt_iiwa_status.__slots__[2:]:
        setattr(msg, name, list(rng.normal(size=7)))
    decoded = Copied.decode(msg.encode())
    assert type(decoded) is Copied and isinstance(decoded, lcmt_iiwa_status)
    for original in (decoded, copy.deepcopy(decoded)):
        for message in (original, copy.deepcopy(original), AbstractValue.Make(original).Clone().get_value()):
            assert message.encode() == msg.encode()
    edited = Copied.decode(msg.encode())
    edited.joint_torque_external = list(edited.joint_torque_external)
    twin = copy.deepcopy(edited)
    twin.joint_torque_external[0] += 1.0
    assert edited.joint_torque_external[0] == msg.joint_torque_external[0]
    assert twin.joint_torque_external is not edited.joint_torque_external
