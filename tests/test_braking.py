"""The safety filter's acceleration and jerk limits against independent
facts: the discrete update's braking walked step by step, a point mass
approaching a plane (closed-form stopping distance), and random requests,
boxes and limits on the two-link arm of test_safety (Drake's distances)."""

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pydrake.common.eigen_geometry import AngleAxis
from pydrake.geometry import Box, Capsule
from pydrake.math import RigidTransform, RollPitchYaw, RotationMatrix
from pydrake.multibody.plant import AddMultibodyPlantSceneGraph, CoulombFriction
from pydrake.multibody.tree import FixedOffsetFrame, RevoluteJoint, SpatialInertia
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from test_safety import VMAX, _arm, _drake_distance, _fix

from drake_cfvol.systems.filter.damper_kernel import probes as probes_of
from drake_cfvol.systems.filter.damper_kinematics import _second_order
from drake_cfvol.systems.filter.filter_kernel import (
    ROW_DECELERATION_SHARE,
    _sum_as_numpy,
    brake_rows,
    braked_rows,
    braking_lead,
    face_speed,
    hard_interval,
    plane_bends,
    stop_distance,
    stop_steps,
)


def _walked(v, a, acc, jerk, h):
    """The braking of the discrete update walked one step at a time (no
    closed form): the distance the positive velocities cover."""
    d = 0.0
    while v > 0:
        a = max(a - jerk * h, -acc)
        v = v + a * h
        d += max(v, 0.0) * h
    return d


def test_stop_distance_is_the_update_walked_step_by_step():
    rng = np.random.default_rng(0)
    for _ in range(300):
        acc, h = rng.uniform(1, 20), rng.choice([0.001, 0.01])
        jerk = np.inf if rng.random() < 0.3 else rng.uniform(50, 5000)
        v, a = rng.uniform(-0.5, 3.0), rng.uniform(-acc, acc)
        assert stop_distance(v, a, acc, jerk, h) == pytest.approx(_walked(v, a, acc, jerk, h), rel=1e-9, abs=1e-12)


def test_stop_steps_are_each_joints_walked_stop_at_the_rows_share():
    """Per joint, signed: where braking at the row's share of its limits
    from (v, a) stops it, walked step by step; 0 for a joint without an
    acceleration limit."""
    rng = np.random.default_rng(5)
    for _ in range(100):
        k = 4
        acc, jerk, h = rng.uniform(1, 20, k), rng.uniform(50, 5000, k), rng.choice([0.001, 0.01])
        acc[0] = np.inf
        v, a = rng.uniform(-3, 3, k), rng.uniform(-1, 1, k) * np.minimum(acc, 20.0)
        got = stop_steps(v, a, acc, jerk, h)
        assert got[0] == 0.0
        share = ROW_DECELERATION_SHARE
        for j in range(1, k):
            s = np.sign(v[j]) or 1.0
            walked = _walked(s * v[j], s * a[j], share * acc[j], share * jerk[j], h)
            assert got[j] == pytest.approx(s * walked, rel=1e-9, abs=1e-12)


def _rotations(rng, n):
    """n random rotations (QR of Gaussian matrices)."""
    out = np.zeros((n, 3, 3))
    for i in range(n):
        Q, R = np.linalg.qr(rng.standard_normal((3, 3)))
        out[i] = Q * np.sign(np.diag(R))
    return out


def _plane_bends_numpy(before, after, A, dirs, points, slots, pair, stop, sides):
    """plane_bends written out in NumPy (to 1e-12: its sums in another order)."""
    probes, counts, radii = sides
    (R0, o0), (R1, o1) = before, after
    out, seen = np.zeros(len(A)), set()
    for i in range(len(A)):
        p = pair[i]
        if p in seen:
            continue
        seen.add(p)
        if (slots[i] < 0).any():
            continue
        extra = []
        for t, sign in ((1, 1.0), (0, -1.0)):  # the plane on side t, the other side's probes
            u, c = 1 - t, counts[p, 1 - t]
            if c == 0:
                continue
            st, su = slots[i, t], slots[i, u]
            turn = R1[st] @ R0[st].T
            gap0 = np.min(sign * (probes[p, u, :c] @ R0[su].T + o0[su] - points[i, t]) @ dirs[i] - radii[p, u, :c])
            n1, w1 = turn @ dirs[i], turn @ (points[i, t] - o0[st]) + o1[st]
            gap1 = np.min(sign * (probes[p, u, :c] @ R1[su].T + o1[su] - w1) @ n1 - radii[p, u, :c])
            extra.append(gap0 + A[i] @ stop - gap1)
        if extra:
            out[i] = max(min(extra), 0.0)
    return out


