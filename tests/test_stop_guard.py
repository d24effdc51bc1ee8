"""The filter's brake and its stop-path guard against independent facts:
the brake walked one update at a time (limits, no reversal from a state
that can stop without one), and the guard's verdict against Drake's
distances along the whole stop, on the two-link arm of test_safety and
a three-link arm folding onto itself."""

import numpy as np
import pytest
from pydrake.geometry import Box, SceneGraph
from pydrake.math import RigidTransform
from pydrake.multibody.plant import CoulombFriction, MultibodyPlant
from pydrake.multibody.tree import FixedOffsetFrame, RevoluteJoint, SpatialInertia
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.rendering import MultibodyPositionToGeometryPose
from test_safety import _arm, _drake_distance, _fix

from drake_cfvol.systems import SafetyFilter
from drake_cfvol.systems.filter.filter_kernel import brake_velocity
from drake_cfvol.systems.filter.stop_guard import brake_path


def _walk(q, v, a, vmax, acc, jerk, h):
    """The brake walked update by update with brake_velocity: positions,
    velocities and accelerations."""
    qs, vs, accs = [q.copy()], [v.copy()], [a.copy()]
    for _ in range(100000):
        if not (v.any() or a.any()):
            break
        w = brake_velocity(vmax, h, v, a, acc, jerk)
        a, v, q = (w - v) / h, w, q + w * h
        qs.append(q)
        vs.append(v)
        accs.append(a)
    return np.array(qs), np.array(vs), np.array(accs)


def test_the_brake_path_is_the_brake_walked_update_by_update():
    """brake_path (a fast run through full deceleration) equals the brake
    walked one update at a time bit for bit, ends at rest, and keeps the
    acceleration and jerk limits at every update (the start's own jump
    aside: a random start need not be reachable)."""
    rng = np.random.default_rng(3)
    for trial in range(300):
        k = 1 + trial % 7
        vmax, acc = rng.uniform(0.5, 3, k), rng.uniform(2, 20, k)
        jerk = np.full(k, np.inf) if trial % 5 == 0 else acc * rng.uniform(5, 1000, k)
        h = float(rng.choice([0.001, 0.002, 0.01]))
        q, v, a = rng.normal(size=k), rng.uniform(-1, 1, k) * vmax, rng.uniform(-1, 1, k) * acc
        path, length, stopped = brake_path(q, v, a, vmax, acc, jerk, h, 100000)
        qs, vs, accs = _walk(q, v, a, vmax, acc, jerk, h)
        assert stopped and np.array_equal(path, qs)
        assert not vs[-1].any() and not accs[-1].any()
        np.testing.assert_allclose(length, np.abs(np.diff(qs, axis=0)).sum(axis=0), rtol=1e-9, atol=1e-15)
        assert (np.abs(np.diff(vs, axis=0)[1:]) <= acc * h * (1 + 1e-9)).all()
        if np.isfinite(jerk).all():
            assert (np.abs(np.diff(accs, axis=0)[1:]) <= jerk * h * (1 + 1e-9)).all()


def test_the_brake_ends_at_rest_without_a_reversal():
    """From a steady velocity (a = 0) the brake never reverses a joint: its
    last ramp brings the acceleration to 0 as the velocity reaches 0 (the
    former brake, 0 clipped to the hard interval, swung about rest)."""
    rng = np.random.default_rng(4)
    for _ in range(300):
        k = 3
        vmax, acc = rng.uniform(0.5, 3, k), rng.uniform(2, 20, k)
        jerk = acc * rng.uniform(5, 1000, k)
        h = float(rng.choice([0.001, 0.01]))
        v = rng.uniform(-1, 1, k) * vmax
        _, vs, _ = _walk(np.zeros(k), v, np.zeros(k), vmax, acc, jerk, h)
        assert (vs * np.sign(v) >= 0).all()


def _trials(diagram, sf, ids, sample, accelerations, h, rng, n=40):
    """Up to n random commands near the pair ``ids``: q from ``sample(rng)``
    where Drake's distance lies in (5 mm, its bound), v_last within 0.8 of
    the velocity limits and v one update's acceleration from it. Yields
    (the guard's verdict, Drake's least distance at every update of the
    stop and halfway between, the guard's threshold)."""
    ctx = diagram.CreateDefaultContext()
    sctx = sf.GetMyContextFromRoot(ctx)
    k = len(accelerations)
    _fix(diagram, ctx, np.zeros(k), lower=[-10] * k, upper=[10] * k)
    tried = 0
    for _ in range(20000):
        if tried == n:
            break
        q, near = sample(rng)
        sf.set_initial_position(sctx, q)
        d_now = _drake_distance(diagram, ctx, *ids)
        if not 0.005 < d_now < near:
            continue
        tried += 1
        rows = sf.damper_rows(sctx)
        v_last = rng.uniform(-1, 1, k) * sf.velocity_limits * 0.8
        v = v_last + rng.uniform(-1, 1, k) * np.asarray(accelerations) * h
        ok = sf.stop_is_clear(rows, q, q, v, v_last)
        path = sf.stop_path(q, v, v_last)
        dists = []
        for x in np.concatenate([path, 0.5 * (path[1:] + path[:-1])]):
            sf.set_initial_position(sctx, x)
            dists.append(_drake_distance(diagram, ctx, *ids))
        yield ok, min(dists), min(sf.clearance - sf.GUARD_BAND * sf.allowance, d_now)


