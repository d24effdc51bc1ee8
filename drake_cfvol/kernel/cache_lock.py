"""numba's cache for the package's compiled code, safe across processes.

numba's cache (``cache=True``) keeps one index per function that names, for
each compiled signature, the data file holding its code. Saving is a
read-modify-write of that index with no lock between processes: two
processes compiling one function for two signatures at once both read an
index without either and both take data file 1, so the index may end up
naming, for one signature, the code compiled for the other. A later process
loading it runs code built for other types and crashes (numba issues #4807
and #10128, open). Processes share a fresh cache often here: pytest-xdist
workers, Dask workers on one machine, the warm-up's helper process.

:func:`install` (called by :mod:`drake_cfvol.kernel` before any function of
the package is compiled) has the package's cache entries written under an
exclusive lock of their cache folder and read under a shared one
(``fcntl.flock`` on a ``drake_cfvol.lock`` file there), so an index and the
data files it names always agree. Other libraries' numba caches are left
as numba keeps them. Where ``fcntl`` is missing (Windows) nothing is
locked.

This file holds no compiled code: it is left out of the kernel's cache
stamp.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
from collections.abc import Iterable, Iterator
from pathlib import Path
from types import ModuleType
from typing import Any

fcntl: ModuleType | None
try:
    import fcntl
except ImportError:  # Windows: no flock; numba's own behaviour
    fcntl = None

#: The lock file in each cache folder.
LOCK_NAME = "drake_cfvol.lock"

#: The package's folder as Python imported it (numba names its folders
#: after the sources' paths as imported, symbolic links unresolved).
PACKAGE = Path(os.path.abspath(Path(__file__).parents[1]))

#: The package's cache folders (:func:`package_cache_folders`, absolute),
#: named at the first :func:`is_ours`.
_folders: set[str] | None = None

#: The file, in each of numba's cache folders of the package, holding the
#: hash of the kernel's sources its entries were compiled from.
STAMP_NAME = "kernel_sources.sha256"

#: That hash for this process's sources (set by :mod:`drake_cfvol.kernel`
#: at import); written into a folder with its first entry, where missing.
STAMP: str | None = None


def package_cache_folders(package: Path = PACKAGE) -> list[Path]:
    """Every folder where numba may keep compiled code of the package's
    modules: beside each subpackage's files (``__pycache__``), and, named
    after the subpackage's path, under ``NUMBA_CACHE_DIR`` when it is set
    and in numba's user-wide folder (its fallback where the package's own
    folder is read-only, as in a system-wide install)."""
    roots = {Path(os.path.abspath(package)), Path(package).resolve()}  # as imported, and resolved
    folders = sorted({f.parent for root in roots for f in root.rglob("*.py") if "__pycache__" not in f.parts})
    out = [f / "__pycache__" for f in folders]
    try:
        from numba.core import caching, config
        from numba.misc.appdirs import AppDirs

        subpaths = [caching._CacheLocator.get_suitable_cache_subpath(str(f / "__init__.py")) for f in folders]
        # numba sets its config's names at run time (from the environment): no stub has them.
        cache_dir = getattr(config, "CACHE_DIR")
        if cache_dir:
            out += [Path(cache_dir) / s for s in subpaths]
        out += [Path(AppDirs(appname="numba", appauthor=False).user_cache_dir) / s for s in subpaths]
    except Exception:  # numba's internals moved: the tree's folders only (a test checks they have not)
        pass
    return out


def is_ours(cache_path: str | os.PathLike[str]) -> bool:
    """Whether ``cache_path`` is where numba caches a module of the package."""
    global _folders
    if _folders is None:
        _folders = {os.path.abspath(str(f)) for f in package_cache_folders()}
    return os.path.abspath(str(cache_path)) in _folders or os.path.realpath(str(cache_path)) in _folders


@contextlib.contextmanager
def folder_lock(folder: str | os.PathLike[str], *, exclusive: bool) -> Iterator[None]:
    """Holds ``folder``'s lock (exclusive or shared) for the ``with`` block;
    no lock where the folder cannot hold one (missing, read-only) or the
    platform has no ``flock``."""
    fd = None
    if fcntl is not None:
        try:
            fd = os.open(os.path.join(folder, LOCK_NAME), os.O_RDWR | os.O_CREAT, 0o666)
        except OSError:
            fd = None
    try:
        if fd is not None and fcntl is not None:
            fcntl.flock(fd, fcntl.LOCK_EX if exclusive else fcntl.LOCK_SH)
        yield
    finally:
        if fd is not None:
            os.close(fd)  # releases the lock


def clear_stale(sources: Path, folders: Iterable[str | os.PathLike[str]], skip: Iterable[Path] = ()) -> str:
    """Removes numba's cache files (``*.nbi``, ``*.nbc``) from ``folders``
    when the ``*.py`` files under ``sources`` (subfolders included; the
    relative paths in ``skip`` left out) differ from those the cache was
    made from: a hash of them is kept in each folder (:data:`STAMP_NAME`).
    numba invalidates a function's cache only when its own file changes,
    not when a function it calls from another file does. A folder that
    does not exist is not made (the lock's first save into it writes the
    hash). Returns the hash."""
    digest = hashlib.sha256()
    for f in sorted(Path(sources).rglob("*.py")):
        if f.relative_to(sources) in skip:
            continue
        digest.update(str(f.relative_to(sources)).encode() + f.read_bytes())
    text = digest.hexdigest()
    for folder in folders:
        stamp = Path(folder) / STAMP_NAME
        try:
            if not Path(folder).is_dir() or (stamp.is_file() and stamp.read_text() == text):
                continue
            with folder_lock(folder, exclusive=True):
                for f in list(Path(folder).glob("*.nbi")) + list(Path(folder).glob("*.nbc")):
                    f.unlink(missing_ok=True)
                stamp.write_text(text)
        except OSError:
            pass  # a read-only place holds no cache numba could use either
    return text


def _write_stamp(folder: str | os.PathLike[str]) -> None:
    """The sources' hash into ``folder`` where it has none (a folder numba
    made after the package's import checked the existing ones)."""
    if STAMP is None:
        return
    path = Path(folder) / STAMP_NAME
    try:
        if not path.exists():
            path.write_text(STAMP)
    except OSError:
        pass  # numba's own save reports a folder it cannot write


