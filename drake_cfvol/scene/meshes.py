"""STL -> OBJ conversion for robot models (Drake 1.51 refuses STL collision
meshes). Converted meshes and rewritten model files are cached by content
hash; the user's files are never modified."""

from __future__ import annotations

import hashlib
import logging
import re
import struct
from pathlib import Path

import numpy as np

from drake_cfvol.exceptions import WorkcellFormatError
from drake_cfvol.io.cache import files_dir, write_atomic

_URDF_MESH = re.compile(r'(<mesh\b[^>]*?\bfilename\s*=\s*")([^"]+)(")', re.IGNORECASE)
_SDF_URI = re.compile(r"(<mesh\b[^>]*>\s*<uri>\s*)([^<\s]+)(\s*</uri>)", re.IGNORECASE | re.DOTALL)


def cache_dir() -> Path:
    """The folder for converted meshes and model files: the cache folder
    (:func:`drake_cfvol.io.cache.cache_root`), or a temporary one of this
    process's own when ``$DRAKE_CFVOL_CACHE`` is ``off``."""
    return files_dir()


def read_stl(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Reads an ASCII or binary STL file.

    Returns:
        (vertices (n, 3), faces (m, 3) int), vertices merged.
    """
    data = Path(path).read_bytes()
    tris = None
    if len(data) >= 84:
        (n,) = struct.unpack_from("<I", data, 80)
        if 84 + 50 * n == len(data):
            rec = np.frombuffer(
                data, dtype=np.dtype([("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")]), count=n, offset=84
            )
            tris = rec["v"].astype(float)
    if tris is None:
        text = data.decode("ascii", errors="replace")
        nums = re.findall(r"vertex\s+(\S+)\s+(\S+)\s+(\S+)", text)
        if not nums or len(nums) % 3:
            raise WorkcellFormatError(str(path), "not a readable STL file (neither binary nor ASCII facets).")
        tris = np.array(nums, dtype=float).reshape(-1, 3, 3)
    verts, inverse = np.unique(np.round(tris.reshape(-1, 3), 9), axis=0, return_inverse=True)
    return verts, inverse.reshape(-1, 3)


def stl_to_obj(stl: Path) -> Path:
    """Converts an STL file to OBJ in the cache; returns the OBJ's path."""
    digest = hashlib.sha256(Path(stl).read_bytes()).hexdigest()[:16]
    out = cache_dir() / "meshes" / f"{Path(stl).stem}_{digest}.obj"
    if out.is_file():
        return out
    verts, faces = read_stl(stl)
    out.parent.mkdir(parents=True, exist_ok=True)
    lines = [f"# converted from {stl} by drake_cfvol"]
    lines += [f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in verts]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in faces]
    return write_atomic(out, "\n".join(lines) + "\n")


def package_url_error(url: str, error: Exception, package_map) -> str:
    """A one-line explanation of a ``package://`` URL that does not resolve,
    with the right fix: name the package's folder, or the file is missing
    from a folder that is known."""
    rest = url[len("package://") :]
    name, _, rel = rest.partition("/")
    if package_map.Contains(name):
        folder = package_map.GetPath(name)
        return (
            f"cannot resolve '{url}': the package '{name}' is the folder {folder}, but it has no file "
            f"'{rel}'. Check the file name and where it lies in the package"
        )
    reason = str(error).strip().rstrip(".")
    return (
        f"cannot resolve '{url}': the package '{name}' is not known ({reason}). Name its folder in the "
        f"workcell's cfvol.package_paths (for example '{name}: path/to/{name}') or put a package.xml in it "
        "next to the workcell file"
    )


#: Converted copies in the cache -> the user's own file (for messages).
_ORIGINALS: dict[str, str] = {}


class _UserFileNames(logging.Filter):
    """Rewrites Drake's messages about a converted copy in the cache so
    that they name the user's own file."""

    def filter(self, record: logging.LogRecord) -> bool:
        if _ORIGINALS:
            msg = record.getMessage()
            new = msg
            for cached, original in _ORIGINALS.items():
                new = new.replace(cached, original)
            if new != msg:
                record.msg, record.args = new, None
        return True


_FILTER = _UserFileNames()


def _remember(cached: Path, original: Path) -> None:
    _ORIGINALS[str(cached)] = str(original)
    logger = logging.getLogger("drake")
    if _FILTER not in logger.filters:
        logger.addFilter(_FILTER)


def _resolve(uri: str, model_file: Path, package_map) -> Path | None:
    if uri.startswith("package://"):
        try:
            return Path(package_map.ResolveUrl(uri))
        except Exception as e:
            raise WorkcellFormatError(str(model_file), package_url_error(uri, e, package_map) + ".") from None
    if uri.startswith("file://"):
        return Path(uri[len("file://") :])
    if "://" in uri:
        return None
    return (model_file.parent / uri).resolve()


def convert_stl_references(model_file: Path, package_map) -> tuple[Path, list[str]]:
    """Returns a model file whose meshes Drake can load.

    If ``model_file`` references STL meshes, writes a copy to the cache with
    those replaced by converted OBJ files (and every other mesh reference made
    absolute); otherwise returns ``model_file`` itself.

    Returns:
        (path to load, notes for the user)
    """
    model_file = Path(model_file)
    if model_file.suffix.lower() not in (".urdf", ".sdf", ".xml"):
        return model_file, []
    text = model_file.read_text()
    if ".stl" not in text.lower():
        return model_file, []
    converted: list[str] = []

    def repl(m: re.Match) -> str:
        uri = m.group(2)
        path = _resolve(uri, model_file, package_map)
        if path is None:
            return m.group(0)
        if path.suffix.lower() == ".stl":
            if not path.is_file():
                raise WorkcellFormatError(str(model_file), f"mesh '{uri}' not found (looked at {path}).")
            obj = stl_to_obj(path)
            _remember(obj, path)
            path = obj
            converted.append(uri)
        return m.group(1) + "file://" + str(path) + m.group(3)

    new_text = _SDF_URI.sub(repl, _URDF_MESH.sub(repl, text))
    if not converted:
        return model_file, []
    digest = hashlib.sha256(new_text.encode()).hexdigest()[:16]
    out = cache_dir() / "models" / f"{model_file.stem}_{digest}{model_file.suffix}"
    out.parent.mkdir(parents=True, exist_ok=True)
    if not out.is_file():
        write_atomic(out, new_text)
    _remember(out, model_file.resolve())
    note = (
        f"{model_file.name}: converted {len(converted)} STL mesh(es) to OBJ because Drake 1.51 "
        f"refuses STL collision meshes; cached in {cache_dir()} (your files are unchanged)."
    )
    return out, [note]
