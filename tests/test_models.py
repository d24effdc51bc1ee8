"""The robot models against the reference numbers (robots-and-cells.md)."""

import numpy as np
import pytest


def _p_FW(wc, q, frame, body="link_5"):
    """Position of a body's origin expressed in ``frame``."""
    ctx = wc.plant_context(q)
    X = wc.plant.GetBodyByName(body).body_frame().CalcPose(ctx, wc.plant.GetFrameByName(frame))
    return X.translation()


def test_abb_wrist_centre_at_zero_pose(automotive):
    """ABB wrist centre at the zero pose is (1.5025, 0, 2.26) m from the base."""
    np.testing.assert_allclose(_p_FW(automotive, np.zeros(6), "base_link"), [1.5025, 0, 2.26], atol=1e-9)


def test_abb_wrist_centre_with_j1_and_j2(automotive):
    """J1 = 90 deg turns the wrist onto +y; J2 = 90 deg lays the lower arm forward."""
    np.testing.assert_allclose(
        _p_FW(automotive, np.radians([90, 0, 0, 0, 0, 0]), "base_link"), [0, 1.5025, 2.26], atol=1e-9
    )
    # J3 at (0.32 + 1.28, 0, 0.78); the wrist offset (1.1825, 0, 0.2) turned
    # by +90 deg about y is (0.2, 0, -1.1825).
    np.testing.assert_allclose(
        _p_FW(automotive, np.radians([0, 90, 0, 0, 0, 0]), "base_link"), [1.6 + 0.2, 0, 0.78 - 1.1825], atol=1e-9
    )


def test_kuka_wrist_centre(aerospace):
    """KUKA wrist centre at A2 = -90, A3 = +90 deg: (1.75, 0, 1.984) m from the
    robot base, which sits 0.385 m above the carriage frame."""
    q = np.zeros(7)
    q[2], q[3] = np.radians(-90), np.radians(90)
    np.testing.assert_allclose(_p_FW(aerospace, q, "carriage"), [1.75, 0, 1.984 + 0.385], atol=1e-9)
    q[0] = 2.5  # the rail moves the wrist along x only
    p_rail = _p_FW(aerospace, q, "rail_base")
    np.testing.assert_allclose(p_rail, [1.75 + 2.5, 0, 1.984 + 0.385 + 0.40], atol=1e-9)


@pytest.mark.parametrize(
    "cell,limits_deg",
    [
        ("automotive", [(-170, 170), (-65, 85), (-180, 70), (-300, 300), (-130, 130), (-360, 360)]),
        ("aerospace", [(-185, 185), (-140, -5), (-120, 155), (-350, 350), (-122.5, 122.5), (-350, 350)]),
    ],
)
def test_position_limits_match_reference(cell, limits_deg, request):
    """Position limits are the reference's (the rail travels 8 m)."""
    wc = request.getfixturevalue(cell)
    lo, hi = wc.position_lower, wc.position_upper
    if cell == "aerospace":
        assert hi[0] - lo[0] == pytest.approx(8.0)
        assert not wc.revolute[0]
        lo, hi = lo[1:], hi[1:]
    np.testing.assert_allclose(np.degrees(lo), [a for a, _ in limits_deg], atol=1e-6)
    np.testing.assert_allclose(np.degrees(hi), [b for _, b in limits_deg], atol=1e-6)


@pytest.mark.parametrize("cell", ["automotive", "aerospace"])
def test_adjacent_links_never_reported_colliding(cell, request):
    """Over random configurations, no reported collision is between a link and
    its parent or child."""
    wc = request.getfixturevalue(cell)
    plant = wc.plant
    adjacent = set()
    for j in plant.GetJointIndices(wc.robot):
        joint = plant.get_joint(j)
        adjacent.add(tuple(sorted((joint.parent_body().name(), joint.child_body().name()))))
    rng = np.random.default_rng(0)
    lo, hi = wc.position_lower, wc.position_upper
    seen_self = 0
    robot_bodies = {plant.get_body(b).name() for b in plant.GetBodyIndices(wc.robot)}
    for _ in range(300):
        q = rng.uniform(lo, hi)
        for pair in wc.colliding_pairs(q):
            assert pair not in adjacent, pair
            seen_self += set(pair) <= robot_bodies
    # Self-collisions do happen (the large gripper), so the check had teeth.
    assert seen_self > 0


@pytest.mark.parametrize("cell", ["automotive", "aerospace"])
def test_gripper_is_a_large_collision_body(cell, request):
    """The draping gripper (1.0 x 1.7 x 0.9 m) takes part in collisions."""
    from pydrake.geometry import Role

    wc = request.getfixturevalue(cell)
    body = wc.plant.GetBodyByName("gripper")
    inspector = wc.scene_graph.model_inspector()
    gids = inspector.GetGeometries(wc.plant.GetBodyFrameIdIfExists(body.index()), Role.kProximity)
    assert len(gids) == 1
    np.testing.assert_allclose(inspector.GetShape(gids[0]).size(), [1.0, 1.7, 0.9])
