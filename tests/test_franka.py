"""The Franka Emika Panda model and its cell against Franka's published
robot specification: the modified Denavit-Hartenberg kinematics (written out
here as the chain product, independently of the URDF), the joint limits,
and collision shapes that cover the arm's skeleton."""

import numpy as np
import pytest
from pydrake.multibody.parsing import Parser
from pydrake.multibody.plant import AddMultibodyPlantSceneGraph
from pydrake.systems.framework import DiagramBuilder

import drake_cfvol as cf
from drake_cfvol.scene.schema import models_dir

# Franka's published modified-DH table (Craig's convention): per row a, d,
# alpha; joint i turns about z of frame i; the last row is the flange.
DH = [
    (0.0, 0.333, 0.0),
    (0.0, 0.0, -np.pi / 2),
    (0.0, 0.316, np.pi / 2),
    (0.0825, 0.0, np.pi / 2),
    (-0.0825, 0.384, -np.pi / 2),
    (0.0, 0.0, np.pi / 2),
    (0.088, 0.0, np.pi / 2),
    (0.0, 0.107, 0.0),
]
# Franka's published joint limits, joints 1-7.
Q_MAX = [2.8973, 1.7628, 2.8973, -0.0698, 2.8973, 3.7525, 2.8973]
Q_MIN = [-2.8973, -1.7628, -2.8973, -3.0718, -2.8973, -0.0175, -2.8973]
V_MAX = [2.1750, 2.1750, 2.1750, 2.1750, 2.6100, 2.6100, 2.6100]
A_MAX = [15, 7.5, 10, 12.5, 15, 20, 20]
TAU_MAX = [87, 87, 87, 87, 12, 12, 12]
JOINTS = [f"panda_joint{i}" for i in range(1, 8)]

# Configurations: zero, Franka's "ready" pose, both limit corners and two
# inside the range (rad).
CONFIGURATIONS = [
    np.zeros(7),
    np.array([0.0, -np.pi / 4, 0.0, -3 * np.pi / 4, 0.0, np.pi / 2, np.pi / 4]),
    np.array(Q_MIN),
    np.array(Q_MAX),
    np.array([0.3, -0.5, 0.7, -1.2, 0.4, 1.9, -0.8]),
    np.array([-1.1, 0.9, -2.0, -2.5, 2.2, 0.6, 2.0]),
]


