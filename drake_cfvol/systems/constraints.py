"""The safety filter's constraints (SPEC 9): each contributes rows
A v >= b on the commanded joint velocity v, with a priority, to the
filter's QP (:class:`PriorityQP`). Adding a constraint is adding a
subclass of :class:`FilterConstraint` and passing it to
:class:`~drake_cfvol.systems.SafetyFilter` (``constraints=``).

Priorities, by the QP's stages (:class:`PriorityQP`):

- :data:`HARD`: never given up (the velocity limits; a tool speed limit);
- :data:`ROW`: given up only where the hard rows leave no way, missed as
  little as possible (the damper's rows, perceived obstacles);
- :data:`BOX`: gives way to a :data:`ROW` row (the bounds' box).
"""

from __future__ import annotations

import itertools
from typing import NamedTuple

import numpy as np
from pydrake.multibody.tree import JacobianWrtVariable

from drake_cfvol.exceptions import ParameterError
from drake_cfvol.systems.qp import QP_OPTIMAL, solve_qp

__all__ = [
    "HARD",
    "ROW",
    "BOX",
    "ConstraintRows",
    "FilterStep",
    "FilterConstraint",
    "VelocityLimits",
    "JointBox",
    "DamperConstraint",
    "ToolSpeedLimit",
    "PriorityQP",
    "solve_rounds",
]

#: Priorities (see the module's documentation).
HARD, ROW, BOX = 0, 1, 2


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
        nominal: the nominal at the next path position (k,), or None.
        damper: the damper's rows at q (:class:`~drake_cfvol.systems.damper.DamperRows`).
    """

    def __init__(
        self, *, q, q_c, period, lo, hi, vmax, nominal, damper, plant, robot_slice, plant_context, second_order
    ):
        self.q, self.q_c, self.period, self.lo, self.hi, self.vmax = q, q_c, period, lo, hi, vmax
        self.nominal, self.damper = nominal, damper
        self.plant, self.robot_slice = plant, robot_slice
        self._pctx, self._second_order, self._memo = plant_context, second_order, (None, None)

    def plant_context(self):
        """The filter's scratch plant context, posed at :attr:`q`."""
        self.robot_slice.set_positions(self._pctx, self.q)
        return self._pctx

    def second_order(self, v) -> np.ndarray:
        """Per damper row, what the step v dt loses beyond its first-order
        change, m (:meth:`~drake_cfvol.systems.damper.VelocityDamper.second_order`;
        computed once per v)."""
        key = np.asarray(v, float).tobytes()
        if self._memo[0] != key:
            self._memo = (key, self._second_order(np.asarray(v, float) * self.period))
        return self._memo[1]


class FilterConstraint:
    """A constraint of the safety filter: rows A v >= b at each update.

    Subclasses set :attr:`name`, :attr:`priority` and :attr:`weight` and
    implement :meth:`rows`; a row whose right-hand side depends on the step
    taken (a second-order term) also implements :meth:`at`.
    """

    name = "constraint"
    priority = ROW
    weight = 1e6

    def rows(self, step: FilterStep) -> tuple[np.ndarray, np.ndarray]:
        """(A (m, k), b (m,)) at this update, to first order."""
        raise NotImplementedError

    def at(self, step: FilterStep, A, b, v) -> np.ndarray:
        """The right-hand sides the rows need for the step v (default b)."""
        return b


class VelocityLimits(FilterConstraint):
    """|v_j| <= vmax_j (:data:`HARD`)."""

    name, priority = "velocity_limits", HARD

    def rows(self, step):
        k = len(step.vmax)
        finite = np.isfinite(step.vmax)
        eye = np.eye(k)[finite]
        return np.vstack([eye, -eye]), np.concatenate([-step.vmax[finite], -step.vmax[finite]])


class JointBox(FilterConstraint):
    """lower <= q_c + v dt <= upper, the box at the next path position, as
    the velocity interval lo <= v <= hi (:data:`BOX`: gives way to a row)."""

    name, priority = "box", BOX

    def __init__(self, weight: float):
        self.weight = float(weight)

    def rows(self, step):
        k = len(step.lo)
        eye = np.eye(k)
        return np.vstack([eye, -eye]), np.concatenate([step.lo, -step.hi])


class DamperConstraint(FilterConstraint):
    """The velocity damper's rows (SPEC 9), with their second-order term
    and, for the static scene, the relaxation towards the nominal.

    Args:
        weight: the weight of a miss.
        relax: the rows' relaxation towards the nominal (``relax(q, nominal,
            lo, hi, A, b)``), or None for rows never relaxed (perceived,
            moving obstacles: the nominal is not known to be free of them).
        select: (rows) -> bools, which of the damper's rows are this
            constraint's.
        name: the constraint's name.
    """

    priority = ROW

    def __init__(self, *, weight: float, relax, select, name: str):
        self.weight, self._relax, self._select, self.name = float(weight), relax, select, name

    def rows(self, step):
        rows = step.damper
        mask = self._select(rows)
        return rows.A[mask], rows.b[mask]

    def at(self, step, A, b, v):
        rows = step.damper
        mask = self._select(rows)
        need = b + step.second_order(v)[mask] / step.period
        if self._relax is None or step.nominal is None or not np.all(np.isfinite(step.nominal)):
            return need
        return self._relax(step.q_c, step.nominal, step.lo, step.hi, A, need)


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

    def __init__(self, frame, speed: float, point=(0.0, 0.0, 0.0)):
        if not speed > 0:
            raise ParameterError(f"ToolSpeedLimit: speed must be > 0 m/s, got {speed}.")
        self.frame, self.speed = frame, float(speed)
        self.point = np.asarray(point, float).reshape(3)

    def jacobian(self, step) -> np.ndarray:
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

    def rows(self, step):
        DJ = _SPEED_DIRS @ self.jacobian(step)
        c = self.speed / _SPEED_RADIUS
        return np.vstack([DJ, -DJ]), np.full(2 * len(DJ), -c)


