"""Every shape kind through every function that knows kinds: the scene's
row, the kernel's support point and box, the block check's ball test, the
cover, the bounding radius and box, the online re-estimation's radius and
the safety filter's probes, point distance and bounds, each against an
independent fact (Drake's signed distance to a point, points of the shape,
hand-computed extents); and a kind the kernel does not know refused when
the scene is built."""

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from pydrake.geometry import Box, Capsule, Convex, Cylinder, Ellipsoid, HalfSpace, Mesh, SceneGraph, Sphere
from pydrake.math import RigidTransform, RollPitchYaw
from pydrake.multibody.plant import CoulombFriction, MultibodyPlant

from drake_cfvol import kernel as K
from drake_cfvol.exceptions import WorkcellError
from drake_cfvol.kernel import kinds
from drake_cfvol.kernel.batch import _near_exact
from drake_cfvol.kernel.blocks import NB
from drake_cfvol.kernel.shapes import support
from drake_cfvol.kernel.spheres import ball_apart_row
from drake_cfvol.scene.arrays import shape_row
from drake_cfvol.scene.covers import check_cover, shape_cover, shape_points
from drake_cfvol.systems.filter import damper_kernel as DK

MESH = str(Path(__file__).resolve().parents[1] / "models" / "mesh_arm" / "meshes" / "link3.obj")

SHAPES = {
    "box": Box(0.3, 0.2, 0.5),
    "sphere": Sphere(0.15),
    "capsule": Capsule(0.1, 0.4),
    "cylinder": Cylinder(0.12, 0.3),
    "ellipsoid": Ellipsoid(0.2, 0.1, 0.15),
    "mesh": Mesh(MESH),
    "convex": Convex(MESH),
}

X_WG = RigidTransform(RollPitchYaw(0.3, -0.2, 0.7), [0.1, -0.2, 0.3])


def _posed(shape):
    """A scene graph holding the shape at X_WG, and its query object."""
    sg = SceneGraph()
    plant = MultibodyPlant(0.0)
    plant.RegisterAsSourceForSceneGraph(sg)
    plant.RegisterCollisionGeometry(plant.world_body(), X_WG, shape, "s", CoulombFriction(1, 1))
    plant.Finalize()
    context = sg.CreateDefaultContext()
    _posed.keep = (sg, plant, context)  # the query object refers to them
    return sg.get_query_output_port().Eval(context)


def _row(shape):
    verts = []
    row, radius, centre = shape_row(shape, X_WG.rotation().matrix(), X_WG.translation(), verts)
    return row, np.concatenate(verts) if verts else np.zeros((0, 3)), radius, centre


def _hull_distance(points, V, R, t):
    """Signed distance of points from conv(V posed at R, t) by its
    facets' planes (scipy's hull: a second method), m; exact outside
    along a facet normal, a lower bound of the distance elsewhere."""
    from scipy.spatial import ConvexHull

    eq = ConvexHull(V @ R.T + t).equations
    return (points @ eq[:, :3].T + eq[:, 3]).max(axis=1)


def _distance(query, shape, points):
    """Signed distance of world points from the posed shape: Drake's, or
    the hull's facet planes for a mesh (Drake measures none from a point)."""
    if isinstance(shape, (Mesh, Convex)):
        hull = shape.GetConvexHull()
        V = np.array([hull.vertex(i) for i in range(hull.num_vertices())])
        return _hull_distance(points, V, X_WG.rotation().matrix(), X_WG.translation())
    return np.array([query.ComputeSignedDistanceToPoint(p, np.inf)[0].distance for p in points])


