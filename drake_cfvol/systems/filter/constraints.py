"""The safety filter's constraints (SPEC 9): each contributes rows
A v >= b on the commanded joint velocity v, with a priority, to the
filter's QP (:class:`PriorityQP`). Adding a constraint is adding a
subclass of :class:`FilterConstraint` and passing it to
:class:`~drake_cfvol.systems.SafetyFilter` (``constraints=``).

Priorities, by the QP's stages (:class:`PriorityQP`):

- :data:`HARD`: never given up (the velocity limits; a tool speed limit);
- :data:`ROW`: given up only where the hard rows leave no way, missed as
  little as possible (the damper's rows, perceived obstacles);
- :data:`STOP`: gives way to a :data:`ROW` row (the damper's rows over the
  stop-path guard's stop, :class:`StopRows`: the guard keeps the margin,
  these rows only steer the QP away from its refusals; a miss is no fault);
- :data:`BOX`: gives way to the rows above (the bounds' box).
"""

from __future__ import annotations

import itertools
from typing import NamedTuple

import numpy as np
import numpy.typing as npt
from pydrake.multibody.tree import Frame, JacobianWrtVariable

from drake_cfvol.exceptions import ParameterError
from drake_cfvol.systems.filter.filter_kernel import (
    BOX_ROWS,
    DAMPER_ROWS,
    LIMIT_ROWS,
    STOP_ROWS,
    filter_rounds,
    stack_rows,
)
from drake_cfvol.systems.filter.qp import stage_problem, staged_solve

__all__ = [
    "HARD",
    "ROW",
    "STOP",
    "BOX",
    "ConstraintRows",
    "FilterStep",
    "FilterConstraint",
    "VelocityLimits",
    "JointBox",
    "DamperConstraint",
    "StopRows",
    "ToolSpeedLimit",
    "PriorityQP",
    "solve_rounds",
]

#: Priorities (see the module's documentation).
HARD, ROW, STOP, BOX = 0, 1, 2, 3


class ConstraintRows(NamedTuple):
    """One constraint's rows at one update: A v >= b."""

    #: (m, k), in the units of b per unit joint velocity.
    A: np.ndarray
    #: (m,).
    b: np.ndarray
    #: :data:`HARD`, :data:`ROW` or :data:`BOX`.
    priority: int
    #: The weight of a miss (slack s, cost weight s^2) where the stage gives
    #: the rows up, relative to the request's |v - v_t|^2.
    weight: float
    #: The constraint's name (for the QP's warm start and reports).
    name: str


class FilterStep:
    """What a constraint sees at one update of the filter.

    Attributes:
        q: where the rows are taken (the measured position, or the command), (k,).
        q_c: the commanded position before the update, (k,).
        period: dt, s.
        lo, hi: the velocity interval per joint that keeps the limits and lands in the box, (k,).
        vmax: the velocity limits the filter commands at most, (k,).
        v_lo, v_hi: the hard velocity interval of this update, (k,): the
            velocity limits, and the acceleration and jerk limits from the
            last command (:func:`~.filter_kernel.hard_interval`); default
            -vmax, vmax.
        nominal: the nominal at the next path position (k,), or None.
        drift: the measured robot's velocity beyond the command's, rad/s
            (m/s), (k,): the tracking error's rate, which the damper's rows
            subtract where it approaches (zeros without a measured position).
        damper: the damper's rows at q (:class:`~drake_cfvol.systems.filter.damper.DamperRows`).
        stop: (A (m, k), b (m,)): the damper's rows over the stop
            (:func:`~drake_cfvol.systems.filter.stop_guard.stop_rows`; none by default).
        kinematics: the damper's moving bodies' kinematics
            (:class:`~drake_cfvol.systems.filter.damper_kinematics.SlotKinematics`),
            for the rows' second-order term.
    """

    def __init__(
        self,
        *,
        q,
        q_c,
        period,
        lo,
        hi,
        vmax,
        nominal,
        damper,
        plant,
        robot_slice,
        plant_context,
        kinematics,
        drift=None,
        v_lo=None,
        v_hi=None,
        stop=None,
    ):
        self.q, self.q_c, self.period, self.lo, self.hi, self.vmax = q, q_c, period, lo, hi, vmax
        self.v_lo = -np.asarray(vmax, float) if v_lo is None else np.asarray(v_lo, float)
        self.v_hi = np.asarray(vmax, float) if v_hi is None else np.asarray(v_hi, float)
        self.drift = np.zeros(len(q_c)) if drift is None else np.asarray(drift, float)
        self.nominal, self.damper, self.kinematics = nominal, damper, kinematics
        self.stop = (np.zeros((0, len(q_c))), np.zeros(0)) if stop is None else stop
        self.plant, self.robot_slice = plant, robot_slice
        self._pctx = plant_context

    def plant_context(self):
        """The filter's scratch plant context, posed at :attr:`q` (the
        ``plant_context`` given, or what it returns where it is a function:
        looked up only when a constraint asks)."""
        if callable(self._pctx):
            self._pctx = self._pctx()
        self.robot_slice.set_positions(self._pctx, self.q)
        return self._pctx

    def nominal_or_nan(self) -> np.ndarray:
        """(k,): the nominal, NaN where there is none (no relaxation)."""
        return np.full(len(self.q_c), np.nan) if self.nominal is None else np.asarray(self.nominal, float)


