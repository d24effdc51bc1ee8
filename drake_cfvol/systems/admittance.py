"""The admittance: the human's push -> a deviation from the nominal, clamped
inside the bounds without wind-up (SPEC 9); its gains (:class:`AdmittanceConfig`)."""

import dataclasses
import sys

import numpy as np
from numba import njit
from pydrake.autodiffutils import AutoDiffXd
from pydrake.common.value import AbstractValue
from pydrake.multibody.tree import JacobianWrtVariable
from pydrake.systems.framework import BasicVector_, Context_, LeafSystem_, ValueProducer
from pydrake.systems.scalar_conversion import TemplateSystem

from drake_cfvol.exceptions import DimensionError, ParameterError
from drake_cfvol.scene.robot import RobotSlice
from drake_cfvol.systems._util import _clip, _limits, _values, _vector, default_instantiation

__all__ = ["AdmittanceConfig", "AdmittanceDeformation", "AdmittanceDeformation_"]


@dataclasses.dataclass
class AdmittanceConfig:
    """The admittance's gains, the same for every joint (the defaults of
    :class:`AdmittanceDeformation`; :func:`~drake_cfvol.systems.AddCoManipulation`
    and the scenarios read them from here).

    Attributes:
        mass: M, kg m^2 per joint (kg for a prismatic joint); > 0.
        damping: D, N m s/rad (N s/m); >= 0.
        stiffness: K, N m/rad (N/m), towards the nominal; >= 0.
    """

    mass: float = 10.0
    damping: float = 200.0
    stiffness: float = 400.0


@njit(cache=True)
def _bad_box(nominal, lower, upper) -> bool:
    """Whether the bounds inputs hold a non-finite value or lower > upper."""
    for j in range(len(nominal)):
        if not (np.isfinite(nominal[j]) and np.isfinite(lower[j]) and np.isfinite(upper[j]) and lower[j] <= upper[j]):
            return True
    return False


@njit(cache=True)
def _push_state(tau, w):
    """(every torque and wrench entry finite, the wrench not zero)."""
    finite, wrench = True, False
    for x in tau:
        finite = finite and np.isfinite(x)
    for x in w:
        finite = finite and np.isfinite(x)
        wrench = wrench or x != 0
    return finite, wrench


@njit(cache=True)
def _commanded(nominal, d, lower, upper):
    """clamp(nominal + d, lower, upper)."""
    out = np.empty(len(nominal))
    for j in range(len(nominal)):
        out[j] = min(max(nominal[j] + d[j], lower[j]), upper[j])
    return out


@njit(cache=True)
def braking_rate(gap, acceleration, h):
    """The largest rate v >= 0 from which the update d <- d + v h, braking
    at ``acceleration`` from the next update on, stops within ``gap``:
    v h / 2 + v^2 / (2 a) + a h^2 / 8 <= gap (the sum of the steps
    v - i a h bounded in closed form); inf without a limit."""
    if not np.isfinite(acceleration):
        return np.inf
    c = max(gap - acceleration * h * h / 8.0, 0.0)
    return acceleration * (-h / 2.0 + np.sqrt(h * h / 4.0 + 2.0 * c / acceleration))


@njit(cache=True, error_model="numpy")
def _step(x, nominal, lower, upper, tau, M, D, K, h, max_rate, brake):
    """The float update's arithmetic (see ``Impl._update``, the same
    operations in the same order): the new [d, v]."""
    k = len(nominal)
    out = np.empty(2 * k)
    for j in range(k):
        d, v = x[j], x[k + j]
        v = v + h * (tau[j] - D[j] * v - K[j] * d) / M[j]
        v = min(max(v, -max_rate[j]), max_rate[j])
        lo, hi = lower[j] - nominal[j], upper[j] - nominal[j]
        v = min(max(v, -braking_rate(d - lo, brake[j], h)), braking_rate(hi - d, brake[j], h))
        d = d + h * v
        at_hi, at_lo = d >= hi, d <= lo
        d = min(max(d, lo), hi)
        if (at_hi and v > 0) or (at_lo and v < 0):
            v = 0.0 * v  # as the generic update's 0 * v (its sign too)
        out[j], out[k + j] = d, v
    return out