@pytest.mark.parametrize("name", list(SHAPES))
def test_every_kind_through_every_function(name):
    shape = SHAPES[name]
    query = _posed(shape)
    g = kinds.geometry(shape)
    row, verts, radius, centre = _row(shape)
    kinds.check_rows(row[None], verts, "test shape")
    k = kinds.kind(row[K.ROW_KIND])
    assert k is g.kind and k.drake_names and type(shape).__name__ in k.drake_names
    R, t = X_WG.rotation().matrix(), X_WG.translation()
    np.testing.assert_allclose(centre, t + R @ g.centre, atol=1e-12)

    # The kind's points hold the shape (their hull, up to the rings' sag):
    # the kernel's support along any direction reaches no farther; every
    # support point is on the shape (Drake); a round shape's points are on
    # it, and a polytope's are its vertices, which the support reaches.
    P = shape_points(row, verts)
    rng = np.random.default_rng(1)
    D = rng.normal(size=(200, 3))
    D /= np.linalg.norm(D, axis=1, keepdims=True)
    S = np.empty((len(D), 3))
    for i, d in enumerate(D):
        support(row, verts, *d, S[i])
    # (Drake measures a point from an ellipsoid only approximately, to
    # about 1e-4 m: there the implicit equation is the fact.)
    if name != "ellipsoid":
        assert np.all(np.abs(_distance(query, shape, S)) <= 1e-9)
    else:
        L = (S - t) @ X_WG.rotation().matrix() / g.sizes
        np.testing.assert_allclose(np.einsum("ij,ij->i", L, L), 1.0, atol=1e-12)
    reach, most = np.einsum("ij,ij->i", S, D), (P @ D.T).max(axis=0)
    assert np.all(reach <= most + 0.03 * radius)
    if name != "ellipsoid":  # (its points are its bounding box's corners)
        assert _distance(query, shape, P).max() <= 1e-9
        assert np.all(reach >= most - 1e-9)

    # The kernel's box is the extent of the support along the axes.
    box = np.empty(6)
    K.row_aabb(row, verts, box)
    for a in range(3):
        e = np.eye(3)[a]
        hi, lo = np.empty(3), np.empty(3)
        support(row, verts, *e, hi)
        support(row, verts, *-e, lo)
        assert box[3 + a] == pytest.approx(hi[a], abs=1e-12) and box[a] == pytest.approx(lo[a], abs=1e-12)

    # Bounding radius and half extents (about the centre) hold the shape;
    # the radius is reached by a point of it.
    local = (S - centre) @ R
    assert np.linalg.norm(local, axis=1).max() <= radius + 1e-12
    assert radius <= np.linalg.norm((P - centre) @ R, axis=1).max() + 0.03 * radius
    assert np.all(np.abs(local) <= k.half_extents(g.sizes, g.verts) + 1e-12)

    # Both covers hold the shape (check_cover raises otherwise) and points inside it.
    for tight in (False, True):
        cover = shape_cover(row, verts, tight)
        check_cover(row, verts, cover)
        gap = np.linalg.norm(S[:, None] - cover[None, :, :3], axis=2) - cover[None, :, 3]
        assert np.all(gap.min(axis=1) <= 1e-9)

    # The block check's closed-form ball test never drops a ball that
    # reaches the shape (Drake's distance of its centre below its radius).
    if k.exact_near:
        Pl = np.zeros(12 * NB)
        for e in range(9):
            Pl[e * NB : (e + 1) * NB] = row[K.ROW_ROTATION + e]
        for e in range(3):
            Pl[(9 + e) * NB : (10 + e) * NB] = row[K.ROW_CENTRE + e]
        cb = np.zeros(3 * NB)
        C = t + rng.uniform(-0.5, 0.5, (NB, 3))
        for e in range(3):
            cb[e * NB : (e + 1) * NB] = C[:, e]
        r = 0.05
        near = np.ones(NB)
        _near_exact(cb, r, k.code, Pl, row[K.ROW_SIZE : K.ROW_SIZE + 3].copy(), near, NB)
        d = _distance(query, shape, C)
        assert np.all(near[d <= r] == 1.0)
        assert np.any(near == 0.0) and np.any(near == 1.0)

    # The region tests' ball test (a cover ball over a cell, against a
    # shape): "apart" only where Drake's distance of the centre exceeds the
    # radius; exact for a kind with a closed form, else against its box.
    C = t + rng.uniform(-0.6, 0.6, (400, 3))
    d = _distance(query, shape, C)
    apart = np.array([ball_apart_row(*c, 0.05, row, box) for c in C])
    assert not apart[d <= 0.05].any()
    if k.exact_near:
        np.testing.assert_array_equal(apart, d > 0.05 + 1e-9)
    else:
        outside = np.maximum(np.maximum(box[:3] - C, C - box[3:]), 0.0)
        np.testing.assert_array_equal(apart, np.linalg.norm(outside, axis=1) > 0.05 + 1e-9)

    # The safety filter: probes on the shape (their lowest points touch it),
    # its bounding ball and box about the shape's frame, and its closed-form
    # point distance where the kind has one (Drake's).
    centres, radii = DK.probes(shape)
    if centres.shape[1]:
        W = centres.T @ R.T + t
        np.testing.assert_allclose(_distance(query, shape, W), -radii, atol=1e-9)
    else:
        assert name in ("sphere", "ellipsoid")
    assert np.linalg.norm(S - t, axis=1).max() <= DK.ball_radius(shape) + 1e-12
    c, half = DK.local_box(shape)
    assert np.all(np.abs((S - t) @ R - c) <= half + 1e-12)
    assert DK.round_radius(shape) == k.round_radius(g.sizes)
    kind_code, prm = DK.point_query_shape(shape)
    if k.point_query:
        assert kind_code == k.code
        gq, nq = np.zeros(3), np.zeros(3)
        for p in rng.uniform(-0.5, 0.5, (50, 3)) + t:
            assert DK.point_distance(kind_code, prm, R.T @ (p - t), gq, nq) == pytest.approx(
                _distance(query, shape, p[None])[0], abs=1e-9
            )
    else:
        assert kind_code == DK.NO_POINT_QUERY


