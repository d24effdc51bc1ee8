"""Parameters of the volume method (paper section IV-A, SPEC 4-6)."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

from drake_cfvol.exceptions import ParameterError
from drake_cfvol.io.arguments import instance
from drake_cfvol.scene.workcell import Workcell

__all__ = ["VolumeParams"]


@dataclasses.dataclass(frozen=True)
class VolumeParams:
    """Every parameter of the height function (eq. 1) and of joint bounding.

    Defaults are the paper's (section IV-A). Lengths in metres, angles in
    radians. A workcell's ``cfvol.params`` overrides the defaults; keyword
    arguments to :meth:`for_workcell` override both.

    Attributes:
        resolution: R, the most height-map cells, a count (> 0): the
            cells' side is sqrt(x_dim y_dim / R).
        alpha_t, alpha_g, alpha_ng: exponents of the trail, goal and
            no-goal terms Delta_t, Delta_g, Delta_ng (each in [0, 1]), no
            unit (> 0).
        d_t_lb, d_t_ub: floor and top of the trail term, m (0 <= d_t_lb <
            d_t_ub): Delta_t grows from 0 to 1 as a cell's distance to the
            trail's footprint grows from one to the other. Cells nearer the
            trail than ``d_t_lb`` get no column (activation A_t = 0).
        d_g_lb, d_g_ub: floor and top of the goal term, m (0 <= d_g_lb <
            d_g_ub): Delta_g grows from 0 to 1 as a cell's distance to the
            goal set's footprint grows from one to the other.
        d_ng_ub: top of the no-goal term, m (> 0): Delta_ng falls from 1 on
            the no-goal set's footprint to 0 this far from it.
        h_max: the largest height one term contributes, m (>= 0); a column
            is at most 3 h_max high.
        reach: cells whose centre is farther than this from the robot's
            base (or the segment its base travels on a rail) get no column,
            m (> 0). None: the workcell's ``reach`` (every cell if that is
            0).
        trail_radius: obstacles nearer than this to the robot at some
            nominal waypoint join the trail set, m (>= 0).
        goal_radius: the other obstacles nearer than this to the robot at
            the goal (signed distance) form the goal set, m (>= 0).
        delta: the tolerance of revolute joints' bounds, rad (> 0): a
            bound's search ends where an interval no wider than this beyond
            the bound may collide.
        delta_prismatic: the same for prismatic joints, m (> 0).
        column_clearance: columns are lowered to stay this far below the
            robot all along the nominal (its waypoints and the motion
            between them), m (>= 0).
        raster: pixel side of the rasters the footprints are drawn on for
            the height function's distances, m (> 0).
        waypoint_time: nominal seconds per waypoint, for the bounds' rate
            limit (each joint's velocity limit times this, per unit s), s
            (> 0). None: the nominal at NOMINAL_SPEED_FRACTION (25 %) of
            the velocity limits
            (:func:`drake_cfvol.algorithm.sweep.default_rate`).
        clearance: the safety margin, m (0 to 0.5): no configuration the
            bounds allow (and none the runtime safety filter commands) comes
            nearer to an obstacle or to the robot itself than min(clearance,
            the nominal's own clearance at s); planning keeps it too. The
            default, 0.02 m, covers the models' tolerance against the real
            cell (a few mm), a tracking error of a few mm at the tool and a
            margin left to stop in; 0 is the paper's setting (touching
            allowed), which the benchmark's paper tables use.
    """

    resolution: int = 1000
    alpha_t: float = 1.0
    alpha_g: float = 1.0
    alpha_ng: float = 1.0
    d_t_lb: float = 0.35
    d_t_ub: float = 1.5
    d_g_lb: float = 0.10
    d_g_ub: float = 2.0
    d_ng_ub: float = 0.5
    h_max: float = 1.5
    reach: float | None = None
    trail_radius: float = 0.10
    goal_radius: float = 0.50
    delta: float = 0.01
    delta_prismatic: float = 0.005
    column_clearance: float = 0.0
    raster: float = 0.04
    waypoint_time: float | None = None
    clearance: float = 0.02

    def __post_init__(self):
        def bad(msg):
            raise ParameterError(f"VolumeParams: {msg}")

        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if v is None:
                continue
            if not isinstance(v, (int, float)) or isinstance(v, bool) or not math.isfinite(v):
                bad(f"{f.name} must be a finite number, got {v!r}.")
        if not (isinstance(self.resolution, int) or float(self.resolution).is_integer()) or self.resolution <= 0:
            bad(f"resolution R must be a positive integer number of cells, got {self.resolution!r}.")
        object.__setattr__(self, "resolution", int(self.resolution))
        for name in ("alpha_t", "alpha_g", "alpha_ng"):
            if getattr(self, name) <= 0:
                bad(f"{name} must be > 0, got {getattr(self, name)}.")
        for lb, ub in (("d_t_lb", "d_t_ub"), ("d_g_lb", "d_g_ub")):
            if getattr(self, lb) < 0:
                bad(f"{lb} must be >= 0 m, got {getattr(self, lb)}.")
            if getattr(self, lb) >= getattr(self, ub):
                bad(f"{lb} ({getattr(self, lb)}) must be below {ub} ({getattr(self, ub)}).")
        if self.d_ng_ub <= 0:
            bad(f"d_ng_ub must be > 0 m, got {self.d_ng_ub}.")
        if self.h_max < 0:
            bad(f"h_max must be >= 0 m, got {self.h_max}.")
        if self.reach is not None and self.reach <= 0:
            bad(f"reach must be > 0 m, got {self.reach}.")
        for name in ("trail_radius", "goal_radius", "column_clearance", "clearance"):
            if getattr(self, name) < 0:
                bad(f"{name} must be >= 0 m, got {getattr(self, name)}.")
        if self.clearance > 0.5:
            bad(f"clearance must be at most 0.5 m (a safety margin of a few cm), got {self.clearance} m.")
        if self.waypoint_time is not None and self.waypoint_time <= 0:
            bad(f"waypoint_time must be > 0 s, got {self.waypoint_time}.")
        for name in ("delta", "delta_prismatic", "raster"):
            if getattr(self, name) <= 0:
                bad(f"{name} must be > 0, got {getattr(self, name)}.")

    @classmethod
    def for_workcell(cls, workcell: Workcell, **overrides: float | None) -> "VolumeParams":
        """Defaults, then the workcell's ``cfvol.params``, then ``overrides``."""
        instance(workcell, Workcell, "VolumeParams.for_workcell: workcell", "drake_cfvol.load_workcell")
        merged = dict(workcell.params)
        merged.update({k: v for k, v in overrides.items() if v is not None})
        _known(merged)
        if merged.get("reach") is None and workcell.reach > 0:
            merged["reach"] = workcell.reach
        return cls(**merged)

    def replace(self, **changes: Any) -> "VolumeParams":
        """A copy with some fields changed (validated)."""
        _known(changes)
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


def _known(values: dict) -> None:
    """Refuses parameters :class:`VolumeParams` does not have, naming the ones it has."""
    names = {f.name for f in dataclasses.fields(VolumeParams)}
    unknown = sorted(set(values) - names)
    if unknown:
        raise ParameterError(f"unknown parameter(s) {', '.join(unknown)}; known: {', '.join(sorted(names))}.")