@TemplateSystem.define("AdmittanceDeformation_", T_list=(float, AutoDiffXd), scope=sys.modules[__name__])
def AdmittanceDeformation_(T):

    class Impl(LeafSystem_[T]):
        """Admittance-controlled deformation of the nominal, clamped in bounds.

        .. pydrake_system::

            name: AdmittanceDeformation
            input_ports:
            - nominal
            - lower
            - upper
            - human_torque
            - human_wrench
            - hold (optional)
            - measured_position (optional)
            output_ports:
            - commanded_position
            - deviation

        Per joint, the deviation d from the nominal obeys
        M d'' + D d' + K d = tau_h + J(q)^T w_h, integrated every ``period``
        seconds (semi-implicit Euler). ``human_torque`` is a joint torque
        (N m, or N for prismatic joints); ``human_wrench`` is the spatial
        force [torque (N m); force (N)] at the tool frame's origin, expressed
        in the world frame, mapped through the tool's spatial Jacobian at the
        ``measured_position`` if that input is connected (a robot that tracks
        its command with an error), else at the current commanded
        configuration. Either push may be left unconnected.

        The output is ``commanded_position = clamp(nominal + d, lower,
        upper)``; it depends on the state and the nominal and bounds only, so
        a co-worker model fed from it forms no algebraic loop. No wind-up:
        after each update the state itself is clamped so that nominal + d
        stays inside the bounds, and a rate pushing outward at a bound is
        zeroed; releasing a push at a bound leaves it on the next step.

        M, D and K are Drake numeric parameters (``mass``, ``damping``,
        ``stiffness``, each of size k): set them per context with
        ``get_mutable_numeric_parameter``; the constructor's values are the
        defaults.

        Velocity limits: with them the deviation's rate is held to
        ``1 - path_share`` of each limit, so that with a path whose nominal
        and bounds move at most ``path_share`` of the limits
        (:func:`safe_path_rate`) the commanded position never moves a joint
        faster than its limit (clamping is 1-Lipschitz in its inputs).

        Acceleration limits: with them the deviation's rate approaches a
        bound no faster than braking at ``1 - path_share`` of each limit
        still stops at it (:func:`braking_rate`): the command meets a face
        at rest, not reversing there.

        Holding: an update while ``hold`` is > 0.5 keeps the deviation and
        its rate as they are (the last safe command: ``commanded_position``
        = clamp(nominal + held deviation, lower, upper) follows the path).
        Wire :class:`~drake_cfvol.systems.human_input.HumanInputCheck`'s
        ``fault`` to it: that system checks the push for plausibility and
        counts the faults. A non-finite push is never integrated, wired or
        not (the update holds). Non-finite ``nominal``, ``lower`` or
        ``upper`` come from the planner, not a sensor: they raise a
        :class:`~drake_cfvol.ParameterError` naming the port.

        The collision checks are not here: a :class:`drake_cfvol.systems.filter.safety.SafetyFilter`
        between this system and the robot keeps the clearance.

        Scalar types: float and AutoDiffXd (``ToAutoDiffXd()``); with
        AutoDiffXd, derivatives flow through the dynamics, the clamp and the
        parameters, while the hold and the wrench's Jacobian are evaluated
        on values.

        Args:
            k: number of joints.
            mass: M, kg m^2 per joint (kg for prismatic); scalar or (k,); > 0.
            damping: D, N m s/rad (N s/m); >= 0.
            stiffness: K, N m/rad (N/m) towards the nominal; >= 0.
            period: update period, s; > 0.
            plant, tool_frame: needed only when ``human_wrench`` is
                connected: the robot's plant (finalized) and the tool frame.
                The Jacobian is computed in a plant context kept in this
                system's own context (a cache entry used as scratch).
            robot: the robot's model instance in ``plant``; needed when the
                plant holds more degrees of freedom than the k joints (a
                gripper, free parts: held at their default in the scratch
                context).
            velocity_limits: (k,) joint velocity limits, rad/s (m/s; inf: no
                limit), or None (no limit).
            acceleration_limits: (k,) rad/s^2 (m/s^2; inf: no limit), or None.
            path_share: see above; in (0, 1).
        """

        def _construct(
            self,
            k: int,
            *,
            mass=AdmittanceConfig.mass,
            damping=AdmittanceConfig.damping,
            stiffness=AdmittanceConfig.stiffness,
            period: float = 0.01,
            plant=None,
            tool_frame=None,
            velocity_limits=None,
            path_share: float = 0.5,
            robot=None,
            acceleration_limits=None,
            converter=None,
        ):
            LeafSystem_[T].__init__(self, converter)
            if not period > 0:
                raise ParameterError(f"period must be > 0 s, got {period}.")
            if not 0.0 < path_share < 1.0:
                raise ParameterError(f"path_share must lie in (0, 1), got {path_share}.")
            self.k = int(k)
            self.M = _vector(mass, k, "mass", positive=True)
            self.D = _vector(damping, k, "damping", nonnegative=True)
            self.K = _vector(stiffness, k, "stiffness", nonnegative=True)
            self.period = float(period)
            self.path_share = float(path_share)
            self.max_rate = None
            self._velocity_limits = velocity_limits
            if velocity_limits is not None:
                self.max_rate = (1.0 - self.path_share) * _limits(velocity_limits, self.k, "velocity_limits")
            self._rate_or_inf = np.full(self.k, np.inf) if self.max_rate is None else self.max_rate
            self._acceleration_limits = acceleration_limits
            self._brake = np.full(self.k, np.inf)  # the deviation's braking, rad/s^2 (m/s^2)
            if acceleration_limits is not None:
                self._brake = (1.0 - self.path_share) * _limits(acceleration_limits, self.k, "acceleration_limits")
            # The unconnected sensors' values (float; shared, never written).
            self._zeros, self._no_wrench = np.zeros(self.k), np.zeros(6)
            self._slice = None
            if plant is not None:
                if robot is None and plant.num_positions() != k:
                    raise DimensionError(
                        "the plant's positions",
                        k,
                        plant.num_positions(),
                        "Pass robot= (the robot's model instance) for a plant that holds more.",
                    )
                self._slice = RobotSlice(plant, robot) if robot is not None else None
                if self._slice is not None and self._slice.k != k:
                    raise DimensionError("the robot's joints", k, self._slice.k)
            self._robot = robot
            self._plant = plant
            self._tool = tool_frame
            self.mass_parameter = self.DeclareNumericParameter(BasicVector_[T](self.M))
            self.damping_parameter = self.DeclareNumericParameter(BasicVector_[T](self.D))
            self.stiffness_parameter = self.DeclareNumericParameter(BasicVector_[T](self.K))
            self._scratch = None
            if plant is not None:
                self._scratch = self.DeclareCacheEntry(
                    description="plant context (scratch for the wrench's Jacobian)",
                    value_producer=ValueProducer(
                        allocate=lambda: AbstractValue.Make(plant.CreateDefaultContext()),
                        calc=lambda context, value: None,
                    ),
                    prerequisites_of_calc={self.nothing_ticket()},
                )
            self.nominal_input = self.DeclareVectorInputPort(name="nominal", size=k)
            self.lower_input = self.DeclareVectorInputPort(name="lower", size=k)
            self.upper_input = self.DeclareVectorInputPort(name="upper", size=k)
            self.human_torque_input = self.DeclareVectorInputPort(name="human_torque", size=k)
            self.human_wrench_input = self.DeclareVectorInputPort(name="human_wrench", size=6)
            self.hold_input = self.DeclareVectorInputPort(name="hold", size=1)
            self.measured_position_input = self.DeclareVectorInputPort(name="measured_position", size=k)
            self._state = self.DeclareDiscreteState(2 * k)  # [deviation, rate]
            self.DeclarePeriodicDiscreteUpdateEvent(period_sec=self.period, offset_sec=0.0, update=self._update)
            self.commanded_position_output = self.DeclareVectorOutputPort(
                name="commanded_position",
                size=k,
                calc=self._calc_commanded,
                prerequisites_of_calc={
                    self.xd_ticket(),
                    self.nominal_input.ticket(),
                    self.lower_input.ticket(),
                    self.upper_input.ticket(),
                },
            )
            self.deviation_output = self.DeclareVectorOutputPort(
                name="deviation",
                size=k,
                calc=lambda ctx, out: out.SetFromVector(ctx.get_discrete_state(self._state).CopyToVector()[: self.k]),
                prerequisites_of_calc={self.xd_ticket()},
            )

        def _construct_copy(self, other, converter=None):
            Impl._construct(
                self,
                other.k,
                mass=other.M,
                damping=other.D,
                stiffness=other.K,
                period=other.period,
                plant=other._plant,
                tool_frame=other._tool,
                velocity_limits=other._velocity_limits,
                path_share=other.path_share,
                robot=other._robot,
                acceleration_limits=other._acceleration_limits,
                converter=converter,
            )

        def gains(self, context: Context_[T]) -> tuple:
            """(M, D, K) of this context (the numeric parameters; for float,
            views into the context: read only)."""
            read = (lambda v: v.get_value()) if T is float else (lambda v: v.CopyToVector())
            return tuple(
                read(context.get_numeric_parameter(i))
                for i in (self.mass_parameter, self.damping_parameter, self.stiffness_parameter)
            )

        def _inputs(self, context):
            nominal = self.nominal_input.Eval(context)
            lower = self.lower_input.Eval(context)
            upper = self.upper_input.Eval(context)
            for name, v in (("nominal", nominal), ("lower", lower), ("upper", upper)):
                if not np.isfinite(_values(v)).all():
                    raise ParameterError(
                        f"AdmittanceDeformation: input '{name}' holds a non-finite value "
                        f"{_values(v).tolist()}; connect a valid source."
                    )
            if (_values(lower) > _values(upper)).any():
                raise ParameterError(
                    f"AdmittanceDeformation: lower > upper at joint(s) "
                    f"{np.flatnonzero(_values(lower) > _values(upper)).tolist()}."
                )
            return nominal, lower, upper

        def _sensors(self, context):
            """The human's joint torque and tool wrench (zeros where not
            connected), and whether this update integrates them: all finite
            and ``hold`` not raised."""
            tau = np.zeros(self.k, dtype=object if T is AutoDiffXd else float)
            w = np.zeros(6)
            ok = True
            if self.human_torque_input.HasValue(context):
                tau = self.human_torque_input.Eval(context)
                ok &= bool(np.isfinite(_values(tau)).all())
            if self.human_wrench_input.HasValue(context):
                w = _values(self.human_wrench_input.Eval(context))
                ok &= bool(np.isfinite(w).all())
            if self.hold_input.HasValue(context):
                ok &= not _values(self.hold_input.Eval(context))[0] > 0.5
            return tau, w, ok

        def _push(self, context, tau, w, q):
            """The joint torque of the push: tau + J(q)^T w."""
            tau = 0 * q + tau
            if (w != 0).any():
                if self._plant is None:
                    raise ParameterError(
                        "AdmittanceDeformation: 'human_wrench' is connected but no plant and "
                        "tool_frame were given to map it through the Jacobian."
                    )
                assert self._scratch is not None  # declared with the plant
                pctx = self._scratch.get_mutable_cache_entry_value(context).GetMutableValueOrThrow()
                if self.measured_position_input.HasValue(context):
                    q = self.measured_position_input.Eval(context)
                if self._slice is not None:
                    self._slice.set_positions(pctx, _values(q))
                else:
                    self._plant.SetPositions(pctx, _values(q))
                J = self._plant.CalcJacobianSpatialVelocity(
                    pctx,
                    JacobianWrtVariable.kQDot,
                    self._tool,
                    np.zeros(3),
                    self._plant.world_frame(),
                    self._plant.world_frame(),
                )
                if self._slice is not None:
                    J = self._slice.columns(J, "qdot")
                tau = tau + J.T @ w
            return tau

        def _update(self, context, discrete_state):
            if T is float:
                return self._update_float(context, discrete_state)
            nominal, lower, upper = self._inputs(context)
            x = context.get_discrete_state(self._state).CopyToVector()
            tau, w, integrate = self._sensors(context)
            if not integrate:
                return  # hold the last safe command: deviation and rate as they are
            d, v = x[: self.k].copy(), x[self.k :].copy()
            M, D, K = self.gains(context)
            tau = self._push(context, tau, w, _clip(nominal + d, lower, upper))
            h = self.period
            v = v + h * (tau - D * v - K * d) / M
            if self.max_rate is not None:
                v = _clip(v, -self.max_rate, self.max_rate)
            lo, hi = lower - nominal, upper - nominal
            if np.isfinite(self._brake).any():  # the braking caps, on values (a clamp's derivative is the clamped's)
                dv0, lo0, hi0 = _values(d), _values(lo), _values(hi)
                cap_lo = np.array([-braking_rate(dv0[j] - lo0[j], self._brake[j], h) for j in range(self.k)])
                cap_hi = np.array([braking_rate(hi0[j] - dv0[j], self._brake[j], h) for j in range(self.k)])
                v = _clip(v, cap_lo, cap_hi)
            d = d + h * v
            # No wind-up: keep nominal + d inside [lower, upper]; stop outward rates.
            dv, vv = _values(d), _values(v)
            at_hi, at_lo = dv >= _values(hi), dv <= _values(lo)
            d = _clip(d, lo, hi)
            v = np.where((at_hi & (vv > 0)) | (at_lo & (vv < 0)), 0 * v, v)
            discrete_state.get_mutable_vector(self._state).SetFromVector(np.concatenate([d, v]))

        def _float_inputs(self, context):
            """(nominal, lower, upper) as float arrays, checked in one compiled call."""
            nominal = self.nominal_input.Eval(context)
            lower = self.lower_input.Eval(context)
            upper = self.upper_input.Eval(context)
            if _bad_box(nominal, lower, upper):
                self._inputs(context)  # raises, naming the port
            return nominal, lower, upper

        def _update_float(self, context, discrete_state):
            """:meth:`_update` for float, its arithmetic in one compiled call
            (the sensors' checks in another)."""
            nominal, lower, upper = self._float_inputs(context)
            tau = self.human_torque_input.Eval(context) if self.human_torque_input.HasValue(context) else self._zeros
            w = self.human_wrench_input.Eval(context) if self.human_wrench_input.HasValue(context) else self._no_wrench
            finite, wrench = _push_state(tau, w)
            if not finite or (self.hold_input.HasValue(context) and self.hold_input.Eval(context)[0] > 0.5):
                return  # as _sensors: hold the last safe command
            x = context.get_discrete_state(self._state).get_value()
            if wrench:
                tau = self._push(context, tau, w, _commanded(nominal, x[: self.k], lower, upper))
            M, D, K = self.gains(context)
            rate = self._rate_or_inf
            discrete_state.get_mutable_vector(self._state).SetFromVector(
                _step(x, nominal, lower, upper, np.asarray(tau, float), M, D, K, self.period, rate, self._brake)
            )

        def _calc_commanded(self, context, output):
            if T is float:
                nominal, lower, upper = self._float_inputs(context)
                d = context.get_discrete_state(self._state).get_value()[: self.k]
                output.SetFromVector(_commanded(nominal, d, lower, upper))
                return
            nominal, lower, upper = self._inputs(context)
            d = context.get_discrete_state(self._state).CopyToVector()[: self.k]
            output.SetFromVector(_clip(nominal + d, lower, upper))

    return Impl


#: The float instantiation (``AdmittanceDeformation_[AutoDiffXd]`` by conversion).
AdmittanceDeformation = default_instantiation(AdmittanceDeformation_)
