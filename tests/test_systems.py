"""The Drake systems, on their outputs (FixValue / Eval)."""

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pydrake.systems.analysis import Simulator

import drake_cfvol as cf
from drake_cfvol.algorithm.table import BoundsTable
from drake_cfvol.systems import AdmittanceDeformation, JointBoundsSource, PathProgress, Push, ScriptedHuman


def _table():
    lower = np.array([[-1.0, 0.0], [-0.5, 0.2], [-0.2, 0.1]])
    upper = np.array([[1.0, 1.0], [2.0, 0.4], [0.3, 0.9]])
    nominal = np.array([[0.0, 0.5], [0.0, 0.3], [0.1, 0.5]])
    return BoundsTable(lower, upper, nominal, ["a", "b"], np.array([-3.0, -3.0]), np.array([3.0, 3.0]))


def _eval(system, s):
    ctx = system.CreateDefaultContext()
    system.path_index_input.FixValue(ctx, [s])
    return (system.lower_output.Eval(ctx), system.upper_output.Eval(ctx), system.nominal_output.Eval(ctx))


def test_bounds_source_at_waypoints():
    """At integer s the outputs are the table's rows."""
    t = _table()
    src = JointBoundsSource(t)
    for i in range(t.g):
        lo, hi, nom = _eval(src, float(i))
        np.testing.assert_array_equal(lo, t.lower[i])
        np.testing.assert_array_equal(hi, t.upper[i])
        np.testing.assert_array_equal(nom, t.nominal[i])


def test_bounds_source_between_waypoints():
    """At fractional s: intersection of the neighbours, holding the
    interpolated nominal (SPEC 7), worked by hand."""
    lo, hi, nom = _eval(JointBoundsSource(_table()), 0.5)
    np.testing.assert_allclose(nom, [0.0, 0.4])
    np.testing.assert_allclose(lo, [-0.5, 0.2])
    np.testing.assert_allclose(hi, [1.0, 0.4])


def test_bounds_source_between_waypoints_with_stretch_boxes():
    """With certified stretch boxes and a rate limit (SPEC 7, "stretch"
    rule), by hand: at s = 0.5 the first stretch's box, each bound capped by
    the second stretch's bound plus rate x 0.5 (joint 0; joint 1 has no
    limit); at s = 1.5 the second stretch's box."""
    t = dataclasses.replace(
        _table(),
        stretch_lower=np.array([[-0.7, 0.1], [-0.3, 0.15]]),
        stretch_upper=np.array([[0.9, 0.45], [0.25, 0.5]]),
        rate=np.array([0.2, np.inf]),
    )
    src = JointBoundsSource(t)
    lo, hi, nom = _eval(src, 0.5)
    np.testing.assert_allclose(nom, [0.0, 0.4])
    np.testing.assert_allclose(lo, [-0.3 - 0.2 * 0.5, 0.1])
    np.testing.assert_allclose(hi, [0.25 + 0.2 * 0.5, 0.45])
    lo, hi, nom = _eval(src, 1.5)
    np.testing.assert_allclose(lo, [-0.3, 0.15])
    np.testing.assert_allclose(hi, [0.25, 0.5])


def test_bounds_source_between_waypoints_linear():
    """A certified ("linear") table, by hand: at s = 0.25 every bound is a
    quarter of the way from waypoint 0's to waypoint 1's."""
    t = dataclasses.replace(_table(), interpolation="linear")
    lo, hi, nom = _eval(JointBoundsSource(t), 0.25)
    np.testing.assert_allclose(nom, [0.0, 0.45])
    np.testing.assert_allclose(lo, [0.75 * -1.0 + 0.25 * -0.5, 0.75 * 0.0 + 0.25 * 0.2])
    np.testing.assert_allclose(hi, [0.75 * 1.0 + 0.25 * 2.0, 0.75 * 1.0 + 0.25 * 0.4])


def test_bounds_source_outside_range():
    """s outside [0, g-1] is an error, or clamped when asked."""
    with pytest.raises(cf.ParameterError, match="outside"):
        _eval(JointBoundsSource(_table()), 2.5)
    lo, hi, nom = _eval(JointBoundsSource(_table(), clamp=True), 7.0)
    np.testing.assert_array_equal(nom, _table().nominal[-1])


def _admittance(k=2, **kw):
    adm = AdmittanceDeformation(k, **kw)
    ctx = adm.CreateDefaultContext()
    return adm, ctx


def _fix(adm, ctx, nominal, lower, upper, tau):
    adm.nominal_input.FixValue(ctx, nominal)
    adm.lower_input.FixValue(ctx, lower)
    adm.upper_input.FixValue(ctx, upper)
    adm.human_torque_input.FixValue(ctx, tau)


