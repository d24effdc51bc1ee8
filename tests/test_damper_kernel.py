"""The damper's compiled point distance (systems/filter/damper_kernel.py) against
Drake's ComputeSignedDistanceToPoint, and the damper's rows against a
Python assembly from Drake's own queries."""

import numpy as np
import pytest
from pydrake.geometry import Box, Capsule, Cylinder, SceneGraph, Sphere
from pydrake.math import RigidTransform, RollPitchYaw
from pydrake.multibody.plant import CoulombFriction, MultibodyPlant

from drake_cfvol.systems.filter.damper_kernel import point_distance, point_query_shape


@pytest.mark.parametrize(
    "shape",
    [Box(0.3, 0.2, 0.5), Sphere(0.15), Capsule(0.1, 0.4), Cylinder(0.12, 0.3)],
    ids=["box", "sphere", "capsule", "cylinder"],
)
def test_point_distance_is_drakes(shape):
    """For 2,000 points around and inside a posed shape (half of them near its centre): the signed
    distance, the gradient and the nearest point are Drake's (1e-9), the
    points mapped into the shape's frame as the damper does."""
    sg = SceneGraph()
    plant = MultibodyPlant(0.0)
    plant.RegisterAsSourceForSceneGraph(sg)
    X = RigidTransform(RollPitchYaw(0.3, -0.2, 0.7), [0.1, -0.2, 0.3])
    plant.RegisterCollisionGeometry(plant.world_body(), X, shape, "s", CoulombFriction(1, 1))
    plant.Finalize()
    ctx = sg.CreateDefaultContext()
    query = sg.get_query_output_port().Eval(ctx)
    kind, prm = point_query_shape(shape)
    R, t = X.rotation().matrix(), X.translation()
    rng = np.random.default_rng(0)
    g, near = np.zeros(3), np.zeros(3)
    checked = inside = 0
    for p in np.vstack([rng.uniform(-0.6, 0.6, (1000, 3)), rng.uniform(-0.15, 0.15, (1000, 3))]) @ R.T + t:
        (found,) = query.ComputeSignedDistanceToPoint(p, np.inf)
        d = point_distance(kind, prm, R.T @ (p - t), g, near)
        assert d == pytest.approx(found.distance, abs=1e-9)
        np.testing.assert_allclose(R @ g, found.grad_W, atol=1e-9)
        np.testing.assert_allclose(near, found.p_GN, atol=1e-9)
        checked += 1
        inside += d < 0
    assert checked == 2000 and inside > 20


def _cell_damper(cell: str):
    """A built-in cell's plant and SceneGraph in a diagram, and a damper on
    them: (workcell, plant, scene graph, robot, damper, plant context,
    scene graph context)."""
    from pydrake.multibody.plant import AddMultibodyPlantSceneGraph
    from pydrake.systems.framework import DiagramBuilder

    from drake_cfvol.scene.workcell import load_workcell
    from drake_cfvol.systems.filter.damper import VelocityDamper

    wc = load_workcell(cell)
    builder = DiagramBuilder()
    plant, sg = AddMultibodyPlantSceneGraph(builder, time_step=0.0)
    robot = wc.add_to_plant(plant)
    plant.Finalize()
    diagram = builder.Build()
    ctx = diagram.CreateDefaultContext()
    pctx, sgctx = plant.GetMyMutableContextFromRoot(ctx), sg.GetMyContextFromRoot(ctx)
    damper = VelocityDamper(
        plant, sg, robot, obstacle_ids=None, target_distance=0.021, influence_distance=0.15, rate=10.0
    )
    return wc, plant, sg, robot, damper, pctx, sgctx


