"""Saved paths and bounds tables used again: loaded and checked against the
cell they are to run in (its joints, limits and obstacles), so that a file
made for another cell or robot is refused before anything runs.

A file records the fingerprint of the cell it was made in
(:func:`fingerprint_of`): one made before the cell changed is refused too,
naming the change."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from drake_cfvol.algorithm.planning import NominalPath
from drake_cfvol.algorithm.table import BoundsTable, absolute_bounds
from drake_cfvol.exceptions import CollisionError, ConfigurationError
from drake_cfvol.io.records import path_label
from drake_cfvol.scene.arrays import cell_fingerprint, fingerprint_differences, fingerprint_problem

__all__ = ["fingerprint_of", "check_fingerprint", "load_path_for", "load_bounds_for"]

_NO_FINGERPRINT = (
    "{file} has no fingerprint of the cell it was made in (a file from before drake_cfvol 0.4): it is "
    "checked against this cell's joints, limits and collisions only; save it again to have it checked fully."
)


def fingerprint_of(workcell, path: NominalPath) -> dict:
    """What a saved path or table records of where it came from: the cell
    (:func:`~drake_cfvol.scene.arrays.cell_fingerprint`), the path's label
    and its waypoints' hash."""
    return {**cell_fingerprint(workcell), "path": path.label, "waypoints_sha256": path.sha256}


def check_fingerprint(workcell, saved: dict, file, what: str, notes: list | None = None) -> None:
    """Refuses a file made in another cell than ``workcell``, naming the
    first difference (an obstacle added, moved or removed; another robot or
    limits). A file without a fingerprint passes, with a notice in ``notes``.

    Raises:
        ConfigurationError: the cell changed since the file was made.
    """
    if not saved:
        if notes is not None:
            notes.append(_NO_FINGERPRINT.format(file=file))
        return
    problem = fingerprint_problem(saved)
    if problem is not None:
        raise ConfigurationError(
            f"{file}: the {what}'s fingerprint {problem}, so the cell it was made in cannot be checked (the file "
            f"was edited after saving). Make the {what} again (cfvol {'plan' if what == 'path' else 'bounds'} ... --out)."
        )
    differences = fingerprint_differences(saved, cell_fingerprint(workcell))
    if differences:
        more = f" (and {len(differences) - 1} more difference(s))" if len(differences) > 1 else ""
        raise ConfigurationError(
            f"{file}: the {what} was made in another cell than '{workcell.name}': {differences[0]}{more}. "
            f"Make the {what} again in this cell (cfvol {'plan' if what == 'path' else 'bounds'} ... --out)."
        )


def _label(saved: str, wanted: str | None, file, what: str) -> None:
    """Refuses a file made for another path than the one named."""
    if wanted is None or not saved:
        return
    if path_label(str(saved)) != path_label(str(wanted)):
        raise ConfigurationError(
            f"{file} holds a {what} for '{saved}', but '{path_label(str(wanted))}' was named. Give the file made "
            f"for '{path_label(str(wanted))}', or name '{saved}' (--path / path.name)."
        )


def _joints(workcell, names, file, what: str) -> None:
    if list(names) != list(workcell.joint_names):
        raise ConfigurationError(
            f"{file} holds a {what} for joints {', '.join(names)}, but cell '{workcell.name}' has joints "
            f"{', '.join(workcell.joint_names)}. Use a {what} made for this cell (cfvol plan/bounds ... --out), "
            "or name the cell it was made for."
        )


def _free(workcell, Q, file, what: str) -> None:
    for n, q in enumerate(Q):
        workcell.validate_configuration(q, f"{file}: {what} waypoint {n + 1}", tolerance=1e-6)
    free = np.array(workcell.checker.CheckConfigsCollisionFree(Q), bool)
    if not free.all():
        n = int(np.flatnonzero(~free)[0])
        raise CollisionError(
            f"{file}: {what} waypoint {n + 1} (counted from 1) in cell '{workcell.name}'",
            workcell.colliding_pairs(Q[n]),
        )