def dh_transforms(q: np.ndarray) -> list[np.ndarray]:
    """The frames of joints 1-7 and the flange in the robot's base frame:
    T_i = RotX(alpha) TransX(a) RotZ(theta_i) TransZ(d), the flange at theta 0."""
    T, frames = np.eye(4), []
    for (a, d, alpha), theta in zip(DH, list(q) + [0.0]):
        ca, sa, ct, st = np.cos(alpha), np.sin(alpha), np.cos(theta), np.sin(theta)
        rot_x = np.array([[1, 0, 0, 0], [0, ca, -sa, 0], [0, sa, ca, 0], [0, 0, 0, 1]])
        trans_x = np.eye(4)
        trans_x[0, 3] = a
        rot_z = np.array([[ct, -st, 0, 0], [st, ct, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
        trans_z = np.eye(4)
        trans_z[2, 3] = d
        T = T @ rot_x @ trans_x @ rot_z @ trans_z
        frames.append(T)
    return frames


@pytest.fixture(scope="module")
def panda():
    """The bare robot (base welded at the world's origin) in a plant with a
    SceneGraph: (plant, scene_graph, diagram)."""
    builder = DiagramBuilder()
    plant, scene_graph = AddMultibodyPlantSceneGraph(builder, 0.0)
    Parser(plant).AddModels(str(models_dir() / "franka_panda" / "panda.urdf"))
    plant.WeldFrames(plant.world_frame(), plant.GetFrameByName("panda_link0"))
    plant.Finalize()
    return plant, scene_graph, builder.Build()


def test_dh_chain_by_hand_at_zero():
    """The test's own chain at q = 0, against the pose worked out by hand:
    joint 5 straight above the base at 0.333 + 0.316 + 0.384 m, the flange
    0.088 m forward and 0.107 m below it, pointing down."""
    flange = dh_transforms(np.zeros(7))[-1]
    np.testing.assert_allclose(dh_transforms(np.zeros(7))[4][:3, 3], [0, 0, 1.033], atol=1e-15)
    np.testing.assert_allclose(flange[:3, 3], [0.088, 0, 0.926], atol=1e-15)
    np.testing.assert_allclose(flange[:3, :3], np.diag([1, -1, -1]), atol=1e-15)


@pytest.mark.parametrize("q", CONFIGURATIONS, ids=lambda q: np.array2string(q, precision=2))
def test_forward_kinematics_match_franka_dh(panda, q):
    """Every joint frame and the flange's pose equal the DH chain product
    (1e-9 m, 1e-9 in each rotation entry)."""
    plant, _, _ = panda
    ctx = plant.CreateDefaultContext()
    plant.SetPositions(ctx, q)
    frames = [plant.GetJointByName(j).frame_on_child() for j in JOINTS] + [plant.GetFrameByName("flange")]
    for frame, T in zip(frames, dh_transforms(q)):
        X = frame.CalcPoseInWorld(ctx)
        np.testing.assert_allclose(X.translation(), T[:3, 3], atol=1e-9, err_msg=frame.name())
        np.testing.assert_allclose(X.rotation().matrix(), T[:3, :3], atol=1e-9, err_msg=frame.name())


def test_limits_equal_the_published_table(panda):
    """Position, velocity, acceleration and torque limits as Franka publishes
    them, joint by joint in Franka's order."""
    plant, _, _ = panda
    assert [plant.get_joint(i).name() for i in plant.GetJointIndices() if plant.get_joint(i).num_positions()] == JOINTS
    np.testing.assert_array_equal(plant.GetPositionLowerLimits(), Q_MIN)
    np.testing.assert_array_equal(plant.GetPositionUpperLimits(), Q_MAX)
    np.testing.assert_array_equal(plant.GetVelocityUpperLimits(), V_MAX)
    np.testing.assert_array_equal(plant.GetAccelerationUpperLimits(), A_MAX)
    np.testing.assert_array_equal(plant.GetAccelerationLowerLimits(), -np.array(A_MAX))
    assert plant.num_actuators() == 7
    np.testing.assert_array_equal(plant.GetEffortUpperLimits(), TAU_MAX)


def _skeleton(q: np.ndarray, tcp_out: float) -> np.ndarray:
    """Points every 5 mm on the segments between consecutive joint origins,
    the flange, and the tool point ``tcp_out`` m out along the flange's z."""
    frames = dh_transforms(q)
    corners = [np.zeros(3)] + [T[:3, 3] for T in frames] + [frames[-1][:3, 3] + tcp_out * frames[-1][:3, 2]]
    points = []
    for p0, p1 in zip(corners[:-1], corners[1:]):
        n = max(2, int(np.ceil(np.linalg.norm(p1 - p0) / 0.005)) + 1)
        points.append(p0 + np.linspace(0.0, 1.0, n)[:, None] * (p1 - p0))
    return np.concatenate(points)


@pytest.mark.parametrize("q", CONFIGURATIONS[:2] + CONFIGURATIONS[4:], ids=lambda q: np.array2string(q, precision=2))
def test_collision_shapes_cover_the_skeleton(panda, q):
    """Every point of the arm's skeleton (the base's mounting point to the
    flange through the joint origins of the DH chain, then the hand to
    Franka's TCP 0.1034 m out) lies at least 1 cm inside the collision
    shapes, by Drake's signed distance to each shape."""
    plant, scene_graph, diagram = panda
    ctx = diagram.CreateDefaultContext()
    plant.SetPositions(plant.GetMyContextFromRoot(ctx), q)
    query = scene_graph.get_query_output_port().Eval(scene_graph.GetMyContextFromRoot(ctx))
    for p in _skeleton(q, 0.1034):
        depth = -min(d.distance for d in query.ComputeSignedDistanceToPoint(p, 1.0))
        assert depth >= 0.01, f"{p} only {depth:.4f} m inside the shapes"


def test_franka_cell():
    """The built-in cell: the Panda's 7 joints actuated, the arm's published
    mass (about 18 kg, 17.8 spread over its links) and the hand's (0.73 kg),
    velocity limits from the model, free named pairs."""
    wc = cf.load_workcell("franka")
    assert wc.joint_names == JOINTS and wc.plant.num_actuated_dofs() == 7
    masses = {
        wc.plant.get_body(b).name(): wc.plant.get_body(b).default_mass() for b in wc.plant.GetBodyIndices(wc.robot)
    }
    assert sum(m for name, m in masses.items() if name.startswith("panda_link")) == pytest.approx(17.8, abs=1e-3)
    assert masses["gripper"] == pytest.approx(0.73, abs=1e-6)
    np.testing.assert_array_equal(wc.velocity_limits, V_MAX)
    for name in ("path1", "path2", "path3"):
        assert all(wc.is_free(q) for q in wc.configuration(name))


@pytest.mark.slow
@pytest.mark.parametrize("label", ["path1", "path2", "path3"])
def test_franka_paths_plan_and_bound(label):
    """Each named pair plans (the path checked free by Drake at every
    waypoint) and its bounds hold the nominal at every waypoint."""
    wc = cf.load_workcell("franka")
    start, goal = wc.configuration(label)
    path = cf.plan_nominal_path(wc, start, goal, seed=0, label=label)
    assert wc.collision_free(path.waypoints).all()
    np.testing.assert_array_equal(path.waypoints[0], start)
    np.testing.assert_array_equal(path.waypoints[-1], goal)
    table = cf.estimate_bounds(wc, path)
    assert np.all(table.lower <= path.waypoints) and np.all(path.waypoints <= table.upper)
