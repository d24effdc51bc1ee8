"""The runtime safety filter against independent facts: a two-link planar
arm worked by hand, Drake's own signed distances (the oracle), and random
inputs (hypothesis)."""

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from pydrake.geometry import Box, Cylinder, SceneGraph, Sphere
from pydrake.math import RigidTransform
from pydrake.multibody.plant import CoulombFriction, MultibodyPlant
from pydrake.multibody.tree import FixedOffsetFrame, RevoluteJoint, SpatialInertia
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import PassThrough
from pydrake.systems.rendering import MultibodyPositionToGeometryPose

import drake_cfvol as cf
from drake_cfvol.systems import SafetyFilter, ToolSpeedLimit
from drake_cfvol.systems.filter.safety import _EXITS, _HAIR, _MIN_DISTANCE  # the status layout; the limits' hair

L1, L2, R = 0.5, 0.4, 0.05  # link lengths and the tip sphere's radius, m
VMAX = np.array([1.0, 1.5])  # rad/s
H = 0.01  # s


def _arm(obstacle: str, **kw):
    """A planar two-link arm (revolute joints about z, the second at x = L1
    on the first link) whose only collision geometry is a sphere of radius
    R at its tip (x = L2 on the second link), and one obstacle: ``wall``,
    a box whose face x = 0.8 faces the arm, or ``column``, a cylinder of
    radius 0.2 about the z axis. The filter's inputs are exported; its
    output poses the plant in the SceneGraph."""
    builder = DiagramBuilder()
    sg = builder.AddSystem(SceneGraph())
    plant = MultibodyPlant(0.0)
    plant.RegisterAsSourceForSceneGraph(sg)
    arm = plant.AddModelInstance("arm")
    inertia = SpatialInertia.SolidSphereWithMass(1.0, 0.05)
    link1 = plant.AddRigidBody("link1", arm, inertia)
    link2 = plant.AddRigidBody("link2", arm, inertia)
    plant.AddJoint(RevoluteJoint("j1", plant.world_frame(), link1.body_frame(), [0, 0, 1]))
    elbow = plant.AddFrame(FixedOffsetFrame("elbow", link1.body_frame(), RigidTransform([L1, 0, 0])))
    plant.AddJoint(RevoluteJoint("j2", elbow, link2.body_frame(), [0, 0, 1]))
    friction = CoulombFriction(0.5, 0.5)
    tip = plant.RegisterCollisionGeometry(link2, RigidTransform([L2, 0, 0]), Sphere(R), "tip", friction)
    if obstacle == "wall":
        obs = plant.RegisterCollisionGeometry(
            plant.world_body(), RigidTransform([1.3, 0, 0]), Box(1.0, 4.0, 1.0), "wall", friction
        )
    else:
        obs = plant.RegisterCollisionGeometry(
            plant.world_body(), RigidTransform(), Cylinder(0.2, 1.0), "column", friction
        )
    plant.Finalize()
    speed = kw.pop("tool_speed", None)  # a ToolSpeedLimit (m/s) at the tip sphere's centre
    if speed is not None:
        kw["constraints"] = [ToolSpeedLimit(link2.body_frame(), speed, point=[L2, 0, 0])]
    kw.setdefault("period", H)
    if kw.pop("obstacle_moves", False):  # the obstacle taken as moving on its own (as perceived geometry is)
        kw["dynamic_ids"] = [obs]
    measured = kw.pop("measured", False)  # the SceneGraph posed from an exported measured position
    sf = builder.AddSystem(SafetyFilter(plant, sg, arm, velocity_limits=VMAX, **kw))
    to_pose = builder.AddSystem(MultibodyPositionToGeometryPose(plant))
    if measured:
        robot = builder.AddSystem(PassThrough(2))
        builder.ExportInput(robot.get_input_port(), "measured_position")
        builder.Connect(robot.get_output_port(), to_pose.get_input_port())
        builder.Connect(robot.get_output_port(), sf.measured_position_input)
    else:
        builder.Connect(sf.commanded_position_output, to_pose.get_input_port())
    builder.Connect(to_pose.get_output_port(), sg.get_source_pose_port(plant.get_source_id()))
    builder.Connect(sg.get_query_output_port(), sf.query_object_input)
    for port in (sf.desired_position_input, sf.lower_input, sf.upper_input, sf.nominal_input):
        builder.ExportInput(port, port.get_name())
    builder.ExportOutput(sg.get_query_output_port(), "query_object")
    diagram = builder.Build()
    return diagram, sf, tip, obs


def _fix(diagram, ctx, desired, lower=(-10, -10), upper=(10, 10), nominal=None):
    diagram.GetInputPort("desired_position").FixValue(ctx, np.asarray(desired, float))
    diagram.GetInputPort("lower").FixValue(ctx, np.asarray(lower, float))
    diagram.GetInputPort("upper").FixValue(ctx, np.asarray(upper, float))
    if nominal is not None:
        diagram.GetInputPort("nominal").FixValue(ctx, np.asarray(nominal, float))


def _tip(q):
    """The tip sphere's centre, by hand."""
    return np.array([L1 * np.cos(q[0]) + L2 * np.cos(q[0] + q[1]), L1 * np.sin(q[0]) + L2 * np.sin(q[0] + q[1])])


def _drake_distance(diagram, ctx, a, b):
    return diagram.GetOutputPort("query_object").Eval(ctx).ComputeSignedDistancePairClosestPoints(a, b).distance


@pytest.fixture(scope="module")
def wall():
    return _arm("wall", clearance=0.02, influence_distance=0.15, damper_gain=1.0)


