"""The user's cache folder, the one place ``$DRAKE_CFVOL_CACHE`` is read:
certificates (:mod:`drake_cfvol.algorithm.cert_cache`) and converted meshes
and model files (:mod:`drake_cfvol.scene.meshes`) are kept below it.
"""

import atexit
import os
import shutil
import tempfile
from pathlib import Path

__all__ = ["cache_root", "files_dir"]

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
