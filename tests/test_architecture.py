"""The package's layout: subpackages in pipeline order whose imports go one
way, no cycles between modules, and the wheel's data found through
importlib.resources."""

import ast
import importlib
from pathlib import Path

import pytest

import drake_cfvol as cf
from drake_cfvol._layers import BASE as _BASE
from drake_cfvol._layers import LAYERS

PACKAGE = Path(cf.__file__).parent
BASE = set(_BASE)


def _modules(package: Path = PACKAGE) -> dict[str, Path]:
    """Dotted name (below the package ``drake_cfvol`` at ``package``) -> file, every module."""
    out = {}
    for p in package.rglob("*.py"):
        rel = p.relative_to(package).with_suffix("")
        parts = list(rel.parts)
        if "__pycache__" in parts:
            continue
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts) if parts else "__init__"] = p
    return out


def _resolve(name: str, modules: dict) -> str | None:
    """The module of the package a dotted name (below drake_cfvol) refers
    to: itself, or its longest prefix that is a module (``algorithm.certify.X``
    -> ``algorithm.certify``)."""
    parts = name.split(".")
    for n in range(len(parts), 0, -1):
        cand = ".".join(parts[:n])
        if cand in modules:
            return cand
    return None


def _import_graph(package: Path = PACKAGE) -> dict[str, set[str]]:
    """Module -> package modules it imports, counting imports inside
    functions and every spelling (``from drake_cfvol.x import y``, ``from
    drake_cfvol.x import module``, ``import drake_cfvol.x``, relative), for
    the package tree at ``package``."""
    modules = _modules(package)
    graph: dict[str, set[str]] = {m: set() for m in modules}
    for m, path in modules.items():
        package = m if path.name == "__init__.py" else m.rpartition(".")[0]
        for node in ast.walk(ast.parse(path.read_text())):
            names: list[str] = []
            if isinstance(node, ast.ImportFrom):
                if node.level:
                    base = package.split(".") if package else []
                    base = base[: len(base) - (node.level - 1)] if node.level > 1 else base
                    root = ".".join(base + ([node.module] if node.module else []))
                elif node.module == "drake_cfvol":
                    root = ""
                elif (node.module or "").startswith("drake_cfvol."):
                    root = node.module[len("drake_cfvol.") :]
                else:
                    continue
                names = [f"{root}.{a.name}" if root else a.name for a in node.names] + ([root] if root else [])
            elif isinstance(node, ast.Import):
                names = [a.name[len("drake_cfvol.") :] for a in node.names if a.name.startswith("drake_cfvol.")]
            for n in names:
                target = _resolve(n, modules)
                if target and target != m:
                    graph[m].add(target)
    return graph


def _layer(module: str) -> int | None:
    head = module.split(".")[0]
    return LAYERS.index(head) if head in LAYERS else None


def _find_cycle(graph):
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(u):
        state[u] = 1
        stack.append(u)
        for v in sorted(graph[u]):
            if state.get(v) == 1:
                return stack[stack.index(v) :] + [v]
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


def test_every_module_sits_in_a_layer():
    """Each module is one of the layers' or a base module (exceptions,
    _version), or the package's own entry points (__init__, __main__)."""
    stray = [m for m in _modules() if _layer(m) is None and m not in BASE | {"__init__", "__main__"}]
    assert not stray, f"modules outside the subpackages: {stray}"


def test_every_folder_of_code_is_a_package_and_a_layer():
    """setup.py finds the wheel's packages on disk (folders with an
    ``__init__.py``): a folder of modules without one would be left out of
    the wheel, and a subpackage missing from ``_layers.LAYERS`` would escape
    the layer check."""
    folders = {p.parent for p in PACKAGE.rglob("*.py") if "__pycache__" not in p.parts}
    no_init = sorted(str(f.relative_to(PACKAGE)) for f in folders if not (f / "__init__.py").is_file())
    assert not no_init, f"folders of modules without __init__.py (left out of the wheel): {no_init}"
    tops = {f.relative_to(PACKAGE).parts[0] for f in folders if f != PACKAGE}
    assert tops == set(LAYERS), f"subpackages {sorted(tops ^ set(LAYERS))} differ from _layers.LAYERS"