def _locked(base: Any) -> type:
    class LockedIndexDataCacheFile(base):
        """numba's index and data files, read and written under the cache
        folder's lock when the folder is the package's."""

        _drake_cfvol_locked = True

        def __init__(self, cache_path, *args, **kwargs):
            super().__init__(cache_path, *args, **kwargs)
            self._lock_folder = cache_path if is_ours(cache_path) else None

        def save(self, key, data):
            if self._lock_folder is None:
                return super().save(key, data)
            with folder_lock(self._lock_folder, exclusive=True):
                _write_stamp(self._lock_folder)
                return super().save(key, data)

        def load(self, key):
            if self._lock_folder is None:
                return super().load(key)
            with folder_lock(self._lock_folder, exclusive=False):
                return super().load(key)

    return LockedIndexDataCacheFile


def install() -> bool:
    """Makes numba's caches made from now on lock the package's folders
    (idempotent). Returns False where numba's internals have moved and
    nothing could be installed (``tests/test_kernel.py`` checks it is)."""
    try:
        from numba.core import caching
    except ImportError:
        return False
    current = getattr(caching, "IndexDataCacheFile", None)
    if current is None or not all(hasattr(current, m) for m in ("save", "load")):
        return False
    if not getattr(current, "_drake_cfvol_locked", False):
        # numba's class replaced in its module (setattr: its stub types the name as that class).
        setattr(caching, "IndexDataCacheFile", _locked(current))
    return True