def test_damper_row_by_hand(wall):
    """Near the wall (face x = 0.8) the tip's distance is d = 0.8 - x_tip - R
    and its rate -dx_tip/dt: the filter's one row is a = (L1 s1 + L2 s12,
    L2 s12) and b = -rate (d - d_s - allowance), worked by hand."""
    diagram, sf, tip, wall_id = wall
    ctx = diagram.CreateDefaultContext()
    sctx = sf.GetMyContextFromRoot(ctx)
    q = np.array([0.85, -0.3])
    sf.set_initial_position(sctx, q)
    A, b, dists = sf.damper_rows(sctx)[:3]
    d = 0.8 - _tip(q)[0] - R
    assert 0.02 < d < 0.15
    s1, s12 = np.sin(q[0]), np.sin(q[0] + q[1])
    np.testing.assert_allclose(dists, [d], atol=1e-9)
    np.testing.assert_allclose(A, [[L1 * s1 + L2 * s12, L2 * s12]], atol=1e-9)
    rate = min(1.0 / (0.15 - 0.021), 1.0 / H)
    np.testing.assert_allclose(b, [-rate * (d - 0.021)], atol=1e-9)
    assert sf.rate == pytest.approx(rate)


def test_damper_row_is_drakes_distance_rate(wall):
    """Drake as the oracle: at random configurations near the wall, a v
    equals the central difference of Drake's signed distance along v."""
    diagram, sf, tip, wall_id = wall
    ctx = diagram.CreateDefaultContext()
    sctx = sf.GetMyContextFromRoot(ctx)
    rng = np.random.default_rng(3)
    checked = 0
    while checked < 10:
        q = rng.uniform([-0.6, -1.2], [0.6, 1.2])
        sf.set_initial_position(sctx, q)
        A, b, dists = sf.damper_rows(sctx)[:3]
        if len(b) == 0 or abs(_tip(q)[1]) > 1.5:
            continue
        v = rng.normal(size=2)
        eps = 1e-6
        sf.set_initial_position(sctx, q + eps * v)
        d_plus = _drake_distance(diagram, ctx, tip, wall_id)
        sf.set_initial_position(sctx, q - eps * v)
        d_minus = _drake_distance(diagram, ctx, tip, wall_id)
        assert A[0] @ v == pytest.approx((d_plus - d_minus) / (2 * eps), abs=1e-6)
        checked += 1


def test_second_order_term_by_hand_and_against_drake(wall):
    """The rows' second-order term at a step dq: the witness point (on the
    tip sphere, facing the wall) carried by link 2's turn, by hand, gives
    e = max(0, a dq - n (p' - p)) + R theta^2 / 2, theta = |dq1| + |dq2|;
    and Drake's distance after the step never falls below d + a dq - e (the
    oracle), nor above the witness point's own gap there, at random
    configurations near the wall and steps up to 4 updates at the limits."""
    diagram, sf, tip, wall_id = wall
    ctx = diagram.CreateDefaultContext()
    sctx = sf.GetMyContextFromRoot(ctx)
    rng = np.random.default_rng(7)

    def rot(a):
        return np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])

    checked = 0
    while checked < 40:
        q = rng.uniform([-0.6, -1.2], [0.6, 1.2])
        sf.set_initial_position(sctx, q)
        rows = sf.damper_rows(sctx)
        if len(rows.b) == 0 or abs(_tip(q)[1]) > 1.5:
            continue
        d = rows.distances[0]
        dq = rng.uniform(-1, 1, 2) * VMAX * H * 4
        elbow = lambda x: L1 * np.array([np.cos(x[0]), np.sin(x[0])])  # noqa: E731
        p_w = _tip(q) + [R, 0.0]  # the witness faces the wall (+x)
        p_link2 = rot(-(q[0] + q[1])) @ (p_w - elbow(q))  # in link 2's frame
        p_after = elbow(q + dq) + rot(q[0] + q[1] + dq[0] + dq[1]) @ p_link2
        theta = np.abs(dq).sum()
        change = -(p_after[0] - p_w[0])  # the witness point's gap change (n = -x)
        e_hand = max(0.0, rows.A[0] @ dq - change) + 0.5 * R * theta**2
        e = sf.second_order(sctx, rows, dq)
        assert e == pytest.approx([e_hand], abs=1e-12)
        sf.set_initial_position(sctx, q + dq)
        after = _drake_distance(diagram, ctx, tip, wall_id)
        # Below: the row's promise; above: the witness point's own gap (a point of the sphere).
        assert d + rows.A[0] @ dq - e[0] - 1e-12 <= after <= d + change + 1e-9
        checked += 1


@pytest.fixture(scope="module")
def wall_1ms():
    return _arm("wall", clearance=0.02, period=0.001)


@pytest.mark.parametrize("arm", ["wall", pytest.param("wall_1ms", marks=pytest.mark.slow)])
def test_push_into_the_wall_stops_at_the_margin(arm, request):
    """Asked to swing straight through the wall, the tip approaches it ever
    slower and stops at the margin: Drake's distance (and the hand formula)
    never below 0.02 m, and within 3 mm of it at the end (4 s); no update
    moves a joint faster than its limit. At 10 ms and at 1 ms."""
    diagram, sf, tip, wall_id = request.getfixturevalue(arm)
    h = sf.period
    ctx = diagram.CreateDefaultContext()
    sctx = sf.GetMyContextFromRoot(ctx)
    sf.set_initial_position(sctx, [1.2, 0.0])
    _fix(diagram, ctx, [-0.3, 0.0])
    sim = Simulator(diagram, ctx)
    q_prev, dists = np.array([1.2, 0.0]), []
    for n in range(1, int(round(4.0 / h)) + 1):
        sim.AdvanceTo(n * h)
        q = sf.commanded_position_output.Eval(sctx)
        assert np.all(np.abs(q - q_prev) <= VMAX * h + 1e-12)
        d = _drake_distance(diagram, ctx, tip, wall_id)
        assert d == pytest.approx(0.8 - _tip(q)[0] - R, abs=1e-9) or _tip(q)[0] < 0.3
        dists.append(d)
        q_prev = q.copy()
    assert min(dists) >= 0.02 - 1e-6
    assert dists[-1] <= 0.023
    assert sf.filter_count_output.Eval(sctx)[0] > 0 and sf.fallback_count_output.Eval(sctx)[0] == 0


