"""A user's own station: a workcell from a RobotDiagram (a 7-DoF arm with
STL meshes, a gripper and a free part in the plant), and the systems added
to the user's builder with AddCoManipulation, under Drake's
InverseDynamicsController."""

import re
import struct
from pathlib import Path

import numpy as np
import pytest
from pydrake.geometry import Box
from pydrake.math import RigidTransform
from pydrake.multibody.parsing import Parser
from pydrake.multibody.plant import AddMultibodyPlantSceneGraph, CoulombFriction, MultibodyPlant
from pydrake.multibody.tree import PrismaticJoint, SpatialInertia
from pydrake.planning import RobotDiagramBuilder
from pydrake.systems.analysis import Simulator
from pydrake.systems.controllers import InverseDynamicsController
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import LogVectorOutput

import drake_cfvol as cf
from drake_cfvol.scene.schema import models_dir
from drake_cfvol.systems import AddCoManipulation, Push, ScriptedHuman, ToolPushForce

SCENE = "tests/data/mesh_scene.sdf"
START = [0.0, 0.6, 0.0, -1.6, 0.0, 1.9, 0.7]
GOAL = [1.6, 0.2, 0.0, -2.2, 0.0, 1.6, 0.7]
PART_AT = [0.75, -0.3, 0.45]  # on the table's corner (its top at z = 0.4)


def _obj_to_stl(obj: Path, stl: Path) -> None:
    """A binary STL of an OBJ mesh (faces fanned into triangles)."""
    verts, tris = [], []
    for line in obj.read_text().splitlines():
        parts = line.split()
        if parts and parts[0] == "v":
            verts.append([float(x) for x in parts[1:4]])
        elif parts and parts[0] == "f":
            idx = [int(p.split("/")[0]) - 1 for p in parts[1:]]
            tris += [(idx[0], idx[i], idx[i + 1]) for i in range(1, len(idx) - 1)]
    V = np.array(verts)
    out = bytearray(b"\0" * 80) + struct.pack("<I", len(tris))
    for a, b, c in tris:
        n = np.cross(V[b] - V[a], V[c] - V[a])
        n = n / max(np.linalg.norm(n), 1e-12)
        out += struct.pack("<12fH", *n, *V[a], *V[b], *V[c], 0)
    stl.write_bytes(bytes(out))


@pytest.fixture(scope="module")
def stl_arm(tmp_path_factory):
    """The mesh test robot as a user might have it: its own folder, STL
    meshes referenced by relative paths."""
    folder = tmp_path_factory.mktemp("stl_arm")
    src = models_dir() / "mesh_arm"
    (folder / "meshes").mkdir()
    for obj in (src / "meshes").glob("*.obj"):
        _obj_to_stl(obj, folder / "meshes" / f"{obj.stem}.stl")
    text = (src / "mesh_arm.urdf").read_text()
    text = re.sub(r"package://drake_cfvol_models/mesh_arm/meshes/(\w+)\.obj", r"meshes/\1.stl", text)
    (folder / "arm.urdf").write_text(text)
    return folder / "arm.urdf"


STL_ARM = None  # set by the module's fixture below (the STL robot's URDF)


@pytest.fixture(scope="module", autouse=True)
def _use_stl_arm(stl_arm):
    global STL_ARM
    STL_ARM = stl_arm