def test_the_compiled_braked_rows_are_numpys_bit_for_bit():
    """braked_rows, one compiled call, equals the filter's former steps in
    NumPy bit for bit: the least A v in the hard interval (NumPy's pairwise
    sum, 8 running sums from 8 joints on), the bound, the rows carried to
    the joints' stop (no round radii), less for a row that opens its first
    order's opening over the stop, brake_rows and the rows the test keeps; random rows
    for 1 to 20 joints. And its sum is NumPy's for 1 to 128 terms. The
    witness rows' plane bends (:func:`plane_bends`, which braked_rows
    calls) are NumPy's to 1e-12 (summed in another order)."""
    rng = np.random.default_rng(11)
    for n in range(1, 129):
        x = rng.standard_normal(n) * 10.0 ** rng.uniform(-5, 5, n)
        assert _sum_as_numpy(x, n) == x.sum()
    kept = rows = bent = offset = 0
    for trial in range(60):
        k, S, m = 1 + trial % 20, int(rng.integers(1, 5)), int(rng.integers(1, 40))
        A, b = rng.standard_normal((m, k)), rng.uniform(-0.3, 0.1, m)
        rows += m
        dirs = rng.standard_normal((m, 3))
        dirs /= np.linalg.norm(dirs, axis=1)[:, None]
        points, slots = rng.standard_normal((m, 2, 3)), rng.integers(-1, S, (m, 2))
        before = (_rotations(rng, S), rng.standard_normal((S, 3)))
        after = (_rotations(rng, S), rng.standard_normal((S, 3)))
        rev = (rng.random((S, k)) < 0.7).astype(float)
        acc, jerk = rng.uniform(1, 20, k), rng.uniform(50, 5000, k)
        acc[0] = np.inf if trial % 3 == 0 else acc[0]
        v_last, h = rng.uniform(-1, 1, k), 1e-3
        h_lo, h_hi = v_last - rng.uniform(0, 0.05, k), v_last + rng.uniform(0, 0.05, k)
        stop, lever_speed = rng.uniform(-0.1, 0.1, k), rng.uniform(0, 2, S)
        rounds, pair = rng.uniform(0, 0.05, (m, 2)), rng.integers(0, 30, m)
        w = np.maximum(np.abs(h_lo), np.abs(h_hi))
        theta = float(w.sum()) * h
        worst = np.minimum(A * h_lo, A * h_hi).sum(axis=1)
        bound = theta * np.append(lever_speed, 0.0)[slots].sum(axis=1)
        n_probes = int(rng.integers(0, 9))
        sides = (
            rng.standard_normal((30, 2, n_probes, 3)),
            rng.integers(0, n_probes + 1, (30, 2)),
            rng.uniform(0, 0.1, (30, 2, n_probes)),
        )
        bend = _second_order(*before, *after, A, dirs, points, slots, np.zeros((m, 2)), rev, stop)
        planes = plane_bends(before, after, A, dirs, points, slots, pair, stop, sides)
        assert np.allclose(
            planes, _plane_bends_numpy(before, after, A, dirs, points, slots, pair, stop, sides), rtol=0, atol=1e-12
        )
        bent += int((planes > 0).sum())
        bend = np.maximum(bend, planes)
        # A row that opens: its first order's opening over the stop (less
        # the step) offsets the bend.
        s_last = -(A @ v_last)
        f = A @ stop + s_last * h
        opens = (s_last <= 0.0) & (f > 0.0)
        offset += int((opens & (bend > 0)).sum())
        bend = np.where(opens, np.maximum(bend - f, 0.0), bend)
        expected = brake_rows(A, b, 2.0, acc, jerk, h, v_last, h_lo, h_hi, bend)
        keep = worst < expected + bound
        got = braked_rows(
            (A, b, dirs, points, slots, rounds, pair),
            before,
            after,
            (rev, stop, lever_speed, w),
            (acc, jerk, h, 2.0),
            (v_last, h_lo, h_hi),
            sides,
        )
        for x, y in zip(
            got, (A[keep], expected[keep], dirs[keep], points[keep], slots[keep], rounds[keep], pair[keep])
        ):
            assert x.dtype == y.dtype and np.array_equal(x, y)
        kept += int(keep.sum())
    assert 0 < kept < rows and bent > 0 and offset > 0


def test_a_row_whose_point_turns_away_is_not_made_to_open_faster():
    """A point at radius r on a link turning about z, opening from a plane
    below it: over a stop of theta its height gains r sin(theta) > 0 (it
    never closes), while its first order says r theta, a bend of r (theta -
    sin(theta)) (by hand), here more than the row's gap. Braked, the row
    keeps the damper's own rule, which it cannot bind at this update, and
    is left out: the first order's opening offsets the bend. Counted whole
    (brake_rows given the raw bend), the same row asks to open faster than
    it does now, at the hard interval's end: the runaway the offset removes."""
    r, theta, h, rate, gap = 1.0, 1.0, 1e-3, 5.0, 0.06
    bend = r * (theta - np.sin(theta))
    assert bend > gap  # the case that ran away
    A, b = np.array([[r]]), np.array([-rate * gap])  # d/dtheta of the height is r at theta = 0
    dirs = np.array([[0.0, 1.0, 0.0]])  # from the plane (side 1) towards the point (side 0)
    points = np.array([[[r, 0.0, 0.0], [r, -0.1, 0.0]]])
    slots, rounds, pair = np.array([[0, -1]]), np.zeros((1, 2)), np.array([0])
    turn = RotationMatrix.MakeZRotation(theta).matrix()
    before, after = (np.eye(3)[None], np.zeros((1, 3))), (turn[None], np.zeros((1, 3)))
    acc, jerk = np.array([10.0]), np.array([500.0])
    v_last = np.array([1.0])  # opening at r v = 1 m/s
    h_lo, h_hi = v_last - 1e-3, v_last + 1e-3
    w = np.maximum(np.abs(h_lo), np.abs(h_hi))
    got = braked_rows(
        (A, b, dirs, points, slots, rounds, pair),
        before,
        after,
        (np.ones((1, 1)), np.array([theta]), np.array([r]), w),
        (acc, jerk, h, rate),
        (v_last, h_lo, h_hi),
        (np.zeros((1, 2, 0, 3)), np.zeros((1, 2), np.int64), np.zeros((1, 2, 0))),
    )
    assert len(got[1]) == 0  # under the damper's rule it cannot bind at this update: left out
    # The raw bend: the row asks for the most opening the hard interval allows.
    raw = brake_rows(A, b, rate, acc, jerk, h, v_last, h_lo, h_hi, np.array([bend]))
    assert raw[0] > A[0] @ v_last  # more opening than now
    assert raw[0] == pytest.approx(r * h_hi[0])


