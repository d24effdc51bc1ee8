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
    p = _write(
        cell_folder,
        "s.yaml",
        {"cell": {"name": "cells/mesh_cell.yaml"}, "bounds": {"certify": None, "resolution": 200}},
    )
    monkeypatch.chdir("/")
    scenario, file = load_scenario(str(p))
    cm = build_comanipulation_diagram(scenario, scenario_file=file)
    assert cm.workcell.name == "mesh_cell" and cm.workcell.num_joints == 7


def test_scenario_holding_its_cell_equals_the_cell_file(cell_folder):
    """A scenario with the cell's directives and cfvol settings inside gives
    the same robot, obstacles and path as the cell file."""
    cell = yaml.safe_load((cell_folder / "cells" / "mesh_cell.yaml").read_text())
    cell["directives"][2]["add_model"]["file"] = "cells/mesh_scene.sdf"
    p = _write(cell_folder, "own.yaml", {**cell, "bounds": {"certify": None, "resolution": 200}})
    scenario, file = load_scenario(str(p))
    own = build_comanipulation_diagram(scenario, scenario_file=file)
    ref = cf.load_workcell(cell_folder / "cells" / "mesh_cell.yaml")
    assert own.workcell.joint_names == ref.joint_names and set(own.workcell.obstacles) == set(ref.obstacles)
    np.testing.assert_array_equal(
        own.path.waypoints, cf.plan_nominal_path(ref, *ref.configuration("path1"), seed=0).waypoints
    )


def _cart(**kw):
    return {"cell": {"name": "automotive", "moving_obstacles": [{"name": "cart", **kw}]}}


@pytest.mark.parametrize(
    "data, field, says",
    [
        (
            {"human": {"pushes": [{"start": 1.0}, {"start": 2.0, "wrench": [1, "x", 3, 0, 0, 0]}]}},
            "human.pushes item 2: wrench item 2",
            "must be a number",
        ),
        (
            {"human": {"pushes": [{"start": 1.0, "wrench": [1, 2, 3]}]}},
            "human.pushes item 1: wrench",
            "has 3 values; give 6",
        ),
        (
            {"human": {"pushes": [{"joint_torque": [1, 2]}, {"joint_torque": [1, 2, 3]}]}},
            "human.pushes item 2: joint_torque",
            "has 3 values but pushes item 1 has 2",
        ),
        ({"human": {"pushes": [{"start": 1.0, "push": 3}]}}, "human.pushes item 1: push", "is not a field of Push"),
        ({"seed": 3}, "seed", "is now 'random_seed'"),
        ({"human": {"random_pushes": {"seed": 3}}}, "human.random_pushes.seed", "is now 'random_seed'"),
        ({"simulation": {"plant_config": {"time_step": 0.0}}}, "simulation.plant_config.time_step", "must be > 0 s"),
        ({"path": {"file": "nowhere.json"}}, "path.file", "does not exist"),
        (_cart(box=[1, 1], waypoints=[[0, 0, 0, 0.5]]), "cell.moving_obstacles item 1", "box must be 3 sides"),
        (
            _cart(waypoints=[[1, 0, 0, 0.5], [0, 1, 0, 0.5]]),
            "cell.moving_obstacles item 1",
            "waypoint times must increase",
        ),
        ({"perception": {"mode": "lidar"}}, "perception.mode", "must be camera or truth"),
        ({"perception": {"mode": "truth"}}, "perception.mode", "add cell.moving_obstacles"),
        (
            {**_cart(waypoints=[[0, 1, 0, 0.5]]), "simulation": {"plant_config": {"time_step": 0.001}}},
            "cell.moving_obstacles",
            "kinematic runs only",
        ),
        ({"perception": {"cell": 0.0}}, "perception.cell", "must be > 0"),
        ({"perception": {"frame_rate": 30}}, "perception.frame_rate", "is not a field of PerceptionSection"),
        ({"bounds": {"online": {"horizon": 0}}}, "bounds.online.horizon", "must be >= 1"),
        ({"bounds": {"params": {"clearence": 0.01}}}, "bounds.params.clearence", "known fields: alpha_t"),
        ({"bounds": {"params": {"d_t_lb": 2.0}}}, "bounds.params.d_t_lb", "must be below d_t_ub"),
        ({"bounds": {"certify": {"seed": 2}}}, "bounds.certify.seed", "is now 'random_seed'"),
        ({"control": {"safety_filter": {"damper_gain": 0.0}}}, "control.safety_filter.damper_gain", "must be > 0"),
        ({"control": {"admittance": {"mass": -1.0}}}, "control.admittance.mass", "must be > 0"),
        (
            {"control": {"path_progress": {"velocity_share": 1.0}}},
            "control.path_progress.velocity_share",
            "must lie in (0, 1)",
        ),
    ],
)
def test_scenario_errors_name_file_item_and_field(tmp_path, data, field, says):
    """Each bad field is named with the file, the list item counted from 1
    and the field, before anything is loaded."""
    p = _write(tmp_path, "bad.yaml", {"cell": {"name": "automotive"}, **data})
    with pytest.raises(cf.ScenarioError) as e:
        load_scenario(str(p))
    assert str(p) in str(e.value) and f"field '{field}'" in str(e.value) and says in str(e.value)