def test_zero_push_gives_nominal():
    """No push (the torque port left unconnected): commanded = nominal."""
    adm, ctx = _admittance()
    adm.nominal_input.FixValue(ctx, [0.3, -0.2])
    adm.lower_input.FixValue(ctx, [-1, -1])
    adm.upper_input.FixValue(ctx, [1, 1])
    Simulator(adm, ctx).AdvanceTo(1.0)
    np.testing.assert_array_equal(adm.commanded_position_output.Eval(ctx), [0.3, -0.2])


def test_steady_state_is_k_inverse_tau():
    """A constant torque inside the bounds settles at d = K^-1 tau."""
    K = np.array([100.0, 250.0])
    adm, ctx = _admittance(mass=[1.0, 2.0], damping=[20.0, 40.0], stiffness=K, period=0.005)
    tau = np.array([12.0, -30.0])
    _fix(adm, ctx, [0.1, 0.2], [-1, -1], [1, 1], tau)
    Simulator(adm, ctx).AdvanceTo(4.0)
    np.testing.assert_allclose(adm.deviation_output.Eval(ctx), tau / K, atol=1e-6)
    np.testing.assert_allclose(adm.commanded_position_output.Eval(ctx), [0.1, 0.2] + tau / K, atol=1e-6)


def test_large_push_sits_on_bound_and_releases_at_once():
    """A push far past the bound holds commanded exactly on it; on release the
    next update leaves the bound (no wind-up)."""
    adm, ctx = _admittance(mass=1.0, damping=20.0, stiffness=100.0, period=0.01)
    _fix(adm, ctx, [0.0, 0.0], [-0.5, -0.05], [0.5, 0.05], [10.0, 500.0])
    sim = Simulator(adm, ctx)
    sim.AdvanceTo(2.0)
    q = adm.commanded_position_output.Eval(ctx)
    assert q[1] == 0.05  # exactly on the bound
    assert q[0] == pytest.approx(0.1, abs=1e-6)
    adm.human_torque_input.FixValue(ctx, [10.0, 0.0])
    sim.AdvanceTo(2.0 + 0.01)
    assert adm.commanded_position_output.Eval(ctx)[1] < 0.05


@settings(max_examples=40, deadline=None)
@given(
    tau=st.lists(st.floats(-1e4, 1e4), min_size=3, max_size=3),
    mass=st.floats(0.1, 50.0),
    damping=st.floats(0.0, 500.0),
    stiffness=st.floats(0.0, 2000.0),
    width=st.lists(st.floats(0.0, 1.0), min_size=3, max_size=3),
)
def test_commanded_always_inside_bounds(tau, mass, damping, stiffness, width):
    """For random pushes and gains, commanded stays inside [lower, upper]."""
    adm, ctx = _admittance(k=3, mass=mass, damping=damping, stiffness=stiffness, period=0.01)
    nominal = np.array([0.1, -0.2, 0.0])
    lo, hi = nominal - np.array(width), nominal + np.array(width)[::-1]
    _fix(adm, ctx, nominal, lo, hi, tau)
    sim = Simulator(adm, ctx)
    for t in np.linspace(0.05, 1.0, 8):
        sim.AdvanceTo(t)
        q = adm.commanded_position_output.Eval(ctx)
        assert np.all(q >= lo) and np.all(q <= hi)


def test_nan_nominal_is_rejected():
    """A NaN on the planner's inputs (nominal, bounds) raises an error
    naming the port."""
    adm, ctx = _admittance()
    _fix(adm, ctx, [0.0, np.nan], [-1, -1], [1, 1], [0, 0])
    with pytest.raises(cf.ParameterError, match="nominal"):
        adm.commanded_position_output.Eval(ctx)


def _checked_admittance(**check_kw):
    """HumanInputCheck -> AdmittanceDeformation (fault -> hold), the push
    and the admittance's planner inputs exported."""
    from pydrake.systems.framework import DiagramBuilder

    from drake_cfvol.systems import HumanInputCheck

    builder = DiagramBuilder()
    check = builder.AddSystem(HumanInputCheck(2, period=0.01, **check_kw))
    adm = builder.AddSystem(AdmittanceDeformation(2, mass=1.0, damping=20.0, stiffness=100.0, period=0.01))
    builder.Connect(check.human_torque_output, adm.human_torque_input)
    builder.Connect(check.human_wrench_output, adm.human_wrench_input)
    builder.Connect(check.fault_output, adm.hold_input)
    for port in (
        check.human_torque_input,
        check.human_wrench_input,
        adm.nominal_input,
        adm.lower_input,
        adm.upper_input,
    ):
        builder.ExportInput(port, port.get_name())
    diagram = builder.Build()
    ctx = diagram.CreateDefaultContext()
    return diagram, check, adm, ctx