def _upward_imports(graph: dict[str, set[str]]) -> list[tuple[str, str]]:
    """The (importer, imported) pairs against the layer order: a base
    module importing anything of the package, or a module importing from a
    later layer."""
    wrong = []
    for m, targets in graph.items():
        if m in ("__init__", "__main__"):
            continue
        for t in targets:
            if m in BASE:
                wrong.append((m, t))
            elif t not in BASE and _layer(t) > _layer(m):
                wrong.append((m, t))
    return sorted(wrong)


def test_imports_go_down_the_layers():
    """A module imports only from its own subpackage, the ones before it
    in pipeline order, and the base modules; the base imports nothing."""
    graph = _import_graph()
    assert graph["algorithm.pipeline"] >= {"algorithm.sweep", "scene.params"}, "the parser found no imports"
    wrong = _upward_imports(graph)
    assert not wrong, "imports against the layer order: " + ", ".join(f"{a} -> {b}" for a, b in wrong)


def _plant_tree(root: Path, files: dict[str, str]) -> Path:
    """A package tree ``root/drake_cfvol`` of the given files (path ->
    source), every folder a package."""
    package = root / "drake_cfvol"
    for rel, text in {"__init__.py": "", **files}.items():
        f = package / rel
        f.parent.mkdir(parents=True, exist_ok=True)
        (f.parent / "__init__.py").touch()
        f.write_text(text)
    return package


def test_layer_check_catches_a_planted_upward_import(tmp_path):
    """The check itself works on a planted tree: an algorithm module
    importing a system (inside a function, relatively, or by ``import``)
    and a base module importing the package are caught; a system importing
    the algorithm, a module importing its own layer or the base, are not."""
    package = _plant_tree(
        tmp_path,
        {
            "exceptions.py": "from drake_cfvol.io import records\n",
            "io/records.py": "X = 1\n",
            "algorithm/certify.py": "def f():\n    from drake_cfvol.systems.filter.safety import SafetyFilter\n",
            "algorithm/sweep.py": "from ..comanip import run\nfrom drake_cfvol.algorithm import certify\n",
            "algorithm/table.py": "import drake_cfvol.apps.cli\nfrom drake_cfvol.io.records import X\n",
            "systems/filter/safety.py": "from drake_cfvol.algorithm.certify import f\nfrom drake_cfvol.exceptions import E\n",
            "comanip/run.py": "",
            "apps/cli.py": "",
        },
    )
    assert _upward_imports(_import_graph(package)) == [
        ("algorithm.certify", "systems.filter.safety"),
        ("algorithm.sweep", "comanip"),
        ("algorithm.sweep", "comanip.run"),
        ("algorithm.table", "apps.cli"),
        ("exceptions", "io"),
        ("exceptions", "io.records"),
    ]


def test_cycle_check_catches_a_planted_cycle(tmp_path):
    """The import graph of a planted tree whose modules import each other
    in a ring (one import inside a function, one relative) has that cycle."""
    package = _plant_tree(
        tmp_path,
        {
            "scene/a.py": "from drake_cfvol.scene.b import B\n",
            "scene/b.py": "def g():\n    import drake_cfvol.scene.c\n",
            "scene/c.py": "from . import a\n",
            "scene/d.py": "from drake_cfvol.scene import a\n",
        },
    )
    assert _find_cycle(_import_graph(package)) == ["scene.a", "scene.b", "scene.c", "scene.a"]


def test_no_import_cycles():
    """No module reaches itself through the package's imports."""
    cycle = _find_cycle(_import_graph())
    assert cycle is None, "import cycle: " + " -> ".join(cycle)