def load_path_for(workcell, file: str | Path, label: str | None = None, notes: list | None = None) -> NominalPath:
    """A saved nominal path (:meth:`NominalPath.save`), checked against the
    cell: the same joints, the cell it was made in (its fingerprint), the
    path named (``label``, if given), every waypoint within the limits, and
    free of collision by Drake at every waypoint and along every edge between.
    A file without a fingerprint adds a notice to ``notes``.

    Raises:
        RecordFormatError: not a readable path file.
        ConfigurationError: made for other joints, in another cell, for
            another path, or outside the limits.
        CollisionError: a waypoint or an edge collides in this cell (named).
    """
    path = NominalPath.load(file)
    _joints(workcell, path.joint_names, file, "path")
    _label(path.label, label, file, "path")
    check_fingerprint(workcell, path.fingerprint, file, "path", notes)
    _free(workcell, path.waypoints, file, "path")
    for n, (a, b) in enumerate(zip(path.waypoints[:-1], path.waypoints[1:])):
        if not workcell.checker.CheckEdgeCollisionFree(a, b):
            raise CollisionError(
                f"{file}: the path's edge from waypoint {n + 1} to {n + 2} in cell '{workcell.name}'",
                workcell.colliding_pairs(b),
            )
    return path


def load_bounds_for(
    workcell,
    file: str | Path,
    path: NominalPath | None = None,
    label: str | None = None,
    notes: list | None = None,
) -> BoundsTable:
    """A saved bounds table (:meth:`BoundsTable.save`), checked against the
    cell: the same joints and limits, the cell it was made in (its
    fingerprint), the path named (``label``, if given), its boxes inside the
    limits, its nominal free of collision at every waypoint, and the same
    nominal as ``path`` if one is given. A file without a fingerprint adds a
    notice to ``notes``.

    Raises:
        RecordFormatError: not a readable table, or its values are unusable.
        ConfigurationError: made for other joints, other limits, in another
            cell or for another path.
        CollisionError: a nominal waypoint collides in this cell.
    """
    table = BoundsTable.load(file)
    _joints(workcell, table.joint_names, file, "bounds table")
    _label(str(table.info.get("path", "")), label, file, "bounds table")
    saved = table.info.get("fingerprint") or {}
    check_fingerprint(workcell, saved, file, "bounds table", notes)
    if saved and saved.get("waypoints_sha256") != NominalPath(table.nominal, table.joint_names).sha256:
        raise ConfigurationError(
            f"{file}: the table's nominal does not match the waypoints it was computed on (the file was edited "
            "after saving). Compute the bounds again."
        )
    lo, hi = absolute_bounds(workcell.position_lower, workcell.position_upper, table.nominal[0])
    same = np.allclose(table.limit_lower, lo, atol=1e-9, equal_nan=True) and np.allclose(
        table.limit_upper, hi, atol=1e-9, equal_nan=True
    )
    if not same:
        raise ConfigurationError(
            f"{file} was made for joint limits {table.limit_lower.tolist()} .. "
            f"{table.limit_upper.tolist()}; cell '{workcell.name}' has {lo.tolist()} .. "
            f"{hi.tolist()}. Compute the bounds again on this cell."
        )
    if path is not None and (
        path.waypoints.shape != table.nominal.shape or not np.allclose(path.waypoints, table.nominal, atol=1e-9)
    ):
        raise ConfigurationError(
            f"{file} was computed along another path than the one given ({path.g} waypoints); "
            "give the path it was computed on, or leave the path out (the table holds it)."
        )
    outside = table.problem(workcell.position_lower, workcell.position_upper)
    if outside is not None:
        raise ConfigurationError(f"{file}: {outside}. Compute the bounds again on this cell.")
    _free(workcell, table.nominal, file, "bounds table's nominal")
    return table
