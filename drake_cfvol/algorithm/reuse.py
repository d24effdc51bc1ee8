"""Saved paths and bounds tables used again: loaded and checked against the
cell they are to run in (its joints, limits and obstacles), so that a file
made for another cell or robot is refused before anything runs."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from drake_cfvol.algorithm.planning import NominalPath
from drake_cfvol.algorithm.table import BoundsTable, absolute_bounds
from drake_cfvol.exceptions import CollisionError, ConfigurationError

__all__ = ["load_path_for", "load_bounds_for"]


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


def load_path_for(workcell, file: str | Path) -> NominalPath:
    """A saved nominal path (:meth:`NominalPath.save`), checked against the
    cell: the same joints, every waypoint within the limits, and free of
    collision by Drake at every waypoint and along every edge between.

    Raises:
        RecordFormatError: not a readable path file.
        ConfigurationError: made for other joints, or outside the limits.
        CollisionError: a waypoint or an edge collides in this cell (named).
    """
    path = NominalPath.load(file)
    _joints(workcell, path.joint_names, file, "path")
    _free(workcell, path.waypoints, file, "path")
    for n, (a, b) in enumerate(zip(path.waypoints[:-1], path.waypoints[1:])):
        if not workcell.checker.CheckEdgeCollisionFree(a, b):
            raise CollisionError(
                f"{file}: the path's edge from waypoint {n + 1} to {n + 2} in cell '{workcell.name}'",
                workcell.colliding_pairs(b),
            )
    return path


def load_bounds_for(workcell, file: str | Path, path: NominalPath | None = None) -> BoundsTable:
    """A saved bounds table (:meth:`BoundsTable.save`), checked against the
    cell: the same joints and limits, its nominal free of collision at every
    waypoint, and the same nominal as ``path`` if one is given.

    Raises:
        RecordFormatError: not a readable table.
        ConfigurationError: made for other joints, other limits or another path.
        CollisionError: a nominal waypoint collides in this cell.
    """
    table = BoundsTable.load(file)
    _joints(workcell, table.joint_names, file, "bounds table")
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
    _free(workcell, table.nominal, file, "bounds table's nominal")
    return table
