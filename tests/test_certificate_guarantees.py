"""What a certified box promises, checked against Drake's own checker
(issue 48): no colliding corner, edge point or face point on any built-in
path or the mesh robot; a planted obstacle found at the rate epsilon
promises; and no joint cut below the bisection delta without a colliding
corner to show for it.

Only the public API is used (``estimate_bounds(..., certify=Certify(...))``,
the table's bounds and boxes, ``info["certificate"]``), so these hold
whatever way the certificate chooses its boxes."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
from conftest import write_arm_cell

import drake_cfvol as cf
from drake_cfvol.algorithm.metrics import (
    boundary_check,
    judged_margins,
    kept_margins,
    position_margins,
    sample_boxes,
)

MESH_CELL = Path(__file__).parent / "data" / "mesh_cell.yaml"

#: Every built-in path of the automotive and aerospace cells, and the mesh
#: test robot's path: all seven in the slow group (about 4-5 minutes here
#: since 0.11's proof); CFVOL_ALL_PATHS=0 takes automotive path 1 only.
ALL_PATHS = [(cell, f"path{i}") for cell in ("automotive", "aerospace") for i in (1, 2, 3)] + [("mesh", "path1")]
PATHS = ALL_PATHS[:1] if os.environ.get("CFVOL_ALL_PATHS") == "0" else ALL_PATHS


@pytest.fixture(scope="module")
def certified(automotive, aerospace, planned):
    """certified(cell, label) -> (workcell, table): the path (seed 0)
    certified at the defaults (R = 1000, the cells' 2 cm clearance,
    ``Certify()``), once per module."""
    cells = {"automotive": automotive, "aerospace": aerospace}
    done: dict = {}

    def get(cell: str, label: str):
        if (cell, label) not in done:
            if cell == "mesh":
                wc = cells.setdefault("mesh", cf.load_workcell(str(MESH_CELL)))
                path = cf.plan_nominal_path(wc, *wc.configuration(label), seed=0, label=label)
            else:
                wc, path = cells[cell], planned(cell, label)
            done[cell, label] = wc, cf.estimate_bounds(wc, path, resolution=1000, certify=cf.Certify())
        return done[cell, label]

    return get


# 1. The boundary ------------------------------------------------------------


@pytest.mark.slow  # certifying takes minutes (shared with the starvation test)
@pytest.mark.parametrize(
    "cell, label",
    PATHS,
)
def test_no_certified_box_has_a_colliding_boundary_point(cell, label, certified):
    """At every waypoint and stretch midpoint, every corner of the certified
    box, 64 edge points (one joint uniform over its width, the others at
    random bounds) and 64 face points (one joint at a random one of its
    bounds, the others uniform in the box) keep the margin by Drake's
    checker: padded to each stretch's margin less 1 mm (a waypoint keeps
    the larger margin of the two stretches it ends). Seeded."""
    wc, table = certified(cell, label)
    res = boundary_check(wc, table, clearance=judged_margins(wc, table), edge_points=64, face_points=64, seed=0)
    assert res.positions == 2 * table.g - 1 and res.corners == res.positions * 2**table.k
    assert (res.corners_colliding, res.edges_colliding, res.faces_colliding) == (0, 0, 0), (
        f"{cell} {label}: {res.corners_colliding} of {res.corners} corners, {res.edges_colliding} of "
        f"{res.edge_points} edge points, {res.faces_colliding} of {res.face_points} face points come nearer "
        f"than the margin less 1 mm (>= {res.clearance * 1e3:.1f} mm), at s = {res.colliding_at}"
    )


def test_position_margins_by_hand():
    """Stretch margins (10, 20, 5) mm: a midpoint keeps its stretch's, a
    waypoint the larger of the two stretches it ends (the path's ends their
    one stretch's)."""
    got = position_margins(np.array([0.01, 0.02, 0.005]), np.arange(0.0, 3.01, 0.5))
    np.testing.assert_array_equal(got, [0.01, 0.01, 0.02, 0.02, 0.02, 0.005, 0.005])


# 2. A planted obstacle --------------------------------------------------------

#: The planar arm of the planted-obstacle test: each joint alone sweeps its
#: whole range clear of the pin, so the uncertified box is the joint limits.
_ARM = [
    {"length": 1.0, "half_width": 0.05, "lower": -0.4, "upper": 0.4},
    {"length": 0.8, "half_width": 0.05, "lower": -0.8, "upper": 0.8},
]
#: A 12 cm pin at (1.2, 1.0) m: only link 2 with both joints near their
#: upper bounds reaches it (at (0.4, 0.8) rad link 2 ends at (1.21, 1.14)).
_PIN = {"pin": ((0.12, 0.12, 0.3), (1.2, 1.0, 0.5))}


@pytest.fixture(scope="module")
def pinned(tmp_path_factory):
    """(the arm's cell with the pin, the same cell without it, a standing
    three-waypoint path at the straight arm)."""
    with_pin = cf.load_workcell(write_arm_cell(tmp_path_factory.mktemp("pinned"), links=_ARM, obstacles=_PIN))
    without = cf.load_workcell(write_arm_cell(tmp_path_factory.mktemp("unpinned"), links=_ARM, obstacles={}))
    path = cf.NominalPath(np.zeros((3, 2)), with_pin.joint_names, with_pin.name)
    return with_pin, without, path


def test_boundary_check_judges_each_stretch_at_its_own_margin(pinned):
    """The arm without the pin, 0.45 m above the floor at every
    configuration of a small box ([-0.1, 0.1] rad each) on a standing
    three-waypoint path: padded by 0.5 m on stretch 0 every point collides
    (with the floor), by 0.3 m on stretch 1 none does. So the positions 0,
    0.5 and 1 (a waypoint keeps the larger margin) collide at every
    corner, edge point and face point, 1.5 and 2 at none; a clearance of
    the wrong length is refused."""
    from drake_cfvol.algorithm.table import BoundsTable

    _, without, path = pinned
    box = BoundsTable(
        np.full((3, 2), -0.1), np.full((3, 2), 0.1), path.waypoints, without.joint_names, -np.ones(2), np.ones(2)
    )
    res = boundary_check(without, box, clearance=np.array([0.5, 0.3]), edge_points=8, face_points=16)
    assert res.positions == 5 and res.colliding_at == [0.0, 0.5, 1.0]
    assert (res.corners, res.corners_colliding) == (20, 12)
    assert (res.edge_points, res.edges_colliding) == (40, 24)
    assert (res.face_points, res.faces_colliding) == (80, 48)
    assert res.clearance == 0.3
    with pytest.raises(cf.DimensionError, match="one per stretch"):
        boundary_check(without, box, clearance=np.zeros(3))


def _colliding(workcell, table, n: int, seed: int) -> int:
    """How many of n configurations drawn as the certificate's promise is
    stated (s uniform over the path, then uniform in the box at s) come
    nearer than the margin less 1 mm, by Drake. Seeded."""
    rng = np.random.default_rng(seed)
    Q = sample_boxes(table, rng.random(n) * (table.g - 1), rng)
    pad = float(judged_margins(workcell, table).min())
    return int(np.sum(~np.asarray(workcell.padded_checker(pad).CheckConfigsCollisionFree(Q, parallelize=True), bool)))


@pytest.mark.slow  # 40 certifications and 0.8 M Drake checks: about 10 s
def test_a_planted_obstacle_is_found_at_the_rate_epsilon_promises(pinned):
    """The sampled certificate alone (epsilon 1e-2, confidence 0.9, no
    boundary proof and no search before its run, so only its N = 231
    uniform and 23 clamp samples can meet the pin) against a pin that the
    uncertified box's uniform configurations hit with share p, measured by
    Drake (40,000 samples): p is above epsilon with a one-sided 99.9 %
    binomial bound, and without the pin the same box is free.

    Over n = 40 certification seeds (independent sample streams), a box is
    missed when its colliding share is above epsilon: X > k of M = 20,000
    fresh Drake samples of it, k the one-sided 1e-4 binomial quantile at
    epsilon, so a box that keeps the promise is called missed with
    probability <= 1e-4, and a box the pin was never found in (share p) is
    called missed with probability > 0.99. The promise: each seed misses with
    probability <= 1 - confidence = 0.1, so misses are at most
    Binomial(40, 0.1001) and the test fails at 12 or more: its
    false-failure probability is 0.04 % (P(Bin(40, 0.1001) >= 12)). A
    certificate drawing a quarter of its N would miss this pin with
    probability about (1 - p)^(N/4) = 0.4 per seed and fail the test 94 % of
    the time."""
    from scipy.stats import beta, binom

    with_pin, without, path = pinned
    eps, conf, n_seeds, M, M_p = 1e-2, 0.9, 40, 20000, 40000
    plain = cf.estimate_bounds(with_pin, path, h_max=0.0)
    hits = _colliding(with_pin, plain, M_p, seed=101)
    assert _colliding(without, plain, M_p, seed=101) == 0  # every collision is the pin's
    p_low = beta.ppf(1e-3, hits, M_p - hits + 1)  # Clopper-Pearson lower bound
    assert p_low >= eps, f"the pin's share {hits / M_p:.4f} (>= {p_low:.4f}) must be at least epsilon"
    k = binom.isf(1e-4, M, eps)
    assert binom.cdf(k, M, hits / M_p) < 0.01  # an unfound pin is called missed
    misses = []
    for seed in range(n_seeds):
        c = cf.Certify(epsilon=eps, confidence=conf, boundary=False, search_rounds=0, seed=seed, cache=False)
        cert = cf.estimate_bounds(with_pin, path, h_max=0.0, certify=c)
        assert cert.info["certificate"]["n_samples"] == 231
        if _colliding(with_pin, cert, M, seed=1000 + seed) > k:
            misses.append(seed)
    limit = 12
    assert binom.sf(limit - 1, n_seeds, (1 - conf) + 1e-4) < 1e-3  # the stated false-failure probability
    assert len(misses) < limit, f"the pin was missed (share > epsilon) at seeds {misses}"


# 3. No starved joint -----------------------------------------------------------


def _starved_without_cause(workcell, table) -> list[str]:
    """Each joint whose certified width at a waypoint is under the
    bisection delta while its uncertified width there is over 10 delta,
    widened alone by delta on a side with that much room in the uncertified
    box, whose widened box at that waypoint has every corner free by Drake
    at the margin (the larger of the two stretches' beside the waypoint).
    A side whose widened bound would move faster than the table's rate
    limit from a neighbour's is not tried: the neighbour holds it (and is
    itself checked)."""
    delta = np.where(workcell.revolute, table.params["delta"], table.params["delta_prismatic"])
    lo0, hi0 = table.info["uncertified_lower"], table.info["uncertified_upper"]
    rate = np.full(table.k, np.inf) if table.rate is None else np.asarray(table.rate, float)
    pads = position_margins(kept_margins(workcell, table), np.arange(table.g, dtype=float))
    k = table.k
    pattern = ((np.arange(2**k)[:, None] >> np.arange(k)[None, :]) & 1) == 1
    found = []
    for i, j in zip(*np.nonzero((table.upper - table.lower < delta) & (hi0 - lo0 > 10 * delta))):
        for side in ("lower", "upper"):
            lo, hi = table.lower[i].copy(), table.upper[i].copy()
            if side == "lower":
                lo[j] -= delta[j]
                room, bound, bounds = lo[j] >= lo0[i, j], lo[j], table.lower[:, j]
            else:
                hi[j] += delta[j]
                room, bound, bounds = hi[j] <= hi0[i, j], hi[j], table.upper[:, j]
            near = bounds[[n for n in (i - 1, i + 1) if 0 <= n < table.g]]
            if not room or np.any(np.abs(near - bound) > rate[j] + 1e-12):
                continue
            corners = np.where(pattern, hi, lo)
            free = np.asarray(workcell.padded_checker(float(pads[i])).CheckConfigsCollisionFree(corners), bool)
            if free.all():
                found.append(
                    f"waypoint {i} joint {j} {side}: certified width {table.upper[i, j] - table.lower[i, j]:.4f}, "
                    f"uncertified {hi0[i, j] - lo0[i, j]:.3f}, delta {delta[j]}"
                )
    return found


@pytest.mark.slow  # shares the certified tables of the boundary test
@pytest.mark.parametrize("cell, label", PATHS)
def test_no_joint_is_starved_without_cause(cell, label, certified):
    """Wherever a joint's certified width at a waypoint is under the
    bisection delta (the table's ``delta``, or ``delta_prismatic`` for a
    prismatic joint) though its uncertified width is over 10 delta, widening
    that joint alone by delta, on each side with that room inside the
    uncertified box (and within the table's rate limit of the neighbouring
    waypoints' bounds), makes some corner of the box at that waypoint come
    nearer than the margin by Drake's checker."""
    wc, table = certified(cell, label)
    found = _starved_without_cause(wc, table)
    assert not found, f"{cell} {label}: {len(found)} starved without cause:\n" + "\n".join(found)