def test_motion_along_an_obstacle_is_not_slowed():
    """The tip circling a column at a constant 5 cm (only the first joint
    turns: the distance does not change) inside the influence zone moves at
    the velocity limit, not slowed; with the elbow turning towards the
    column it is slowed."""
    diagram, sf, tip, col = _arm("column", clearance=0.02, influence_distance=0.15)
    ctx = diagram.CreateDefaultContext()
    sctx = sf.GetMyContextFromRoot(ctx)
    q2 = np.arccos(((0.2 + R + 0.05) ** 2 - L1**2 - L2**2) / (2 * L1 * L2))  # |p_tip| = 0.3
    sf.set_initial_position(sctx, [0.0, q2])
    assert _drake_distance(diagram, ctx, tip, col) == pytest.approx(0.05, abs=1e-9)
    _fix(diagram, ctx, [3.0, q2])
    sim = Simulator(diagram, ctx)
    sim.AdvanceTo(0.5 + H / 2)
    q = sf.commanded_position_output.Eval(sctx)
    assert q[0] == pytest.approx(VMAX[0] * 0.51, abs=1e-9) and q[1] == pytest.approx(q2, abs=1e-9)
    assert _drake_distance(diagram, ctx, tip, col) == pytest.approx(0.05, abs=1e-9)
    # Folding the elbow brings the tip towards the column: slowed by the damper.
    _fix(diagram, ctx, [q[0], q2 + 1.0])
    sim.AdvanceTo(0.5 + 2 * H + H / 2)
    step = sf.commanded_position_output.Eval(sctx)[1] - q2
    assert 0 < step < 2 * VMAX[1] * H - 1e-3


def test_far_from_obstacles_the_filter_is_the_identity(wall):
    """Out of the influence zone and within the limits and the box, the
    command is the request, and filter_active stays 0."""
    diagram, sf, tip, wall_id = wall
    ctx = diagram.CreateDefaultContext()
    sctx = sf.GetMyContextFromRoot(ctx)
    sf.set_initial_position(sctx, [2.0, 0.5])
    sim = Simulator(diagram, ctx)
    for n, dq in enumerate(([0.005, -0.01], [0.009, 0.0], [-0.002, 0.014])):
        q = sf.commanded_position_output.Eval(sctx) + dq
        _fix(diagram, ctx, q, [1.0, -1.0], [3.0, 1.0])
        sim.AdvanceTo(n * H + H / 2)
        np.testing.assert_array_equal(sf.commanded_position_output.Eval(sctx), q)
        assert sf.filter_active_output.Eval(sctx)[0] == 0.0
    assert sf.filter_count_output.Eval(sctx)[0] == 0.0


def test_the_nominal_is_admissible_below_the_margin(wall):
    """A nominal that passes the wall closer than the margin (1 cm, margin
    2 cm, approaching) is followed exactly at zero deviation: the filter
    does not act."""
    diagram, sf, tip, wall_id = wall
    ctx = diagram.CreateDefaultContext()
    sctx = sf.GetMyContextFromRoot(ctx)
    # q1 sweeps towards the wall with the elbow straight: x_tip = 0.9 cos q1.
    x_at = lambda q1: 0.9 * np.cos(q1)  # noqa: E731
    q1_end = np.arccos((0.8 - R - 0.01) / 0.9)
    nominal = [np.array([q1_end + 0.004 * (20 - n), 0.0]) for n in range(21)]
    sf.set_initial_position(sctx, nominal[0])
    sim = Simulator(diagram, ctx)
    for n in range(1, 21):
        _fix(diagram, ctx, nominal[n], nominal[n] - 0.1, nominal[n] + 0.1, nominal=nominal[n])
        sim.AdvanceTo((n - 1) * H + H / 2)
        np.testing.assert_allclose(sf.commanded_position_output.Eval(sctx), nominal[n], atol=1e-12)
    assert 0.8 - x_at(nominal[-1][0]) - R == pytest.approx(0.01)
    assert sf.filter_count_output.Eval(sctx)[0] == 0.0


def test_a_box_out_of_reach_is_approached_at_the_limit(wall):
    """A box farther than one step at the velocity limits is approached at
    the limits, not jumped to."""
    diagram, sf, tip, wall_id = wall
    ctx = diagram.CreateDefaultContext()
    sctx = sf.GetMyContextFromRoot(ctx)
    sf.set_initial_position(sctx, [2.0, 0.0])
    _fix(diagram, ctx, [2.5, -0.5], [2.4, -0.6], [2.6, -0.4])
    Simulator(diagram, ctx).AdvanceTo(H / 2)
    np.testing.assert_allclose(sf.commanded_position_output.Eval(sctx), [2.0 + VMAX[0] * H, -VMAX[1] * H])
    assert sf.velocity_ratio_output.Eval(sctx)[0] == pytest.approx(1.0)


