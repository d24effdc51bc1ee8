"""The human's sensed push, checked: plausible values pass to the
admittance, anything else raises a fault that holds its last safe command
(SPEC 9)."""

import sys

import numpy as np
from numba import njit
from pydrake.autodiffutils import AutoDiffXd
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import Context_, LeafSystem_
from pydrake.systems.scalar_conversion import TemplateSystem

from drake_cfvol.exceptions import ParameterError
from drake_cfvol.systems._util import _values, _vector, default_instantiation

__all__ = ["HumanInputCheck", "HumanInputCheck_"]

#: Default plausibility limits: 2000 N m per joint (beyond any person's push
#: through the arm's levers; the adversarial pushes use 1500 N m), and
#: [500 N m x3; 1500 N x3] at the tool (a person pushes with a few hundred
#: newtons).
MAX_TORQUE = 2000.0
MAX_WRENCH = (500.0, 500.0, 500.0, 1500.0, 1500.0, 1500.0)


@njit(cache=True)
def _within(x, limit) -> bool:
    """Every x_i finite and |x_i| <= limit_i."""
    for i in range(len(x)):
        if not (np.isfinite(x[i]) and abs(x[i]) <= limit[i]):
            return False
    return True


@TemplateSystem.define("HumanInputCheck_", T_list=(float, AutoDiffXd), scope=sys.modules[__name__])
def HumanInputCheck_(T):

    class Impl(LeafSystem_[T]):
        """The human's joint torque and tool wrench, checked for plausibility.

        .. pydrake_system::

            name: HumanInputCheck
            input_ports:
            - human_torque (optional)
            - human_wrench (optional)
            output_ports:
            - human_torque
            - human_wrench
            - fault
            - fault_count

        ``human_torque`` (k, N m or N) and ``human_wrench`` ([torque N m;
        force N] at the tool, world frame) pass through as they are (zeros
        where unconnected). ``fault`` is 1 while either holds a non-finite
        value or one beyond its limit (``max_torque``, ``max_wrench``):
        wire it to :class:`AdmittanceDeformation`'s ``hold`` input, which
        then keeps its deviation and rate (the last safe command).
        ``fault_count`` counts the updates (every ``period`` s) that saw a
        fault. Nothing raises in the control loop.

        Scalar types: float and AutoDiffXd (the checks are on values; the
        count is an integer, abstract state).

        Args:
            k: number of joints.
            period: the admittance's update period, s (> 0): faults are
                counted at its updates.
            max_torque: the largest plausible |human_torque_j|, N m (N);
                scalar or (k,); > 0.
            max_wrench: the largest plausible |human_wrench_i|; scalar or
                (6,); > 0.
        """

        def _construct(
            self, k: int, *, period: float = 0.01, max_torque=MAX_TORQUE, max_wrench=MAX_WRENCH, converter=None
        ):
            LeafSystem_[T].__init__(self, converter)
            if not period > 0:
                raise ParameterError(f"period must be > 0 s, got {period}.")
            self.k = int(k)
            self.period = float(period)
            self.max_torque = _vector(max_torque, k, "max_torque", positive=True)
            self.max_wrench = _vector(max_wrench, 6, "max_wrench", positive=True)
            self.human_torque_input = self.DeclareVectorInputPort(name="human_torque", size=k)
            self.human_wrench_input = self.DeclareVectorInputPort(name="human_wrench", size=6)
            self._count = self.DeclareAbstractState(AbstractValue.Make(0))
            self.DeclarePeriodicUnrestrictedUpdateEvent(period_sec=self.period, offset_sec=0.0, update=self._update)
            self.human_torque_output = self.DeclareVectorOutputPort(
                name="human_torque",
                size=k,
                calc=lambda ctx, out: out.SetFromVector(self._torque(ctx)),
                prerequisites_of_calc={self.human_torque_input.ticket()},
            )
            self.human_wrench_output = self.DeclareVectorOutputPort(
                name="human_wrench",
                size=6,
                calc=lambda ctx, out: out.SetFromVector(self._wrench(ctx)),
                prerequisites_of_calc={self.human_wrench_input.ticket()},
            )
            self.fault_output = self.DeclareVectorOutputPort(
                name="fault",
                size=1,
                calc=lambda ctx, out: out.SetAtIndex(0, 0.0 if self.plausible(ctx) else 1.0),
                prerequisites_of_calc={self.human_torque_input.ticket(), self.human_wrench_input.ticket()},
            )
            self.fault_count_output = self.DeclareVectorOutputPort(
                name="fault_count",
                size=1,
                calc=lambda ctx, out: out.SetAtIndex(0, float(ctx.get_abstract_state(self._count).get_value())),
                prerequisites_of_calc={self.all_state_ticket()},
            )

        def _construct_copy(self, other, converter=None):
            Impl._construct(
                self,
                other.k,
                period=other.period,
                max_torque=other.max_torque,
                max_wrench=other.max_wrench,
                converter=converter,
            )

        def _torque(self, context):
            if self.human_torque_input.HasValue(context):
                return self.human_torque_input.Eval(context)
            return np.zeros(self.k)

        def _wrench(self, context):
            if self.human_wrench_input.HasValue(context):
                return self.human_wrench_input.Eval(context)
            return np.zeros(6)

        def plausible(self, context: Context_[T]) -> bool:
            """True if both inputs are finite and within their limits."""
            tau, w = _values(self._torque(context)), _values(self._wrench(context))
            if T is float:
                return _within(tau, self.max_torque) and _within(w, self.max_wrench)
            return bool(
                np.isfinite(tau).all()
                and (np.abs(tau) <= self.max_torque).all()
                and np.isfinite(w).all()
                and (np.abs(w) <= self.max_wrench).all()
            )

        def _update(self, context, state):
            if self.fault_output.Eval(context)[0] > 0.5:  # the fault output's cached value
                n = context.get_abstract_state(self._count).get_value()
                state.get_mutable_abstract_state(self._count).set_value(n + 1)

    return Impl


#: The float instantiation (``HumanInputCheck_[AutoDiffXd]`` by conversion).
HumanInputCheck = default_instantiation(HumanInputCheck_)