@pytest.mark.parametrize("bad", [np.nan, np.inf, 1e5])
def test_sensor_fault_holds_the_last_safe_command(bad):
    """A non-finite or implausible torque (NaN, inf, 1e5 N m > max_torque)
    raises no exception: the check's ``fault`` holds the admittance, whose
    deviation and rate stay as they were, so the command follows the
    nominal with the deviation of the last good update; ``fault_count``
    counts the faulted updates; a plausible torque again clears the fault."""
    diagram, check, adm, ctx = _checked_admittance()
    a_ctx, c_ctx = adm.GetMyContextFromRoot(ctx), check.GetMyContextFromRoot(ctx)

    def fix(nominal, tau):
        diagram.GetInputPort("nominal").FixValue(ctx, nominal)
        diagram.GetInputPort("lower").FixValue(ctx, [-1, -1])
        diagram.GetInputPort("upper").FixValue(ctx, [1, 1])
        diagram.GetInputPort("human_torque").FixValue(ctx, tau)

    fix([0.0, 0.0], [10.0, -5.0])
    sim = Simulator(diagram, ctx)
    sim.AdvanceTo(0.5 - 1e-9)  # updates at 0, .., 0.49
    held = adm.deviation_output.Eval(a_ctx).copy()
    state = a_ctx.get_discrete_state(0).CopyToVector().copy()
    assert np.abs(held).max() > 0.01 and check.fault_output.Eval(c_ctx)[0] == 0.0
    fix([0.2, 0.1], [bad, -5.0])
    sim.AdvanceTo(0.6 - 1e-9)  # ten faulted updates
    np.testing.assert_array_equal(a_ctx.get_discrete_state(0).CopyToVector(), state)
    np.testing.assert_allclose(adm.commanded_position_output.Eval(a_ctx), [0.2, 0.1] + held)
    assert check.fault_output.Eval(c_ctx)[0] == 1.0 and check.fault_count_output.Eval(c_ctx)[0] == 10.0
    fix([0.2, 0.1], [10.0, -5.0])
    sim.AdvanceTo(0.61 - 1e-9)
    assert check.fault_output.Eval(c_ctx)[0] == 0.0 and check.fault_count_output.Eval(c_ctx)[0] == 10.0
    assert not np.array_equal(adm.deviation_output.Eval(a_ctx), held)


def test_wrench_fault_and_plausibility_limits():
    """A NaN or implausible tool wrench (force beyond max_wrench) faults
    like a torque, a plausible one does not; the limits are checked at
    construction."""
    from drake_cfvol.systems import HumanInputCheck

    check = HumanInputCheck(2, max_wrench=[50, 50, 50, 200, 200, 200])
    ctx = check.CreateDefaultContext()
    check.human_torque_input.FixValue(ctx, [0.0, 0.0])
    for w, fault in (([0, 0, 0, np.nan, 0, 0], 1.0), ([0, 0, 0, 0, 0, 300.0], 1.0), ([0, 0, 0, 0, 0, 150.0], 0.0)):
        check.human_wrench_input.FixValue(ctx, w)
        assert check.fault_output.Eval(ctx)[0] == fault
    with pytest.raises(cf.ParameterError, match="max_torque"):
        HumanInputCheck(2, max_torque=0.0)
    with pytest.raises(cf.DimensionError, match="max_wrench"):
        HumanInputCheck(2, max_wrench=[1.0, 2.0])


def test_a_non_finite_push_is_never_integrated():
    """Wired without a check, the admittance still holds on a NaN push
    (its state stays finite and unchanged)."""
    adm, ctx = _admittance()
    _fix(adm, ctx, [0.0, 0.0], [-1, -1], [1, 1], [np.nan, 0.0])
    before = ctx.get_discrete_state(0).CopyToVector().copy()
    x = adm.EvalUniquePeriodicDiscreteUpdate(ctx)
    np.testing.assert_array_equal(x.get_vector(0).CopyToVector(), before)


def test_wrench_needs_a_plant():
    """A wrench without a plant to map it is refused clearly."""
    adm, ctx = _admittance()
    _fix(adm, ctx, [0.0, 0.0], [-1, -1], [1, 1], [0, 0])
    adm.human_wrench_input.FixValue(ctx, [0, 0, 0, 1.0, 0, 0])
    with pytest.raises(Exception, match="Jacobian"):
        Simulator(adm, ctx).AdvanceTo(0.05)


