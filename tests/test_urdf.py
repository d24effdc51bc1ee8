"""Robots as ROS ships them: clashing actuator names load with a note, a
world link plus an add_weld is refused naming the fix, missing inertias are
noted, and Drake's parser warnings come condensed, one line per kind."""

import logging
import shutil
from pathlib import Path

import pytest
import yaml

import drake_cfvol as cf

DATA = Path(__file__).parent / "data"


def _cell(tmp_path, weld: bool) -> Path:
    for name in ("ros_arm.urdf", "box_scene.sdf"):
        shutil.copy(DATA / name, tmp_path / name)
    directives = [
        {"add_model": {"name": "arm", "file": "ros_arm.urdf"}},
        {"add_model": {"name": "scene", "file": "box_scene.sdf"}},
    ]
    if weld:
        directives.insert(1, {"add_weld": {"parent": "world", "child": "arm::base_link"}})
    p = tmp_path / "cell.yaml"
    p.write_text(
        yaml.safe_dump(
            {
                "directives": directives,
                "cfvol": {
                    "robot": "arm",
                    "tool_frame": "tool0",
                    "configurations": {"p": {"start": [0.0, 0.5], "goal": [1.5, 0.5]}},
                },
            }
        )
    )
    return p


def test_clashing_actuators_load_with_a_note_and_the_file_unchanged(tmp_path):
    """Two transmissions naming their actuator 'motor' load as joint1_motor
    and joint2_motor, with one note; the user's URDF is byte for byte as it was."""
    cell = _cell(tmp_path, weld=False)
    before = (tmp_path / "ros_arm.urdf").read_bytes()
    wc = cf.load_workcell(cell)
    names = sorted(wc.plant.get_joint_actuator(a).name() for a in wc.plant.GetJointActuatorIndices(wc.robot))
    assert names == ["joint1_motor", "joint2_motor"]
    assert sum("actuator names 'motor' (2 transmissions) clash" in n for n in wc.notes) == 1
    assert any("link1 have geometry but no <inertial>" in n for n in wc.notes)
    assert (tmp_path / "ros_arm.urdf").read_bytes() == before


def test_world_link_fixes_the_base_and_a_second_weld_is_refused(tmp_path):
    """The URDF's own world joint fixes its base (the robot's root body does
    not move); a directive welding it again gets one error naming the fix."""
    wc = cf.load_workcell(_cell(tmp_path, weld=False))
    base = wc.plant.GetBodyByName("base_link", wc.robot)
    assert wc.plant.GetBodiesWeldedTo(wc.plant.world_body()).count(base) == 1
    with pytest.raises(cf.WorkcellFormatError, match=r"already fixes link 'base_link'.*remove that add_weld"):
        cf.load_workcell(_cell(tmp_path, weld=True))


def test_drake_parser_warnings_condensed_one_line_per_kind(tmp_path, caplog):
    """Drake's three warnings (joint friction twice, an inertia once) come as
    two lines naming the user's file with their counts; Drake's own
    multi-line messages do not come through."""
    with caplog.at_level(logging.WARNING):
        cf.load_workcell(_cell(tmp_path, weld=False))
    ours = [r.getMessage() for r in caplog.records if r.name == "drake_cfvol"]
    raw = [r for r in caplog.records if r.name == "drake"]
    assert raw == []
    assert len(ours) == 2 and all(m.startswith(f"{tmp_path / 'ros_arm.urdf'}: ") for m in ours)
    assert any("2 parser warning(s): A joint has specified a non-zero value for the 'friction'" in m for m in ours)
    assert any("1 parser warning(s): While parsing inertia matrix" in m for m in ours)
