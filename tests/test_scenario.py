"""Scenario files after Drake's hardware_sim: one random_seed, a cell held in
the scenario or named relative to its folder, saved paths and bounds
checked against the cell, and errors that name the file, the list item
(counted from 1) and the field before anything loads."""

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

import drake_cfvol as cf
from drake_cfvol.apps.cli import main
from drake_cfvol.comanip import load_scenario
from drake_cfvol.comanip.diagram import build_comanipulation_diagram

DATA = Path(__file__).parent / "data"


@pytest.fixture()
def cell_folder(tmp_path):
    """A scenario folder with the mesh test cell in a subfolder."""
    (tmp_path / "cells").mkdir()
    for name in ("mesh_cell.yaml", "mesh_scene.sdf"):
        shutil.copy(DATA / name, tmp_path / "cells" / name)
    return tmp_path


def _write(folder, name, data) -> Path:
    p = folder / name
    p.write_text(yaml.safe_dump(data, sort_keys=False))
    return p


def test_relative_cell_is_taken_from_the_scenarios_folder(cell_folder, monkeypatch):
    """A relative cell path resolves against the scenario's folder, whatever
    the working folder."""
    p = _write(cell_folder, "s.yaml", {"cell": "cells/mesh_cell.yaml", "certify": False, "resolution": 200})
    monkeypatch.chdir("/")
    scenario, file = load_scenario(str(p))
    cm = build_comanipulation_diagram(scenario, scenario_file=file)
    assert cm.workcell.name == "mesh_cell" and cm.workcell.num_joints == 7


def test_scenario_holding_its_cell_equals_the_cell_file(cell_folder):
    """A scenario with the cell's directives and cfvol settings inside gives
    the same robot, obstacles and path as the cell file."""
    cell = yaml.safe_load((cell_folder / "cells" / "mesh_cell.yaml").read_text())
    cell["directives"][2]["add_model"]["file"] = "cells/mesh_scene.sdf"
    p = _write(cell_folder, "own.yaml", {**cell, "certify": False, "resolution": 200})
    scenario, file = load_scenario(str(p))
    own = build_comanipulation_diagram(scenario, scenario_file=file)
    ref = cf.load_workcell(cell_folder / "cells" / "mesh_cell.yaml")
    assert own.workcell.joint_names == ref.joint_names and set(own.workcell.obstacles) == set(ref.obstacles)
    np.testing.assert_array_equal(own.path.waypoints, cf.plan_nominal_path(ref, *ref.configuration("path1"),
                                                                           seed=0).waypoints)


@pytest.mark.parametrize("data, field, says", [
    ({"pushes": [{"start": 1.0}, {"start": 2.0, "wrench": [1, "x", 3, 0, 0, 0]}]},
     "pushes item 2: wrench item 2", "must be a number"),
    ({"pushes": [{"start": 1.0, "wrench": [1, 2, 3]}]}, "pushes item 1: wrench", "has 3 values; give 6"),
    ({"pushes": [{"joint_torque": [1, 2]}, {"joint_torque": [1, 2, 3]}]}, "pushes item 2: joint_torque",
     "has 3 values but pushes item 1 has 2"),
    ({"pushes": [{"start": 1.0, "push": 3}]}, "pushes item 1: push", "is not a field of Push"),
    ({"seed": 3}, "seed", "is now 'random_seed'"),
    ({"random_pushes": {"seed": 3}}, "random_pushes.seed", "is now 'random_seed'"),
    ({"plant_config": {"time_step": 0.0}}, "plant_config.time_step", "must be > 0 s"),
    ({"path_file": "nowhere.json"}, "path_file", "does not exist"),
    ({"moving_obstacles": [{"name": "cart", "box": [1, 1], "waypoints": [[0, 0, 0, 0.5]]}]},
     "moving_obstacles item 1", "box must be 3 sides"),
    ({"moving_obstacles": [{"name": "cart", "waypoints": [[1, 0, 0, 0.5], [0, 1, 0, 0.5]]}]},
     "moving_obstacles item 1", "waypoint times must increase"),
    ({"perception": "lidar"}, "perception", "must be camera or truth"),
    ({"perception": "truth"}, "perception", "add moving_obstacles"),
    ({"moving_obstacles": [{"name": "cart", "waypoints": [[0, 1, 0, 0.5]]}], "plant_config": {"time_step": 0.001}},
     "moving_obstacles", "kinematic runs only"),
    ({"online": {"cell": 0.0}}, "online.cell", "must be > 0"),
    ({"online": {"frame_rate": 30}}, "online.frame_rate", "is not a field of OnlineConfig"),
])
def test_scenario_errors_name_file_item_and_field(tmp_path, data, field, says):
    """Each bad field is named with the file, the list item counted from 1
    and the field, before anything is loaded."""
    p = _write(tmp_path, "bad.yaml", {"cell": "automotive", **data})
    with pytest.raises(cf.ScenarioError) as e:
        load_scenario(str(p))
    assert str(p) in str(e.value) and f"field '{field}'" in str(e.value) and says in str(e.value)


