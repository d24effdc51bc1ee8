"""Every code block of the README and of the guide (docs/*.md) runs or is
checked:

- Python blocks run as written: the README's library, diagram and station
  blocks with checks of their own below, any other block as it is (a block
  after a ``<!-- slow -->`` line is in the slow group).
- Shell blocks are checked, not run (they plan, certify and simulate for
  minutes): each ``cfvol ...`` line is parsed by the command line's own
  parser, so a renamed command or option fails, and its ``--scenario-text``
  loads over its scenario; ``tools/...`` and ``python tools/...`` name files
  that exist, ``python -m X`` a module that imports; ``pip`` and ``sudo``
  lines are taken as they are.
- YAML blocks load as what they are: a batch jobs file, a workcell file (the
  cell is built), or scenario text over a bundled scenario.

The README stays a page a newcomer reads (at most 300 lines), and neither it
nor the guide's hand-written pages tell the project's history.
"""

import importlib
import importlib.util
import re
import shlex
from pathlib import Path

import numpy as np
import pytest
import yaml

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"
PAGES = [README] + sorted((ROOT / "docs").glob("*.md"))
#: Pages written by tools from other files (their sources are results and dataclasses), and the spec, kept as is.
NOT_HAND_WRITTEN = {"benchmarks.md", "configuration.md", "spec.md"}
_FENCE = re.compile(r"^```([A-Za-z]*)\n(.*?)^```", re.S | re.M)
#: The README's Python blocks that have a test of their own: name -> a string only that block holds.
OWN_TESTS = {"library": "cf.Certify(", "diagram": "MultibodyPositionToGeometryPose", "station": "FromRobotDiagram"}


def _blocks():
    """(page, line, language, code, slow) of every fenced block."""
    out = []
    for page in PAGES:
        text = page.read_text()
        for m in _FENCE.finditer(text):
            line = text.count("\n", 0, m.start()) + 1
            before = text[: m.start()].rstrip().splitlines()[-1:] or [""]
            out.append((page, line, m.group(1), m.group(2), before[0].strip() == "<!-- slow -->"))
    return out


BLOCKS = _blocks()


def _id(block):
    return f"{block[0].relative_to(ROOT)}:{block[1]}"


def _readme_block(key: str) -> str:
    (code,) = [c for p, _, lang, c, _ in BLOCKS if p == README and lang == "python" and OWN_TESTS[key] in c]
    return code


def test_every_block_has_a_language_this_file_checks():
    """A block without a language, or in one no test here checks, would run
    nowhere: name it python, bash or yaml."""
    wrong = [_id(b) for b in BLOCKS if b[2] not in ("python", "bash", "yaml")]
    assert not wrong, f"code blocks in no checked language: {wrong}"
    assert sum(b[2] == "bash" for b in BLOCKS) >= 5 and sum(b[2] == "yaml" for b in BLOCKS) >= 2


def test_own_tests_find_their_blocks():
    """Each README block with a test of its own is found exactly once, and
    only in the README (a copy elsewhere would run in neither test)."""
    for key, marker in OWN_TESTS.items():
        hits = [_id(b) for b in BLOCKS if b[2] == "python" and marker in b[3]]
        assert len(hits) == 1 and hits[0].startswith("README.md"), (key, hits)


def test_readme_is_short():
    """The README is a page a newcomer reads: at most 300 lines."""
    assert len(README.read_text().splitlines()) <= 300


@pytest.mark.parametrize("page", [p for p in PAGES if p.name not in NOT_HAND_WRITTEN], ids=lambda p: p.name)
def test_pages_tell_no_history(page):
    """No issue history or dated comparisons: no "issue", no month names,
    no "than before" in the README and the hand-written pages."""
    months = "January|February|March|April|June|July|August|September|October|November|December"
    found = re.findall(
        rf"\b(issues?|{months}|than before|previous (?:run|version|certifier))\b", page.read_text(), re.I
    )
    assert not found, f"{page.name}: {found}"


def _anchors(page: Path) -> set[str]:
    """The anchors of a page: its headings as GitHub spells them, and explicit ``<a id>``s."""
    text = page.read_text()
    heads = re.findall(r"^#+ (.+)$", _FENCE.sub("", text), re.M)
    slugs = {re.sub(r"[^\w\- ]", "", h.strip().lower()).replace(" ", "-") for h in heads}
    return slugs | set(re.findall(r'<a id="([^"]+)"', text))


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_links_resolve(page):
    """Every relative link (and image) of the README and the guide names a
    file that exists, and an anchor on a Markdown page names one of its
    headings."""
    text = _FENCE.sub("", page.read_text())
    links = re.findall(r"\]\(([^)\s]+)\)", text) + re.findall(r'src="([^"]+)"', text)
    for link in links:
        if re.match(r"[a-z]+:", link):
            continue
        target, _, anchor = link.partition("#")
        file = (page.parent / target).resolve() if target else page
        assert file.exists(), f"{page.name}: {link}"
        if anchor and file.suffix == ".md":
            assert anchor in _anchors(file), f"{page.name}: {link} (anchors: {sorted(_anchors(file))[:8]}...)"