def add_station_models(plant, parser, *, scene=True, part=True, finger=True, actuators=True):
    """The mesh test robot with STL meshes (actuated; through
    drake_cfvol.AddModels, which converts them), a gripper welded to its
    tool (palm, and a finger on a prismatic joint), the mesh scene and a
    free part."""
    parser.package_map().AddPackageXml(str(models_dir() / "package.xml"))
    arm = cf.AddModels(parser, file=STL_ARM)[0]
    plant.WeldFrames(plant.world_frame(), plant.GetFrameByName("base", arm))
    if actuators:
        for j in plant.GetJointIndices(arm):
            joint = plant.get_joint(j)
            if joint.num_velocities() == 1:
                plant.AddJointActuator(joint.name(), joint, 100.0)
    grip = plant.AddModelInstance("gripper")
    palm = plant.AddRigidBody("palm", grip, SpatialInertia.SolidBoxWithMass(0.3, 0.08, 0.08, 0.04))
    plant.WeldFrames(plant.GetFrameByName("tool", arm), palm.body_frame())
    shapes = [(palm, [0, 0, 0.02], Box(0.08, 0.08, 0.04))]
    if finger:
        tip = plant.AddRigidBody("finger", grip, SpatialInertia.SolidBoxWithMass(0.05, 0.02, 0.02, 0.05))
        joint = plant.AddJoint(
            PrismaticJoint("finger_slide", palm.body_frame(), tip.body_frame(), [1, 0, 0], -0.03, 0.03)
        )
        joint.set_default_translation(0.02)
        shapes.append((tip, [0, 0, 0.065], Box(0.02, 0.02, 0.05)))
    if plant.geometry_source_is_registered():
        for body, p, shape in shapes:
            plant.RegisterCollisionGeometry(body, RigidTransform(p), shape, body.name(), CoulombFriction(1, 1))
            plant.RegisterVisualGeometry(body, RigidTransform(p), shape, body.name(), [0.3, 0.3, 0.3, 1])
    if scene:
        parser.AddModels(SCENE)
    if part:
        inst = plant.AddModelInstance("part")
        body = plant.AddRigidBody("part", inst, SpatialInertia.SolidBoxWithMass(0.5, 0.1, 0.1, 0.1))
        if plant.geometry_source_is_registered():
            plant.RegisterCollisionGeometry(body, RigidTransform(), Box(0.1, 0.1, 0.1), "part", CoulombFriction(1, 1))
            plant.RegisterVisualGeometry(body, RigidTransform(), Box(0.1, 0.1, 0.1), "part", [0.8, 0.5, 0.2, 1])
        plant.SetDefaultFloatingBaseBodyPose(body, RigidTransform(PART_AT))
    return arm


def robot_diagram(**kwargs):
    builder = RobotDiagramBuilder(time_step=0.0)
    add_station_models(builder.plant(), builder.parser(), **kwargs)
    builder.plant().Finalize()
    return builder.Build()


@pytest.fixture(scope="module")
def mesh_cell():
    return cf.load_workcell("tests/data/mesh_cell.yaml")


@pytest.fixture(scope="module")
def station_cell():
    return cf.Workcell.FromRobotDiagram(
        robot_diagram(), robot="mesh_arm", tool_frame="tool", configurations={"path1": (START, GOAL)}, name="station"
    )


@pytest.fixture(scope="module")
def station_bounds(station_cell):
    path = cf.plan_nominal_path(station_cell, *station_cell.configuration("path1"), seed=0)
    return path, cf.estimate_bounds(station_cell, path, resolution=1000)


def test_robot_diagram_workcell_sorts_gripper_part_and_obstacles(station_cell):
    """The gripper belongs to the robot, the free part is an obstacle at its
    default pose, the finger and the part are named as held, and the user's
    diagram is left as it was."""
    wc = station_cell
    assert wc.joint_names == [f"j{i}" for i in range(1, 8)]
    assert set(wc.obstacles) == {"floor", "table", "post", "part"}
    assert "palm" in wc.scene_arrays().body_names and "finger" in wc.scene_arrays().body_names
    assert any("finger_slide" in n and "part (free body)" in n for n in wc.notes)
    X_WP = wc.plant.GetBodyByName("part").EvalPoseInWorld(wc.plant_context(np.zeros(7)))
    np.testing.assert_allclose(X_WP.translation(), PART_AT, atol=1e-12)
    user = robot_diagram()
    before = user.plant().GetPositions(user.plant().CreateDefaultContext())
    cf.Workcell.FromRobotDiagram(user, robot="mesh_arm", tool_frame="tool")
    np.testing.assert_array_equal(user.plant().GetPositions(user.plant().CreateDefaultContext()), before)