def test_joint_torque_size_checked_against_the_robot_before_planning(cell_folder, monkeypatch):
    """A push with the wrong number of joint torques for the cell's robot
    fails right after the cell loads: planning is never reached."""
    p = _write(cell_folder, "s.yaml", {"cell": "cells/mesh_cell.yaml", "pushes": [{"joint_torque": [1, 2, 3]}]})
    import drake_cfvol.comanip.diagram as diagram

    monkeypatch.setattr(diagram, "plan_nominal_path", lambda *a, **k: pytest.fail("planned"))
    scenario, file = load_scenario(str(p))
    with pytest.raises(cf.ScenarioError, match=r"pushes item 1: joint_torque' has 3 values; the robot .* 7 joints"):
        build_comanipulation_diagram(scenario, scenario_file=file)


def test_saved_path_and_bounds_are_reused_and_checked(cell_folder, tmp_path, automotive):
    """A saved path and bounds table run as saved (no planning); a file made
    for another cell is refused with the joints named."""
    wc = cf.load_workcell(cell_folder / "cells" / "mesh_cell.yaml")
    path = cf.plan_nominal_path(wc, *wc.configuration("path1"), seed=4)
    table = cf.estimate_bounds(wc, path, resolution=200)
    path.save(cell_folder / "p.json")
    table.save(cell_folder / "b.npz")
    p = _write(cell_folder, "s.yaml", {"cell": "cells/mesh_cell.yaml", "path_file": "p.json",
                                       "bounds_file": "b.npz", "certify": False})
    scenario, file = load_scenario(str(p))
    cm = build_comanipulation_diagram(scenario, scenario_file=file)
    np.testing.assert_array_equal(cm.path.waypoints, path.waypoints)
    np.testing.assert_array_equal(cm.bounds.lower, table.lower)
    other = cf.plan_nominal_path(automotive, *automotive.configuration("path1"), seed=0)
    other.save(tmp_path / "auto.json")
    from drake_cfvol.algorithm.reuse import load_path_for

    with pytest.raises(cf.ConfigurationError, match="holds a path for joints joint_1.*has joints j1"):
        load_path_for(wc, tmp_path / "auto.json")


def test_cli_reuses_a_saved_path_and_a_failed_run_leaves_no_folder(cell_folder, tmp_path, capsys):
    """``cfvol bounds --path-file`` bounds the saved path as it is (same
    waypoints' hash), ``--bounds-file`` evaluates the saved table to the
    same CF and freedom, and a simulate run that fails leaves no empty --out."""
    wc = cf.load_workcell(cell_folder / "cells" / "mesh_cell.yaml")
    path = cf.plan_nominal_path(wc, *wc.configuration("path1"), seed=2)
    path.save(tmp_path / "p.json")
    assert main(["bounds", str(cell_folder / "cells" / "mesh_cell.yaml"), "--path-file", str(tmp_path / "p.json"),
                 "-R", "200", "--cf-windows", "2", "--cf-samples", "50", "--out", str(tmp_path / "b"),
                 "--json"]) == 0
    saved = cf.NominalPath.load(next((tmp_path / "b").glob("*_path.json")))
    assert saved.sha256 == path.sha256
    computed = json.loads(capsys.readouterr().out)
    # The saved table evaluated again: the same CF and freedom (same samples), nothing recomputed.
    assert main(["bounds", str(cell_folder / "cells" / "mesh_cell.yaml"), "--bounds-file",
                 str(next((tmp_path / "b").glob("*_bounds.npz"))), "--cf-windows", "2", "--cf-samples", "50",
                 "--json"]) == 0
    again = json.loads(capsys.readouterr().out)
    assert (again["cf_percent"], again["freedom"], again["g"]) == (computed["cf_percent"], computed["freedom"],
                                                                    computed["g"])
    bad = _write(cell_folder, "bad.yaml", {"cell": "cells/mesh_cell.yaml", "path": "nope", "certify": False})
    assert main(["simulate", str(bad), "--out", str(tmp_path / "never"), "--no-record"]) != 0
    assert not (tmp_path / "never").exists()
