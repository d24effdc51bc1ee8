"""A smooth runtime safety filter between the admittance and the robot
(SPEC 9, :class:`SafetyFilter`): every update it commands the motion
closest to the one asked for that keeps the joint velocity limits (and
the acceleration and jerk limits, where given), the box at the next path
position and a clearance margin. The margin is a velocity damper on the
signed distances of the diagram's own SceneGraph, its rows held to second
order. Where the request would break a row, a small QP solves the rows by
priority; elsewhere the filter is the identity. Nothing raises in the
control loop: a bad input holds the command.

Ports in: ``desired_position``, the box (``lower``, ``upper``; optional
``lower_ahead``, ``upper_ahead``), the optional ``nominal``,
``measured_position`` and ``hold``, and ``query_object``. Out: the
discrete state q_c as ``commanded_position`` (it depends on no input, so
the plant may be posed from it), ``commanded_velocity``,
``desired_state`` and status outputs (counts, flags, the latched
``filter_fault``).

The theory is in one place, docs/safety.md, "The safety filter": the
update, the damper and its second-order term, the box, the nominal, the
solver's stages, a robot that tracks with an error, hold and faults, the
outputs, the cost, and the acceleration and jerk limits. The requirement
is docs/spec.md, SPEC 9.
"""

import dataclasses
import math
import typing
from collections.abc import Iterable

import numpy as np
import numpy.typing as npt
from pydrake.common.value import AbstractValue
from pydrake.geometry import GeometryId, QueryObject, SceneGraph
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import ModelInstanceIndex
from pydrake.systems.framework import Context, LeafSystem, ValueProducer

from drake_cfvol.exceptions import DimensionError, ParameterError
from drake_cfvol.scene.robot import RobotSlice
from drake_cfvol.systems._util import _limits
from drake_cfvol.systems.filter.constraints import (
    DamperConstraint,
    FilterConstraint,
    FilterStep,
    JointBox,
    PriorityQP,
    StopRows,
    VelocityLimits,
    solve_rounds,
)
from drake_cfvol.systems.filter.damper import DamperRows, DynamicPairs, VelocityDamper
from drake_cfvol.systems.filter.filter_kernel import (
    brake_velocity,
    braked_rows_at,
    budget_after,
    finish,
    outside,
    request,
)
from drake_cfvol.systems.filter.stop_guard import brake_path, check_stop, stop_rows

__all__ = ["FAULTS", "SafetyFilter", "SafetyFilterConfig"]


@dataclasses.dataclass
class SafetyFilterConfig:
    """The filter's margin and damper (:class:`SafetyFilter`'s defaults).

    Attributes:
        clearance: the margin, m (>= 0); None: the bounds table's own (``AddCoManipulation``; by hand: 0).
        influence_distance: d_inf, m (> clearance + allowance): farther pairs do not constrain.
        damper_gain: xi, m/s (> 0): the approach speed allowed at d_inf.
        allowance: m (>= 0): the damper aims this far above the margin (what the rows' second-order bound misses).
        tool_speed: m/s (> 0): the tool frame's origin moves at most this fast (a
            :class:`~drake_cfvol.systems.filter.constraints.ToolSpeedLimit`); None: no such limit.
    """

    clearance: typing.Optional[float] = None
    influence_distance: float = 0.15
    damper_gain: float = 1.0
    allowance: float = 0.001
    tool_speed: typing.Optional[float] = None


#: Status state layout: [acted at the last update, updates it acted,
#: smallest signed distance seen at the last update (m), largest
#: |v_j| / limit_j of the last update, updates that used the fallback,
#: updates that had to miss a damper row, updates whose command left the
#: box, updates held, a tracking fault at the last update, updates with
#: one, the latched fault (:data:`FAULTS`; 0: none), updates that missed
#: a row with acceleration or jerk limits in force, updates whose command
#: the stop-path guard refused].
(
    _ACTIVE,
    _COUNT,
    _MIN_DISTANCE,
    _RATIO,
    _FALLBACKS,
    _MISSES,
    _EXITS,
    _HOLDS,
    _TRACKING,
    _TRACKING_COUNT,
    _FAULT,
    _BRAKING,
    _GUARD,
) = range(13)

#: The filter's faults (its ``filter_fault`` output), by code: what hit it.
FAULTS = {
    1: "too_many_rows",  # more damper rows than SafetyFilter.MAX_ROWS: the QP is not solved
    2: "perceived_overlap",  # a perceived obstacle overlaps the robot deeper than overlap_depth
}

#: The share of the velocity limits the filter keeps below them.
_HAIR = 1e-9

#: The share of the acceleration and jerk limits the filter keeps below
#: them: a velocity recomputed from two commanded positions differs from
#: the commanded one by rounding (about 1e-13 rad/s at 1 ms).
_HAIR_ACCELERATION = 1e-6

#: A command counts as changed when it differs from the request by more
#: than this, rad (m).
_CHANGED = 1e-9