class FilterConstraint:
    """A constraint of the safety filter: rows A v >= b at each update.

    Subclasses set :attr:`name`, :attr:`priority` and :attr:`weight` and
    implement :meth:`rows`. Rows that are damper rows (their right-hand
    side grows by the row's second-order term at the step taken) say which
    in :meth:`second_order_rows`; :attr:`relaxed` rows are relaxed towards
    the nominal (:func:`~drake_cfvol.systems.filter.filter_kernel.relaxation`).
    """

    name = "constraint"
    priority = ROW
    weight = 1e6
    relaxed = False
    #: The filter's own constraints: the kind of rows
    #: :func:`~.filter_kernel.stack_rows` makes for them, so that an update
    #: stacks them in one compiled call; None for any other (its
    #: :meth:`rows` are called).
    stack: int | None = None

    def rows(self, step: FilterStep) -> tuple[np.ndarray, np.ndarray]:
        """(A (m, k), b (m,)) at this update, to first order."""
        raise NotImplementedError

    def second_order_rows(self, step: FilterStep) -> np.ndarray | None:
        """(m,) per row, the damper row (of ``step.damper``) whose
        second-order term it adds at the step taken; None: none."""
        return None


def _own_rows(c, step) -> tuple:
    """(A, b, second-order rows) of one of the filter's own constraints (its
    :attr:`~FilterConstraint.stack` kind) by :func:`~.filter_kernel.stack_rows`,
    the code that stacks them all at an update."""
    damper = step.damper
    pairs = c.pairs[None, :] if c.stack == DAMPER_ROWS else np.zeros((1, 0), bool)
    _check_pairs(c.stack == DAMPER_ROWS, pairs, damper)
    A, b, _, _, so, _, _ = stack_rows(
        np.array([c.stack], np.int64),
        np.array([c.weight], float),
        np.array([c.priority], np.int64),
        np.array([c.relaxed]),
        pairs,
        np.asarray(step.v_lo, float),
        np.asarray(step.v_hi, float),
        np.asarray(step.lo, float),
        np.asarray(step.hi, float),
        damper.A,
        damper.b,
        damper.pair,
        *step.stop,
    )
    return A, b, so


def _check_pairs(has_damper: bool, pairs, damper) -> None:
    """A damper block's pairs must flag every damper pair (the compiled
    stacking reads them by the rows' pair indices, unchecked)."""
    if has_damper and pairs.shape[1] != len(damper.distances):
        raise ParameterError(
            f"DamperConstraint: pairs must hold one flag per damper pair ({len(damper.distances)}), "
            f"got {pairs.shape[1]}."
        )


class VelocityLimits(FilterConstraint):
    """v_lo <= v <= v_hi (:data:`HARD`): the velocity limits, and the
    acceleration and jerk limits from the last command
    (:func:`~.filter_kernel.hard_interval`)."""

    name, priority, stack = "velocity_limits", HARD, LIMIT_ROWS

    def rows(self, step: FilterStep) -> tuple[np.ndarray, np.ndarray]:
        return _own_rows(self, step)[:2]


