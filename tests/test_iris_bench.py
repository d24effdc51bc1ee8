"""The IrisZo comparison (benchmarks/iris.py): the largest box inside a
polytope against brute force and by hand, the measure of a box against the
package's freedom, and the targets' verdicts on made-up results."""

import dataclasses

import numpy as np
import pytest

import drake_cfvol as cf
from benchmarks.iris import IrisBenchConfig, box_freedom, iris_markdown, iris_region, iris_targets, largest_box
from drake_cfvol.algorithm.table import BoundsTable


def _gm(w: np.ndarray) -> float:
    return float(np.exp(np.mean(np.log(np.maximum(w, 1e-300)))))


def _random_instance(rng: np.random.Generator, k: int, m: int, one_sided: bool = False) -> tuple[np.ndarray, ...]:
    """A random polytope {A x <= b} with q inside (each row 0.1-1 from it),
    and a box [lower, upper] around q (``one_sided``: the first joint may
    only grow upwards from q)."""
    q = rng.uniform(-1, 1, k)
    A = rng.normal(size=(m, k))
    A /= np.linalg.norm(A, axis=1, keepdims=True)
    b = A @ q + rng.uniform(0.1, 1.0, m)
    lower, upper = q - rng.uniform(0.5, 2.0, k), q + rng.uniform(0.5, 2.0, k)
    if one_sided:
        lower[0] = q[0]
    return A, b, q, lower, upper


def _grid_best(A: np.ndarray, b: np.ndarray, q: np.ndarray, lower: np.ndarray, upper: np.ndarray, n: int) -> float:
    """The largest geometric mean of widths over every box whose ends lie on
    an n-point grid per joint side ([lower, q] for lo, [q, upper] for hi)
    and whose every corner satisfies A x <= b (exhaustive)."""
    k = len(q)
    los = [np.linspace(lower[j], q[j], n) for j in range(k)]
    his = [np.linspace(q[j], upper[j], n) for j in range(k)]

    def axes(j: int, a: np.ndarray) -> np.ndarray:  # an (n, n) array of (lo_j, hi_j) placed on axes 2j, 2j+1
        shape = [1] * (2 * k)
        shape[2 * j] = shape[2 * j + 1] = n
        return a.reshape(shape)

    ok = np.ones([n] * (2 * k), bool)
    for r in range(len(b)):
        # Every corner of the box satisfies row r iff its largest a.x does.
        most = sum(axes(j, max(A[r, j], 0) * his[j][None, :] - max(-A[r, j], 0) * los[j][:, None]) for j in range(k))
        ok &= most <= b[r] + 1e-12
    log_w = sum(axes(j, np.log(np.maximum(his[j][None, :] - los[j][:, None], 1e-300))) for j in range(k))
    return float(np.exp(log_w[ok].max() / k))


