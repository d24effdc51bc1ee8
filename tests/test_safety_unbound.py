"""The safety filter's unmeasured pairs (drake_cfvol.systems.filter.unbound)
against independent facts: a twin filter that measures every pair at every
update (its commands, and the rows it keeps), the discrete update's
braking walked step by step, and Drake's normals of boxes moved at random."""

import numpy as np
import pytest
from pydrake.common.eigen_geometry import AngleAxis
from pydrake.geometry import (
    Box,
    FramePoseVector,
    GeometryFrame,
    GeometryInstance,
    MakePhongIllustrationProperties,
    ProximityProperties,
    SceneGraph,
)
from pydrake.math import RigidTransform, RollPitchYaw, RotationMatrix
from pydrake.systems.analysis import Simulator
from test_braking import _walked
from test_safety import L1, L2, _arm, _drake_distance, _fix

from drake_cfvol.systems.filter.filter_kernel import stop_distance
from drake_cfvol.systems.filter.unbound import normal_cone, stop_at_most

ACC, JERK = np.array([1.5, 2.0]), np.array([40.0, 50.0])  # low: the filter brakes from far out


def _twins(period, obstacle="wall"):
    """The two-link arm twice: a filter that may skip pairs, and one that
    measures every pair at every update (``skip_far_pairs=False``)."""
    kw = dict(clearance=0.02, period=period, acceleration_limits=ACC, jerk_limits=JERK)
    return _arm(obstacle, **kw), _arm(obstacle, skip_far_pairs=False, **kw)


class _Run:
    """Both twins simulated update by update: per update, whether the
    skipping filter left the pair unmeasured, which pairs the twin kept
    rows of, both commands and statuses."""

    def __init__(self, twins, start):
        self.twins = twins
        self.sims = [Simulator(t[0]) for t in twins]
        self.kept: set = set()
        for (diagram, sf, _, _), sim in zip(twins, self.sims):
            sf.set_initial_position(sf.GetMyMutableContextFromRoot(sim.get_mutable_context()), start)
        sf_b = twins[1][1]
        braked = sf_b._braked_rows

        def spy(rows, *args):
            out = braked(rows, *args)
            self.kept |= set(out.pair.tolist())
            return out

        sf_b._braked_rows = spy  # the rows the twin measuring everything keeps
        self.n = 0

    def fix(self, *args, **kw):
        for (diagram, *_), sim in zip(self.twins, self.sims):
            _fix(diagram, sim.get_mutable_context(), *args, **kw)

    def step(self, period):
        """One update of both: (skipped, kept by the twin, commands equal,
        statuses equal but min_distance, Drake's distance)."""
        self.n += 1
        self.kept = set()
        out = []
        for (diagram, sf, tip, wall), sim in zip(self.twins, self.sims):
            sim.AdvanceTo((self.n + 0.5) * period)
            ctx = sf.GetMyContextFromRoot(sim.get_context())
            self.q, self.v = sf.commanded_position_output.Eval(ctx), sf.commanded_velocity_output.Eval(ctx)
            status = [sf.GetOutputPort(name).Eval(ctx)[0] for name in ("filter_count", "damper_misses", "box_exits")]
            out.append(
                (
                    sf.commanded_position_output.Eval(ctx).copy(),
                    sf.commanded_velocity_output.Eval(ctx).copy(),
                    status + [sf.GetOutputPort("braking_faults").Eval(ctx)[0]],
                    sf.min_distance_output.Eval(ctx)[0],
                    ctx.get_discrete_state(sf._last).get_value()[-1],  # updates skipped in a row (one pair)
                )
            )
        (qa, va, sa, da, skipped), (qb, vb, sb, db, _) = out
        same = np.array_equal(qa, qb) and np.array_equal(va, vb) and sa == sb
        diagram, _, tip, wall = self.twins[1]
        return (
            skipped >= 1,
            0 in self.kept,
            same,
            (da, db),
            _drake_distance(diagram, self.sims[1].get_context(), tip, wall),
        )