class JointBox(FilterConstraint):
    """lower <= q_c + v dt <= upper, the box at the next path position, as
    the velocity interval lo <= v <= hi (:data:`BOX`: gives way to a row)."""

    name, priority, stack = "box", BOX, BOX_ROWS

    def __init__(self, weight: float):
        self.weight = float(weight)

    def rows(self, step: FilterStep) -> tuple[np.ndarray, np.ndarray]:
        return _own_rows(self, step)[:2]


class DamperConstraint(FilterConstraint):
    """The velocity damper's rows (SPEC 9) of some of its pairs, with their
    second-order term and, for the static scene, the relaxation towards
    the nominal.

    Args:
        weight: the weight of a miss.
        relax: whether the rows are relaxed towards the nominal (False for
            perceived, moving obstacles: the nominal is not known to be
            free of them).
        pairs: (pairs,) bools over the damper's pairs: the rows of these
            pairs are this constraint's.
        name: the constraint's name.
    """

    priority, stack = ROW, DAMPER_ROWS

    def __init__(self, *, weight: float, relax: bool, pairs: npt.ArrayLike, name: str):
        self.weight, self.relaxed, self.name = float(weight), bool(relax), name
        self.pairs = np.array(pairs, bool).reshape(-1)

    def rows(self, step: FilterStep) -> tuple[np.ndarray, np.ndarray]:
        return _own_rows(self, step)[:2]

    def second_order_rows(self, step: FilterStep) -> np.ndarray | None:
        return _own_rows(self, step)[2]


class StopRows(FilterConstraint):
    """The damper's rows over the stop the stop-path guard checks: each
    row's first-order closing over the step and the brake after it stays
    within its gap (:func:`~drake_cfvol.systems.filter.stop_guard.stop_rows`,
    made by the filter with acceleration limits: ``step.stop``), as
    :data:`STOP` rows with no second-order term. A command the guard would
    refuse brakes every joint; these rows let the QP slow the joints that
    close the pair instead. They are first order and may be out of reach
    (a row already below its target that any brake still closes): they
    give way to the damper's rows, and a miss is no fault (the guard
    keeps the margin)."""

    name, priority, stack = "stop_rows", STOP, STOP_ROWS

    def __init__(self, weight: float):
        self.weight = float(weight)

    def rows(self, step: FilterStep) -> tuple[np.ndarray, np.ndarray]:
        return _own_rows(self, step)[:2]


def _polytope_radius(dirs) -> float:
    """The largest |u| over {u : |d . u| <= 1 for every row d of dirs}: by
    the polytope's vertices (three planes each)."""
    planes = np.vstack([dirs, -dirs])
    best = 0.0
    for i, j, k in itertools.combinations(range(len(planes)), 3):
        M = planes[[i, j, k]]
        if abs(np.linalg.det(M)) < 1e-9:
            continue
        u = np.linalg.solve(M, np.ones(3))
        if np.all(planes @ u <= 1.0 + 1e-9):
            best = max(best, float(np.linalg.norm(u)))
    return best


#: Directions of the tool speed limit's rows: the cube's face, edge and
#: vertex normals (13, each used with both signs).
_SPEED_DIRS = np.array([d for d in itertools.product((-1, 0, 1), repeat=3) if d > (0, 0, 0)], float)
_SPEED_DIRS /= np.linalg.norm(_SPEED_DIRS, axis=1, keepdims=True)
#: The polytope |d . u| <= 1 over those directions reaches this far out.
_SPEED_RADIUS = _polytope_radius(_SPEED_DIRS)