def test_cycle_finder_finds_a_planted_cycle():
    """The cycle finder itself works: a planted a -> b -> c -> a is found."""
    assert _find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": set()}) == ["a", "b", "c", "a"]


@pytest.mark.parametrize("old", ["certify", "workcell", "safety", "viz", "cli", "_records", "bench"])
def test_old_module_names_are_gone(old):
    """The flat module names of 0.1 (``drake_cfvol.certify``, ...) were
    removed in 0.3 (CHANGELOG.md): they no longer import."""
    with pytest.raises(ModuleNotFoundError):
        importlib.import_module(f"drake_cfvol.{old}")


@pytest.mark.parametrize(
    "old",
    [
        "safety",
        "constraints",
        "damper",
        "damper_kernel",
        "damper_kinematics",
        "damper_parts",
        "filter_kernel",
        "qp",
        "warmup",
    ],
)
def test_the_filter_modules_moved(old):
    """The safety filter's flat modules in ``systems`` moved to ``systems.filter`` in 0.10
    (CHANGELOG.md): the old paths no longer import."""
    with pytest.raises(ModuleNotFoundError):
        importlib.import_module(f"drake_cfvol.systems.{old}")


#: What the safety filter takes from the rest of the systems layer: the shared helpers.
FILTER_NEEDS = {"systems._util", "systems.columns"}


def _in_filter(module: str) -> bool:
    return module == "systems.filter" or module.startswith("systems.filter.")


def _filter_reaches_out(graph: dict[str, set[str]]) -> list[tuple[str, str]]:
    """The (filter module, systems module) pairs where ``systems.filter`` imports a module of the
    systems layer outside it other than :data:`FILTER_NEEDS`."""
    return sorted(
        (m, t)
        for m, targets in graph.items()
        if _in_filter(m)
        for t in targets
        if _layer(t) == LAYERS.index("systems") and not _in_filter(t) and t not in FILTER_NEEDS
    )


def test_the_filter_stands_below_the_other_systems():
    """The safety filter (``systems.filter``) is a subpackage of the systems layer that the stations
    build on: it imports from the rest of the layer only its shared helpers, never a station."""
    graph = _import_graph()
    assert graph["systems.station"] >= {"systems.filter.safety"}, "the parser found no filter import"
    assert not _filter_reaches_out(graph), _filter_reaches_out(graph)


def test_the_filter_check_catches_a_planted_import(tmp_path):
    """Planted: a filter module importing the station (inside a function), and one importing the
    systems' helpers and its own subpackage, which pass."""
    package = _plant_tree(
        tmp_path,
        {
            "systems/_util.py": "",
            "systems/station.py": "from drake_cfvol.systems.filter.safety import F\n",
            "systems/filter/safety.py": "def f():\n    from drake_cfvol.systems import station\n",
            "systems/filter/qp.py": "from drake_cfvol.systems._util import x\nfrom . import safety\n",
        },
    )
    assert _filter_reaches_out(_import_graph(package)) == [
        ("systems.filter.safety", "systems"),
        ("systems.filter.safety", "systems.station"),
    ]


@pytest.mark.parametrize("old", ["certify", "boundary", "boundary_regions", "cuts", "cert_cache"])
def test_the_certificate_modules_moved(old):
    """The certificate's flat modules in ``algorithm`` moved to ``algorithm.certificate`` in 0.11
    (CHANGELOG.md): the old paths no longer import."""
    with pytest.raises(ModuleNotFoundError):
        importlib.import_module(f"drake_cfvol.algorithm.{old}")


def _in_certificate(module: str) -> bool:
    return module == "algorithm.certificate" or module.startswith("algorithm.certificate.")


#: The one module of the paper's method that calls the certificate: the pipeline (Algorithm 1
#: with ``certify=``).
CERTIFICATE_CALLERS = {"algorithm.pipeline"}


