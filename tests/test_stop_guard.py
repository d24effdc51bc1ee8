"""The filter's brake and its stop-path guard against independent facts:
the brake walked one update at a time (limits, no reversal from a state
that can stop without one), and the guard's verdict against Drake's
distances along the whole stop, on the two-link arm of test_safety."""

import numpy as np
import pytest
from test_safety import _arm, _drake_distance, _fix

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
    ctx = diagram.CreateDefaultContext()
    sctx = sf.GetMyContextFromRoot(ctx)
    _fix(diagram, ctx, [0.0, 0.0])
    rng = np.random.default_rng(7 if obstacle == "wall" else 8)
    kept = refused = 0
    low, high = ([-0.3, -1.2], [1.2, 1.2]) if obstacle == "wall" else ([-np.pi, 2.0], [np.pi, 3.0])
    for _ in range(20000):
        if kept + refused == 40:
            break
        q = rng.uniform(low, high)
        sf.set_initial_position(sctx, q)
        d_now = _drake_distance(diagram, ctx, tip, obs)
        if not 0.005 < d_now < (0.12 if obstacle == "wall" else 0.05):
            continue
        rows = sf.damper_rows(sctx)
        v_last = rng.uniform(-1, 1, 2) * sf.velocity_limits * 0.8
        v = v_last + rng.uniform(-1, 1, 2) * np.array([6.0, 8.0]) * h
        ok = sf.stop_is_clear(rows, q, q, v, v_last)
        path = sf.stop_path(q, v, v_last)
        points = np.concatenate([path, 0.5 * (path[1:] + path[:-1])])
        dists = []
        for x in points:
            sf.set_initial_position(sctx, x)
            dists.append(_drake_distance(diagram, ctx, tip, obs))
        threshold = min(sf.clearance - sf.GUARD_BAND * sf.allowance, d_now)
        if ok:
            kept += 1
            assert min(dists) >= threshold - 1e-9
        else:
            refused += 1
            if obstacle == "wall":
                assert min(dists) < threshold + 1e-4
    assert kept >= 5 and refused >= 5  # both verdicts were tried
