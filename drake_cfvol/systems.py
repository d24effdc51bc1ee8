"""Drake systems for co-manipulation runs (SPEC 9).

- :class:`JointBoundsSource`: the bounds table as a system of the path index.
- :class:`AdmittanceDeformation`: the human's push -> a deviation from the
  nominal, clamped inside the bounds without wind-up; sensor faults hold
  the last safe command.
- :class:`SafetyFilter` (from :mod:`drake_cfvol.safety`): between the
  admittance and the robot, the motion closest to the one asked for that
  keeps the velocity limits, the box ahead and a clearance margin (a
  velocity damper on the SceneGraph's signed distances).
- :class:`PathProgress`: the path index over time.
- :class:`ScriptedHuman`: pushes with set magnitude, direction and timing.
- :class:`RandomPushShaper`: random pushes from Drake's ``RandomSource``
  (seeded through the context).
- :class:`ReactiveCoworker`: a person reacting to the robot's position.
- :class:`ClearanceMonitor`: clearance, collision and volume contact, through
  a SceneGraph's query port.
"""


import dataclasses

import numpy as np
from pydrake.multibody.tree import JacobianWrtVariable
from pydrake.autodiffutils import AutoDiffXd
from pydrake.common.value import AbstractValue
from pydrake.geometry import QueryObject
from pydrake.systems.framework import BasicVector_, Diagram, DiagramBuilder, LeafSystem, LeafSystem_, ValueProducer
from pydrake.systems.scalar_conversion import TemplateSystem
from pydrake.systems.primitives import TrajectorySource
from pydrake.trajectories import PiecewisePolynomial

from drake_cfvol.exceptions import DimensionError, ParameterError
from drake_cfvol.safety import SafetyFilter
from drake_cfvol.table import BoundsTable

__all__ = ["JointBoundsSource", "JointBoundsSource_", "AdmittanceDeformation", "AdmittanceDeformation_", "PathProgress", "Push", "ScriptedHuman",
           "ClearanceMonitor", "RandomPushShaper", "ReactiveCoworker", "SafetyFilter", "safe_path_rate"]


def _vector(value, k: int, name: str, *, positive: bool = False, nonnegative: bool = False) -> np.ndarray:
    v = np.broadcast_to(np.asarray(value, float), (k,)).copy() if np.ndim(value) == 0 else np.asarray(value, float)
    if v.shape != (k,):
        raise DimensionError(name, k, v.shape)
    if not np.all(np.isfinite(v)):
        raise ParameterError(f"{name} must be finite, got {v.tolist()}.")
    if positive and np.any(v <= 0):
        raise ParameterError(f"{name} must be > 0, got {v.tolist()}.")
    if nonnegative and np.any(v < 0):
        raise ParameterError(f"{name} must be >= 0, got {v.tolist()}.")
    return v


def _values(x) -> np.ndarray:
    """Float values of a float or AutoDiffXd array (derivatives dropped)."""
    x = np.asarray(x)
    if x.dtype == object:
        return np.array([float(e.value()) for e in x.ravel()]).reshape(x.shape)
    return x.astype(float)


def _clip(x, lo, hi):
    """Elementwise clip for float or AutoDiffXd arrays (the derivative is
    that of the active argument)."""
    x = np.asarray(x)
    if x.dtype != object:
        return np.clip(x, lo, hi)
    xv, lov, hiv = _values(x), _values(lo), _values(hi)
    lo, hi = np.asarray(lo, dtype=object), np.asarray(hi, dtype=object)
    return np.where(xv < lov, lo, np.where(xv > hiv, hi, x))


