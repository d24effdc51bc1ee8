"""Typed YAML files with friendly errors: the one loader of the package's
YAML files (workcells, scenarios, batch jobs). A file is read as UTF-8,
parsed with no key given twice, checked field by field against its
dataclass (unknown keys, values of the wrong type, each named with its
field, line and fix), then read with pydrake's ``yaml_load_typed``, as
Drake's hardware_sim reads its scenarios.
"""

from __future__ import annotations

import dataclasses
import re
import types
import typing
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, TypeVar

import yaml

from drake_cfvol.exceptions import CfvolError, FileError

__all__ = [
    "DuplicateKeyError",
    "ErrorFactory",
    "check_fields",
    "key_lines",
    "load_typed",
    "read_yaml",
    "read_yaml_text",
    "yaml_error_line",
]

T = TypeVar("T")

#: Makes a caller's error from (field or None, what is wrong, line or None).
#: With a field, the text is a predicate on it ("must be a number, got
#: 'x'"); without, a predicate on the file ("is not valid YAML (...)").
#: Neither ends with a full stop.
ErrorFactory = Callable[[str | None, str, int | None], CfvolError]


class DuplicateKeyError(yaml.constructor.ConstructorError):
    """A mapping names one key twice (PyYAML and Drake's reader would keep
    the last one without a word)."""

    def __init__(self, key: str, first_line: int, mark):
        super().__init__(
            None,
            None,
            f"duplicate key '{key}' (first on line {first_line}; YAML would keep only the last): "
            "remove or rename one of them",
            mark,
        )


# libyaml's loader where PyYAML was built with it.
_SafeLoader: Any = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


class _UniqueLoader(_SafeLoader):
    """YAML's safe loader that refuses a key given twice in one mapping
    (libyaml's parser where PyYAML has it: faster than PyYAML's own)."""

    def construct_mapping(self, node, deep=False):
        if isinstance(node, yaml.MappingNode):
            seen: dict[str, int] = {}
            for key_node, _ in node.value:
                # A merge key (<<) may be overridden by design; other keys not.
                if not isinstance(key_node, yaml.ScalarNode) or key_node.tag == "tag:yaml.org,2002:merge":
                    continue
                if key_node.value in seen:
                    raise DuplicateKeyError(key_node.value, seen[key_node.value], key_node.start_mark)
                seen[key_node.value] = key_node.start_mark.line + 1
        return super().construct_mapping(node, deep)


class _TagLoader(_UniqueLoader):
    """The unique-key loader, reading a tagged node (``!IiwaDriver {...}``) as
    its plain value (Drake's reader checks the variant)."""


_TagLoader.add_multi_constructor(
    "!",
    lambda loader, suffix, node: (
        loader.construct_mapping(node)
        if isinstance(node, yaml.MappingNode)
        else loader.construct_sequence(node)
        if isinstance(node, yaml.SequenceNode)
        else loader.construct_scalar(node)
    ),
)


def read_yaml(text: str, *, tags: bool = True):
    """A YAML text as plain Python values, Drake's variant tags read as the
    value they tag (``tags=False``: refused, as YAML's safe loader does).

    Raises:
        yaml.YAMLError: not valid YAML, or a key given twice in one mapping
            (:class:`DuplicateKeyError`).
    """
    return yaml.load(text, Loader=_TagLoader if tags else _UniqueLoader)


def yaml_error_line(e: yaml.YAMLError) -> str:
    """A YAML error on one line: where (line, column) and what."""
    if isinstance(e, yaml.MarkedYAMLError):
        mark = e.problem_mark or e.context_mark
        where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark is not None else ""
        what = " ".join(x for x in (e.context, e.problem) if x)
        return where + (what or type(e).__name__)
    return " ".join(str(e).split())


_SAVE_AS_UTF8 = (
    "save it as UTF-8 (an editor's 'Save As' with encoding UTF-8; PowerShell: "
    "Get-Content FILE | Set-Content -Encoding utf8 NEW; or iconv -f {enc} -t UTF-8 FILE > NEW)"
)


