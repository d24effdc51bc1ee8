"""Robots as ROS ships them: the common URDF quirks, and Drake's parser
warnings condensed.

- Transmissions whose actuator names clash (``motor`` in every one): Drake
  refuses the model; a copy with each clashing actuator renamed
  ``<joint>_<actuator>`` is loaded, with a one-line note.
- A ``world`` link with a joint fixing the base to it: Drake welds the base
  to the world itself, so a workcell's ``add_weld`` of the same model is
  refused with a one-line error naming the fix.
- Links that carry geometry but no ``<inertial>``: Drake gives them no
  mass; fine for the bounds and for kinematic runs, noted in one line (a
  dynamic run needs their inertias).
- Drake's parser warnings (inertias that fail its triangle test, joint
  friction it ignores, ...): one line per kind and file instead of one
  block per element (:func:`condensed_drake_warnings`).

The user's files are never changed: fixed copies go to the cache.
"""

from __future__ import annotations

import contextlib
import hashlib
import logging
import re
import xml.etree.ElementTree as ET
from collections import Counter
from pathlib import Path
from typing import TYPE_CHECKING

from drake_cfvol.io.cache import write_atomic
from drake_cfvol.scene import meshes as _meshes

if TYPE_CHECKING:
    from pydrake.multibody.parsing import Parser

__all__ = ["AddModels", "UrdfQuirks", "fix_urdf_quirks", "condensed_drake_warnings"]

_LOG = logging.getLogger("drake_cfvol")


class UrdfQuirks:
    """What :func:`fix_urdf_quirks` found in one file.

    Attributes:
        path: the file to load (the user's, or a fixed copy in the cache).
        notes: one line per quirk handled.
        fixed_to_world: links the file itself fixes to the ``world`` link.
        name: the user's file's name (for messages).
    """

    def __init__(self, path: Path, notes: list[str], fixed_to_world: list[str], name: str = ""):
        self.path, self.notes, self.fixed_to_world = path, notes, fixed_to_world
        self.name = name or Path(path).name


def _rename_clashing_actuators(root, name: str) -> list[str]:
    actuators = [(t, a) for t in root.iter("transmission") for a in t.iter("actuator")]
    counts = Counter(a.get("name") for _, a in actuators)
    clashing = {n for n, c in counts.items() if c > 1}
    if not clashing:
        return []
    for t, a in actuators:
        if a.get("name") in clashing:
            joint = next(iter(t.iter("joint")), None)
            a.set("name", f"{joint.get('name') if joint is not None else t.get('name')}_{a.get('name')}")
    listed = ", ".join(f"'{n}' ({counts[n]} transmissions)" for n in sorted(clashing))
    return [
        f"{name}: actuator names {listed} clash (Drake needs them unique); loaded a copy with each renamed "
        "<joint>_<actuator> (your file is unchanged)."
    ]


def _massless_links(root, name: str) -> list[str]:
    moved = {
        j.find("child").get("link")
        for j in root.iter("joint")
        if j.get("type") not in ("fixed", None) and j.find("child") is not None
    }
    bare = sorted(
        link.get("name")
        for link in root.iter("link")
        if link.find("inertial") is None
        and link.get("name") in moved
        and (link.find("collision") is not None or link.find("visual") is not None)
    )
    if not bare:
        return []
    return [
        f"{name}: link(s) {', '.join(bare)} have geometry but no <inertial>; Drake gives them no mass (fine for "
        "the bounds and kinematic runs; add <inertial> for a dynamic run)."
    ]


def fix_urdf_quirks(model_file: Path, package_map, original: Path | None = None) -> UrdfQuirks:
    """Checks a URDF for the common ROS quirks (see the module's docs) and
    returns the file to load.

    Args:
        model_file: the URDF (perhaps already a converted copy).
        package_map: Drake's package map (to make mesh references absolute
            in a copy).
        original: the user's file the notes should name (default ``model_file``).
    """
    model_file = Path(model_file)
    name = Path(original or model_file).name
    if model_file.suffix.lower() != ".urdf":
        return UrdfQuirks(model_file, [], [])
    try:
        root = ET.parse(model_file).getroot()
    except ET.ParseError:
        return UrdfQuirks(model_file, [], [])  # Drake's parser names the syntax error
    world = [
        str(child.get("link"))
        for j in root.iter("joint")
        if (parent := j.find("parent")) is not None
        and parent.get("link") == "world"
        and (child := j.find("child")) is not None
    ]
    notes = _massless_links(root, name)
    renamed = _rename_clashing_actuators(root, name)
    if not renamed:
        return UrdfQuirks(model_file, notes, world, name)
    for mesh in root.iter("mesh"):  # the copy lives elsewhere: absolute mesh references
        uri = mesh.get("filename", "")
        path = _meshes._resolve(uri, model_file, package_map)
        if path is not None:
            mesh.set("filename", "file://" + str(path))
    text = ET.tostring(root, encoding="unicode")
    digest = hashlib.sha256(text.encode()).hexdigest()[:16]
    out = _meshes.cache_dir() / "models" / f"{model_file.stem}_{digest}.urdf"
    out.parent.mkdir(parents=True, exist_ok=True)
    if not out.is_file():
        write_atomic(out, text)
    _meshes._remember(out, Path(original or model_file).resolve())
    return UrdfQuirks(out, renamed + notes, world, name)