@TemplateSystem.define("JointBoundsSource_", T_list=(float, AutoDiffXd))
def JointBoundsSource_(T):

    class Impl(LeafSystem_[T]):
        """Joint bounds for the current path index.

        .. pydrake_system::

            name: JointBoundsSource
            input_ports:
            - path_index
            output_ports:
            - lower
            - upper
            - nominal

        ``path_index`` is the path parameter s in [0, g-1] (a float; integer
        s is a waypoint). Between waypoints the bounds follow SPEC 7: the
        certified stretch box, changing at most at the table's rate per
        unit s and widened to hold the interpolated nominal.

        Scalar types: float and AutoDiffXd (``ToAutoDiffXd()``). With
        AutoDiffXd the outputs carry their derivative with respect to s:
        the nominal's exactly (linear between waypoints), the bounds' by a
        central difference of width 1e-7 (they are piecewise linear in s).
        Not Symbolic: the table is a lookup in s.

        Args:
            bounds: the bounds table.
            clamp: clamp s into [0, g-1] instead of raising (default False:
                an s outside raises :class:`~drake_cfvol.ParameterError`).
        """

        def _construct(self, bounds: BoundsTable, *, clamp: bool = False, converter=None):
            LeafSystem_[T].__init__(self, converter)
            self._bounds = bounds
            self._clamp = clamp
            k = bounds.k
            self.path_index_input = self.DeclareVectorInputPort(name="path_index", size=1)
            # The three outputs share one lookup per path index (a cache entry).
            self._box = self.DeclareCacheEntry(
                description="(lower, upper, nominal) at the path index",
                value_producer=ValueProducer(allocate=lambda: AbstractValue.Make(object()),
                                             calc=lambda ctx, value: value.set_value(self._at(ctx))),
                prerequisites_of_calc={self.path_index_input.ticket()})
            self.lower_output = self.DeclareVectorOutputPort(
                name="lower", size=k, calc=lambda ctx, out: out.SetFromVector(self._box.Eval(ctx)[0]),
                prerequisites_of_calc={self.path_index_input.ticket()})
            self.upper_output = self.DeclareVectorOutputPort(
                name="upper", size=k, calc=lambda ctx, out: out.SetFromVector(self._box.Eval(ctx)[1]),
                prerequisites_of_calc={self.path_index_input.ticket()})
            self.nominal_output = self.DeclareVectorOutputPort(
                name="nominal", size=k, calc=lambda ctx, out: out.SetFromVector(self._box.Eval(ctx)[2]),
                prerequisites_of_calc={self.path_index_input.ticket()})

        def _construct_copy(self, other, converter=None):
            Impl._construct(self, other._bounds, clamp=other._clamp, converter=converter)

        @property
        def bounds(self) -> BoundsTable:
            return self._bounds

        def _lookup(self, s: float):
            if self._clamp:
                s = min(max(s, 0.0), self._bounds.g - 1.0) if np.isfinite(s) else s
            return self._bounds.at(s)

        def _at(self, context):
            s_in = self.path_index_input.Eval(context)[0]
            if T is float:
                return self._lookup(float(s_in))
            s = float(s_in.value())
            lo, hi, nom = self._lookup(s)
            ds = s_in.derivatives()
            g = self._bounds.g
            h = 1e-7
            a, b = max(s - h, 0.0), min(s + h, g - 1.0)
            if b > a:
                lo_a, hi_a, nom_a = self._lookup(a)
                lo_b, hi_b, nom_b = self._lookup(b)
                slopes = [(lo_b - lo_a) / (b - a), (hi_b - hi_a) / (b - a)]
                i = min(int(np.floor(s)), g - 2)
                slopes.append(self._bounds.nominal[i + 1] - self._bounds.nominal[i] if g > 1 else 0 * nom)
            else:
                slopes = [0 * lo, 0 * hi, 0 * nom]
            return tuple(np.array([AutoDiffXd(float(v), float(dv) * ds) for v, dv in zip(val, slope)], dtype=object)
                         for val, slope in zip((lo, hi, nom), slopes))

    return Impl


#: The float instantiation (``JointBoundsSource_[AutoDiffXd]`` by conversion).
JointBoundsSource = JointBoundsSource_[None]