def _method_reaches_certificate(graph: dict[str, set[str]]) -> list[tuple[str, str]]:
    """The (method module, certificate module) pairs where a module of the paper's method (the
    algorithm layer outside ``algorithm.certificate``) other than :data:`CERTIFICATE_CALLERS`
    imports the certificate."""
    return sorted(
        (m, t)
        for m, targets in graph.items()
        if _layer(m) == LAYERS.index("algorithm") and not _in_certificate(m) and m not in CERTIFICATE_CALLERS
        for t in targets
        if _in_certificate(t)
    )


def test_the_method_stands_apart_from_the_certificate():
    """The paper's method does not use the certificate built on it: only the pipeline calls it."""
    graph = _import_graph()
    assert graph["algorithm.pipeline"] >= {"algorithm.certificate.certify"}, "the parser found no certificate import"
    assert graph["algorithm.certificate.certify"] >= {"algorithm.table"}, "the parser found no method import"
    assert not _method_reaches_certificate(graph), _method_reaches_certificate(graph)


def test_the_certificate_check_catches_a_planted_import(tmp_path):
    """Planted: the sweep importing the certificate's cuts (inside a function); the pipeline's
    import passes."""
    package = _plant_tree(
        tmp_path,
        {
            "algorithm/pipeline.py": "from drake_cfvol.algorithm.certificate.certify import C\n",
            "algorithm/sweep.py": "def f():\n    from drake_cfvol.algorithm.certificate import cuts\n",
            "algorithm/certificate/cuts.py": "from drake_cfvol.algorithm.table import T\n",
            "algorithm/certificate/certify.py": "",
        },
    )
    assert _method_reaches_certificate(_import_graph(package)) == [
        ("algorithm.sweep", "algorithm.certificate"),
        ("algorithm.sweep", "algorithm.certificate.cuts"),
    ]


@pytest.mark.parametrize("old", ["apps.batch", "comanip.checks", "algorithm.regions"])
def test_the_repeated_module_names_moved(old):
    """The modules whose names repeated another layer's were renamed in 0.10 (CHANGELOG.md):
    the old paths no longer import."""
    with pytest.raises(ModuleNotFoundError):
        importlib.import_module(f"drake_cfvol.{old}")


def test_comanipulation_takes_its_siblings_spelling():
    """``Comanipulation`` is ``CoManipulation`` since 0.10, beside ``AddCoManipulation`` and
    ``CoManipulationConfig``; no alias keeps the old name."""
    import drake_cfvol.comanip as comanip

    assert hasattr(comanip, "CoManipulation")
    assert not hasattr(comanip, "Comanipulation")


def _repeated_module_names(package: Path = PACKAGE) -> dict[str, list[str]]:
    """Module basename -> its modules (dotted, below the package at ``package``), for every
    basename two or more modules share; ``__init__`` and ``__main__`` are not names of their own."""
    by_name: dict[str, list[str]] = {}
    for m, path in _modules(package).items():
        if path.stem not in ("__init__", "__main__"):
            by_name.setdefault(path.stem, []).append(m)
    return {n: sorted(ms) for n, ms in sorted(by_name.items()) if len(ms) > 1}


def test_no_module_name_repeats():
    """Each module's own name says what it holds, once in the package: two layers' ``regions``
    (or ``checks``, ``batch``) leave a reader, a traceback and a search to tell them apart by
    their path."""
    assert "algorithm.certificate.boundary_regions" in _modules(), "the tree walk found no modules"
    repeated = _repeated_module_names()
    assert not repeated, f"module names used twice: {repeated}"


def test_the_repeated_name_check_catches_a_planted_pair(tmp_path):
    """Planted: ``regions`` in two layers and ``checks`` in a layer and its subpackage are caught;
    the ``__init__`` of every folder and names met once are not."""
    package = _plant_tree(
        tmp_path,
        {
            "kernel/regions.py": "",
            "algorithm/regions.py": "",
            "systems/checks.py": "",
            "systems/filter/checks.py": "",
            "systems/filter/qp.py": "",
            "__main__.py": "",
        },
    )
    assert _repeated_module_names(package) == {
        "checks": ["systems.checks", "systems.filter.checks"],
        "regions": ["algorithm.regions", "kernel.regions"],
    }