def test_robot_diagram_workcell_kernel_agrees_with_drake(station_cell):
    """The kernel's poses (the held finger included) equal Drake's, and it
    never calls free a configuration Drake finds colliding, the gripper's and
    the part's collisions included."""
    wc = station_cell
    arrays = wc.scene_arrays()
    Q = np.random.default_rng(3).uniform(wc.position_lower, wc.position_upper, (1500, 7))
    R, p = arrays.fk(Q[:20])
    for n, q in enumerate(Q[:20]):
        ctx = wc.plant_context(q)
        for b, index in enumerate(arrays.body_indices):
            X = wc.plant.get_body(index).EvalPoseInWorld(ctx)
            np.testing.assert_allclose(p[n, b], X.translation(), atol=1e-12)
            np.testing.assert_allclose(R[n, b], X.rotation().matrix(), atol=1e-12)
    drake_hit = ~np.array(wc.checker.CheckConfigsCollisionFree(Q), bool)
    kernel_hit = arrays.may_collide(Q)
    assert 0.05 * len(Q) < drake_hit.sum() < 0.95 * len(Q)
    assert not (drake_hit & ~kernel_hit).any()
    # Configurations whose only collision involves the gripper or the part: the kernel finds them too.
    extra = [
        n
        for n in np.flatnonzero(drake_hit)[:300]
        if all({"palm", "finger", "part"} & set(pair) for pair in wc.colliding_pairs(Q[n]))
    ]
    assert extra and kernel_hit[extra].all()


def test_robot_diagram_workcell_gives_the_yaml_workcells_bounds(mesh_cell):
    """The same models as the mesh test cell's file, given as a RobotDiagram
    with the same settings, give the same path and the same bounds."""
    builder = RobotDiagramBuilder(time_step=0.0)
    parser = builder.parser()
    parser.package_map().AddPackageXml(str(models_dir() / "package.xml"))
    arm = parser.AddModels(url="package://drake_cfvol_models/mesh_arm/mesh_arm.urdf")[0]
    builder.plant().WeldFrames(builder.plant().world_frame(), builder.plant().GetFrameByName("base", arm))
    parser.AddModels(SCENE)
    builder.plant().Finalize()
    wc = cf.Workcell.FromRobotDiagram(
        builder.Build(),
        robot="mesh_arm",
        tool_frame="tool",
        base_frame="base",
        reach=mesh_cell.reach,
        height_map_origin=mesh_cell.height_map_origin,
        height_map_size=mesh_cell.height_map_size,
    )
    np.testing.assert_array_equal(wc.position_lower, mesh_cell.position_lower)
    np.testing.assert_array_equal(wc.velocity_limits, mesh_cell.velocity_limits)
    assert set(wc.obstacles) == set(mesh_cell.obstacles)
    start, goal = mesh_cell.configuration("path1")
    a = cf.plan_nominal_path(wc, start, goal, seed=0)
    b = cf.plan_nominal_path(mesh_cell, start, goal, seed=0)
    np.testing.assert_array_equal(a.waypoints, b.waypoints)
    ta, tb = cf.estimate_bounds(wc, a, resolution=500), cf.estimate_bounds(mesh_cell, b, resolution=500)
    np.testing.assert_array_equal(ta.lower, tb.lower)
    np.testing.assert_array_equal(ta.upper, tb.upper)


def test_robot_diagram_workcell_defaults_cover_the_reach(station_cell):
    """The default reach bounds the distance of every robot body origin from
    joint 1's axis point on random configurations (Drake's poses), and the
    default height map holds the disc of that reach around the base."""
    wc = station_cell
    c = wc.plant.GetFrameByName("link1").CalcPoseInWorld(wc.plant_context(np.zeros(7))).translation()
    Q = np.random.default_rng(0).uniform(wc.position_lower, wc.position_upper, (50, 7))
    far = max(
        np.linalg.norm(wc.plant.get_body(b).EvalPoseInWorld(wc.plant_context(q)).translation() - c)
        for q in Q
        for b in wc.scene_arrays().body_indices
    )
    assert far <= wc.reach
    o, s = wc.height_map_origin, wc.height_map_size
    assert np.all(o <= c[:2] - wc.reach) and np.all(o + s >= c[:2] + wc.reach)


