"""Nominal paths: RRT-Connect through OMPL, verified by Drake."""

import numpy as np
import pytest
from conftest import write_arm_cell

import drake_cfvol as cf
from drake_cfvol.algorithm.planning import NominalPath, densify, plan_nominal_path


def _fine_checker(wc):
    """A second Drake checker with a 4x finer edge step than the planner's."""
    from pydrake.planning import SceneGraphCollisionChecker

    return SceneGraphCollisionChecker(model=wc.diagram, robot_model_instances=[wc.robot], edge_step_size=0.0025)


@pytest.mark.slow  # 4-5 s per cell; the default group stays under 90 s
@pytest.mark.parametrize("cell", ["automotive", "aerospace"])
def test_all_named_paths_plan_and_are_free(cell, request):
    """All named paths plan for seeds 0..4; every waypoint and every edge is
    free per an independent fine Drake check; limits and max_step hold."""
    wc = request.getfixturevalue(cell)
    fine = _fine_checker(wc)
    for name in wc.configurations:
        s, g = wc.configuration(name)
        for seed in range(5):
            p = plan_nominal_path(wc, s, g, seed=seed)
            wp = p.waypoints
            np.testing.assert_array_equal(wp[0], s)
            np.testing.assert_array_equal(wp[-1], g)
            assert np.all(np.abs(np.diff(wp, axis=0)) <= 0.05 + 1e-12)
            assert np.all(wp >= wc.position_lower) and np.all(wp <= wc.position_upper)
            assert all(fine.CheckConfigsCollisionFree(wp))
            assert all(fine.CheckEdgeCollisionFree(a, b) for a, b in zip(wp[:-1], wp[1:])), (name, seed)


def test_same_seed_same_bytes(automotive):
    """The same seed twice gives byte-identical waypoints, another seed differs."""
    s, g = automotive.configuration("path2")
    a = plan_nominal_path(automotive, s, g, seed=3)
    other = plan_nominal_path(automotive, s, g, seed=4)
    b = plan_nominal_path(automotive, s, g, seed=3)
    assert a.waypoints.tobytes() == b.waypoints.tobytes()
    assert a.sha256 == b.sha256 != other.sha256


def test_waypoints_not_singular(aerospace):
    """Every waypoint's tool Jacobian has its smallest singular value above the
    threshold (SPEC 3)."""
    from drake_cfvol.algorithm.planning import min_singular_value

    p = plan_nominal_path(aerospace, *aerospace.configuration("path1"), seed=0)
    assert min(min_singular_value(aerospace, q) for q in p.waypoints) > 1e-3


def test_densify_bounds_every_step():
    """densify keeps the vertices and caps each joint's step."""
    v = np.array([[0.0, 0.0], [1.0, -0.3], [1.0, 0.7]])
    d = densify(v, 0.05)
    assert np.all(np.abs(np.diff(d, axis=0)) <= 0.05 + 1e-12)
    for row in v:
        assert np.any(np.all(np.isclose(d, row), axis=1))
    assert len(d) == 1 + 20 + 20


@pytest.mark.parametrize("suffix", [".npz", ".json"])
def test_save_load_roundtrip(automotive, tmp_path, suffix):
    """Saved paths load back bit for bit, and are not overwritten silently."""
    p = plan_nominal_path(automotive, *automotive.configuration("path3"), seed=1, label="path3")
    f = p.save(tmp_path / f"p{suffix}")
    q = NominalPath.load(f)
    assert q.waypoints.tobytes() == p.waypoints.tobytes()
    assert q.joint_names == p.joint_names and q.label == "path3" and q.seed == 1
    with pytest.raises(FileExistsError, match="overwrite"):
        p.save(f)


def test_start_in_collision_names_bodies(automotive):
    """A start in collision is refused with the colliding bodies named."""
    s = np.radians([0, 85, 30, 0, 0, 0])
    with pytest.raises(cf.CollisionError, match="start.*<->"):
        plan_nominal_path(automotive, s, automotive.configuration("path1")[1], seed=0)


def test_goal_outside_limits(automotive):
    """A goal outside the limits names the joint."""
    s, g = automotive.configuration("path1")
    g[4] = 3.0
    with pytest.raises(cf.JointLimitError, match="joint_5"):
        plan_nominal_path(automotive, s, g, seed=0)


def test_wrong_length(automotive):
    """A start of the wrong length is refused with the expected size."""
    s, g = automotive.configuration("path1")
    with pytest.raises(cf.DimensionError, match="expected 6"):
        plan_nominal_path(automotive, s[:4], g, seed=0)