def test_wrench_maps_through_jacobian(automotive):
    """A force at the tool gives the deviation K^-1 J^T w (J at the
    commanded configuration; small push so J barely changes)."""
    from pydrake.multibody.tree import JacobianWrtVariable

    wc = automotive
    q0 = wc.configuration("path1")[0]
    K = 1e4
    adm = AdmittanceDeformation(
        6, mass=1.0, damping=300.0, stiffness=K, period=0.002, plant=wc.plant, tool_frame=wc.tool_frame
    )
    ctx = adm.CreateDefaultContext()
    _fix(adm, ctx, q0, q0 - 1, q0 + 1, np.zeros(6))
    w = np.array([0, 0, 0, 0, 0, -20.0])
    adm.human_wrench_input.FixValue(ctx, w)
    Simulator(adm, ctx).AdvanceTo(3.0)
    J = wc.plant.CalcJacobianSpatialVelocity(
        wc.plant_context(q0),
        JacobianWrtVariable.kQDot,
        wc.tool_frame,
        np.zeros(3),
        wc.plant.world_frame(),
        wc.plant.world_frame(),
    )
    # J is taken at the deviated configuration: entries move by O(deviation).
    np.testing.assert_allclose(adm.deviation_output.Eval(ctx), J.T @ w / K, rtol=0.02, atol=1e-4)


def test_path_index_ahead_leads_by_the_lead():
    """PathProgress's path_index_ahead is s(t + lead)."""
    p = PathProgress(11, rate=2.0, start_time=0.5, lead=0.25)
    ctx = p.CreateDefaultContext()
    for t in (0.0, 0.6, 3.0, 6.0):
        ctx.SetTime(t)
        assert p.path_index_ahead_output.Eval(ctx)[0] == pytest.approx(p.index_at(t + 0.25))


def test_path_progress_and_human():
    """Path index ramps at the rate and holds at g-1; pushes act in their window."""
    pp = PathProgress(11, rate=2.0, start_time=1.0)
    ctx = pp.CreateDefaultContext()
    for t, s in ((0.0, 0.0), (1.0, 0.0), (3.5, 5.0), (100.0, 10.0)):
        ctx.SetTime(t)
        assert pp.path_index_output.Eval(ctx)[0] == pytest.approx(s)
    human = ScriptedHuman(2, [Push(1.0, 0.5, [3.0, 0.0], []), Push(1.2, 1.0, [1.0, 1.0], [0, 0, 0, 5, 0, 0])])
    hctx = human.CreateDefaultContext()
    hctx.SetTime(1.3)
    np.testing.assert_array_equal(human.human_torque_output.Eval(hctx), [4.0, 1.0])
    np.testing.assert_array_equal(human.human_wrench_output.Eval(hctx), [0, 0, 0, 5, 0, 0])
    hctx.SetTime(0.5)
    np.testing.assert_array_equal(human.human_torque_output.Eval(hctx), [0.0, 0.0])


def test_bad_gains():
    """Non-positive mass or period, negative stiffness: clear errors."""
    with pytest.raises(cf.ParameterError, match="mass"):
        AdmittanceDeformation(2, mass=0.0)
    with pytest.raises(cf.ParameterError, match="period"):
        AdmittanceDeformation(2, period=0.0)
    with pytest.raises(cf.ParameterError, match="stiffness"):
        AdmittanceDeformation(2, stiffness=[-1.0, 1.0])


def test_reactive_coworker_forms_no_algebraic_loop():
    """A co-worker who pushes with 5 N m and yields 20 N m/rad to the
    commanded position (a gain from commanded_position back to
    human_torque) builds and simulates: commanded_position does not depend
    on the push directly. With no stiffness toward the nominal the joints
    settle where the push balances: q = 5 / 20 = 0.25 rad."""
    from pydrake.systems.analysis import Simulator
    from pydrake.systems.framework import DiagramBuilder
    from pydrake.systems.primitives import Adder, ConstantVectorSource, Gain

    k = 2
    builder = DiagramBuilder()
    adm = builder.AddSystem(AdmittanceDeformation(k, mass=1.0, damping=10.0, stiffness=0.0, period=0.01))
    nominal = builder.AddSystem(ConstantVectorSource(np.zeros(k)))
    lower = builder.AddSystem(ConstantVectorSource(np.full(k, -1.0)))
    upper = builder.AddSystem(ConstantVectorSource(np.full(k, 1.0)))
    push = builder.AddSystem(ConstantVectorSource(np.array([5.0, -5.0])))
    yielding = builder.AddSystem(Gain(-20.0, k))
    total = builder.AddSystem(Adder(2, k))
    builder.Connect(nominal.get_output_port(), adm.nominal_input)
    builder.Connect(lower.get_output_port(), adm.lower_input)
    builder.Connect(upper.get_output_port(), adm.upper_input)
    builder.Connect(adm.commanded_position_output, yielding.get_input_port())
    builder.Connect(yielding.get_output_port(), total.get_input_port(0))
    builder.Connect(push.get_output_port(), total.get_input_port(1))
    builder.Connect(total.get_output_port(), adm.human_torque_input)
    builder.ExportOutput(adm.commanded_position_output, "q")
    diagram = builder.Build()
    sim = Simulator(diagram)
    sim.AdvanceTo(6.0)
    q = diagram.GetOutputPort("q").Eval(sim.get_context())
    np.testing.assert_allclose(q, [0.25, -0.25], atol=5e-3)