def _corners(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    k = len(lo)
    pattern = (np.arange(2**k)[:, None] >> np.arange(k)[None, :]) & 1
    return np.where(pattern == 1, hi, lo)


@pytest.mark.parametrize(
    ("k", "m", "n", "seed", "one_sided"),
    [(2, 5, 40, 0, False), (2, 8, 40, 1, False), (2, 6, 40, 5, True), (3, 6, 13, 2, False), (3, 10, 13, 3, True)],
)
def test_largest_box_is_the_brute_force_optimum(k: int, m: int, n: int, seed: int, one_sided: bool) -> None:
    """On random 2-D and 3-D polytopes (a joint with room on one side of q
    only in some): the box contains q, lies in [lower, upper], every corner
    satisfies A x <= b; no grid box has a larger geometric mean of widths,
    and the best grid box comes within the grid's step of it (the optimum
    rounded inwards onto the grid is a grid box)."""
    A, b, q, lower, upper = _random_instance(np.random.default_rng(seed), k, m, one_sided)
    lo, hi = largest_box(A, b, q, lower, upper)
    assert np.all(lo <= q) and np.all(q <= hi)
    assert np.all(lower <= lo) and np.all(hi <= upper)
    assert np.all(_corners(lo, hi) @ A.T <= b + 1e-12)
    best = _grid_best(A, b, q, lower, upper, n)
    step = (q - lower) / (n - 1) + (upper - q) / (n - 1)
    assert best <= _gm(hi - lo) * (1 + 1e-6)
    assert best >= _gm(hi - lo - step) - 1e-9


def test_largest_box_by_hand() -> None:
    """In the triangle x, y >= 0, x + y <= 1 around (0.25, 0.25), the box of
    the largest area is [0, 0.5]^2 (a + b <= 1, ab largest at a = b). With x
    kept >= 0.25, the box [0.25, a] x [0, c] with a + c <= 1 is largest at
    c = 0.375 ((0.75 - c) c). A joint without room is held at q, and the
    other takes all of its room."""
    A = np.array([[-1.0, 0.0], [0.0, -1.0], [1.0, 1.0]])
    b = np.array([0.0, 0.0, 1.0])
    q = np.array([0.25, 0.25])
    # The optimum is flat (an area's error is the square of a side's): the
    # sides to 1e-4, the areas to 1e-8.
    lo, hi = largest_box(A, b, q, [-1, -1], [1, 1])
    np.testing.assert_allclose(np.r_[lo, hi], [0, 0, 0.5, 0.5], atol=1e-4)
    assert np.prod(hi - lo) == pytest.approx(0.25, abs=1e-8)
    lo, hi = largest_box(A, b, q, [0.25, -1], [1, 1])
    np.testing.assert_allclose(np.r_[lo, hi], [0.25, 0, 0.625, 0.375], atol=1e-4)
    assert np.prod(hi - lo) == pytest.approx(0.375**2, abs=1e-8)
    lo, hi = largest_box(A, b, q, [0.25, -1], [0.25, 1])
    np.testing.assert_allclose(np.r_[lo, hi], [0.25, 0, 0.25, 0.75], atol=1e-4)


def test_largest_box_refuses_bad_input() -> None:
    A, b = np.eye(2), np.ones(2)
    with pytest.raises(cf.ParameterError, match="outside the polytope"):
        largest_box(A, b, [2.0, 0.0], [-3, -3], [3, 3])
    with pytest.raises(cf.ParameterError, match="outside \\[lower, upper\\]"):
        largest_box(A, b, [0.0, 0.0], [0.5, -3], [3, 3])
    with pytest.raises(cf.ParameterError, match="b needs"):
        largest_box(A, np.ones(3), [0.0, 0.0], [-3, -3], [3, 3])


def test_box_freedom_is_the_packages_freedom() -> None:
    """Per waypoint, the measure of a table's boxes equals freedom's
    per-waypoint figure (widths over the joints' ranges, clipped, their
    geometric mean)."""
    rng = np.random.default_rng(4)
    nominal = rng.uniform(-1, 1, (5, 3))
    lower, upper = nominal - rng.uniform(0, 1, (5, 3)), nominal + rng.uniform(0, 1, (5, 3))
    lower[2, 1] = upper[2, 1] = nominal[2, 1]  # a joint without room: measure 0
    lim_lo, lim_hi = np.full(3, -2.0), np.array([2.0, 1.5, 3.0])
    table = BoundsTable(lower, upper, nominal, ["a", "b", "c"], lim_lo, lim_hi)
    np.testing.assert_allclose(box_freedom(lower, upper, lim_lo, lim_hi), cf.freedom(table).per_waypoint)
    assert box_freedom(lower[2], upper[2], lim_lo, lim_hi) == 0.0


def _result(rows: list[dict], certify_s: float, error: str | None = None) -> dict:
    path = {
        "cell": "automotive",
        "path": "path1",
        "g": 119,
        "certify_error": error,
        "certify_s": certify_s,
        "certify_s_runs": [] if error else [certify_s],
        "freedom_uncertified": 0.5,
        "freedom_certified": float("nan") if error else 0.3,
        "iris_s_median": 7.0,
    }
    config = dataclasses.asdict(IrisBenchConfig())
    return {"config": config, "wall_s": 1.0, "paths": [{**path, "waypoints": rows}]}


def test_targets_judge_only_where_iris_box_is_free() -> None:
    """A waypoint where ours is narrower misses the freedom target only if
    IRIS's box was free by every sample; a refused waypoint is not compared;
    the time target is met at or under its limit; a failed certification
    misses. The report names each case."""
    base = {"padding_m": 0.02, "uncertified": 0.5, "iris_s": 7.0, "faces": 90, "warnings": [], "samples": 2000}
    free_narrow = {**base, "waypoint": 3, "certified": 0.2, "iris": 0.3, "ratio": 2 / 3, "colliding": 0}
    free_narrow["free_share"] = 1.0
    hit_narrow = {**free_narrow, "waypoint": 5, "colliding": 4, "free_share": 0.998}
    wide = {**free_narrow, "waypoint": 7, "certified": 0.4, "ratio": 4 / 3}
    refused = {**base, "waypoint": 0, "certified": 0.1, "refused": "in collision"}
    (f1, ok1, text1), (t1, tok1, _) = iris_targets(_result([wide, hit_narrow, refused], 5.0))
    assert ok1 and tok1 and "1 waypoints compared" in text1 and "certification <= 5 s" in t1
    (_, ok2, text2), (_, tok2, ttext2) = iris_targets(_result([wide, free_narrow], 6.0))
    assert not ok2 and "narrower at 3" in text2 and "0.67" in text2
    assert not tok2 and "1.2x over" in ttext2
    failed = _result([{**free_narrow, "certified": float("nan"), "ratio": float("nan")}], float("nan"), "boom")
    ((_, ok3, text3),) = iris_targets(failed)
    assert not ok3 and "boom" in text3
    md = iris_markdown(_result([wide, hit_narrow, refused], 5.0), {"cpu": "x", "cores": 2})
    assert "| 5 | 20.0 | 0.500 | 0.200 | 0.300 | 0.67 | 0.9980 (4 of 2,000 collide)" in md
    assert "refused: in collision" in md and "Machine: x (2 cores)" in md
    assert "Certification failed: boom" in iris_markdown(failed)


@pytest.mark.slow
def test_iris_region_and_its_box_on_a_real_cell() -> None:
    """IrisZo around a waypoint of automotive path 1 (padded checker, one
    thread): the region holds the nominal, and the largest box inside it
    and the uncertified box keeps every corner inside the region and is
    free by Drake at most of its corners (IrisZo is probabilistic)."""
    wc = cf.load_workcell("automotive")
    path = cf.plan_nominal_path(wc, *wc.configuration("path1"), seed=0, clearance=0.02)
    table = cf.estimate_bounds(wc, path, resolution=1000, clearance=0.02)
    i = path.g // 2
    q = path.waypoints[i]
    checker = wc.padded_checker(0.02)
    region, _ = iris_region(checker.drake, q, table.limit_lower, table.limit_upper, seed=0, threads=1)
    assert region.PointInSet(q, 1e-9)
    lo, hi = largest_box(region.A(), region.b(), q, table.lower[i], table.upper[i])
    assert np.all(lo <= q) and np.all(q <= hi) and np.all(table.lower[i] <= lo) and np.all(hi <= table.upper[i])
    C = _corners(lo, hi)
    assert np.all(C @ region.A().T <= region.b() + 1e-9)
    assert box_freedom(lo, hi, table.limit_lower, table.limit_upper) > 0
    assert np.mean(checker.CheckConfigsCollisionFree(C)) > 0.9