def test_the_box_gives_way_to_the_damper(wall):
    """A box (uncertified) whose upper bound on the first joint sweeps
    through the wall at 0.5 rad/s, the elbow's box a point at 0: the
    filter leaves the box rather than follow it into the wall (Drake's
    distance never below the margin), reports it (``box_exits``), and never
    exceeds a velocity limit."""
    diagram, sf, tip, wall_id = wall
    ctx = diagram.CreateDefaultContext()
    sctx = sf.GetMyContextFromRoot(ctx)
    sf.set_initial_position(sctx, [1.3, 0.0])
    sim = Simulator(diagram, ctx)
    q_prev, worst = np.array([1.3, 0.0]), np.inf
    for n in range(1, 301):
        hi = max(1.3 - 0.5 * n * H, -0.9)
        _fix(diagram, ctx, [hi, 0.0], [-1.2, 0.0], [hi, 0.0], nominal=[-1.0, 0.0])
        sim.AdvanceTo((n - 1) * H + H / 2)
        q = sf.commanded_position_output.Eval(sctx)
        assert np.all(np.abs(q - q_prev) <= VMAX * H + 1e-12)
        worst = min(worst, _drake_distance(diagram, ctx, tip, wall_id))
        q_prev = q.copy()
    assert worst >= 0.02 - 1e-3
    assert sf.box_exits_output.Eval(sctx)[0] > 0


def test_bad_inputs_hold_without_raising(wall):
    """A NaN request or crossed bounds hold the command (no exception) and
    count as fallbacks."""
    diagram, sf, tip, wall_id = wall
    ctx = diagram.CreateDefaultContext()
    sctx = sf.GetMyContextFromRoot(ctx)
    sf.set_initial_position(sctx, [2.0, 0.3])
    _fix(diagram, ctx, [np.nan, 0.0])
    sim = Simulator(diagram, ctx)
    sim.AdvanceTo(H / 2)
    np.testing.assert_array_equal(sf.commanded_position_output.Eval(sctx), [2.0, 0.3])
    _fix(diagram, ctx, [2.1, 0.3], [3.0, 0.0], [2.0, 1.0])
    sim.AdvanceTo(H + H / 2)
    np.testing.assert_array_equal(sf.commanded_position_output.Eval(sctx), [2.0, 0.3])
    assert sf.fallback_count_output.Eval(sctx)[0] == 2.0


def test_hold_keeps_the_last_command(wall):
    """While ``hold`` is above 0.5 (or NaN: fail safe) an update keeps the
    command and counts in hold_count; at 0 the command moves again."""
    diagram, sf, tip, wall_id = wall
    ctx = diagram.CreateDefaultContext()
    sctx = sf.GetMyContextFromRoot(ctx)
    sf.set_initial_position(sctx, [2.0, 0.3])
    _fix(diagram, ctx, [2.1, 0.4])
    sim = Simulator(diagram, ctx)
    for n, hold in enumerate((1.0, np.nan)):
        sf.hold_input.FixValue(sctx, [hold])
        sim.AdvanceTo((n + 0.5) * sf.period)
        np.testing.assert_array_equal(sf.commanded_position_output.Eval(sctx), [2.0, 0.3])
        np.testing.assert_array_equal(sf.commanded_velocity_output.Eval(sctx), [0.0, 0.0])
    assert sf.hold_count_output.Eval(sctx)[0] == 2.0
    sf.hold_input.FixValue(sctx, [0.0])
    sim.AdvanceTo(2.5 * sf.period)
    assert np.abs(sf.commanded_position_output.Eval(sctx) - [2.0, 0.3]).max() > 0
    assert sf.hold_count_output.Eval(sctx)[0] == 2.0


@pytest.mark.parametrize(("depth", "fault"), [(0.10, 2), (0.20, 0)])
def test_an_obstacle_overlapping_the_robot_deeper_than_the_depth_faults_and_holds(depth, fault):
    """The arm straight along x: its tip sphere spans x in [0.85, 0.95], the wall's face lies at x = 0.8, so
    they overlap by 0.15 m (by hand; Drake agrees). Taken as moving on its own (perceived) with an
    overlap_depth of 0.10 m, the filter faults (2) at its first update and holds the command there for good,
    whatever is asked; with 0.20 m it does not fault, and the damper moves the tip out of the wall."""
    diagram, sf, tip, wall_id = _arm("wall", clearance=0.02, obstacle_moves=True, overlap_depth=depth)
    ctx = diagram.CreateDefaultContext()
    sctx = sf.GetMyContextFromRoot(ctx)
    sf.set_initial_position(sctx, [0.0, 0.0])
    assert _drake_distance(diagram, ctx, tip, wall_id) == pytest.approx(0.8 - (L1 + L2 + R))
    _fix(diagram, ctx, [0.0, 0.0])
    sim = Simulator(diagram, ctx)
    sim.AdvanceTo(5.5 * H)
    assert sf.filter_fault_output.Eval(sctx)[0] == fault
    q = sf.commanded_position_output.Eval(sctx)
    if fault:
        np.testing.assert_array_equal(q, [0.0, 0.0])
        _fix(diagram, ctx, [0.5, 0.5])  # asked to move: still held
        sim.AdvanceTo(10.5 * H)
        np.testing.assert_array_equal(sf.commanded_position_output.Eval(sctx), [0.0, 0.0])
        np.testing.assert_array_equal(sf.commanded_velocity_output.Eval(sctx), [0.0, 0.0])
    else:
        assert _drake_distance(diagram, ctx, tip, wall_id) > 0.8 - (L1 + L2 + R)  # moving out of the wall


def test_more_rows_than_the_cap_fault_the_filter_and_hold():
    """The tip 0.105 m from the wall's face (inside the influence distance: the damper has rows): a filter whose
    row cap is 0 faults (1) at its first update instead of solving, and holds the command."""
    diagram, sf, tip, wall_id = _arm("wall", clearance=0.02)
    sf.MAX_ROWS = 0  # this instance only
    ctx = diagram.CreateDefaultContext()
    sctx = sf.GetMyContextFromRoot(ctx)
    q0 = [0.0, -1.2]
    sf.set_initial_position(sctx, q0)
    d = _drake_distance(diagram, ctx, tip, wall_id)
    assert 0 < d < sf.influence_distance
    _fix(diagram, ctx, [0.1, -1.2])
    Simulator(diagram, ctx).AdvanceTo(1.5 * H)
    assert sf.filter_fault_output.Eval(sctx)[0] == 1
    np.testing.assert_array_equal(sf.commanded_position_output.Eval(sctx), q0)


