"""The shape kinds, one module each: a kind's compiled functions (support
point, extent, excess over its core, signed distance of a point) and its
:class:`~drake_cfvol.kernel.kinds.base.ShapeKind` (what the scene, the
covers, the online re-estimation and the safety filter know of it).

Adding a kind is adding a module: its class here in :data:`KINDS`, its code
in :mod:`drake_cfvol.kernel.types`, and its branch in the kernel's
dispatchers (``shapes._local_support`` and ``shapes._row_aabb``; where it
has them, ``batch._near_exact``, ``spheres.ball_apart_row`` and the
damper's ``point_distance``). A row
of a kind the kernel does not know is refused when the scene is built
(:func:`check_rows`), and the kernel's default branch answers "may
collide" for it.
"""

from __future__ import annotations

import numpy as np

from drake_cfvol.exceptions import WorkcellError
from drake_cfvol.kernel.kinds.base import (
    MAX_SEGMENT_BALLS,
    MAX_SLABS,
    SEGMENT_SLACK,
    Geometry,
    ShapeKind,
)
from drake_cfvol.kernel.kinds.box import HALF_SPACE_SIZE, Box, HalfSpace
from drake_cfvol.kernel.kinds.capsule import Capsule
from drake_cfvol.kernel.kinds.cylinder import Cylinder
from drake_cfvol.kernel.kinds.ellipsoid import Ellipsoid
from drake_cfvol.kernel.kinds.hull import Hull
from drake_cfvol.kernel.kinds.sphere import Sphere
from drake_cfvol.kernel.types import _K, _V0, _V1

__all__ = [
    "ShapeKind",
    "Geometry",
    "KINDS",
    "DRAKE_KINDS",
    "kind",
    "geometry",
    "check_rows",
    "HALF_SPACE_SIZE",
    "MAX_SLABS",
    "SEGMENT_SLACK",
    "MAX_SEGMENT_BALLS",
]

#: Every kind a kernel row may hold, by its code.
KINDS: dict[int, ShapeKind] = {k.code: k for k in (Box(), Sphere(), Capsule(), Cylinder(), Ellipsoid(), Hull())}

#: The kinds Drake shapes are read as, by the Drake class's name (a half
#: space as a box).
DRAKE_KINDS: dict[str, ShapeKind] = {name: k for k in (*KINDS.values(), HalfSpace()) for name in k.drake_names}


def kind(code) -> ShapeKind:
    """The kind of a row's code.

    Raises:
        WorkcellError: a code no kind has.
    """
    try:
        return KINDS[int(code)]
    except (KeyError, ValueError, TypeError):
        raise WorkcellError(
            f"shape kind {code!r} is not one the kernel knows ({_known()}); build rows with "
            "drake_cfvol.scene.arrays.shape_row or SceneArrays.with_boxes."
        ) from None


def geometry(shape, strict: bool = True) -> Geometry | None:
    """A Drake shape as its kind sees it.

    Args:
        shape: a ``pydrake.geometry`` shape.
        strict: raise for a shape no kind reads (else None), and for a mesh
            whose hull cannot be made.

    Raises:
        WorkcellError: (with ``strict``) an unsupported shape, or a mesh
            without a proper convex hull.
    """
    k = DRAKE_KINDS.get(type(shape).__name__)
    if k is None:
        if strict:
            raise WorkcellError(
                f"shape {type(shape).__name__} is not supported by the fast backend; use "
                f"{', '.join(sorted(DRAKE_KINDS))} (or backend='drake')."
            )
        return None
    if strict:
        return k.geometry(shape)
    try:
        return k.geometry(shape)
    except Exception:  # a mesh Drake cannot make a hull of: the caller measures it with Drake
        return None


def check_rows(rows: np.ndarray, verts: np.ndarray, what: str) -> None:
    """Refuses rows of a kind the kernel does not know, and hull rows
    whose vertex range is not a proper hull's in ``verts``.

    Raises:
        WorkcellError: naming the first bad row.
    """
    rows = np.asarray(rows, float)
    if rows.size == 0:
        return
    code = rows[:, _K]
    bad = np.flatnonzero(~np.isin(code, np.array(sorted(KINDS), float)))
    if len(bad):
        n = int(bad[0])
        raise WorkcellError(
            f"{what} {n} has shape kind {code[n]:g}, which the kernel does not know ({_known()}); build rows "
            "with drake_cfvol.scene.arrays.shape_row or SceneArrays.with_boxes."
        )
    hull = np.flatnonzero(code == Hull.code)
    v0, v1 = rows[hull, _V0], rows[hull, _V1]
    bad = hull[(v0 < 0) | (v1 - v0 < 4) | (v1 > len(verts))]
    if len(bad):
        n = int(bad[0])
        raise WorkcellError(
            f"{what} {n} is a convex hull with vertices [{rows[n, _V0]:g}, {rows[n, _V1]:g}) of a table of "
            f"{len(verts)}; a hull needs at least 4 vertices in the table."
        )


def _known() -> str:
    return ", ".join(f"{c} {k.name}" for c, k in sorted(KINDS.items()))
