"""The boundary proof's building blocks (cuts, their cost, their room)."""

import numpy as np
import pytest
from conftest import write_arm_cell

import drake_cfvol as cf
from drake_cfvol.algorithm.certificate import boundary as B
from drake_cfvol.algorithm.certificate import cuts as C


@pytest.fixture(scope="module")
def corner(tmp_path_factory):
    """A 2-link planar arm (1.0 m + 0.8 m, 0.1 m thick, 0.5 m above the
    floor) straight along x at (0, 0) rad, and a 0.3 m post at (1.15, 1.0):
    the nominal keeps 0.45 m from the floor and 0.8 m from the post. At the
    corner (0.4, 0.8) rad link 2 reaches into the post."""
    wc = cf.load_workcell(
        write_arm_cell(
            tmp_path_factory.mktemp("corner"),
            links=[
                {"length": 1.0, "half_width": 0.05, "lower": -0.4, "upper": 0.4},
                {"length": 0.8, "half_width": 0.05, "lower": -0.8, "upper": 0.8},
            ],
            obstacles={"post": ((0.3, 0.3, 1.0), (1.15, 1.0, 0.5))},
            base_z=0.5,
        )
    )
    return wc, wc.scene_arrays()


def test_width_loss_counts_what_the_rate_limit_takes():
    """Cutting waypoint 1's upper bound of one joint from 1.0 to 0.2 on a
    five-waypoint table at rate 0.3 per waypoint (nominal 0): waypoints 0
    and 2 must drop to 0.5, 3 to 0.8, 4 stays (1.1 > 1). The loss is
    log(2/1.2) + 2 log(2/1.5) + log(2/1.8), not the cut's own log(2/1.2)."""
    lower, upper, nominal = -np.ones((5, 1)), np.ones((5, 1)), np.zeros((5, 1))
    lo, hi = lower[1:3].copy(), upper[1:3].copy()
    hi[0, 0] = 0.2
    got = C._width_loss(lower, upper, nominal, np.array([0.3]), 1, lo, hi)
    assert got == pytest.approx(np.log(2 / 1.2) + 2 * np.log(2 / 1.5) + np.log(2 / 1.8))
    # Without a rate limit only the cut itself counts.
    assert C._width_loss(lower, upper, nominal, np.array([np.inf]), 1, lo, hi) == pytest.approx(np.log(2 / 1.2))


def test_cut_slacks_never_exceed_the_nominals_own_room(corner):
    """The nominal keeps 0.45 m (the floor): asked for 1 m of room, each
    stretch gets the largest rung that fits, 0.25 m; asked for 3 m, 0.375 m;
    asked for 0.02 m, all of it; none beyond margin + room the nominal has."""
    wc, arrays = corner
    nominal = np.zeros((4, 2))
    margins = np.zeros(3)
    np.testing.assert_allclose(B.cut_slacks(arrays, nominal, margins, 1.0), 0.25)
    np.testing.assert_allclose(B.cut_slacks(arrays, nominal, margins, 3.0), 0.375)
    np.testing.assert_allclose(B.cut_slacks(arrays, nominal, margins, 0.02), 0.02)
    np.testing.assert_allclose(B.cut_slacks(arrays, nominal, np.full(3, 0.3), 0.4), 0.1)


@pytest.mark.parametrize("slack", [0.0, 0.05])
def test_cut_point_frees_a_colliding_corner(corner, slack):
    """The colliding corner (0.4, 0.8) of the box [-0.4, 0.4] x [-0.8, 0.8]:
    one cut moves only upper bounds toward the nominal, and the corner of
    the new box keeps the slack by Drake's padded checker."""
    wc, arrays = corner
    lower = np.array([[-0.4, -0.8], [-0.4, -0.8]])
    upper = -lower
    nominal = np.zeros((2, 2))
    q = np.array([0.4, 0.8])
    assert not wc.is_free(q)
    lo0, hi0 = lower.copy(), upper.copy()
    taken = set()
    B.cut_point(wc, arrays, lower, upper, nominal, np.full(2, np.inf), 0, 0.5, q, 0.0, slack, taken)
    assert len(taken) == 1
    np.testing.assert_array_equal(lower, lo0)
    assert np.all(upper <= hi0) and np.any(upper < hi0)
    assert np.all(upper[0] == upper[1])  # the same box at both ends: the same cut at both
    corner_now = upper[0]
    assert np.asarray(wc.padded_checker(slack).CheckConfigsCollisionFree(corner_now[None], parallelize=False)).all()
    if slack == 0.0:
        # Not needlessly deep: at half their deviation either joint alone
        # keeps link 2 >= 2 cm below the post (by hand), so the cut keeps more.
        cut = np.flatnonzero(upper[0] < hi0[0])
        assert np.all(upper[0, cut] >= 0.5 * hi0[0, cut])