def test_robot_diagram_workcell_refuses_bad_input():
    """Each bad input names what is wrong."""
    with pytest.raises(cf.StationError, match="RobotDiagram"):
        cf.Workcell.FromRobotDiagram(object(), robot="mesh_arm", tool_frame="tool")
    builder = RobotDiagramBuilder(time_step=0.0)
    add_station_models(builder.plant(), builder.parser())
    with pytest.raises(cf.StationError, match="not finalized"):
        cf.Workcell.FromRobotDiagram(builder, robot="mesh_arm", tool_frame="tool")
    d = robot_diagram()
    with pytest.raises(cf.StationError, match="'arm' is not a model instance.*mesh_arm"):
        cf.Workcell.FromRobotDiagram(d, robot="arm", tool_frame="tool")
    with pytest.raises(cf.StationError, match="tool_frame 'flange' is not a frame"):
        cf.Workcell.FromRobotDiagram(d, robot="mesh_arm", tool_frame="flange")
    with pytest.raises(cf.StationError, match="quaternion_floating.*only revolute and prismatic"):
        cf.Workcell.FromRobotDiagram(d, robot="part", tool_frame="part")
    wc = cf.Workcell.FromRobotDiagram(d, robot="mesh_arm", tool_frame="tool")
    with pytest.raises(cf.StationError, match="AddCoManipulation"):
        wc.add_to_plant(MultibodyPlant(0.0))


def _sim_station(table, pushes, kp=1e4, kd=200.0):
    """The user's station: a 1 ms plant of the same models under Drake's
    InverseDynamicsController (gains kp 1/s^2, kd 1/s per joint), the pushes
    as real forces at the tool, read through human_wrench_input."""
    builder = DiagramBuilder()
    plant, sg = AddMultibodyPlantSceneGraph(builder, time_step=0.001)
    arm = add_station_models(plant, Parser(plant), finger=False)
    plant.Finalize()
    cm = AddCoManipulation(builder, plant=plant, scene_graph=sg, robot="mesh_arm", table=table, tool_frame="tool")
    human = builder.AddSystem(ScriptedHuman(7, pushes))
    builder.Connect(human.human_wrench_output, cm.human_wrench_input)
    control = MultibodyPlant(0.001)
    add_station_models(control, Parser(control), scene=False, part=False, finger=False)
    control.Finalize()
    idc = builder.AddSystem(
        InverseDynamicsController(control, kp=[kp] * 7, ki=[0.0] * 7, kd=[kd] * 7, has_reference_acceleration=False)
    )
    builder.Connect(plant.get_state_output_port(arm), idc.get_input_port_estimated_state())
    builder.Connect(cm.desired_state_output, idc.get_input_port_desired_state())
    builder.Connect(idc.get_output_port_control(), plant.get_actuation_input_port(arm))
    push = builder.AddSystem(ToolPushForce(plant.GetFrameByName("tool", arm)))
    builder.Connect(human.human_wrench_output, push.wrench_input)
    builder.Connect(push.spatial_forces_output, plant.get_applied_spatial_force_input_port())
    logs = {
        name: LogVectorOutput(port, builder, publish_period=0.01)
        for name, port in (
            ("measured", plant.get_state_output_port(arm)),
            ("commanded", cm.commanded_position_output),
            ("s", cm.path_index_output),
            ("lower", cm.bounds.lower_output),
            ("upper", cm.bounds.upper_output),
            ("nominal", cm.bounds.nominal_output),
        )
    }
    diagram = builder.Build()
    sim = Simulator(diagram)
    plant.SetPositions(plant.GetMyMutableContextFromRoot(sim.get_mutable_context()), arm, table.nominal[0])
    sim.AdvanceTo(cm.duration + 1.0)
    ctx = sim.get_context()
    return {name: log.FindLog(ctx).data().T for name, log in logs.items()}, cm


