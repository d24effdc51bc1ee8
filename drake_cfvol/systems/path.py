"""The path's progress over time, the fastest safe rate for a table, and
their settings (:class:`PathProgressConfig`)."""

import dataclasses
import typing

import numpy as np
import numpy.typing as npt
from pydrake.systems.framework import Diagram, DiagramBuilder
from pydrake.systems.primitives import TrajectorySource
from pydrake.trajectories import PiecewisePolynomial

from drake_cfvol.algorithm.table import BoundsTable
from drake_cfvol.exceptions import ParameterError

__all__ = ["PathProgress", "PathProgressConfig", "path_ramp", "safe_path_rate"]


@dataclasses.dataclass
class PathProgressConfig:
    """How the path advances (:func:`~drake_cfvol.systems.AddCoManipulation`
    reads it).

    Attributes:
        velocity_share: the share of each joint's velocity limit that the
            path's own motion (nominal and bounds) may use; the push gets
            the rest (:func:`safe_path_rate`); in (0, 1).
        start_time: when the path starts, s (>= 0).
        max_rate: a cap on the path's rate, waypoints/s (None: the safe
            rate alone).
    """

    velocity_share: float = 0.5
    start_time: float = 0.0
    max_rate: typing.Optional[float] = None


def safe_path_rate(
    bounds: BoundsTable, velocity_limits: npt.ArrayLike, *, share: float = PathProgressConfig.velocity_share
) -> float:
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
        steps = np.max(
            [np.abs(np.diff(a, axis=0)).max(axis=0) for a in (bounds.nominal, bounds.lower, bounds.upper)], axis=0
        )
    else:
        steps = np.zeros(bounds.k)
    rate = np.asarray(bounds.rate, float)
    per_s = np.where(np.isfinite(rate), rate, steps)
    ok = np.isfinite(vmax) & (vmax > 0) & (per_s > 0)
    return float(np.min(share * vmax[ok] / per_s[ok])) if ok.any() else float("inf")


def _progress(g: int, rate: float, t0: float, ramp: float) -> PiecewisePolynomial:
    """s(t) from 0 at t0 to g - 1: at ``rate``, reached from rest and
    brought back to rest over ``ramp`` seconds each (s quadratic there: a
    cubic Hermite piece reproduces it exactly); without a ramp, linear."""
    span = (g - 1) / rate
    if ramp <= 0.0 or g < 2:
        return PiecewisePolynomial.FirstOrderHold([t0, t0 + max(span, 1e-9)], np.array([[0.0, g - 1.0]]))
    ramp = min(ramp, 0.999 * span)  # a short path: the two ramps nearly meet
    end = t0 + span + ramp
    # A last, constant microsecond: held after it, the end is g - 1 exactly (no rounding of a cubic).
    breaks = [t0, t0 + ramp, end - ramp, end, end + 1e-6]
    values = np.array([[0.0, rate * ramp / 2, g - 1.0 - rate * ramp / 2, g - 1.0, g - 1.0]])
    return PiecewisePolynomial.CubicHermite(breaks, values, np.array([[0.0, rate, rate, 0.0, 0.0]]))


class PathProgress(Diagram):
    """The path index over time: s(t) = clip(rate (t - start_time), 0, g-1),
    a Drake ``TrajectorySource`` of a first-order-hold trajectory; with a
    ``ramp``, reached from rest and brought back to rest over ``ramp``
    seconds each (so that the nominal starts and stops within the
    acceleration limits, :func:`path_ramp`).

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
        ramp: s (>= 0): the start's and the end's time to reach the rate from rest and back.
    """

    def __init__(self, g: int, *, rate: float, start_time: float = 0.0, lead: float = 0.0, ramp: float = 0.0):
        super().__init__()
        if not rate > 0:
            raise ParameterError(f"rate must be > 0 waypoints/s, got {rate}.")
        if int(g) < 1:
            raise ParameterError(f"g must be >= 1 waypoint, got {g}.")
        if not 0.0 <= ramp < np.inf:
            raise ParameterError(f"ramp must be a finite time >= 0 s, got {ramp}.")
        self.g, self.rate, self.start_time = int(g), float(rate), float(start_time)
        # Held at 0 before start_time and at g-1 after the end (Drake
        # trajectories hold their end values outside their time span).
        t0 = self.start_time
        self.trajectory = _progress(self.g, self.rate, t0, float(ramp))
        self.ramp = float(self.trajectory.end_time() - 1e-6 - t0 - (self.g - 1) / self.rate) if ramp > 0 else 0.0
        builder = DiagramBuilder()
        if not lead >= 0:
            raise ParameterError(f"lead must be >= 0 s, got {lead}.")
        self.lead = float(lead)
        source = builder.AddNamedSystem("trajectory", TrajectorySource(self.trajectory))
        ahead = _progress(self.g, self.rate, t0 - self.lead, float(ramp))
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
        return self.start_time + (self.g - 1) / self.rate + self.ramp


def path_ramp(bounds: BoundsTable, rate: float, acceleration_limits: npt.ArrayLike, *, share: float) -> float:
    """The ramp (s) over which the path reaches ``rate`` from rest so that
    the nominal accelerates no joint faster than ``share`` of its
    acceleration limit (the nominal's largest step per waypoint times the
    rate's change per second); 0 without acceleration limits."""
    a = np.asarray(acceleration_limits, float)
    if bounds.g < 2 or not np.isfinite(a).any() or not np.isfinite(rate):
        return 0.0
    steps = np.abs(np.diff(bounds.nominal, axis=0)).max(axis=0)
    ok = np.isfinite(a) & (a > 0)
    return float(np.max(rate * steps[ok] / (share * a[ok]), initial=0.0))
