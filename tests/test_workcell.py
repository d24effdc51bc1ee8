"""Loading workcells: built-in cells, a user's own robot package, errors."""

import numpy as np
import pytest
from conftest import write_arm_cell

import drake_cfvol as cf


def test_builtin_cells_load(automotive, aerospace):
    """Both built-in cells load with their robots, obstacles and 3 path pairs."""
    assert automotive.num_joints == 6 and aerospace.num_joints == 7
    assert aerospace.joint_names[0] == "rail" and aerospace.rail_joint == "rail"
    for wc in (automotive, aerospace):
        assert "floor" in wc.obstacles
        assert set(wc.configurations) == {"path1", "path2", "path3"}
    assert {"pick_table", "mould", "cabinet"} <= set(automotive.obstacles)
    assert {"ply_pallet", "mould", "jig"} <= set(aerospace.obstacles)


@pytest.mark.parametrize("cell", ["automotive", "aerospace"])
def test_named_pairs_are_free_and_nontrivial(cell, request):
    """Each start and goal is free, and the straight joint-space line between
    them collides (checked with a finer edge step than the planner's)."""
    wc = request.getfixturevalue(cell)
    for name, (s, g) in wc.configurations.items():
        assert wc.is_free(s) and wc.is_free(g), name
        line = np.linspace(s, g, 2000)
        assert not all(wc.is_free(q) for q in line), f"{name}: straight line is free"


def test_unknown_cell_lists_known():
    """An unknown name lists the built-in cells."""
    with pytest.raises(cf.UnknownCellError, match="automotive.*|aerospace") as e:
        cf.load_workcell("shipyard")
    assert "aerospace" in str(e.value) and "automotive" in str(e.value)


def test_malformed_yaml_names_file_and_line(tmp_path):
    """A YAML syntax error reports the file and line."""
    p = tmp_path / "bad.yaml"
    p.write_text("directives:\n- add_model:\n    name: x\n  file: [unclosed\ncfvol: {}\n")
    with pytest.raises(cf.WorkcellFormatError) as e:
        cf.load_workcell(p)
    assert "bad.yaml" in str(e.value) and "line" in str(e.value)
    assert e.value.line is not None and 3 <= e.value.line <= 6


def test_missing_cfvol_key_is_reported(tmp_path):
    """A workcell without cfvol.robot says which key is missing."""
    path = write_arm_cell(tmp_path, links=[{"length": 1.0, "half_width": 0.05, "lower": -3, "upper": 3}], obstacles={})
    text = path.read_text().replace("  robot: toy\n", "")
    path.write_text(text)
    with pytest.raises(cf.WorkcellFormatError, match="'robot'"):
        cf.load_workcell(path)


def test_wrong_robot_instance_lists_instances(tmp_path):
    """A cfvol.robot that is not a model instance lists the instances."""
    path = write_arm_cell(tmp_path, links=[{"length": 1.0, "half_width": 0.05, "lower": -3, "upper": 3}], obstacles={})
    path.write_text(path.read_text().replace("robot: toy", "robot: tyo"))
    with pytest.raises(cf.WorkcellFormatError, match="'tyo'.*toy"):
        cf.load_workcell(path)


def test_user_robot_package_with_stl_meshes(tmp_path, monkeypatch):
    """A ROS-style package with STL collision meshes loads through package://,
    the meshes are converted (and said so), and they collide where the box
    they describe does."""
    monkeypatch.setenv("DRAKE_CFVOL_CACHE", str(tmp_path / "cache"))
    path = write_arm_cell(
        tmp_path,
        links=[{"length": 1.0, "half_width": 0.05, "lower": -3, "upper": 3}],
        obstacles={"post": ((0.2, 0.2, 2.0), (0.0, 0.8, 1.0))},
        mesh_links=True,
    )
    stl_before = (tmp_path / "toy_description" / "meshes" / "link1.stl").read_bytes()
    wc = cf.load_workcell(path)
    assert any("STL" in n for n in wc.notes)
    assert (tmp_path / "toy_description" / "meshes" / "link1.stl").read_bytes() == stl_before
    assert wc.joint_names == ["joint1"]
    # The link spans x in [0, 1] at 0 rad: free. At 90 deg it lies along +y
    # through the post at y in [0.7, 0.9].
    assert wc.is_free([0.0])
    assert wc.colliding_pairs([np.pi / 2]) == [("link1", "post")]