def test_constructor_checks(wall):
    """Margins and rates out of range are refused, naming the argument."""
    diagram, sf, tip, wall_id = wall
    plant = sf._plant
    with pytest.raises(cf.ParameterError, match="influence_distance"):
        SafetyFilter(plant, SceneGraph(), plant.GetModelInstanceByName("arm"), clearance=0.2, influence_distance=0.1)
    with pytest.raises(cf.DimensionError, match="velocity_limits"):
        SafetyFilter(plant, SceneGraph(), plant.GetModelInstanceByName("arm"), velocity_limits=[1.0, 1.0, 1.0])


@pytest.fixture(scope="module")
def arm_with_accel():
    return _arm("wall", clearance=0.02, acceleration_limits=[20.0, 30.0])


@pytest.fixture(scope="module")
def arm_1ms():
    return _arm("wall", clearance=0.02, period=0.001, acceleration_limits=[20.0, 30.0])


@settings(max_examples=60, deadline=None)
@given(
    q=st.lists(st.floats(-3.0, 3.0), min_size=2, max_size=2),
    desired=st.lists(st.floats(-5.0, 5.0), min_size=2, max_size=2),
    centre=st.lists(st.floats(-3.0, 3.0), min_size=2, max_size=2),
    width=st.lists(st.floats(0.0, 1.0), min_size=2, max_size=2),
    nominal_at=st.lists(st.floats(0.0, 1.0), min_size=2, max_size=2),
    accel=st.booleans(),
    fast=st.booleans(),
)
@example(
    q=[0.01, 0.0],
    desired=[0.0, 0.0],
    centre=[0.0, 0.0],
    width=[0.0, 0.0],
    nominal_at=[0.0, 0.0],
    accel=False,
    fast=False,
)
def test_never_faster_than_the_limits(
    wall, arm_with_accel, arm_1ms, q, desired, centre, width, nominal_at, accel, fast
):
    """Random states, requests, boxes and nominals (the arm may start in
    the wall): no update moves a joint more than limit x period; the
    command lands in the box wherever the box is within one step, unless
    the filter reports leaving it (``box_exits``), which it does only with
    the wall inside the influence distance (a damper row needed the room).
    At a 10 ms period and (``fast``) at 1 ms."""
    diagram, sf, tip, wall_id = arm_1ms if fast else arm_with_accel if accel else wall
    H = sf.period
    ctx = diagram.CreateDefaultContext()
    sctx = sf.GetMyContextFromRoot(ctx)
    q = np.array(q)
    lower = np.array(centre) - np.array(width) / 2
    upper = lower + np.array(width)
    nominal = lower + np.array(nominal_at) * (upper - lower)
    sf.set_initial_position(sctx, q)
    _fix(diagram, ctx, desired, lower, upper, nominal=nominal)
    update = sf.EvalUniquePeriodicDiscreteUpdate(sctx)
    x = update.get_vector(0).CopyToVector()
    assert np.all(np.abs(x - q) <= VMAX * H + 1e-12)
    reachable = (lower - q <= VMAX * H) & (q - upper <= VMAX * H)
    # The filter commands a hair under the limits (1 - _HAIR): a box a whole
    # step away is reached to within VMAX H _HAIR (hypothesis found q 0.01,
    # a zero-width box at 0, landing 1e-11 short).
    tol = VMAX * H * _HAIR + 1e-12
    inside = np.all(~reachable | ((x >= lower - tol) & (x <= upper + tol)))
    status = update.get_vector(2).CopyToVector()
    exited = status[_EXITS] > 0
    assert inside or exited
    if exited:
        # A damper row needed the room, or (with acceleration limits, from
        # rest) the box lies farther than one step at a dt can reach.
        step = VMAX * H if sf.acceleration_limits is None else np.minimum(VMAX * H, sf.acceleration_limits * H * H)
        near = (lower - q <= step) & (q - upper <= step)
        assert status[_MIN_DISTANCE] < sf.influence_distance or not near.all()


@pytest.mark.parametrize("speed", [None, 0.3])
def test_tool_speed_limit_caps_the_tip_speed(speed):
    """A ToolSpeedLimit (one FilterConstraint class, no change to the QP)
    at the tip, 0.3 m/s: asked to swing far from the wall at the joints'
    limits, the tip's chord per update (the hand formula) never exceeds
    0.3 m/s beyond the step's second-order term (1e-3 m/s here), and the
    limit binds (the tip reaches 0.3 / 1.13 m/s, the rows' inner
    polytope's worst direction, or more). Without it the same request moves
    the tip at about 1 m/s; requests under the limit pass unchanged."""
    diagram, sf, tip, wall_id = _arm("wall", clearance=0.02, tool_speed=speed)
    ctx = diagram.CreateDefaultContext()
    sctx = sf.GetMyContextFromRoot(ctx)
    q0 = np.array([2.0, 0.5])
    sf.set_initial_position(sctx, q0)
    _fix(diagram, ctx, [4.0, 2.5])
    sim = Simulator(diagram, ctx)
    q_prev, speeds = q0, []
    for n in range(1, 101):
        sim.AdvanceTo(n * H)
        q = sf.commanded_position_output.Eval(sctx).copy()
        assert np.all(np.abs(q - q_prev) <= VMAX * H + 1e-12)
        speeds.append(np.linalg.norm(_tip(q) - _tip(q_prev)) / H)
        q_prev = q
    if speed is None:
        assert max(speeds) > 0.9
        return
    assert max(speeds) <= speed + 1e-3
    assert max(speeds) >= speed / 1.13 - 1e-3
    # A slow request (0.1 m/s at most) is commanded as is.
    q = sf.commanded_position_output.Eval(sctx).copy()
    target = q + np.array([0.1, -0.05]) * H
    _fix(diagram, ctx, target)
    sim.AdvanceTo(101 * H)
    np.testing.assert_allclose(sf.commanded_position_output.Eval(sctx), target, atol=1e-12)


