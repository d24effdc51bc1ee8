"""The region tests' broad phase (lever-arm balls at the region's centre)
and cell-by-cell hulls: never free where Drake finds a collision in the
region, and bounds at least as wide as the whole-grid hull test gave."""

import numpy as np
import pytest

from drake_cfvol import kernel as K
from drake_cfvol.algorithm.sweep import no_memo
from drake_cfvol.kernel.heightfield import no_height_field
from drake_cfvol.kernel.regions import _region_workspace
from drake_cfvol.kernel.spheres import ball_apart_row
from drake_cfvol.kernel.swept import region_quick_free
from drake_cfvol.kernel.types import ROW_E_ISO
from drake_cfvol.scene.covers import robot_covers

#: Sweep inputs and bounds recorded from the kernel before sphere covers and
#: cell-by-cell hulls (commit e475662, R = 1000, seed 0): the regression
#: baseline for "at least today's widths".
BEFORE = "tests/data/sweep_before_v3.npz"


def _recorded(case):
    d = np.load(BEFORE)
    g = {k.split("/", 1)[1]: d[k] for k in d.files if k.startswith(case + "/")}
    chain = K.Chain(*(g["chain." + n] for n in K.Chain._fields))
    fields = {n: g["model." + n] for n in K.Model._fields[1:14]}
    spheres, ranges = robot_covers(fields["shapes"], fields["verts"])
    m = K.Model(chain, *fields.values(), spheres, ranges)
    field = K.HeightField(g["table"], *map(float, g["grid"]))
    return g, m, field


@pytest.mark.parametrize("case", ["automotive_path1", "aerospace_path1"])
def test_bounds_at_least_as_wide_as_the_whole_grid_hull(case):
    """On the recorded inputs, every bound is at least the recorded one
    less the search's delta (the searches' steps differ, each stops within
    delta of its true end)."""
    g, m, field = _recorded(case)
    bounds, tests, _ = K.sweep_chains(
        g["chains"],
        (g["lim_lo"], g["lim_hi"], g["delta"]),
        g["nts"],
        g["v_steps"],
        g["W"],
        m,
        field,
        g["pads"],
        g["guesses"],
        *no_memo(),
    )
    sign = g["chains"][:, 1][:, None].astype(float)
    gain = sign * (bounds - g["bounds"])
    delta = g["delta"][g["chains"][:, 0]][:, None]
    assert np.all(gain >= -delta - 1e-9), f"narrower by {(-gain - delta).max():.4f} past delta"


def test_ball_against_a_box_by_hand():
    """A ball against a rotated box: apart exactly when its centre is
    farther than its radius from the box (distance worked by hand)."""
    row = np.zeros(K.SHAPE_W)
    row[K.ROW_KIND] = K.BOX
    c, s = np.cos(0.3), np.sin(0.3)
    R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    row[K.ROW_CENTRE : K.ROW_CENTRE + 3] = (1.0, 2.0, 0.5)
    row[K.ROW_ROTATION : K.ROW_ROTATION + 9] = R.ravel()
    row[K.ROW_SIZE : K.ROW_SIZE + 3] = (0.5, 0.2, 0.5)
    aabb = np.zeros(6)
    K.row_aabb(row, np.zeros((0, 3)), aabb)
    # 0.3 m beyond the +x face and 0.4 m beyond the +y face: 0.5 m away.
    x = np.array([1.0, 2.0, 0.5]) + R @ np.array([0.8, 0.6, 0.0])
    assert ball_apart_row(*x, 0.49, row, aabb)
    assert not ball_apart_row(*x, 0.51, row, aabb)
    row[ROW_E_ISO] = 0.02  # the row's inflation counts
    assert not ball_apart_row(*x, 0.49, row, aabb)