def test_velocity_limits_hold_the_deviation_rate():
    """With velocity limits, a huge push moves the commanded position by at
    most (1 - path_share) x limit x period per update (fixed nominal and
    bounds), and the steady state is unchanged: d = K^-1 tau."""
    vmax = np.array([1.0, 2.0])
    K = np.array([100.0, 100.0])
    adm, ctx = _admittance(mass=0.1, damping=1.0, stiffness=K, period=0.01, velocity_limits=vmax, path_share=0.5)
    tau = np.array([80.0, -90.0])
    _fix(adm, ctx, [0.0, 0.0], [-2, -2], [2, 2], tau)
    sim = Simulator(adm, ctx)
    qs = []
    for n in range(1, 301):
        sim.AdvanceTo(0.01 * n)
        qs.append(adm.commanded_position_output.Eval(ctx).copy())
    steps = np.abs(np.diff(np.array(qs), axis=0))
    assert np.all(steps <= 0.5 * vmax * 0.01 + 1e-12)
    assert steps.max(axis=0) == pytest.approx(0.5 * vmax * 0.01)  # the limit is reached, not just respected
    np.testing.assert_allclose(qs[-1], tau / K, atol=1e-3)


def test_velocity_limits_checked():
    """Velocity limits of the wrong size, zero or NaN, or a share outside
    (0, 1), are refused with the argument's name."""
    with pytest.raises(cf.DimensionError, match="velocity_limits"):
        AdmittanceDeformation(2, velocity_limits=[1.0, 1.0, 1.0])
    with pytest.raises(cf.ParameterError, match="velocity_limits"):
        AdmittanceDeformation(2, velocity_limits=[1.0, 0.0])
    with pytest.raises(cf.ParameterError, match="path_share"):
        AdmittanceDeformation(2, velocity_limits=[1.0, 1.0], path_share=1.0)


def test_safe_path_rate_by_hand():
    """The bounds' rate r (per unit s) and a velocity limit v give at most
    share x v / r waypoints per second; the slowest joint sets it. Without
    a rate the largest change between neighbouring waypoints stands in."""
    from drake_cfvol.systems import safe_path_rate

    t = _table()
    rated = BoundsTable(
        t.lower, t.upper, t.nominal, t.joint_names, t.limit_lower, t.limit_upper, rate=np.array([0.5, 0.2])
    )
    assert safe_path_rate(rated, [1.0, 1.0], share=0.5) == pytest.approx(min(0.5 / 0.5, 0.5 / 0.2))
    # No rate: the largest neighbour change per joint is joint a's upper 2.0 -> 0.3 (1.7) and
    # joint b's upper 1.0 -> 0.4 (0.6); the rate is min(0.5 / 1.7, 0.5 / 0.6).
    assert safe_path_rate(t, [1.0, 1.0], share=0.5) == pytest.approx(0.5 / 1.7)
    assert safe_path_rate(t, [np.inf, np.inf]) == np.inf