def test_a_tightened_box_is_reentered_at_the_limits():
    """A live box tightened around the command (joint 1 left 0.049 rad
    above it, joint 2 0.2 rad), the request held where it was: each joint
    returns at its velocity limit, q_j(n) = max(upper_j, q0_j - n vmax_j
    dt), so joint 1 is back after 5 updates and joint 2 after 14; the
    command never leaves the base box it started in; and the run's bound
    figures (comanip.run.bound_figures) report 0 against the base table,
    0.2 rad of live excess and 14 updates of catch-up."""
    from drake_cfvol.comanip.run import bound_figures

    diagram, sf, tip, wall_id = _arm("wall", clearance=0.02)
    ctx = diagram.CreateDefaultContext()
    sctx = sf.GetMyContextFromRoot(ctx)
    q0 = np.array([2.0, 0.5])
    base_lo, base_hi = np.array([1.5, 0.0]), np.array([2.5, 1.0])
    live_lo, live_hi = np.array([1.9, 0.0]), np.array([1.951, 0.3])
    sf.set_initial_position(sctx, q0)
    _fix(diagram, ctx, q0, live_lo, live_hi)
    sim = Simulator(diagram, ctx)
    t, q = [0.0], [q0]
    for n in range(1, 31):
        sim.AdvanceTo(n * H)
        t.append(n * H)
        q.append(sf.commanded_position_output.Eval(sctx).copy())
    t, q = np.array(t), np.array(q)
    n = np.arange(len(t))[:, None]
    expected = np.maximum(live_hi, q0 - n * VMAX * (1 - 1e-9) * H)
    np.testing.assert_allclose(q, expected, atol=1e-12)
    assert np.all((q >= base_lo) & (q <= base_hi))
    inside = np.all(q <= live_hi + 1e-12, axis=1)
    assert np.flatnonzero(q[:, 0] <= live_hi[0] + 1e-12)[0] == 5 and np.flatnonzero(inside)[0] == 14
    figures = bound_figures(
        t,
        q,
        np.tile(base_lo, (len(t), 1)),
        np.tile(base_hi, (len(t), 1)),
        np.tile(live_lo, (len(t), 1)),
        np.tile(live_hi, (len(t), 1)),
    )
    assert figures["max_bound_violation"] == 0.0
    assert figures["live_box_excess_max"] == pytest.approx(0.2, abs=1e-12)
    assert figures["live_box_catchup_s"] == pytest.approx(14 * H, abs=1e-12)


def test_a_measured_robot_skips_far_pairs_and_measures_every_near_one():
    """A robot that tracks with an error (the SceneGraph posed from the
    measured position, which moves up to 0.08 rad per update, five times
    the command's step at the limits) swept from far off the wall to within
    a few cm of it and back: at every update the filter's smallest distance
    is a lower bound of Drake's at the measured configuration, within GJK's
    tolerance of it whenever the tip lies within the influence distance (the
    pair was measured), and below it at updates where the pair lay far and was
    skipped (its budget spent by the measured motion since it was
    measured)."""
    from drake_cfvol.systems.filter.distance_kernel import GJK_TOLERANCE

    diagram, sf, tip, wall_id = _arm("wall", clearance=0.02, influence_distance=0.15, measured=True)
    sim = Simulator(diagram)
    ctx = sim.get_mutable_context()
    sctx = sf.GetMyContextFromRoot(ctx)
    rng = np.random.default_rng(11)
    # q1 from 1.2 rad (the tip 0.9 m off the wall's face) to 0 (3 cm off) and back, with jitter.
    sweep = np.concatenate([np.linspace(1.2, 0.0, 60), np.linspace(0.0, 1.2, 60)])
    near = skipped = 0
    for n, a in enumerate(sweep):
        q_m = np.array([a + rng.uniform(-0.03, 0.03), rng.uniform(-0.03, 0.03)])
        _fix(diagram, ctx, desired=q_m)
        diagram.GetInputPort("measured_position").FixValue(ctx, q_m)
        sim.AdvanceTo((n + 1) * H)  # the update at n H, with the robot at q_m
        seen = sctx.get_discrete_state(sf._status).GetAtIndex(_MIN_DISTANCE)
        true = _drake_distance(diagram, ctx, tip, wall_id)
        assert seen <= true + 1e-9
        if true < sf.influence_distance:  # measured: GJK's lower bound, within its tolerance
            assert seen >= true - GJK_TOLERANCE
            near += 1
        elif seen < true - 1e-6:
            skipped += 1
    assert near > 10 and skipped > 20


def test_a_constraint_naming_a_damper_row_that_does_not_exist_is_refused():
    """A user's constraint whose second_order_rows name a damper row the
    update does not have (the compiled rounds would read past the rows) is
    refused at the update with an error naming the constraint."""
    from drake_cfvol.exceptions import ParameterError
    from drake_cfvol.systems.filter.constraints import FilterConstraint

    class Wrong(FilterConstraint):
        name = "wrong"

        def rows(self, step):
            return np.array([[1.0, 0.0]]), np.array([-10.0])

        def second_order_rows(self, step):
            return [len(step.damper.b) + 3]

    diagram, sf, _, _ = _arm("wall", clearance=0.02, constraints=[Wrong()])
    sim = Simulator(diagram)
    _fix(diagram, sim.get_mutable_context(), desired=[0.3, 0.2])
    with pytest.raises(ParameterError, match="constraint 'wrong': second_order_rows"):
        sim.AdvanceTo(2 * H)