class ToolSpeedLimit(FilterConstraint):
    """The tool's translational speed at most ``speed`` (ISO/TS 15066's
    speed and separation monitoring; :data:`HARD`).

    |J_tool v| <= speed, J_tool the translational Jacobian (world frame) of
    the frame's origin at the filter's base position: as 26 rows
    |d . J_tool v| <= speed / rho over 13 directions d (the cube's face,
    edge and vertex normals), rho the largest |u| with |d . u| <= 1 for
    all of them, so every v that meets the rows moves the tool at most
    ``speed`` (to first order in the step).

    Args:
        frame: the tool frame (of the filter's plant).
        speed: m/s (> 0).
        point: the point, in the frame, whose speed is limited (m; default
            its origin).
    """

    name, priority = "tool_speed", HARD

    def __init__(self, frame: Frame, speed: float, point: npt.ArrayLike = (0.0, 0.0, 0.0)):
        if not speed > 0:
            raise ParameterError(f"ToolSpeedLimit: speed must be > 0 m/s, got {speed}.")
        self.frame, self.speed = frame, float(speed)
        self.point = np.asarray(point, float).reshape(3)

    def jacobian(self, step: FilterStep) -> np.ndarray:
        """(3, k): the point's translational velocity per unit joint velocity."""
        plant = step.plant
        J = plant.CalcJacobianTranslationalVelocity(
            step.plant_context(),
            JacobianWrtVariable.kV,
            self.frame,
            self.point,
            plant.world_frame(),
            plant.world_frame(),
        )
        return step.robot_slice.columns(J)

    def rows(self, step: FilterStep) -> tuple[np.ndarray, np.ndarray]:
        DJ = _SPEED_DIRS @ self.jacobian(step)
        c = self.speed / _SPEED_RADIUS
        return np.vstack([DJ, -DJ]), np.full(2 * len(DJ), -c)


class PriorityQP:
    """The filter's QP, argmin |v - v_t|^2 over the constraints' rows, in
    stages by priority: first every row hard; if no v meets them all, the
    :data:`BOX` rows soft (a miss s >= 0 per row, cost weight s^2); then the
    :data:`ROW` rows soft too. :data:`HARD` rows are hard in every stage.
    Solved by :func:`~drake_cfvol.systems.filter.qp.staged_solve`, warm-started
    from the last solve's active rows (by constraint and row).

    Attributes:
        solves: QP solves so far.
    """

    def __init__(self):
        self._warm: dict = {}
        self._last = None  # (((name, rows) per block), active) of the last solve
        self.solves = 0

    def solve(self, v_t, blocks: list[ConstraintRows]):
        """The solution of the first stage that has one, or None."""
        return self.solve_staged(v_t, blocks)[0]

    def solve_staged(self, v_t, blocks: list[ConstraintRows]):
        """(v, the stage that gave it: 0 all rows hard, 1 the lowest
        priority soft, ...), or (None, None)."""
        A, b, prio, weight = _stack(blocks, len(v_t))
        v, active = np.zeros(len(v_t)), np.zeros(len(b), bool)
        stage, solves, _ = staged_solve(
            np.asarray(v_t, float), A, b, prio, weight, _levels(blocks), HARD, self.hints(blocks), v, active
        )
        self.solves += solves
        if stage < 0:
            return None, None
        self.remember(blocks, active)
        return v, stage

    @staticmethod
    def stage_problem(v_t, blocks, soft_from):
        """The stage's QP (:func:`~drake_cfvol.systems.filter.qp.stage_problem`):
        (h, g, C, c, soft) over x = [v; one slack per soft row, in the
        blocks' order], ``soft`` per block; blocks of priority >=
        ``soft_from`` (None: none) soft."""
        A, b, prio, weight = _stack(blocks, len(v_t))
        top = np.iinfo(np.int64).max if soft_from is None else int(soft_from)
        h, g, C, c, _ = stage_problem(np.asarray(v_t, float), A, b, prio, weight, top, HARD)
        soft = [blk.priority != HARD and soft_from is not None and blk.priority >= soft_from for blk in blocks]
        return h, g, C, c, soft

    def hints(self, blocks) -> np.ndarray:
        """The rows active at the last solve, by constraint name (none for a
        constraint whose row count changed)."""
        return self.hints_for(tuple((blk.name, len(blk.b)) for blk in blocks))

    def hints_for(self, layout) -> np.ndarray:
        """:meth:`hints` of blocks of this layout ((name, rows) per block)."""
        if self._last is not None:
            if layout == self._last[0]:  # the same constraints and row counts as the last solve
                return self._last[1].copy()
            at = 0
            for name, m in self._last[0]:
                self._warm[name] = self._last[1][at : at + m]
                at += m
            self._last = None
        out = [self._warm.get(name) for name, _ in layout]
        return np.concatenate(
            [np.zeros(0, bool)]
            + [w if w is not None and len(w) == m else np.zeros(m, bool) for w, (_, m) in zip(out, layout)]
        )

    def remember(self, blocks, active) -> None:
        """Keeps the rows active at a solve (stacked as the blocks), by constraint name."""
        self.remember_layout(tuple((blk.name, len(blk.b)) for blk in blocks), active)

    def remember_layout(self, layout, active) -> None:
        """:meth:`remember` of blocks of this layout ((name, rows) per block)."""
        self._last = (layout, np.array(active, bool))