def _encoding_found(data: bytes) -> str | None:
    """The encoding of a file's bytes if it is not UTF-8 (with or without
    its byte-order mark): a name for the user, or None for UTF-8."""
    if data.startswith((b"\xff\xfe\x00\x00", b"\x00\x00\xfe\xff")):
        return "UTF-32"
    if data.startswith((b"\xff\xfe", b"\xfe\xff")):
        return "UTF-16"
    if b"\x00" in data:
        head = data[:4096]
        # UTF-16 without a byte-order mark: ASCII text with every other byte 0.
        if len(head) >= 2 and (head[1::2].count(0) > 0.4 * len(head) / 2 or head[0::2].count(0) > 0.4 * len(head) / 2):
            return "UTF-16"
        return "binary"
    try:
        data.decode("utf-8")
    except UnicodeDecodeError:
        # Windows-1252 is Latin-1 with printable characters where Latin-1 has controls.
        text = data.decode("cp1252", errors="replace")
        printable = sum((c.isprintable() and c != "\ufffd") or c in "\t\r\n" for c in text)
        return "Latin-1 (or Windows-1252)" if printable > 0.95 * len(text) else "binary"
    return None


def read_yaml_text(path: Path, what: str = "YAML", error: Callable[[str], Exception] | None = None) -> str:
    """The text of a YAML file, which must be UTF-8 (a UTF-8 byte-order
    mark, as Windows' editors write it, is accepted and dropped).

    Args:
        error: makes the exception from the problem's text (default: a
            :class:`FileError` naming ``path``).

    Raises:
        FileError (or what ``error`` makes): the file cannot be read, or it
            is not UTF-8 text (the encoding found and how to save it as UTF-8
            in the message).
    """
    error = error or (lambda message: FileError(f"{what} file '{path}' {message}"))
    try:
        data = Path(path).read_bytes()
    except OSError as e:
        raise error(f"cannot be read ({e.strerror or e}).") from None
    if data.startswith(b"\xef\xbb\xbf"):
        data = data[3:]
    found = _encoding_found(data)
    if found == "binary":
        raise error(
            "holds binary data, not text (encoding found: binary). Pass the YAML text file itself, saved as UTF-8."
        )
    if found is not None:
        enc = "UTF-16" if found.startswith("UTF-16") else "UTF-32" if found == "UTF-32" else "LATIN1"
        raise error(f"is {found} text, but YAML files are read as UTF-8: " + _SAVE_AS_UTF8.format(enc=enc) + ".")
    return data.decode("utf-8")


def key_lines(text: str) -> dict[str, int]:
    """First line (1-based) of every mapping key in a YAML text: by key, by
    dotted path, and by the field name :func:`check_fields` gives it (list
    items by position, counted from 1: ``human.pushes item 2: wrench``)."""
    out: dict[str, int] = {}
    try:
        root = yaml.compose(text, Loader=_TagLoader)
    except yaml.YAMLError:
        return out

    def walk(node, prefix, field):
        if isinstance(node, yaml.MappingNode):
            for k, v in node.value:
                name = str(k.value)
                line = k.start_mark.line + 1
                sub = _field_name(field, name)
                for key in (name, prefix + name, sub):
                    out.setdefault(key, line)
                walk(v, prefix + name + ".", sub)
        elif isinstance(node, yaml.SequenceNode):
            for i, item in enumerate(node.value, 1):
                walk(item, prefix, f"{field} item {i}")

    walk(root, "", "")
    return out


def _field_name(where: str, key: object) -> str:
    """A key's field name below ``where`` (a list item's keys after a colon)."""
    if not where:
        return str(key)
    return f"{where}{': ' if re.search(r'item [0-9]+$', where) else '.'}{key}"


def _line_of(field: str, lines: Mapping[str, int]) -> int | None:
    """The line of a field (a list's scalar item: its list's line)."""
    while field not in lines:
        head, sep, tail = field.rpartition(" item ")
        if not sep or not tail.isdigit():
            return None
        field = head
    return lines[field]


def _type_name(t) -> str:
    return {int: "an integer", float: "a number", bool: "true or false", str: "a string"}.get(t, str(t))


def _is_number(value) -> bool:
    """A YAML number, or text Drake's reader takes as one (PyYAML reads
    ``1.0e6`` as text; Drake reads it as a float)."""
    if isinstance(value, bool):
        return False
    if isinstance(value, (int, float)):
        return True
    if not isinstance(value, str):
        return False  # None, a list, a mapping
    try:
        float(value)
        return True
    except ValueError:
        return False