def test_cache_off_writes_no_cache_anywhere(tmp_path, monkeypatch):
    """DRAKE_CFVOL_CACHE=off turns every cache off: an STL robot still loads
    (its meshes converted into a folder of the process's own), nothing is
    written into ./off or the user's cache folder, and the certificate cache
    is off too."""
    from drake_cfvol.algorithm.certificate.cert_cache import cache_dir as certificate_dir
    from drake_cfvol.scene.meshes import cache_dir as mesh_dir

    work, user_cache = tmp_path / "work", tmp_path / "xdg"
    work.mkdir()
    monkeypatch.chdir(work)
    monkeypatch.setenv("XDG_CACHE_HOME", str(user_cache))
    monkeypatch.setenv("DRAKE_CFVOL_CACHE", "off")
    path = write_arm_cell(
        tmp_path,
        links=[{"length": 1.0, "half_width": 0.05, "lower": -3, "upper": 3}],
        obstacles={"post": ((0.2, 0.2, 2.0), (0.0, 0.8, 1.0))},
        mesh_links=True,
    )
    wc = cf.load_workcell(path)
    assert any("STL" in n for n in wc.notes)
    assert wc.colliding_pairs([np.pi / 2]) == [("link1", "post")]  # the converted mesh is the link
    assert certificate_dir() is None
    assert not (work / "off").exists() and list(work.iterdir()) == []
    assert not user_cache.exists()
    assert list((mesh_dir() / "meshes").glob("*.obj")), "the converted meshes are in the process's folder"
    assert tmp_path not in mesh_dir().parents


def test_wrong_length_configuration(automotive):
    """A configuration of the wrong size names the expected size and joints."""
    with pytest.raises(cf.DimensionError, match="expected 6, got 5.*joint_1"):
        automotive.validate_configuration(np.zeros(5), "start configuration")


def test_outside_limits_names_joint(automotive):
    """A value outside the limits names the joint, the value and the limits."""
    q = np.zeros(6)
    q[1] = 2.0
    with pytest.raises(cf.JointLimitError, match="joint_2.*2.*-1.13.*1.48") as e:
        automotive.validate_configuration(q, "goal configuration")
    assert e.value.joint == "joint_2"


def test_collision_names_bodies(automotive):
    """A colliding configuration names the colliding bodies."""
    q = np.radians([0, 85, 30, 0, 0, 0])  # arm thrown down to the floor
    with pytest.raises(cf.CollisionError) as e:
        automotive.require_free(q, "The start configuration")
    assert any("floor" in p or "cabinet" in p for pair in e.value.pairs for p in pair)


@pytest.mark.parametrize(
    "key, anchor",
    [
        ("rail_jiont: rail", "  reach: 3.0\n"),  # a misspelled optional key in cfvol
        ("flie: x.urdf", "    name: toy\n"),  # inside a model directive
        ("orgin: [0, 0]", "    origin:\n"),  # inside the height map
    ],
)
def test_misspelled_key_is_rejected_with_its_name_and_line(tmp_path, key, anchor):
    """An unknown key anywhere in a workcell file is an error naming the key
    and the line it is on (it used to load silently, e.g. as a cell without a rail)."""
    path = write_arm_cell(tmp_path, links=[{"length": 1.0, "half_width": 0.05, "lower": -3, "upper": 3}], obstacles={})
    text = path.read_text()
    assert anchor in text
    indent = anchor[: len(anchor) - len(anchor.lstrip())]
    text = text.replace(anchor, indent + key + "\n" + anchor, 1)
    path.write_text(text)
    bad_line = text.splitlines().index(indent + key) + 1
    name = key.split(":")[0]
    with pytest.raises(cf.WorkcellFormatError, match=f"unknown key '{name}'") as e:
        cf.load_workcell(path)
    assert e.value.line == bad_line and path.name in str(e.value)