def test_joint_torque_size_checked_against_the_robot_before_planning(cell_folder, monkeypatch):
    """A push with the wrong number of joint torques for the cell's robot
    fails right after the cell loads: planning is never reached."""
    p = _write(
        cell_folder,
        "s.yaml",
        {"cell": {"name": "cells/mesh_cell.yaml"}, "human": {"pushes": [{"joint_torque": [1, 2, 3]}]}},
    )
    import drake_cfvol.comanip.diagram as diagram

    monkeypatch.setattr(diagram, "plan_nominal_path", lambda *a, **k: pytest.fail("planned"))
    scenario, file = load_scenario(str(p))
    with pytest.raises(
        cf.ScenarioError,
        match=r"human.pushes item 1: joint_torque' has 3 values; the robot .* 7 "
        "joints",
    ):
        build_comanipulation_diagram(scenario, scenario_file=file)


def test_saved_path_and_bounds_are_reused_and_checked(cell_folder, tmp_path, automotive):
    """A saved path and bounds table run as saved (no planning); a file made
    for another cell is refused with the joints named."""
    wc = cf.load_workcell(cell_folder / "cells" / "mesh_cell.yaml")
    path = cf.plan_nominal_path(wc, *wc.configuration("path1"), seed=4)
    table = cf.estimate_bounds(wc, path, resolution=200)
    path.save(cell_folder / "p.json")
    table.save(cell_folder / "b.npz")
    p = _write(
        cell_folder,
        "s.yaml",
        {
            "cell": {"name": "cells/mesh_cell.yaml"},
            "path": {"file": "p.json"},
            "bounds": {"file": "b.npz", "certify": None},
        },
    )
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
    assert (
        main(
            [
                "bounds",
                str(cell_folder / "cells" / "mesh_cell.yaml"),
                "--path-file",
                str(tmp_path / "p.json"),
                "-R",
                "200",
                "--cf-windows",
                "2",
                "--cf-samples",
                "50",
                "--out",
                str(tmp_path / "b"),
                "--json",
            ]
        )
        == 0
    )
    saved = cf.NominalPath.load(next((tmp_path / "b").glob("*_path.json")))
    assert saved.sha256 == path.sha256
    computed = json.loads(capsys.readouterr().out)
    # The saved table evaluated again: the same CF and freedom (same samples), nothing recomputed.
    assert (
        main(
            [
                "bounds",
                str(cell_folder / "cells" / "mesh_cell.yaml"),
                "--bounds-file",
                str(next((tmp_path / "b").glob("*_bounds.npz"))),
                "--cf-windows",
                "2",
                "--cf-samples",
                "50",
                "--json",
            ]
        )
        == 0
    )
    again = json.loads(capsys.readouterr().out)
    assert (again["cf_percent"], again["freedom"], again["g"]) == (
        computed["cf_percent"],
        computed["freedom"],
        computed["g"],
    )
    bad = _write(
        cell_folder,
        "bad.yaml",
        {"cell": {"name": "cells/mesh_cell.yaml"}, "path": {"name": "nope"}, "bounds": {"certify": None}},
    )
    assert main(["simulate", str(bad), "--out", str(tmp_path / "never"), "--no-record"]) != 0
    assert not (tmp_path / "never").exists()