def test_public_api_and_readme_paths_import():
    """Every name of ``drake_cfvol.__all__`` and the module paths the README
    shows (systems, exceptions, comanip, kernel) still import."""
    for name in cf.__all__:
        assert hasattr(cf, name), name
    for mod, attr in (
        ("systems", "JointBoundsSource"),
        ("systems", "SafetyFilter"),
        ("exceptions", "CfvolError"),
        ("comanip", "run_scenario"),
        ("kernel", "warm_up"),
    ):
        assert hasattr(importlib.import_module(f"drake_cfvol.{mod}"), attr), (mod, attr)


def test_no_module_writes_into_another_objects_dict():
    """Caches live with their owners: no ``x.__dict__[...] =`` in the package."""
    for p in _modules().values():
        assert "__dict__" not in p.read_text(), p


def test_bundled_data_found_through_package_resources():
    """Models and scenarios resolve as package data (as in an installed wheel)."""
    from drake_cfvol.comanip import diagrams_dir
    from drake_cfvol.scene.workcell import models_dir

    assert (models_dir() / "package.xml").is_file()
    assert set(cf.builtin_cells()) >= {"automotive", "aerospace"}
    assert (diagrams_dir() / "automotive_push.yaml").is_file()


def test_layout_page_is_drawn_from_the_tree():
    """The guide's layout section (docs/layout.md) is what tools/layout.py
    draws from the package tree now (every subpackage and module, with its
    docstring's first sentence): rerun ``tools/layout.py --write`` after a
    change."""
    import importlib.util

    root = PACKAGE.parent
    spec = importlib.util.spec_from_file_location("layout_tool", root / "tools" / "layout.py")
    tool = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tool)
    drawn = tool.layout()
    assert "`algorithm/`" in drawn and "`safety`" in drawn
    assert drawn in (root / "docs" / "layout.md").read_text()


def test_size_report_sees_planted_long_function():
    """tools/sizes.py is a report, not a gate: it lists, and the counter sees
    a planted function over 80 lines and a compiled function with more than
    12 parameters, and nothing in a short module beside them."""
    import importlib.util
    import tempfile

    spec = importlib.util.spec_from_file_location("sizes_tool", PACKAGE.parent / "tools" / "sizes.py")
    tool = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tool)
    with tempfile.TemporaryDirectory() as d:
        pkg = Path(d) / "pkg"
        pkg.mkdir()
        body = "\n".join(f"    x{i} = {i}" for i in range(90))
        (pkg / "m.py").write_text(
            f"def long():\n{body}\n\n\nfrom numba import njit\n\n\n@njit\n"
            f"def many({', '.join(f'a{i}' for i in range(13))}):\n    return a0\n"
        )
        short = "\n".join(f"    y{i} = {i}" for i in range(79))
        (pkg / "ok.py").write_text(f"def short():\n{short}\n")
        planted = tool.violations(pkg)
        found = {(kind, where.split()[-1], size) for kind, where, size in planted}
    assert found == {("function", "long", 91), ("compiled parameters", "many", 13)}
    tool.violations = lambda: planted  # the report on a tree over the limits still exits 0
    assert tool.main() == 0


_PYDRAKE_PROBE = (
    "import sys, importlib\n"
    "for m in sys.argv[1:]:\n"
    "    importlib.import_module(m)\n"
    "print(' '.join(sorted({n.split('.')[0] for n in sys.modules if n.split('.')[0] == 'pydrake'})))\n"
)


def _pydrake_after(*modules: str) -> list:
    """The pydrake packages a fresh interpreter holds after importing ``modules``."""
    import subprocess
    import sys

    out = subprocess.run(
        [sys.executable, "-c", _PYDRAKE_PROBE, *modules], capture_output=True, text=True, check=True
    ).stdout
    return out.splitlines()[-1].split() if out.strip() else []


