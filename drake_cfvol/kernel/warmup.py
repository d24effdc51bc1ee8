"""Compiling every kernel once (or loading it from numba's cache).

Run as ``python -m drake_cfvol.kernel.warmup STEP ...``, it compiles those
steps (the helper process of :func:`warm_up`). Nothing here is compiled, so
this file is left out of the kernel's cache stamp.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from collections.abc import Callable, Iterable
from pathlib import Path

import numpy as np

from drake_cfvol.kernel.batch import configs_may_collide, configs_may_collide_serial
from drake_cfvol.kernel.blocks import COHERENT_BITS, COHERENT_DIMS, block_chain, coherent_order, fk_blocks, shape_bounds
from drake_cfvol.kernel.checks import lower_columns_under, obstacle_distances
from drake_cfvol.kernel.footprints import distance_map, fill_convex_polygon, robot_footprint, shape_footprint
from drake_cfvol.kernel.gjk import gjk_intersect
from drake_cfvol.kernel.heightfield import range_max_table
from drake_cfvol.kernel.kinematics import fk
from drake_cfvol.kernel.regions import regions_hit, sweep_chains
from drake_cfvol.kernel.shapes import row_aabb
from drake_cfvol.kernel.types import (
    _C,
    _K,
    _R,
    _S,
    BOX,
    FOOTPRINT_DIRECTIONS,
    MEMO_T,
    MEMO_W,
    SHAPE_W,
    Blocks,
    Chain,
    HeightField,
    Model,
)

#: Each step's share of a fresh compile, s (measured on this 2-core machine
#: with an empty numba cache by ``cfvol bench --kernel`` at 960a21e, the
#: machine otherwise idle; the shares, not the seconds, carry over to other
#: machines). A step compiles what the steps before it have not.
STEP_SHARES = {
    "fk": 7.7,
    "configs_may_collide": 59.6,
    "configs_may_collide_serial": 8.7,
    "range_max_table": 8.6,
    "sweep_chains": 67.4,
    "regions_hit": 39.2,
    "lower_columns_under": 2.0,
    "obstacle_distances": 6.2,
    "footprints": 2.8,
    "gjk_intersect": 0.3,
}

#: The steps a helper process compiles while this one compiles the others
#: (:func:`warm_up`, on a fresh cache with two or more cores): the region
#: tests' entry points, which share most of their callees.
HELPER_STEPS = ("sweep_chains", "regions_hit")

#: Shares of a fresh compile with the helper: this process's steps, then
#: ``helper``, the wait for the helper's steps after them (less any
#: ``meanwhile`` steps run before it), s (measured by ``tools/eta_check.py
#: --compile-only`` at 0.6.1 on this 2-core machine).
PARALLEL_SHARES = {
    "fk": 10.9,
    "configs_may_collide": 61.1,
    "configs_may_collide_serial": 9.0,
    "range_max_table": 7.8,
    "lower_columns_under": 2.0,
    "obstacle_distances": 7.2,
    "footprints": 4.2,
    "gjk_intersect": 0.5,
    "helper": 44.2,
}


def _scene():
    """A tiny made-up scene: a one-joint arm with one box link, one
    obstacle and a 2 x 2 height field."""
    eye = np.eye(3)
    parent = np.array([-1], np.int64)
    jtype = np.array([1], np.int64)
    qidx = np.array([0], np.int64)
    axis = np.array([[0.0, 0.0, 1.0]])
    R_PF = eye[None].copy()
    p_PF = np.array([[0.0, 0.0, 0.5]])
    R_MB = eye[None].copy()
    p_MB = np.zeros((1, 3))
    chain = Chain(parent, jtype, qidx, axis, R_PF, p_PF, R_MB, p_MB)
    shapes = np.zeros((1, SHAPE_W))
    shapes[0, _K] = BOX
    shapes[0, _C : _C + 3] = (0.5, 0.0, 0.0)
    shapes[0, _R : _R + 9] = eye.ravel()
    shapes[0, _S : _S + 3] = (0.5, 0.05, 0.05)
    verts = np.zeros((0, 3))
    obstacles = shapes.copy()
    obstacles[0, _C : _C + 3] = (0.0, 1.5, 0.5)
    obs_aabb = np.empty((1, 6))
    row_aabb(obstacles[0], verts, obs_aabb[0])
    no_pairs = np.zeros((0, 2), np.int64)
    m = Model(
        chain,
        shapes,
        np.array([0], np.int64),
        verts,
        obstacles,
        obs_aabb,
        no_pairs,
        no_pairs,
        np.array([True]),
        np.array([[True]]),
        np.array([[1.01]]),
        np.array([[[1.01]]]),
        np.array([True]),
        np.array([0], np.int64),
        np.array([[0.5, 0.0, 0.0, 0.52]]),
        np.array([[0, 1]], np.int64),
    )
    return m, verts


def _steps():
    """(name, call) for every kernel entry point, on the tiny scene."""
    m, verts = _scene()
    chain, shapes, obstacles = m.chain, m.shapes, m.obstacles
    KR, Kp = block_chain(chain)
    blk = Blocks(
        KR, Kp, m.spheres, m.shape_spheres, shape_bounds(m.spheres, m.shape_spheres), np.array([BOX], np.int64)
    )
    W = np.array([[0.0], [0.1]])
    Q = np.ascontiguousarray(W)
    heights = np.array([[0.0, 0.3], [0.2, 0.0]])

    def sweep():
        # A 1 x 1 field of height 0: its table is the height itself (the
        # helper process need not compile range_max_table).
        field = HeightField(np.zeros((1, 1, 1, 1)), -1.0, -1.0, 1.0)
        sweep_chains(
            np.array([[0, 1], [0, -1]], np.int64),
            (np.array([[-3.0]]), np.array([[3.0]]), np.array([0.01])),
            np.array([[2]], np.int64),
            np.array([0.2]),
            W,
            m,
            field,
            np.zeros(1),
            np.full(2, np.nan),
            np.zeros((2, 1, MEMO_T, MEMO_W)),  # a memo of both searches (as the online bounds keep)
            np.zeros((2, 1), np.int64),
            np.zeros((1, 6)),
        )

    def footprints():
        mask = np.zeros((8, 8), np.bool_)
        robot_footprint(Q, m, mask, -2.0, -2.0, 0.5)
        poly = np.empty((FOOTPRINT_DIRECTIONS, 2))
        shape_footprint(obstacles[0], verts, poly)
        fill_convex_polygon(mask, poly, -2.0, -2.0, 0.5)
        distance_map(mask)

    return [
        ("fk", lambda: (fk(Q, chain), fk_blocks(Q, chain, KR, Kp))),
        # ``per`` given, as SceneArrays.may_collide gives it: an omitted
        # argument is another signature, compiled again at the first use.
        (
            "configs_may_collide",
            lambda: configs_may_collide(Q, coherent_order(Q, COHERENT_DIMS, COHERENT_BITS), m, blk, 0.0, 4),
        ),
        ("configs_may_collide_serial", lambda: configs_may_collide_serial(Q, m, blk, 0.0)),
        ("range_max_table", lambda: range_max_table(heights)),
        ("sweep_chains", sweep),
        (
            "regions_hit",
            lambda: regions_hit(
                W[:1].copy(),
                W[1:].copy(),
                np.array([0], np.int64),
                np.array([-0.1]),
                np.array([0.1]),
                np.array([2], np.int64),
                np.array([2], np.int64),
                np.array([0.01]),
                m,
            ),
        ),
        (
            "lower_columns_under",
            lambda: lower_columns_under(Q, np.zeros((2, 1)), m, heights.copy(), (-1.0, -1.0, 1.0), 0.0),
        ),
        ("obstacle_distances", lambda: obstacle_distances(Q, 0.5, 1e-3, m)),
        ("footprints", footprints),
        (
            "gjk_intersect",
            lambda: (gjk_intersect(shapes, verts, obstacles, verts), row_aabb(obstacles[0], verts, np.empty(6))),
        ),
    ]


def _helper_wanted(jobs: int | None) -> bool:
    """Whether :func:`warm_up` starts a helper process: ``jobs`` >= 2, or
    (None) two or more cores here and no cached code of the helper's steps
    yet (a fresh cache; a warm one loads in a fraction of a second)."""
    if jobs is not None:
        return int(jobs) >= 2
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        cores = os.cpu_count() or 1
    return cores >= 2 and not cached(sweep_chains)


def cached(dispatcher) -> bool:
    """Whether numba's cache holds compiled code of a ``cache=True``
    function (its index file exists: a fresh cache has none). True where
    numba's internals moved (nothing is then done ahead that would not be
    done at first use)."""
    try:
        return os.path.exists(dispatcher._cache._cache_file._index_path)
    except AttributeError:
        return True


def warm_up_shares(jobs: int | None = None) -> dict:
    """The steps :func:`warm_up` will report and their shares of the work:
    :data:`PARALLEL_SHARES` with a helper process, else :data:`STEP_SHARES`."""
    return dict(PARALLEL_SHARES if _helper_wanted(jobs) else STEP_SHARES)


def warm_up(
    on_step: Callable[[str, float], object] | None = None,
    *,
    jobs: int | None = None,
    meanwhile: Iterable[tuple[str, Callable[[], object]]] = (),
) -> float:
    """Compiles (or loads from numba's cache) every kernel by running it
    once on a tiny made-up scene. ``on_step(name, seconds)`` is called after
    each step (:func:`warm_up_shares` names them). Returns the seconds it
    took; the paper's timing never includes this.

    On a fresh cache with two or more cores (or ``jobs`` >= 2), a helper
    process compiles :data:`HELPER_STEPS` into numba's cache while this one
    compiles the rest; this one then loads them (or compiles them itself
    if the helper failed). ``jobs=1``: everything here, in order.

    ``meanwhile``: (name, call) steps of the caller's, run after this
    process's own kernel steps and before the wait for the helper (other
    compiled code to overlap with it), each reported to ``on_step``.
    """
    t0 = time.perf_counter()
    steps = _steps()
    helper = None
    if _helper_wanted(jobs):
        # The package importable from wherever this process found it.
        root = str(Path(__file__).resolve().parents[2])
        path = os.pathsep.join(p for p in (root, os.environ.get("PYTHONPATH", "")) if p)
        helper = subprocess.Popen(
            [sys.executable, "-m", "drake_cfvol.kernel.warmup", *HELPER_STEPS],
            env=dict(os.environ, PYTHONPATH=path),
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
    try:
        for name, call in steps:
            if helper is not None and name in HELPER_STEPS:
                continue
            t = time.perf_counter()
            call()
            if on_step is not None:
                on_step(name, time.perf_counter() - t)
        for name, call in meanwhile:
            t = time.perf_counter()
            call()
            if on_step is not None:
                on_step(name, time.perf_counter() - t)
        if helper is not None:
            t = time.perf_counter()
            helper.wait()  # a failed helper: its steps compile below instead of loading
            for name, call in steps:
                if name in HELPER_STEPS:
                    call()
            if on_step is not None:
                on_step("helper", time.perf_counter() - t)
    finally:
        if helper is not None and helper.poll() is None:
            helper.kill()  # interrupted: no compile left running behind
            helper.wait()
    return time.perf_counter() - t0


def _main(names) -> int:
    """The helper: compiles the named steps, in :func:`_steps`' order."""
    unknown = set(names) - {name for name, _ in _steps()}
    if unknown:
        print(f"unknown warm-up steps {sorted(unknown)}", file=sys.stderr)
        return 2
    for name, call in _steps():
        if name in names:
            call()
    return 0


if __name__ == "__main__":
    sys.exit(_main(sys.argv[1:]))
