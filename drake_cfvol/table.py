"""The bounds table B = [b_1 .. b_g] and the rule for the box at any path
parameter s (docs/spec.md, sections 2 and 7).

This module is data only: it knows nothing of how the bounds were computed.
:func:`box_at` is the one implementation of the box-at-s rule; the systems,
the Confidence Factor and certification all call it.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np
from pydrake.trajectories import PiecewisePolynomial

from drake_cfvol._records import load_record, save_record
from drake_cfvol.exceptions import DimensionError, ParameterError

__all__ = ["BoundsTable", "absolute_bounds", "box_at", "nominal_trajectory"]

FORMAT_VERSION = 1
_ARRAYS = ("lower", "upper", "nominal")


def absolute_bounds(position_lower, position_upper, q) -> tuple[np.ndarray, np.ndarray]:
    """Algorithm 2's absolute bounds B: the position limits; a joint without
    limits uses nominal +- pi (docs/spec.md, section 2).

    Args:
        position_lower, position_upper: (k,) limits, rad or m (may be inf).
        q: (k,) or (n, k) nominal configurations.

    Returns:
        (lower, upper), shaped like ``q``.
    """
    q = np.asarray(q, float)
    lo = np.where(np.isfinite(position_lower), position_lower, q - np.pi)
    hi = np.where(np.isfinite(position_upper), position_upper, q + np.pi)
    return np.broadcast_to(lo, q.shape).copy(), np.broadcast_to(hi, q.shape).copy()


def nominal_trajectory(nominal: np.ndarray) -> PiecewisePolynomial:
    """The nominal as a function of the path parameter s in [0, g-1]: linear
    between waypoints (a first-order hold), held constant outside."""
    nominal = np.asarray(nominal, float)
    return PiecewisePolynomial.FirstOrderHold(np.arange(len(nominal), dtype=float), nominal.T)


def box_at(lower: np.ndarray, upper: np.ndarray, nominal: np.ndarray, s, *,
           trajectory: PiecewisePolynomial | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The box at path parameters s (docs/spec.md, section 7), vectorised.

    At an integer s the waypoint's box. Between waypoints i and i+1: the
    intersection of the two boxes, widened where needed to hold the
    interpolated nominal.

    Args:
        lower, upper, nominal: (g, k) per-waypoint bounds and nominal.
        s: a scalar or (n,) path parameters in [0, g-1].
        trajectory: :func:`nominal_trajectory` of ``nominal`` (saves building it).

    Returns:
        (lower, upper, nominal), each (k,) for a scalar s, else (n, k).

    Raises:
        ParameterError: an s outside [0, g-1] or not finite.
    """
    g = len(nominal)
    scalar = np.ndim(s) == 0
    s = np.atleast_1d(np.asarray(s, float))
    bad = ~np.isfinite(s) | (s < 0) | (s > g - 1)
    if bad.any():
        raise ParameterError(f"path index s = {s[bad][0]} is outside [0, {g - 1}] (g = {g} waypoints).")
    traj = trajectory if trajectory is not None else nominal_trajectory(nominal)
    nom = traj.vector_values(s).T if g > 1 else np.repeat(nominal[:1], len(s), axis=0)
    i = np.clip(np.floor(s).astype(int), 0, max(g - 2, 0))
    j = np.minimum(i + 1, g - 1)
    t = s - i
    lo = np.minimum(np.maximum(lower[i], lower[j]), nom)
    hi = np.maximum(np.minimum(upper[i], upper[j]), nom)
    at_i, at_j = t == 0.0, t == 1.0
    lo[at_i], hi[at_i], nom[at_i] = lower[i[at_i]], upper[i[at_i]], nominal[i[at_i]]
    lo[at_j], hi[at_j], nom[at_j] = lower[j[at_j]], upper[j[at_j]], nominal[j[at_j]]
    if scalar:
        return lo[0], hi[0], nom[0]
    return lo, hi, nom