def test_robot_without_limits(tmp_path):
    """A continuous joint (no limits) cannot be planned for; the error names it
    and says how to add limits."""
    path = write_arm_cell(
        tmp_path, links=[{"length": 1.0, "half_width": 0.05, "lower": None, "upper": None}], obstacles={}
    )
    wc = cf.load_workcell(path)
    with pytest.raises(cf.MissingJointLimitsError, match="joint1.*joint_limits"):
        plan_nominal_path(wc, [0.0], [1.0], seed=0)
    # The YAML override fixes it.
    path.write_text(path.read_text().replace("cfvol:\n", "cfvol:\n  joint_limits: {joint1: [-3.0, 3.0]}\n"))
    p = plan_nominal_path(cf.load_workcell(path), [0.0], [1.0], seed=0)
    assert p.g == 21


def test_unreachable_goal_times_out(tmp_path):
    """A goal walled off from the start fails within the time limit, saying the
    time and the attempts."""
    # A one-link arm of length 1 turning about z; posts at y = +-0.8 block
    # both ways round from 0 rad to pi rad.
    path = write_arm_cell(
        tmp_path,
        links=[{"length": 1.0, "half_width": 0.05, "lower": -3.1, "upper": 3.1}],
        obstacles={"post_a": ((0.1, 0.1, 2.0), (0.0, 0.8, 1.0)), "post_b": ((0.1, 0.1, 2.0), (0.0, -0.8, 1.0))},
    )
    wc = cf.load_workcell(path)
    with pytest.raises(cf.PlanningError, match=r"in 0.5 s \(\d+ attempt"):
        plan_nominal_path(wc, [0.0], [3.0], seed=0, time_limit=0.5)


def test_path_index_outside_range(automotive):
    """NominalPath.at refuses s outside [0, g-1]."""
    p = plan_nominal_path(automotive, *automotive.configuration("path1"), seed=0)
    np.testing.assert_array_equal(p.at(0), p.waypoints[0])
    np.testing.assert_allclose(p.at(1.5), (p.waypoints[1] + p.waypoints[2]) / 2)
    with pytest.raises(cf.ParameterError, match="outside"):
        p.at(p.g)


def test_planning_keeps_the_clearance(automotive):
    """Every waypoint of a path planned with a margin keeps it, by Drake's
    own distance query; the margin in force is lowered only to 0.9 x a
    start or goal that is nearer (the automotive start: 19.2 mm)."""
    for name in ("path1", "path2"):
        s, g = automotive.configuration(name)
        p = plan_nominal_path(automotive, s, g, seed=0, clearance=0.02)
        ends = min(automotive.clearance(s), automotive.clearance(g))
        assert p.stats["clearance_m"] == pytest.approx(min(0.02, 0.9 * ends))
        d = np.array([automotive.clearance(q) for q in p.waypoints])
        assert d.min() >= p.stats["clearance_m"] - 1e-9


def test_bad_clearance(automotive):
    """A negative or huge margin is refused with a clear message."""
    s, g = automotive.configuration("path1")
    with pytest.raises(cf.ParameterError, match="clearance"):
        plan_nominal_path(automotive, s, g, seed=0, clearance=-0.01)
    with pytest.raises(cf.ParameterError, match="clearance"):
        cf.VolumeParams(clearance=2.0)


@pytest.mark.parametrize("cell", ["automotive", "tests/data/mesh_cell.yaml"])
def test_the_kernel_first_checker_gives_drakes_answers(cell, request):
    """The planner's checker (the kernel asked first, Drake for what it
    cannot certify) answers as Drake's padded checker does, on random
    edges of all lengths (free and colliding) and random configurations,
    at paddings 0 and 2 cm; on the mesh robot too (STL links, a gripper, a
    free part). Also with an interpolation Drake does not write as
    (1 - r) q1 + r q2: then it takes Drake's own samples."""
    wc = request.getfixturevalue(cell) if cell == "automotive" else cf.load_workcell(cell)
    rng = np.random.default_rng(7)
    lo, hi = wc.position_lower, wc.position_upper
    for clearance in (0.0, 0.02):
        fast, drake = wc.planning_checker(clearance), wc.padded_checker(clearance)
        assert fast._linear
        Q = rng.uniform(lo, hi, (60, wc.num_joints))
        for q in Q:
            assert fast.CheckConfigCollisionFree(q) == drake.CheckConfigCollisionFree(q)
        answers = []
        for a, b in zip(Q[:30], Q[30:]):
            b = a + (b - a) * rng.choice([0.01, 0.1, 0.5, 1.0])  # short and long edges
            answers.append(drake.CheckEdgeCollisionFree(a, b))
            assert fast.CheckEdgeCollisionFree(a, b) == answers[-1]
        assert 0 < sum(answers) < len(answers)  # both kinds of edges were asked
    # An interpolation that is not the linear one (the same samples, each
    # Drake's own): still Drake's answers.
    from drake_cfvol.scene.queries import KernelFirstChecker

    drake = wc.padded_checker(0.0)
    odd = KernelFirstChecker(wc, drake, 0.0)
    odd._linear = False
    for a, b in zip(Q[:10], Q[10:20]):
        assert odd.CheckEdgeCollisionFree(a, b) == drake.CheckEdgeCollisionFree(a, b)
