"""The bad-input corpus (issue 49): files, values and calls a new user may
get wrong. Each case ends with exit 2 (or a CfvolError) and one line that
names what is wrong and where; none ends in a traceback.

The cases call ``cfvol``'s ``main`` in-process (no subprocess), so the
corpus stays fast; a case that needs a planned path or a table shares the
session's fixtures.
"""

from __future__ import annotations

import math
import textwrap
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from drake_cfvol.apps.cli import main
from drake_cfvol.exceptions import CfvolError
from drake_cfvol.scene.schema import builtin_cells

ROOT = Path(__file__).resolve().parents[1]
AUTOMOTIVE = builtin_cells()["automotive"].read_text()
SCENARIO = (ROOT / "diagrams" / "automotive_push.yaml").read_text()
JOBS = "cells: [automotive]\npaths: [1]\n"


def refused(argv: list[str], capsys, *expected: str) -> str:
    """Runs ``cfvol argv``: exit 2, one line on stderr naming each of
    ``expected`` (case-insensitive), no traceback. Returns the line."""
    capsys.readouterr()
    code = main([str(a) for a in argv])
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip() and not ln.startswith("cfvol: note:")]
    assert code == 2, err
    assert "Traceback" not in err
    assert len(lines) == 1 and lines[0].startswith("cfvol: error: "), err
    for e in expected:
        assert e.lower() in lines[0].lower(), (e, lines[0])
    return lines[0]


def raises(call, *expected: str) -> CfvolError:
    """``call()`` raises a CfvolError whose one-line message names each of ``expected``."""
    with pytest.raises(CfvolError) as info:
        call()
    msg = str(info.value)
    assert "\n" not in msg, msg
    for e in expected:
        assert e.lower() in msg.lower(), (e, msg)
    return info.value


# --- 1. Files: encodings and duplicate keys ---------------------------------------------------------------

ENCODINGS = {
    "utf16-bom": (lambda t: t.encode("utf-16"), "UTF-16"),
    "utf16-le": (lambda t: t.encode("utf-16-le"), "UTF-16"),
    "utf16-be": (lambda t: t.encode("utf-16-be"), "UTF-16"),
    "utf32": (lambda t: t.encode("utf-32"), "UTF-32"),
    "latin1": (lambda t: ("# Größe der Zelle\n" + t).encode("latin-1"), "Latin-1"),
    "cp1252": (lambda t: ("# “quoted” – dash\n" + t).encode("cp1252"), "Latin-1"),
    "binary": (lambda t: bytes(range(256)) * 8, "binary"),
    "gzip": (lambda t: __import__("gzip").compress(t.encode()), "binary"),
}
#: What each command reads: (its file's text, the command line for a file).
READERS = {
    "workcell": (AUTOMOTIVE, lambda f: ["plan", f]),
    "scenario": (SCENARIO, lambda f: ["simulate", f, "--out", Path(f).parent / "out"]),
    "jobs": (JOBS, lambda f: ["batch", f, "--serial"]),
}


@pytest.mark.parametrize("encoding", ENCODINGS)
@pytest.mark.parametrize("reader", READERS)
def test_a_yaml_file_not_in_utf8_is_named_with_its_encoding(tmp_path, capsys, reader, encoding):
    text, argv = READERS[reader]
    encode, found = ENCODINGS[encoding]
    f = tmp_path / "file.yaml"
    f.write_bytes(encode(text))
    line = refused(argv(f), capsys, str(f), found)
    assert "UTF-8" in line  # how to save it


def test_a_utf8_byte_order_mark_is_accepted(tmp_path):
    from drake_cfvol.comanip.scenario import load_scenario
    from drake_cfvol.scene.schema import read_workcell_file

    cell = tmp_path / "cell.yaml"
    cell.write_bytes(b"\xef\xbb\xbf" + AUTOMOTIVE.encode())
    plain = tmp_path / "plain.yaml"
    plain.write_text(AUTOMOTIVE)
    (bom, bom_lines), (ref, ref_lines) = read_workcell_file(cell), read_workcell_file(plain)
    assert bom.cfvol == ref.cfvol and bom_lines == ref_lines and len(bom.directives) == len(ref.directives)
    scen = tmp_path / "scen.yaml"
    scen.write_bytes(b"\xef\xbb\xbf" + SCENARIO.encode())
    from pydrake.common.yaml import yaml_dump_typed

    bundled = load_scenario(ROOT / "diagrams" / "automotive_push.yaml")[0]
    assert yaml_dump_typed(load_scenario(scen)[0]) == yaml_dump_typed(bundled)


#: (reader, the text's line to find, the line added after it, the key named)
DUPLICATES = [
    ("workcell", "  reach: 2.8\n", "  reach: 3.0\n", "reach"),
    ("workcell", "  robot: abb\n", "  robot: cell\n", "robot"),
    ("workcell", "cfvol:\n", None, "cfvol"),
    ("workcell", "    path1:  # pick table -> mould\n", None, "path1"),
    (
        "workcell",
        "      start: [1.22173, 0.872665, -0.872665, 0.0, 1.570796, 0.0]  # [70, 50, -50, 0, 90, 0]\n",
        "      start: [0, 0, 0, 0, 0, 0]\n",
        "start",
    ),
    ("workcell", "    origin: [-2.8, -2.8]\n", "    origin: [0, 0]\n", "origin"),
    ("scenario", "  end_hold: 1.0\n", "  duration: 9.0\n", "duration"),
    ("scenario", "random_seed: 0\n", "random_seed: 1\n", "random_seed"),
    ("scenario", "  resolution: 1000\n", "  resolution: 2000\n", "resolution"),
    ("scenario", "    mass: 10.0\n", "    mass: 1.0\n", "mass"),
    ("scenario", "  period: 0.01\n", "  period: 0.02\n", "period"),
    ("jobs", "paths: [1]\n", "paths: [2]\n", "paths"),
]


def _with_duplicate(text: str, anchor: str, extra: str | None) -> str:
    assert anchor in text, anchor
    if extra is None:  # the whole section again, under its own key
        indent = len(anchor) - len(anchor.lstrip())
        block = anchor
        rest = text[text.index(anchor) + len(anchor) :].splitlines(keepends=True)
        for ln in rest:
            if ln.strip() and len(ln) - len(ln.lstrip()) <= indent:
                break
            block += ln
        return text + ("\n" if not text.endswith("\n") else "") + textwrap.indent(textwrap.dedent(block), " " * indent)
    return text.replace(anchor, anchor + extra, 1)


@pytest.mark.parametrize(("reader", "anchor", "extra", "key"), DUPLICATES, ids=[f"{d[0]}-{d[3]}" for d in DUPLICATES])
def test_a_duplicate_yaml_key_is_refused_with_its_line(tmp_path, capsys, reader, anchor, extra, key):
    text, argv = READERS[reader]
    f = tmp_path / "file.yaml"
    f.write_text(_with_duplicate(text, anchor, extra))
    line = refused(argv(f), capsys, str(f), f"duplicate key '{key}'", "line")
    assert "first on line" in line