def test_reaching_joints_of_a_link_2_collision(corner):
    """At the corner link 2 touches the post: both joints move link 2, so both
    reach; at the nominal nothing is near and every joint counts."""
    wc, arrays = corner
    np.testing.assert_array_equal(B.reaching_joints(wc, arrays, np.array([0.4, 0.8]), 0.0), [True, True])
    np.testing.assert_array_equal(B.reaching_joints(wc, arrays, np.zeros(2), 0.0), [True, True])


def test_proven_edges_are_not_tested_again(corner):
    """A free box (the arm's small box away from the post): every edge is
    proven and remembered; proving it again tests nothing. Shrinking joint
    0's upper bound keeps joint 0's own edges (their range shrank, the
    others did not move) and joint 1's edges at joint 0's lower bound; only
    joint 1's edges at the moved bound are tested again, and they pass."""
    wc, arrays = corner
    lower = np.array([[-0.1, -0.1], [-0.1, -0.1]])
    upper = -lower
    nominal = np.zeros((2, 2))
    margins = np.zeros(1)
    memo: dict = {}
    failed, tests = B.failures(arrays, lower, upper, nominal, [0], margins, memo)
    n_edges = len(B.edge_tasks(lower[0], upper[0], lower[1], upper[1])[2])
    assert not failed and tests == n_edges == 4 and len(memo) == 4
    assert B.failures(arrays, lower, upper, nominal, [0], margins, memo) == ([], 0)
    upper[:, 0] = 0.05
    failed, tests = B.failures(arrays, lower, upper, nominal, [0], margins, memo)
    assert not failed and tests == 1  # joint 1's edge with joint 0 on its (moved) upper bound
    # Joint 0's lower bound moved at the far waypoint only: joint 1's edge
    # on that bound is a new region (the other joint's path changed).
    lower[1, 0] = -0.04
    failed, tests = B.failures(arrays, lower, upper, nominal, [0], margins, memo)
    assert not failed and tests == 1
    # A larger margin than the proven one is tested again.
    assert B.failures(arrays, lower, upper, nominal, [0], np.full(1, 0.01), memo)[1] == 4


def test_an_edge_tested_again_starts_from_the_pieces_it_needed(corner):
    """A box near the post at a 2 cm margin: the two edges nearest the post
    pass only halved along their joint (the whole edge's hull of poses
    bulges towards the post), and the memo remembers that. After joint 1's upper bound
    shrinks a little, joint 0's edge on that bound is a new region; it is
    tested from its two halves at once (2 tests), and it is free by Drake's
    checker at points all along it."""
    wc, arrays = corner
    upper = np.array([[0.3, 0.6], [0.3, 0.6]])
    lower = -upper
    nominal = np.zeros((2, 2))
    margins = np.full(1, 0.02)
    memo: dict = {}
    failed, tests = B.failures(arrays, lower, upper, nominal, [0], margins, memo)
    sig = B.edge_tasks(lower[0], upper[0], lower[1], upper[1])[5].dtype
    depths = {(k[2], tuple(np.frombuffer(k[3], sig))): v for k, v in memo.items() if k[0] == "depth"}
    # Joint 0 with joint 1 on its upper bound, and joint 1 with joint 0 on
    # its upper bound, both nearest the post: each passed in two halves.
    assert not failed and depths == {(0, (0, 1)): 1, (1, (1, 0)): 1}
    upper[:, 1] = 0.59
    failed, tests = B.failures(arrays, lower, upper, nominal, [0], margins, memo)
    assert not failed and tests == 2  # joint 0's edge at joint 1's moved bound, from its halves
    s = np.linspace(0.0, 1.0, 11)
    v = np.linspace(lower[0, 0], upper[0, 0], 41)
    Q = np.array([[a, upper[0, 1]] for a in v for _ in s])
    assert np.asarray(wc.padded_checker(0.02).CheckConfigsCollisionFree(Q, parallelize=False)).all()


