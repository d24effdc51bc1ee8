"""The fast conservative checks against Drake's checker (the reference)."""

import numpy as np
import pytest

from drake_cfvol.collision import SceneTester, obb_overlap
from drake_cfvol.reference import ReferenceScene
import drake_cfvol as cf


def _random_rotations(n, rng):
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1)], 1)


def test_box_overlap_never_misses():
    """The separating-axis test finds every overlap that point sampling finds."""
    rng = np.random.default_rng(0)
    n = 3000
    cA, cB = rng.uniform(-1, 1, (n, 3)), rng.uniform(-1, 1, (n, 3))
    RA, RB = _random_rotations(n, rng), _random_rotations(n, rng)
    hA, hB = rng.uniform(0.05, 0.6, (n, 3)), rng.uniform(0.05, 0.6, (n, 3))
    ov = obb_overlap(cA, RA, hA, cB, RB, hB, 0.0)
    pts = rng.uniform(-1, 1, (n, 300, 3)) * hA[:, None]
    world = np.einsum("nij,nsj->nsi", RA, pts) + cA[:, None]
    local = np.einsum("nji,nsj->nsi", RB, world - cB[:, None])
    sampled = (np.abs(local) <= hB[:, None]).all(-1).any(-1)
    assert sampled.sum() > 300 and not np.any(sampled & ~ov)


@pytest.mark.parametrize("cell", ["automotive", "aerospace"])
def test_obstacles_and_self_never_missed(cell, request):
    """On 2000 random configurations, the fast test reports every collision
    Drake reports (obstacles + self); the conservative rate is small."""
    wc = request.getfixturevalue(cell)
    model = wc.robot_geometry()
    tester = SceneTester(model, wc.obstacle_boxes())
    Q = np.random.default_rng(3).uniform(wc.position_lower, wc.position_upper, (2000, wc.num_joints))
    R, p = model.batch_poses(wc, Q)
    fast = tester.hits(R, p, np.zeros(R.shape[:2]), model.moved_by.any(axis=0))
    drake = ~np.array(wc.checker.CheckConfigsCollisionFree(Q), bool)
    assert drake.sum() > 200
    assert not np.any(drake & ~fast)
    assert (fast & ~drake).sum() / len(Q) < 0.05


def test_volume_check_never_reports_free_where_drake_collides(automotive, bounded):
    """Thousands of configurations near the volume's surface (uniform in and
    just past the per-joint bounds): where Drake finds the robot touching a
    column, the fast check reports it too. Conservative rate printed."""
    wc = automotive
    table = bounded("automotive", "path1", 1000)
    path = cf.NominalPath(table.nominal, table.joint_names)
    vol = table.volume.volume
    scene = ReferenceScene(wc, vol)
    rng = np.random.default_rng(7)
    idx = rng.integers(0, path.g, 2500)
    span = table.upper[idx] - table.lower[idx]
    Q = table.lower[idx] - 0.15 * span + rng.random((2500, wc.num_joints)) * 1.3 * span
    Q = np.clip(Q, wc.position_lower, wc.position_upper)
    model = wc.robot_geometry()
    R, p = model.batch_poses(wc, Q)
    fast = SceneTester(model, None, vol).hits(R, p, np.zeros(R.shape[:2]), model.moved_by.any(axis=0),
                                              self_collision=False)
    drake = scene.volume_hits(Q)
    print(f"\nvolume: drake hits {drake.sum()}, fast hits {fast.sum()}, "
          f"conservative rate {(fast & ~drake).mean():.3f}")
    assert drake.sum() > 100
    assert not np.any(drake & ~fast)