def test_a_duplicate_key_in_included_directives_is_refused(tmp_path, capsys):
    inc = tmp_path / "more.dmd.yaml"
    inc.write_text("directives:\n- add_frame: {name: f, X_PF: {base_frame: world}}\ndirectives: []\n")
    text = AUTOMOTIVE.replace("cfvol:\n", "- add_directives:\n    file: more.dmd.yaml\ncfvol:\n", 1)
    f = tmp_path / "cell.yaml"
    f.write_text(text)
    refused(["plan", f], capsys, str(inc), "duplicate key 'directives'")


@pytest.mark.parametrize("included", [False, True])
def test_a_directive_that_does_nothing_is_refused(tmp_path, capsys, included):
    """An empty directive (``- {}``) crashed Drake's loader (it checks a directive only in a debug build)."""
    empty = "- {}\n"
    if included:
        inc = tmp_path / "more.dmd.yaml"
        inc.write_text("directives:\n" + empty)
        empty = "- add_directives:\n    file: more.dmd.yaml\n"
    f = tmp_path / "cell.yaml"
    f.write_text(AUTOMOTIVE.replace("cfvol:\n", empty + "cfvol:\n", 1))
    where = str(tmp_path / "more.dmd.yaml") if included else str(f)
    refused(["plan", f], capsys, where, "directive", "exactly one of add_model")


def test_a_duplicate_json_key_in_a_saved_path_is_refused(tmp_path, capsys):
    f = tmp_path / "p.json"
    f.write_text('{"format": "drake_cfvol.NominalPath", "waypoints": [[0]], "waypoints": [[1]]}')
    refused(["bounds", "automotive", "--path-file", f], capsys, str(f), "'waypoints' appears twice")


#: The one typed-YAML loader (drake_cfvol.io.typed_yaml) behind every command's file:
#: (reader, the text's line to find, what replaces it, the field named, the fix). The bad line is the
#: replacement's first line that the original text does not hold.
TYPED = {
    "workcell-wrong-type": ("workcell", "  reach: 2.8\n", "  reach: far\n", "cfvol.reach", "must be a number"),
    "workcell-list-item": (
        "workcell",
        "      goal: [-1.134464, 0.610865,",
        "      goal: [-1.134464, near,",
        "cfvol.configurations.path1.goal item 2",
        "must be a number",
    ),
    "workcell-misspelled": (
        "workcell",
        "  reach: 2.8\n",
        "  reach: 2.8\n  rail_jiont: x\n",
        "cfvol.rail_jiont",
        "check its spelling",
    ),
    "workcell-directive": (
        "workcell",
        "- add_model:\n    name: cell\n",
        "- add_modle:\n    name: cell\n",
        "directives item 3: add_modle",
        "known fields: add_model,",
    ),
    "workcell-inside-drake": (
        "workcell",
        "    name: abb\n",
        "    name: abb\n    flie: x.urdf\n",
        "directives item 1: add_model.flie",
        "check its spelling",
    ),
    "scenario-wrong-type": ("scenario", "  resolution: 1000\n", "  resolution: fine\n", "bounds.resolution", "integer"),
    "scenario-list-item": (
        "scenario",
        "      wrench: [0, 0, 0, 0, 250, 0]\n",
        "      wrench: [0, 0, 0, 0, strong, 0]\n",
        "human.pushes item 1: wrench item 5",
        "must be a number",
    ),
    "scenario-misspelled": (
        "scenario",
        "random_seed: 0\n",
        "random_sed: 0\n",
        "random_sed",
        "known fields: random_seed",
    ),
    "scenario-inside-drake": (
        "scenario",
        "simulation:\n",
        "simulation:\n  visualization: {default_illustration_color: {rgbb: [1, 0, 0]}}\n",
        "simulation.visualization.default_illustration_color.rgbb",
        "check its spelling",
    ),
    "jobs-misspelled": ("jobs", "paths: [1]\n", "pathz: [1]\n", "pathz", "known fields: cells, paths"),
    "jobs-wrong-type": ("jobs", "cells: [automotive]\n", "cells: automotive\n", "cells", "must be a list"),
}


@pytest.mark.parametrize("case", TYPED)
def test_a_bad_field_is_named_with_its_file_line_and_fix(tmp_path, capsys, case):
    reader, old, new, field, fix = TYPED[case]
    text, argv = READERS[reader]
    assert old in text, old
    bad = text.replace(old, new, 1)
    line = next(n for n, (a, b) in enumerate(zip(bad.splitlines(), text.splitlines()), 1) if a != b)
    f = tmp_path / "file.yaml"
    f.write_text(bad)
    refused(argv(f), capsys, f"{f}, line {line}: field '{field}'", fix)
    assert not (tmp_path / "out").exists()  # nothing written


@pytest.mark.parametrize("reader", READERS)
@pytest.mark.parametrize("text", ["- a list\n- at the top\n", "key: [unclosed\n"])
def test_a_file_that_is_no_mapping_or_no_yaml_is_refused_at_its_line(tmp_path, capsys, reader, text):
    f = tmp_path / "file.yaml"
    f.write_text("# a comment\n" + text)
    line = 2 if text.startswith("-") else 3  # the list's first item; the end where the bracket is missed
    says = "must hold a mapping of" if text.startswith("-") else "is not valid YAML"
    refused(READERS[reader][1](f), capsys, f"{f}, line {line}: ", says)


# --- 2. Saved tables and paths: values, and the cell they were made in ---------------------------------


@pytest.fixture(scope="module")
def saved(tmp_path_factory, bounded, planned, automotive):
    """A table and a path of the automotive cell, saved by cfvol bounds (with their fingerprints)."""
    folder = tmp_path_factory.mktemp("saved")
    table = bounded("automotive")
    table.save(folder / "bounds.npz")
    table.save(folder / "bounds.json")
    path = planned("automotive")
    from drake_cfvol.algorithm.reuse import fingerprint_of

    path.fingerprint = fingerprint_of(automotive, path)
    path.save(folder / "path.json")
    return folder


def _edited_table(saved: Path, tmp_path: Path, edit) -> Path:
    import json

    d = json.loads((saved / "bounds.json").read_text())
    edit(d)
    f = tmp_path / "edited.json"
    f.write_text(json.dumps(d).replace("Infinity", "1e999"))  # json writes inf as Infinity
    return f


