"""Joint bounding on the compiled kernel: single-joint safety at every s
(checked by Drake's own checker of the real scene), the rate limit, and
agreement with the Drake reference backend."""

import numpy as np
import pytest
from pydrake.planning import SceneGraphCollisionChecker

import drake_cfvol as cf

#: Joint step between the configurations checked along a motion, rad or m.
CHECK_STEP = 0.01


def independent_checker(wc):
    """A Drake checker of the real scene, built apart from the library's."""
    return SceneGraphCollisionChecker(
        model=wc.diagram,
        robot_model_instances=[wc.robot],
        edge_step_size=0.01,
        env_collision_padding=0.0,
        self_collision_padding=0.0,
    )


def single_joint_violations(wc, table, s_values, checker, step=CHECK_STEP):
    """For each s and joint and direction, configurations from the nominal
    at s to the bound at s, joint j alone, every ``step``; returns the
    (s, joint, direction, value) of every colliding one (Drake)."""
    lo, hi, nom = table.boxes_at(np.asarray(s_values, float))
    configs, labels = [], []
    for n, s in enumerate(s_values):
        for j in range(table.k):
            for sign, end in ((+1, hi[n, j]), (-1, lo[n, j])):
                span = abs(end - nom[n, j])
                t = np.r_[np.arange(step, span, step), span] if span > 0 else np.zeros(0)
                Q = np.repeat(nom[n][None], len(t), axis=0)
                Q[:, j] = nom[n, j] + sign * t
                configs.append(Q)
                labels += [(float(s), j, sign, float(v)) for v in Q[:, j]]
    Q = np.concatenate(configs)
    free = np.array(checker.CheckConfigsCollisionFree(Q, parallelize=True), bool)
    return [labels[i] for i in np.flatnonzero(~free)]


@pytest.mark.slow  # 5 s; the slow group also checks all six paths
def test_single_joint_safety_between_waypoints(automotive, bounded):
    """Moving one joint alone from the interpolated nominal to its bound is
    free at s = i + 1/2 for every stretch (every s = i + m/10 of all six
    paths in the slow group), checked by an independent Drake checker."""
    table = bounded("automotive", "path1", 1000)
    s = np.arange(table.g - 1) + 0.5
    bad = single_joint_violations(automotive, table, s, independent_checker(automotive))
    assert not bad, f"{len(bad)} colliding configurations, e.g. {bad[:3]}"


@pytest.mark.slow
@pytest.mark.parametrize("cell", ["automotive", "aerospace"])
@pytest.mark.parametrize("label", ["path1", "path2", "path3"])
def test_single_joint_safety_every_stretch_all_paths(cell, label, request, planned):
    """The engine issue's check: every stretch, s = i + m/10 for m = 0 and
    5 (the default group checks m = 5 on automotive path 1), all six
    built-in paths at R = 1000, against Drake's real scene."""
    wc = request.getfixturevalue(cell)
    table = cf.estimate_bounds(wc, planned(cell, label), resolution=1000)
    s = np.concatenate([np.arange(table.g - 1) + m / 10 for m in (0, 5)])
    bad = single_joint_violations(wc, table, s, independent_checker(wc), step=0.02)
    assert not bad, f"{len(bad)} colliding configurations, e.g. {bad[:3]}"


def test_bounds_change_at_most_at_their_rate(bounded):
    """|bound(s1) - bound(s2)| <= rate |s1 - s2| along the whole path, and
    the rate limit only tightens: each box lies inside its stretch's
    certified box (or is the nominal itself)."""
    table = bounded("automotive", "path1", 1000)
    assert np.all(np.isfinite(table.rate)) and np.all(table.rate > 0)
    s = np.linspace(0, table.g - 1, 20 * (table.g - 1) + 1)
    lo, hi, nom = table.boxes_at(s)
    ds = np.diff(s)[:, None]
    assert np.all(np.abs(np.diff(hi, axis=0)) <= table.rate * ds + 1e-9)
    assert np.all(np.abs(np.diff(lo, axis=0)) <= table.rate * ds + 1e-9)
    i = np.clip(np.floor(s).astype(int), 0, table.g - 2)
    assert np.all(hi <= np.maximum(table.stretch_upper[i], nom) + 1e-12)
    assert np.all(lo >= np.minimum(table.stretch_lower[i], nom) - 1e-12)
    assert np.all((lo <= nom + 1e-12) & (nom <= hi + 1e-12))


def test_rate_comes_from_velocity_limits(automotive, planned):
    """With a given time per waypoint, the rate is velocity limit x time."""
    path = planned("automotive")
    table = cf.estimate_bounds(automotive, path, resolution=300, waypoint_time=0.1)
    np.testing.assert_allclose(
        table.rate, np.maximum(automotive.velocity_limits * 0.1, np.abs(np.diff(path.waypoints, axis=0)).max(axis=0))
    )


@pytest.mark.slow
def test_waypoint_boxes_within_reference_backend(automotive, planned):
    """Each fast waypoint bound lies inside the Drake reference's bound
    (which samples single-joint motions at delta against one SceneGraph box
    per column), to within delta: the kernel is conservative, never wider."""
    path = planned("automotive", "path1")
    # At clearance 0: the reference pads every waypoint alike, where the
    # fast bounds lower a stretch's margin to the nominal's own clearance.
    fast = cf.estimate_bounds(automotive, path, resolution=400, clearance=0.0)
    ref = cf.estimate_bounds(automotive, path, resolution=400, backend="drake", clearance=0.0)
    delta = fast.params["delta"]
    assert np.all(fast.upper <= ref.upper + delta + 1e-9)
    assert np.all(fast.lower >= ref.lower - delta - 1e-9)
    # ... and not needlessly narrow: most of the reference's width is kept.
    assert (fast.upper - fast.lower).sum() >= 0.6 * (ref.upper - ref.lower).sum()