def _drift_arm():
    diagram, sf, tip, wall_id = _arm("wall", clearance=0.02, influence_distance=0.15, measured=True)
    sim = Simulator(diagram)
    ctx = sim.get_mutable_context()
    return (diagram, sf, sim), ctx, sf.GetMyContextFromRoot(ctx)


def _at_distance(d):
    """q = (q1, 0) with the tip sphere d (m) off the wall's face, by hand."""
    return np.array([np.arccos((0.8 - R - d) / (L1 + L2)), 0.0])


def _update(arm, ctx, sctx, n, q_m, desired):
    """The filter's update n (at n H) with the robot measured at q_m; its commanded step (rad)."""
    diagram, sf, sim = arm
    q0 = sf.commanded_position_output.Eval(sctx).copy()
    _fix(diagram, ctx, desired)
    diagram.GetInputPort("measured_position").FixValue(ctx, np.asarray(q_m, float))
    sim.AdvanceTo((n + 1) * H)
    return sf.commanded_position_output.Eval(sctx) - q0


def test_a_measured_robot_drifting_towards_an_obstacle_is_countered():
    """The measured robot moved 0.01 rad towards the wall in one update while
    its command stood still (a co-worker bending a soft arm): the tip row,
    by hand a = -d x_tip / dq = (L1 + L2) sin q1 (1, L2 / (L1 + L2)) at
    q2 = 0, asks the command for its share of that drift on top of the
    damper's -rate (d - d_t): the commanded step meets a v = -rate (d - d_t)
    + a (0.01 / H, 0) (to the rows' second-order term), where the same robot
    measured there without the drift is left where it is."""
    q_a = _at_distance(0.06)
    q_b = q_a - [0.01, 0.0]
    d_b = 0.8 - R - _tip(q_b)[0]
    a = (L1 + L2) * np.sin(q_b[0]) * np.array([1.0, L2 / (L1 + L2)])
    steps = {}
    for case, measured in (("still", [q_b]), ("drift", [q_a, q_b])):
        arm, ctx, sctx = _drift_arm()
        sf = arm[1]
        sf.set_initial_position(sctx, q_a)
        for n, q_m in enumerate(measured):
            step = _update(arm, ctx, sctx, n, q_m, desired=q_a)
        steps[case] = step / H
    b = -sf.rate * (d_b - sf.target_distance)
    assert b < 0 and np.allclose(steps["still"], 0.0)  # the request (stand still) keeps the row
    need = b + a @ np.array([0.01 / H, 0.0])
    assert need > 0  # the drift turns the allowance into a retreat
    assert need - 1e-9 <= a @ steps["drift"] <= need + 2e-3


def test_a_drift_beyond_the_limits_raises_a_tracking_fault_and_holds_the_request():
    """The measured robot drifts towards the wall at 5 rad/s, faster than any
    command within the limits (1, 1.5 rad/s) can counter: the update misses
    the tip row, raises tracking_fault and counts it; the next update
    (the robot now following its command, every row kept) holds the request
    and clears the fault, and the one after follows the request again."""
    arm, ctx, sctx = _drift_arm()
    sf = arm[1]
    q_a = _at_distance(0.10)
    sf.set_initial_position(sctx, q_a)
    _update(arm, ctx, sctx, 0, q_a, desired=q_a)
    q_m = q_a - [0.05, 0.0]
    step = _update(arm, ctx, sctx, 1, q_m, desired=q_a)
    a = (L1 + L2) * np.sin(q_m[0]) * np.array([1.0, L2 / (L1 + L2)])
    assert a @ (VMAX * [1.0, 1.0]) < -sf.rate * (0.8 - R - _tip(q_m)[0] - sf.target_distance) + a @ [5.0, 0.0]
    assert np.all(np.abs(step) <= VMAX * H * (1 + 1e-12))
    assert sf.tracking_fault_output.Eval(sctx)[0] == 1.0 and sf.tracking_faults_output.Eval(sctx)[0] == 1.0
    assert sf.damper_misses_output.Eval(sctx)[0] == 1.0
    q_m = q_m + step  # the robot follows its command from here on
    ask = [0.0, 0.005]  # a step along the wall that keeps every row
    for n, held in ((2, True), (3, False)):
        q_c = sf.commanded_position_output.Eval(sctx).copy()
        step = _update(arm, ctx, sctx, n, q_m, desired=q_c + ask)
        np.testing.assert_allclose(step, np.zeros(2) if held else ask, atol=1e-12)
        assert sf.tracking_fault_output.Eval(sctx)[0] == 0.0 and sf.tracking_faults_output.Eval(sctx)[0] == 1.0
        q_m = q_m + step


def test_a_non_finite_measured_position_holds_the_command():
    """A NaN in the measured position (a dropped sensor value) holds the
    command and counts a fallback, as a non-finite input does; the next
    finite measurement is followed again without a drift from the stale one."""
    arm, ctx, sctx = _drift_arm()
    sf = arm[1]
    q_a = _at_distance(0.10)
    sf.set_initial_position(sctx, q_a)
    _update(arm, ctx, sctx, 0, q_a, desired=q_a)
    ask = [0.0, 0.005]
    step = _update(arm, ctx, sctx, 1, [np.nan, 0.0], desired=q_a + ask)
    np.testing.assert_array_equal(step, np.zeros(2))
    assert sf.fallback_count_output.Eval(sctx)[0] == 1.0
    step = _update(arm, ctx, sctx, 2, q_a, desired=q_a + ask)
    np.testing.assert_allclose(step, ask, atol=1e-12)
    assert sf.tracking_faults_output.Eval(sctx)[0] == 0.0