def test_compiled_rows_are_the_drake_assembled_rows():
    """The cobot cell at 150 random configurations within its joint
    limits: the compiled rows (pair_rows, own point distances) equal the
    rows assembled pair by pair from Drake's point queries (1e-9), row by
    row; every measured pair's distance is Drake's and every pair the broad
    phase skipped lies at least its lower bound away (Drake)."""
    from drake_cfvol.systems.filter.damper_parts import side_arrays

    wc, plant, sg, robot, damper, pctx, sgctx = _cell_damper("cobot")
    lo, hi = wc.position_lower, wc.position_upper
    rng = np.random.default_rng(0)
    rows_seen = point_rows = 0
    for _ in range(150):
        q = lo + rng.random(len(lo)) * (hi - lo)
        plant.SetPositions(pctx, robot, q)
        query = sg.get_query_output_port().Eval(sgctx)
        fast = damper.rows(query, q)
        damper._drake_rows[:] = True
        try:
            slow = damper.rows(query, q)
        finally:
            damper._sides, damper._drake_rows = side_arrays(damper, sg.model_inspector())
        for field in ("A", "b", "dirs", "points", "rounds"):
            np.testing.assert_allclose(getattr(fast, field), getattr(slow, field), atol=1e-9)
        np.testing.assert_array_equal(fast.slots, slow.slots)
        np.testing.assert_array_equal(fast.pair, slow.pair)
        for n, (a, b, _, _) in enumerate(damper._pairs):
            d = query.ComputeSignedDistancePairClosestPoints(a, b).distance
            if fast.measured[n]:
                assert fast.distances[n] == pytest.approx(d, abs=1e-12)
            else:
                assert fast.distances[n] >= damper.influence_distance and d >= fast.distances[n] - 1e-9
        rows_seen += len(fast.b)
        point_rows += int(np.sum((fast.slots >= 0).all(axis=1)))
    assert rows_seen > 500 and point_rows > 50


def _gripper_station():
    """The mesh test robot with a gripper welded to its tool (a palm and a
    finger on a prismatic joint held at 2 cm) and a free part: degrees of
    freedom beyond the robot's, and a robot body in another model
    instance."""
    from pydrake.multibody.parsing import Parser
    from pydrake.multibody.tree import PrismaticJoint, SpatialInertia

    from drake_cfvol.scene.schema import models_dir

    plant = MultibodyPlant(0.0)
    parser = Parser(plant)
    parser.package_map().AddPackageXml(str(models_dir() / "package.xml"))
    arm = parser.AddModels(url="package://drake_cfvol_models/mesh_arm/mesh_arm.urdf")[0]
    plant.WeldFrames(plant.world_frame(), plant.GetFrameByName("base", arm))
    grip = plant.AddModelInstance("gripper")
    palm = plant.AddRigidBody("palm", grip, SpatialInertia.SolidBoxWithMass(0.3, 0.08, 0.08, 0.04))
    plant.WeldFrames(plant.GetFrameByName("tool", arm), palm.body_frame(), RigidTransform([0.01, 0.0, 0.03]))
    tip = plant.AddRigidBody("finger", grip, SpatialInertia.SolidBoxWithMass(0.05, 0.02, 0.02, 0.05))
    plant.AddJoint(
        PrismaticJoint("finger_slide", palm.body_frame(), tip.body_frame(), [1, 0, 0], -0.03, 0.03)
    ).set_default_translation(0.02)
    part = plant.AddRigidBody(
        "part", plant.AddModelInstance("part"), SpatialInertia.SolidBoxWithMass(0.5, 0.1, 0.1, 0.1)
    )
    plant.SetDefaultFloatingBaseBodyPose(part, RigidTransform([0.6, 0.0, 0.45]))
    plant.Finalize()
    return plant, arm, [palm, tip]


@pytest.mark.parametrize("cell", ["automotive", "aerospace", "gripper"])
def test_slot_kinematics_are_drakes(cell, request):
    """The damper's compiled forward kinematics (SlotKinematics) against
    Drake's at 200 random configurations: every robot body's pose
    (EvalBodyPoseInWorld) and its Jacobian at its origin in the robot's
    velocities (CalcJacobianSpatialVelocity), to 1e-12 / 1e-11; the held
    finger of the gripper station where the plant's default puts it.
    Cells: a 6-DoF arm, the 7-DoF arm on a linear axis (prismatic), the
    mesh robot with a gripper (a prismatic finger held) and a free part."""
    from pydrake.multibody.tree import JacobianWrtVariable

    from drake_cfvol.scene.robot import RobotSlice, robot_bodies
    from drake_cfvol.systems.filter.damper_kinematics import SlotKinematics

    if cell == "gripper":
        plant, robot, extra = _gripper_station()
    else:
        wc = request.getfixturevalue(cell)
        plant, robot, extra = wc.plant, wc.robot, []
    robot_slice = RobotSlice(plant, robot)
    bodies = [plant.get_body(b) for b in robot_bodies(plant, robot)]
    assert all(b in bodies for b in extra)
    kin = SlotKinematics(plant, robot, robot_slice, bodies)
    ctx = plant.CreateDefaultContext()
    lo = np.maximum(plant.GetPositionLowerLimits()[robot_slice.qidx], -np.pi)
    hi = np.minimum(plant.GetPositionUpperLimits()[robot_slice.qidx], np.pi)
    rng = np.random.default_rng(3)
    world = plant.world_frame()
    for _ in range(200):
        q = lo + rng.random(len(lo)) * (hi - lo)
        robot_slice.set_positions(ctx, q)
        R, o, J_w, J_v = kin.poses_and_jacobians(q)
        for s, body in enumerate(bodies):
            X = plant.EvalBodyPoseInWorld(ctx, body)
            np.testing.assert_allclose(R[s], X.rotation().matrix(), atol=1e-12)
            np.testing.assert_allclose(o[s], X.translation(), atol=1e-12)
            J = robot_slice.columns(
                plant.CalcJacobianSpatialVelocity(
                    ctx, JacobianWrtVariable.kV, body.body_frame(), np.zeros(3), world, world
                )
            )
            np.testing.assert_allclose(J_w[s], J[:3], atol=1e-11)
            np.testing.assert_allclose(J_v[s], J[3:], atol=1e-11)


