"""Categorization (SPEC 4) and the volume (SPEC 5)."""

import numpy as np
import pytest
from conftest import write_arm_cell

import drake_cfvol as cf
from drake_cfvol.algorithm.reference import ReferenceScene
from drake_cfvol.algorithm.volume import build_volume, categorize, ground_obstacles
from drake_cfvol.scene.params import VolumeParams


def test_categorization_of_a_hand_made_scene(tmp_path):
    """A table just under the link at the start is trail; a box 0.25 m past
    the tip at the goal is goal; a far box is no-goal; the sets are disjoint."""
    z = 1.0  # the link spans z in [0.95, 1.05]
    goal_dir = np.array([np.cos(0.5), np.sin(0.5)])
    goal_box = 1.35 * goal_dir  # centre; its near face is 0.25 m past the tip
    path_yaml = write_arm_cell(
        tmp_path,
        links=[{"length": 1.0, "half_width": 0.05, "lower": -3, "upper": 3}],
        base_z=z,
        obstacles={
            "table": ((0.5, 0.2, 0.9), (0.55, 0.0, 0.45)),  # top 0.05 below the link
            "fixture": ((0.2, 0.2, 0.2), (goal_box[0], goal_box[1], z)),
            "cabinet": ((0.4, 0.4, 1.0), (-2.0, -2.0, 0.5)),
        },
    )
    wc = cf.load_workcell(path_yaml)
    path = cf.NominalPath(np.linspace([0.0], [0.5], 11), wc.joint_names, wc.name)
    cats = categorize(wc, path, VolumeParams())
    assert cats.trail == ["table"]
    assert cats.goal == ["fixture"]
    assert set(cats.no_goal) == {"cabinet", "floor"}
    assert cats.trail_distance["table"] == pytest.approx(0.05, abs=1e-6)
    assert 0.1 < cats.goal_distance["fixture"] < 0.5
    assert ground_obstacles(wc) == {"floor"}


@pytest.mark.parametrize("cell", ["automotive", "aerospace"])
@pytest.mark.parametrize("resolution", [100, 1000])
def test_nominal_free_of_volume_per_drake(cell, resolution, request, planned):
    """The robot at every nominal waypoint is free of V, checked by Drake with
    the real geometry against one SceneGraph box per column."""
    wc = request.getfixturevalue(cell)
    path = planned(cell)
    vb = build_volume(wc, path, VolumeParams.for_workcell(wc, resolution=resolution))
    assert vb.volume.n_boxes > 0
    scene = ReferenceScene(wc, vb.volume)
    assert not scene.volume_hits(path.waypoints).any()


def test_coarse_columns_are_lowered(tmp_path):
    """At R = 4 over 6 x 6 m a cell is 3 m wide: its centre is far from the
    arm but its column would swallow it. Such columns are lowered or dropped,
    counted in the output, and the arm is then free of V (Drake)."""
    path_yaml = write_arm_cell(
        tmp_path, links=[{"length": 1.0, "half_width": 0.05, "lower": -3, "upper": 3}], obstacles={}, base_z=1.0
    )
    wc = cf.load_workcell(path_yaml)
    path = cf.NominalPath(np.linspace([0.0], [0.5], 11), wc.joint_names, wc.name)
    vb = build_volume(wc, path, VolumeParams.for_workcell(wc, resolution=4))
    v = vb.volume
    assert v.heightmap.side == pytest.approx(3.0)
    # The cell holding the arm, (i, j) = (1, 1): its centre (1.5, 1.5) is
    # ~1 m from the arm, so eq. 1 gives it a tall column ...
    assert v.raw_heights[1, 1] > 1.0
    # ... which is cut down under the arm's bottom (z = 0.95).
    assert v.heights[1, 1] < 0.95
    assert v.lowered + v.dropped >= 1
    assert not ReferenceScene(wc, v).volume_hits(path.waypoints).any()
    table = cf.estimate_bounds(wc, path, resolution=4)
    assert table.info["lowered_columns"] + table.info["dropped_columns"] >= 1


def test_volume_is_numpy_over_cells(automotive, planned):
    """The volume's arrays have the height map's shape at R = 20000 and the
    columns are side x side x h boxes on the floor."""
    path = planned("automotive")
    vb = build_volume(automotive, path, VolumeParams.for_workcell(automotive, resolution=20000))
    hm = vb.volume.heightmap
    assert vb.volume.heights.shape == (hm.m, hm.n) and hm.m * hm.n <= 20000
    centres, sizes = vb.volume.boxes()
    np.testing.assert_allclose(centres[:, 2], sizes[:, 2] / 2)
    np.testing.assert_allclose(sizes[:, :2], hm.side)
    assert len(centres) == vb.volume.n_boxes


def test_volume_mesh_and_meshcat_view(automotive, planned):
    """The volume as one mesh has 12 triangles and 8 vertices per column, its
    bounding box is the columns'; show_volume draws it with the obstacles."""
    from pydrake.geometry import Meshcat, MeshcatParams

    from drake_cfvol.comanip.recording import show_volume, volume_mesh

    path = planned("automotive")
    vb = build_volume(automotive, path, VolumeParams.for_workcell(automotive, resolution=300))
    mesh = volume_mesh(vb.volume)
    n = vb.volume.n_boxes
    assert mesh.num_triangles() == 12 * n and mesh.num_vertices() == 8 * n
    verts = np.array([mesh.vertex(i) for i in range(mesh.num_vertices())])
    assert verts[:, 2].min() == 0.0 and verts[:, 2].max() == pytest.approx(vb.volume.heights.max())
    meshcat = Meshcat(MeshcatParams(host="localhost"))
    show_volume(meshcat, automotive, vb, path)
    assert meshcat.HasPath("/cfvol/volume") and meshcat.HasPath("/cfvol/obstacles/goal")
    assert meshcat.HasPath("/cfvol/nominal_tool_path")