class PriorityQP:
    """The filter's QP, argmin |v - v_t|^2 over the constraints' rows, in
    stages by priority: first every row hard; if no v meets them all, the
    :data:`BOX` rows soft (a miss s >= 0 per row, cost weight s^2); then the
    :data:`ROW` rows soft too. :data:`HARD` rows are hard in every stage.
    Solved by :func:`~drake_cfvol.systems.qp.solve_qp`, warm-started from
    the last solve's active rows (by constraint and row)."""

    def __init__(self):
        self._warm: dict = {}

    def solve(self, v_t, blocks: list[ConstraintRows]):
        """The solution of the first stage that has one, or None."""
        return self.solve_staged(v_t, blocks)[0]

    def solve_staged(self, v_t, blocks: list[ConstraintRows]):
        """(v, the stage that gave it: 0 all rows hard, 1 the lowest
        priority soft, ...), or (None, None)."""
        levels = sorted({blk.priority for blk in blocks if blk.priority != HARD}, reverse=True)
        for stage in range(len(levels) + 1):
            soft_from = levels[stage - 1] if stage else None
            v = self._stage(np.asarray(v_t, float), blocks, soft_from)
            if v is not None:
                return v, stage
        return None, None

    @staticmethod
    def stage_problem(v_t, blocks, soft_from):
        """The stage's QP for :func:`~drake_cfvol.systems.qp.solve_qp`:
        (h, g, C, c, soft) over x = [v; one slack per soft row], ``soft``
        per block; blocks of priority >= ``soft_from`` (None: none) soft."""
        k = len(v_t)
        soft = [soft_from is not None and blk.priority != HARD and blk.priority >= soft_from for blk in blocks]
        n_s = sum(len(blk.b) for blk, s in zip(blocks, soft) if s)
        n = k + n_s
        h = np.concatenate(
            [np.full(k, 2.0)] + [np.full(len(blk.b), 2.0 * blk.weight) for blk, s in zip(blocks, soft) if s]
        )
        g = np.concatenate([-2.0 * np.asarray(v_t, float), np.zeros(n_s)])
        Cs, cs = [], []
        col = k
        for blk, s in zip(blocks, soft):
            m = len(blk.b)
            C = np.zeros((m, n))
            C[:, :k] = blk.A
            Cs.append(C)
            cs.append(blk.b)
            if s:  # A v + s >= b and s >= 0
                C[:, col : col + m] = np.eye(m)
                slack = np.zeros((m, n))
                slack[:, col : col + m] = np.eye(m)
                Cs.append(slack)
                cs.append(np.zeros(m))
                col += m
        C = np.vstack(Cs) if Cs else np.zeros((0, n))
        c = np.concatenate(cs) if cs else np.zeros(0)
        return h, g, C, c, soft

    def _stage(self, v_t, blocks, soft_from):
        k = len(v_t)
        h, g, C, c, soft = self.stage_problem(v_t, blocks, soft_from)
        warm = []
        for blk, s in zip(blocks, soft):
            warm.append(self._hint(blk.name, len(blk.b)))
            if s:
                warm.append(np.zeros(len(blk.b), bool))
        status, x, active = solve_qp(h, g, C, c, warm=np.concatenate(warm) if warm else None)
        if status != QP_OPTIMAL:
            return None
        at = 0
        for blk, s in zip(blocks, soft):
            m = len(blk.b)
            self._warm[blk.name] = active[at : at + m].copy()
            at += 2 * m if s else m
        return x[:k]

    def _hint(self, name, m):
        last = self._warm.get(name)
        return last if last is not None and len(last) == m else np.zeros(m, bool)


def solve_rounds(qp: PriorityQP, constraints, step: FilterStep, v_t, *, rounds: int, nudge: float):
    """The velocity commanded for the request v_t (within the box and the
    limits): (v, missed: a :data:`ROW` row missed at v, solved: False where
    the QP failed and v holds as far as the box allows). The request as is
    where it meets every row at its own step; else the QP, its right-hand
    sides at the last solution (:meth:`FilterConstraint.at`) until that
    solution meets its own (at most ``rounds`` solves; the right-hand sides
    only grow, a row still short by ``nudge`` more)."""
    first = [(c, *c.rows(step)) for c in constraints]
    first = [(c, A, b) for c, A, b in first if len(b)]

    def need(v):
        return [c.at(step, A, b, v) for c, A, b in first]

    def missed(v, bs):
        return any(c.priority == ROW and np.any(A @ v < b_v - 1e-6) for (c, A, _), b_v in zip(first, bs))

    bs = need(v_t)
    if all(np.all(A @ v_t >= b - 1e-12) for (_, A, _), b in zip(first, bs)):
        return v_t, False, True
    v = v_t
    for _ in range(rounds):
        v = qp.solve(v_t, [ConstraintRows(A, b, c.priority, c.weight, c.name) for (c, A, _), b in zip(first, bs)])
        if v is None:
            v = np.clip(np.zeros(len(v_t)), step.lo, step.hi)
            return v, missed(v, need(v)), False
        b_v = need(v)
        short = [A @ v < bv - 1e-9 for (_, A, _), bv in zip(first, b_v)]
        if not any(s.any() for s in short):
            return v, missed(v, b_v), True
        bs = [np.maximum(b, bv) + nudge * s for b, bv, s in zip(bs, b_v, short)]
    return v, missed(v, need(v)), True