@TemplateSystem.define("AdmittanceDeformation_", T_list=(float, AutoDiffXd))
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
            output_ports:
            - commanded_position
            - deviation
            - fault
            - fault_count

        Per joint, the deviation d from the nominal obeys
        M d'' + D d' + K d = tau_h + J(q)^T w_h, integrated every ``period``
        seconds (semi-implicit Euler). ``human_torque`` is a joint torque
        (N m, or N for prismatic joints); ``human_wrench`` is the spatial
        force [torque (N m); force (N)] at the tool frame's origin, expressed
        in the world frame, mapped through the tool's spatial Jacobian at the
        current commanded configuration. Either may be left unconnected.

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

        Sensor faults: an update whose ``human_torque`` or ``human_wrench``
        holds a non-finite value, or one beyond its plausibility limit
        (``max_torque``, ``max_wrench``), holds the last safe command: the
        deviation and its rate are kept as they are (so ``commanded_position``
        = clamp(nominal + held deviation, lower, upper) follows the path), and
        ``fault`` is 1 until an update reads plausible inputs again;
        ``fault_count`` counts the faulted updates. Nothing raises in the
        control loop for a sensor input. (Non-finite ``nominal``, ``lower``
        or ``upper`` come from the planner, not a sensor: they raise a
        :class:`~drake_cfvol.ParameterError` naming the port.)

        The collision checks are not here: a :class:`drake_cfvol.safety.SafetyFilter`
        between this system and the robot keeps the clearance.

        Scalar types: float and AutoDiffXd (``ToAutoDiffXd()``); with
        AutoDiffXd, derivatives flow through the dynamics, the clamp and the
        parameters, while the fault checks and the wrench's Jacobian are
        evaluated on values.

        Args:
            k: number of joints.
            mass: M, kg m^2 per joint (kg for prismatic); scalar or (k,); > 0.
            damping: D, N m s/rad (N s/m); >= 0.
            stiffness: K, N m/rad (N/m) towards the nominal; >= 0.
            period: update period, s; > 0.
            plant, tool_frame: needed only when ``human_wrench`` is
                connected: the robot's plant (finalized; its positions are the
                k joints) and the tool frame. The Jacobian is computed in a
                plant context kept in this system's own context (a cache
                entry used as scratch).
            velocity_limits: (k,) joint velocity limits, rad/s (m/s; inf: no
                limit), or None (no limit).
            path_share: see above; in (0, 1).
            max_torque: the largest plausible |human_torque_j|, N m (N);
                scalar or (k,); > 0. Default 2000 N m: beyond any person's
                push through the arm's levers (the adversarial pushes of
                ``tools/adversarial_runs.py`` use 1500 N m).
            max_wrench: the largest plausible |human_wrench_i|, [torque N m
                x3; force N x3]; scalar or (6,); > 0. Default 500 N m and
                1500 N (a person pushes with a few hundred newtons).
        """

        def _construct(self, k: int, *, mass=10.0, damping=200.0, stiffness=400.0, period: float = 0.01,
                       plant=None, tool_frame=None, velocity_limits=None, path_share: float = 0.5,
                       max_torque=2000.0, max_wrench=(500.0, 500.0, 500.0, 1500.0, 1500.0, 1500.0),
                       converter=None):
            LeafSystem_[T].__init__(self, converter)
            if not period > 0:
                raise ParameterError(f"period must be > 0 s, got {period}.")
            if not 0.0 < path_share < 1.0:
                raise ParameterError(f"path_share must lie in (0, 1), got {path_share}.")
            self.k = int(k)
            self.M = _vector(mass, k, "mass", positive=True)
            self.D = _vector(damping, k, "damping", nonnegative=True)
            self.K = _vector(stiffness, k, "stiffness", nonnegative=True)
            self.max_torque = _vector(max_torque, k, "max_torque", positive=True)
            self.max_wrench = _vector(max_wrench, 6, "max_wrench", positive=True)
            self.period = float(period)
            self.path_share = float(path_share)
            self.max_rate = None
            self._velocity_limits = velocity_limits
            if velocity_limits is not None:
                vl = np.asarray(velocity_limits, float).reshape(-1)
                if vl.shape != (self.k,):
                    raise DimensionError("velocity_limits", self.k, vl.shape)
                if np.any(np.isnan(vl)) or np.any(vl <= 0):
                    raise ParameterError(f"velocity_limits must be > 0 (inf: no limit), got {vl.tolist()}.")
                self.max_rate = (1.0 - self.path_share) * vl
            if plant is not None and plant.num_positions() != k:
                raise DimensionError("the plant's positions", k, plant.num_positions())
            self._plant = plant
            self._tool = tool_frame
            self.mass_parameter = self.DeclareNumericParameter(BasicVector_[T](self.M))
            self.damping_parameter = self.DeclareNumericParameter(BasicVector_[T](self.D))
            self.stiffness_parameter = self.DeclareNumericParameter(BasicVector_[T](self.K))
            self._scratch = None
            if plant is not None:
                self._scratch = self.DeclareCacheEntry(
                    description="plant context (scratch for the wrench's Jacobian)",
                    value_producer=ValueProducer(allocate=lambda: AbstractValue.Make(plant.CreateDefaultContext()),
                                                 calc=lambda context, value: None),
                    prerequisites_of_calc={self.nothing_ticket()})
            self.nominal_input = self.DeclareVectorInputPort(name="nominal", size=k)
            self.lower_input = self.DeclareVectorInputPort(name="lower", size=k)
            self.upper_input = self.DeclareVectorInputPort(name="upper", size=k)
            self.human_torque_input = self.DeclareVectorInputPort(name="human_torque", size=k)
            self.human_wrench_input = self.DeclareVectorInputPort(name="human_wrench", size=6)
            self._state = self.DeclareDiscreteState(2 * k)  # [deviation, rate]
            self._fault_state = self.DeclareDiscreteState(2)  # [faulted at the last update, faulted updates]
            self.DeclarePeriodicDiscreteUpdateEvent(period_sec=self.period, offset_sec=0.0, update=self._update)
            self.commanded_position_output = self.DeclareVectorOutputPort(
                name="commanded_position", size=k, calc=self._calc_commanded,
                prerequisites_of_calc={self.xd_ticket(), self.nominal_input.ticket(), self.lower_input.ticket(),
                                       self.upper_input.ticket()})
            self.deviation_output = self.DeclareVectorOutputPort(
                name="deviation", size=k,
                calc=lambda ctx, out: out.SetFromVector(ctx.get_discrete_state(self._state).CopyToVector()[:self.k]),
                prerequisites_of_calc={self.xd_ticket()})
            self.fault_output = self.DeclareVectorOutputPort(
                name="fault", size=1,
                calc=lambda ctx, out: out.SetFromVector(ctx.get_discrete_state(self._fault_state).CopyToVector()[:1]),
                prerequisites_of_calc={self.xd_ticket()})
            self.fault_count_output = self.DeclareVectorOutputPort(
                name="fault_count", size=1,
                calc=lambda ctx, out: out.SetFromVector(ctx.get_discrete_state(self._fault_state).CopyToVector()[1:]),
                prerequisites_of_calc={self.xd_ticket()})

        def _construct_copy(self, other, converter=None):
            Impl._construct(self, other.k, mass=other.M, damping=other.D, stiffness=other.K, period=other.period,
                            plant=other._plant, tool_frame=other._tool, velocity_limits=other._velocity_limits,
                            path_share=other.path_share, max_torque=other.max_torque, max_wrench=other.max_wrench,
                            converter=converter)

        def gains(self, context) -> tuple:
            """(M, D, K) of this context (the numeric parameters)."""
            return tuple(context.get_numeric_parameter(i).CopyToVector() for i in
                         (self.mass_parameter, self.damping_parameter, self.stiffness_parameter))

        def _inputs(self, context):
            nominal = self.nominal_input.Eval(context)
            lower = self.lower_input.Eval(context)
            upper = self.upper_input.Eval(context)
            for name, v in (("nominal", nominal), ("lower", lower), ("upper", upper)):
                if not np.all(np.isfinite(_values(v))):
                    raise ParameterError(f"AdmittanceDeformation: input '{name}' holds a non-finite value "
                                         f"{_values(v).tolist()}; connect a valid source.")
            if np.any(_values(lower) > _values(upper)):
                raise ParameterError(f"AdmittanceDeformation: lower > upper at joint(s) "
                                     f"{np.flatnonzero(_values(lower) > _values(upper)).tolist()}.")
            return nominal, lower, upper

        def _sensors(self, context):
            """The human's joint torque and tool wrench (zeros where not
            connected), and whether they are plausible: finite and within
            ``max_torque`` and ``max_wrench``."""
            tau = np.zeros(self.k, dtype=object if T is AutoDiffXd else float)
            w = np.zeros(6)
            ok = True
            if self.human_torque_input.HasValue(context):
                tau = self.human_torque_input.Eval(context)
                tv = _values(tau)
                ok &= bool(np.all(np.isfinite(tv)) and np.all(np.abs(tv) <= self.max_torque))
            if self.human_wrench_input.HasValue(context):
                w = _values(self.human_wrench_input.Eval(context))
                ok &= bool(np.all(np.isfinite(w)) and np.all(np.abs(w) <= self.max_wrench))
            return tau, w, ok

        def _push(self, context, tau, w, q):
            """The joint torque of the push: tau + J(q)^T w."""
            tau = 0 * q + tau
            if np.any(w != 0):
                if self._plant is None:
                    raise ParameterError("AdmittanceDeformation: 'human_wrench' is connected but no plant and "
                                         "tool_frame were given to map it through the Jacobian.")
                pctx = self._scratch.get_mutable_cache_entry_value(context).GetMutableValueOrThrow()
                self._plant.SetPositions(pctx, _values(q))
                J = self._plant.CalcJacobianSpatialVelocity(
                    pctx, JacobianWrtVariable.kQDot, self._tool, np.zeros(3),
                    self._plant.world_frame(), self._plant.world_frame())
                tau = tau + J.T @ w
            return tau

        def _update(self, context, discrete_state):
            nominal, lower, upper = self._inputs(context)
            x = context.get_discrete_state(self._state).CopyToVector()
            faults = context.get_discrete_state(self._fault_state).CopyToVector()
            tau, w, plausible = self._sensors(context)
            if not plausible:
                # Hold the last safe command: deviation and rate as they are.
                discrete_state.get_mutable_vector(self._fault_state).SetFromVector([1.0, faults[1] + 1.0])
                return
            d, v = x[:self.k].copy(), x[self.k:].copy()
            M, D, K = self.gains(context)
            tau = self._push(context, tau, w, _clip(nominal + d, lower, upper))
            h = self.period
            v = v + h * (tau - D * v - K * d) / M
            if self.max_rate is not None:
                v = _clip(v, -self.max_rate, self.max_rate)
            d = d + h * v
            # No wind-up: keep nominal + d inside [lower, upper]; stop outward rates.
            lo, hi = lower - nominal, upper - nominal
            dv, vv = _values(d), _values(v)
            at_hi, at_lo = dv >= _values(hi), dv <= _values(lo)
            d = _clip(d, lo, hi)
            v = np.where((at_hi & (vv > 0)) | (at_lo & (vv < 0)), 0 * v, v)
            discrete_state.get_mutable_vector(self._state).SetFromVector(np.concatenate([d, v]))
            discrete_state.get_mutable_vector(self._fault_state).SetFromVector([0.0, faults[1]])

        def _calc_commanded(self, context, output):
            nominal, lower, upper = self._inputs(context)
            d = context.get_discrete_state(self._state).CopyToVector()[:self.k]
            output.SetFromVector(_clip(nominal + d, lower, upper))

    return Impl


#: The float instantiation (``AdmittanceDeformation_[AutoDiffXd]`` by conversion).
AdmittanceDeformation = AdmittanceDeformation_[None]


def safe_path_rate(bounds: BoundsTable, velocity_limits, *, share: float = 0.5) -> float:
    """The fastest path progress, in waypoints per second, at which the
    nominal and the bounds move no joint faster than ``share`` of its
    velocity limit.

    The bounds change by at most ``bounds.rate`` per unit s (SPEC 7) and
    the nominal, linear between waypoints, by at most its largest step,
    which the rate already covers. A table without a rate (the reference
    backend, or saved without one) uses its largest change between
    neighbouring waypoints; its bounds may still jump within a stretch.

    Returns:
        The rate (inf if no joint has a velocity limit).
    """
    vmax = np.asarray(velocity_limits, float)
    if bounds.g > 1:
        steps = np.max([np.abs(np.diff(a, axis=0)).max(axis=0) for a in (bounds.nominal, bounds.lower, bounds.upper)],
                       axis=0)
    else:
        steps = np.zeros(bounds.k)
    rate = np.asarray(bounds.rate, float)
    per_s = np.where(np.isfinite(rate), rate, steps)
    ok = np.isfinite(vmax) & (vmax > 0) & (per_s > 0)
    return float(np.min(share * vmax[ok] / per_s[ok])) if ok.any() else float("inf")


class PathProgress(Diagram):
    """The path index over time: s(t) = clip(rate (t - start_time), 0, g-1),
    a Drake ``TrajectorySource`` of a first-order-hold trajectory.

    .. pydrake_system::

        name: PathProgress
        output_ports:
        - path_index
        - path_index_ahead

    ``path_index_ahead`` is s(t + lead): where the path will be one
    controller period later, when a command computed now takes effect (the
    co-manipulation diagram feeds the admittance and the safety filter the
    bounds there).

    Args:
        g: number of waypoints.
        rate: waypoints per second (> 0).
        start_time: when the robot starts along the path, s.
        lead: the look-ahead of ``path_index_ahead``, s (>= 0).
    """

    def __init__(self, g: int, *, rate: float, start_time: float = 0.0, lead: float = 0.0):
        super().__init__()
        if not rate > 0:
            raise ParameterError(f"rate must be > 0 waypoints/s, got {rate}.")
        if int(g) < 1:
            raise ParameterError(f"g must be >= 1 waypoint, got {g}.")
        self.g, self.rate, self.start_time = int(g), float(rate), float(start_time)
        # Held at 0 before start_time and at g-1 after the end (Drake
        # trajectories hold their end values outside their time span).
        t0 = self.start_time
        self.trajectory = PiecewisePolynomial.FirstOrderHold(
            [t0, max(self.duration, t0 + 1e-9)], np.array([[0.0, self.g - 1.0]]))
        builder = DiagramBuilder()
        if not lead >= 0:
            raise ParameterError(f"lead must be >= 0 s, got {lead}.")
        self.lead = float(lead)
        source = builder.AddNamedSystem("trajectory", TrajectorySource(self.trajectory))
        ahead = PiecewisePolynomial.FirstOrderHold(
            [t0 - self.lead, max(self.duration, t0 + 1e-9) - self.lead], np.array([[0.0, self.g - 1.0]]))
        source_ahead = builder.AddNamedSystem("trajectory_ahead", TrajectorySource(ahead))
        builder.ExportOutput(source.get_output_port(), "path_index")
        builder.ExportOutput(source_ahead.get_output_port(), "path_index_ahead")
        builder.BuildInto(self)
        self.set_name("path_progress")
        self.path_index_output = self.GetOutputPort("path_index")
        self.path_index_ahead_output = self.GetOutputPort("path_index_ahead")

    def index_at(self, t: float) -> float:
        """s at time t."""
        return float(self.trajectory.value(float(t))[0, 0])

    @property
    def duration(self) -> float:
        """Time to reach the end of the path, s."""
        return self.start_time + (self.g - 1) / self.rate


@dataclasses.dataclass
class Push:
    """One push of the scripted human.

    Attributes:
        start: when it begins, s.
        duration: how long it lasts, s.
        joint_torque: joint torque (N m / N), length k, or empty.
        wrench: [torque (N m); force (N)] at the tool in the world frame, or empty.
        toward_nearest_obstacle: a force (N) at the tool, pointing from the
            robot to the obstacle nearest its moving links at the nominal
            when the push starts (the co-manipulation builder turns it into
            a wrench); 0: none.
    """

    start: float = 0.0
    duration: float = 1.0
    joint_torque: list[float] = dataclasses.field(default_factory=list)
    wrench: list[float] = dataclasses.field(default_factory=list)
    toward_nearest_obstacle: float = 0.0


class ScriptedHuman(LeafSystem):
    """A scripted co-worker: pushes as given, or seeded random ones.

    .. pydrake_system::

        name: ScriptedHuman
        output_ports:
        - human_torque
        - human_wrench

    Args:
        k: number of joints.
        pushes: the pushes (overlapping pushes add up).
    """

    def __init__(self, k: int, pushes: list[Push]):
        super().__init__()
        self.k = int(k)
        self.pushes = []
        for i, p in enumerate(pushes):
            if p.duration < 0:
                raise ParameterError(f"push {i}: duration must be >= 0 s, got {p.duration}.")
            tau = np.asarray(p.joint_torque, float) if len(p.joint_torque) else np.zeros(self.k)
            if p.toward_nearest_obstacle:
                raise ParameterError(f"push {i}: toward_nearest_obstacle needs the workcell and the path; build "
                                     "the diagram with drake_cfvol.comanip, which turns it into a wrench.")
            w = np.asarray(p.wrench, float) if len(p.wrench) else np.zeros(6)
            if tau.shape != (self.k,):
                raise DimensionError(f"push {i} joint_torque", self.k, tau.shape)
            if w.shape != (6,):
                raise DimensionError(f"push {i} wrench", 6, w.shape)
            self.pushes.append((float(p.start), float(p.start + p.duration), tau, w))
        self.human_torque_output = self.DeclareVectorOutputPort(
            name="human_torque", size=self.k, calc=lambda c, o: o.SetFromVector(self.at(c.get_time())[0]),
            prerequisites_of_calc={self.time_ticket()})
        self.human_wrench_output = self.DeclareVectorOutputPort(
            name="human_wrench", size=6, calc=lambda c, o: o.SetFromVector(self.at(c.get_time())[1]),
            prerequisites_of_calc={self.time_ticket()})

    def at(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        tau, w = np.zeros(self.k), np.zeros(6)
        for t0, t1, a, b in self.pushes:
            if t0 <= t < t1:
                tau += a
                w += b
        return tau, w


class ReactiveCoworker(LeafSystem):
    """A co-worker who reacts to where the robot is: a spring pulling it
    towards the nominal plus an offset (the pose the person wants), during
    a time window.

    .. pydrake_system::

        name: ReactiveCoworker
        input_ports:
        - commanded_position
        - nominal
        output_ports:
        - human_torque

    human_torque = clip(gain (nominal + offset - commanded_position),
    +-max_torque) for start <= t < start + duration, else 0. Fed from the
    admittance system's output it forms no algebraic loop (that output does
    not depend on the push).

    Args:
        k: number of joints.
        gain: N m/rad (N/m) per joint; scalar or (k,); >= 0.
        offset: rad (m) per joint; (k,).
        start, duration: the window, s.
        max_torque: N m (N) per joint; scalar or (k,); >= 0.
    """

    def __init__(self, k: int, *, gain, offset, start: float, duration: float, max_torque):
        super().__init__()
        self.k = int(k)
        self.gain = _vector(gain, k, "gain", nonnegative=True)
        self.offset = _vector(offset, k, "offset")
        self.max_torque = _vector(max_torque, k, "max_torque", nonnegative=True)
        if duration < 0:
            raise ParameterError(f"duration must be >= 0 s, got {duration}.")
        self.start, self.end = float(start), float(start + duration)
        self.commanded_position_input = self.DeclareVectorInputPort(name="commanded_position", size=self.k)
        self.nominal_input = self.DeclareVectorInputPort(name="nominal", size=self.k)
        self.human_torque_output = self.DeclareVectorOutputPort(
            name="human_torque", size=self.k, calc=self._calc)

    def _calc(self, context, output):
        t = context.get_time()
        if not self.start <= t < self.end:
            output.SetFromVector(np.zeros(self.k))
            return
        q = self.commanded_position_input.Eval(context)
        nominal = self.nominal_input.Eval(context)
        output.SetFromVector(np.clip(self.gain * (nominal + self.offset - q), -self.max_torque, self.max_torque))


class RandomPushShaper(LeafSystem):
    """Turns uniform random numbers into joint-torque pushes.

    .. pydrake_system::

        name: RandomPushShaper
        input_ports:
        - uniform
        output_ports:
        - human_torque

    Fed by Drake's ``RandomSource`` (uniform in [0, 1], held for one
    sampling interval): with u = [u_0, u_1 .. u_k], a push acts in that
    interval when u_0 < ``probability``, with joint torques
    (2 u_j - 1) x ``max_torque``; else the torque is zero. Randomness thus
    lives in the source's state, seeded through the context
    (``diagram.SetRandomContext(context, RandomGenerator(seed))``).

    Args:
        k: number of joints.
        probability: chance that an interval holds a push, in [0, 1].
        max_torque: N m (N) per joint; scalar or (k,); >= 0.
    """

    def __init__(self, k: int, *, probability: float, max_torque):
        super().__init__()
        if not 0.0 <= probability <= 1.0:
            raise ParameterError(f"probability must lie in [0, 1], got {probability}.")
        self.k = int(k)
        self.probability = float(probability)
        self.max_torque = _vector(max_torque, k, "max_torque", nonnegative=True)
        self.uniform_input = self.DeclareVectorInputPort(name="uniform", size=self.k + 1)
        self.human_torque_output = self.DeclareVectorOutputPort(
            name="human_torque", size=self.k, calc=lambda c, o: o.SetFromVector(self.torque(
                self.uniform_input.Eval(c))))

    def torque(self, u) -> np.ndarray:
        """The push for random numbers u (k + 1,)."""
        u = np.asarray(u, float)
        if u[0] >= self.probability:
            return np.zeros(self.k)
        return (2.0 * u[1:] - 1.0) * self.max_torque


class ClearanceMonitor(LeafSystem):
    """Clearance, collision and volume contact of the robot, queried from
    the diagram's own SceneGraph through its ``query_object`` port.

    .. pydrake_system::

        name: ClearanceMonitor
        input_ports:
        - query_object
        output_ports:
        - min_distance
        - in_collision
        - in_volume

    ``min_distance`` is the smallest signed distance from the robot's moving
    links to the real obstacles (not the volume; a fixed base resting on its
    pedestal says nothing about a push, nor do ``ignored_pairs``), capped at
    ``max_distance``.
    ``in_collision`` is 1 where the robot penetrates an obstacle or itself
    (the plant's collision filters apply), ``in_volume`` 1 where it
    penetrates a box of the volume V. The system keeps no state and writes
    nothing outside its context.

    Args:
        robot_ids: proximity geometry ids of the robot (all links).
        moving_ids: the subset on links the joints move.
        volume_ids: the volume's boxes; every other proximity geometry is an
            obstacle, unless ``obstacle_ids`` names them.
        max_distance: distances beyond this are reported as this, m.
        obstacle_ids: the obstacles, if known: ``min_distance`` then asks
            for the moving links' distance to each of them only (cheaper in
            a scene holding other geometry, such as the volume V's boxes);
            ``in_collision`` ignores any other geometry.
        ignored_pairs: (moving link geometry, obstacle geometry) pairs left
            out of ``min_distance``: those whose distance no joint motion
            changes (:meth:`drake_cfvol.workcell.Workcell.invariant_pairs`),
            which a push cannot bring closer. ``in_collision`` still counts them.
    """

    def __init__(self, *, robot_ids, moving_ids, volume_ids, max_distance: float = 2.0, obstacle_ids=None,
                 ignored_pairs=()):
        super().__init__()
        self._robot = frozenset(robot_ids)
        self._moving = frozenset(moving_ids)
        self._volume = frozenset(volume_ids)
        self._obstacles = None if obstacle_ids is None else frozenset(obstacle_ids)
        self._ignored = frozenset((a, b) for a, b in ignored_pairs) | frozenset((b, a) for a, b in ignored_pairs)
        self._pairs = None if obstacle_ids is None else [(a, b) for a in sorted(self._moving, key=lambda g: g.get_value())
                                                          for b in sorted(self._obstacles, key=lambda g: g.get_value())
                                                          if (a, b) not in self._ignored]
        if not self._moving <= self._robot:
            raise ParameterError("ClearanceMonitor: moving_ids must be a subset of robot_ids.")
        self._max = float(max_distance)
        self.query_object_input = self.DeclareAbstractInputPort(
            name="query_object", model_value=AbstractValue.Make(QueryObject()))
        self.min_distance_output = self.DeclareVectorOutputPort(
            name="min_distance", size=1, calc=lambda c, o: o.SetAtIndex(0, self.min_distance(c)))
        # One penetration query serves both contact outputs (a cache entry).
        self._contact_cache = self.DeclareCacheEntry(
            description="(robot collides, robot touches V)",
            value_producer=ValueProducer(allocate=lambda: AbstractValue.Make(object()),
                                         calc=lambda c, value: value.set_value(self._contacts(c))),
            prerequisites_of_calc={self.query_object_input.ticket()})
        self.in_collision_output = self.DeclareVectorOutputPort(
            name="in_collision", size=1, calc=lambda c, o: o.SetAtIndex(0, float(self._contact_cache.Eval(c)[0])),
            prerequisites_of_calc={self.query_object_input.ticket()})
        self.in_volume_output = self.DeclareVectorOutputPort(
            name="in_volume", size=1, calc=lambda c, o: o.SetAtIndex(0, float(self._contact_cache.Eval(c)[1])),
            prerequisites_of_calc={self.query_object_input.ticket()})

    def min_distance(self, context) -> float:
        """Smallest signed distance, moving links to obstacles, m."""
        query = self.query_object_input.Eval(context)
        best = self._max
        if self._pairs is not None:
            for a, b in self._pairs:
                best = min(best, query.ComputeSignedDistancePairClosestPoints(a, b).distance)
            return best
        for pair in query.ComputeSignedDistancePairwiseClosestPoints(max_distance=self._max):
            a, b = pair.id_A, pair.id_B
            if a in self._volume or b in self._volume or (a, b) in self._ignored:
                continue
            if (a in self._moving and b not in self._robot) or (b in self._moving and a not in self._robot):
                best = min(best, pair.distance)
        return best

    def _contacts(self, context) -> tuple[bool, bool]:
        query = self.query_object_input.Eval(context)
        collides = touches_volume = False
        for pp in query.ComputePointPairPenetration():
            a, b = pp.id_A, pp.id_B
            if a in self._volume or b in self._volume:
                touches_volume |= (a in self._robot or b in self._robot)
            elif a in self._robot or b in self._robot:
                other = b if a in self._robot else a
                if self._obstacles is None or other in self._robot or other in self._obstacles:
                    collides = True
        return collides, touches_volume