def _stack(blocks, k: int, relaxed=None):
    """The blocks' rows stacked: A (m, k), b, priorities and weights per row
    (and, given each block's ``relaxed`` flag, the per-row flags and the
    soft stages' priorities, :func:`_levels`)."""
    if not blocks:
        empty = np.empty((0, k)), np.empty(0), np.empty(0, np.int64), np.empty(0)
        return empty if relaxed is None else empty + (np.zeros(0, bool), np.zeros(0, np.int64))
    for blk in blocks:
        if np.shape(blk.A) != (len(blk.b), k) or blk.weight is None:
            raise ParameterError(
                f"constraint '{blk.name}': rows must be A ({len(blk.b)}, {k}) with b ({len(blk.b)},) and a weight, "
                f"got A of shape {np.shape(blk.A)} and weight {blk.weight!r}."
            )
    counts = [len(blk.b) for blk in blocks]
    A = np.concatenate([blk.A for blk in blocks]).astype(float, copy=False)
    b = np.concatenate([blk.b for blk in blocks]).astype(float, copy=False)
    prio = np.repeat(np.array([blk.priority for blk in blocks], np.int64), counts)
    weight = np.repeat(np.array([blk.weight for blk in blocks], float), counts)
    if relaxed is None:
        return A, b, prio, weight
    return A, b, prio, weight, np.repeat(np.array(relaxed, bool), counts), _levels(blocks)


def _levels(blocks) -> np.ndarray:
    """The priorities made soft stage by stage (:func:`_levels_of`) of the blocks."""
    return _levels_of(tuple(blk.priority for blk in blocks))


def _stacked(constraints, step, k: int) -> tuple:
    """Every constraint's rows at the step, stacked: (A, b, priority, weight,
    second-order row, relaxed per row, the soft stages' priorities, the
    layout ((name, rows) per constraint with rows)). A constraint's
    second-order rows are checked (the compiled rounds trust them)."""
    blocks, so_rows, relaxed = [], [], []
    for c in constraints:
        A, b = c.rows(step)
        if not len(b):
            continue
        blocks.append(ConstraintRows(A, b, c.priority, c.weight, c.name))
        so = c.second_order_rows(step)
        if so is not None:
            so = np.asarray(so, np.int64)
            if so.shape != (len(b),) or (len(so) and so.max() >= len(step.damper.b)):
                raise ParameterError(
                    f"constraint '{c.name}': second_order_rows must give one damper row index (or -1) per row "
                    f"({len(b)} rows, {len(step.damper.b)} damper rows), got shape {so.shape} with largest "
                    f"{so.max(initial=-1)}."
                )
        so_rows.append(so)
        relaxed.append(bool(c.relaxed))
    A, b, prio, weight, relaxed_rows, levels = _stack(blocks, k, tuple(relaxed))
    so_row = np.full(len(b), -1, np.int64)
    at = 0
    for blk, so in zip(blocks, so_rows):
        if so is not None:
            so_row[at : at + len(so)] = so
        at += len(blk.b)
    return A, b, prio, weight, so_row, relaxed_rows, levels, tuple((blk.name, len(blk.b)) for blk in blocks)