@pytest.mark.parametrize("period", [0.01, 0.001])
def test_a_tip_swung_at_the_wall_is_measured_again_before_its_row_can_bind(period):
    """The tip swung at the wall from 0.54 m with low limits (it needs
    about 0.6 m to stop): while it is far the pair is left unmeasured, and
    it is measured again before the twin that measures at every update
    keeps a row of it. The commands are the twin's bit for bit, and
    min_distance too below the influence distance."""
    run = _Run(_twins(period), np.array([1.2, 0.3]))
    run.fix([-0.6, 0.0], nominal=[1.2, 0.3])  # deep in the wall
    first_kept, skips, last_skip, fastest = None, 0, None, 0.0
    for n in range(int(round(2.0 / period))):
        skipped, kept, same, (da, db), drake = run.step(period)
        assert same, n
        assert not (skipped and kept), n  # a skipped pair's rows would all have been dropped
        if skipped:
            skips, last_skip = skips + 1, n
            assert drake > 0.15  # beyond the influence distance
            q, v = run.q, run.v  # the tip's speed towards the wall (+x), by hand
            fastest = max(fastest, -L1 * np.sin(q[0]) * v[0] - L2 * np.sin(q[0] + q[1]) * (v[0] + v[1]))
        if db < 0.15:
            assert da == db
        if kept and first_kept is None:
            first_kept = n
    print(
        f"{period}: skipped {skips}, the last at {last_skip}, a row kept from {first_kept}; tip up to {fastest:.2f} m/s"
    )
    assert first_kept is not None and skips > 0 and last_skip < first_kept
    assert fastest > 0.3  # skipped while closing in, not only at rest


@pytest.mark.slow
@pytest.mark.parametrize("obstacle", ["wall", "column"])
@pytest.mark.parametrize("period", [0.01, 0.001])
def test_random_pushes_command_the_same_with_and_without_skipping(obstacle, period):
    """Random desired positions that jump every 0.1 s, boxes that move and
    change width (three seeds): the filter that skips pairs commands what
    the twin measuring every pair commands, bit for bit, at every update,
    and keeps no row of a pair it skipped."""
    skips, updates = 0, 0
    for seed in range(3):
        rng = np.random.default_rng(seed)
        start = np.array([1.2, 0.3]) if obstacle == "wall" else np.array([0.0, 1.0])
        run = _Run(_twins(period, obstacle), start)
        centre, width = start.copy(), np.array([2.0, 2.0])
        for _ in range(12):
            desired = rng.uniform(-1.5, 1.5, 2)
            centre = centre + rng.uniform(-0.3, 0.3, 2)
            width = np.clip(width + rng.uniform(-0.6, 0.6, 2), 0.05, 3.0)
            run.fix(desired, centre - width / 2, centre + width / 2, nominal=centre)
            for _ in range(int(round(0.1 / period))):
                skipped, kept, same, (da, db), _ = run.step(period)
                assert same and not (skipped and kept)
                assert da == db or min(da, db) >= 0.15
                skips, updates = skips + skipped, updates + 1
    print(f"{obstacle} {period}: skipped at {skips} of {updates} updates")
    assert skips > 0