# --- Python blocks -------------------------------------------------------------------------------------------


@pytest.mark.slow
def test_library_example_runs(tmp_path, monkeypatch, capsys):
    """The README's library block runs unchanged (in a temporary folder: it
    saves a file) and prints the certificate in words, twice in a row (the
    second run replaces its own file, as the block asks)."""
    code = _readme_block("library")
    monkeypatch.chdir(tmp_path)
    for _ in range(2):
        exec(compile(code, str(README), "exec"), {})
        assert (tmp_path / "bounds.npz").is_file()
        assert "samples uniform in the box" in capsys.readouterr().out


def test_diagram_example_runs(capsys):
    """The README's Drake-diagram block runs unchanged: it wires the systems
    by hand, simulates, and the push moves the robot off the nominal while
    the commanded motion stays inside the bounds."""
    scope = {}
    exec(compile(_readme_block("diagram"), str(README), "exec"), scope)
    out = capsys.readouterr().out
    assert "commanded configurations" in out
    q = scope["q"]
    table = scope["table"]
    times = scope["log"].FindLog(scope["simulator"].get_context()).sample_times()
    lo, hi, nominal = table.boxes_at(np.array([scope["progress"].index_at(t) for t in times]))
    assert np.all(q >= lo - 1e-12) and np.all(q <= hi + 1e-12)
    assert np.abs(q - nominal).max() > 0.1  # pushed off the nominal


@pytest.mark.slow
def test_station_example_runs(capsys):
    """The README's own-station block runs unchanged: a workcell from a
    RobotDiagram with a free part, the systems in the user's builder under
    InverseDynamicsController, a real push; every measured configuration is
    free (Drake) and the robot ends at the path's goal."""
    scope = {}
    exec(compile(_readme_block("station"), str(README), "exec"), scope)
    assert "collision-free: True" in capsys.readouterr().out
    q, table = scope["q"], scope["table"]
    lo, hi, nominal = table.at(table.g - 1)
    # At the goal the steady push holds the robot off the nominal, inside the box (within tracking).
    assert np.all(q[-1] >= lo - 0.01) and np.all(q[-1] <= hi + 0.01)
    assert np.abs(q[-1] - nominal).max() > 0.005
    assert "part" in scope["wc"].obstacles


_OTHER_PYTHON = [
    pytest.param(b, id=_id(b), marks=[pytest.mark.slow] if b[4] else [])
    for b in BLOCKS
    if b[2] == "python" and not any(m in b[3] for m in OWN_TESTS.values())
]


@pytest.mark.parametrize("block", _OTHER_PYTHON or [pytest.param(None, marks=pytest.mark.skip("none"))])
def test_other_python_blocks_run(block, tmp_path, monkeypatch):
    """Any other Python block runs as written, in a temporary folder."""
    page, line, _, code, _ = block
    monkeypatch.chdir(tmp_path)
    exec(compile("\n" * (line) + code, str(page), "exec"), {})


# --- Shell blocks --------------------------------------------------------------------------------------------


def _commands(code: str) -> list[list[str]]:
    """The command lines of a shell block (continuations joined, comments dropped)."""
    return [
        argv for argv in (shlex.split(line, comments=True) for line in code.replace("\\\n", " ").splitlines()) if argv
    ]


def _check_command(argv: list[str]) -> None:
    from drake_cfvol.apps.cli import build_parser
    from drake_cfvol.comanip import load_scenario

    if argv[0] == "tools/dev.sh":
        assert (ROOT / argv[0]).is_file()
        argv = argv[1:]
    head = argv[0]
    if head == "cfvol":
        try:
            args = build_parser().parse_args(argv[1:])
        except SystemExit as e:
            raise AssertionError(f"cfvol's parser refuses {shlex.join(argv)}") from e
        if args.command == "simulate" and args.scenario_text:
            load_scenario(args.scenario, scenario_text=args.scenario_text)
    elif head == "python" and argv[1] == "-m":
        assert importlib.util.find_spec(argv[2]) is not None, argv
    elif head == "python":
        assert (ROOT / argv[1]).is_file(), argv
    elif head.startswith("tools/"):
        assert (ROOT / head).is_file(), argv
    else:
        assert head in ("pip", "sudo"), f"a command this test does not know: {shlex.join(argv)}"