def _kind(message: str) -> tuple[str, str]:
    """(file, kind) of a Drake parser warning: its first line's text after
    'warning:', numbers and quoted names left out."""
    first = message.strip().splitlines()[0] if message.strip() else ""
    m = re.match(r"(.*?):\d+: warning: (.*)", first)
    file, text = (m.group(1), m.group(2)) if m else ("", first)
    text = text.split(". ")[0]  # its first sentence
    text = re.sub(r"[-+]?\d[\d.e+-]*", "#", text)
    return file, (text[:100] + ("..." if len(text) > 100 else "")).rstrip(" .:")


class _Collector(logging.Handler):
    def __init__(self):
        super().__init__(logging.WARNING)
        self.records: list[str] = []

    def emit(self, record) -> None:
        self.records.append(record.getMessage())


@contextlib.contextmanager
def condensed_drake_warnings(notes: list[str] | None = None, *, log: bool = True):
    """Within the block, Drake's warnings are collected instead of printed;
    after it, one line per (file, kind) with its count goes (with ``log``)
    to the ``drake_cfvol`` logger as a warning, and to ``notes`` if given."""
    logger = logging.getLogger("drake")
    collector = _Collector()
    for f in logger.filters:  # the cache's file names mapped back to the user's
        collector.addFilter(f)
    old = logger.propagate, list(logger.handlers)
    logger.handlers, logger.propagate = [collector], False
    try:
        yield
    finally:
        logger.propagate, logger.handlers = old
        kinds = Counter(_kind(m) for m in collector.records)
        for (file, kind), n in sorted(kinds.items()):
            line = f"{file or 'drake'}: {n} parser warning(s): {kind}"
            if notes is not None:
                notes.append(line)
            if log:
                _LOG.warning("%s", line)


def AddModels(
    parser: Parser, *, file: str | Path | None = None, url: str | None = None, notes: list[str] | None = None
) -> list:
    """Drake's ``Parser.AddModels`` for a user's own robot file, as a
    workcell file's directives load it: STL meshes converted (Drake 1.51
    refuses STL collision meshes), the URDF quirks above fixed or refused,
    Drake's warnings condensed. For building your own ``RobotDiagram``
    (:meth:`drake_cfvol.Workcell.FromRobotDiagram`) from ROS-style files.

    Args:
        parser: the ``Parser`` of the plant to add to.
        file: a model file path; or
        url: a ``package://`` (or ``file://``) URL, resolved by the parser's
            package map (the bundled models' ``drake_cfvol_models`` package
            is added to it if missing).
        notes: a list the notes (conversions, fixes) are appended to; they
            are logged at INFO level too.

    Returns:
        The added model instances (as ``Parser.AddModels``).

    Raises:
        WorkcellFormatError: the file is missing, or a referenced mesh is.
    """
    from drake_cfvol.exceptions import WorkcellFormatError

    if (file is None) == (url is None):
        raise WorkcellFormatError(str(file or url), "give exactly one of file= or url=.")
    package_map = parser.package_map()
    if not package_map.Contains("drake_cfvol_models"):  # the bundled models, by package:// URL
        from drake_cfvol.scene.schema import models_dir

        package_map.AddPackageXml(str(models_dir() / "package.xml"))
    if url is not None:
        try:
            path = Path(package_map.ResolveUrl(url))
        except Exception as e:
            raise WorkcellFormatError(url, _meshes.package_url_error(url, e, package_map) + ".") from None
    else:
        assert file is not None  # exactly one of file and url (checked above)
        path = Path(file).expanduser().resolve()
    if not path.is_file():
        raise WorkcellFormatError(str(path), "model file not found.")
    converted, said = _meshes.convert_stl_references(path, package_map)
    quirks = fix_urdf_quirks(converted, package_map, original=path)
    for note in said + quirks.notes:
        _LOG.info("%s", note)
        if notes is not None:
            notes.append(note)
    with condensed_drake_warnings(notes):
        return parser.AddModels(str(quirks.path))