def test_face_speed_is_the_fastest_that_still_stops_in_time():
    """The velocity returned stops within the gap; a hair faster does not
    (unless it is the interval's end)."""
    rng = np.random.default_rng(1)
    for _ in range(300):
        acc, jerk, h = rng.uniform(2, 20), rng.uniform(100, 5000), rng.choice([0.001, 0.01])
        v_last, gap = rng.uniform(-1, 1), rng.uniform(0.0, 0.3)
        lo, hi = v_last - acc * h, v_last + acc * h
        v = face_speed(gap, v_last, lo, hi, acc, jerk, h)

        def travel(x):
            return x * h + _walked(x, (x - v_last) / h, acc, jerk, h)

        if v > lo:
            assert travel(v) <= gap + 1e-12
        if v < hi:
            assert travel(v + 1e-9) > gap - 1e-9


def test_a_point_mass_braking_on_the_row_stops_at_the_plane():
    """A point mass (one joint, the row A = -1: its distance shrinks at its
    velocity) driven at the plane as fast as brake_rows' row and its hard
    interval allow, from 0.3 m above the target: it never crosses the
    target, keeps its acceleration and jerk limits, and ends at rest
    within a millimetre of the target (the damper's own rule near it)."""
    rate = 6.7
    for h in (0.01, 0.001):
        for acc_, jerk_ in ((0.5, 20.0), (2.0, 100.0), (8.0, np.inf)):
            acc, jerk, vmax = np.array([acc_]), np.array([jerk_]), np.array([2.0])
            A = np.array([[-1.0]])
            gap, v, a = 0.3, np.zeros(1), np.zeros(1)
            for _ in range(int(round(20.0 / h))):
                lo, hi = hard_interval(vmax, h, v, a, acc, jerk)
                b = brake_rows(A, np.array([-rate * gap]), rate, acc, jerk, h, v, lo, hi, np.zeros(1))
                v_new = np.minimum(hi, -b)  # as fast towards the plane as the row allows
                assert v_new[0] >= lo[0] - 1e-12
                a_new = (v_new - v) / h
                assert abs(a_new[0]) <= acc_ * (1 + 1e-9)
                assert abs(a_new[0] - a[0]) <= jerk_ * h * (1 + 1e-9) or not np.isfinite(jerk_)
                v, a = v_new, a_new
                gap -= v[0] * h
                assert gap >= -1e-12
            assert gap < 1e-3 and abs(v[0]) < 1e-3


def test_a_row_made_at_the_braking_lead_can_still_stop_its_pair():
    """Random rows, limits, velocities and accelerations: a pair first seen
    at the gap braking_lead gives for its speed and acceleration bounds
    (sum_j |A_ij| (|v_j| + a_j dt), sum_j |A_ij| (|a_j| + j_j dt), as
    VelocityDamper.pair_speeds bounds them) can still be stopped by the
    row's own braking (brake_rows' point mass at the share of the row's
    limits): from the slowest closing the hard interval allows, the walked
    stop (stop_distance) stays within the gap."""
    rng = np.random.default_rng(4)
    share = ROW_DECELERATION_SHARE
    checked = 0
    for _ in range(3000):
        k = int(rng.integers(1, 8))
        h = rng.choice([0.001, 0.01])
        vmax = rng.uniform(0.5, 3.0, k)
        acc = rng.uniform(1.0, 30.0, k)
        jerk = np.where(rng.random(k) < 0.2, np.inf, rng.uniform(50.0, 5000.0, k))
        v, a = rng.uniform(-vmax, vmax), rng.uniform(-acc, acc)
        A = rng.uniform(-2.0, 2.0, k) * (rng.random(k) < 0.8)
        if not A.any():
            continue
        lo, hi = hard_interval(vmax, h, v, a, acc, jerk)
        speed = float(np.abs(A) @ np.minimum(np.abs(v) + acc * h, vmax))
        closing = float(np.abs(A) @ np.where(np.isfinite(jerk), np.abs(a) + jerk * h, 0.0))
        lead, ramp = braking_lead(v, a, vmax, acc, jerk, h)
        gap = (speed + ramp * closing) * lead
        s_last, s_lo = -float(A @ v), -float(np.maximum(A * lo, A * hi).sum())
        nz = A != 0
        row_acc, row_jerk = share * float(np.abs(A[nz]) @ acc[nz]), share * float(np.abs(A[nz]) @ jerk[nz])
        assert s_lo * h + stop_distance(s_lo, (s_lo - s_last) / h, row_acc, row_jerk, h) <= gap + 1e-12
        checked += 1
    assert checked > 2500