#: What a row that fell short of its second-order term asks for beyond it
#: at the next solve, m/s (10 nm per 10 ms update): the rounds converge.
_NUDGE = 1e-6


def _check_parameters(period, clearance, allowance, influence_distance, damper_gain) -> None:
    """Raises ParameterError naming the first of SafetyFilter's scalar parameters that is out of range."""
    if not period > 0:
        raise ParameterError(f"SafetyFilter: period must be > 0 s, got {period}.")
    if not clearance >= 0:
        raise ParameterError(f"SafetyFilter: clearance must be >= 0 m, got {clearance}.")
    if not allowance >= 0:
        raise ParameterError(f"SafetyFilter: allowance must be >= 0 m, got {allowance}.")
    if not influence_distance > clearance + allowance:
        raise ParameterError(
            f"SafetyFilter: influence_distance ({influence_distance} m) must exceed the "
            f"clearance plus the allowance ({clearance} + {allowance} m)."
        )
    if not damper_gain > 0:
        raise ParameterError(f"SafetyFilter: damper_gain must be > 0 m/s, got {damper_gain}.")


def _declare_status_outputs(system, status) -> None:
    """The filter's status outputs (``filter_active_output``, ...), each one
    entry of the ``status`` discrete state."""
    for name, i in [
        ("filter_active", _ACTIVE),
        ("filter_count", _COUNT),
        ("min_distance", _MIN_DISTANCE),
        ("velocity_ratio", _RATIO),
        ("fallback_count", _FALLBACKS),
        ("damper_misses", _MISSES),
        ("box_exits", _EXITS),
        ("hold_count", _HOLDS),
        ("tracking_fault", _TRACKING),
        ("tracking_faults", _TRACKING_COUNT),
        ("filter_fault", _FAULT),
        ("braking_faults", _BRAKING),
        ("guard_stops", _GUARD),
    ]:
        port = system.DeclareVectorOutputPort(
            name=name,
            size=1,
            calc=lambda ctx, out, i=i: out.SetAtIndex(0, ctx.get_discrete_state(status).GetAtIndex(i)),
            prerequisites_of_calc={system.xd_ticket()},
        )
        setattr(system, f"{name}_output", port)


def _desired_state(q, v, h: float, t: float) -> np.ndarray:
    """[q_d; v]: the command's straight line from the last update's position
    to the commanded one ``q``, reached at the next update (a tracking
    controller follows it without the lag of a staircase)."""
    left = h - (t - h * np.floor(t / h + 1e-9))  # time to the next update, in (0, h]
    return np.concatenate([q - v * left, v])