@pytest.mark.parametrize("cell", [pytest.param("automotive", marks=pytest.mark.slow), "mesh"])  # automotive: 5 s
def test_quick_pass_never_frees_a_colliding_region(cell, request):
    """Random regions (a stretch of two random free configurations with one
    joint swept): wherever the broad phase calls a region free, Drake's
    padded checker finds every configuration of a dense grid over it free."""
    if cell == "mesh":
        import drake_cfvol as cf

        wc = cf.load_workcell("tests/data/mesh_cell.yaml")
    else:
        wc = request.getfixturevalue(cell)
    m = wc.scene_arrays().model
    k = wc.num_joints
    rs = _region_workspace(
        m.chain.parent.shape[0], k, m.obstacles.shape[0], m.shapes, m.verts, m.spheres, m.shape_spheres
    )
    rng = np.random.default_rng(0)
    lo, hi = wc.position_lower, wc.position_upper
    checker = wc.padded_checker(0.02)
    freed, tried, checked = 0, 0, []
    while tried < 300:
        a = rng.uniform(lo, hi)
        b = np.clip(a + rng.normal(scale=0.01, size=k), lo, hi)
        # The region test takes the nominal stretch as free (it tests what
        # joint j moves): draw stretches Drake finds free at 11 points.
        if not all(checker.CheckConfigsCollisionFree(a + np.linspace(0, 1, 11)[:, None] * (b - a))):
            continue
        tried += 1
        j = int(rng.integers(k))
        va = a[j]
        vb = min(va + rng.uniform(0.002, 0.03), hi[j])
        W = np.stack([a, b])
        if not region_quick_free(W, 0, j, (0.0, 1.0, 5), (va, vb, 9), m, no_height_field(), rs, 0.02):
            continue
        freed += 1
        t, v = np.meshgrid(np.linspace(0, 1, 11), np.linspace(va, vb, 11))
        Q = a + t.reshape(-1, 1) * (b - a)
        Q[:, j] = v.ravel()
        checked.append(Q)
    assert freed >= 10, "too few regions decided to say anything"
    Q = np.concatenate(checked)
    free = np.array(checker.CheckConfigsCollisionFree(Q, parallelize=True), bool)
    assert free.all(), f"{(~free).sum()} colliding configurations in regions called free"


@pytest.mark.parametrize("cell", ["automotive", "mesh"])
def test_the_whole_region_test_never_frees_a_colliding_region(cell, request):
    """The whole region test (the broad phase, the scene cell by cell, the
    self pairs with their cover balls over each cell before GJK) on random
    regions anywhere in the joint limits, where the robot often nears
    itself: wherever it calls a region free, Drake's padded checker (self
    pairs included) finds a dense grid over it free. Both verdicts occur."""
    from drake_cfvol.algorithm.certificate.boundary_regions import regions_may_collide

    if cell == "mesh":
        import drake_cfvol as cf

        wc = cf.load_workcell("tests/data/mesh_cell.yaml")
    else:
        wc = request.getfixturevalue(cell)
    k = wc.num_joints
    rng = np.random.default_rng(3)
    lo, hi = wc.position_lower, wc.position_upper
    checker = wc.padded_checker(0.02)
    A, B, js, va, vb = [], [], [], [], []
    while len(js) < 200:
        a = rng.uniform(lo, hi)
        b = np.clip(a + rng.normal(scale=0.02, size=k), lo, hi)
        if not all(checker.CheckConfigsCollisionFree(a + np.linspace(0, 1, 11)[:, None] * (b - a))):
            continue
        j = int(rng.integers(k))
        A.append(a), B.append(b), js.append(j), va.append(a[j])
        vb.append(min(a[j] + rng.uniform(0.05, 0.6), hi[j]))
    A, B, js, va, vb = map(np.array, (A, B, js, va, vb))
    hit = regions_may_collide(wc.scene_arrays(), A, B, js, va, vb, 0.02)
    assert 10 <= (~hit).sum() and 10 <= hit.sum(), "both verdicts, or the test says nothing"
    t, v = np.meshgrid(np.linspace(0, 1, 11), np.linspace(0, 1, 21))
    Q = []
    for n in np.flatnonzero(~hit):
        q = A[n] + t.reshape(-1, 1) * (B[n] - A[n])
        q[:, js[n]] = va[n] + v.ravel() * (vb[n] - va[n])
        Q.append(q)
    free = np.array(checker.CheckConfigsCollisionFree(np.concatenate(Q), parallelize=True), bool)
    assert free.all(), f"{(~free).sum()} colliding configurations in regions called free"