def _spun_pair(shape_a, X_A, shape_b, X_BG, axis, centre):
    """Shape A fixed at X_A and shape B on a body turning about ``axis``
    through ``centre`` (the body's origin, X_BG its pose on it): the plant,
    its context, the scene graph's query port and the two geometry ids."""
    builder = DiagramBuilder()
    plant, sg = AddMultibodyPlantSceneGraph(builder, 0.0)
    inertia = SpatialInertia.SolidSphereWithMass(1.0, 0.05)
    body = plant.AddRigidBody("b", inertia)
    pivot = plant.AddFrame(FixedOffsetFrame("pivot", plant.world_frame(), RigidTransform(centre)))
    plant.AddJoint(RevoluteJoint("turn", pivot, body.body_frame(), axis))
    friction = CoulombFriction(0.5, 0.5)
    id_a = plant.RegisterCollisionGeometry(plant.world_body(), X_A, shape_a, "a", friction)
    id_b = plant.RegisterCollisionGeometry(body, X_BG, shape_b, "b", friction)
    plant.Finalize()
    diagram = builder.Build()
    ctx = diagram.CreateDefaultContext()
    return (
        plant,
        plant.GetMyMutableContextFromRoot(ctx),
        sg.get_query_output_port(),
        sg.GetMyContextFromRoot(ctx),
        id_a,
        id_b,
    )


def test_a_spun_link_s_witness_row_closes_no_more_than_its_planes_say():
    """Two boxes, or a box and a capsule, of two links (the one fixed, the
    other turning about an axis through a point, up to 0.8 rad: a joint's
    stop): the pair's witness row, first order in the turn less its bend
    (the rows' points carried to the turn and, by plane_bends, the pair's
    witness planes carried with their links), never says more than Drake's
    signed distance after the turn. The rows' own points alone say more by
    up to tens of mm where the closest points slide (a box's edge swept
    across the other's, as the aerospace cell's spinning gripper over its
    link_3 came 16 mm inside the margin it braked for)."""
    rng = np.random.default_rng(7)
    checked, misses = 0, []
    while checked < 150:
        size_a, size_b = rng.uniform(0.1, 1.0, 3), rng.uniform(0.1, 1.0, 3)
        shape_b = Box(*size_b) if checked % 3 else Capsule(size_b[0] / 2, size_b[1])
        X_A = RigidTransform(RollPitchYaw(rng.uniform(-np.pi, np.pi, 3)), rng.uniform(-0.3, 0.3, 3))
        X_BG = RigidTransform(RollPitchYaw(rng.uniform(-np.pi, np.pi, 3)), rng.uniform(-0.5, 0.5, 3))
        axis = rng.standard_normal(3)
        axis /= np.linalg.norm(axis)
        centre = rng.uniform(-1.5, 1.5, 3)
        plant, pctx, port, sctx, id_a, id_b = _spun_pair(Box(*size_a), X_A, shape_b, X_BG, axis, centre)
        query = port.Eval(sctx)
        pair = query.ComputeSignedDistancePairClosestPoints(id_a, id_b)
        if not 0.005 < pair.distance < 0.2:
            continue
        first = pair.id_A == id_a  # Drake's A is side 0 of the row
        ids = (id_a, id_b) if first else (id_b, id_a)
        shapes = (Box(*size_a), shape_b) if first else (shape_b, Box(*size_a))
        geometry_on_body = (X_A, X_BG) if first else (X_BG, X_A)
        slot_of = (0, 1) if first else (1, 0)  # slot 0: the fixed link, 1: the turning one
        n = np.asarray(pair.nhat_BA_W, float)
        P1 = query.GetPoseInWorld(ids[0]).multiply(pair.p_ACa)
        P2 = query.GetPoseInWorld(ids[1]).multiply(pair.p_BCb)
        speed = {
            0: np.zeros(3),
            1: np.cross(axis, (P2 if first else P1) - centre),
        }  # per unit turn, on the turning side
        A_row = np.array([[n @ speed[slot_of[0]] - n @ speed[slot_of[1]]]])

        def poses(theta):
            R = RotationMatrix(AngleAxis(theta, axis)).matrix()
            return np.stack([np.eye(3), R]), np.stack([np.zeros(3), centre])

        counts, probes, radii = np.zeros((1, 2), np.int64), np.zeros((1, 2, 8, 3)), np.zeros((1, 2, 8))
        for side in range(2):
            c, r = probes_of(shapes[side])
            P_B = geometry_on_body[side].multiply(c).T
            counts[0, side], probes[0, side, : len(r)], radii[0, side, : len(r)] = len(r), P_B, r
        dirs, points = n[None], np.array([[P1, P2]])
        slots, rev = np.array([slot_of]), np.array([[0.0], [1.0]])
        theta = rng.uniform(-0.8, 0.8)
        stop = np.array([theta])
        before, after = poses(0.0), poses(theta)
        own = _second_order(*before, *after, A_row, dirs, points, slots, np.zeros((1, 2)), rev, stop)[0]
        planes = plane_bends(
            before, after, A_row, dirs, points, slots, np.zeros(1, np.int64), stop, (probes, counts, radii)
        )
        plant.SetPositions(pctx, [theta])
        truth = port.Eval(sctx).ComputeSignedDistancePairClosestPoints(id_a, id_b).distance
        first_order = pair.distance + float(A_row[0] @ stop)
        assert first_order - max(own, planes[0]) <= truth + 1e-9
        misses.append(first_order - own - truth)
        checked += 1
    assert max(misses) > 0.02  # the rows' own points alone would have said more by over 20 mm