def _plan(constraints):
    """For constraints that are all the filter's own (each with a
    :attr:`~FilterConstraint.stack` kind), what :func:`~.filter_kernel.stack_rows`
    needs besides the step: (kinds, weights, priorities, relaxed flags,
    damper pairs per block, names, whether a block is the damper's); else
    None. Made once per list of constraints."""
    key = tuple(map(id, constraints))
    memo = _PLANS.get(key)
    if memo is not None and all(a is b for a, b in zip(memo[0], constraints)):
        return memo[1]
    plan = None
    if constraints and all(c.stack is not None for c in constraints):
        P = max((len(c.pairs) for c in constraints if c.stack == DAMPER_ROWS), default=0)
        pairs = np.zeros((len(constraints), P), bool)
        for i, c in enumerate(constraints):
            if c.stack == DAMPER_ROWS:
                if len(c.pairs) != P:
                    raise ParameterError(
                        f"DamperConstraint '{c.name}': pairs must hold one flag per damper pair ({P}), "
                        f"got {len(c.pairs)}."
                    )
                pairs[i] = c.pairs
        plan = (
            np.array([c.stack for c in constraints], np.int64),
            np.array([c.weight for c in constraints], float),
            np.array([c.priority for c in constraints], np.int64),
            np.array([c.relaxed for c in constraints], bool),
            pairs,
            tuple(c.name for c in constraints),
            any(c.stack == DAMPER_ROWS for c in constraints),
        )
    if len(_PLANS) > 64:
        _PLANS.clear()
    _PLANS[key] = (tuple(constraints), plan)
    return plan


#: :func:`_plan` by the constraints' identities (kept with them, so an id is never reused while cached).
_PLANS: dict = {}


def _levels_of(prios: tuple) -> np.ndarray:
    """The soft stages' priorities of blocks of these priorities: the
    non-hard ones, lowest priority (largest number) first (read-only,
    made once per combination)."""
    out = _LEVELS.get(prios)
    if out is None:
        out = _LEVELS[prios] = np.array(sorted({p for p in prios if p != HARD}, reverse=True), np.int64)
        out.flags.writeable = False
    return out


#: :func:`_levels_of` by the blocks' priorities.
_LEVELS: dict = {}


def solve_rounds(qp: PriorityQP, constraints, step: FilterStep, v_t, *, rounds: int, nudge: float):
    """The velocity commanded for the request v_t (within the box and the
    limits): (v, missed: a :data:`ROW` row missed at v, solved: False where
    the QP failed and v holds as far as the box allows). The request as is
    where it meets every row at its own step; else the QP, the damper rows'
    right-hand sides at the last solution (their second-order term there,
    then the relaxation towards the nominal) until that solution meets its
    own (at most ``rounds`` solves; the right-hand sides only grow, a row
    still short by ``nudge`` more). One compiled call
    (:func:`~drake_cfvol.systems.filter.filter_kernel.filter_rounds`)."""
    k = len(v_t)
    plan = _plan(constraints)
    if plan is not None:  # the filter's own constraints only: stacked in one compiled call
        kinds, weights, prios, relaxed, pairs, names, has_damper = plan
        damper = step.damper
        _check_pairs(has_damper, pairs, damper)
        A, b, prio, weight, so_row, relaxed_rows, counts = stack_rows(
            kinds,
            weights,
            prios,
            relaxed,
            pairs,
            step.v_lo,
            step.v_hi,
            step.lo,
            step.hi,
            damper.A,
            damper.b,
            damper.pair,
            *step.stop,
        )
        counts = counts.tolist()
        layout = tuple((name, n) for name, n in zip(names, counts) if n)
        levels = _levels_of(tuple(p for p, n in zip(prios.tolist(), counts) if n))
        hints = qp.hints_for(layout)
    else:  # a constraint of the user's: each constraint's rows, stacked
        A, b, prio, weight, so_row, relaxed_rows, levels, layout = _stacked(constraints, step, k)
        hints = qp.hints_for(layout)
    damper, kin = step.damper, step.kinematics
    v, missed, solved, active, solves = filter_rounds(
        np.asarray(v_t, float),
        (A, b, prio, weight, so_row, relaxed_rows),
        (damper.A, damper.dirs, damper.points, damper.slots, damper.rounds, kin.rev),
        kin.compiled(),
        (step.q, step.q_c, step.nominal_or_nan(), step.lo, step.hi, step.vmax, step.drift),
        (levels, HARD, ROW, int(rounds), float(nudge), float(step.period)),
        hints,
    )
    qp.solves += solves
    if solves:
        qp.remember_layout(layout, active)
    return v, bool(missed), bool(solved)