class SafetyFilter(LeafSystem):
    """The commanded position closest to the one asked for that keeps the
    velocity limits, the box ahead and the clearance margin.

    .. pydrake_system::

        name: SafetyFilter
        input_ports:
        - desired_position
        - lower
        - upper
        - nominal (optional)
        - lower_ahead (optional)
        - upper_ahead (optional)
        - measured_position (optional)
        - hold (optional)
        - query_object
        output_ports:
        - commanded_position
        - commanded_velocity
        - desired_state
        - filter_active
        - filter_count
        - min_distance
        - velocity_ratio
        - fallback_count
        - damper_misses
        - box_exits
        - hold_count
        - tracking_fault
        - tracking_faults
        - filter_fault
        - braking_faults
        - guard_stops

    The update, its constraints and guarantees, the outputs and the measured
    position: see docs/safety.md, "The safety filter". Scalar type: float only.

    Args:
        plant: the finalized MultibodyPlant registered with ``scene_graph``;
            the robot's k joints are a revolute or prismatic joint each
            (other degrees of freedom may be there: a gripper, free parts).
        scene_graph: the diagram's SceneGraph (geometry, bodies, collision filters).
        robot: the robot's model instance in ``plant``.
        velocity_limits: (k,) rad/s (m/s; inf: none); default: the plant's.
        obstacle_ids: the real obstacles' geometry ids (default: every
            proximity geometry not on the robot; pass them to leave out
            virtual geometry such as the volume V's boxes).
        clearance, influence_distance, damper_gain, allowance: see :class:`SafetyFilterConfig` (clearance: 0).
        period: update period dt, s (> 0).
        acceleration_limits: (k,) rad/s^2 (m/s^2; inf: none), or None: none.
        jerk_limits: (k,) rad/s^3 (m/s^3; inf: none), or None: none.
        initial_position: the default q_c (k,); default zeros (see
            :meth:`set_initial_position`).
        skip_far_pairs: measure a pair again only once the robot's motion
            since it was measured (body displacements bounded from the poses
            at the two updates' base positions) could have brought it within
            the influence distance. Valid when the SceneGraph is posed at
            the base position (this filter's output, or the measured
            position when ``measured_position`` is connected, as in the
            co-manipulation diagrams); set False when it is posed from
            anything else.
        dynamic_ids: geometry that moves on its own: measured at every
            update (:meth:`~.damper.DynamicPairs.mark`), rows never relaxed.
        constraints: further :class:`~drake_cfvol.systems.filter.constraints.FilterConstraint`
            objects (e.g. a :class:`~drake_cfvol.systems.filter.constraints.ToolSpeedLimit`).
        overlap_depth: m (>= 0): a pair with geometry of ``dynamic_ids``
            overlapping the robot deeper than this faults the filter (see
            docs/safety.md, "Hold and faults"); None: never (perceived columns: the margin
            their map adds around what the camera saw).
    """

    #: Weight of a damper row's miss (slack) against the request's, (s/m)^2
    #: over (s/rad)^2: a row is missed only where the hard constraints leave
    #: no choice.
    SLACK_WEIGHT = 1e6

    #: Weight of a step out of the box against the request's, both (s/rad)^2:
    #: the box gives way only to a damper row.
    BOX_WEIGHT = 1e3

    #: Most QP solves per update for the rows' second-order term.
    SECOND_ORDER_ROUNDS = 4

    #: Most damper rows an update solves a QP over: more fault the filter (the QP's cost grows with the cube of
    #: its rows where they conflict; the bundled moving-obstacle runs peak at 172 and 232 rows).
    MAX_ROWS = 400

    #: A stop longer than this is refused by the stop-path guard, s.
    GUARD_HORIZON = 10.0

    #: The stop-path guard keeps a pair above the margin less this many
    #: allowances: its bound is a supporting plane's, which a link sliding
    #: round a curved obstacle undercuts (the damper itself aims at the
    #: margin plus one allowance).
    GUARD_BAND = 2.0

    def __init__(
        self,
        plant: MultibodyPlant,
        scene_graph: SceneGraph,
        robot: ModelInstanceIndex,
        *,
        velocity_limits: npt.ArrayLike | None = None,
        obstacle_ids: Iterable[GeometryId] | None = None,
        clearance: float = 0.0,
        influence_distance: float = SafetyFilterConfig.influence_distance,
        period: float = 0.01,
        damper_gain: float = SafetyFilterConfig.damper_gain,
        allowance: float = SafetyFilterConfig.allowance,
        acceleration_limits: npt.ArrayLike | None = None,
        jerk_limits: npt.ArrayLike | None = None,
        initial_position: npt.ArrayLike | None = None,
        skip_far_pairs: bool = True,
        dynamic_ids: Iterable[GeometryId] = (),
        constraints: Iterable[FilterConstraint] = (),
        overlap_depth: float | None = None,
    ):
        super().__init__()
        if overlap_depth is not None and not 0 <= overlap_depth < np.inf:
            raise ParameterError(
                f"SafetyFilter: overlap_depth must be a finite depth >= 0 m or None, got {overlap_depth}."
            )
        self.overlap_depth = None if overlap_depth is None else float(overlap_depth)
        robot_slice = RobotSlice(plant, robot)
        k = robot_slice.k
        _check_parameters(period, clearance, allowance, influence_distance, damper_gain)
        self.k = k
        self.period = float(period)
        self.clearance = float(clearance)
        self.allowance = float(allowance)
        self.influence_distance = float(influence_distance)
        self.damper_gain = float(damper_gain)
        #: The distance the damper aims at, m: the margin plus the allowance.
        self.target_distance = self.clearance + self.allowance
        #: The damper's rate, 1/s: min(xi / (d_inf - d_s), 1 / dt).
        self.rate = min(self.damper_gain / (self.influence_distance - self.target_distance), 1.0 / self.period)
        self.velocity_limits = _limits(
            plant.GetVelocityUpperLimits()[robot_slice.vidx] if velocity_limits is None else velocity_limits,
            k,
            "velocity_limits",
        )
        # Commanded at most this: a hair (1e-9) under the limits, so that
        # rounding in q + v dt never shows a step above them.
        self._vmax = self.velocity_limits * (1.0 - _HAIR)
        self.acceleration_limits = (
            None if acceleration_limits is None else _limits(acceleration_limits, k, "acceleration_limits")
        )
        self.jerk_limits = None if jerk_limits is None else _limits(jerk_limits, k, "jerk_limits")
        # Commanded at most these, a hair under the limits (see _HAIR_ACCELERATION).
        self._acceleration = (np.full(k, np.inf) if self.acceleration_limits is None else self.acceleration_limits) * (
            1.0 - _HAIR_ACCELERATION
        )
        self._jerk = (np.full(k, np.inf) if self.jerk_limits is None else self.jerk_limits) * (1.0 - _HAIR_ACCELERATION)
        self._braked = bool(np.isfinite(self._acceleration).any() or np.isfinite(self._jerk).any())
        self._guard_steps = int(np.ceil(self.GUARD_HORIZON / self.period))
        # A filter without pairs' budget and pairs to measure (empty).
        self._no_pairs = (np.zeros(0), np.zeros(0, bool))
        # No box ahead and no nominal's motion, (2, k) NaN (never written:
        # a read-only flag would make numba compile request a second time).
        self._no_box = np.full((2, k), np.nan)
        # One update's change of the velocity and of the acceleration at the
        # limits (0 without one), for the braking reach.
        self._step_dv = np.where(np.isfinite(self._acceleration), self._acceleration * self.period, 0.0)
        self._step_da = np.where(np.isfinite(self._jerk), self._jerk * self.period, 0.0)
        q0 = np.zeros(k) if initial_position is None else np.asarray(initial_position, float)
        if q0.shape != (k,):
            raise DimensionError("initial_position", k, q0.shape)
        self._plant = plant
        self._damper = VelocityDamper(
            plant,
            scene_graph,
            robot,
            obstacle_ids=obstacle_ids,
            target_distance=self.target_distance,
            influence_distance=self.influence_distance,
            rate=self.rate,
        )
        self._qp = PriorityQP()
        self.skip_far_pairs = bool(skip_far_pairs)
        n_pairs = self._damper.num_pairs
        self._dynamic = DynamicPairs(self._damper, dynamic_ids)
        dynamic = np.zeros(n_pairs, bool)  # per pair: with geometry that moves on its own
        dynamic[self._dynamic.pairs] = True

        #: The QP's constraints (:mod:`~drake_cfvol.systems.filter.constraints`):
        #: the velocity limits, the box, the damper's rows (the static
        #: scene's, relaxed near the nominal; the moving geometry's, never),
        #: with acceleration limits the rows over the stop, then ``constraints``.
        self.constraints = [
            VelocityLimits(),
            JointBox(self.BOX_WEIGHT),
            DamperConstraint(weight=self.SLACK_WEIGHT, relax=True, name="damper", pairs=~dynamic),
            DamperConstraint(weight=self.SLACK_WEIGHT, relax=False, name="perceived_obstacles", pairs=dynamic),
        ]
        if self._braked:  # the static scene's rows over the guard's stop
            self.constraints.append(StopRows(self.SLACK_WEIGHT))
        self.constraints += list(constraints)
        self._robot_slice = robot_slice

        self.desired_position_input = self.DeclareVectorInputPort(name="desired_position", size=k)
        self.lower_input = self.DeclareVectorInputPort(name="lower", size=k)
        self.upper_input = self.DeclareVectorInputPort(name="upper", size=k)
        self.nominal_input = self.DeclareVectorInputPort(name="nominal", size=k)
        # The box a robot braking in time keeps (JointBoundsSource's lower_ahead, upper_ahead).
        self.lower_ahead_input = self.DeclareVectorInputPort(name="lower_ahead", size=k)
        self.upper_ahead_input = self.DeclareVectorInputPort(name="upper_ahead", size=k)
        self.measured_position_input = self.DeclareVectorInputPort(name="measured_position", size=k)
        self.hold_input = self.DeclareVectorInputPort(name="hold", size=1)
        self.query_object_input = self.DeclareAbstractInputPort(
            name="query_object", model_value=AbstractValue.Make(QueryObject())
        )
        self._position = self.DeclareDiscreteState(q0)
        self._velocity = self.DeclareDiscreteState(k)  # the last commanded velocity
        self._status = self.DeclareDiscreteState(
            np.array([0.0, 0.0, np.inf, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
        )
        # Per pair, how far it is known to lie beyond the influence distance
        # (m; negative: measure it at the next update), with the robot at the
        # last update's base position (the budget's last entry on).
        self._budget = self.DeclareDiscreteState(np.concatenate([np.full(max(n_pairs, 1), -1.0), q0]))
        # The measured position at the last update (NaN: none yet, or held):
        # the robot's drift from its command between updates.
        self._measured_last = self.DeclareDiscreteState(np.full(k, np.nan))
        # The last commanded acceleration, (v - v_last) / dt (declared last: the
        # other states keep their indices).
        self._accel = self.DeclareDiscreteState(k)
        # The nominal at the last update (NaN: none): the box's faces move
        # with it, and braking for them means matching its velocity.
        self._nominal_last = self.DeclareDiscreteState(np.full(k, np.nan))
        # Per pair, GJK's last normal: its first direction at the next update.
        self._gjk_hint = self.DeclareDiscreteState(np.zeros(3 * max(self._damper.num_pairs, 1)))
        # Two convex shapes are measured in compiled code, not by Drake's
        # query one call at a time: two spheres or capsules exactly, others
        # GJK's lower bound (distance_kernel).
        self._convex = self._damper.convex_shapes & ~dynamic
        # Pairs measured at every update whatever their budget: geometry that
        # moves on its own (not the perceived kind, whose pairs are measured
        # while it is in use: DynamicPairs.mark).
        self._always = self._damper.self_moving & ~dynamic
        # The pairs the stop-path guard leaves to the rows: geometry that
        # moves on its own (its supporting plane moves too).
        self._unguarded = self._damper.self_moving | dynamic
        # A plant context used as scratch for the Jacobians (never a context
        # outside this system's own).
        self._scratch = self.DeclareCacheEntry(
            description="plant context (scratch for the witness points' Jacobians)",
            value_producer=ValueProducer(
                allocate=lambda: AbstractValue.Make(plant.CreateDefaultContext()), calc=lambda context, value: None
            ),
            prerequisites_of_calc={self.nothing_ticket()},
        )
        self.DeclarePeriodicDiscreteUpdateEvent(period_sec=self.period, offset_sec=0.0, update=self._update)
        self.commanded_position_output = self.DeclareStateOutputPort("commanded_position", self._position)
        self.commanded_velocity_output = self.DeclareStateOutputPort("commanded_velocity", self._velocity)
        self.desired_state_output = self.DeclareVectorOutputPort(
            name="desired_state",
            size=2 * k,
            calc=self._calc_desired_state,
            prerequisites_of_calc={self.xd_ticket(), self.time_ticket()},
        )
        _declare_status_outputs(self, self._status)

    @property
    def num_pairs(self) -> int:
        """How many geometry pairs the damper watches."""
        return self._damper.num_pairs

    @property
    def qp_solves(self) -> int:
        """QP solves of this filter (of all its contexts) so far."""
        return self._qp.solves

    def _calc_desired_state(self, context, output) -> None:
        xd = context.get_discrete_state
        output.SetFromVector(
            _desired_state(
                xd(self._position).CopyToVector(), xd(self._velocity).CopyToVector(), self.period, context.get_time()
            )
        )

    def _pctx(self, context):
        return self._scratch.get_mutable_cache_entry_value(context).GetMutableValueOrThrow()

    def base_position(self, context: Context) -> np.ndarray:
        """Where the rows are taken: the ``measured_position`` input if it
        is connected (a robot that tracks its command with an error; the
        SceneGraph is posed from the measured state), else the commanded
        position (the SceneGraph posed from this filter's output)."""
        if self.measured_position_input.HasValue(context):
            return np.asarray(self.measured_position_input.Eval(context), float)
        return context.get_discrete_state(self._position).CopyToVector()

    def damper_rows(self, context: Context, measure: np.ndarray | None = None) -> DamperRows:
        """The damper's rows at :meth:`base_position` (:meth:`VelocityDamper.rows`):
        A v >= b to first order, before the second-order term and the
        relaxation towards the nominal.

        Args:
            measure: (pairs,) bools, the pairs to measure (default all);
                the others' distances are NaN.
        """
        q = self.base_position(context)
        return self._damper.rows(self.query_object_input.Eval(context), q, measure)

    def second_order(self, context: Context, rows: DamperRows, dq: np.ndarray) -> np.ndarray:
        """Per row, how far a joint step ``dq`` from :meth:`base_position`
        falls short of the row's first-order change, m
        (:meth:`VelocityDamper.second_order`)."""
        return self._damper.second_order(self.base_position(context), rows, dq)

    def set_initial_position(self, context: Context, q: npt.ArrayLike) -> None:
        """Sets the commanded position q_c of ``context`` (e.g. the path's
        start before a run)."""
        q = np.asarray(q, float)
        if q.shape != (self.k,):
            raise DimensionError("q", self.k, q.shape)
        context.get_mutable_discrete_state(self._position).SetFromVector(q)
        self._restart(context.get_mutable_discrete_state)

    def _restart(self, state) -> None:
        """Every pair measured and no drift taken at the next update
        (``state``: discrete state index -> its mutable vector)."""
        self._reset_budget(state(self._budget))
        state(self._measured_last).SetFromVector(np.full(self.k, np.nan))
        state(self._nominal_last).SetFromVector(np.full(self.k, np.nan))
        state(self._gjk_hint).SetFromVector(np.zeros(3 * max(self._damper.num_pairs, 1)))

    def _reset_budget(self, vector) -> None:
        """Every pair measured at the next update."""
        x = vector.CopyToVector()
        x[: max(self._damper.num_pairs, 1)] = -1.0
        vector.SetFromVector(x)

    # -- the update ----------------------------------------------------------

    def _update(self, context, discrete_state):
        h, k = self.period, self.k
        q = context.get_discrete_state(self._position).CopyToVector()
        v_last = context.get_discrete_state(self._velocity).CopyToVector()
        a_last = context.get_discrete_state(self._accel).CopyToVector()
        status = context.get_discrete_state(self._status).CopyToVector()
        if status[_FAULT]:  # latched: the command brakes to a stop and stays (docs/safety.md, "Hold and faults")
            self._brake(discrete_state, q, v_last, a_last)
            return
        if self.hold_input.HasValue(context) and not self.hold_input.Eval(context)[0] <= 0.5:
            # Held (a stale robot status, a fault upstream): the command
            # brakes to a stop at its limits; every pair is measured again
            # when the hold ends.
            self._brake(discrete_state, q, v_last, a_last)
            self._restart(discrete_state.get_mutable_vector)
            held = status.copy()
            held[_ACTIVE], held[_RATIO], held[_HOLDS], held[_TRACKING] = 1.0, 0.0, status[_HOLDS] + 1, 0.0
            held[_COUNT] += 1
            discrete_state.get_mutable_vector(self._status).SetFromVector(held)
            return
        desired = np.asarray(self.desired_position_input.Eval(context), float)
        lower = np.asarray(self.lower_input.Eval(context), float)
        upper = np.asarray(self.upper_input.Eval(context), float)
        nominal = np.asarray(self.nominal_input.Eval(context), float) if self.nominal_input.HasValue(context) else None
        fallback = False
        nominals = self._no_box  # the faces' motion: the nominal now and at the last update (NaN: none)
        if nominal is not None and self._braked:
            nominals = np.array([nominal, context.get_discrete_state(self._nominal_last).get_value()])
            discrete_state.get_mutable_vector(self._nominal_last).SetFromVector(nominal)
        ahead = self._no_box
        if self.lower_ahead_input.HasValue(context) and self.upper_ahead_input.HasValue(context):
            ahead = np.array([self.lower_ahead_input.Eval(context), self.upper_ahead_input.Eval(context)], float)
        sane, lo, hi, v_t, h_lo, h_hi = request(
            q,
            desired,
            lower,
            upper,
            ahead,
            self._vmax,
            h,
            v_last,
            a_last,
            self._acceleration,
            self._jerk,
            nominals,
        )
        base, drift = self._base_and_drift(context, q, v_last)
        finite = math.isfinite(base.sum())  # one check for every entry (an overflow counts as not finite)
        if sane and (status[_TRACKING] or not finite):
            # The last update could not keep the measured robot's rows, or the
            # measured position is not finite: the request is held, braked at
            # the limits (only the box and, with a finite measured position,
            # the rows move the command).
            v_t = np.minimum(np.maximum(np.minimum(np.maximum(0.0, h_lo), h_hi), lo), hi)
            sane = finite
        measured_rows = None  # the damper's rows before braking: the stop-path guard's pairs
        slot_poses = None  # the damper's slot poses at the base, where its rows are made
        if not sane:  # hold, as far as the box (if it is usable) allows
            v, fallback, dmin, missed, tracking = v_t, True, status[_MIN_DISTANCE], False, False
            discrete_state.get_mutable_vector(self._measured_last).SetFromVector(np.full(k, np.nan))
        else:
            n = self._damper.num_pairs
            kin, reach, levers = None, None, None
            budget, measure = self._no_pairs  # no pairs: nothing to measure
            if n:
                # The kinematics, each pair's reach (how near it must be to get
                # a row at this update: farther with the limits, to brake in
                # time) and the pairs whose budget kept at the last base no
                # longer holds here, to measure, in one compiled call
                # (:func:`~.filter_kernel.update_kinematics`).
                kept = context.get_discrete_state(self._budget).get_value()
                R, o, J_w, J_v, levers, reach, budget, measure = self._damper.update_kinematics(
                    base,
                    (kept[-k:], kept[:n]),
                    (v_last, a_last, self._step_dv, self._step_da),
                    (self._vmax, self._acceleration, self._jerk, h, self._braked),
                    (self.skip_far_pairs, self._always),
                )
                kin, slot_poses = (R, o, J_w, J_v), (R, o)
            query = self.query_object_input.Eval(context)
            poses = self._dynamic.mark(query, measure)
            hint = discrete_state.get_mutable_value(self._gjk_hint).reshape(-1, 3)
            try:
                rows = self._damper.rows(
                    query,
                    base,
                    measure,
                    poses,
                    reach=reach,
                    kin=kin,
                    convex=(self._convex, hint),
                )
            except RuntimeError:
                rows = self._damper.empty()
                fallback = True
            # Skipped pairs lie at least their budget beyond the influence
            # distance; the budget kept: measured pairs' distance beyond it,
            # the others' budget, both with the robot at this base.
            dmin, keep = budget_after(rows.distances, budget, self.influence_distance, base)
            measured_rows = rows
            if self._braked and len(rows.b):
                rows = self._braked_rows(rows, base, v_last, a_last, h_lo, h_hi, levers, slot_poses)
            fault = self._fault(rows)
            if fault:  # braked to a stop from now on: no QP at this update or after
                self._brake(discrete_state, q, v_last, a_last)
                faulted = status.copy()
                faulted[_ACTIVE], faulted[_RATIO], faulted[_MIN_DISTANCE], faulted[_FAULT] = 1.0, 0.0, dmin, fault
                faulted[_COUNT] += 1
                discrete_state.get_mutable_vector(self._status).SetFromVector(faulted)
                return
            stop = None
            if self._braked and len(measured_rows.b):
                stop = self._stop_rows(measured_rows, q - base, v_last, h_lo, h_hi)
            v, missed, solved = self._filter(context, base, q, v_t, lo, hi, rows, nominal, drift, (h_lo, h_hi), stop)
            tracking = missed and drift is not None
            if drift is not None:
                discrete_state.get_mutable_vector(self._measured_last).SetFromVector(base)
            fallback = fallback or not solved
        v, q_next, exited, ratio, acted = finish(
            q, np.asarray(v, float), lo, hi, h_lo, h_hi, self.velocity_limits, desired, h, sane, _CHANGED
        )
        guarded = False
        if sane and self._braked and not fallback and measured_rows is not None and len(measured_rows.b):
            if not self.stop_is_clear(measured_rows, base, q_next, v, v_last, poses=slot_poses):
                # The next step of the stop the last command was checked with.
                v = brake_velocity(self._vmax, h, v_last, a_last, self._acceleration, self._jerk)
                q_next, guarded, acted = q + v * h, True, True
        if sane and self._braked:  # a face the limits could not brake for in time counts as leaving the box
            exited = exited or outside(q_next, lower, upper, 1e-9)
        self._command(discrete_state, q_next, v, v_last)
        if sane and self._damper.num_pairs and self.skip_far_pairs:
            discrete_state.get_mutable_vector(self._budget).SetFromVector(keep)
        else:  # measure every pair at the next update
            self._reset_budget(discrete_state.get_mutable_vector(self._budget))
        discrete_state.get_mutable_vector(self._status).SetFromVector(
            [
                float(acted),
                status[_COUNT] + acted,
                dmin,
                ratio,
                status[_FALLBACKS] + fallback,
                status[_MISSES] + missed,
                status[_EXITS] + exited,
                status[_HOLDS],
                float(tracking),
                status[_TRACKING_COUNT] + tracking,
                0.0,  # no fault (a faulted update returned above)
                status[_BRAKING] + (missed and self._braked),
                status[_GUARD] + guarded,
            ]
        )

    def _command(self, discrete_state, q_next, v, v_last) -> None:
        """Writes the update's command: the position, its velocity and acceleration."""
        discrete_state.get_mutable_vector(self._position).SetFromVector(q_next)
        discrete_state.get_mutable_vector(self._velocity).SetFromVector(v)
        discrete_state.get_mutable_vector(self._accel).SetFromVector((v - v_last) / self.period)

    def _brake(self, discrete_state, q, v_last, a_last) -> None:
        """The command brakes to a stop as hard as the limits allow, its last
        ramp ending at rest (:func:`~.filter_kernel.brake_step`; at once,
        without acceleration and jerk limits)."""
        v = brake_velocity(self._vmax, self.period, v_last, a_last, self._acceleration, self._jerk)
        self._command(discrete_state, q + v * self.period, v, v_last)

    def stop_path(self, q_next: np.ndarray, v: np.ndarray, v_last: np.ndarray) -> np.ndarray:
        """The positions (n + 1, k) the filter commands if it brakes from the
        command (q_next, v) that followed ``v_last``, one per update, q_next
        first (:meth:`_brake` walked to rest; :func:`~.stop_guard.brake_path`)."""
        h = self.period
        v = np.asarray(v, float)
        path, _, _ = brake_path(
            np.asarray(q_next, float),
            v,
            (v - np.asarray(v_last, float)) / h,
            self._vmax,
            self._acceleration,
            self._jerk,
            h,
            self._guard_steps,
        )
        return path

    def stop_is_clear(
        self,
        rows: DamperRows,
        base: np.ndarray,
        q_next: np.ndarray,
        v: np.ndarray,
        v_last: np.ndarray,
        *,
        poses: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> bool:
        """The stop-path guard: whether braking at the limits from the
        command (q_next, v) (:meth:`stop_path`) keeps the pairs with damper
        ``rows`` (made at ``base``; ``poses``: the damper's slot poses
        there, if at hand) above the margin less the allowance, or above
        their distance now where that is nearer (their lower bound there,
        where that is lower)
        (:func:`~.stop_guard.check_stop`; docs/safety.md, "The stop-path guard")."""
        h = self.period
        v, base = np.asarray(v, float), np.asarray(base, float)
        kin = self._damper.kinematics
        ok, _, _ = check_stop(
            (np.asarray(q_next, float), v, (v - np.asarray(v_last, float)) / h),
            (self._vmax, self._acceleration, self._jerk, h),
            (kin.compiled(), kin.poses(base) if poses is None else poses, base),
            (*self._damper.path_bounds, kin.moves),
            (rows.dirs, rows.points, rows.slots, rows.pair),
            (*self._damper.support_spheres, self._damper.round_radii),
            (self._unguarded, rows.distances, self.clearance, self.GUARD_BAND * self.allowance),
            self._guard_steps,
        )
        return bool(ok)

    def _braked_rows(self, rows: DamperRows, base, v_last, a_last, h_lo, h_hi, levers, poses) -> DamperRows:
        """The rows braked in time (:func:`~.filter_kernel.brake_rows`, by
        :func:`~.filter_kernel.braked_rows`),
        less those that cannot bind at this update: within the hard
        interval [h_lo, h_hi] (|v_j| <= w_j) their first-order rate A v
        stays above b plus twice a bound of the second-order term the
        rounds add. A point on a slot's body moved by the step dq = v dt
        falls short of its first-order motion by at most theta (sum_j
        levers_j |dq_j|) / 2 (theta = sum_j |dq_j|, levers the slot's
        :meth:`VelocityDamper.levers`: each second derivative of a point is
        at most the lever of the later joint). Such a pair is measured
        again at the next update (its budget is spent). ``poses``: the
        slots' (R, o) at ``base`` (the update's kinematics)."""
        # The rows' points turn on the way to the joints' stop: each row
        # closes by its second-order term over that step more than it says;
        # a pair of two moving links by as much as its supporting planes
        # say (its closest points slide: :func:`~.filter_kernel.plane_bends`).
        # One compiled call for every row (the rows are many, few are kept):
        # the joints' stop and the slots posed there, the least A v in the
        # interval, twice the bound as a rate (m/s), the braked b and the test.
        kin = self._damper.kinematics
        A, b, dirs, points, slots, rounds, pair = braked_rows_at(
            (rows.A, rows.b, rows.dirs, rows.points, rows.slots, rows.rounds, rows.pair),
            poses,
            base,
            kin.compiled(),
            levers,
            kin.rev,
            (self._acceleration, self._jerk, self.period, self.rate),
            (v_last, a_last, h_lo, h_hi),
            self._damper.probe_spheres,
        )
        return rows._replace(A=A, b=b, dirs=dirs, points=points, slots=slots, rounds=rounds, pair=pair)

    def _stop_rows(self, rows: DamperRows, lead, v_last, h_lo, h_hi) -> tuple[np.ndarray, np.ndarray]:
        """The damper's rows of a link and the static scene over the stop
        the guard checks (:func:`~.stop_guard.stop_rows`): each may close
        over the command's lead over the rows' base (``lead``), the step
        and the brake after it down to the margin less one allowance, one
        allowance above the guard's own threshold (``GUARD_BAND``)."""
        # A link against the static scene the guard watches: the pairs it
        # refuses for (two links' rows stay the damper's alone: the Panda's
        # are many).
        A, b, _ = stop_rows(
            (rows.A, rows.b, rows.slots, rows.pair, ~self._unguarded),
            self.rate,
            (self.target_distance - (self.clearance - self.allowance)),
            (v_last, h_lo, h_hi, lead),
            (self._vmax, self._acceleration, self._jerk, self.period),
            self._guard_steps,
        )
        return A, b

    def _fault(self, rows: DamperRows) -> int:
        """The fault these rows raise (:data:`FAULTS`), or 0: more rows than
        :attr:`MAX_ROWS`; a pair with self-moving geometry overlapping the
        robot deeper than :attr:`overlap_depth`."""
        if len(rows.b) > self.MAX_ROWS:
            return 1
        if self.overlap_depth is not None and len(self._dynamic):
            d = rows.distances[self._dynamic.pairs]
            if (d[np.isfinite(d)] < -self.overlap_depth).any():
                return 2
        return 0

    def _base_and_drift(self, context, q, v_last):
        """(base, drift): :meth:`base_position`, and with a measured
        position the robot's velocity beyond the command's over the last
        period, (q_m - q_m,last) / dt - v_last (zeros at the first update
        and after a hold; None without a measured position)."""
        if not self.measured_position_input.HasValue(context):
            return q, None
        base = np.asarray(self.measured_position_input.Eval(context), float)
        last = context.get_discrete_state(self._measured_last).CopyToVector()
        drift = (base - last) / self.period - v_last
        return base, np.where(np.isfinite(drift), drift, 0.0)

    def _filter(self, context, base, q, v_t, lo, hi, rows: DamperRows, nominal, drift=None, hard=None, stop=None):
        """The velocity commanded for the request v_t: (v, missed: a
        :data:`~drake_cfvol.systems.filter.constraints.ROW` row missed at v,
        solved (False: the fallback)). Each constraint's rows at the step
        taken (the damper's: first order plus the second-order bound
        :meth:`second_order` at v, then relaxed towards the nominal): they
        depend on v, so the QP is solved with them at the last solution
        until that solution meets its own (at most ``SECOND_ORDER_ROUNDS``
        solves; the right-hand sides only grow)."""
        # The rows are taken at the base (:meth:`base_position`: the measured
        # position, if given) and constrain the command's own step v h: a
        # tracking error is the controller's to close (demanding that the
        # command undo it at once would chase the robot).
        step = FilterStep(
            q=base,
            q_c=q,
            period=self.period,
            lo=lo,
            hi=hi,
            vmax=self._vmax,
            nominal=nominal,
            damper=rows,
            plant=self._plant,
            robot_slice=self._robot_slice,
            plant_context=lambda: self._pctx(context),  # looked up only where a constraint needs it
            kinematics=self._damper.kinematics,
            drift=drift,
            v_lo=None if hard is None else hard[0],
            v_hi=None if hard is None else hard[1],
            stop=stop,
        )
        return solve_rounds(self._qp, self.constraints, step, v_t, rounds=self.SECOND_ORDER_ROUNDS, nudge=_NUDGE)
