"""Sphere covers of the robot's shapes: checked against every hull vertex
and against points drawn inside each shape, by hand on a box, and the
kernel's placed balls against Drake's body poses."""

import numpy as np
import pytest

from drake_cfvol import kernel as K
from drake_cfvol.exceptions import WorkcellError
from drake_cfvol.kernel.spheres import place_balls
from drake_cfvol.kernel.types import ROW_E_ISO
from drake_cfvol.scene.covers import MAX_SLABS, check_cover, shape_cover

MESH_CELL = "tests/data/mesh_cell.yaml"


@pytest.fixture(scope="module")
def mesh_cell():
    import drake_cfvol as cf

    return cf.load_workcell(MESH_CELL)


def _row(kind, size, R=np.eye(3), c=(0.0, 0.0, 0.0), inflation=0.0):
    row = np.zeros(K.SHAPE_W)
    row[K.ROW_KIND] = kind
    row[K.ROW_CENTRE : K.ROW_CENTRE + 3] = c
    row[K.ROW_ROTATION : K.ROW_ROTATION + 9] = np.asarray(R).ravel()
    row[K.ROW_SIZE : K.ROW_SIZE + 3] = size
    row[ROW_E_ISO] = inflation
    return row


def _points_inside(row, verts, n, rng):
    """n points drawn inside the shape (its own geometry, not the cover's),
    in the row's parent frame."""
    kind = int(row[K.ROW_KIND])
    s = row[K.ROW_SIZE : K.ROW_SIZE + 3]
    if kind == K.HULL:
        V = verts[int(row[K.ROW_FIRST_VERTEX]) : int(row[K.ROW_END_VERTEX])]
        w = rng.dirichlet(np.full(len(V), 0.3), n)
        local = w @ V
    elif kind == K.BOX:
        local = rng.uniform(-1, 1, (n, 3)) * s
    elif kind == K.ELLIPSOID:
        u = rng.normal(size=(n, 3))
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        local = u * rng.random((n, 1)) ** (1 / 3) * s
    else:  # sphere, capsule, cylinder: a point of the axis plus a radial offset
        r, h = s[0], (0.0 if kind == K.SPHERE else s[1])
        u = rng.normal(size=(n, 3))
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        z = rng.uniform(-h, h, n)
        if kind == K.CYLINDER:
            u[:, 2] = 0.0
            u /= np.maximum(np.linalg.norm(u, axis=1, keepdims=True), 1e-12)
        local = u * r * rng.random((n, 1)) ** 0.5
        local[:, 2] += z
        if kind == K.CYLINDER:  # points on the end discs too
            local[: n // 4, 2] = np.sign(z[: n // 4] + 1e-12) * h
    # ... grown by the inflation in a random direction
    g = rng.normal(size=(n, 3))
    g /= np.linalg.norm(g, axis=1, keepdims=True)
    local = local + g * row[ROW_E_ISO] * rng.random((n, 1))
    R = row[K.ROW_ROTATION : K.ROW_ROTATION + 9].reshape(3, 3)
    return row[K.ROW_CENTRE : K.ROW_CENTRE + 3] + local @ R.T


def _outside(points, cover):
    d = np.linalg.norm(points[:, None, :] - cover[None, :, :3], axis=2) - cover[None, :, 3]
    return d.min(axis=1)


@pytest.mark.parametrize("cell", ["automotive", "aerospace", "mesh"])
def test_covers_contain_every_vertex_and_points_inside(cell, request, mesh_cell):
    """Every shape of the built-in robots and of the mesh robot lies in its
    cover: every hull vertex (the build's own check), and 4000 points drawn
    inside each shape, inflation included."""
    wc = mesh_cell if cell == "mesh" else request.getfixturevalue(cell)
    arrays = wc.scene_arrays()
    spheres, ranges = arrays.covers
    rng = np.random.default_rng(0)
    assert len(ranges) == len(arrays.shapes)
    kinds = set()
    for s, row in enumerate(arrays.shapes):
        cover = spheres[ranges[s, 0] : ranges[s, 1]]
        assert 1 <= len(cover) <= MAX_SLABS
        kinds.add(int(row[K.ROW_KIND]))
        if int(row[K.ROW_KIND]) == K.HULL:  # the vertices themselves, by hand
            V = arrays.verts[int(row[K.ROW_FIRST_VERTEX]) : int(row[K.ROW_END_VERTEX])]
            R = row[K.ROW_ROTATION : K.ROW_ROTATION + 9].reshape(3, 3)
            assert _outside(row[K.ROW_CENTRE : K.ROW_CENTRE + 3] + V @ R.T, cover).max() <= 0.0
        assert _outside(_points_inside(row, arrays.verts, 4000, rng), cover).max() <= 0.0
    if cell == "mesh":
        assert K.HULL in kinds


@pytest.mark.parametrize("kind", [K.BOX, K.SPHERE, K.CAPSULE, K.CYLINDER, K.ELLIPSOID])
def test_primitive_covers_contain_points_inside(kind):
    """Each primitive kind, rotated, offset and inflated, lies in its cover."""
    rng = np.random.default_rng(1)
    Q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    row = _row(kind, (0.3, 0.7, 0.12), R=Q, c=(0.4, -0.2, 1.0), inflation=0.015)
    cover = shape_cover(row, np.zeros((0, 3)))
    check_cover(row, np.zeros((0, 3)), cover)
    assert _outside(_points_inside(row, np.zeros((0, 3)), 20000, rng), cover).max() <= 0.0


def test_box_cover_by_hand():
    """A 2 x 1 x 1 m box: the longest cell side is split while at most 8
    cells result (3 x 2 x 1 -> cells of 2/3 x 1/2 x 1), each in the ball
    through its corners."""
    cover = shape_cover(_row(K.BOX, (1.0, 0.5, 0.5)), np.zeros((0, 3)))
    assert len(cover) == 6
    np.testing.assert_allclose(cover[:, 3], np.linalg.norm([2 / 3, 1 / 2, 1]) / 2, atol=1e-8)
    np.testing.assert_allclose(sorted(set(np.round(cover[:, 0], 9))), [-2 / 3, 0, 2 / 3], atol=1e-9)


def test_hull_cover_of_a_long_prism():
    """A random convex point cloud stretched along a tilted axis: the cover
    has several slabs, each smaller than one ball over the whole hull, and
    holds every point of the hull drawn as convex combinations."""
    rng = np.random.default_rng(2)
    V = rng.normal(size=(60, 3)) * (1.0, 0.15, 0.1)
    row = _row(K.HULL, (0, 0, 0))
    row[K.ROW_FIRST_VERTEX], row[K.ROW_END_VERTEX] = 0, len(V)
    cover = shape_cover(row, V)
    assert len(cover) > 2
    assert cover[:, 3].max() < np.linalg.norm(V - V.mean(0), axis=1).max()
    w = rng.dirichlet(np.full(len(V), 0.2), 20000)
    assert _outside(w @ V, cover).max() <= 0.0


def test_check_cover_refuses_a_short_cover():
    """A cover that misses a vertex is refused with the shortfall."""
    row = _row(K.BOX, (1.0, 0.5, 0.5))
    cover = shape_cover(row, np.zeros((0, 3)))
    cover[:, 3] *= 0.9
    with pytest.raises(WorkcellError, match="misses a point"):
        check_cover(row, np.zeros((0, 3)), cover)


def test_placed_balls_follow_drakes_body_poses(automotive):
    """The kernel's balls in the world are the covers' centres moved by
    Drake's body poses, radii grown by the pad; each shape's box holds its
    balls."""
    arrays = automotive.scene_arrays()
    spheres, ranges = arrays.covers
    plant = automotive.plant
    rng = np.random.default_rng(3)
    q = rng.uniform(automotive.position_lower, automotive.position_upper)
    R_WB, p_WB = arrays.fk(q)
    balls = np.empty((len(spheres), 4))
    box = np.empty((len(ranges), 6))
    place_balls(R_WB[0], p_WB[0], arrays.shape_body, spheres, ranges, 0.05, balls, box)
    ctx = automotive.plant_context(q)
    for s in range(len(ranges)):
        body = plant.get_body(arrays.body_indices[arrays.shape_body[s]])
        X_WB = plant.EvalBodyPoseInWorld(ctx, body)
        mine = spheres[ranges[s, 0] : ranges[s, 1]]
        np.testing.assert_allclose(
            balls[ranges[s, 0] : ranges[s, 1], :3],
            mine[:, :3] @ X_WB.rotation().matrix().T + X_WB.translation(),
            atol=1e-9,
        )
        np.testing.assert_allclose(balls[ranges[s, 0] : ranges[s, 1], 3], mine[:, 3] + 0.05)
        b = balls[ranges[s, 0] : ranges[s, 1]]
        assert np.all(b[:, :3] - b[:, 3:] >= box[s, :3] - 1e-12) and np.all(b[:, :3] + b[:, 3:] <= box[s, 3:] + 1e-12)
