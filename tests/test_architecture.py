"""The package's layout: imports go one way (no cycles), and the wheel's data
is found through importlib.resources."""

import ast
from pathlib import Path

import drake_cfvol as cf

PACKAGE = Path(cf.__file__).parent


def _import_graph() -> dict[str, set[str]]:
    """Module -> package modules it imports, counting imports inside
    functions and every spelling (``from . import x``, ``from drake_cfvol.x
    import y``, ``import drake_cfvol.x``)."""
    mods = {p.stem for p in PACKAGE.glob("*.py")}
    graph: dict[str, set[str]] = {m: set() for m in mods}
    for m in mods:
        tree = ast.parse((PACKAGE / f"{m}.py").read_text())
        for node in ast.walk(tree):
            targets: list[str] = []
            if isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level == 1:
                    targets = [base.split(".")[0]] if base else [a.name for a in node.names]
                elif base == "drake_cfvol":
                    targets = [a.name for a in node.names]
                elif base.startswith("drake_cfvol."):
                    targets = [base.split(".")[1]]
            elif isinstance(node, ast.Import):
                targets = [a.name.split(".")[1] for a in node.names
                           if a.name.startswith("drake_cfvol.") and len(a.name.split(".")) > 1]
            graph[m] |= {t for t in targets if t in mods and t != m}
    return graph


def _find_cycle(graph):
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(u):
        state[u] = 1
        stack.append(u)
        for v in sorted(graph[u]):
            if state.get(v) == 1:
                return stack[stack.index(v):] + [v]
            if v not in state:
                found = visit(v)
                if found:
                    return found
        stack.pop()
        state[u] = 2
        return None

    for m in sorted(graph):
        if m not in state:
            found = visit(m)
            if found:
                return found
    return None


def test_no_import_cycles():
    """No module reaches itself through the package's imports."""
    graph = _import_graph()
    assert graph["pipeline"], "the graph parser found no imports: it is broken"
    cycle = _find_cycle(graph)
    assert cycle is None, "import cycle: " + " -> ".join(cycle)


def test_cycle_finder_finds_a_planted_cycle():
    """The cycle finder itself works: a planted a -> b -> c -> a is found."""
    assert _find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": set()}) == ["a", "b", "c", "a"]


def test_data_types_sit_below_the_pipeline():
    """The data modules import nothing from the algorithm or the systems."""
    graph = _import_graph()
    upper = {"pipeline", "sweep", "volume", "certify", "metrics", "reference", "systems", "safety", "comanip", "viz",
             "demo", "bench", "cli", "planning", "workcell", "collision"}
    for low in ("table", "heightmap", "params", "exceptions", "style", "_records"):
        assert not graph[low] & upper, f"{low} imports {graph[low] & upper}"


def test_no_module_writes_into_another_objects_dict():
    """Caches live with their owners: no ``x.__dict__[...] =`` in the package."""
    for p in PACKAGE.glob("*.py"):
        assert "__dict__" not in p.read_text(), p.name


def test_bundled_data_found_through_package_resources():
    """Models and scenarios resolve as package data (as in an installed wheel)."""
    from drake_cfvol.comanip import diagrams_dir
    from drake_cfvol.workcell import models_dir

    assert (models_dir() / "package.xml").is_file()
    assert set(cf.builtin_cells()) >= {"automotive", "aerospace"}
    assert (diagrams_dir() / "automotive_push.yaml").is_file()