@pytest.mark.parametrize(
    "old, new",
    [
        ({"collision_guard": False}, "control.safety_filter (null: no filter)"),
        ({"certify": False}, "bounds.certify (null: the paper's bounds"),
        ({"resolution": 2000}, "bounds.resolution"),
        (
            {"admittance": {"mass": 10.0, "period": 0.01}},
            "control.admittance (mass, damping, stiffness) and control.period",
        ),
        ({"pushes": []}, "human.pushes"),
        ({"path_file": "p.json"}, "path.file"),
        (
            {"online": {"bounds_period": 0.1}},
            "perception (camera_period, width, height, cell, obstacle_speed) and "
            "bounds.online (period: was bounds_period",
        ),
    ],
)
def test_old_form_scenario_gets_one_error_naming_the_new_field(tmp_path, old, new):
    """A scenario file of the flat form before 0.3 is refused, not read with
    defaults in place of its values: one ScenarioError naming the old field
    and where it went."""
    p = _write(tmp_path, "old.yaml", {**old, "path_duration": 8.0})
    with pytest.raises(cf.ScenarioError) as e:
        load_scenario(str(p))
    key = next(iter(old))
    assert f"field '{key}' is a field of the scenario form before drake_cfvol 0.3" in str(e.value)
    assert f"it is now '{new}" in str(e.value) and "CHANGELOG.md" in str(e.value)
    with pytest.raises(
        cf.ScenarioError,
        match=r"field 'cell' is a section since drake_cfvol 0.3: write 'cell: "
        r"\{name: aerospace\}'",
    ):
        load_scenario("automotive_push", scenario_text="{cell: aerospace}")


def test_bundled_scenarios_load_in_the_new_form():
    """Every bundled scenario loads, its sections typed: the systems' own
    config classes, certified bounds and the safety filter on."""
    from drake_cfvol.comanip import diagrams_dir
    from drake_cfvol.systems import AdmittanceConfig, SafetyFilterConfig

    names = sorted(p.stem for p in diagrams_dir().glob("*.yaml"))
    assert len(names) >= 9
    for name in names:
        s, _ = load_scenario(name)
        assert isinstance(s.control.admittance, AdmittanceConfig)
        assert isinstance(s.control.safety_filter, SafetyFilterConfig)
        assert s.certify() == cf.Certify(seed=s.random_seed)


def test_config_field_types_are_ones_drakes_reader_takes():
    """Drake's YAML reader takes each dataclass field's type as written: a
    string (a module with ``from __future__ import annotations``) fails with
    an empty message. No config class a scenario reaches (the systems' own
    among them) has one."""
    import dataclasses
    import typing

    from drake_cfvol.comanip import Scenario

    seen, bad = set(), []

    def walk(cls):
        if cls in seen:
            return
        seen.add(cls)
        for f in dataclasses.fields(cls):
            if isinstance(f.type, str):
                bad.append(f"{cls.__module__}.{cls.__name__}.{f.name}: {f.type!r} (a string)")
                continue
            for a in typing.get_args(f.type) or (f.type,):
                for b in typing.get_args(a) or (a,):
                    if dataclasses.is_dataclass(b):
                        walk(b)

    walk(Scenario)
    assert len(seen) >= 12 and not bad, bad


def test_bounds_section_is_volume_params_and_certify():
    """The scenario's bounds.params and bounds.certify are VolumeParams' and
    Certify's own fields (made from the classes, not copied): params all
    null (not given: the cell's), certify at Certify's defaults; a value
    given reaches the VolumeParams and the Certify the run uses."""
    import dataclasses

    from drake_cfvol.comanip.scenario import CertifyConfig, VolumeParamsConfig

    names = lambda cls: [f.name for f in dataclasses.fields(cls)]  # noqa: E731
    assert names(VolumeParamsConfig) == [n for n in names(cf.VolumeParams) if n != "resolution"]
    assert names(CertifyConfig) == [n for n in names(cf.Certify) if n != "seed"]
    assert all(v is None for v in dataclasses.asdict(VolumeParamsConfig()).values())
    s, _ = load_scenario(
        "automotive_push",
        scenario_text="{random_seed: 5, bounds: {resolution: 300, params: "
        "{h_max: 1.2, reach: null}, certify: {confidence: 0.9}}}",
    )
    assert s.certify() == cf.Certify(seed=5, confidence=0.9)
    params = cf.VolumeParams.for_workcell(cf.load_workcell("automotive"), **s.bounds.overrides())
    assert (params.resolution, params.h_max, params.clearance) == (300, 1.2, cf.VolumeParams().clearance)
