"""A workcell file's model directives made into a Drake ``RobotDiagram``:
its packages (the bundled models', the file's ``package_paths``), model
files resolved against the file's folder, STL meshes converted (Drake 1.51
refuses STL collision meshes)."""

from __future__ import annotations

import copy
from pathlib import Path

import yaml
from pydrake.multibody.parsing import ModelDirectives, ProcessModelDirectives
from pydrake.planning import RobotDiagramBuilder

from drake_cfvol.exceptions import WorkcellFormatError
from drake_cfvol.io.typed_yaml import read_yaml, read_yaml_text, yaml_error_line
from drake_cfvol.scene import meshes as _meshes
from drake_cfvol.scene.schema import models_dir
from drake_cfvol.scene.urdf import condensed_drake_warnings, fix_urdf_quirks

__all__ = ["add_packages", "diagram_from_directives", "prepare_directives"]


def add_packages(package_map, path: Path, package_paths: dict, lines: dict) -> None:
    """Adds the bundled models' package, then the file's ``package_paths``
    (folders relative to the file at ``path``)."""
    package_map.AddPackageXml(str(models_dir() / "package.xml"))
    for pname, ppath in package_paths.items():
        folder = (path.parent / str(ppath)).resolve()
        if not folder.is_dir():
            raise WorkcellFormatError(
                str(path),
                f"cfvol.package_paths.{pname}: folder '{folder}' does not exist.",
                lines.get(pname, lines.get("package_paths")),
            )
        if package_map.Contains(str(pname)):
            package_map.Remove(str(pname))
        package_map.Add(str(pname), str(folder))


#: What a model directive may do: exactly one of these per directive.
_ACTIONS = ("add_model", "add_model_instance", "add_frame", "add_weld", "add_collision_filter_group", "add_directives")


def prepare_directives(directives: list, package_map, path: Path, lines: dict, notes: list) -> list:
    """Copies of the typed directives with model files resolved (relative to
    the file at ``path``) and STL meshes converted; what the conversion did
    is appended to ``notes``."""
    out = []
    for n, d in enumerate(directives, 1):
        actions = [name for name in _ACTIONS if getattr(d, name) is not None]
        if len(actions) != 1:  # Drake checks this only in a debug build: an empty one crashes its loader
            raise WorkcellFormatError(
                str(path),
                f"directive {n} (counted from 1) must hold exactly one of {', '.join(_ACTIONS)}, "
                f"got {', '.join(actions) or 'none'}.",
                lines.get("directives"),
            )
        d = copy.deepcopy(d)
        if d.add_directives is not None:
            _check_included(str(d.add_directives.file), package_map, path, lines)
        if d.add_model is not None:
            url = str(d.add_model.file)
            if url.startswith("package://"):
                try:
                    resolved = Path(package_map.ResolveUrl(url))
                except Exception as e:
                    raise WorkcellFormatError(
                        str(path), _meshes.package_url_error(url, e, package_map) + ".", lines.get("directives")
                    ) from None
            elif url.startswith("file://"):
                resolved = Path(url[len("file://") :])
            else:
                resolved = (path.parent / url).resolve()
            if not resolved.is_file():
                raise WorkcellFormatError(
                    str(path), f"model file '{url}' not found (looked at {resolved}).", lines.get("directives")
                )
            converted, more = _meshes.convert_stl_references(resolved, package_map)
            notes.extend(more)
            quirks = fix_urdf_quirks(converted, package_map, original=resolved)
            notes.extend(quirks.notes)
            _check_world_welds(quirks, d.add_model.name, directives, path, lines)
            d.add_model.file = "file://" + str(quirks.path)
        out.append(d)
    return out


def _check_included(url: str, package_map, path: Path, lines: dict) -> None:
    """A directives file that ``add_directives`` includes, read as this
    package reads YAML (UTF-8, no key twice) before Drake reads it."""
    try:
        included = Path(package_map.ResolveUrl(url)) if "://" in url else (path.parent / url).resolve()
    except Exception as e:  # Drake raises RuntimeError for an unknown package.
        raise WorkcellFormatError(
            str(path), _meshes.package_url_error(url, e, package_map) + ".", lines.get("add_directives")
        ) from None
    if not included.is_file():
        return  # Drake names the missing file itself.
    text = read_yaml_text(
        included, "directives", lambda message: WorkcellFormatError(str(included), "the directives file " + message)
    )
    try:
        raw = read_yaml(text, tags=False)
    except yaml.YAMLError as e:
        raise WorkcellFormatError(str(included), f"not valid YAML: {yaml_error_line(e)}. Fix it there.") from None
    items = raw.get("directives") if isinstance(raw, dict) else None
    for n, d in enumerate(items if isinstance(items, list) else [], 1):
        if not (isinstance(d, dict) and len(d) == 1 and next(iter(d)) in _ACTIONS):
            raise WorkcellFormatError(
                str(included), f"directive {n} (counted from 1) must hold exactly one of {', '.join(_ACTIONS)}."
            )


def _check_world_welds(quirks, model: str, directives: list, path: Path, lines: dict) -> None:
    """A model whose file fixes a link to its own ``world`` link must not
    be welded again by the directives (Drake would refuse it obscurely)."""
    if not quirks.fixed_to_world:
        return
    for d in directives:
        if d.add_weld is not None and d.add_weld.child.split("::")[0] == model:
            raise WorkcellFormatError(
                str(path),
                f"model '{model}' ({quirks.name}) already fixes link "
                f"'{quirks.fixed_to_world[0]}' to the world through its own 'world' link, so the directive "
                f"add_weld {{parent: {d.add_weld.parent}, child: {d.add_weld.child}}} welds it twice: remove that "
                "add_weld (or the URDF's world joint).",
                lines.get("add_weld", lines.get("directives")),
            )


def diagram_from_directives(path: Path, spec, lines: dict, notes: list):
    """The RobotDiagram of a workcell file's directives.

    Returns:
        (diagram, the prepared directives: for adding the same models to
        another plant)
    """
    builder = RobotDiagramBuilder(time_step=0.0)
    parser = builder.parser()
    add_packages(parser.package_map(), path, spec.cfvol.package_paths, lines)
    directives = prepare_directives(spec.directives, parser.package_map(), path, lines, notes)
    try:
        with condensed_drake_warnings():
            ProcessModelDirectives(ModelDirectives(directives=directives), builder.plant(), parser)
    except Exception as e:  # Drake raises RuntimeError / ValueError here.
        raise WorkcellFormatError(
            str(path), f"Drake cannot load the model directives: {e}", lines.get("directives")
        ) from e
    builder.plant().Finalize()
    return builder.Build(), directives
