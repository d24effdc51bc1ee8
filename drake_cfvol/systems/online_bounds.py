"""Bounds re-estimated online from the perceived obstacles, as a Drake
system (SPEC 12)."""

import dataclasses

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import Context, LeafSystem

from drake_cfvol.exceptions import ParameterError
from drake_cfvol.online.obstacle_map import MapGrid, ObstacleMap
from drake_cfvol.online.reestimate import FrozenLog, OnlineBounds

__all__ = ["OnlineBoundsConfig", "OnlineBoundsEstimator"]


@dataclasses.dataclass
class OnlineBoundsConfig:
    """How often and how far ahead the bounds are re-estimated.

    Attributes:
        period: s between updates (an update computed at t is in force from
            t + period); > 0.
        horizon: stretches ahead of the path index searched again at an
            update; >= 1.
    """

    period: float = 0.05
    horizon: int = 8


class OnlineBoundsEstimator(LeafSystem):
    """Re-estimates the volume and the bounds ahead whenever the obstacle map
    changes (:class:`~drake_cfvol.online.OnlineBounds`), and publishes them.

    .. pydrake_system::

        name: OnlineBoundsEstimator
        input_ports:
        - obstacle_map
        - path_index
        output_ports:
        - bounds
        - bounds_version

    Every ``period`` s the system publishes what it computed at its last
    update (the computation is given one period: bounds computed from the
    map at t are in force from t + period), then re-estimates from the map
    and the path index now. ``bounds`` is a
    :class:`~drake_cfvol.online.LiveBounds` (connect it to
    :class:`JointBoundsSource`'s ``bounds`` input); ``bounds_version`` counts
    the changes in force.

    The published bounds and the log of updates are the context's state;
    the incremental caches (the kernel's scene and the searches' footprints)
    live in the system: simulate one context at a time (:meth:`reset` before
    another run).

    Args:
        online: the re-estimator (its base table and settings).
        grid: the obstacle map's grid.
        period: s between updates.
        offset: s before the first.
    """

    #: Per update in the log: time, compute ms, map stamp, stretches searched,
    #: version in force after publishing, map changed (1/0).
    LOG_FIELDS = ("time", "compute_ms", "map_stamp", "recomputed", "version", "map_changed")

    def __init__(
        self, online: OnlineBounds, grid: MapGrid, *, period: float = OnlineBoundsConfig.period, offset: float = 0.0
    ):
        super().__init__()
        if not period > 0:
            raise ParameterError(f"OnlineBoundsEstimator: period must be > 0 s, got {period!r}.")
        self.online, self.period = online, float(period)
        #: The bounds in force before any update (the known cell's).
        self.initial_bounds = online.live
        self.obstacle_map_input = self.DeclareAbstractInputPort(
            "obstacle_map", AbstractValue.Make(ObstacleMap.empty(grid))
        )
        self.path_index_input = self.DeclareVectorInputPort(name="path_index", size=1)
        self._published = self.DeclareAbstractState(AbstractValue.Make(online.live))
        self._computed = self.DeclareAbstractState(AbstractValue.Make(online.live))
        self._log = self.DeclareAbstractState(AbstractValue.Make(FrozenLog()))
        self._last_map = self.DeclareAbstractState(AbstractValue.Make(ObstacleMap.empty(grid)))
        self.DeclarePeriodicUnrestrictedUpdateEvent(
            period_sec=self.period, offset_sec=float(offset), update=self._update
        )
        self.bounds_output = self.DeclareStateOutputPort("bounds", self._published)
        self.bounds_version_output = self.DeclareVectorOutputPort(
            "bounds_version",
            1,
            lambda c, o: o.SetAtIndex(0, float(c.get_abstract_state(self._published).get_value().version)),
            prerequisites_of_calc={self.abstract_state_ticket(self._published)},
        )

    def reset(self) -> None:
        """A fresh re-estimator for another run (same base table and settings)."""
        o = self.online
        self.online = OnlineBounds(o.workcell, o.base, horizon=o.horizon, max_proofs=o.max_proofs)

    def log(self, context: Context) -> np.ndarray:
        """(n, 6) the updates so far (:data:`LOG_FIELDS`)."""
        rows = context.get_abstract_state(self._log).get_value()
        return np.array(rows, float).reshape(-1, len(self.LOG_FIELDS))

    def _update(self, context, state) -> None:
        computed = context.get_abstract_state(self._computed).get_value()
        state.get_mutable_abstract_state(self._published).set_value(computed)
        m = self.obstacle_map_input.Eval(context)
        last = context.get_abstract_state(self._last_map).get_value()
        s = float(self.path_index_input.Eval(context)[0])
        u = self.online.update(m, s)
        changed = not m.same_as(last)
        state.get_mutable_abstract_state(self._computed).set_value(self.online.live)
        state.get_mutable_abstract_state(self._last_map).set_value(m)
        row = (context.get_time(), u.time_ms, m.stamp, u.recomputed, computed.version, float(changed))
        state.get_mutable_abstract_state(self._log).set_value(
            context.get_abstract_state(self._log).get_value() + (row,)
        )