TABLE_EDITS = {
    "lower-above-upper": (lambda d: d["lower"][5].__setitem__(1, d["upper"][5][1] + 0.5), "lower", "> upper"),
    "nan-lower": (lambda d: d["lower"][3].__setitem__(0, float("nan")), "lower", "not a finite number"),
    "inf-upper": (lambda d: d["upper"][0].__setitem__(2, float("inf")), "upper", "not a finite number"),
    "nan-nominal": (lambda d: d["nominal"][7].__setitem__(4, float("nan")), "nominal", "not a finite number"),
    "nominal-outside": (lambda d: d["nominal"][9].__setitem__(0, d["upper"][9][0] + 0.1), "nominal", "> upper"),
    "nominal-below": (lambda d: d["nominal"][9].__setitem__(0, d["lower"][9][0] - 0.1), "lower", "> nominal"),
    "nan-stretch": (lambda d: d["stretch_lower"][2].__setitem__(1, float("nan")), "stretch_lower", "stretch 3"),
    "negative-rate": (lambda d: d.__setitem__("rate", [-1.0] * 6), "rate", ">= 0"),
    "box-outside-limits": (
        lambda d: (d["upper"][0].__setitem__(0, 3.5), d["upper"][1].__setitem__(0, 3.5)),
        "limit",
        "joint_1",
    ),
    "short-row": (lambda d: d["lower"].__setitem__(0, d["lower"][0][:5]), "bounds", "bounds"),
    "joint-names-not-list": (lambda d: d.__setitem__("joint_names", 3), "bounds", "bounds"),
    "bad-interpolation": (lambda d: d.__setitem__("interpolation", "cubic"), "interpolation", "cubic"),
    "edited-nominal": (
        lambda d: d["nominal"][20].__setitem__(5, d["nominal"][20][5] + 1e-4),
        "nominal",
        "edited after saving",
    ),
    "other-path-label": (lambda d: d["info"].__setitem__("path", "path2"), "path2", "path1"),
    "info-not-a-mapping": (lambda d: d.__setitem__("info", []), "info", "list"),
    "fingerprint-limits-edited": (
        lambda d: d["info"]["fingerprint"].__setitem__("limits", "wide"),
        "fingerprint has no valid 'limits'",
        "edited",
    ),
    "fingerprint-box-short": (
        lambda d: d["info"]["fingerprint"]["obstacles"]["floor"].__setitem__("box", [0.0] * 5),
        "obstacle 'floor'",
        "fingerprint",
    ),
    "fingerprint-of-a-later-version": (
        lambda d: d["info"]["fingerprint"].__setitem__("version", 99),
        "version 99",
        "fingerprint",
    ),
}


@pytest.mark.parametrize("edit", TABLE_EDITS)
def test_an_unusable_saved_table_is_refused(saved, tmp_path, automotive, edit):
    """What --bounds-file and bounds.file load (the CLI's line is the error's message: checked below)."""
    from drake_cfvol.algorithm.reuse import load_bounds_for

    change, *named = TABLE_EDITS[edit]
    f = _edited_table(saved, tmp_path, change)
    raises(lambda: load_bounds_for(automotive, f, None, label="path1", notes=[]), str(f), *named)


def test_the_cli_refuses_an_unusable_table_or_path_in_one_line(saved, tmp_path, capsys):
    import json

    f = _edited_table(saved, tmp_path, TABLE_EDITS["lower-above-upper"][0])
    refused(["bounds", "automotive", "--path", "1", "--bounds-file", f, "--cf-samples", "1"], capsys, str(f), "> upper")
    d = json.loads((saved / "path.json").read_text())
    PATH_EDITS["nan-waypoint"][0](d)
    f = tmp_path / "p.json"
    f.write_text(json.dumps(d))
    refused(["bounds", "automotive", "--path-file", f], capsys, str(f), "not a number")


def test_a_table_whose_stretch_bounds_cross_is_valid():
    """Two waypoint boxes that do not overlap (the joint has no room beyond the nominal, which moves): their
    stretch box crosses (lower 0.0339 > upper 0.0298), and the box rule widens it to hold the nominal, as the sweep's
    own tables do (aerospace path 1, joint A4): the table is usable, not refused."""
    import numpy as np

    from drake_cfvol.algorithm.table import BoundsTable, check_table
    from drake_cfvol.systems import JointBoundsSource

    table = BoundsTable([[0.0], [0.0339]], [[0.0298], [0.0339]], [[0.0], [0.0339]], ["a4"], [-1.0], [1.0])
    assert table.stretch_lower[0, 0] > table.stretch_upper[0, 0]
    check_table(table, "here", np.array([-1.0]), np.array([1.0]))
    JointBoundsSource(table)
    lo, hi, nom = table.at(0.5)
    assert lo[0] == nom[0] == 0.0339 / 2 <= hi[0]  # it holds the nominal (no room below it)


def test_a_table_is_refused_where_a_system_meets_it(bounded, planned):
    import dataclasses

    import numpy as np

    from drake_cfvol.systems import JointBoundsSource

    table = bounded("automotive")
    upper = table.upper.copy()
    upper[4, 2] = table.lower[4, 2] - 0.1
    raises(lambda: JointBoundsSource(dataclasses.replace(table, upper=upper)), "JointBoundsSource", "joint_3")
    nominal = table.nominal.copy()
    nominal[0, 0] = np.nan
    raises(lambda: JointBoundsSource(dataclasses.replace(table, nominal=nominal)), "nominal", "finite")
    raises(lambda: JointBoundsSource(planned("automotive")), "BoundsTable", "NominalPath")
    raises(lambda: JointBoundsSource(None), "BoundsTable", "NoneType")


def _cell_with(tmp_path: Path, extra: str) -> Path:
    """The automotive cell with ``extra`` directives (obstacles) added."""
    f = tmp_path / "automotive.yaml"
    f.write_text(AUTOMOTIVE.replace("cfvol:\n", extra + "cfvol:\n", 1))
    return f


def _crate(tmp_path: Path, centre=(1.5, 0.0, 1.2), name: str = "crate") -> str:
    """A directive adding a 0.2 m box named ``name`` at ``centre``."""
    sdf = tmp_path / f"{name}.sdf"
    sdf.write_text(
        f'<?xml version="1.0"?><sdf version="1.9"><model name="{name}"><static>true</static>'
        f'<link name="{name}"><pose>{" ".join(map(str, centre))} 0 0 0</pose><collision name="c"><geometry><box>'
        "<size>0.2 0.2 0.2</size></box></geometry></collision></link></model></sdf>"
    )
    return f"- add_model:\n    name: {name}\n    file: {sdf}\n"


