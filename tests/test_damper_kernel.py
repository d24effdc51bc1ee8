"""The damper's compiled point distance (systems/damper_kernel.py) against
Drake's ComputeSignedDistanceToPoint, and the damper's rows against a
Python assembly from Drake's own queries."""

import numpy as np
import pytest
from pydrake.geometry import Box, Capsule, Cylinder, SceneGraph, Sphere
from pydrake.math import RigidTransform, RollPitchYaw
from pydrake.multibody.plant import CoulombFriction, MultibodyPlant

from drake_cfvol.systems.damper_kernel import point_distance, point_query_shape


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


def test_compiled_rows_are_the_drake_assembled_rows():
    """The cobot cell at 150 random configurations within its joint
    limits: the compiled rows (pair_rows, own point distances) equal the
    rows assembled pair by pair from Drake's point queries (1e-9), row by
    row; every measured pair's distance is Drake's and every pair the broad
    phase skipped lies at least its lower bound away (Drake)."""
    from pydrake.multibody.plant import AddMultibodyPlantSceneGraph
    from pydrake.systems.framework import DiagramBuilder

    from drake_cfvol.scene.workcell import load_workcell
    from drake_cfvol.systems.damper import VelocityDamper
    from drake_cfvol.systems.damper_parts import side_arrays

    wc = load_workcell("cobot")
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
    scratch = plant.CreateDefaultContext()
    lo, hi = wc.position_lower, wc.position_upper
    rng = np.random.default_rng(0)
    rows_seen = point_rows = 0
    for _ in range(150):
        q = lo + rng.random(len(lo)) * (hi - lo)
        plant.SetPositions(pctx, robot, q)
        query = sg.get_query_output_port().Eval(sgctx)
        fast = damper.rows(scratch, query, q)
        damper._drake_rows[:] = True
        try:
            slow = damper.rows(scratch, query, q)
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
