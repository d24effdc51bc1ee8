"""The public API's annotation share (issue 51): of the parameters and the
returns of every public function and method, how many carry a type
annotation. Public: the names in ``drake_cfvol.__all__`` and in each
subpackage's ``__all__``; for a class, its ``__init__`` and its public
methods and properties defined in the package (a Drake base class's
methods are Drake's). ``self``/``cls`` are not parameters; ``__init__``
returns nothing to annotate. mypy (CI) checks the annotations themselves."""

from __future__ import annotations

import importlib
import inspect
from collections.abc import Callable, Iterator

import pytest

import drake_cfvol
from drake_cfvol._layers import LAYERS

#: The shares last measured (652 of 652 parameters, 163 of 163 returns;
#: 436 of 646 and 125 of 161 when this test was written): the floor each may
#: not fall below. The whole public API is annotated: a new function or
#: method is annotated with it.
FLOOR = {"parameters": 1.0, "returns": 1.0}


def _python_function(obj: object) -> Callable | None:
    """The Python function behind ``obj`` (a numba dispatcher's ``py_func``),
    or None when ``obj`` is not a function."""
    obj = getattr(obj, "py_func", obj)
    return obj if inspect.isfunction(obj) else None


def _in_package(f: Callable) -> bool:
    return (getattr(f, "__module__", "") or "").startswith("drake_cfvol")


def public_callables() -> Iterator[tuple[str, Callable, bool]]:
    """(qualified name, function, whether its return counts) for every public
    function and method, each once."""
    modules = [drake_cfvol] + [importlib.import_module(f"drake_cfvol.{name}") for name in LAYERS]
    seen: set[int] = set()
    for module in modules:
        for name in getattr(module, "__all__", ()):
            obj = getattr(module, name)
            f = _python_function(obj)
            if f is not None:
                if id(f) not in seen and _in_package(f):
                    seen.add(id(f))
                    yield f"{module.__name__}.{name}", f, True
                continue
            if not inspect.isclass(obj):
                continue
            for klass in obj.__mro__:
                if not klass.__module__.startswith("drake_cfvol"):
                    continue
                for attr, member in vars(klass).items():
                    if attr.startswith("_") and attr != "__init__":
                        continue
                    if isinstance(member, (staticmethod, classmethod)):
                        member = member.__func__
                    elif isinstance(member, property):
                        member = member.fget
                    f = _python_function(member)
                    if f is None or id(f) in seen or not _in_package(f):
                        continue
                    seen.add(id(f))
                    yield f"{obj.__module__}.{obj.__qualname__}.{attr}", f, attr != "__init__"


def annotation_counts() -> dict[str, list[str]]:
    """The parameters and returns, annotated or not, by name."""
    out: dict[str, list[str]] = {"parameters": [], "parameters_missing": [], "returns": [], "returns_missing": []}
    for name, f, has_return in public_callables():
        params = list(inspect.signature(f).parameters.values())
        if params and params[0].name in ("self", "cls"):
            params = params[1:]
        for p in params:
            key = "parameters" if p.annotation is not inspect.Parameter.empty else "parameters_missing"
            out[key].append(f"{name}({p.name})")
        if has_return:
            key = (
                "returns"
                if inspect.signature(f).return_annotation is not inspect.Signature.empty
                else "returns_missing"
            )
            out[key].append(name)
    return out


def test_a_planted_function_is_counted():
    """The count sees a function's annotated and missing parts."""

    def f(a: int, b, *args, c: str = "", **kw) -> int:
        return a

    params = list(inspect.signature(f).parameters.values())
    assert [p.annotation is not inspect.Parameter.empty for p in params] == [True, False, False, True, False]
    assert _python_function(f) is f and _python_function(3) is None


@pytest.mark.parametrize("kind", ["parameters", "returns"])
def test_public_api_annotation_share(kind):
    """The public API's share of annotated parameters (returns) does not fall
    below the floor measured; it prints the share and the first gaps."""
    counts = annotation_counts()
    done, missing = counts[kind], counts[f"{kind}_missing"]
    share = len(done) / (len(done) + len(missing))
    print(f"\npublic API {kind}: {len(done)} of {len(done) + len(missing)} annotated ({share:.1%})")
    print("  not yet:", ", ".join(missing[:20]), "..." if len(missing) > 20 else "")
    assert len(done) + len(missing) > 100  # the whole API was found, not a part
    assert share >= FLOOR[kind], f"{kind}: {share:.1%} annotated, below the floor {FLOOR[kind]:.1%}"
