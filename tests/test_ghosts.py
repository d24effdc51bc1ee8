"""Ghost robots in a SceneGraph: collision answers through the query port,
against Drake's own collision checker."""

import numpy as np
import pytest
from pydrake.geometry import Role, SceneGraph
from pydrake.multibody.plant import MultibodyPlant
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource
from pydrake.systems.rendering import MultibodyPositionToGeometryPose

import drake_cfvol as cf
from drake_cfvol.ghosts import GhostGuard
from drake_cfvol.systems import AdmittanceDeformation, ClearanceMonitor
from drake_cfvol.workcell import robot_geometry_ids


def _scene(wc, Q, q_robot):
    """A diagram: the workcell's models posed at q_robot, and one ghost per
    row of Q."""
    b = DiagramBuilder()
    sg = b.AddSystem(SceneGraph())
    plant = MultibodyPlant(0.0)
    plant.RegisterAsSourceForSceneGraph(sg)
    robot = wc.add_to_plant(plant)
    plant.Finalize()
    ids, moving = robot_geometry_ids(plant, robot)
    ghost = b.AddSystem(GhostGuard(sg, wc, len(Q), exclude_ids=ids))
    b.Connect(b.AddSystem(ConstantVectorSource(np.asarray(Q, float).ravel())).get_output_port(),
              ghost.configurations_input)
    b.Connect(ghost.geometry_pose_output, sg.get_source_pose_port(ghost.source_id))
    b.Connect(sg.get_query_output_port(), ghost.query_object_input)
    to_pose = b.AddSystem(MultibodyPositionToGeometryPose(plant))
    b.Connect(b.AddSystem(ConstantVectorSource(np.asarray(q_robot, float))).get_output_port(),
              to_pose.get_input_port())
    b.Connect(to_pose.get_output_port(), sg.get_source_pose_port(plant.get_source_id()))
    monitor = b.AddSystem(ClearanceMonitor(robot_ids=ids, moving_ids=moving, volume_ids=[]))
    b.Connect(sg.get_query_output_port(), monitor.query_object_input)
    diagram = b.Build()
    return diagram, ghost, monitor, sg


@pytest.mark.parametrize("name", ["automotive", "aerospace", "tests/data/mesh_cell.yaml"])
def test_ghosts_answer_like_drakes_checker(name):
    """Ghosts posed at random configurations (half of them colliding, with
    obstacles or the robot itself) are free exactly where Drake's collision
    checker says the configuration is free; the mesh robot included."""
    wc = cf.load_workcell(name)
    rng = np.random.default_rng(3)
    lo = np.where(np.isfinite(wc.position_lower), wc.position_lower, -np.pi)
    hi = np.where(np.isfinite(wc.position_upper), wc.position_upper, np.pi)
    Q = lo + rng.random((30, wc.num_joints)) * (hi - lo)
    diagram, ghost, _, _ = _scene(wc, Q, Q[0])
    ctx = diagram.CreateDefaultContext()
    free = ghost.free_output.Eval(ghost.GetMyContextFromRoot(ctx)).astype(bool)
    ref = np.array(wc.checker.CheckConfigsCollisionFree(Q), bool)
    assert 0 < ref.sum() < len(Q)  # both kinds present
    np.testing.assert_array_equal(free, ref)


def test_ghosts_are_invisible_to_the_rest(automotive):
    """A ghost posed inside the real robot and another inside an obstacle
    change nothing the ClearanceMonitor reports, and have no illustration
    role (a recording never draws them)."""
    wc = automotive
    q = wc.configuration("path1")[0]
    diagram, ghost, monitor, sg = _scene(wc, np.array([q, q]), q)
    ctx = diagram.CreateDefaultContext()
    mctx = monitor.GetMyContextFromRoot(ctx)
    assert monitor.in_collision_output.Eval(mctx)[0] == 0.0
    assert monitor.min_distance(mctx) == pytest.approx(min(wc.obstacle_distances(q, 2.0, moving_only=True).values()),
                                                      abs=1e-6)
    free = ghost.free_output.Eval(ghost.GetMyContextFromRoot(ctx))
    np.testing.assert_array_equal(free, [1.0, 1.0])  # overlapping each other and the robot: ignored
    inspector = sg.model_inspector()
    ids = [g for n in range(ghost.count) for g in ghost.ghost_ids[n]]
    assert ids and all(inspector.GetProperties(g, Role.kIllustration) is None for g in ids)
    assert all(inspector.GetProximityProperties(g) is not None for g in ids)


def test_invalid_ghost_count(automotive):
    """A ghost count below one is refused with a clear error."""
    with pytest.raises(cf.ParameterError, match="count must be >= 1"):
        GhostGuard(SceneGraph(), automotive, 0)


def test_query_guard_excludes_a_callable_guard():
    """The admittance takes one kind of guard, and says so."""
    with pytest.raises(cf.ParameterError, match="either collision_guard"):
        AdmittanceDeformation(2, collision_guard=lambda q: True, query_guard=True)


def test_comanipulation_guard_goes_through_the_query_port():
    """The co-manipulation diagram's guard is the query guard: its ghosts'
    answers come from the diagram's own SceneGraph and no callable is held
    (that it acts and keeps runs free: tests/test_comanip.py)."""
    from drake_cfvol.comanip import build_comanipulation_diagram, load_scenario

    scenario, file = load_scenario("automotive_random", scenario_text="{certify: false}")
    cm = build_comanipulation_diagram(scenario, base_dir=file.parent)
    adm = cm.diagram.GetSubsystemByName("admittance")
    ghosts = cm.diagram.GetSubsystemByName("ghost_guard")
    assert adm.query_guard and adm._guard is None
    assert ghosts.count == 2 * AdmittanceDeformation.num_candidates
    # Its query input is the SceneGraph's query output.
    conn = cm.diagram.connection_map()
    assert conn[(ghosts, ghosts.query_object_input.get_index())] == (
        cm.scene_graph, cm.scene_graph.get_query_output_port().get_index())