@pytest.mark.slow
def test_user_station_under_inverse_dynamics_control(station_cell, station_bounds):
    """Under Drake's InverseDynamicsController on a 1 ms plant, with steady
    pushes as real forces at the tool: the commands stay inside the box, the
    measured configuration never collides (Drake, the free part included),
    the push deforms the motion, the robot tracks with an error, and the path
    completes at the goal."""
    path, table = station_bounds
    pushes = [Push(0.3, 1.5, [], [0, 0, 0, 0, 0, -150.0]), Push(2.3, 1.2, [], [0, 0, 0, 0, 60.0, 0.0])]
    logs, cm = _sim_station(table, pushes)
    q_m, q_c = logs["measured"][:, :7], logs["commanded"]
    lo, hi, nom = logs["lower"], logs["upper"], logs["nominal"]
    # The command is the filter's state: it lies inside the box it was clamped to one update earlier.
    assert np.all(q_c[1:] >= np.minimum(lo[:-1], lo[1:]) - 1e-9) and np.all(
        q_c[1:] <= np.maximum(hi[:-1], hi[1:]) + 1e-9
    )
    assert np.array(station_cell.checker.CheckConfigsCollisionFree(q_m), bool).all()
    assert np.abs(q_c - nom).max() > 0.05  # the push deformed the motion
    tracking = np.abs(q_m[1:] - q_c[:-1]).max()
    assert 1e-4 < tracking < 0.1
    assert logs["s"][-1, 0] == table.g - 1
    np.testing.assert_allclose(q_m[-1], table.nominal[-1], atol=2e-3)


def _station_comanipulation(table, *, part: bool = True, **kwargs):
    """A builder with the station's 1 ms plant (finalized) and
    AddCoManipulation on it for the mesh arm at its tool: (builder, plant, cm)."""
    builder = DiagramBuilder()
    plant, sg = AddMultibodyPlantSceneGraph(builder, time_step=0.001)
    add_station_models(plant, Parser(plant), part=part)
    plant.Finalize()
    cm = AddCoManipulation(
        builder, plant=plant, scene_graph=sg, robot="mesh_arm", table=table, tool_frame="tool", **kwargs
    )
    return builder, plant, cm


def _robot_clearance(cell, q) -> float:
    """The robot's smallest distance to the obstacles and to itself (Drake's checker), m, or 0.1 beyond."""
    d = cell.checker.CalcRobotClearance(q, 0.1).distances()
    return float(d.min()) if len(d) else 0.1


@pytest.mark.slow
def test_loose_tracker_keeps_the_margin(station_cell, station_bounds):
    """A user's soft controller (kp 400 1/s^2, kd 40 1/s) lags its command
    by tenths of a radian under a steady 60 N push at the tool, which bends
    the wrist towards its own links: the measured robot never touches
    anything, itself included, and comes no nearer than min(margin, the
    nominal's own clearance at the same path position) - 2 mm, by Drake's
    checker at every 10 ms (four seeded push directions)."""
    path, table = station_bounds
    rng = np.random.default_rng(0)
    for _ in range(4):
        d = rng.normal(size=3)
        logs, cm = _sim_station(table, [Push(0.3, 100.0, [], [0, 0, 0, *(60.0 * d / np.linalg.norm(d))])], 400.0, 40.0)
        q_m, q_c, nom = logs["measured"][:, :7], logs["commanded"], logs["nominal"]
        assert np.abs(q_m[1:] - q_c[:-1]).max() > 0.15  # the controller is loose: the push bends it
        assert np.abs(q_c - nom).max() > 0.05  # and the command follows the push, not merely holds
        assert np.array(station_cell.checker.CheckConfigsCollisionFree(q_m), bool).all()
        measured = np.array([_robot_clearance(station_cell, q) for q in q_m])
        nominal = np.array([_robot_clearance(station_cell, q) for q in nom])
        shortfall = np.minimum(cm.safety.clearance, nominal) - measured
        assert shortfall.max() <= 0.002, (d, shortfall.max(), np.argmax(shortfall))


