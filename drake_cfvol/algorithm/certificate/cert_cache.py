"""The certificate cache: certified boxes kept on disk, named by a hash of
every input (settings, clearance, bounds, path, the scene's arrays, every
source file of the package, and the numpy, numba and drake versions), so a
changed input or method never reuses an old entry.
"""

import hashlib
import io
import json
import zipfile
from pathlib import Path

import numpy as np

from drake_cfvol.io.cache import cache_root, write_atomic

__all__ = ["cache_dir", "cache_key", "cache_load", "cache_store"]


def cache_dir() -> Path | None:
    """Where certified boxes are kept: ``$DRAKE_CFVOL_CACHE`` (``off``
    disables the cache), else ``$XDG_CACHE_HOME/drake_cfvol`` or
    ``~/.cache/drake_cfvol``. Entries are named by a hash of every input
    (and of the certifier's and kernel's source), so a changed scene, path,
    bound, setting or method never reuses a stale one; delete the folder to
    clear it."""
    return cache_root()


def _versions() -> str:
    """The versions of what a certificate's result depends on."""
    import numba
    import pydrake

    return f"numpy {np.__version__}, numba {numba.__version__}, drake {getattr(pydrake, '__version__', '?')}"


def cache_key(arrays, table, certify) -> str:
    """A hash of everything the result depends on: the settings and the
    clearance, the bounds and path, the scene's arrays, the source of every
    module of the package (the box-at-s rule, the kernel, the certifier...)
    and the versions of numpy, numba and drake (a changed method or
    dependency never reuses an old entry)."""
    h = hashlib.sha256(f"certify/{certify!r}/{table.params.get('clearance', 0.0)!r}".encode())
    package = Path(__file__).resolve().parents[1]
    for module in sorted(package.rglob("*.py")):
        h.update(module.relative_to(package).as_posix().encode())
        h.update(module.read_bytes())
    h.update(_versions().encode())
    for a in (
        table.nominal,
        table.stretch_lower,
        table.stretch_upper,
        table.rate,
        arrays.shapes,
        arrays.shape_body,
        arrays.obstacles,
        arrays.verts,
        arrays.self_pairs,
        *arrays.chain,
    ):
        if a is None:
            h.update(b"none")
            continue
        a = np.ascontiguousarray(a)
        h.update(f"{a.dtype}{a.shape}".encode())
        h.update(a.tobytes())
    return h.hexdigest()[:32]


def cache_load(file: Path, report_type):
    """(lower, upper, report_type.from_dict(the saved report)), or None if
    the entry is missing or damaged (then it is computed again)."""
    try:
        with np.load(file, allow_pickle=False) as z:
            report = report_type.from_dict(json.loads(str(z["report"])))
            return z["lower"].copy(), z["upper"].copy(), report
    except (OSError, ValueError, KeyError, TypeError, EOFError, zipfile.BadZipFile):
        return None


def cache_store(file: Path, lower, upper, report) -> None:
    """Saves an entry atomically; a read-only or full disk is no error."""
    try:
        file.parent.mkdir(parents=True, exist_ok=True)
        buf = io.BytesIO()
        np.savez(buf, lower=lower, upper=upper, report=json.dumps(report.to_dict()))
        write_atomic(file, buf.getvalue())
    except OSError:
        pass  # a read-only or full disk only costs the next run its time