@pytest.mark.parametrize(
    "named_obstacles, ignore_invariant", [(False, False), (True, False), (False, True), (True, True)]
)
def test_clearance_monitor_agrees_with_the_workcell(named_obstacles, ignore_invariant):
    """Through the query port of a diagram holding the workcell and one
    volume box: the moving links' clearance and the collision flag equal the
    workcell's own (second) Drake scene at random configurations, and the
    volume flag is 1 exactly when the box is placed around the tool; the
    same whether the monitor asks all pairs or is given the obstacles. Given
    the pairs no joint motion changes (matched by name from the workcell's
    scene: link 1 over the pedestal and the floor), the clearance equals
    the workcell's changeable distances."""
    from pydrake.geometry import Box
    from pydrake.math import RigidTransform
    from pydrake.multibody.plant import AddMultibodyPlantSceneGraph, CoulombFriction
    from pydrake.systems.framework import DiagramBuilder

    from drake_cfvol.scene.workcell import robot_geometry_ids
    from drake_cfvol.systems import ClearanceMonitor

    wc = cf.load_workcell("automotive")
    q_tool = np.asarray(wc.configuration("path1")[0])
    X_WT = wc.plant.CalcRelativeTransform(wc.plant_context(q_tool), wc.plant.world_frame(), wc.tool_frame)
    builder = DiagramBuilder()
    plant, sg = AddMultibodyPlantSceneGraph(builder, 0.0)
    robot = wc.add_to_plant(plant)
    box = plant.RegisterCollisionGeometry(
        plant.world_body(),
        RigidTransform(X_WT.translation()),
        Box(0.05, 0.05, 0.05),
        "volume_box",
        CoulombFriction(0.5, 0.5),
    )
    plant.Finalize()
    every, moving = robot_geometry_ids(plant, robot)
    obstacles = None
    if named_obstacles:
        inspector = sg.model_inspector()
        obstacles = [
            g
            for g in inspector.GetAllGeometryIds()
            if g not in every and g != box and inspector.GetProximityProperties(g) is not None
        ]
    ignored = []
    if ignore_invariant:
        from drake_cfvol.scene.workcell import geometry_key

        inspector = sg.model_inspector()
        names = wc.invariant_pair_names()
        ignored = [
            (a, b)
            for a in moving
            for b in inspector.GetAllGeometryIds()
            if (geometry_key(inspector, a), geometry_key(inspector, b)) in names
        ]
        assert ignored
    mon = builder.AddSystem(
        ClearanceMonitor(
            robot_ids=every, moving_ids=moving, volume_ids=[box], obstacle_ids=obstacles, ignored_pairs=ignored
        )
    )
    builder.Connect(sg.get_query_output_port(), mon.query_object_input)
    diagram = builder.Build()
    ctx = diagram.CreateDefaultContext()
    mctx = mon.GetMyContextFromRoot(ctx)
    pctx = plant.GetMyMutableContextFromRoot(ctx)
    plant.SetPositions(pctx, robot, q_tool)
    assert mon.in_volume_output.Eval(mctx)[0] == 1.0
    rng = np.random.default_rng(7)
    seen_collision = seen_free = 0
    for _ in range(25):
        q = rng.uniform(wc.position_lower, wc.position_upper)
        plant.SetPositions(pctx, robot, q)
        expected = min(
            wc.obstacle_distances(q, 2.0, moving_only=True, changeable_only=ignore_invariant).values(), default=2.0
        )
        assert mon.min_distance_output.Eval(mctx)[0] == pytest.approx(min(expected, 2.0), abs=1e-9)
        collides = mon.in_collision_output.Eval(mctx)[0] == 1.0
        assert collides == (not wc.is_free(q))
        seen_collision += collides
        seen_free += not collides
    assert seen_collision and seen_free


def test_clearance_monitor_skips_pairs_without_changing_the_minimum():
    """Along a slow random walk of the robot and of a free box beside it
    (an obstacle that moves and turns), the monitor's clearance equals the
    minimum over every named pair queried afresh, exactly, at every step,
    while its pair memo spares most of the queries; a jump (every pose far
    from the memo's) is exact too, and so is another context."""
    from pydrake.geometry import Box
    from pydrake.math import RigidTransform, RotationMatrix
    from pydrake.multibody.plant import AddMultibodyPlantSceneGraph, CoulombFriction
    from pydrake.multibody.tree import SpatialInertia
    from pydrake.systems.framework import DiagramBuilder

    from drake_cfvol.scene.workcell import robot_geometry_ids
    from drake_cfvol.systems import ClearanceMonitor

    wc = cf.load_workcell("automotive")
    builder = DiagramBuilder()
    plant, sg = AddMultibodyPlantSceneGraph(builder, 0.0)
    robot = wc.add_to_plant(plant)
    visitor = plant.AddRigidBody(
        "visitor", plant.AddModelInstance("visitor"), SpatialInertia.SolidBoxWithMass(1.0, 0.4, 0.2, 0.1)
    )
    plant.RegisterCollisionGeometry(
        visitor, RigidTransform([0.1, 0.0, 0.0]), Box(0.4, 0.2, 0.1), "visitor", CoulombFriction(0.5, 0.5)
    )
    plant.Finalize()
    every, moving = robot_geometry_ids(plant, robot)
    inspector = sg.model_inspector()
    obstacles = [
        g for g in inspector.GetAllGeometryIds() if g not in every and inspector.GetProximityProperties(g) is not None
    ]
    mon = builder.AddSystem(ClearanceMonitor(robot_ids=every, moving_ids=moving, volume_ids=[], obstacle_ids=obstacles))
    builder.Connect(sg.get_query_output_port(), mon.query_object_input)
    diagram = builder.Build()
    ctx = diagram.CreateDefaultContext()
    mctx = mon.GetMyContextFromRoot(ctx)
    pctx = plant.GetMyMutableContextFromRoot(ctx)
    pairs = [(a, b) for a in moving for b in obstacles]
    rng = np.random.default_rng(3)
    q = np.asarray(wc.configuration("path1")[0], float)
    p_box, yaw = np.array([1.2, 0.8, 1.0]), 0.0
    queried = []
    for step in range(120):
        q = np.clip(q + rng.normal(0.0, 0.01, q.shape), wc.position_lower, wc.position_upper)
        p_box, yaw = p_box + rng.normal(0.0, 0.01, 3), yaw + rng.normal(0.0, 0.02)
        if step == 80:
            q = rng.uniform(wc.position_lower, wc.position_upper)  # a jump
        plant.SetPositions(pctx, robot, q)
        plant.SetFreeBodyPose(pctx, visitor, RigidTransform(RotationMatrix.MakeZRotation(yaw), p_box))
        before = mon.pair_queries
        got = mon.min_distance_output.Eval(mctx)[0]
        queried.append(mon.pair_queries - before)
        query = sg.get_query_output_port().Eval(sg.GetMyContextFromRoot(ctx))
        brute = min([2.0] + [query.ComputeSignedDistancePairClosestPoints(a, b).distance for a, b in pairs])
        assert got == brute
    assert queried[0] == len(pairs)  # nothing remembered yet
    assert np.median(queried) < 0.5 * len(pairs)
    # The memo's facts hold in another context: a second context at the
    # nominal start gives the same minimum as every pair queried there.
    ctx2 = diagram.CreateDefaultContext()
    plant.SetPositions(plant.GetMyMutableContextFromRoot(ctx2), robot, wc.configuration("path1")[0])
    query = sg.get_query_output_port().Eval(sg.GetMyContextFromRoot(ctx2))
    brute = min([2.0] + [query.ComputeSignedDistancePairClosestPoints(a, b).distance for a, b in pairs])
    assert mon.min_distance_output.Eval(mon.GetMyContextFromRoot(ctx2))[0] == brute