def _two_finger_model():
    """A fixed palm with two fingers on revolute joints about z, 0.4 m apart
    along x (a tree): finger 0 a 4 cm knuckle on its joint, finger 1 a box
    from 0.3 to 0.45 m along -x from its joint (towards finger 0 at 0 rad);
    the fingers are a self pair."""
    eye = np.eye(3)
    chain = K.Chain(
        np.array([-1, -1], np.int64),
        np.array([1, 1], np.int64),
        np.array([0, 1], np.int64),
        np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]]),
        np.stack([eye, eye]),
        np.array([[0.0, 0.0, 0.0], [0.4, 0.0, 0.0]]),
        np.stack([eye, eye]),
        np.zeros((2, 3)),
    )
    shapes = np.zeros((2, K.SHAPE_W))
    shapes[:, K.ROW_KIND] = K.BOX
    shapes[:, K.ROW_ROTATION : K.ROW_ROTATION + 9] = eye.ravel()
    shapes[0, K.ROW_SIZE : K.ROW_SIZE + 3] = (0.02, 0.02, 0.02)
    shapes[1, K.ROW_SIZE : K.ROW_SIZE + 3] = (0.075, 0.02, 0.02)
    shapes[1, K.ROW_CENTRE : K.ROW_CENTRE + 3] = (-0.375, 0.0, 0.0)
    verts = np.zeros((0, 3))
    spheres, ranges = robot_covers(shapes, verts)
    moved = np.array([[True, False], [False, True]])
    reach = np.array([[0.03, 0.0], [0.0, 0.46]])
    curvature = np.zeros((2, 2, 2))
    curvature[0, 0, 0], curvature[1, 1, 1] = 0.03, 0.46
    return K.Model(
        chain,
        shapes,
        np.array([0, 1], np.int64),
        verts,
        np.zeros((0, K.SHAPE_W)),
        np.zeros((0, 6)),
        np.array([[0, 1]], np.int64),
        np.array([[0, 1]], np.int64),
        np.array([True, True]),
        moved,
        reach,
        curvature,
        np.array([True, True]),
        np.array([0, 1], np.int64),
        spheres,
        ranges,
    )


def test_a_moving_second_branch_is_never_called_free():
    """Two fingers of a tree: the knuckle (finger 0, swept 0-0.04 rad) sits
    0.4 m from finger 1's joint while the stretch turns finger 1 from -1 to
    +1 rad. At 0 rad finger 1 covers x in [-0.05, 0.1] on y = 0, over the
    knuckle (by hand); at the stretch's two grid poses (+-1 rad), seen from
    finger 1, the knuckle sits 0.4 cos 1 = 0.22 m from its joint, short of
    the box that starts at 0.3 m, so the grid's hull misses what the arc
    hits: the region may collide. With finger 1 held at -1 rad the same
    sweep is proven free (the test does not simply always fail)."""
    m = _two_finger_model()
    one = np.ones(1, np.int64)

    def hit(b1):
        return K.regions_hit(
            np.array([[0.0, -1.0]]),
            np.array([[0.0, b1]]),
            np.zeros(1, np.int64),
            np.array([0.0]),
            np.array([0.04]),
            2 * one,
            2 * one,
            np.zeros(1),
            m,
        )[0]

    assert hit(1.0)
    assert not hit(-1.0)