@dataclasses.dataclass
class BoundsTable:
    """Per-waypoint joint bounds B = [b_1 .. b_g] along a nominal path.

    Attributes:
        lower, upper, nominal: (g, k), rad or m.
        joint_names: the k joints.
        limit_lower, limit_upper: (k,) the absolute bounds used.
        params: the parameters used (a dict).
        timing_ms: categorize / volume / bounding / total (and certify), ms.
        info: everything else worth keeping (cell, path label, seed,
            backend, categories, n_boxes, lowered, dropped, test counts).
        volume: the volume V and the obstacle categories it was grown from
            (a :class:`drake_cfvol.volume.VolumeBuild`), or None for a table
            loaded from disk (not saved; rebuild it with
            :func:`drake_cfvol.volume.build_volume`).
    """

    lower: np.ndarray
    upper: np.ndarray
    nominal: np.ndarray
    joint_names: list[str]
    limit_lower: np.ndarray
    limit_upper: np.ndarray
    params: dict = dataclasses.field(default_factory=dict)
    timing_ms: dict = dataclasses.field(default_factory=dict)
    info: dict = dataclasses.field(default_factory=dict)
    volume: Any = dataclasses.field(default=None, repr=False, compare=False)

    def __post_init__(self):
        for name in ("lower", "upper", "nominal", "limit_lower", "limit_upper"):
            setattr(self, name, np.asarray(getattr(self, name), float))
        if not (self.lower.shape == self.upper.shape == self.nominal.shape) or self.nominal.ndim != 2:
            raise DimensionError("bounds arrays", self.nominal.shape, (self.lower.shape, self.upper.shape))
        if self.nominal.shape[1] != len(self.joint_names):
            raise DimensionError("bounds columns", len(self.joint_names), self.nominal.shape[1])
        self._trajectory = nominal_trajectory(self.nominal)

    @property
    def g(self) -> int:
        """Number of waypoints."""
        return self.nominal.shape[0]

    @property
    def k(self) -> int:
        """Number of joints."""
        return self.nominal.shape[1]

    @property
    def trajectory(self) -> PiecewisePolynomial:
        """The nominal as a Drake trajectory of s (:func:`nominal_trajectory`)."""
        return self._trajectory

    @property
    def s(self) -> np.ndarray:
        """The path parameter of each waypoint: 0 .. g-1."""
        return np.arange(self.g, dtype=float)

    def at(self, s: float):
        """(lower, upper, nominal) at path parameter s in [0, g-1]."""
        return box_at(self.lower, self.upper, self.nominal, float(s), trajectory=self._trajectory)

    def boxes_at(self, s: np.ndarray):
        """:meth:`at` for many s at once: three (n, k) arrays."""
        return box_at(self.lower, self.upper, self.nominal, np.asarray(s, float), trajectory=self._trajectory)

    def widths(self) -> np.ndarray:
        """(g, k) upper - lower."""
        return self.upper - self.lower

    def to_json_dict(self) -> dict:
        return {"format": "drake_cfvol.BoundsTable", "version": FORMAT_VERSION,
                "joint_names": list(self.joint_names), "lower": self.lower.tolist(),
                "upper": self.upper.tolist(), "nominal": self.nominal.tolist(),
                "limit_lower": self.limit_lower.tolist(), "limit_upper": self.limit_upper.tolist(),
                "params": self.params, "timing_ms": self.timing_ms, "info": _jsonable(self.info)}

    def save(self, path: str | Path, *, overwrite: bool = False) -> Path:
        """Saves as ``.npz`` (arrays + JSON metadata) or ``.json`` (the
        volume is not saved)."""
        return save_record(path, self.to_json_dict(), _ARRAYS, "bounds", overwrite=overwrite)

    @classmethod
    def load(cls, path: str | Path) -> "BoundsTable":
        """Loads a table saved by :meth:`save` (``volume`` is None)."""
        d, a = load_record(path, _ARRAYS, "bounds")
        return cls(a["lower"], a["upper"], a["nominal"], d["joint_names"],
                   np.array(d["limit_lower"], float), np.array(d["limit_upper"], float),
                   d.get("params", {}), d.get("timing_ms", {}), d.get("info", {}))


def _jsonable(obj):
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, (np.floating, np.integer)):
        return obj.item()
    return obj