def test_gains_are_numeric_parameters():
    """M, D, K live in the context: a context with a stiffer K settles at
    tau / K_new while the system's defaults stay as constructed."""
    adm, ctx = _admittance(mass=1.0, damping=20.0, stiffness=100.0, period=0.005)
    ctx.get_mutable_numeric_parameter(adm.stiffness_parameter).SetFromVector([400.0, 50.0])
    tau = np.array([8.0, -2.0])
    _fix(adm, ctx, [0.0, 0.0], [-1, -1], [1, 1], tau)
    Simulator(adm, ctx).AdvanceTo(4.0)
    np.testing.assert_allclose(adm.deviation_output.Eval(ctx), tau / [400.0, 50.0], atol=1e-6)
    np.testing.assert_array_equal(adm.gains(adm.CreateDefaultContext())[2], [100.0, 100.0])


def test_admittance_autodiff_derivative_by_hand():
    """ToAutoDiffXd: one update from d = 0.1, v = 0, no push gives
    v' = -h K d / M and d' = d + h v'; the derivative with respect to K is
    -h d / M for v' and -h^2 d / M for d' (seeded on joint 0's K)."""
    from pydrake.autodiffutils import AutoDiffXd

    adm = AdmittanceDeformation(2, mass=2.0, damping=0.0, stiffness=50.0, period=0.01)
    ad = adm.ToAutoDiffXd()
    ctx = ad.CreateDefaultContext()
    K = [AutoDiffXd(50.0, np.array([1.0])), AutoDiffXd(50.0, np.array([0.0]))]
    ctx.get_mutable_numeric_parameter(ad.stiffness_parameter).SetFromVector(K)
    ctx.SetDiscreteState(
        0,
        [
            AutoDiffXd(0.1, np.zeros(1)),
            AutoDiffXd(0.0, np.zeros(1)),
            AutoDiffXd(0.0, np.zeros(1)),
            AutoDiffXd(0.0, np.zeros(1)),
        ],
    )
    for port, value in ((ad.nominal_input, [0.0, 0.0]), (ad.lower_input, [-1.0, -1.0]), (ad.upper_input, [1.0, 1.0])):
        port.FixValue(ctx, [AutoDiffXd(x, np.zeros(1)) for x in value])
    x = ad.EvalUniquePeriodicDiscreteUpdate(ctx).get_vector(0).CopyToVector()
    h, d, M = 0.01, 0.1, 2.0
    assert x[2].value() == pytest.approx(-h * 50.0 * d / M)
    assert x[2].derivatives()[0] == pytest.approx(-h * d / M)
    assert x[0].derivatives()[0] == pytest.approx(-h * h * d / M)
    q = ad.commanded_position_output.Eval(ctx)
    assert q[0].value() == pytest.approx(0.1)