def test_a_half_space_is_a_big_box_below_its_plane_for_the_kernel_and_drakes_alone_for_the_filter():
    row, verts, _, centre = _row(HalfSpace())
    assert kinds.kind(row[K.ROW_KIND]) is kinds.KINDS[K.BOX]
    n = X_WG.rotation().matrix()[:, 2]  # the plane's normal in the world
    top = np.empty(3)
    support(row, verts, *n, top)
    assert top @ n == pytest.approx(X_WG.translation() @ n, abs=1e-9)  # the box's top face is the plane
    assert np.linalg.norm(centre - X_WG.translation()) == pytest.approx(kinds.HALF_SPACE_SIZE / 2)
    assert DK.ball_radius(HalfSpace()) == np.inf and DK.probes(HalfSpace())[0].shape == (3, 0)
    assert DK.point_query_shape(HalfSpace())[0] == DK.NO_POINT_QUERY


def test_an_unknown_kind_is_refused_when_the_scene_is_built(mesh_arrays):
    """A row of a kind no module has, or a hull without vertices, is
    refused with a message naming it; the known kinds pass."""
    bad = mesh_arrays.obstacles.copy()
    bad[0, K.ROW_KIND] = 9
    with pytest.raises(WorkcellError, match="obstacle shape 0 has shape kind 9"):
        dataclasses.replace(mesh_arrays, obstacles=bad)
    bad = mesh_arrays.shapes.copy()
    hull = int(np.flatnonzero(bad[:, K.ROW_KIND] == K.HULL)[0])
    bad[hull, K.ROW_END_VERTEX] = bad[hull, K.ROW_FIRST_VERTEX] + 2
    with pytest.raises(WorkcellError, match=f"robot shape {hull} is a convex hull"):
        dataclasses.replace(mesh_arrays, shapes=bad)
    with pytest.raises(WorkcellError, match="not one the kernel knows"):
        kinds.kind(7)
    with pytest.raises(WorkcellError, match="not supported by the fast backend"):
        kinds.geometry(object())
    assert kinds.geometry(object(), strict=False) is None


def test_the_registry_covers_every_code_and_drake_shape():
    """One kind per code, every Drake shape class the scene reads has a
    kind, and the block check's closed-form kinds are the registry's."""
    assert sorted(kinds.KINDS) == sorted([K.BOX, K.SPHERE, K.CAPSULE, K.CYLINDER, K.ELLIPSOID, K.HULL])
    for name in ("Box", "Sphere", "Capsule", "Cylinder", "Ellipsoid", "Mesh", "Convex", "HalfSpace"):
        assert kinds.DRAKE_KINDS[name].drake_names
    assert K.EXACT_KINDS == tuple(sorted(c for c, k in kinds.KINDS.items() if k.exact_near))


@pytest.fixture(scope="module")
def mesh_arrays():
    import drake_cfvol as cf
    from drake_cfvol.scene.arrays import scene_arrays

    return scene_arrays(cf.load_workcell("tests/data/mesh_cell.yaml"))