def test_add_comanipulation_ports_on_a_plant_with_more_dofs(station_bounds):
    """On a plant holding a gripper finger and a free part (k = 7 of 15
    positions) the returned ports have the documented sizes, the desired
    state starts at the path's start at rest, and the duration is the path's
    at its safe rate."""
    _, table = station_bounds
    builder, plant, cm = _station_comanipulation(table, period=0.01)
    assert plant.num_positions() == 15
    assert cm.human_wrench_input.size() == 6 and cm.human_torque_input.size() == 7
    assert cm.desired_state_output.size() == 14 and cm.commanded_position_output.size() == 7
    assert cm.path_index_output.size() == 1
    rate = cf.systems.safe_path_rate(table, plant.GetVelocityUpperLimits()[:7], share=0.5)
    assert cm.duration == pytest.approx((table.g - 1) / rate)
    diagram = builder.Build()
    ctx = diagram.CreateDefaultContext()
    x = cm.desired_state_output.Eval(cm.safety.GetMyContextFromRoot(ctx))
    np.testing.assert_array_equal(x, np.concatenate([table.nominal[0], np.zeros(7)]))


def test_add_comanipulation_tool_speed_limit_from_the_config(station_bounds):
    """SafetyFilterConfig(tool_speed=...) gives the filter a ToolSpeedLimit
    at the tool frame; the default gives it none."""
    from drake_cfvol.systems import CoManipulationConfig, SafetyFilterConfig, ToolSpeedLimit

    _, table = station_bounds
    for speed in (None, 0.25):
        _, _, cm = _station_comanipulation(
            table, part=False, config=CoManipulationConfig(safety_filter=SafetyFilterConfig(tool_speed=speed))
        )
        limits = [c for c in cm.safety.constraints if isinstance(c, ToolSpeedLimit)]
        if speed is None:
            assert limits == []
        else:
            (limit,) = limits
            assert limit.speed == speed and limit.frame.name() == "tool"


def test_add_comanipulation_refuses_a_table_of_other_joints(station_bounds, bounded):
    """A table for another robot, an unknown robot or frame: a StationError that names it."""
    _, table = station_bounds
    other = bounded("automotive")
    builder = DiagramBuilder()
    plant, sg = AddMultibodyPlantSceneGraph(builder, time_step=0.001)
    add_station_models(plant, Parser(plant))
    plant.Finalize()
    with pytest.raises(cf.StationError, match="bounds table is for joints"):
        AddCoManipulation(builder, plant=plant, scene_graph=sg, robot="mesh_arm", table=other, tool_frame="tool")
    with pytest.raises(cf.StationError, match="'abb' is not a model instance"):
        AddCoManipulation(builder, plant=plant, scene_graph=sg, robot="abb", table=table, tool_frame="tool")
    with pytest.raises(cf.StationError, match="tool_frame 'tcp'"):
        AddCoManipulation(builder, plant=plant, scene_graph=sg, robot="mesh_arm", table=table, tool_frame="tcp")