@pytest.mark.parametrize("cell", ["cobot", "aerospace"])
def test_pair_speeds_bound_drakes_distance_rates(cell):
    """Every watched pair's distance, by Drake, changes no faster than
    VelocityDamper.pair_speeds says: at 40 random configurations and joint
    velocities v of up to the limits, the rate (d(q + v eps) - d(q - v
    eps)) / (2 eps) of each pair within 1 m (robot to obstacles and to
    itself) is at most the bound at v (e = 0), and at v + e for a random e
    within dv it is at most the bound at v with dv (1 mm/s). Cells: the
    iiwa (self pairs between links) and the arm on a linear axis
    (prismatic)."""
    wc, plant, sg, robot, damper, pctx, sgctx = _cell_damper(cell)

    def distances(q):
        plant.SetPositions(pctx, robot, q)
        query = sg.get_query_output_port().Eval(sgctx)
        return np.array([query.ComputeSignedDistancePairClosestPoints(a, b).distance for a, b, _, _ in damper._pairs])

    lo, hi = wc.position_lower, wc.position_upper
    vmax = np.minimum(wc.velocity_limits, 3.0)
    rng = np.random.default_rng(3)
    checked, self_checked = 0, 0
    both = (damper._pair_bodies >= 0).all(axis=1)
    for _ in range(40):
        q = lo + rng.random(len(lo)) * (hi - lo)
        v = rng.uniform(-vmax, vmax)
        dv = rng.uniform(0, 0.3 * vmax)
        e = rng.uniform(-dv, dv)
        J = damper.kinematics.poses_and_jacobians(q)[2:]
        d0 = distances(q)
        near = np.flatnonzero(d0 < 1.0)
        for u, bound in ((v, damper.pair_speeds(*J, v, 0 * dv)), (v + e, damper.pair_speeds(*J, v, dv))):
            # The median over three steps: Drake's distance between meshes
            # (GJK on their hulls) jumps by micrometres now and then.
            rate = np.median(
                [
                    (distances(q + u * eps)[near] - distances(q - u * eps)[near]) / (2 * eps)
                    for eps in (1e-3, 1e-4, 1e-5)
                ],
                axis=0,
            )
            bad = near[-rate > bound[near] + 1e-3]
            assert not len(bad), (
                cell,
                bad,
                damper._pair_bodies[bad],
                (-rate - bound[near])[-rate > bound[near] + 1e-3],
                d0[bad],
            )
        checked += len(near)
        self_checked += int(both[near].sum())
    assert checked > 200 and (self_checked > 20 or cell == "aerospace")


def _compiled_distances(plant, robot, pctx, sg, sgctx, damper, q, usable, hint):
    """The plant posed at q: (Drake's query object, and gjk_pairs of the
    ``usable`` pairs: the pairs measured, distances, normals, witnesses);
    every usable pair either measured or left to Drake."""
    from drake_cfvol.systems.filter.distance_kernel import gjk_pairs

    plant.SetPositions(pctx, robot, q)
    query = sg.get_query_output_port().Eval(sgctx)
    R, o, _, _ = damper.kinematics.poses_and_jacobians(q)
    look = np.flatnonzero(usable)
    done, dist, normal, witness, left = gjk_pairs(
        look, usable, damper._sides[:3], damper._convex, damper._broad.box_R, damper._broad.box_p, R, o, hint
    )
    assert len(done) + len(left) == len(look)
    return query, done, dist, normal, witness