def test_the_top_level_and_the_cli_load_no_pydrake():
    """``import drake_cfvol``, the CLI module and the push patterns it lists
    (through the lazy ``drake_cfvol.comanip``) load no pydrake (the public
    names that need it are imported on first use); the probe itself sees
    pydrake where a module does import it (a planted violation: the
    workcell module), so its empty answer means something."""
    assert _pydrake_after("drake_cfvol", "drake_cfvol.apps.cli", "drake_cfvol.comanip.push_patterns") == []
    assert _pydrake_after("drake_cfvol.scene.workcell") == ["pydrake"]


def test_every_public_name_resolves():
    """Every name of ``drake_cfvol.__all__`` is reachable, lazily or not, and
    is the object its module defines."""
    for name in cf.__all__:
        value = getattr(cf, name)
        if name in cf._LAZY:
            assert value is getattr(importlib.import_module(cf._LAZY[name]), name)
    assert cf.algorithm.certificate.certify.Certify is cf.Certify
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        cf.nope  # noqa: B018


def test_every_name_of_the_lazy_comanip_resolves():
    """``drake_cfvol.comanip`` imports its names on first use: each of its
    ``__all__`` is in its lazy table and is the object its module defines,
    and the type checker's imports name the same modules."""
    import ast

    import drake_cfvol.comanip as comanip

    assert set(comanip.__all__) == set(comanip._LAZY)
    for name in comanip.__all__:
        assert getattr(comanip, name) is getattr(importlib.import_module(comanip._LAZY[name]), name)
    tree = ast.parse(Path(comanip.__file__).read_text())
    checked = {
        alias.name: node.module
        for block in tree.body
        if isinstance(block, ast.If)
        for node in block.body
        if isinstance(node, ast.ImportFrom)
        for alias in node.names
    }
    assert checked == comanip._LAZY


def _subpackage(module: str) -> str:
    """The subpackage a module belongs to ('' for the top level's own modules)."""
    return module.split(".")[0] if "." in module or module in LAYERS else ""


def _private_crossings(package: Path = PACKAGE) -> set[tuple[str, str, str]]:
    """(module, the module it takes it from, name) for every private name
    (one leading underscore) a module takes from another subpackage's
    module: imported by name, or read as an attribute of a module imported
    under an alias (``import drake_cfvol.kernel as K``; ``K._V0``)."""
    modules = _modules(package)
    out = set()
    for m, path in modules.items():
        tree = ast.parse(path.read_text())
        aliases = {}
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and (node.module or "").split(".")[0] == "drake_cfvol":
                below = node.module[len("drake_cfvol.") :] if "." in node.module else ""
                source = _resolve(below, modules) if below else None
                for a in node.names:
                    target = _resolve(f"{below}.{a.name}" if below else a.name, modules)
                    if target and target != source:  # a module imported by name
                        aliases[a.asname or a.name] = target
                    elif a.name.startswith("_") and not a.name.startswith("__"):
                        if source and _subpackage(source) != _subpackage(m):
                            out.add((m, source, a.name))
            elif isinstance(node, ast.Import):
                for a in node.names:
                    if a.name.startswith("drake_cfvol.") and a.asname:
                        aliases[a.asname] = _resolve(a.name[len("drake_cfvol.") :], modules)
        for node in ast.walk(tree):
            if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id in aliases:
                source = aliases[node.value.id]
                private = node.attr.startswith("_") and not node.attr.startswith("__")
                if private and source and _subpackage(source) != _subpackage(m):
                    out.add((m, source, node.attr))
    return out