def test_the_stop_bound_holds_the_discrete_update_walked_step_by_step():
    """A row's stop (its closing speed s, acceleration alpha, and the row's
    share of the arm's deceleration a and jerk j), walked step by step,
    never exceeds the closed-form bound from the ratios alone: s' = s +
    alpha tau_w / 2, s' (tau_w + tau + dt) + s' (sigma + ratio tau_w / 2) / 2."""
    rng = np.random.default_rng(3)
    for _ in range(2000):
        h = rng.choice([0.001, 0.01])
        acc = rng.uniform(0.5, 30.0)
        jerk = np.inf if rng.random() < 0.2 else acc / rng.uniform(0.005, 0.1)
        s = rng.uniform(0.0, 3.0)
        alpha = rng.uniform(-acc, 2.0 * acc)
        tau_w = 0.0 if not np.isfinite(jerk) else max(alpha, 0.0) / jerk * rng.uniform(1.0, 2.0)
        tau = 0.0 if not np.isfinite(jerk) else acc / jerk
        sigma = s / acc * rng.uniform(1.0, 2.0)
        ratio = max(alpha, 0.0) / acc * rng.uniform(1.0, 2.0)
        top = s + 0.5 * max(alpha, 0.0) * tau_w
        walked = _walked(s, alpha, acc, jerk, h)
        assert walked <= stop_at_most(top, tau_w, tau, sigma, ratio, h) + 1e-12
        assert stop_distance(s, alpha, acc, jerk, h) == pytest.approx(walked, rel=1e-9, abs=1e-12)


def _two_boxes():
    """A SceneGraph with a fixed box and a box on a frame posed by a fixed
    input: (scene graph, context, the source's pose port, frame, ids)."""
    sg = SceneGraph()
    source = sg.RegisterSource("test")
    frame = sg.RegisterFrame(source, GeometryFrame("moving"))
    props = ProximityProperties()
    moving = sg.RegisterGeometry(source, frame, GeometryInstance(RigidTransform(), Box(0.4, 0.2, 0.1), "moving"))
    fixed = sg.RegisterAnchoredGeometry(source, GeometryInstance(RigidTransform(), Box(1.0, 0.6, 0.3), "fixed"))
    for g in (moving, fixed):
        sg.AssignRole(source, g, props)
        sg.AssignRole(source, g, MakePhongIllustrationProperties([0.5, 0.5, 0.5, 1.0]))
    ctx = sg.CreateDefaultContext()
    return sg, ctx, sg.get_source_pose_port(source), frame, (moving, fixed)


def _pair(sg, ctx, port, frame, ids, X):
    poses = FramePoseVector()
    poses.set_value(frame, X)
    port.FixValue(ctx, poses)
    return sg.get_query_output_port().Eval(ctx).ComputeSignedDistancePairClosestPoints(*ids)


def test_drakes_normal_after_a_move_lies_in_the_cone():
    """A box moved at random (every point by at most delta: |dp| + turn x
    radius) from a pose at distance d0 from a fixed box: Drake's normal
    after the move lies within normal_cone(d0, d0 - delta) of the one
    before, and its distance is at least d0 - delta."""
    sg, ctx, port, frame, ids = _two_boxes()
    rng = np.random.default_rng(7)
    radius = np.linalg.norm([0.2, 0.1, 0.05])
    widest = 0.0
    for _ in range(400):
        p = rng.uniform(-1.5, 1.5, 3)
        X0 = RigidTransform(RollPitchYaw(rng.uniform(-np.pi, np.pi, 3)), p)
        before = _pair(sg, ctx, port, frame, ids, X0)
        if before.distance < 0.05:
            continue
        turn, shift, axis = rng.uniform(0, 0.3), rng.normal(size=3), rng.normal(size=3)
        shift *= rng.uniform(0, 0.2) / np.linalg.norm(shift)
        R = RotationMatrix(AngleAxis(turn, axis / np.linalg.norm(axis)))
        X1 = RigidTransform(R.multiply(X0.rotation()), p + shift)  # turned about its centre, then shifted
        delta = np.linalg.norm(shift) + turn * radius
        lower = before.distance - delta
        if lower <= 0.0:
            continue
        after = _pair(sg, ctx, port, frame, ids, X1)
        assert after.distance >= lower - 1e-9
        angle = np.arccos(np.clip(np.dot(before.nhat_BA_W, after.nhat_BA_W), -1.0, 1.0))
        bound = normal_cone(before.distance, lower, 1e-5)  # Drake's box-box tolerance, well within
        assert angle <= bound + 1e-9
        widest = max(widest, angle / bound if bound > 0 else 0.0)
    assert widest > 0.2  # the bound is not vacuous
