"""The bad-input corpus (issue 49): files, values and calls a new user may
get wrong. Each case ends with exit 2 (or a CfvolError) and one line that
names what is wrong and where; none ends in a traceback.

The cases call ``cfvol``'s ``main`` in-process (no subprocess), so the
corpus stays fast; a case that needs a planned path or a table shares the
session's fixtures.
"""

from __future__ import annotations

import textwrap
from pathlib import Path

import pytest

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


def test_a_duplicate_json_key_in_a_saved_path_is_refused(tmp_path, capsys):
    f = tmp_path / "p.json"
    f.write_text('{"format": "drake_cfvol.NominalPath", "waypoints": [[0]], "waypoints": [[1]]}')
    refused(["bounds", "automotive", "--path-file", f], capsys, str(f), "'waypoints' appears twice")