def test_the_hard_interval_keeps_every_limit_and_stays_open():
    """Random walks from rest, each step a random velocity of the interval:
    every step keeps |dv| <= a h, |da| <= j h and |v| <= vmax, braking the
    acceleration to 0 at the jerk limit would keep |v| <= vmax, and the
    interval is never empty (the invariant carries over)."""
    rng = np.random.default_rng(2)
    for _ in range(40):
        k = 3
        vmax, acc, jerk = rng.uniform(0.5, 2, k), rng.uniform(2, 20, k), rng.uniform(100, 5000, k)
        h = rng.choice([0.001, 0.01])
        v_last, a_last = np.zeros(k), np.zeros(k)
        for _ in range(400):
            lo, hi = hard_interval(vmax, h, v_last, a_last, acc, jerk)
            assert np.all(lo <= hi)
            v = lo + rng.choice([0.0, 1.0, rng.random()], size=k) * (hi - lo)
            a = (v - v_last) / h
            assert np.all(np.abs(a) <= acc * (1 + 1e-9))
            assert np.all(np.abs(a - a_last) <= jerk * h * (1 + 1e-9))
            assert np.all(np.abs(v) <= vmax * (1 + 1e-9))
            assert np.all(np.abs(v) + np.maximum(np.sign(v) * a, 0) ** 2 / (2 * jerk) <= vmax * (1 + 1e-9))
            v_last, a_last = v, a


@pytest.fixture(scope="module")
def limited_arms():
    acc, jerk = np.array([6.0, 9.0]), np.array([300.0, 500.0])
    return (
        {h: _arm("wall", clearance=0.02, period=h, acceleration_limits=acc, jerk_limits=jerk) for h in (0.01, 0.001)},
        acc,
        jerk,
    )


@pytest.mark.slow
@settings(max_examples=12, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    fast=st.booleans(),
)
def test_random_pushes_and_boxes_never_break_a_limit_nor_collide(limited_arms, seed, fast):
    """Random desired positions (a push that jumps every few updates), boxes
    that widen, narrow and move: every commanded update keeps the
    velocity, acceleration and jerk limits, and the tip never touches the
    wall (Drake's distance, at every update)."""
    arms, acc, jerk = limited_arms
    h = 0.001 if fast else 0.01
    diagram, sf, tip, wall_id = arms[h]
    rng = np.random.default_rng(seed)
    sim = Simulator(diagram)
    ctx = sim.get_mutable_context()
    start = np.array([1.2, 0.3])  # the tip 0.54 m from the wall
    sf.set_initial_position(sf.GetMyMutableContextFromRoot(ctx), start)
    qs, n = [], 0
    centre, width = start.copy(), np.array([2.0, 2.0])
    for _ in range(12):
        desired = rng.uniform(-1.5, 1.5, 2)
        centre = centre + rng.uniform(-0.3, 0.3, 2)
        width = np.clip(width + rng.uniform(-0.6, 0.6, 2), 0.05, 3.0)
        _fix(diagram, ctx, desired, centre - width / 2, centre + width / 2, nominal=centre)
        for _ in range(int(round(0.1 / h))):
            n += 1
            sim.AdvanceTo((n + 0.5) * h)  # between two updates: one update per sample
            qs.append(sf.commanded_position_output.Eval(sf.GetMyContextFromRoot(ctx)).copy())
            assert _drake_distance(diagram, ctx, tip, wall_id) > 0.0
    q = np.array(qs)
    v = np.diff(q, axis=0) / h
    a = np.diff(v, axis=0) / h
    j = np.diff(a, axis=0) / h
    assert np.all(np.abs(v) <= VMAX * (1 + 1e-9))
    assert np.all(np.abs(a) <= acc * (1 + 1e-6))
    assert np.all(np.abs(j) <= jerk * (1 + 1e-5))


def test_the_box_ahead_holds_the_nominal_and_every_box_it_looks_at(bounded):
    """JointBoundsSource's lower_ahead, upper_ahead on automotive path 1:
    inside the box at s and holding the nominal; about the nominal, no
    wider than any box in [s, s + L] (checked at 200 points of the window,
    between the source's own samples too, within the box's change over a
    quarter step); and somewhere tighter than the box at s (a face that
    closes in ahead)."""
    from drake_cfvol.systems import JointBoundsSource

    table = bounded("automotive", "path1")
    L = 3.0
    src = JointBoundsSource(table, clamp=True, lookahead=L)
    ctx = src.CreateDefaultContext()
    q_lo, q_hi, q_nom = table.boxes_at(np.arange(0.0, table.g - 1.0, 0.25))
    quarter = max(np.abs(np.diff(q_lo - q_nom, axis=0)).max(), np.abs(np.diff(q_hi - q_nom, axis=0)).max())
    tighter = False
    for s in np.linspace(0.0, table.g - 1.0, 157):
        src.path_index_input.FixValue(ctx, [s])
        lo, hi, nom = (src.GetOutputPort(n).Eval(ctx) for n in ("lower", "upper", "nominal"))
        lo_a, hi_a = src.lower_ahead_output.Eval(ctx), src.upper_ahead_output.Eval(ctx)
        assert np.all(lo <= lo_a) and np.all(lo_a <= nom) and np.all(nom <= hi_a) and np.all(hi_a <= hi)
        sig = np.linspace(s, min(s + L, table.g - 1.0), 200)
        lo_s, hi_s, nom_s = table.boxes_at(sig)
        assert np.all(lo_a - nom >= (lo_s - nom_s).max(axis=0) - quarter - 1e-12)
        assert np.all(hi_a - nom <= (hi_s - nom_s).min(axis=0) + quarter + 1e-12)
        tighter = tighter or bool(np.any(lo_a > lo + 1e-6) or np.any(hi_a < hi - 1e-6))
    assert tighter