def _private_exports(package: Path = PACKAGE) -> set[tuple[str, str]]:
    """(module, name) for every private name (one leading underscore) a
    module lists in its ``__all__`` (assigned or extended)."""
    out = set()
    for m, path in _modules(package).items():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Assign):
                targets, value = node.targets, node.value
            elif isinstance(node, (ast.AugAssign, ast.AnnAssign)):
                targets, value = [node.target], node.value
            else:
                continue
            if value is None or not any(isinstance(t, ast.Name) and t.id == "__all__" for t in targets):
                continue
            for c in ast.walk(value):
                if isinstance(c, ast.Constant) and isinstance(c.value, str):
                    if c.value.startswith("_") and not c.value.startswith("__"):
                        out.add((m, c.value))
    return out


def test_no_private_name_crosses_a_subpackage():
    """A private name stays inside its subpackage: no module takes one from
    another subpackage, and no module exports one in its ``__all__``."""
    assert not _private_crossings(), sorted(_private_crossings())
    assert not _private_exports(), sorted(_private_exports())


def test_the_private_name_check_finds_planted_crossings(tmp_path):
    """Planted: a private function imported from another subpackage, and a
    private constant read through a module alias; a private name within its
    own subpackage is fine."""
    package = _plant_tree(
        tmp_path,
        {
            "scene/a.py": "_HIDDEN = 1\ndef _helper():\n    pass\n",
            "scene/b.py": "from drake_cfvol.scene.a import _helper\n",
            "systems/c.py": "from drake_cfvol.scene.a import _helper\n",
            "systems/d.py": "import drake_cfvol.scene.a as A\nx = A._HIDDEN\n",
            "systems/e.py": "from drake_cfvol import scene as S\nx = S._TOP\n",
        },
    )
    assert _private_crossings(package) == {
        ("systems.c", "scene.a", "_helper"),
        ("systems.d", "scene.a", "_HIDDEN"),
        ("systems.e", "scene", "_TOP"),
    }


def test_the_private_export_check_finds_planted_exports(tmp_path):
    """Planted: a subpackage's ``__all__`` holding private names (assigned,
    annotated and extended), beside public and dunder names, which pass."""
    package = _plant_tree(
        tmp_path,
        {
            "kernel/__init__.py": '_K = 0\nfk = 1\n__all__ = ["fk", "_K"]\n',
            "kernel/types.py": '__all__: list[str] = ["SHAPE_W", "__version__"]\n__all__ += ["_V0"]\n',
            "scene/a.py": '__all__ = ("shape_cover",)\n',
        },
    )
    assert _private_exports(package) == {("kernel", "_K"), ("kernel.types", "_V0")}


#: The safety filter's module docstring points to its theory's one document and stays short.
SAFETY_DOC_LINES = 30


def _safety_doc_problems(source: str) -> list[str]:
    """What is wrong with a safety module's docstring (``source``: the module's text): longer than
    :data:`SAFETY_DOC_LINES` lines, or no pointer to docs/safety.md."""
    doc = ast.get_docstring(ast.parse(source), clean=False) or ""
    problems = []
    if len(doc.splitlines()) > SAFETY_DOC_LINES:
        problems.append(f"{len(doc.splitlines())} lines (at most {SAFETY_DOC_LINES})")
    if "docs/safety.md" not in doc:
        problems.append("no pointer to docs/safety.md")
    return problems


def test_safety_module_docstring_points_to_the_theory():
    """The filter's theory is written once, in docs/safety.md: systems/filter/safety.py's module docstring says
    what the system is in at most 30 lines and points there."""
    assert _safety_doc_problems((PACKAGE / "systems" / "filter" / "safety.py").read_text()) == []


def test_safety_docstring_check_catches_a_long_docstring():
    """Planted: a 31-line docstring that points to docs/safety.md, and a short one that does not."""
    long = '"""A filter.\n' + "More theory.\n" * 29 + 'docs/safety.md"""\n'
    assert _safety_doc_problems(long) == ["31 lines (at most 30)"]
    assert _safety_doc_problems('"""A filter."""\n') == ["no pointer to docs/safety.md"]
    assert _safety_doc_problems('"""A filter; its theory: docs/safety.md."""\n') == []