def test_wrong_value_type_is_rejected(tmp_path):
    """A value of the wrong type (text for the reach) is a format error, not a crash."""
    path = write_arm_cell(tmp_path, links=[{"length": 1.0, "half_width": 0.05, "lower": -3, "upper": 3}], obstacles={})
    path.write_text(path.read_text().replace("reach: 3.0", "reach: far"))
    with pytest.raises(cf.WorkcellFormatError, match="far"):
        cf.load_workcell(path)


def test_typed_file_is_kept_and_not_changed_by_loading(tmp_path, monkeypatch):
    """The typed file is kept on the workcell; STL conversion rewrites a copy
    of the directives, never the user's own entries."""
    monkeypatch.setenv("DRAKE_CFVOL_CACHE", str(tmp_path / "cache"))
    path = write_arm_cell(
        tmp_path, links=[{"length": 1.0, "half_width": 0.05, "lower": -3, "upper": 3}], obstacles={}, mesh_links=True
    )
    wc = cf.load_workcell(path)
    assert wc.spec.directives[0].add_model.file == "package://toy_description/urdf/toy.urdf"
    assert wc.spec.cfvol.robot == "toy" and wc.spec.cfvol.reach == 3.0


def test_nan_configuration_named(automotive):
    """A NaN is reported as a value that is not a number, naming the joint."""
    q = np.zeros(6)
    q[2] = np.nan
    with pytest.raises(cf.ConfigurationError, match="not a finite number: joint_3 = nan"):
        automotive.validate_configuration(q, "start configuration")


def test_missing_workcell_file_named(tmp_path):
    """A workcell path that does not exist is a missing file, not an unknown cell."""
    with pytest.raises(cf.WorkcellFileNotFoundError, match="does not exist"):
        cf.load_workcell(tmp_path / "nope.yaml")
    with pytest.raises(cf.UnknownCellError, match="Built-in cells"):
        cf.load_workcell("nocell")


def _mesh_cell(folder):
    path = write_arm_cell(
        folder, links=[{"length": 1.0, "half_width": 0.05, "lower": -3, "upper": 3}], obstacles={}, mesh_links=True
    )
    return path, folder / "toy_description" / "urdf" / "toy.urdf"


def test_package_url_messages(tmp_path, monkeypatch):
    """A missing file in a known package and an unknown package get different,
    correct hints, without a doubled period."""
    monkeypatch.setenv("DRAKE_CFVOL_CACHE", str(tmp_path / "cache"))
    path, urdf = _mesh_cell(tmp_path)
    text = urdf.read_text()
    urdf.write_text(text.replace("meshes/link1.stl", "meshes/linkX.stl"))
    with pytest.raises(
        cf.WorkcellFormatError, match="is the folder .*toy_description, but it has no file 'meshes/linkX.stl'"
    ) as e:
        cf.load_workcell(path)
    assert ".." not in str(e.value).replace("../", "")
    urdf.write_text(text.replace("package://toy_description", "package://nopkg"))
    with pytest.raises(cf.WorkcellFormatError, match="package 'nopkg' is not known.*cfvol.package_paths") as e:
        cf.load_workcell(path)
    assert ".." not in str(e.value)


def test_converted_model_warnings_name_user_file(tmp_path, monkeypatch, caplog):
    """Drake's warnings about a model whose STL meshes were converted name the
    user's file, not the converted copy in the cache."""
    monkeypatch.setenv("DRAKE_CFVOL_CACHE", str(tmp_path / "cache"))
    path, urdf = _mesh_cell(tmp_path)
    urdf.write_text(
        urdf.read_text().replace('<axis xyz="0 0 1"/>', '<axis xyz="0 0 1"/><dynamics damping="0.1" friction="1"/>')
    )
    with caplog.at_level("WARNING", logger="drake"):
        cf.load_workcell(path)
    msgs = [r.getMessage() for r in caplog.records if "friction" in r.getMessage()]
    assert msgs and all(str(urdf) in m and str(tmp_path / "cache") not in m for m in msgs)