@pytest.mark.parametrize("period", [0.01, 0.001])
def test_the_admittance_meets_a_face_at_rest(period):
    """A steady push towards the upper face: with acceleration limits the
    deviation's rate falls by at most (1 - path_share) a dt per update and
    is (nearly) zero when the deviation reaches the face, never past it;
    without them the clamp stops it from full speed in one update."""
    from drake_cfvol.systems import AdmittanceDeformation

    k, a, share = 2, np.array([4.0, 9.0]), 0.5

    def run(limits):
        adm = AdmittanceDeformation(
            k, mass=2.0, damping=5.0, stiffness=0.0, period=period, path_share=share, acceleration_limits=limits
        )
        ctx = adm.CreateDefaultContext()
        adm.nominal_input.FixValue(ctx, np.zeros(k))
        adm.lower_input.FixValue(ctx, np.full(k, -0.5))
        adm.upper_input.FixValue(ctx, np.full(k, 0.3))
        adm.human_torque_input.FixValue(ctx, np.full(k, 20.0))
        rates = []
        for _ in range(int(round(1.5 / period))):
            x = adm.EvalUniquePeriodicDiscreteUpdate(ctx).get_vector(0).CopyToVector()
            ctx.SetDiscreteState(0, x)
            rates.append(x[k:].copy())
            assert np.all(x[:k] <= 0.3 + 1e-12)
        return np.array(rates), x

    rates, x = run(a)
    np.testing.assert_allclose(x[:k], 0.3, atol=1e-3)  # it got there
    drops = -np.diff(rates, axis=0)
    assert np.all(drops <= (1 - share) * a * period * (1 + 1e-6) + 1e-12)
    free, _ = run(None)
    assert np.max(-np.diff(free, axis=0)) > 10 * (1 - share) * a.max() * period  # the clamp's stop, for contrast


def test_the_tables_box_ahead_equals_its_boxes(bounded):
    """BoundsTable.box_ahead (the bounds source's window, one compiled call)
    equals, bit for bit, what boxes_at gives: the box at s, and the box at s
    tightened to the largest lower and smallest upper deviation of the boxes
    at the quarter steps after s and at the window's end, clipped to the box
    at s; for both interpolation rules, at waypoints and near the end."""
    table = bounded("automotive", "path1")
    rng = np.random.default_rng(5)
    for interpolation in ("stretch", "linear"):
        t = dataclasses.replace(table, interpolation=interpolation)
        for s in [0.0, 3.0, t.g - 1.0, t.g - 1.3, *rng.uniform(0, t.g - 1, 60)]:
            lookahead = float(rng.choice([0.0, 0.25, 1.0, rng.uniform(0, 5)]))
            lo, hi, nom, lo_a, hi_a = t.box_ahead(s, lookahead)
            box = t.boxes_at([s])
            for got_, want in zip((lo, hi, nom), box):
                assert np.array_equal(got_, want[0])
            end = min(s + lookahead, t.g - 1.0)
            if end <= s:
                assert np.array_equal(lo_a, lo) and np.array_equal(hi_a, hi)
                continue
            sigma = [x / 4.0 for x in range(int(np.floor(4 * s)) + 1, int(np.ceil(4 * end)))] + [end]
            l_s, h_s, n_s = t.boxes_at(sigma)
            dev_lo = np.maximum(lo - nom, (l_s - n_s).max(axis=0))
            dev_hi = np.minimum(hi - nom, (h_s - n_s).min(axis=0))
            assert np.array_equal(lo_a, np.clip(nom + np.minimum(dev_lo, 0.0), lo, hi))
            assert np.array_equal(hi_a, np.clip(nom + np.maximum(dev_hi, 0.0), lo, hi))
            assert np.all(lo <= lo_a) and np.all(lo_a <= nom) and np.all(nom <= hi_a) and np.all(hi_a <= hi)


def test_the_path_starts_and_stops_within_the_acceleration_limits(bounded):
    """PathProgress with path_ramp's ramp: s(t) reaches the rate from rest
    and comes back to rest, the nominal's joint accelerations (second
    differences of the nominal along s(t), 1 ms apart) within the share of
    the limits away from the waypoints' kinks; the end still reached, later
    by the ramp; without limits no ramp (the linear progress as before)."""
    from drake_cfvol.systems import PathProgress, path_ramp, safe_path_rate

    table = bounded("automotive", "path1")
    vmax = np.array([1.92, 1.92, 1.92, 3.32, 2.62, 3.67])
    acc = vmax / 0.2
    rate = safe_path_rate(table, vmax, share=0.5)
    ramp = path_ramp(table, rate, acc, share=0.5)
    assert ramp > 0 and path_ramp(table, rate, np.full(6, np.inf), share=0.5) == 0.0
    p = PathProgress(table.g, rate=rate, start_time=0.5, ramp=ramp)
    flat = PathProgress(table.g, rate=rate, start_time=0.5)
    assert p.duration == pytest.approx(flat.duration + ramp)
    h = 1e-3
    t = np.arange(0.5, p.duration + 0.1, h)
    s = np.array([p.index_at(x) for x in t])
    assert s[0] == 0.0 and s[-1] == table.g - 1 and np.all(np.diff(s) >= 0)
    ds = np.diff(s) / h
    # From rest: the first millisecond's mean speed is the quadratic's, rate h / (2 ramp); back to rest at the end.
    assert ds[0] == pytest.approx(rate * h / (2 * p.ramp), rel=1e-6) and ds.max() == pytest.approx(rate, rel=1e-6)
    moving = np.flatnonzero(ds > 0)
    assert ds[moving[-1]] <= rate * h / p.ramp * (1 + 1e-6)
    # In the ramps, the path's own acceleration times the nominal's steepest step stays within share x limit.
    dds = np.abs(np.diff(ds)) / h
    steps = np.abs(np.diff(table.nominal, axis=0)).max(axis=0)
    assert np.all(dds.max() * steps <= 0.5 * acc * (1 + 1e-3))