def test_a_stale_table_names_the_obstacle_added_inside_its_box(saved, bounded, tmp_path, capsys):
    """Bounds made for the cell; a crate placed where the path's box lets the
    robot go (the tool's position at a waypoint, checked to collide there);
    the table and the path are refused, naming the crate."""
    import drake_cfvol as cf

    table = bounded("automotive")
    q = table.nominal[len(table.nominal) // 2]
    wc = cf.load_workcell("automotive")
    plant = wc.plant
    ctx = plant.GetMyContextFromRoot(wc.context)
    plant.SetPositions(ctx, wc.robot, q)
    tool = plant.GetFrameByName("tcp").CalcPoseInWorld(ctx).translation()
    cell = _cell_with(tmp_path, _crate(tmp_path, tuple(float(x) for x in tool)))
    stale = cf.load_workcell(str(cell))
    assert not stale.checker.CheckConfigCollisionFree(q)  # the crate lies inside the box: the nominal hits it
    refused(["bounds", cell, "--bounds-file", saved / "bounds.npz"], capsys, "obstacle 'crate' was added")
    refused(["bounds", cell, "--path-file", saved / "path.json"], capsys, "obstacle 'crate' was added")


def test_a_moved_or_removed_obstacle_is_named(saved, tmp_path, capsys):
    import re

    from drake_cfvol.scene.schema import models_dir

    sdf = (models_dir() / "cells" / "automotive_cell.sdf").read_text()

    poses = re.findall(r"<pose>([^<]*)</pose>", sdf)
    assert poses
    first = poses[0]
    x, *rest = first.split()
    shifted = sdf.replace(f"<pose>{first}</pose>", f"<pose>{float(x) + 0.25} {' '.join(rest)}</pose>", 1)
    (tmp_path / "cell.sdf").write_text(shifted)
    f = tmp_path / "cell.yaml"
    f.write_text(
        AUTOMOTIVE.replace("package://drake_cfvol_models/cells/automotive_cell.sdf", str(tmp_path / "cell.sdf"))
    )
    line = refused(["bounds", f, "--bounds-file", saved / "bounds.npz"], capsys, "was moved", "0.25")
    assert "obstacle '" in line


def test_another_robot_or_limits_is_named(saved, tmp_path, capsys):
    limited = AUTOMOTIVE.replace("  params: {}\n", "  params: {}\n  joint_limits: {joint_1: [-2.0, 2.0]}\n")
    f = tmp_path / "limited.yaml"
    f.write_text(limited)
    refused(["bounds", f, "--bounds-file", saved / "bounds.npz"], capsys, "joint limits changed", "joint_1")
    refused(["bounds", "aerospace", "--bounds-file", saved / "bounds.npz"], capsys, "joints")


@pytest.mark.parametrize("flag", ["--bounds-file", "--path-file"])
def test_a_file_for_another_path_than_the_one_named_is_refused(saved, capsys, flag):
    name = "bounds.npz" if flag == "--bounds-file" else "path.json"
    refused(["bounds", "automotive", "--path", "2", flag, saved / name], capsys, "'path1'", "'path2' was named")


def test_an_old_file_without_a_fingerprint_loads_with_a_notice(saved, tmp_path, capsys):
    import json

    import numpy as np

    from drake_cfvol.algorithm.table import BoundsTable

    d = json.loads((saved / "bounds.json").read_text())
    del d["info"]["fingerprint"]
    f = tmp_path / "old.json"
    f.write_text(json.dumps(d))
    capsys.readouterr()
    assert main(["bounds", "automotive", "--bounds-file", str(f), "--cf-samples", "10", "--cf-windows", "2"]) == 0
    notes = [ln for ln in capsys.readouterr().err.splitlines() if "fingerprint" in ln]
    assert len(notes) == 1 and notes[0].startswith("cfvol: note:") and str(f) in notes[0]
    # The table itself is what was saved, bit for bit.
    a, b = BoundsTable.load(f), BoundsTable.load(saved / "bounds.npz")
    assert np.array_equal(a.lower, b.lower) and np.array_equal(a.upper, b.upper)


PATH_EDITS = {
    "nan-waypoint": (lambda d: d["waypoints"][2].__setitem__(1, float("nan")), "not a number"),
    "edited-waypoint": (lambda d: d["waypoints"][2].__setitem__(1, d["waypoints"][2][1] + 1e-3), "edited after"),
    "one-waypoint": (lambda d: (d.__setitem__("waypoints", d["waypoints"][:1]), d.pop("sha256")), "g >= 2"),
    "wrong-columns": (lambda d: (d.__setitem__("waypoints", [w[:5] for w in d["waypoints"]]), d.pop("sha256")), "5"),
    "no-waypoints": (lambda d: d.pop("waypoints"), "'waypoints'"),
    "not-an-object": (lambda d: d.clear(), "'waypoints'"),
}


@pytest.mark.parametrize("edit", PATH_EDITS)
def test_an_unusable_saved_path_is_refused(saved, tmp_path, automotive, edit):
    """What --path-file and path.file load."""
    import json

    from drake_cfvol.algorithm.reuse import load_path_for

    change, named = PATH_EDITS[edit]
    d = json.loads((saved / "path.json").read_text())
    change(d)
    f = tmp_path / "p.json"
    f.write_text(json.dumps(d))
    raises(lambda: load_path_for(automotive, f, notes=[]), str(f), named)


def _arm_without_collision_geometry(tmp_path: Path) -> tuple[Path, Path]:
    """A one-link arm (limits +-3 rad) and a post in its swing at angle 0;
    returns the cell's file with the link's <collision> and the same cell
    without it (the link drawn only)."""
    import re

    from conftest import write_arm_cell

    configurations = {"path1": {"start": [-1.0], "goal": [1.0]}}
    link = {"length": 1.0, "half_width": 0.05, "lower": -3.0, "upper": 3.0}
    post = {"post": ((0.2, 0.2, 1.0), (0.7, 0.0, 0.5))}
    solid = write_arm_cell(tmp_path / "solid", links=[link], obstacles=post, configurations=configurations)
    hollow = write_arm_cell(tmp_path / "hollow", links=[link], obstacles=post, configurations=configurations)
    urdf = hollow.parent / "toy_description" / "urdf" / "toy.urdf"
    text = urdf.read_text()
    link1 = re.search(r'<link name="link1">.*?</link>', text).group(0)
    urdf.write_text(text.replace(link1, re.sub(r"<collision>.*?</collision>", "", link1)))
    return solid, hollow


def test_a_robot_without_collision_geometry_is_refused_by_every_command(tmp_path, capsys):
    """With its collision geometry the arm's straight swing from -1 to 1
    rad hits the post (Drake); without it every check would call the swing
    free, so plan, bounds and simulate refuse the cell, naming the robot."""
    import drake_cfvol as cf
    from drake_cfvol.exceptions import WorkcellError

    solid, hollow = _arm_without_collision_geometry(tmp_path)
    assert not cf.load_workcell(str(solid)).checker.CheckConfigCollisionFree([0.0])
    wc = cf.load_workcell(str(hollow))
    assert wc.checker.CheckConfigCollisionFree([0.0])  # the hole the refusal closes
    for argv in (["plan", hollow], ["bounds", hollow]):
        refused(argv, capsys, "robot 'toy'", str(hollow), "no collision geometry", "<collision>")
    scenario = tmp_path / "run.yaml"
    scenario.write_text(f"cell: {{name: {hollow}}}\npath: {{name: path1, duration: 2.0}}\n")
    refused(["simulate", scenario, "--out", tmp_path / "out"], capsys, "robot 'toy'", "co-manipulation run")
    raises(lambda: cf.plan_nominal_path(wc, [-1.0], [1.0], seed=0), "no collision geometry", "planning")
    with pytest.raises(WorkcellError):
        wc.scene_arrays()


# --- 3. Values checked where they are read ---------------------------------------------------------------

CELL_VALUES = {
    "negative-reach": (("  reach: 2.8\n", "  reach: -1.0\n"), "reach"),
    "nan-reach": (("  reach: 2.8\n", "  reach: .nan\n"), "reach"),
    "inf-reach": (("  reach: 2.8\n", "  reach: .inf\n"), "reach"),
    "negative-size": (("    size: [5.6, 5.6]\n", "    size: [-5.6, 5.6]\n"), "height_map.size"),
    "zero-size": (("    size: [5.6, 5.6]\n", "    size: [5.6, 0.0]\n"), "height_map.size"),
    "nan-origin": (("    origin: [-2.8, -2.8]\n", "    origin: [.nan, -2.8]\n"), "height_map.origin"),
    "three-sizes": (("    size: [5.6, 5.6]\n", "    size: [5.6, 5.6, 1.0]\n"), "height_map.size"),
    "nan-start": (("      start: [1.22173, 0.872665,", "      start: [.nan, 0.872665,"), "configurations.path1.start"),
    "two-number-translation": (
        ("      translation: [0.0, 0.0, 0.42]\n", "      translation: [0.0, 0.42]\n"),
        "a Transform field got array([0.",
    ),
}


@pytest.mark.parametrize("value", ["inf", "-1", "0", "nan", "1e999"])
def test_a_time_limit_that_is_not_a_finite_positive_number_is_refused(capsys, value):
    refused(["plan", "automotive", "--time-limit", value], capsys, "time_limit", "--time-limit")


@pytest.mark.parametrize(("windows", "samples"), [(30, 10_000_000_000), (100_000, 100_000), (1, 2**40)])
def test_cf_samples_beyond_memory_are_refused_before_any_work(capsys, monkeypatch, windows, samples):
    import drake_cfvol.algorithm.pipeline as pipeline

    monkeypatch.setattr(pipeline, "estimate_bounds", lambda *a, **k: pytest.fail("bounds computed before the check"))
    refused(["bounds", "automotive", "--cf-windows", windows, "--cf-samples", samples], capsys, "GB", "--cf-samples")


SCENARIO_VALUES = {
    "nan-push-torque": (
        ("      joint_torque: [0, 900, 0, 0, 0, 0]\n", "      joint_torque: [0, .nan, 0, 0, 0, 0]\n"),
        "joint_torque",
    ),
    "inf-push-wrench": (("      wrench: [0, 0, 0, 0, 250, 0]\n", "      wrench: [0, 0, 0, 0, .inf, 0]\n"), "wrench"),
    "nan-toward": (
        ("    toward_nearest_obstacle: 300.0\n", "    toward_nearest_obstacle: .nan\n"),
        "toward_nearest_obstacle",
    ),
    "inf-duration": (("  duration: 8.0\n", "  duration: .inf\n"), "path.duration"),
    "null-duration": (("  duration: 8.0\n", "  duration: null\n"), "path.duration"),
    "list-log-period": (("  log_period: 0.02\n", "  log_period: [0.02]\n"), "simulation.log_period"),
    "period-over-path": (("  period: 0.01\n", "  period: 20\n"), "control.period"),
    "period-equal-path": (("  period: 0.01\n", "  period: 8.0\n"), "control.period"),
    "inf-period": (("  period: 0.01\n", "  period: .inf\n"), "control.period"),
    "inf-log-period": (("  log_period: 0.02\n", "  log_period: .inf\n"), "simulation.log_period"),
    "nan-push-start": (("    - start: 1.5\n", "    - start: .nan\n"), "start"),
    "inf-push-duration": (("      duration: 1.5\n      wrench", "      duration: .inf\n      wrench"), "duration"),
}


VALUES = {
    **{("workcell", k): v for k, v in CELL_VALUES.items()},
    **{("scenario", k): v for k, v in SCENARIO_VALUES.items()},
}


@pytest.mark.parametrize(("reader", "case"), VALUES, ids=[f"{r}-{c}" for r, c in VALUES])
def test_a_bad_value_is_named_with_its_file_and_field(tmp_path, capsys, reader, case):
    (old, new), field = VALUES[reader, case]
    text, argv = READERS[reader]
    assert old in text, old
    f = tmp_path / "file.yaml"
    f.write_text(text.replace(old, new, 1))
    refused(argv(f), capsys, str(f), field)
    assert not (tmp_path / "out").exists()  # nothing written


# --- 4. The Python API: a wrong type or shape is named, never a TypeError from inside ------------------------


@pytest.fixture(scope="module")
def api(automotive, planned, bounded):
    """What the calls below need: the automotive cell, its path 1 and table, and a finalized plant of the
    cell in a builder (for AddCoManipulation, which refuses before adding anything)."""
    from types import SimpleNamespace

    from pydrake.multibody.plant import AddMultibodyPlantSceneGraph
    from pydrake.systems.framework import DiagramBuilder

    builder = DiagramBuilder()
    plant, scene_graph = AddMultibodyPlantSceneGraph(builder, 0.0)
    robot = automotive.add_to_plant(plant)
    plant.Finalize()
    start, goal = automotive.configuration("path1")
    station = {"plant": plant, "scene_graph": scene_graph, "robot": robot, "table": bounded("automotive")}
    station["tool_frame"] = "tcp"
    return SimpleNamespace(
        wc=automotive,
        path=planned("automotive"),
        table=bounded("automotive"),
        start=start,
        goal=goal,
        builder=builder,
        station=station,
    )


def _plan(c, **changes):
    import drake_cfvol as cf

    args = {"workcell": c.wc, "q_start": c.start, "q_goal": c.goal, "seed": 0, **changes}
    return cf.plan_nominal_path(**args)


def _station(c, **changes):
    from drake_cfvol.systems import AddCoManipulation

    args = {"builder": c.builder, **c.station, **changes}
    return AddCoManipulation(args.pop("builder"), **args)


def _cf():
    import drake_cfvol

    return drake_cfvol


#: id -> (the call on the fixture api, what the message names)
API_CASES = {
    "load_workcell-int": (lambda c: _cf().load_workcell(3), "name_or_path", "int"),
    "load_workcell-dict": (lambda c: _cf().load_workcell({"cell": "automotive"}), "name_or_path", "dict"),
    "load_workcell-unknown-argument": (lambda c: _cf().load_workcell("automotive", edge=0.1), "edge"),
    "load_workcell-edge-step-str": (lambda c: _cf().load_workcell("automotive", edge_step="0.1"), "edge_step", "str"),
    "load_workcell-edge-step-negative": (lambda c: _cf().load_workcell("automotive", edge_step=-1), "edge_step"),
    "plan-start-dict": (lambda c: _plan(c, q_start=dict(enumerate(c.start))), "start configuration", "dict"),
    "plan-goal-dict": (lambda c: _plan(c, q_goal={"joint_1": 0.0}), "goal configuration", "dict"),
    "plan-start-short": (lambda c: _plan(c, q_start=c.start[:5]), "start configuration", "expected 6, got 5"),
    "plan-goal-long": (lambda c: _plan(c, q_goal=list(c.goal) + [0.0]), "goal configuration", "expected 6, got 7"),
    "plan-start-str": (lambda c: _plan(c, q_start="home"), "start configuration", "str"),
    "plan-start-strings": (lambda c: _plan(c, q_start=["0"] * 6), "start configuration", "list ['0'"),
    "plan-start-is-the-pair": (lambda c: _plan(c, q_start=(c.start, c.goal)), "start configuration", "(2, 6)"),
    "plan-start-nan": (lambda c: _plan(c, q_start=c.start * float("nan")), "start configuration", "finite"),
    "plan-workcell-name": (lambda c: _plan(c, workcell="automotive"), "workcell", "str"),
    "plan-time-limit-str": (lambda c: _plan(c, time_limit="10"), "time_limit", "str"),
    "plan-seed-float": (lambda c: _plan(c, seed=0.5), "seed", "float"),
    "plan-seed-negative": (lambda c: _plan(c, seed=-1), "seed", ">= 0"),
    "plan-clearance-str": (lambda c: _plan(c, clearance="0.02"), "clearance", "str"),
    "plan-max-step-zero": (lambda c: _plan(c, max_step=0), "max_step", "> 0"),
    "plan-label-int": (lambda c: _plan(c, label=1), "label", "int"),
    "plan-shortcuts-float": (lambda c: _plan(c, shortcut_iterations=1.5), "shortcut_iterations"),
    "bounds-workcell-none": (lambda c: _cf().estimate_bounds(None, c.path), "workcell", "NoneType"),
    "bounds-path-none": (lambda c: _cf().estimate_bounds(c.wc, None), "path", "NoneType"),
    "bounds-path-is-the-table": (lambda c: _cf().estimate_bounds(c.wc, c.table), "path", "BoundsTable"),
    "bounds-path-as-waypoints": (lambda c: _cf().estimate_bounds(c.wc, c.path.waypoints), "path", "ndarray"),
    "bounds-params-dict": (lambda c: _cf().estimate_bounds(c.wc, c.path, {"resolution": 100}), "params", "dict"),
    "bounds-resolution-str": (lambda c: _cf().estimate_bounds(c.wc, c.path, resolution="1000"), "resolution"),
    "bounds-unknown-parameter": (lambda c: _cf().estimate_bounds(c.wc, c.path, resolutoin=100), "resolutoin"),
    "bounds-certify-true": (lambda c: _cf().estimate_bounds(c.wc, c.path, certify=True), "certify", "bool"),
    "bounds-path-of-another-robot": (
        lambda c: _cf().estimate_bounds(c.wc, _cf().NominalPath([[0.0] * 7] * 2, [f"j{i}" for i in range(7)])),
        "path's configurations",
        "expected 6, got 7",
    ),
    "cf-table-none": (lambda c: _cf().confidence_factor(c.wc, None), "bounds", "NoneType"),
    "cf-table-is-the-path": (lambda c: _cf().confidence_factor(c.wc, c.path), "bounds", "NominalPath"),
    "cf-workcell-name": (lambda c: _cf().confidence_factor("automotive", c.table), "workcell", "str"),
    "cf-samples-str": (lambda c: _cf().confidence_factor(c.wc, c.table, samples="100"), "samples", "str"),
    "cf-samples-float": (lambda c: _cf().confidence_factor(c.wc, c.table, samples=10.5), "samples", "float"),
    "cf-seed-str": (lambda c: _cf().confidence_factor(c.wc, c.table, seed="0"), "seed", "str"),
    "cf-windows-zero": (lambda c: _cf().confidence_factor(c.wc, c.table, windows=0), "windows", ">= 1"),
    "freedom-mask-short": (lambda c: _cf().freedom(c.table, [True] * 5), "revolute", "expected 6, got (5,)"),
    "freedom-mask-dict": (lambda c: _cf().freedom(c.table, {"joint_1": True}), "revolute", "dict"),
    "freedom-mask-str": (lambda c: _cf().freedom(c.table, "revolute"), "revolute", "str"),
    "freedom-table-is-the-path": (lambda c: _cf().freedom(c.path, [True] * 6), "bounds", "NominalPath"),
    "freedom-table-none": (lambda c: _cf().freedom(None), "bounds", "NoneType"),
    "at-array": (lambda c: c.table.at(__import__("numpy").array([1.0, 2.0])), "BoundsTable.at", "boxes_at"),
    "at-str": (lambda c: c.table.at("1"), "BoundsTable.at", "str"),
    "at-none": (lambda c: c.table.at(None), "BoundsTable.at", "NoneType"),
    "at-beyond-the-path": (lambda c: c.table.at(c.table.g), "outside", "[0, "),
    "boxes_at-2d": (lambda c: c.table.boxes_at([[1.0, 2.0]]), "boxes_at", "dimension"),
    "boxes_at-strings": (lambda c: c.table.boxes_at(["a"]), "boxes_at", "list"),
    "table-save-int": (lambda c: c.table.save(3), "bounds file", "int"),
    "table-save-suffix": (lambda c: c.table.save("bounds.txt"), "'.txt'", ".npz or .json"),
    "table-load-none": (lambda c: _cf().BoundsTable.load(None), "bounds file", "NoneType"),
    "path-load-dict": (lambda c: _cf().NominalPath.load({}), "path file", "dict"),
    "table-lower-dict": (
        lambda c: _cf().BoundsTable({}, c.table.upper, c.table.nominal, c.table.joint_names, [0] * 6, [1] * 6),
        "BoundsTable: lower",
        "dict",
    ),
    "table-rate-short": (
        lambda c: __import__("dataclasses").replace(c.table, rate=[1.0, 2.0]),
        "rate",
        "expected 6",
    ),
    "path-waypoints-dict": (lambda c: _cf().NominalPath({"q": [0.0]}, ["joint_1"]), "waypoints", "dict"),
    "path-joint-names-none": (lambda c: _cf().NominalPath(c.path.waypoints, None), "joint_names", "NoneType"),
    "path-joint-names-short": (lambda c: _cf().NominalPath(c.path.waypoints, ["joint_1"]), "columns", "expected 1"),
    "path-waypoint-nan": (
        lambda c: _cf().NominalPath(c.path.waypoints * float("nan"), c.path.joint_names),
        "waypoint 1",
        "not a number",
    ),
    "path-at-str": (lambda c: c.path.at("1"), "NominalPath.at", "str"),
    "bounds-source-path": (
        lambda c: __import__("drake_cfvol.systems", fromlist=["x"]).JointBoundsSource(c.path),
        "JointBoundsSource",
        "NominalPath",
    ),
    "bounds-source-clamp-str": (
        lambda c: __import__("drake_cfvol.systems", fromlist=["x"]).JointBoundsSource(c.table, clamp="yes"),
        "clamp",
        "str",
    ),
    "station-builder-none": (lambda c: _station(c, builder=None), "builder", "NoneType"),
    "station-plant-str": (lambda c: _station(c, plant="plant"), "plant", "str"),
    "station-scene-graph-none": (lambda c: _station(c, scene_graph=None), "scene_graph", "NoneType"),
    "station-table-is-the-path": (lambda c: _station(c, table=c.path), "table", "NominalPath"),
    "station-tool-frame-int": (lambda c: _station(c, tool_frame=7), "tool_frame", "int"),
    "station-period-str": (lambda c: _station(c, period="0.01"), "period", "str"),
    "station-period-zero": (lambda c: _station(c, period=0.0), "period", "> 0"),
    "station-config-dict": (lambda c: _station(c, config={}), "config", "dict"),
    "is-free-dict": (lambda c: c.wc.is_free({"joint_1": 0.0}), "q", "dict"),
    "configuration-list": (lambda c: c.wc.configuration(["path1"]), "configuration", "path1, path2"),
    "params-for-no-workcell": (lambda c: _cf().VolumeParams.for_workcell(None), "workcell", "NoneType"),
    "params-replace-unknown": (lambda c: _cf().VolumeParams().replace(resoluton=5), "resoluton", "known"),
}


@pytest.mark.parametrize("case", API_CASES)
def test_the_api_names_a_wrong_argument(api, case):
    call, *named = API_CASES[case]
    raises(lambda: call(api), *named)


# --- 5. Outputs: nothing overwritten, every output checked before any work ---------------------------------


def _no_work(monkeypatch) -> None:
    """Planning, bounding and building a run fail the test: a refusal must come first."""
    import drake_cfvol.algorithm.pipeline as pipeline
    import drake_cfvol.algorithm.planning as planning
    import drake_cfvol.comanip.run as run

    def work(*args, **kwargs):
        pytest.fail("work started before the outputs were checked")

    monkeypatch.setattr(pipeline, "estimate_bounds", work)
    monkeypatch.setattr(planning, "plan_nominal_path", work)
    monkeypatch.setattr(run, "build_comanipulation_diagram", work)


SIMULATE_OUTPUTS = ["summary.json", "logs.npz", "run.png", "recording.html", "diagram.dot", "diagram.svg"]


@pytest.mark.parametrize("name", SIMULATE_OUTPUTS)
def test_simulate_refuses_an_earlier_runs_file_before_any_work(tmp_path, capsys, monkeypatch, name):
    _no_work(monkeypatch)
    (tmp_path / name).write_text("mine")
    refused(["simulate", "automotive_push", "--out", tmp_path], capsys, str(tmp_path), name, "--force")
    assert [f.name for f in tmp_path.iterdir()] == [name] and (tmp_path / name).read_text() == "mine"


def test_simulate_names_every_file_in_the_way_in_one_line(tmp_path, capsys, monkeypatch):
    _no_work(monkeypatch)
    for name in SIMULATE_OUTPUTS:
        (tmp_path / name).write_text("mine")
    refused(["simulate", "automotive_push", "--out", tmp_path], capsys, *SIMULATE_OUTPUTS)


def test_simulate_force_and_files_it_will_not_write_pass_the_check(tmp_path, capsys, monkeypatch):
    """--no-record leaves recording.html alone, so it is not in the way;
    --force lets any file through: both reach the build (stopped there)."""
    import drake_cfvol.comanip.run as run
    from drake_cfvol.exceptions import ScenarioError

    def built(*args, **kwargs):
        raise ScenarioError("here", None, "the build was reached")

    monkeypatch.setattr(run, "build_comanipulation_diagram", built)
    (tmp_path / "recording.html").write_text("mine")
    refused(["simulate", "automotive_push", "--out", tmp_path, "--no-record"], capsys, "the build was reached")
    (tmp_path / "summary.json").write_text("mine")
    refused(["simulate", "automotive_push", "--out", tmp_path, "--force"], capsys, "the build was reached")


BOUNDS_OUTPUTS = ["bounds.npz", "bounds.json", "path.json", "bounds.png"]


@pytest.mark.parametrize("kind", BOUNDS_OUTPUTS)
def test_bounds_refuses_an_existing_output_plot_included_before_any_work(tmp_path, capsys, monkeypatch, kind):
    _no_work(monkeypatch)
    name = f"automotive_path1_R1000_{kind}"
    (tmp_path / name).write_text("mine")
    refused(["bounds", "automotive", "--out", tmp_path, "--plot"], capsys, name, "--force")
    assert (tmp_path / name).read_text() == "mine"


def test_a_second_certification_into_one_folder_refuses_at_once(tmp_path, capsys, monkeypatch, bounded, planned):
    """The first --certify run writes its files (its computation replaced by
    the session's table, to stay fast); the second refuses before planning
    or bounding anything, naming the files the first one wrote."""
    import drake_cfvol.algorithm.certificate.certify as certify
    import drake_cfvol.algorithm.pipeline as pipeline
    import drake_cfvol.algorithm.planning as planning

    monkeypatch.setattr(certify, "Certify", lambda **settings: settings)
    monkeypatch.setattr(planning, "plan_nominal_path", lambda *a, **k: planned("automotive"))
    monkeypatch.setattr(pipeline, "estimate_bounds", lambda *a, **k: bounded("automotive"))
    argv = ["bounds", "automotive", "--certify", "--out", tmp_path, "--cf-samples", "1", "--cf-windows", "1"]
    assert main([str(a) for a in argv]) == 0
    written = sorted(f.name for f in tmp_path.iterdir())
    assert written == sorted(f"automotive_path1_R1000_certified_{k}" for k in BOUNDS_OUTPUTS[:3])
    _no_work(monkeypatch)
    refused(argv, capsys, *written)


def test_batch_names_every_existing_output(tmp_path, capsys):
    jobs = tmp_path / "jobs.yaml"
    jobs.write_text("cells: [automotive]\npaths: [path1, path2]\n")
    out = tmp_path / "out"
    out.mkdir()
    for name in ("results.json", "automotive_path2_R1000_bounds.npz"):
        (out / name).write_text("mine")
    refused(["batch", jobs, "--serial", "--out", out], capsys, "results.json", "automotive_path2_R1000_bounds.npz")


# --- 7. Mutated files: nothing but CfvolErrors and valid results (hypothesis) -------------------------------

#: Values of other types and out of range, put where a valid one was.
ODD_VALUES = [None, True, "text", "", -1, 0, 2.5, 1e308, -1e308, 10**30, math.nan, math.inf, -math.inf, [], {}]
ODD_VALUES += [[1.0, 2.0], {"a": 1}, "1e-3", [None], [[0.0]]]
#: A comment with letters outside ASCII, in the encodings a file may come in (UTF-8 with or without BOM is valid).
ENCODED = {
    "utf-8": "# Größe – “cell”\n",
    "utf-8-sig": "# Größe – “cell”\n",
    "utf-16": "# Größe\n",
    "utf-16-be": "# Größe\n",
    "utf-32": "# Größe\n",
    "latin-1": "# Größe\n",
    "cp1252": "# Größe – “cell”\n",
}


def _nodes(tree, at=()):
    """The paths (keys and indices) of every node of a parsed file below its root."""
    if isinstance(tree, dict):
        items = tree.items()
    elif isinstance(tree, list):
        items = enumerate(tree)
    else:
        return
    for key, value in items:
        yield at + (key,)
        yield from _nodes(value, at + (key,))


def _mutated(data, tree, dump) -> bytes:
    """One mutation of a parsed file, drawn by hypothesis, as the bytes of a file: a node's value replaced by
    one of another type or range, a number's sign flipped, a key or item removed, a key given twice, or the
    whole file in another encoding."""
    import copy
    import functools
    import operator
    import re

    from hypothesis import strategies as st

    tree = copy.deepcopy(tree)
    op = data.draw(st.sampled_from(["value", "negate", "delete", "duplicate", "encoding"]), label="op")
    if op == "encoding":
        encoding = data.draw(st.sampled_from(sorted(ENCODED)), label="encoding")
        return (ENCODED[encoding] + dump(tree)).encode(encoding)
    path = data.draw(st.sampled_from(list(_nodes(tree))), label="node")
    parent = functools.reduce(operator.getitem, path[:-1], tree)
    key = path[-1]
    if op == "value":
        parent[key] = data.draw(st.sampled_from(ODD_VALUES), label="value")
    elif op == "negate" and isinstance(parent[key], (int, float)) and not isinstance(parent[key], bool):
        parent[key] = -parent[key] if parent[key] else -1.0
    elif op in ("delete", "negate"):
        del parent[key]
    text = dump(tree)
    if op == "duplicate":
        lines = text.splitlines(keepends=True)
        keyed = [i for i, ln in enumerate(lines) if re.match(r'\s*(- )?"?[\w.]+"?\s*:', ln)]
        i = data.draw(st.sampled_from(keyed), label="line")
        # The line again (a list item's first key again inside its item): a scalar key holds the same value
        # twice; a section's key opens once empty, then with its block.
        lines.insert(i + 1, re.sub(r"^(\s*)- ", r"\1  ", lines[i]))
        text = "".join(lines)
    return text.encode()


def _yaml_dump(tree) -> str:
    import yaml

    return yaml.safe_dump(tree, sort_keys=False, allow_unicode=True)


def _json_dump(tree) -> str:
    import json

    return json.dumps(tree, indent=1)  # one key a line, as save() writes it; NaN and Infinity as JSON reads them


def _only_cfvol_errors(call):
    """``call()``'s result, or None if it raised a CfvolError of one line; anything else fails the test."""
    try:
        return call()
    except CfvolError as e:
        assert "\n" not in str(e), str(e)
        return None


@pytest.fixture(scope="module")
def mutation_folder(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("mutated")


def _check_mutated_workcell(data, folder: Path) -> None:
    import yaml

    import drake_cfvol as cf

    f = folder / "cell.yaml"
    f.write_bytes(_mutated(data, yaml.safe_load(AUTOMOTIVE), _yaml_dump))
    wc = _only_cfvol_errors(lambda: cf.load_workcell(str(f)))
    if wc is not None:  # a valid cell: its settings are usable numbers
        assert 0 < wc.reach < math.inf
        assert all(0 < x < math.inf for x in wc.height_map_size)
        for start, goal in wc.configurations.values():
            assert np.isfinite(start).all() and np.isfinite(goal).all()


def _check_mutated_scenario(data, folder: Path, automotive) -> None:
    import yaml

    import drake_cfvol as cf
    from drake_cfvol.comanip.scenario import load_scenario
    from drake_cfvol.comanip.scenario_checks import check_scenario_against_cell

    f = folder / "scenario.yaml"
    f.write_bytes(_mutated(data, yaml.safe_load(SCENARIO), _yaml_dump))

    def check():
        scenario, file = load_scenario(f)
        cell = scenario.cell.name
        wc = automotive if cell == "automotive" else cf.load_workcell(cell)
        check_scenario_against_cell(scenario, wc, file)
        return scenario

    scenario = _only_cfvol_errors(check)
    if scenario is not None:  # a valid scenario: its times are usable numbers
        assert 0 < scenario.control.period < scenario.path.duration < math.inf
        assert 0 < scenario.simulation.log_period < math.inf


def _check_mutated_table(data, folder: Path, saved: Path, automotive) -> None:
    import json

    from drake_cfvol.algorithm.reuse import load_bounds_for

    f = folder / "bounds.json"
    f.write_bytes(_mutated(data, json.loads((saved / "bounds.json").read_text()), _json_dump))
    table = _only_cfvol_errors(lambda: load_bounds_for(automotive, f, None, notes=[]))
    if table is not None:  # a table taken for this cell is usable in it (an invariant of its own)
        assert table.problem(automotive.position_lower, automotive.position_upper) is None
        assert table.nominal.shape[1] == automotive.num_joints


def _property(examples: int):
    from hypothesis import HealthCheck, settings

    return settings(max_examples=examples, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


FEW, MANY = 12, 200  # examples in the default group (a few seconds) and in the slow group


@_property(FEW)
@given(data=st.data())
def test_a_mutated_workcell_file_loads_or_is_refused(data, mutation_folder):
    _check_mutated_workcell(data, mutation_folder)


@_property(FEW)
@given(data=st.data())
def test_a_mutated_scenario_file_loads_or_is_refused(data, mutation_folder, automotive):
    _check_mutated_scenario(data, mutation_folder, automotive)


@_property(2 * FEW)
@given(data=st.data())
def test_a_mutated_table_file_loads_or_is_refused(data, mutation_folder, saved, automotive):
    _check_mutated_table(data, mutation_folder, saved, automotive)


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["workcell", "scenario", "table"])
@_property(MANY)
@given(data=st.data())
def test_many_mutated_files_load_or_are_refused(data, kind, mutation_folder, saved, automotive):
    if kind == "workcell":
        _check_mutated_workcell(data, mutation_folder)
    elif kind == "scenario":
        _check_mutated_scenario(data, mutation_folder, automotive)
    else:
        _check_mutated_table(data, mutation_folder, saved, automotive)


# --- 6. Interrupts ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("command", [["plan", "automotive"], ["bounds", "automotive"], ["simulate", "automotive_push"]])
def test_ctrl_c_ends_a_command_with_one_line_and_exit_130(capsys, monkeypatch, command):
    import drake_cfvol.scene.workcell as workcell

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(workcell, "load_workcell", interrupted)
    import drake_cfvol.comanip as comanip

    monkeypatch.setattr(comanip, "run_scenario", interrupted)
    capsys.readouterr()
    assert main(command) == 130
    err = capsys.readouterr().err
    assert err.strip() == "cfvol: interrupted"


def test_an_interrupted_save_leaves_no_partial_file(tmp_path, monkeypatch, bounded):
    import numpy as np

    table = bounded("automotive")
    real = np.savez

    def half_then_interrupt(f, **arrays):
        real(f, **arrays)
        raise KeyboardInterrupt

    monkeypatch.setattr(np, "savez", half_then_interrupt)
    with pytest.raises(KeyboardInterrupt):
        table.save(tmp_path / "t.npz")
    assert list(tmp_path.iterdir()) == []