@dataclasses.dataclass
class _Check:
    """What the field checks share: the caller's error, the keys' lines and
    the renamed fields (field -> what to write instead)."""

    error: ErrorFactory
    lines: Mapping[str, int]
    renamed: Mapping[str, str]

    def fail(self, field: str, message: str) -> CfvolError:
        return self.error(field, message, _line_of(field, self.lines))


def _check_scalar(value, t, name: str, c: _Check) -> None:
    ok = (
        isinstance(value, bool)
        if t is bool
        else isinstance(value, int) and not isinstance(value, bool)
        if t is int
        else _is_number(value)
        if t is float
        else isinstance(value, str)
    )
    if not ok:
        raise c.fail(name, f"must be {_type_name(t)}, got {value!r}")


def _check_value(value, t, name: str, c: _Check) -> None:
    """Checks one value against its type: dataclasses field by field, list
    items by their position (counted from 1), Drake's config structs by
    their field names, scalars by type."""
    origin = typing.get_origin(t)
    if origin in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(t) if a is not type(None)]
        if value is not None and len(args) == 1:
            _check_value(value, args[0], name, c)
        return  # None, or a tagged variant: Drake's reader checks it
    if dataclasses.is_dataclass(t):
        _check_mapping(value, t, name, c)
    elif origin is list:
        if not isinstance(value, list):
            raise c.fail(name, f"must be a list, got {value!r}")
        (item,) = typing.get_args(t)
        for i, v in enumerate(value, 1):
            _check_value(v, item, f"{name} item {i}", c)
    elif origin is dict:
        if not isinstance(value, dict):
            raise c.fail(name, f"must be a mapping, got {value!r}")
        for key, v in value.items():
            _check_value(v, typing.get_args(t)[1], f"{name}.{key}", c)
    elif hasattr(t, "__fields__"):  # a Drake config struct (SimulatorConfig, ModelDirective, ...)
        known = [f.name for f in t.__fields__]
        if not isinstance(value, dict):
            raise c.fail(name, f"must be a mapping of {t.__name__} fields, got {value!r}")
        for sub in value:
            if sub not in known:
                raise c.fail(_field_name(name, sub), _unknown(t.__name__, sub, known))
    elif t in (int, float, bool, str):
        _check_scalar(value, t, name, c)


def _unknown(schema: str, key: object, known: list[str]) -> str:
    return f"is not a field of {schema}: unknown key '{key}' (known fields: {', '.join(known)}); check its spelling"


def _check_mapping(raw, schema: Any, where: str, c: _Check) -> None:
    if raw is None:
        return
    if not isinstance(raw, dict):
        raise c.fail(where, f"must be a mapping of {schema.__name__} fields, got {raw!r}")
    fields = {f.name: f for f in dataclasses.fields(schema)}
    hints = typing.get_type_hints(schema)
    for key, value in raw.items():
        name = _field_name(where, key)
        if key not in fields:
            if name in c.renamed:
                raise c.fail(name, c.renamed[name])
            raise c.fail(name, _unknown(schema.__name__, key, list(fields)))
        _check_value(value, hints[key], name, c)


def check_fields(
    raw: Any,
    schema: type,
    where: str,
    error: ErrorFactory,
    *,
    lines: Mapping[str, int] | None = None,
    renamed: Mapping[str, str] | None = None,
) -> None:
    """Checks a mapping read from YAML against its dataclass before Drake
    reads it: unknown or renamed keys and values of the wrong type are named
    with the field (list items by position, counted from 1), its line
    (``lines``: :func:`key_lines`) and the fix.

    Args:
        where: the mapping's field name ("" at the file's top).
        error: makes the caller's error (:data:`ErrorFactory`).
        renamed: field -> what the error says of it (a field that moved:
            "is now 'x'; rename it").
    """
    _check_mapping(raw, schema, where, _Check(error, lines or {}, renamed or {}))


