"""The bounds table B = [b_1 .. b_g] and the rule for the box at any path
parameter s (docs/spec.md, sections 2 and 7).

This module is data only: it knows nothing of how the bounds were computed.
:func:`box_at` is the one implementation of the box-at-s rule; the systems,
the Confidence Factor and certification all call it.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
from numba import njit, prange
from pydrake.trajectories import PiecewisePolynomial

from drake_cfvol.exceptions import CfvolError, DimensionError, ParameterError, RecordFormatError
from drake_cfvol.io.arguments import instance, names, real_array, real_number
from drake_cfvol.io.records import load_record, save_record

__all__ = [
    "BoundsTable",
    "absolute_bounds",
    "check_table",
    "require_table",
    "box_at",
    "nominal_trajectory",
    "waypoint_boxes",
    "intersection_stretches",
    "rate_limited",
    "within_stretches",
    "INTERPOLATIONS",
]

#: Version 3 added ``interpolation`` (a version-2 file is read as "stretch").
FORMAT_VERSION = 3
#: The box-at-s rules between waypoints (docs/spec.md, section 7):
#: "stretch", the stretch box rate-limited (the paper's per-joint bounds);
#: "linear", each bound linear between its waypoints (certified tables:
#: every corner of the box moves on a straight segment over a stretch, so
#: the certificate can prove the box's edges and corners).
INTERPOLATIONS = ("stretch", "linear")
_ARRAYS = ("lower", "upper", "nominal")
#: How far (rad or m) a saved value may pass the one it must not pass:
#: float noise, far below any bound's meaning.
_CHECK_TOLERANCE = 1e-9
_STRETCH_ARRAYS = ("stretch_lower", "stretch_upper")


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


def intersection_stretches(lower: np.ndarray, upper: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Stretch boxes from waypoint boxes by the plain intersection of the
    two neighbours (the rule of format-1 tables)."""
    return np.maximum(lower[:-1], lower[1:]), np.minimum(upper[:-1], upper[1:])


def _envelopes(U: np.ndarray, rate: np.ndarray, sign: float) -> tuple[np.ndarray, np.ndarray]:
    """For the upper bound (sign +1): A[i] = min over i' < i of
    (U[i'] - rate (i' + 1)) and Bv[i] = min over i' > i of (U[i'] + rate i'),
    so that min(U[i], A[i] + rate s, Bv[i] - rate s) is the smallest of
    U[i'] + rate * dist(s, stretch i') for s in stretch i. For the lower bound
    (sign -1) the same with max and the signs turned."""
    n, k = U.shape
    idx = np.arange(n, dtype=float)[:, None]
    with np.errstate(invalid="ignore"):
        before = sign * U - rate * (idx + 1)
        after = sign * U + rate * idx
    before = np.where(np.isfinite(rate), before, np.inf)
    after = np.where(np.isfinite(rate), after, np.inf)
    A = np.full((n, k), np.inf)
    Bv = np.full((n, k), np.inf)
    if n > 1:
        A[1:] = np.minimum.accumulate(before[:-1], axis=0)
        Bv[:-1] = np.minimum.accumulate(after[::-1], axis=0)[::-1][1:]
    return A, Bv


#: The last envelopes computed, with copies of their inputs: a system
#: looking up one s at a time asks for the same table's again and again.
_LAST_ENVELOPES: list = []


@njit(cache=True)
def _equal(a, b):
    """Two arrays of one shape equal element by element (np.array_equal: NaN unequal)."""
    x, y = a.ravel(), b.ravel()
    for n in range(x.size):
        if not x[n] == y[n]:
            return False
    return True


@njit(cache=True)
def _same_inputs(lo, hi, r, stretch_lower, stretch_upper, rate):
    """The last envelopes' inputs (lo, hi, r) equal these, shapes and
    values (one compiled call per control update)."""
    return (
        lo.shape == stretch_lower.shape
        and hi.shape == stretch_upper.shape
        and r.shape == rate.shape
        and _equal(lo, stretch_lower)
        and _equal(hi, stretch_upper)
        and _equal(r, rate)
    )