@pytest.mark.parametrize("limits", [None, [0.5, 2.0, 0.3]])
def test_admittance_float_update_equals_the_generic_one(limits):
    """The float update (compiled) and the AutoDiffXd one (the generic
    numpy arithmetic) give the same values bit for bit over 200 updates of
    random pushes that drive joints into their bounds and back, with and
    without velocity limits (the rate clip); the command the same too."""
    from pydrake.autodiffutils import AutoDiffXd

    rng = np.random.default_rng(3)
    adm = AdmittanceDeformation(3, mass=2.0, damping=20.0, stiffness=30.0, period=0.01, velocity_limits=limits)
    ad = adm.ToAutoDiffXd()
    fctx, actx = adm.CreateDefaultContext(), ad.CreateDefaultContext()
    lower, upper = np.array([-0.2, -0.05, -1.0]), np.array([0.3, 0.05, 1.0])
    for port, value in (("nominal", np.zeros(3)), ("lower", lower), ("upper", upper)):
        adm.GetInputPort(port).FixValue(fctx, value)
        ad.GetInputPort(port).FixValue(actx, [AutoDiffXd(x) for x in value])
    at_bound = 0
    for _ in range(200):
        tau = rng.uniform(-300.0, 300.0, 3)
        adm.human_torque_input.FixValue(fctx, tau)
        ad.human_torque_input.FixValue(actx, [AutoDiffXd(x) for x in tau])
        x_f = adm.EvalUniquePeriodicDiscreteUpdate(fctx).get_vector(0).CopyToVector()
        x_a = np.array([e.value() for e in ad.EvalUniquePeriodicDiscreteUpdate(actx).get_vector(0).CopyToVector()])
        np.testing.assert_array_equal(x_f, x_a)
        fctx.SetDiscreteState(0, x_f)
        actx.SetDiscreteState(0, [AutoDiffXd(x) for x in x_a])
        q_f = adm.commanded_position_output.Eval(fctx)
        np.testing.assert_array_equal(q_f, [e.value() for e in ad.commanded_position_output.Eval(actx)])
        at_bound += bool(np.any(q_f == lower) or np.any(q_f == upper))
    assert at_bound > 20  # the clamp and its rate reset were exercised


def test_bounds_source_autodiff_slope():
    """ToAutoDiffXd: at s = 0.25 (seeded ds = 1) the nominal's derivative
    is the first segment's slope, and values equal the float system's."""
    from pydrake.autodiffutils import AutoDiffXd

    t = _table()
    ad = JointBoundsSource(t).ToAutoDiffXd()
    ctx = ad.CreateDefaultContext()
    ad.path_index_input.FixValue(ctx, [AutoDiffXd(0.25, np.array([1.0]))])
    nom = ad.nominal_output.Eval(ctx)
    np.testing.assert_allclose([n.derivatives()[0] for n in nom], t.nominal[1] - t.nominal[0])
    lo_f, hi_f, nom_f = _eval(JointBoundsSource(t), 0.25)
    np.testing.assert_allclose([x.value() for x in ad.lower_output.Eval(ctx)], lo_f)
    np.testing.assert_allclose([x.value() for x in nom], nom_f)


def test_reactive_coworker_spring_by_hand():
    """Inside its window the co-worker's torque is gain x (nominal + offset -
    q), clipped at max_torque; outside it, zero."""
    from drake_cfvol.systems import ReactiveCoworker

    c = ReactiveCoworker(2, gain=[100.0, 10.0], offset=[0.5, 0.0], start=1.0, duration=2.0, max_torque=20.0)
    ctx = c.CreateDefaultContext()
    c.commanded_position_input.FixValue(ctx, [0.1, 0.3])
    c.nominal_input.FixValue(ctx, [0.0, 0.0])
    ctx.SetTime(1.5)
    np.testing.assert_allclose(c.human_torque_output.Eval(ctx), [20.0, -3.0])  # 40 clipped to 20; 10 x -0.3
    ctx.SetTime(3.0)
    np.testing.assert_array_equal(c.human_torque_output.Eval(ctx), [0.0, 0.0])


def _tiny_template(name):
    """A templated system of this module (float and AutoDiffXd)."""
    import sys

    from pydrake.autodiffutils import AutoDiffXd
    from pydrake.systems.framework import LeafSystem_
    from pydrake.systems.scalar_conversion import TemplateSystem

    @TemplateSystem.define(name, T_list=(float, AutoDiffXd), scope=sys.modules[__name__])
    def template(T):
        class Impl(LeafSystem_[T]):
            def _construct(self, converter=None):
                LeafSystem_[T].__init__(self, converter)

            def _construct_copy(self, other, converter=None):
                Impl._construct(self, converter=converter)

        return Impl

    return template


def test_default_instantiation_gives_pydrakes_own_scopes():
    """A templated system's float class made by default_instantiation (no
    stack inspection) has the scopes pydrake's own ``template[None]`` gives
    its scalar-conversion methods, and pydrake's lookup is back in place
    afterwards."""
    from pydrake.autodiffutils import AutoDiffXd
    from pydrake.common import cpp_template

    from drake_cfvol.systems._util import default_instantiation

    original = cpp_template._get_module_from_stack
    plain = _tiny_template("Plain_")[None]
    template = _tiny_template("Fast_")
    fast = default_instantiation(template)
    assert cpp_template._get_module_from_stack is original
    for method in ("ToScalarType", "ToScalarTypeMaybe"):
        assert getattr(fast, method)._scope is getattr(plain, method)._scope is not None
    assert isinstance(fast().ToAutoDiffXd(), template[AutoDiffXd])