@pytest.mark.parametrize("period", [0.01, 0.001])
def test_a_fast_approach_from_afar_brakes_in_time_for_the_margin(period):
    """The two-link arm swung at the wall from 0.5 m away with low
    acceleration limits: its tip, up to 1.5 m/s, needs about 0.6 m to
    stop, four times the influence distance. The filter brakes for it all
    the same: Drake's distance never comes more than 2 mm under the margin,
    and every command keeps the limits. (A row the damper's rule finds
    late asks for the slowest closing the limits allow, with no room for
    its second-order term: it may miss that by micrometres per second,
    counted in braking_faults.)"""
    acc, jerk = np.array([1.5, 2.0]), np.array([40.0, 50.0])
    diagram, sf, tip, wall_id = _arm("wall", clearance=0.02, period=period, acceleration_limits=acc, jerk_limits=jerk)
    sim = Simulator(diagram)
    ctx = sim.get_mutable_context()
    sf.set_initial_position(sf.GetMyMutableContextFromRoot(ctx), np.array([1.2, 0.3]))
    _fix(diagram, ctx, [-0.6, 0.0], nominal=[1.2, 0.3])  # deep in the wall
    qs, closest = [], np.inf
    for n in range(int(round(3.0 / period))):
        sim.AdvanceTo((n + 1.5) * period)
        qs.append(sf.commanded_position_output.Eval(sf.GetMyContextFromRoot(ctx)).copy())
        closest = min(closest, _drake_distance(diagram, ctx, tip, wall_id))
    q = np.array(qs)
    v = np.diff(q, axis=0) / period
    assert np.abs(v).max() > 0.8  # it did swing fast
    assert closest >= 0.02 - 0.002
    a = np.diff(v, axis=0) / period
    assert np.all(np.abs(a) <= acc * (1 + 1e-6))
    assert np.all(np.abs(np.diff(a, axis=0) / period) <= jerk * (1 + 1e-5))


def test_the_stop_rows_read_the_brake_walked_at_the_hard_intervals_ends():
    """stop_guard.stop_rows against the brake itself (stop_guard.brake_path,
    the guard's walk, which test_stop_guard checks against a walk of its
    own): at each end of the hard interval a kept row reads A (e + v dt +
    where the brake stops) plus the row's allowed closing, max(g + slack,
    0) (g = -b / rate, e the command's lead over the rows' base), exactly;
    a row of two links or of moving geometry is never kept; a row left out
    cannot bind: at every corner of the interval its walked closing stays
    within its allowance (brute force over the 2^k corners). A joint with
    no limits at all (an unbounded interval) that moves no row leaves the
    rows finite."""
    import itertools

    from drake_cfvol.systems.filter.stop_guard import brake_path, stop_rows

    rng = np.random.default_rng(5)
    kept_total = 0
    for _ in range(40):
        k, m, P = 4, 12, 4
        h = rng.choice([0.001, 0.01])
        vmax, acc = rng.uniform(1, 3, k), rng.uniform(5, 20, k)
        jerk = acc / rng.uniform(0.005, 0.05, k)
        vmax[3] = acc[3] = jerk[3] = np.inf  # the last joint has no limits (and moves no row)
        v_last = rng.uniform(-0.8, 0.8, k) * np.minimum(vmax, 1.0)
        a_last = rng.uniform(-0.5, 0.5, k) * np.minimum(acc, 1.0)
        h_lo, h_hi = hard_interval(vmax, h, v_last, a_last, acc, jerk)
        lead = rng.normal(size=k) * 0.002 * (rng.random() < 0.5)
        lead[3] = 0.0
        A, b = rng.normal(size=(m, k)) * 0.3, -rng.uniform(-0.05, 0.6, m)
        A[:, 3] = 0.0
        slots = np.where(rng.random((m, 2)) < 0.5, -1, rng.integers(0, 3, (m, 2)))
        pair, static = rng.integers(0, P, m), rng.random(P) < 0.7
        rate, slack, limits = 5.0, 0.002, (vmax, acc, jerk, h)
        As, bs, idx = stop_rows((A, b, slots, pair, static), rate, slack, (v_last, h_lo, h_hi, lead), limits, 10**6)
        kept_total += len(idx)
        assert np.isfinite(As).all() and np.isfinite(bs).all()

        def walked(v):  # the brake's stop from v after the step, joint by joint (the free joint: none)
            v = np.where(np.isfinite(v), v, 0.0)
            path, _, done = brake_path(np.zeros(k), v, (v - v_last) / h, vmax, acc, jerk, h, 10**6)
            assert done
            return np.where(np.isfinite(h_lo), path[-1], 0.0)

        allowed = np.maximum(-b / rate + slack, 0.0)
        for r, i in enumerate(idx):
            assert static[pair[i]] and (slots[i] < 0).any()
            for end in (h_lo, h_hi):
                v = np.where(np.isfinite(end), end, 0.0)
                want = A[i] @ (lead + v * h + walked(v)) + allowed[i]
                assert As[r] @ v - bs[r] == pytest.approx(want, abs=1e-9)
        for i in set(range(m)) - set(idx.tolist()):
            if not (static[pair[i]] and (slots[i] < 0).any()):
                continue
            for corner in itertools.product(*zip(h_lo[:3], h_hi[:3])):
                v = np.array(corner + (0.0,))
                assert A[i] @ (lead + v * h + walked(v)) + allowed[i] >= -1e-9
    assert kept_total > 0  # some rows bound