@pytest.mark.parametrize("obstacle", ["wall", "column"])
def test_a_stop_the_guard_keeps_stays_clear_by_drake(obstacle):
    """Random commands near a wall (flat face) and a column (round): where
    the guard keeps a command, Drake's distance at every update of the
    stop and halfway between updates stays above the threshold (the
    margin less the guard's band, or the distance now where nearer). Against
    the wall the plane is exact: a refused stop comes within the
    threshold by Drake too, up to the guard's bound for the path between
    updates (a few micrometres at 1 ms)."""
    h = 0.001
    diagram, sf, tip, obs = _arm(
        obstacle,
        clearance=0.02,
        influence_distance=0.15,
        damper_gain=1.0,
        period=h,
        acceleration_limits=[6.0, 8.0],
        jerk_limits=[300.0, 400.0],
    )
    low, high = ([-0.3, -1.2], [1.2, 1.2]) if obstacle == "wall" else ([-np.pi, 2.0], [np.pi, 3.0])
    near = 0.12 if obstacle == "wall" else 0.05
    rng = np.random.default_rng(7 if obstacle == "wall" else 8)
    kept = refused = 0
    for ok, closest, threshold in _trials(
        diagram, sf, (tip, obs), lambda r: (r.uniform(low, high), near), [6.0, 8.0], h, rng
    ):
        if ok:
            kept += 1
            assert closest >= threshold - 1e-9
        else:
            refused += 1
            if obstacle == "wall":
                assert closest < threshold + 1e-4
    assert kept >= 5 and refused >= 5  # both verdicts were tried


def _folding_arm(h: float):
    """A planar three-link arm (revolute joints about z) with a box on its
    first and third links, a pair Drake does not filter (the links are not
    adjacent), no other geometry; the filter's commanded position poses
    the SceneGraph. Returns (diagram, filter, box on link 1, box on link 3)."""
    builder = DiagramBuilder()
    sg = builder.AddSystem(SceneGraph())
    plant = MultibodyPlant(0.0)
    plant.RegisterAsSourceForSceneGraph(sg)
    arm = plant.AddModelInstance("arm")
    inertia = SpatialInertia.SolidSphereWithMass(1.0, 0.05)
    links = [plant.AddRigidBody(f"link{i}", arm, inertia) for i in (1, 2, 3)]
    parent = plant.world_frame()
    for i, (link, length) in enumerate(zip(links, (0.5, 0.3, 0.0))):
        plant.AddJoint(RevoluteJoint(f"j{i + 1}", parent, link.body_frame(), [0, 0, 1]))
        parent = plant.AddFrame(FixedOffsetFrame(f"end{i + 1}", link.body_frame(), RigidTransform([length, 0, 0])))
    friction = CoulombFriction(0.5, 0.5)
    first = plant.RegisterCollisionGeometry(
        links[0], RigidTransform([0.25, 0, 0]), Box(0.5, 0.08, 0.08), "first", friction
    )
    third = plant.RegisterCollisionGeometry(
        links[2], RigidTransform([0.2, 0, 0]), Box(0.4, 0.06, 0.06), "third", friction
    )
    plant.Finalize()
    sf = builder.AddSystem(
        SafetyFilter(
            plant,
            sg,
            arm,
            velocity_limits=[1.0, 1.5, 2.0],
            obstacle_ids=[],
            clearance=0.02,
            period=h,
            acceleration_limits=[6.0, 8.0, 10.0],
            jerk_limits=[300.0, 400.0, 500.0],
        )
    )
    to_pose = builder.AddSystem(MultibodyPositionToGeometryPose(plant))
    builder.Connect(sf.commanded_position_output, to_pose.get_input_port())
    builder.Connect(to_pose.get_output_port(), sg.get_source_pose_port(plant.get_source_id()))
    builder.Connect(sg.get_query_output_port(), sf.query_object_input)
    for port in (sf.desired_position_input, sf.lower_input, sf.upper_input, sf.nominal_input):
        builder.ExportInput(port, port.get_name())
    builder.ExportOutput(sg.get_query_output_port(), "query_object")
    return builder.Build(), sf, first, third


def test_a_stop_the_guard_keeps_between_two_links_stays_clear_by_drake():
    """Random commands with the third link's box near the first's (a pair of
    two links, the first the third's ancestor: the plane is carried with
    the first link): where the guard keeps a command, Drake's distance at
    every update of the stop and halfway between stays above the threshold."""
    h = 0.001
    diagram, sf, first, third = _folding_arm(h)
    rng = np.random.default_rng(9)
    kept = refused = 0
    sample = lambda r: (r.uniform([-1.0, 1.6, 1.0], [1.0, 2.9, 2.9]), 0.08)  # noqa: E731
    for ok, closest, threshold in _trials(diagram, sf, (first, third), sample, [6.0, 8.0, 10.0], h, rng):
        if ok:
            kept += 1
            assert closest >= threshold - 1e-9
        else:
            refused += 1
    assert kept >= 5 and refused >= 5  # both verdicts were tried
