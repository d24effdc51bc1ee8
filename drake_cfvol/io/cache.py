"""The user's cache folder, the one place ``$DRAKE_CFVOL_CACHE`` is read:
certificates (:mod:`drake_cfvol.algorithm.certificate.cert_cache`) and converted meshes
and model files (:mod:`drake_cfvol.scene.meshes`) are kept below it.
"""

import atexit
import os
import shutil
import tempfile
import uuid
from pathlib import Path

__all__ = ["cache_root", "files_dir", "write_atomic"]

#: Values of ``$DRAKE_CFVOL_CACHE`` that turn every cache off.
OFF = ("", "off", "0", "no", "false")
_scratch: Path | None = None


def cache_root() -> Path | None:
    """The cache folder: ``$DRAKE_CFVOL_CACHE`` (``off``, or any of
    :data:`OFF`, disables every cache: None), else
    ``$XDG_CACHE_HOME/drake_cfvol`` or ``~/.cache/drake_cfvol``."""
    env = os.environ.get("DRAKE_CFVOL_CACHE")
    if env is not None:
        return None if env.strip().lower() in OFF else Path(env).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "drake_cfvol"


def files_dir() -> Path:
    """Where files Drake must read (converted meshes, rewritten model files)
    are written: the cache folder, or, with caching off, a temporary folder
    of this process's own, removed when it exits (never reused by another)."""
    root = cache_root()
    if root is not None:
        return root
    global _scratch
    if _scratch is None or not _scratch.is_dir():
        _scratch = Path(tempfile.mkdtemp(prefix="drake_cfvol-"))
        atexit.register(shutil.rmtree, _scratch, ignore_errors=True)
    return _scratch


def write_atomic(path: Path, data: str | bytes) -> Path:
    """Writes ``data`` (text as UTF-8) to ``path`` through a temporary file
    of this process's own beside it, then renames it into place: another
    process reading ``path`` meanwhile (Dask workers, pytest-xdist, a
    second ``cfvol`` sharing the cache) sees the old file or the whole new
    one, never a part. Returns ``path``."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{uuid.uuid4().hex[:12]}.tmp")
    try:
        if isinstance(data, str):
            tmp.write_text(data, encoding="utf-8")
        else:
            tmp.write_bytes(data)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return path