def test_the_stacked_rows_are_the_constraints_written_out():
    """The filter's own constraints stacked in one compiled call equal the
    rows written out by hand with numpy: [I; -I] over the joints with a
    finite limit (b = v_lo, -v_hi), the box [I; -I] (b = lo, -hi), each
    damper block's rows of its pairs in order (with their row indices),
    the stop rows as given (no second-order row), the per-row priorities,
    weights and relaxation, zeros' signs included."""
    from drake_cfvol.systems.filter.constraints import BOX, HARD, ROW
    from drake_cfvol.systems.filter.filter_kernel import BOX_ROWS, DAMPER_ROWS, LIMIT_ROWS, STOP_ROWS, stack_rows

    rng = np.random.default_rng(3)
    for _ in range(50):
        k, P, m = rng.integers(1, 8), rng.integers(0, 6), rng.integers(0, 15)
        vmax = rng.uniform(0.5, 2.0, k)
        vmax[rng.random(k) < 0.3] = np.inf
        v_lo, v_hi = -vmax * rng.uniform(0.5, 1.0, k), vmax * rng.uniform(0.5, 1.0, k)
        lo, hi = -rng.uniform(0, 1, k), rng.uniform(0, 1, k)
        dA, db = rng.normal(size=(m, k)), rng.normal(size=m)
        dpair = rng.integers(0, max(P, 1), m) if P else np.zeros(0, np.int64)
        if not P:
            dA, db = dA[:0], db[:0]
        dynamic = rng.random(P) < 0.4
        n_stop = rng.integers(0, 4)
        sA, sb = rng.normal(size=(n_stop, k)), rng.normal(size=n_stop)
        kinds = np.array([LIMIT_ROWS, BOX_ROWS, DAMPER_ROWS, DAMPER_ROWS, STOP_ROWS])
        weights, prios = np.array([1e6, 1e3, 1e6, 1e6, 1e6]), np.array([HARD, BOX, ROW, ROW, ROW])
        relaxed = np.array([False, False, True, False, False])
        pairs = np.array([np.zeros(P, bool), np.zeros(P, bool), ~dynamic, dynamic, np.zeros(P, bool)])
        A, b, prio, weight, so, rel, counts = stack_rows(
            kinds, weights, prios, relaxed, pairs, v_lo, v_hi, lo, hi, dA, db, dpair, sA, sb
        )
        finite = np.isfinite(vmax)
        eye = np.eye(k)
        static, moving = ~dynamic[dpair], dynamic[dpair]
        want_A = np.vstack([eye[finite], -eye[finite], eye, -eye, dA[static], dA[moving], sA])
        want_b = np.concatenate([v_lo[finite], -v_hi[finite], lo, -hi, db[static], db[moving], sb])
        want_counts = [2 * finite.sum(), 2 * k, static.sum(), moving.sum(), n_stop]
        assert counts.tolist() == want_counts
        assert np.array_equal(A, want_A) and np.array_equal(np.signbit(A), np.signbit(want_A))
        assert np.array_equal(b, want_b)
        assert np.array_equal(prio, np.repeat(prios, want_counts))
        assert np.array_equal(weight, np.repeat(weights, want_counts))
        assert np.array_equal(rel, np.repeat(relaxed, want_counts))
        want_so = np.concatenate(
            [np.full(2 * finite.sum() + 2 * k, -1), np.flatnonzero(static), np.flatnonzero(moving), np.full(n_stop, -1)]
        )
        assert np.array_equal(so, want_so)


def test_the_filters_own_constraints_in_one_call_equal_them_one_by_one():
    """A filter whose constraints are its own stacks them in one compiled
    call; a user's constraint (here one with no rows) sends the update
    through each constraint's rows instead. Both give the same commands,
    bit for bit, over a push into the wall and along it (damper rows
    active, the box and the limits binding)."""
    from drake_cfvol.systems.filter.constraints import FilterConstraint

    class NoRows(FilterConstraint):
        name = "no_rows"

        def rows(self, step):
            return np.zeros((0, 2)), np.zeros(0)

    runs = []
    for extra in ([], [NoRows()]):
        diagram, sf, _, _ = _arm("wall", clearance=0.02, influence_distance=0.15, constraints=extra)
        ctx = diagram.CreateDefaultContext()
        sctx = sf.GetMyContextFromRoot(ctx)
        sf.set_initial_position(sctx, [1.2, 0.0])
        sim = Simulator(diagram, ctx)
        out = []
        for n, desired in enumerate([[-0.3, 0.0]] * 150 + [[0.2, 1.0]] * 100):
            _fix(diagram, ctx, desired, lower=(-0.5, -2.0), upper=(1.5, 0.8), nominal=[1.2, 0.0])
            sim.AdvanceTo((n + 1) * H)
            out.append(sf.commanded_position_output.Eval(sctx).copy())
        runs.append((np.array(out), sf.filter_count_output.Eval(sctx)[0], sf.qp_solves))
    (a, count_a, solves_a), (b, count_b, solves_b) = runs
    assert count_a > 50 and solves_a > 0  # the damper and the box at work
    assert np.array_equal(a, b) and count_a == count_b and solves_a == solves_b


def test_a_damper_constraint_with_the_wrong_number_of_pairs_is_refused():
    """A DamperConstraint whose pairs flag another number of pairs than the
    damper watches (the compiled stacking would read past them) is refused
    at the update, naming what it must hold."""
    from drake_cfvol.exceptions import ParameterError
    from drake_cfvol.systems.filter.constraints import DamperConstraint

    short = DamperConstraint(weight=1.0, relax=False, pairs=[], name="short")
    diagram, sf, _, _ = _arm("wall", clearance=0.02, constraints=[short])
    ctx = diagram.CreateDefaultContext()
    sf.set_initial_position(sf.GetMyContextFromRoot(ctx), [1.2, 0.0])
    sim = Simulator(diagram, ctx)
    _fix(diagram, ctx, desired=[1.0, 0.0])
    with pytest.raises(ParameterError, match="pairs must hold one flag per damper pair"):
        sim.AdvanceTo(2 * H)