@pytest.mark.parametrize("cell", ["cobot", "franka"])
def test_round_pairs_are_drakes(cell):
    """The pairs of two spheres or capsules, which gjk_pairs measures in
    closed form (the distance of their segments less their radii; the
    SafetyFilter's default), against Drake's query at 80 random
    configurations of the cell's robot: every such pair's distance lies at
    most 1e-9 above Drake's (whose GJK converges from above: it reports up
    to 0.2 mm more on the iiwa's capsules); no two points of the segments
    (brute force, 301 x 301, the first 200 pairs) lie nearer, and the grid's
    least lies within 1 mm; its witnesses lie on the two surfaces, |p_A -
    p_B| = |d|
    along its normal (so they are a closest pair), which points as Drake's
    where the pair is apart (d > 1 mm). VelocityDamper.rows gives these
    distances for the pairs it measures."""
    from drake_cfvol.systems.filter.damper_kernel import CAPSULE, SPHERE, point_distance

    wc, plant, sg, robot, damper, pctx, sgctx = _cell_damper(cell)
    lo, hi = wc.position_lower, wc.position_upper
    rng = np.random.default_rng(7)
    kind = damper._convex[0]
    round_ = damper.convex_shapes & ((kind == SPHERE) | (kind == CAPSULE)).all(axis=1)
    assert round_.sum() >= 10
    sides = damper._sides
    checked = unique = 0
    for _ in range(80):
        q = lo + rng.random(len(lo)) * (hi - lo)
        hint = np.zeros((damper.num_pairs, 3))
        query, done, dist, normal, witness = _compiled_distances(plant, robot, pctx, sg, sgctx, damper, q, round_, hint)
        for i, p in enumerate(done):
            a, b, _, _ = damper._pairs[p]
            found = query.ComputeSignedDistancePairClosestPoints(a, b)
            assert dist[i] <= found.distance + 1e-9
            if checked < 200:  # brute force: no two points of the segments lie nearer
                ends = []
                for s, g in enumerate((a, b)):
                    X = query.GetPoseInWorld(g)
                    h = sides[7][p, s, 1] if sides[6][p, s] == CAPSULE else 0.0
                    ends.append((X.multiply([0, 0, -h]), X.multiply([0, 0, h])))
                u = np.linspace(0, 1, 301)[:, None]
                seg = [e0 + u * (e1 - e0) for e0, e1 in ends]
                gap = (
                    np.linalg.norm(seg[0][:, None] - seg[1][None], axis=2).min() - sides[7][p, 0, 0] - sides[7][p, 1, 0]
                )
                assert dist[i] <= gap + 1e-12 and gap - dist[i] < 1e-3
            X = [query.GetPoseInWorld(g) for g in (a, b)]
            pa, pb = (X[s].multiply(witness[i, s]) for s in range(2))
            assert np.linalg.norm(pa - pb) == pytest.approx(abs(dist[i]), abs=1e-9)
            assert normal[i] @ (pa - pb) == pytest.approx(dist[i], abs=1e-9)
            for s in range(2):
                on = point_distance(sides[6][p, s], sides[7][p, s], witness[i, s], np.zeros(3), np.zeros(3))
                assert on == pytest.approx(0.0, abs=1e-9)
            checked += 1
            if found.distance > 1e-3:  # both normals point from B to A along a closest pair
                assert normal[i] @ found.nhat_BA_W > 0.99
                unique += 1
        rows = damper.rows(query, q, convex=(round_, hint))
        seen = rows.measured[done]  # the others the broad phase bounded, beyond the influence distance
        np.testing.assert_allclose(rows.distances[done][seen], dist[seen])
        assert np.all(rows.distances[done][~seen] <= dist[~seen] + 1e-9)
    assert checked > 400 and unique > 0.5 * checked


