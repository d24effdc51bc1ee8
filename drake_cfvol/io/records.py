"""Saving and loading records as ``.npz`` (arrays + JSON metadata) or
readable ``.json``, shared by NominalPath and BoundsTable."""

import io
import json
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from drake_cfvol.exceptions import OutputExistsError, OutputPathError, ParameterError, RecordFormatError
from drake_cfvol.io.arguments import file_path
from drake_cfvol.io.cache import write_atomic

#: The ``format`` tag each kind of record carries.
FORMATS = {"path": "drake_cfvol.NominalPath", "bounds": "drake_cfvol.BoundsTable"}


def path_label(name: str) -> str:
    """A configuration pair's label as the user may write it: ``1`` is
    ``path1``; any other name is kept."""
    return name if name.startswith("path") or not name.isdigit() else f"path{name}"


def output_stem(cell: str, label: str, resolution: int | None = None, *, certified: bool = False) -> str:
    """The one naming scheme of output files: ``<cell>_<path>[_R<R>][_certified]``,
    followed by ``_<kind>.<ext>`` (``automotive_path1_R1000_bounds.npz``,
    ``automotive_path1_R1000_certified_bounds.npz``)."""
    return (
        f"{cell}_{label}" + (f"_R{resolution}" if resolution is not None else "") + ("_certified" if certified else "")
    )


def prepare_output(path, *, overwrite: bool, folder: bool = False) -> Path:
    """Checks that ``path`` can be written before any work starts: creates
    its folder (or ``path`` itself when ``folder``) and refuses an existing
    file unless ``overwrite``.

    Raises:
        OutputExistsError: the file exists and ``overwrite`` is False.
        OutputPathError: the folder cannot be created or written to.
    """
    path = Path(path)
    target = path if folder else path.parent
    try:
        target.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise OutputPathError(target, e.strerror or str(e)) from None
    if not target.is_dir():
        raise OutputPathError(target, "it is a file, not a folder")
    if not folder and path.exists() and not overwrite:
        raise OutputExistsError(f"{path} exists; pass overwrite=True (CLI: --force) to replace it.")
    return path


def prepare_outputs(folder, names, *, overwrite: bool) -> list[Path]:
    """Checks every file a command writes into ``folder`` before any work
    starts: creates the folder and refuses, in one line naming them all,
    the files that exist unless ``overwrite``. Returns their paths.

    Raises:
        OutputExistsError: some of the files exist and ``overwrite`` is False.
        OutputPathError: the folder cannot be created or written to.
    """
    folder = prepare_output(folder, overwrite=overwrite, folder=True)
    files = [folder / name for name in names]
    existing = [f.name for f in files if f.exists()]
    if existing and not overwrite:
        raise OutputExistsError(
            f"{folder} already holds {', '.join(existing)}; pass overwrite=True (CLI: --force) to replace "
            f"{'it' if len(existing) == 1 else 'them'}, or write to another folder."
        )
    return files


def save_record(path, record: dict, array_keys: tuple, what: str, *, overwrite: bool) -> Path:
    """Writes ``record`` (JSON-ready; the ``array_keys`` entries are arrays).

    Raises:
        OutputExistsError: the file exists and ``overwrite`` is False.
        OutputPathError: the file cannot be written.
        ParameterError: the suffix is neither .npz nor .json.
    """
    path = file_path(path, f"the {what} file to save")
    if path.suffix not in (".npz", ".json"):
        raise ParameterError(f"unknown {what} file type '{path.suffix}' in '{path}': use .npz or .json.")
    prepare_output(path, overwrite=overwrite)
    try:
        # Through a temporary file: an interrupted save leaves no partial file.
        if path.suffix == ".json":
            write_atomic(
                path,
                json.dumps(
                    {k: (np.asarray(v).tolist() if k in array_keys else v) for k, v in record.items()}, indent=1
                ),
            )
        else:
            meta = {k: v for k, v in record.items() if k not in array_keys}
            buffer = io.BytesIO()
            # Any: numpy's stub would take a key of the dict for savez's allow_pickle.
            arrays: dict[str, Any] = {k: np.asarray(record[k]) for k in array_keys} | {"meta": json.dumps(meta)}
            np.savez(buffer, **arrays)
            write_atomic(path, buffer.getvalue())
    except OSError as e:
        raise OutputPathError(path, e.strerror or str(e)) from None
    return path


def _unique_keys(pairs: list) -> dict:
    """A JSON object, refused if it names a key twice (json keeps the last)."""
    out = {}
    for key, value in pairs:
        if key in out:
            raise ValueError(f"the key '{key}' appears twice in one object; remove one of them")
        out[key] = value
    return out


def load_record(path, array_keys: tuple, what: str, optional: tuple = (), required: tuple = ()) -> tuple[dict, dict]:
    """Reads a record saved by :func:`save_record`: (metadata, float arrays);
    the ``optional`` arrays are left out where the file lacks them.

    Raises:
        RecordFormatError: the file is missing, empty, truncated, of another
            kind (a bounds file given as a path, say) or lacks a field.
        ParameterError: the suffix is neither .npz nor .json.
    """
    path = file_path(path, f"the {what} file to load")
    if path.suffix not in (".npz", ".json"):
        raise ParameterError(f"unknown {what} file type '{path.suffix}' in '{path}': use .npz or .json.")
    if not path.is_file():
        raise RecordFormatError(path, what, "no such file" if not path.exists() else "it is not a file")
    try:
        if path.suffix == ".json":
            d = json.loads(path.read_text(encoding="utf-8-sig"), object_pairs_hook=_unique_keys)
            if not isinstance(d, dict):
                raise RecordFormatError(path, what, "it holds no JSON object")
            arrays = {k: np.array(d[k], dtype=np.float64) for k in array_keys + optional if k in d}
        else:
            with np.load(path, allow_pickle=False) as z:
                if "meta" not in z.files:
                    raise RecordFormatError(path, what, "it has no 'meta' entry")
                d = json.loads(str(z["meta"]), object_pairs_hook=_unique_keys)
                arrays = {k: np.asarray(z[k], dtype=np.float64) for k in array_keys + optional if k in z.files}
    except RecordFormatError:
        raise
    except (OSError, EOFError, zipfile.BadZipFile) as e:
        raise RecordFormatError(path, what, f"it is empty or truncated ({type(e).__name__}: {e})") from None
    except (ValueError, TypeError) as e:  # JSONDecodeError is a ValueError
        raise RecordFormatError(path, what, f"it is not valid ({type(e).__name__}: {e})") from None
    fmt = d.get("format")
    if fmt is not None and fmt != FORMATS[what]:
        raise RecordFormatError(path, what, f"it is a '{fmt}' file, not a {FORMATS[what]}")
    missing = [k for k in array_keys if k not in arrays] + [k for k in required if k not in d]
    if missing:
        raise RecordFormatError(path, what, f"it lacks {', '.join(repr(m) for m in missing)}")
    return d, arrays