def test_add_comanipulation_config_reaches_the_systems(station_bounds):
    """The config's gains and limits are the systems' own: the admittance's
    M, D, K parameters, the filter's margin and damper (its clearance the
    table's when left null), the path's rate at the config's share capped
    by its max_rate, and its start time; the period is the rate of every
    update."""
    from drake_cfvol.systems import (
        AdmittanceConfig,
        CoManipulationConfig,
        PathProgressConfig,
        SafetyFilterConfig,
        safe_path_rate,
    )

    _, table = station_bounds
    builder = DiagramBuilder()
    plant, sg = AddMultibodyPlantSceneGraph(builder, time_step=0.001)
    add_station_models(plant, Parser(plant))
    plant.Finalize()
    limits = plant.GetVelocityUpperLimits()[:7]
    slow = safe_path_rate(table, limits, share=0.3) / 2
    config = CoManipulationConfig(
        admittance=AdmittanceConfig(mass=3.0, damping=50.0, stiffness=0.0),
        safety_filter=SafetyFilterConfig(influence_distance=0.2, damper_gain=0.5),
        path_progress=PathProgressConfig(velocity_share=0.3, start_time=1.5, max_rate=slow),
    )
    cm = AddCoManipulation(
        builder,
        plant=plant,
        scene_graph=sg,
        robot="mesh_arm",
        table=table,
        tool_frame="tool",
        period=0.02,
        config=config,
    )
    np.testing.assert_array_equal(
        [cm.admittance.M, cm.admittance.D, cm.admittance.K], [[3.0] * 7, [50.0] * 7, [0.0] * 7]
    )
    assert cm.admittance.period == cm.safety.period == 0.02 and cm.admittance.path_share == 0.3
    assert cm.safety.clearance == table.params["clearance"] and cm.safety.influence_distance == 0.2
    assert cm.safety.damper_gain == 0.5 and cm.safety.allowance == SafetyFilterConfig().allowance
    assert cm.progress.rate == slow and cm.progress.start_time == 1.5
    assert cm.duration == pytest.approx(1.5 + (table.g - 1) / slow)


@pytest.mark.parametrize("measured_state", [True, False])
def test_the_filters_tracking_fault_holds_the_admittance(station_bounds, measured_state):
    """The admittance's hold is raised by the filter's tracking fault as by
    the push's check, either alone (the admittance's hold itself:
    ``tests/test_systems.py``), also where the caller connects the measured
    position itself (``measured_state=False``, as the scenario runner and
    the iiwa controller do)."""
    from drake_cfvol.systems.filter.safety import _TRACKING

    _, table = station_bounds
    builder, _, cm = _station_comanipulation(table, measured_state=measured_state)
    builder.ExportInput(cm.human_torque_input, "torque")
    diagram = builder.Build()
    for tracking, check in ((0.0, 0.0), (1.0, 0.0), (0.0, 1.0)):
        ctx = diagram.CreateDefaultContext()
        diagram.GetInputPort("torque").FixValue(ctx, np.full(7, 1e4 if check else 20.0))  # 1e4 N m: implausible
        sctx = cm.safety.GetMyMutableContextFromRoot(ctx)
        status = sctx.get_discrete_state(cm.safety._status).CopyToVector()
        status[_TRACKING] = tracking
        sctx.get_mutable_discrete_state(cm.safety._status).SetFromVector(status)
        assert cm.check.fault_output.Eval(cm.check.GetMyContextFromRoot(ctx))[0] == check
        hold = cm.admittance.hold_input.Eval(cm.admittance.GetMyContextFromRoot(ctx))[0]
        assert (hold > 0.5) == bool(tracking or check)


def test_add_comanipulation_without_the_filter(station_bounds):
    """safety_filter null: no filter is added, the admittance's command is
    the output and there is no desired state; the filter's margin, when
    given, is the config's."""
    import dataclasses

    from drake_cfvol.systems import CoManipulationConfig, SafetyFilterConfig

    _, table = station_bounds
    for filter_config in (None, SafetyFilterConfig(clearance=0.05)):
        config = dataclasses.replace(CoManipulationConfig(), safety_filter=filter_config)
        builder, _, cm = _station_comanipulation(table, config=config, name="arm")
        names = {s.get_name() for s in builder.GetSystems()}
        if filter_config is None:
            assert cm.safety is None and cm.desired_state_output is None and "arm_safety_filter" not in names
            assert cm.commanded_position_output is cm.admittance.commanded_position_output
        else:
            assert cm.safety.clearance == 0.05 and "arm_safety_filter" in names
            assert cm.commanded_position_output is cm.safety.commanded_position_output