def test_a_joint_inside_the_box_returns_to_the_box_ahead_within_its_braking_time():
    """filter_kernel.request, by hand: a joint 4 mrad below the box ahead's
    lower face, inside the box, at rest on a nominal at rest, asks to move
    up by at least 4 mrad over return_time (v_max / a + a / j + dt), not
    at the hard interval's top; 4 mrad below the box itself it still asks
    for the top (as fast as the limits allow)."""
    from drake_cfvol.systems.filter.filter_kernel import request, return_time

    k, h = 1, 0.01
    vmax, acc, jerk = np.array([2.0]), np.array([10.0]), np.array([500.0])
    zero = np.zeros(k)
    nominals = np.zeros((2, k))
    T = 2.0 / 10.0 + 10.0 / 500.0 + h
    assert return_time(2.0, 10.0, 500.0, h) == pytest.approx(T)
    q, desired = np.array([0.0]), np.array([-1.0])  # the push pulls down, away from the box ahead
    ahead = np.array([[0.004], [1.0]])
    _, lo, hi, v_t, h_lo, h_hi = request(
        q, desired, np.array([-1.0]), np.array([1.0]), ahead, vmax, h, zero, zero, acc, jerk, nominals
    )
    assert h_hi[0] == pytest.approx(jerk[0] * h * h)  # from rest: one jerk step
    assert 0.004 / T < h_hi[0]  # the return is slower than the limits allow
    assert lo[0] == pytest.approx(0.004 / T) and v_t[0] == pytest.approx(0.004 / T)
    # Above the box ahead on a nominal moving up at u: back down at least
    # 4 mrad over T faster than the nominal.
    u = 0.01
    moving = np.array([[u * h], [0.0]])
    q_up = np.array([0.5]) + 0.004
    _, lo, hi, v_t, h_lo, h_hi = request(
        q_up,
        q_up + 1.0,
        np.array([-1.0]),
        np.array([1.0]),
        np.array([[-1.0], [0.5]]),
        vmax,
        h,
        zero,
        zero,
        acc,
        jerk,
        moving,
    )
    assert h_lo[0] < u - 0.004 / T < 0.0
    assert hi[0] == pytest.approx(u - 0.004 / T) and v_t[0] == pytest.approx(u - 0.004 / T)
    # Below the box itself: as fast as the limits allow.
    _, lo, hi, v_t, h_lo, h_hi = request(
        q, desired, np.array([0.004]), np.array([1.0]), ahead, vmax, h, zero, zero, acc, jerk, nominals
    )
    assert lo[0] == pytest.approx(h_hi[0]) and v_t[0] == pytest.approx(h_hi[0])


def test_a_stop_row_gives_way_to_a_damper_row_and_is_no_miss():
    """The staged QP with a damper row (ROW: v0 >= 1) against a stop row
    (STOP: -v0 >= 0) that cannot both hold, in |v| <= 2: the damper row
    holds exactly (v0 = 1, the least miss of the stop row), the stage is
    the one with the stop rows soft; with the box (BOX: v1 <= -1) against
    a stop row (STOP: v1 >= 0) the stop row holds and the box gives way."""
    from drake_cfvol.systems.filter.constraints import BOX, HARD, ROW, STOP, ConstraintRows, PriorityQP

    eye = np.eye(2)
    limits = ConstraintRows(np.vstack([eye, -eye]), np.full(4, -2.0), HARD, 1e6, "limits")
    v_t = np.zeros(2)
    v, stage = PriorityQP().solve_staged(
        v_t,
        [
            limits,
            ConstraintRows(eye[:1], np.array([1.0]), ROW, 1e6, "damper"),
            ConstraintRows(-eye[:1], np.array([0.0]), STOP, 1e6, "stop_rows"),
        ],
    )
    assert v[0] == pytest.approx(1.0, abs=1e-9) and stage == 1  # the one soft stage: STOP
    v, stage = PriorityQP().solve_staged(
        v_t,
        [
            limits,
            ConstraintRows(-eye[1:], np.array([1.0]), BOX, 1e3, "box"),
            ConstraintRows(eye[1:], np.array([0.0]), STOP, 1e6, "stop_rows"),
        ],
    )
    assert v[1] == pytest.approx(0.0, abs=1e-6) and stage == 1  # the box soft, the stop row held