def _stretch_envelopes(stretch_lower, stretch_upper, rate):
    """(Au, Bu, Al, Bl) of :func:`_envelopes`, reused while the inputs are
    equal to the last call's (compared by value, so an array changed in
    place is never served stale envelopes)."""
    rate = np.asarray(rate, float)
    if _LAST_ENVELOPES:
        (lo, hi, r), out = _LAST_ENVELOPES[0]
        if stretch_lower.ndim == 2 and stretch_upper.ndim == 2 and rate.ndim == 1:
            if _same_inputs(lo, hi, r, stretch_lower, stretch_upper, rate):
                return out
    Au, Bu = _envelopes(stretch_upper, rate, 1.0)
    Al, Bl = _envelopes(stretch_lower, rate, -1.0)
    _LAST_ENVELOPES[:] = [((stretch_lower.copy(), stretch_upper.copy(), rate.copy()), (Au, Bu, Al, Bl))]
    return Au, Bu, Al, Bl


def _stretch_rule(
    stretch_lower: np.ndarray, stretch_upper: np.ndarray, rate: np.ndarray, s: np.ndarray, i: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The rate-limited stretch bounds at path parameters s, each in stretch
    i (before the nominal is added; see :func:`box_at`)."""
    Au, Bu, Al, Bl = _stretch_envelopes(stretch_lower, stretch_upper, rate)
    r = np.where(np.isfinite(rate), rate, 0.0)
    sc = np.asarray(s, float)[..., None]  # (n, 1) for n values of s; (1,) for one
    hi = np.minimum(np.minimum(stretch_upper[i], Au[i] + r * sc), Bu[i] - r * sc)
    lo = -np.minimum(np.minimum(-stretch_lower[i], Al[i] + r * sc), Bl[i] - r * sc)
    return lo, hi


def _box_at_one(lower, upper, nominal, s: float, stretch_lower, stretch_upper, rate, interpolation):
    """:func:`box_at` at one s (g > 1; the stretch rule's defaults filled
    in), the same arithmetic on (k,) rows in one compiled call (the bounds
    source asks once per control update)."""
    g = len(nominal)
    if not (math.isfinite(s) and 0.0 <= s <= g - 1):
        raise ParameterError(f"path index s = {s} is outside [0, {g - 1}] (g = {g} waypoints).")
    if s == math.floor(s):
        w = int(s)
        return lower[w].copy(), upper[w].copy(), nominal[w].copy()
    if interpolation == "linear":
        return _box_one(lower, upper, nominal, s, True, lower, upper, lower, upper, lower, upper, np.zeros(0))
    Au, Bu, Al, Bl = _stretch_envelopes(stretch_lower, stretch_upper, rate)
    return _box_one(lower, upper, nominal, s, False, stretch_lower, stretch_upper, Au, Bu, Al, Bl, rate)


@njit(cache=True)
def _box_one(lower, upper, nominal, s, linear, stretch_lower, stretch_upper, Au, Bu, Al, Bl, rate):
    """(lo, hi, nom) at one s strictly inside a stretch: the "linear" rule
    (every bound between its waypoints' values), else the "stretch" rule
    (:func:`_stretch_rule`; the stretch arrays are unused for "linear");
    the vectorised rule's arithmetic, operation by operation."""
    g, k = nominal.shape
    i = min(int(math.floor(s)), g - 2)
    t = s - i
    lo, hi, nom = np.empty(k), np.empty(k), np.empty(k)
    for j in range(k):
        n = nominal[i, j] + t * (nominal[i + 1, j] - nominal[i, j])
        if linear:
            a = (1.0 - t) * lower[i, j] + t * lower[i + 1, j]
            b = (1.0 - t) * upper[i, j] + t * upper[i + 1, j]
        else:
            r = rate[j] if math.isfinite(rate[j]) else 0.0
            b = min(min(stretch_upper[i, j], Au[i, j] + r * s), Bu[i, j] - r * s)
            a = -min(min(-stretch_lower[i, j], Al[i, j] + r * s), Bl[i, j] - r * s)
        lo[j], hi[j], nom[j] = min(a, n), max(b, n), n
    return lo, hi, nom


@njit(cache=True)
def _box_ahead(lower, upper, nominal, s, end, linear, stretch_lower, stretch_upper, Au, Bu, Al, Bl, rate):
    """(lo, hi, nom, lo_ahead, hi_ahead) at one s in [0, g-1] (g > 1), by
    :func:`_box_one`'s rule (a waypoint's box at an integer): the box at s
    and the box ahead, the box at s tightened to the largest lower and the
    smallest upper deviation from the nominal of the boxes at the quarter
    steps in (s, end) and at ``end`` (none where end <= s), about the
    nominal at s and never past the box at s."""
    g, k = nominal.shape
    if s == math.floor(s):
        w = int(s)
        lo, hi, nom = lower[w].copy(), upper[w].copy(), nominal[w].copy()
    else:
        lo, hi, nom = _box_one(lower, upper, nominal, s, linear, stretch_lower, stretch_upper, Au, Bu, Al, Bl, rate)
    if not end > s:
        return lo, hi, nom, lo.copy(), hi.copy()
    dev_lo, dev_hi = lo - nom, hi - nom
    first, last = math.floor(4.0 * s) + 1.0, math.ceil(4.0 * end)
    n = max(int(last - first), 0)
    for m in range(n + 1):
        x = (first + m) / 4.0 if m < n else end
        if x == math.floor(x):
            w = int(x)
            lo_x, hi_x, nom_x = lower[w], upper[w], nominal[w]
        else:
            lo_x, hi_x, nom_x = _box_one(
                lower, upper, nominal, x, linear, stretch_lower, stretch_upper, Au, Bu, Al, Bl, rate
            )
        for j in range(k):
            dev_lo[j] = max(dev_lo[j], lo_x[j] - nom_x[j])
            dev_hi[j] = min(dev_hi[j], hi_x[j] - nom_x[j])
    lo_a, hi_a = np.empty(k), np.empty(k)
    for j in range(k):
        lo_a[j] = min(max(nom[j] + min(dev_lo[j], 0.0), lo[j]), hi[j])
        hi_a[j] = min(max(nom[j] + max(dev_hi[j], 0.0), lo[j]), hi[j])
    return lo, hi, nom, lo_a, hi_a


@njit(cache=True, parallel=True)
def _linear_boxes(lower, upper, nominal, s, i):
    """box_at's "linear" rule for (n,) s in stretches i (g > 1), in its
    arithmetic bit for bit: each bound linear between its waypoints', held
    at the nominal; at an integer s the waypoint's box and nominal."""
    n, k = len(s), nominal.shape[1]
    lo, hi, nom = np.empty((n, k)), np.empty((n, k)), np.empty((n, k))
    for r in prange(n):  # rows apart: the same values on any thread
        a = i[r]
        t = s[r] - a
        w = int(s[r])
        exact = s[r] == math.floor(s[r])
        for j in range(k):
            if exact:
                lo[r, j], hi[r, j], nom[r, j] = lower[w, j], upper[w, j], nominal[w, j]
                continue
            x = nominal[a, j] + t * (nominal[a + 1, j] - nominal[a, j])
            lo[r, j] = min((1.0 - t) * lower[a, j] + t * lower[a + 1, j], x)
            hi[r, j] = max((1.0 - t) * upper[a, j] + t * upper[a + 1, j], x)
            nom[r, j] = x
    return lo, hi, nom


def box_at(
    lower: np.ndarray,
    upper: np.ndarray,
    nominal: np.ndarray,
    s,
    *,
    stretch_lower: np.ndarray | None = None,
    stretch_upper: np.ndarray | None = None,
    rate: np.ndarray | None = None,
    interpolation: str = "stretch",
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The box at path parameters s (docs/spec.md, section 7), vectorised.

    At an integer s: the waypoint's box. In stretch [i, i+1], by
    ``interpolation``:

    - "stretch": its certified stretch box, tightened so that no bound
      changes faster than ``rate`` per unit s (the smallest of the stretch
      bounds plus rate times the distance to their stretch), and widened
      where needed to hold the interpolated nominal. Without stretch boxes
      they are the intersection of the two waypoints' boxes; without a
      rate, no rate limit.
    - "linear": every bound linear from its value at waypoint i to its
      value at i + 1 (holds the nominal, which is linear too; the rate
      limit is the waypoints', :func:`rate_limited`).

    Args:
        lower, upper, nominal: (g, k) waypoint boxes and nominal.
        s: a scalar or (n,) path parameters in [0, g-1].
        stretch_lower, stretch_upper: (g-1, k) certified stretch boxes.
        rate: (k,) largest change of a bound per unit s (inf: none).

    Returns:
        (lower, upper, nominal), each (k,) for a scalar s, else (n, k).

    Raises:
        ParameterError: an s outside [0, g-1] or not finite.
    """
    if interpolation not in INTERPOLATIONS:
        raise ParameterError(
            f"interpolation must be one of {', '.join(map(repr, INTERPOLATIONS))}, got {interpolation!r}."
        )
    g, k = nominal.shape
    if interpolation == "stretch" and g > 1:
        if stretch_lower is None or stretch_upper is None:
            stretch_lower, stretch_upper = intersection_stretches(lower, upper)
        if rate is None:
            rate = np.full(k, np.inf)
        elif not (isinstance(rate, np.ndarray) and rate.shape == (k,) and rate.dtype == float):
            rate = np.broadcast_to(np.asarray(rate, float), (k,))
    scalar = isinstance(s, float) or np.ndim(s) == 0  # a float (the control loop): no array made
    if scalar and g > 1:
        return _box_at_one(lower, upper, nominal, float(s), stretch_lower, stretch_upper, rate, interpolation)
    s = np.atleast_1d(np.asarray(s, float))
    bad = ~np.isfinite(s) | (s < 0) | (s > g - 1)
    if bad.any():
        raise ParameterError(f"path index s = {s[bad][0]} is outside [0, {g - 1}] (g = {g} waypoints).")
    i = np.clip(np.floor(s).astype(int), 0, max(g - 2, 0))
    if g > 1 and interpolation == "linear":
        # One compiled pass: the certificate's search asks for millions.
        lo, hi, nom = _linear_boxes(lower, upper, nominal, s, i)
        return (lo[0], hi[0], nom[0]) if scalar else (lo, hi, nom)
    # The nominal, linear between waypoints (nominal_trajectory's values, bit for bit).
    nom = nominal[i] + (s - i)[:, None] * (nominal[i + 1] - nominal[i]) if g > 1 else nominal[i]
    if g == 1:
        lo, hi = lower[i], upper[i]
    else:
        # The stretch rule with g > 1: its arrays were filled in above.
        assert stretch_lower is not None and stretch_upper is not None and rate is not None
        lo, hi = _stretch_rule(stretch_lower, stretch_upper, rate, s, i)
        lo, hi = np.minimum(lo, nom), np.maximum(hi, nom)
        at = s == np.floor(s)
        w = s[at].astype(int)
        lo[at], hi[at], nom[at] = lower[w], upper[w], nominal[w]
    if scalar:
        return lo[0], hi[0], nom[0]
    return lo, hi, nom


def waypoint_boxes(
    stretch_lower: np.ndarray, stretch_upper: np.ndarray, nominal: np.ndarray, rate: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The waypoint boxes that the stretch rule gives at integer s (the limit
    from either side): both neighbouring stretches' bounds, rate-limited."""
    g = len(nominal)
    # The stretch rule at every integer s (s = g-1 lies in the last stretch).
    lo, hi = _stretch_rule(
        stretch_lower,
        stretch_upper,
        np.asarray(rate, float),
        np.arange(g, dtype=float),
        np.clip(np.arange(g), 0, g - 2),
    )
    # At an interior waypoint the previous stretch's cap also applies.
    hi[1 : g - 1] = np.minimum(hi[1 : g - 1], stretch_upper[: g - 2])
    lo[1 : g - 1] = np.maximum(lo[1 : g - 1], stretch_lower[: g - 2])
    return np.minimum(lo, nominal), np.maximum(hi, nominal)


def rate_limited(
    lower: np.ndarray, upper: np.ndarray, nominal: np.ndarray, rate: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Waypoint boxes tightened (never widened) so that no bound changes
    by more than ``rate`` from one waypoint to the next: the upper bound
    becomes min over i' of (upper[i'] + rate |i - i'|), the lower bound the
    mirror image; then held at the nominal (a no-op when the rate is at
    least the nominal's own step, as :func:`drake_cfvol.algorithm.sweep.default_rate`
    makes it). The "linear" rule then never moves a bound faster than rate."""
    lower, upper = np.asarray(lower, float), np.asarray(upper, float)
    rate = np.asarray(rate, float)
    r = np.where(np.isfinite(rate), rate, 0.0)
    lim = np.isfinite(rate)
    hi, lo = upper.copy(), lower.copy()
    for i in range(1, len(hi)):  # forward pass, then backward: the min over i' of U[i'] + rate |i - i'|
        hi[i] = np.where(lim, np.minimum(hi[i], hi[i - 1] + r), hi[i])
        lo[i] = np.where(lim, np.maximum(lo[i], lo[i - 1] - r), lo[i])
    for i in range(len(hi) - 2, -1, -1):
        hi[i] = np.where(lim, np.minimum(hi[i], hi[i + 1] + r), hi[i])
        lo[i] = np.where(lim, np.maximum(lo[i], lo[i + 1] - r), lo[i])
    return np.minimum(lo, nominal), np.maximum(hi, nominal)


def within_stretches(
    lower: np.ndarray, upper: np.ndarray, nominal: np.ndarray, stretch_lower: np.ndarray, stretch_upper: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Waypoint boxes tightened (never widened) so that under the "linear"
    rule no bound leaves what the stretch boxes prove: on stretch i, the
    upper bound at s stays at most max(stretch_upper[i], nom(s)) (lower
    mirrored). A waypoint's bound may sit at its nominal beyond the stretch
    box (SPEC 7, rule 3); then the line to the other waypoint may pass
    above both the stretch bound and the nominal where the nominal crosses
    the stretch bound, at t*. There the other end is lowered just enough:
    to the value whose line meets the stretch bound at t* (never below its
    nominal)."""
    lo, hi = np.array(lower, float), np.array(upper, float)
    nom = np.asarray(nominal, float)
    for sign, b, st in ((1.0, hi, stretch_upper), (-1.0, lo, stretch_lower)):
        for i in range(len(nom) - 1):
            a0, a1 = sign * b[i], sign * b[i + 1]
            n0, n1 = sign * nom[i], sign * nom[i + 1]
            cap = sign * st[i]
            with np.errstate(divide="ignore", invalid="ignore"):
                ts = (cap - n0) / (n1 - n0)
            cross = np.isfinite(ts) & (ts > 0) & (ts < 1)
            ts = np.where(cross, ts, 0.5)  # elsewhere unused (and inf - inf for a joint without limits)
            over = cross & ((1 - ts) * a0 + ts * a1 > cap)
            if not over.any():
                continue
            # The end where the nominal lies below the cap is the one to lower.
            lower_end1 = over & (n0 > cap)
            lower_end0 = over & ~(n0 > cap)
            with np.errstate(divide="ignore", invalid="ignore"):
                new1 = (cap - (1 - ts) * a0) / ts
                new0 = (cap - ts * a1) / (1 - ts)
            a1n = np.where(lower_end1, np.maximum(np.minimum(a1, new1), n1), a1)
            a0n = np.where(lower_end0, np.maximum(np.minimum(a0, new0), n0), a0)
            b[i], b[i + 1] = sign * a0n, sign * a1n
    return np.minimum(lo, nom), np.maximum(hi, nom)


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
            (a :class:`drake_cfvol.algorithm.volume.VolumeBuild`), or None for a table
            loaded from disk (not saved; rebuild it with
            :func:`drake_cfvol.algorithm.volume.build_volume`).
        stretch_lower, stretch_upper: (g-1, k) the certified box of each
            stretch [i, i+1] (default: the intersection of its two waypoint
            boxes, as in format-1 files).
        rate: (k,) the largest change of a bound per unit s (inf: none).
        interpolation: the box between waypoints, "stretch" or "linear"
            (:func:`box_at`; certified tables are "linear").
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
    stretch_lower: np.ndarray | None = None
    stretch_upper: np.ndarray | None = None
    rate: np.ndarray | None = None
    interpolation: str = "stretch"

    def __post_init__(self):
        for name in ("lower", "upper", "nominal", "limit_lower", "limit_upper"):
            setattr(self, name, real_array(getattr(self, name), f"BoundsTable: {name}"))
        self.joint_names = names(self.joint_names, "BoundsTable: joint_names")
        for name in ("params", "timing_ms", "info"):
            instance(getattr(self, name), dict, f"BoundsTable: {name}")
        if not (self.lower.shape == self.upper.shape == self.nominal.shape) or self.nominal.ndim != 2:
            raise DimensionError("bounds arrays", self.nominal.shape, (self.lower.shape, self.upper.shape))
        if self.nominal.shape[1] != len(self.joint_names):
            raise DimensionError("bounds columns", len(self.joint_names), self.nominal.shape[1])
        g, k = self.nominal.shape
        if self.stretch_lower is None or self.stretch_upper is None:
            self.stretch_lower, self.stretch_upper = intersection_stretches(self.lower, self.upper)
        self.stretch_lower = real_array(self.stretch_lower, "BoundsTable: stretch_lower")
        self.stretch_upper = real_array(self.stretch_upper, "BoundsTable: stretch_upper")
        if self.stretch_lower.shape != (max(g - 1, 0), k) or self.stretch_upper.shape != (max(g - 1, 0), k):
            raise DimensionError("stretch bounds", (g - 1, k), (self.stretch_lower.shape, self.stretch_upper.shape))
        self.rate = np.full(k, np.inf) if self.rate is None else real_array(self.rate, "BoundsTable: rate")
        if self.rate.size != k:
            raise DimensionError("BoundsTable: rate (one per joint)", k, self.rate.shape)
        self.rate = self.rate.reshape(k)
        if self.interpolation not in INTERPOLATIONS:
            raise ParameterError(
                f"BoundsTable: interpolation must be one of {', '.join(map(repr, INTERPOLATIONS))}"
                f", got {self.interpolation!r}."
            )
        self._trajectory = nominal_trajectory(self.nominal)

    def __getstate__(self) -> dict:
        """Pickled (to another process, e.g. a Dask worker's result) as it
        is saved: without the volume V (Drake objects; rebuild it with
        :func:`drake_cfvol.algorithm.volume.build_volume`); the nominal's
        trajectory is rebuilt on arrival."""
        state = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        state["volume"] = None
        return state

    def __setstate__(self, state: dict) -> None:
        for name, value in state.items():
            setattr(self, name, value)
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

    def at(self, s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(lower, upper, nominal) at path parameter s in [0, g-1]."""
        return box_at(
            self.lower,
            self.upper,
            self.nominal,
            real_number(s, "BoundsTable.at: s (one path parameter; boxes_at takes many)"),
            stretch_lower=self.stretch_lower,
            stretch_upper=self.stretch_upper,
            rate=self.rate,
            interpolation=self.interpolation,
        )

    def box_ahead(
        self, s: float, lookahead: float
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(lower, upper, nominal, lower_ahead, upper_ahead) at path parameter
        s in [0, g-1], in one compiled call (the control loop's bounds
        source asks once per update): :meth:`at`, and the box at s tightened
        to the deviations from the nominal that the boxes allow at the
        quarter steps over (s, min(s + lookahead, g-1)] (the box at s where
        that is empty), about the nominal at s, never past the box at s."""
        s = real_number(s, "BoundsTable.box_ahead: s")
        g = self.g
        if g < 2 or not 0.0 <= s <= g - 1:
            lo, hi, nom = self.at(s)  # one waypoint, or raises for an s outside
            return lo, hi, nom, lo.copy(), hi.copy()
        end = min(s + float(lookahead), g - 1.0)
        if self.interpolation == "linear":
            z, L, U = np.zeros(0), self.lower, self.upper
            return _box_ahead(L, U, self.nominal, s, end, True, L, U, L, U, L, U, z)
        sl, su, rate = self.stretch_lower, self.stretch_upper, self.rate
        assert sl is not None and su is not None and rate is not None  # filled in by __post_init__
        Au, Bu, Al, Bl = _stretch_envelopes(sl, su, rate)
        return _box_ahead(self.lower, self.upper, self.nominal, s, end, False, sl, su, Au, Bu, Al, Bl, rate)

    def boxes_at(self, s: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`at` for many s at once: three (n, k) arrays."""
        return box_at(
            self.lower,
            self.upper,
            self.nominal,
            real_array(s, "BoundsTable.boxes_at: s", ndim=(0, 1)),
            stretch_lower=self.stretch_lower,
            stretch_upper=self.stretch_upper,
            rate=self.rate,
            interpolation=self.interpolation,
        )

    def widths(self) -> np.ndarray:
        """(g, k) upper - lower."""
        return self.upper - self.lower

    def problem(
        self, position_lower: npt.ArrayLike | None = None, position_upper: npt.ArrayLike | None = None
    ) -> str | None:
        """What makes the table unusable, as one phrase (the first found), or
        None: a non-finite value, lower > upper, a nominal outside its box,
        a negative rate (a stretch's bounds may cross: :func:`box_at` widens
        them to hold the nominal, as the sweep leaves a joint with no room), or (given the robot's position limits, inf where a
        joint has none) a box outside the limits."""
        assert (
            self.stretch_lower is not None and self.stretch_upper is not None and self.rate is not None
        )  # __post_init__
        arrays = {
            "lower": self.lower,
            "upper": self.upper,
            "nominal": self.nominal,
            "stretch_lower": self.stretch_lower,
            "stretch_upper": self.stretch_upper,
        }
        for name, a in arrays.items():
            bad = np.argwhere(~np.isfinite(a))
            if len(bad):
                i, j = bad[0]
                unit = "stretch" if name.startswith("stretch") else "waypoint"
                return f"{name} of joint '{self.joint_names[j]}' at {unit} {i + 1} is {a[i, j]}, not a finite number"
        for name, a in (("limit_lower", self.limit_lower), ("limit_upper", self.limit_upper)):
            if a.shape != (self.k,) or np.isnan(a).any():
                return f"{name} must hold {self.k} numbers, got {np.asarray(a).tolist()}"
        if np.isnan(self.rate).any() or (self.rate < 0).any():
            return f"rate must be >= 0 (or none) for every joint, got {self.rate.tolist()}"
        inf = np.full(self.k, np.inf)
        if (
            position_lower is not None
            and position_upper is not None
            and np.shape(position_lower) == np.shape(position_upper) == (self.k,)
        ):
            lo = np.where(np.isfinite(position_lower), position_lower, -np.inf)
            hi = np.where(np.isfinite(position_upper), position_upper, np.inf)
        else:  # no limits, or another robot's (its joints are named where they are compared)
            lo, hi = -inf, inf
        tol = _CHECK_TOLERANCE
        checks = (
            ("lower", self.lower, "upper", self.upper, "waypoint"),
            ("lower", self.lower, "nominal", self.nominal, "waypoint"),
            ("nominal", self.nominal, "upper", self.upper, "waypoint"),
            ("the joint's lower limit", np.broadcast_to(lo, self.lower.shape), "lower", self.lower, "waypoint"),
            ("upper", self.upper, "the joint's upper limit", np.broadcast_to(hi, self.upper.shape), "waypoint"),
        )
        for a_name, a, b_name, b, unit in checks:
            bad = np.argwhere(a > b + tol)
            if len(bad):
                i, j = bad[0]
                return (
                    f"{a_name} {a[i, j]:.6g} > {b_name} {b[i, j]:.6g} for joint '{self.joint_names[j]}' "
                    f"at {unit} {i + 1} (counted from 1)"
                )
        return None

    def to_json_dict(self) -> dict:
        assert (
            self.stretch_lower is not None and self.stretch_upper is not None and self.rate is not None
        )  # __post_init__
        return {
            "format": "drake_cfvol.BoundsTable",
            "version": FORMAT_VERSION,
            "joint_names": list(self.joint_names),
            "lower": self.lower.tolist(),
            "upper": self.upper.tolist(),
            "nominal": self.nominal.tolist(),
            "limit_lower": self.limit_lower.tolist(),
            "limit_upper": self.limit_upper.tolist(),
            "stretch_lower": self.stretch_lower.tolist(),
            "stretch_upper": self.stretch_upper.tolist(),
            "rate": [v if np.isfinite(v) else None for v in self.rate.tolist()],
            "interpolation": self.interpolation,
            "params": self.params,
            "timing_ms": self.timing_ms,
            "info": _jsonable(self.info),
        }

    def save(self, path: str | Path, *, overwrite: bool = False) -> Path:
        """Saves as ``.npz`` (arrays + JSON metadata) or ``.json`` (the
        volume is not saved)."""
        return save_record(path, self.to_json_dict(), _ARRAYS + _STRETCH_ARRAYS, "bounds", overwrite=overwrite)

    @classmethod
    def load(cls, path: str | Path) -> "BoundsTable":
        """Loads a table saved by :meth:`save` (``volume`` is None).

        Raises:
            RecordFormatError: the file is missing, empty, truncated or not a table.
        """
        d, a = load_record(
            path, _ARRAYS, "bounds", optional=_STRETCH_ARRAYS, required=("joint_names", "limit_lower", "limit_upper")
        )
        version = d.get("version", 1)
        if not isinstance(version, int) or version > FORMAT_VERSION:
            raise RecordFormatError(
                path,
                "bounds",
                f"it is of format version {version!r} and this drake_cfvol "
                f"reads versions up to {FORMAT_VERSION} (update drake_cfvol to read it)",
            )
        rate = d.get("rate")
        try:
            table = cls(
                a["lower"],
                a["upper"],
                a["nominal"],
                d["joint_names"],
                np.array(d["limit_lower"], float),
                np.array(d["limit_upper"], float),
                d.get("params", {}),
                d.get("timing_ms", {}),
                d.get("info", {}),
                stretch_lower=a.get("stretch_lower"),
                stretch_upper=a.get("stretch_upper"),
                rate=None if rate is None else np.array([np.inf if v is None else v for v in rate], float),
                interpolation=d.get("interpolation", "stretch"),
            )
        except (CfvolError, TypeError, ValueError) as e:
            raise RecordFormatError(path, "bounds", " ".join(str(e).split()).rstrip(".")) from None
        problem = table.problem()
        if problem is not None:
            raise RecordFormatError(path, "bounds", problem)
        return table


def require_table(table, where: str) -> BoundsTable:
    """``table`` itself if it is a :class:`BoundsTable`.

    Raises:
        ParameterError: it is not (a path given as the table is named).
    """
    if not isinstance(table, BoundsTable):
        hint = " (a NominalPath is the path, not its bounds)" if type(table).__name__ == "NominalPath" else ""
        raise ParameterError(
            f"{where}: expected a BoundsTable (drake_cfvol.estimate_bounds or BoundsTable.load), got "
            f"{type(table).__name__}{hint}."
        )
    return table


def check_table(table, where: str, position_lower=None, position_upper=None) -> None:
    """Refuses what is not a usable :class:`BoundsTable` before a system
    or a run uses it (:meth:`BoundsTable.problem`).

    Raises:
        ParameterError: not a table, or its values are unusable (named).
    """
    require_table(table, where)
    problem = table.problem(position_lower, position_upper)
    if problem is not None:
        raise ParameterError(f"{where}: the bounds table is unusable: {problem}. Compute or load a valid table.")


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