@pytest.mark.parametrize("cell", ["automotive", "franka", "cobot"])
def test_gjk_pairs_bound_drakes_distance(cell):
    """gjk_pairs (the filter's distance for two convex shapes) against
    Drake's query at 40 random configurations of the cell's robot: every
    distance lies at most 1e-9 above Drake's and within 3 mm below it (Drake's
    own GJK reports up to 2.7 mm more than the shapes' distance on the
    Panda's capsule and box: its witness lies 2 mm inside the capsule); a
    capsule's against a box is the brute-force distance of the capsule's
    segment (2001 points, exact point-box distances) to the grid's resolution,
    never above it; its normal
    and witnesses make the distance (n . (p_A - p_B) = d); and the plane
    through each witness along the normal holds its shape (Drake's closest
    points of the two shapes, and 200 points of each shape's surface
    along random directions, the support points: none lies past its
    plane), so d bounds the distance from below by construction."""
    from drake_cfvol.kernel.types import BOX, CAPSULE

    wc, plant, sg, robot, damper, pctx, sgctx = _cell_damper(cell)
    lo, hi = wc.position_lower, wc.position_upper
    rng = np.random.default_rng(5)
    usable = damper.convex_shapes
    brute = 0
    assert usable.sum() > 0.9 * damper.num_pairs
    hint = np.zeros((damper.num_pairs, 3))
    checked = 0
    for trial in range(40):
        q = lo + rng.random(len(lo)) * (hi - lo)
        query, done, dist, normal, witness = _compiled_distances(plant, robot, pctx, sg, sgctx, damper, q, usable, hint)
        for i, p in enumerate(done):
            a, b, _, _ = damper._pairs[p]
            found = query.ComputeSignedDistancePairClosestPoints(a, b)
            assert found.distance - 3e-3 <= dist[i] <= found.distance + 1e-9
            X = [query.GetPoseInWorld(g) for g in (a, b)]
            kind, sizes = damper._convex[0][p], damper._convex[1][p]
            if kind[0] == CAPSULE and kind[1] == BOX and brute < 40:  # tight: the segment's points against the box
                brute += 1
                seg = [X[0].multiply([0, 0, t]) for t in np.linspace(-sizes[0, 1], sizes[0, 1], 2001)]
                local = X[1].inverse().multiply(np.array(seg).T).T
                box = min(point_distance(BOX, sizes[1], x, np.zeros(3), np.zeros(3)) for x in local)
                # Tight to the grid's resolution (0.1 mm steps: about 1e-7 m off the least).
                assert dist[i] <= box - sizes[0, 0] + 1e-9 and box - sizes[0, 0] - dist[i] < 1e-6
            pa, pb = (X[s].multiply(witness[i, s]) for s in range(2))
            n = normal[i]
            assert n @ (pa - pb) == pytest.approx(dist[i], abs=1e-9)
            # Drake's closest points lie on the shapes: beyond the planes.
            assert n @ X[0].multiply(found.p_ACa) >= n @ pa - 1e-9
            assert n @ X[1].multiply(found.p_BCb) <= n @ pb + 1e-9
            checked += 1
        if trial < 5:  # each shape's support points along random directions: none past its plane
            for i, p in enumerate(done[:30]):
                kind, sizes, centre, verts, count = (x[p] for x in damper._convex)
                a, b, _, _ = damper._pairs[p]
                for s, g in enumerate((a, b)):
                    X = query.GetPoseInWorld(g)
                    sign = 1.0 if s == 0 else -1.0  # A lies along +n from its plane, B along -n
                    w = X.multiply(witness[i, s])
                    for d in rng.normal(size=(200, 3)):
                        y = X.multiply(_support_point(kind[s], sizes[s], centre[s], verts[s, : count[s]], d))
                        assert sign * (normal[i] @ (y - w)) >= -1e-9
    assert checked > 1000 and brute == 40


def _support_point(kind, sizes, centre, verts, d):
    """A shape's support point along d (its frame), by hand for the
    primitives and by the vertices for a hull."""
    from drake_cfvol.kernel.types import BOX, CAPSULE, CYLINDER, SPHERE

    d = np.asarray(d, float)
    if kind == BOX:
        return np.sign(d) * sizes
    if kind == SPHERE:
        return sizes[0] * d / np.linalg.norm(d)
    if kind == CAPSULE:
        return np.array([0, 0, np.sign(d[2]) * sizes[1]]) + sizes[0] * d / np.linalg.norm(d)
    if kind == CYLINDER:
        radial = np.array([d[0], d[1], 0.0])
        return np.array([0, 0, np.sign(d[2]) * sizes[1]]) + sizes[0] * radial / np.linalg.norm(radial)
    return centre + verts[np.argmax(verts @ d)]