def _drake_error(e: Exception, lines: Mapping[str, int], error: ErrorFactory) -> CfvolError:
    """What Drake's reader refused, on one line: an unknown key inside one of
    Drake's own structs (named, with its line), or a value it cannot take."""
    msg = str(e)
    unknown = re.search(r"fields \[([^\]]*)\] were unknown", msg)
    if unknown:
        names = [n.strip(" '\"") for n in unknown.group(1).split(",")]
        keys = ", ".join(repr(n) for n in names)
        line = lines.get(names[0])
        # Drake names no path: the field is the first key of that name (its longest name: list items counted).
        at = [f for f, ln in lines.items() if ln == line and f.endswith((f".{names[0]}", f": {names[0]}"))]
        if not at:
            return error(None, f"has unknown key {keys}; check its spelling", line)
        return error(max(at, key=len), f"is not a field of its section: unknown key {keys}; check its spelling", line)
    flat = " ".join(msg.split())  # pybind11 lists the signatures it tried over several lines
    tried = re.search(r"self: ([\w.]+).*Invoked with: .*\), (.+)$", flat)
    if tried:  # e.g. a translation of two numbers: "a Transform field got array([1., 2.])"
        flat = f"a {tried.group(1).rsplit('.', 1)[-1]} field got {tried.group(2)}"
    return error(None, f"has a value Drake's YAML reader refuses: {flat.rstrip('.')}; fix it there", None)


def load_typed(
    schema: type[T],
    path: Path,
    error: ErrorFactory,
    *,
    text: str | None = None,
    defaults: T | None = None,
    tags: bool = True,
    keep: tuple[str, ...] | None = None,
    check_raw: Callable[[dict], None] | None = None,
    renamed: Mapping[str, str] | None = None,
) -> tuple[T, dict[str, int]]:
    """Reads a YAML file into its dataclass ``schema`` (or ``text``, named
    ``path`` in errors), every problem one error of the caller's
    (``error``, :data:`ErrorFactory`) naming the field, its line and the fix:

    1. the file's text, UTF-8 (:func:`read_yaml_text`);
    2. YAML with no key twice (:func:`read_yaml`; ``tags``: Drake's variant
       tags allowed);
    3. a mapping at the top (an empty file: no field given); ``keep``: only
       these top-level keys are read (the file's others belong to another
       reader); ``check_raw``: the caller's own checks of the mapping;
    4. every field against its type (:func:`check_fields`, ``renamed``);
    5. ``yaml_load_typed`` over ``defaults`` (None: the schema's own).

    Returns:
        (the typed file, key -> line: :func:`key_lines`)
    """
    from pydrake.common.yaml import yaml_load_typed  # here: reading the module loads no pydrake

    if text is None:
        text = read_yaml_text(path, error=lambda message: error(None, message.rstrip("."), None))
    try:
        raw = read_yaml(text, tags=tags)
    except yaml.YAMLError as e:
        mark = (e.problem_mark or e.context_mark) if isinstance(e, yaml.MarkedYAMLError) else None
        if mark is None:
            raise error(None, f"is not valid YAML ({yaml_error_line(e)}); fix it there", None) from None
        # The line goes to the error (which names it); the column stays in the text.
        what = yaml_error_line(e).split(": ", 1)[-1]
        raise error(
            None, f"is not valid YAML (column {mark.column + 1}: {what}); fix it there", mark.line + 1
        ) from None
    if raw is None:
        raw = {}
    if not isinstance(raw, dict):
        fields = ", ".join(f.name for f in dataclasses.fields(schema))  # type: ignore[arg-type]
        got = repr(raw) if len(repr(raw)) <= 60 else repr(raw)[:57] + "..."
        top = yaml.compose(text, Loader=_TagLoader)  # parsed above: the top node's line
        line = top.start_mark.line + 1 if top is not None else 1
        raise error(None, f"must hold a mapping of {schema.__name__} fields ({fields}) at its top, got {got}", line)
    lines = key_lines(text)
    if keep is not None:
        raw = {key: raw.get(key) for key in keep}
        text = yaml.safe_dump(raw, sort_keys=False)
    if check_raw is not None:
        check_raw(raw)
    check_fields(raw, schema, "", error, lines=lines, renamed=renamed)
    try:
        if defaults is None:
            typed = yaml_load_typed(schema=schema, data=text)
        else:
            typed = yaml_load_typed(schema=schema, data=text, defaults=defaults)
    except Exception as e:  # Drake raises RuntimeError / ValueError / TypeError here.
        raise _drake_error(e, lines, error) from None
    return typed, lines