@pytest.mark.parametrize("block", [b for b in BLOCKS if b[2] == "bash"], ids=_id)
def test_shell_block_commands_exist(block):
    """Every command of a shell block exists with the options it is given
    (parsed, not run: see the module's docstring)."""
    commands = _commands(block[3])
    assert commands
    for argv in commands:
        _check_command(argv)


def test_shell_check_catches_a_wrong_option():
    """The shell check itself works: a misspelt option, an unknown command
    and a scenario field that does not exist are refused."""
    for line in (
        "cfvol bounds automotive --certfy",
        "cfvol plot automotive",
        "tools/nothing.sh",
        "cfvol simulate automotive_push --scenario-text '{no_such_field: 1}'",
    ):
        with pytest.raises(Exception):
            for argv in _commands(line):
                _check_command(argv)


# --- YAML blocks ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("block", [b for b in BLOCKS if b[2] == "yaml"], ids=_id)
def test_yaml_blocks_load(block, tmp_path):
    """A YAML block loads as a batch jobs file, a workcell file (the cell is
    built) or scenario text over a bundled scenario."""
    import drake_cfvol as cf
    from drake_cfvol.apps.batch_jobs import expand_jobs, load_jobs
    from drake_cfvol.comanip import load_scenario

    code = block[3]
    keys = set(yaml.safe_load(code))
    if {"cells", "settings"} <= keys:
        jobs, _ = load_jobs(text=code)
        assert expand_jobs(jobs)
    elif {"directives", "cfvol"} <= keys:
        file = tmp_path / "cell.yaml"
        file.write_text(code)
        wc = cf.load_workcell(file)
        assert wc.configuration("path1")
    else:
        load_scenario("automotive_push", scenario_text=code)


# --- Generated pages -----------------------------------------------------------------------------------------


def _docs_tool():
    spec = importlib.util.spec_from_file_location("docs_pages", ROOT / "tools" / "docs_pages.py")
    tool = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tool)
    return tool


def test_generated_pages_are_up_to_date():
    """docs/benchmarks.md and docs/configuration.md are what
    tools/docs_pages.py draws now: rerun it with --write after a benchmark
    run or a change to a configuration dataclass."""
    for page, draw in _docs_tool().PAGES.items():
        assert page.read_text() == draw(), f"{page.name} is stale: run python tools/docs_pages.py --write"


def test_configuration_page_lists_every_field():
    """Every field of every root dataclass and of the dataclasses nested in
    them has its row, with its default, and its description where the
    class's docstring gives one."""
    import dataclasses
    import typing

    tool = _docs_tool()
    page = tool.configuration_page()
    seen, queue = set(), [getattr(importlib.import_module(m), c) for _, m, c, _ in tool.ROOTS]
    while queue:
        cls = queue.pop()
        if cls in seen:
            continue
        seen.add(cls)
        assert f"### {cls.__name__}" in page
        hints = typing.get_type_hints(cls)
        for f in dataclasses.fields(cls):
            assert re.search(rf"^\| `{f.name}` \|", page, re.M), (cls.__name__, f.name)
            queue += tool._nested(hints[f.name])
    assert {c.__name__ for c in seen} >= {"Scenario", "WorkcellFile", "CfvolSection", "VolumeParams", "Certify"}
    from drake_cfvol.scene.params import VolumeParams

    row = next(line for line in page.splitlines() if line.startswith("| `clearance` | number | 0.02 |"))
    assert "safety margin" in row and VolumeParams().clearance == 0.02


def test_every_configuration_field_is_described():
    """Every field reachable from the configuration page's roots has a
    description (its class's ``Attributes:``, a base dataclass's, or the
    class a scenario section copies); and the check finds a field left out,
    in a class nested below a root, and keeps prose with "; name:" whole."""
    import dataclasses

    tool = _docs_tool()
    assert tool.undocumented() == [], "describe these fields in their class's Attributes: section"

    @dataclasses.dataclass
    class Planted:
        """A made-up section with one undocumented field.

        Attributes:
            described: a length, m; null: none.
        """

        described: float | None = None
        bare: float = 0.0

    @dataclasses.dataclass
    class Root:
        """A made-up root.

        Attributes:
            section: :class:`Planted`.
        """

        section: Planted = dataclasses.field(default_factory=Planted)

    assert tool.undocumented([Root]) == ["Planted.bare"]
    assert tool.descriptions(Planted) == {"described": "a length, m; null: none."}


def test_benchmark_page_holds_every_result():
    """Every committed run's results are on the page: each table row of
    each benchmarks/*/results.md, and each of its plots linked."""
    page = _docs_tool().benchmarks_page()
    for results in sorted((ROOT / "benchmarks").glob("*/results.md")):
        rows = [line for line in results.read_text().splitlines() if line.startswith("| ")]
        assert rows and all(row in page for row in rows), results
        for png in results.parent.glob("*.png"):
            assert f"](../benchmarks/{results.parent.name}/{png.name})" in page
