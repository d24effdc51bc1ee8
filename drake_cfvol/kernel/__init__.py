"""The compiled collision kernel (numba, ``@njit(cache=True)``).

One kernel serves joint bounding, the volume test, categorization
distances, the Confidence Factor's pre-filter and certification. It works on
plain arrays extracted from Drake once (:mod:`drake_cfvol.scene.arrays`):

- forward kinematics of the robot's chain (:func:`fk`), tested against
  Drake's poses to 1e-12;
- convex shapes given by exact support functions: boxes, spheres, capsules,
  cylinders, ellipsoids, and convex hulls of meshes (what Drake itself uses
  for a mesh in point-pair queries);
- motion sets folded into the support: a ball of radius ``e_iso`` (any
  motion), a disc of radius ``e_disc`` normal to an axis u (rotation about
  u), a segment of half-length ``e_seg`` along u (translation);
- a boolean GJK whose "separated" answer is a certificate: a direction d
  with h_A(d) + h_B(-d) < 0 computed from the exact supports, so the kernel
  never calls a pose free where the shapes overlap. Where GJK does not
  conclude it answers "may collide" (conservative);
- the height-field volume V: a 2-D range-maximum table, and a shape against
  the columns by recursive halving of its footprint (exact at one cell).

Shape rows (``SHAPE_W`` floats): kind, centre (3), rotation (9, row-major),
size (3), first vertex, end vertex, e_iso, axis u (3), e_disc, e_seg; their
offsets are ``ROW_KIND`` ... ``ROW_E_SEG``.

Modules, by concern: ``types`` (constants and the typed arguments),
``kinematics``, ``shapes``, ``gjk``, ``heightfield``, ``checks``
(configurations), ``blocks`` and ``batch`` (configurations in blocks of
``NB``: forward kinematics and the batch check), ``regions`` (region
tests and the sweep), ``flat_model`` (the model into their parallel
loops), ``footprints``, ``warmup`` and ``cache_lock`` (numba's
cache kept consistent across processes). Imports nothing of the package.

numba's cache (``cache=True``) invalidates a compiled function when its own
file changes, not when a function it calls from another file does; so the
package's numba cache is cleared whenever any of the kernel's files (its
kinds' included) differs from the ones it was compiled from
(:func:`_clear_stale_cache`, before anything compiles).
"""

from pathlib import Path as _Path

from drake_cfvol.kernel import cache_lock as _cache_lock

#: Kernel files with nothing compiled in them (no numba function, no
#: constant a compiled one reads): left out of the cache stamp.
_NOT_COMPILED = (_Path("warmup.py"), _Path("cache_lock.py"))


def _clear_stale_cache(folder: _Path, caches) -> str:
    """:func:`cache_lock.clear_stale` of the kernel's sources in ``folder``
    (its kinds' included, :data:`_NOT_COMPILED` left out) over the cache
    folders ``caches``; returns the sources' hash."""
    return _cache_lock.clear_stale(folder, caches, _NOT_COMPILED)


# numba's cache folders of the whole package (the kernel's and that of
# modules calling it, such as the damper's) cleared if the kernel changed;
# a folder numba makes later gets the hash with its first entry.
_cache_lock.STAMP = _clear_stale_cache(_Path(__file__).resolve().parent, _cache_lock.package_cache_folders())
# Before any of the package's functions is decorated: their cache entries
# are written and read under a lock shared by all processes (cache_lock).
_cache_lock.install()

from drake_cfvol.kernel.batch import configs_may_collide, configs_may_collide_serial  # noqa: E402
from drake_cfvol.kernel.blocks import (  # noqa: E402
    COHERENT_BITS,
    COHERENT_DIMS,
    EXACT_KINDS,
    NB,
    block_chain,
    coherent_order,
    fk_blocks,
    shape_bounds,
)
from drake_cfvol.kernel.checks import lower_columns_under, obstacle_distances  # noqa: E402
from drake_cfvol.kernel.footprints import distance_map, fill_convex_polygon, robot_footprint, shape_footprint  # noqa: E402
from drake_cfvol.kernel.gjk import gjk_intersect  # noqa: E402
from drake_cfvol.kernel.heightfield import (  # noqa: E402
    new_scratch,
    new_workspace,
    no_height_field,
    object_hits_columns,
    range_max,
    range_max_table,
)
from drake_cfvol.kernel.kinematics import fk, fk_into  # noqa: E402
from drake_cfvol.kernel.regions import regions_hit, sweep_chains  # noqa: E402
from drake_cfvol.kernel.shapes import object_aabb, pose_shape, row_aabb, set_motion, support  # noqa: E402
from drake_cfvol.kernel.types import (  # noqa: E402
    BOX,
    CAPSULE,
    CYLINDER,
    ELLIPSOID,
    FOOTPRINT_DIRECTIONS,
    HULL,
    MAX_T_SAMPLES,
    MAX_V_SAMPLES,
    MEMO_T,
    MEMO_W,
    ROW_AXIS,
    ROW_CENTRE,
    ROW_E_DISC,
    ROW_E_ISO,
    ROW_E_SEG,
    ROW_END_VERTEX,
    ROW_FIRST_VERTEX,
    ROW_KIND,
    ROW_ROTATION,
    ROW_SIZE,
    SHAPE_W,
    SPHERE,
    Blocks,
    Chain,
    HeightField,
    Model,
    RegionScratch,
    Scratch,
)
from drake_cfvol.kernel.warmup import HELPER_STEPS, PARALLEL_SHARES, STEP_SHARES, warm_up, warm_up_shares  # noqa: E402

__all__ = [
    "Chain",
    "Model",
    "Blocks",
    "HeightField",
    "Scratch",
    "RegionScratch",
    "BOX",
    "SPHERE",
    "CAPSULE",
    "CYLINDER",
    "ELLIPSOID",
    "HULL",
    "SHAPE_W",
    "MAX_T_SAMPLES",
    "MAX_V_SAMPLES",
    "FOOTPRINT_DIRECTIONS",
    "fk",
    "fk_into",
    "support",
    "pose_shape",
    "set_motion",
    "row_aabb",
    "object_aabb",
    "gjk_intersect",
    "range_max_table",
    "range_max",
    "new_workspace",
    "new_scratch",
    "no_height_field",
    "object_hits_columns",
    "configs_may_collide",
    "configs_may_collide_serial",
    "lower_columns_under",
    "obstacle_distances",
    "NB",
    "EXACT_KINDS",
    "block_chain",
    "shape_bounds",
    "fk_blocks",
    "coherent_order",
    "COHERENT_DIMS",
    "COHERENT_BITS",
    "sweep_chains",
    "regions_hit",
    "MEMO_T",
    "MEMO_W",
    "shape_footprint",
    "fill_convex_polygon",
    "robot_footprint",
    "distance_map",
    "warm_up",
    "warm_up_shares",
    "STEP_SHARES",
    "PARALLEL_SHARES",
    "HELPER_STEPS",
    "ROW_KIND",
    "ROW_CENTRE",
    "ROW_ROTATION",
    "ROW_SIZE",
    "ROW_FIRST_VERTEX",
    "ROW_END_VERTEX",
    "ROW_E_ISO",
    "ROW_AXIS",
    "ROW_E_DISC",
    "ROW_E_SEG",
]