def test_fixed_links_left_out_of_moving_clearance():
    """The robot's fixed geometries are exactly those on bodies no joint
    moves (the root welded to the world); leaving them out never lowers the
    clearance."""
    wc = cf.load_workcell("automotive")
    plant = wc.plant
    moved = set(plant.GetBodiesKinematicallyAffectedBy(list(plant.GetJointIndices(wc.robot))))
    fixed = wc.fixed_robot_geometries()
    assert fixed
    for gid in fixed:
        body = plant.GetBodyFromFrameId(wc.scene_graph.model_inspector().GetFrameId(gid))
        assert body.index() not in moved and body.model_instance() == wc.robot
    rng = np.random.default_rng(3)
    for _ in range(5):
        q = rng.uniform(wc.position_lower, wc.position_upper)
        every = wc.obstacle_distances(q, 2.0)
        moving = wc.obstacle_distances(q, 2.0, moving_only=True)
        assert set(moving) <= set(every)
        assert all(moving[n] >= every[n] - 1e-12 for n in moving)


def test_invariant_pairs_of_a_planar_arm(tmp_path):
    """A two-link arm turning about vertical axes 0.5 m above the floor: its
    links' distance to the floor is the same at every configuration (0.45 m,
    by hand: 0.5 m less the 0.05 m half width), so those pairs are invariant
    and left out of the changeable distances; the post's distance changes
    with the joints and stays."""

    wc = cf.load_workcell(
        write_arm_cell(
            tmp_path,
            links=[
                {"length": 1.0, "half_width": 0.05, "lower": -0.4, "upper": 0.4},
                {"length": 0.8, "half_width": 0.05, "lower": -0.8, "upper": 0.8},
            ],
            obstacles={"post": ((0.3, 0.3, 1.0), (1.15, 1.0, 0.5))},
            base_z=0.5,
        )
    )
    owner = {o: name for name, ob in wc.obstacles.items() for o in ob.geometry_ids}
    assert {owner[o] for _, o in wc.invariant_pairs()} == {"floor"}
    rng = np.random.default_rng(5)
    for q in rng.uniform(wc.position_lower, wc.position_upper, (4, 2)):
        every = wc.obstacle_distances(q, 2.0, moving_only=True)
        assert every["floor"] == pytest.approx(0.45, abs=1e-6)
        changeable = wc.obstacle_distances(q, 2.0, changeable_only=True)
        assert "floor" not in changeable and changeable["post"] == every["post"]


@pytest.mark.parametrize("cell", ["automotive", "aerospace", "cobot", "franka", "tests/data/mesh_cell.yaml"])
def test_collision_free_never_free_where_drake_collides(cell, request):
    """The public batch check is never True where Drake's checker (padded by
    the same clearance, 0 and 2 cm) finds a collision, on random
    configurations of every built-in robot and the mesh test robot (about
    half colliding), and calls almost nothing else colliding."""
    wc = request.getfixturevalue(cell) if cell in ("automotive", "aerospace") else cf.load_workcell(cell)
    Q = np.random.default_rng(5).uniform(wc.position_lower, wc.position_upper, (1000, wc.num_joints))
    for clearance in (0.0, 0.02):
        free = wc.collision_free(Q, clearance=clearance)
        drake = np.array(wc.padded_checker(clearance).CheckConfigsCollisionFree(Q), bool)
        assert 0.2 * len(Q) < (~drake).sum() < 0.9 * len(Q)
        assert not (free & ~drake).any()
        assert (~free & drake).sum() <= 0.002 * len(Q)
    assert wc.collision_free(Q[0]).shape == (1,)


def test_collision_free_refuses_bad_input(automotive):
    """Wrong width, non-finite values and a negative clearance are named."""
    with pytest.raises(cf.DimensionError, match="joint_1"):
        automotive.collision_free(np.zeros((3, 5)))
    with pytest.raises(cf.ConfigurationError, match="finite"):
        automotive.collision_free(np.full((2, 6), np.nan))
    with pytest.raises(cf.ParameterError, match="clearance"):
        automotive.collision_free(np.zeros(6), clearance=-0.1)
