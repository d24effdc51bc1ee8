"""Saving and loading records as ``.npz`` (arrays + JSON metadata) or
readable ``.json``, shared by NominalPath and BoundsTable."""

import json
from pathlib import Path

import numpy as np

from drake_cfvol.exceptions import ParameterError


def save_record(path, record: dict, array_keys: tuple, what: str, *, overwrite: bool) -> Path:
    """Writes ``record`` (JSON-ready; the ``array_keys`` entries are arrays).

    Raises:
        FileExistsError: the file exists and ``overwrite`` is False.
        ParameterError: the suffix is neither .npz nor .json.
    """
    path = Path(path)
    if path.suffix not in (".npz", ".json"):
        raise ParameterError(f"unknown {what} file type '{path.suffix}': use .npz or .json.")
    if path.exists() and not overwrite:
        raise FileExistsError(f"{path} exists; pass overwrite=True (CLI: --force) to replace it.")
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix == ".json":
        path.write_text(json.dumps({k: (np.asarray(v).tolist() if k in array_keys else v)
                                    for k, v in record.items()}, indent=1))
    else:
        meta = {k: v for k, v in record.items() if k not in array_keys}
        np.savez(path, **{k: np.asarray(record[k]) for k in array_keys}, meta=json.dumps(meta))
    return path


def load_record(path, array_keys: tuple, what: str, optional: tuple = ()) -> tuple[dict, dict]:
    """Reads a record saved by :func:`save_record`: (metadata, float arrays);
    the ``optional`` arrays are left out where the file lacks them."""
    path = Path(path)
    if path.suffix == ".json":
        d = json.loads(path.read_text())
        return d, {k: np.array(d[k], dtype=np.float64) for k in array_keys + optional if k in d}
    if path.suffix == ".npz":
        with np.load(path) as z:
            return json.loads(str(z["meta"])), {k: z[k] for k in array_keys + optional if k in z.files}
    raise ParameterError(f"unknown {what} file type '{path.suffix}': use .npz or .json.")