def test_failed_edges_are_remembered_and_cut_once_per_round(corner):
    """A box whose corner (0.4, 0.8) rad reaches into the post: some edges
    fail. Asked again with nothing changed, the same regions fail without
    a single region test (the result is a function of the edge, its range
    and the margin); a new margin tests again. A round cuts the first
    failing region of each failing edge only."""
    wc, arrays = corner
    lower = np.array([[-0.1, -0.1], [-0.1, -0.1]])
    upper = np.array([[0.4, 0.8], [0.4, 0.8]])
    nominal = np.zeros((2, 2))
    memo: dict = {}
    failed, tests = B.failures(arrays, lower, upper, nominal, [0], np.zeros(1), memo)
    assert failed and tests > 0
    again, tests_again = B.failures(arrays, lower, upper, nominal, [0], np.zeros(1), memo)
    assert tests_again == 0
    fresh, fresh_tests = B.failures(arrays, lower, upper, nominal, [0], np.zeros(1), None)
    assert fresh_tests == tests
    regions = [(f.sa, f.sb, f.j, f.va, f.vb, f.S.tobytes()) for f in fresh]
    assert [(f.sa, f.sb, f.j, f.va, f.vb, f.S.tobytes()) for f in again] == regions
    # The failing edges' own range changed at one end only: tested again.
    lower_1 = lower.copy()
    lower_1[1] += 0.01
    assert B.failures(arrays, lower_1, upper, nominal, [0], np.zeros(1), memo)[1] > 0
    assert B.failures(arrays, lower, upper, nominal, [0], np.full(1, 0.01), memo)[1] > 0
    first = B._one_per_edge(failed)
    edges = {(f.j, f.S.tobytes(), f.root) for f in failed}
    assert len(first) == len(edges) and {(f.j, f.S.tobytes(), f.root) for f in first} == edges
    assert all(f is next(g for g in failed if g.root == f.root) for f in first)


def test_prove_boundary_leaves_no_failing_edge(corner):
    """The proof on the box reaching into the post: afterwards a fresh
    region test of every edge (no memo) finds nothing, the corners on a
    fine grid of s are free by Drake, and the box only shrank."""
    wc, arrays = corner
    lower = np.array([[-0.4, -0.8]] * 3)
    upper = -lower.copy()
    nominal = np.zeros((3, 2))
    lo0, hi0 = lower.copy(), upper.copy()
    margins = np.zeros(2)
    stats = B.prove_boundary(wc, arrays, lower, upper, nominal, np.full(2, np.inf), margins)
    assert stats["unproven"] == [] and stats["edge_cuts"] > 0
    assert np.all(lower >= lo0) and np.all(upper <= hi0)
    assert B.failures(arrays, lower, upper, nominal, [0, 1], margins, None)[0] == []
    Q = B.corner_points(lower, upper, nominal, np.linspace(0.0, 2.0, 41))
    assert all(wc.is_free(q) for q in Q)


def test_a_cut_that_changes_nothing_leaves_the_stretch_unproven(corner, monkeypatch):
    """Cuts stubbed to change no bound (but report a cut taken): the
    failing edges must not count as proven; the proof runs out of rounds
    and names the stretch."""
    wc, arrays = corner

    def no_cut(*args, **kwargs):
        fail_or_i = args[6]
        args[-1].add((getattr(fail_or_i, "i", fail_or_i), "nothing"))
        return True

    monkeypatch.setattr(B, "cut_point", no_cut)
    monkeypatch.setattr(B, "cut_for", no_cut)
    lower = np.array([[-0.1, -0.1], [-0.1, -0.1]])
    upper = np.array([[0.4, 0.8], [0.4, 0.8]])
    stats = B.prove_boundary(wc, arrays, lower, upper, np.zeros((2, 2)), np.full(2, np.inf), np.zeros(1), max_rounds=3)
    assert stats["unproven"] == [0] and stats["edge_rounds"] == 3
