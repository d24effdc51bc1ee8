"""The compiled kernel against independent facts: Drake's poses and
collision checks, exact sphere and box geometry, and brute force over the
height field."""

import time

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import drake_cfvol as cf
from drake_cfvol import kernel as K
from drake_cfvol.algorithm.heightmap import HeightMap, Volume
from drake_cfvol.algorithm.sweep import volume_table
from drake_cfvol.online import MapGrid, ObstacleMap, OnlineBounds

MESH_CELL = "tests/data/mesh_cell.yaml"


@pytest.fixture(scope="module")
def mesh_cell():
    return cf.load_workcell(MESH_CELL)


def _cells(request, names=("automotive", "aerospace")):
    return [request.getfixturevalue(n) for n in names]


def _random_configs(wc, n, seed):
    return np.random.default_rng(seed).uniform(wc.position_lower, wc.position_upper, (n, wc.num_joints))


def _cell(cell, request, mesh_cell):
    if cell == "mesh":
        return mesh_cell
    if cell in ("cobot", "franka"):
        return cf.load_workcell(cell)
    return request.getfixturevalue(cell)


@pytest.mark.parametrize("cell", ["automotive", "aerospace", "cobot", "franka", "mesh"])
def test_fk_matches_drake(cell, request, mesh_cell):
    """Body poses from the kernel's chain, computed in blocks of NB
    configurations (45: a full block and a partial one), equal Drake's to
    1e-12 on random configurations."""
    wc = _cell(cell, request, mesh_cell)
    arrays = wc.scene_arrays()
    Q = _random_configs(wc, K.NB + 45, 1)
    R, p = arrays.fk(Q)
    for n, q in enumerate(Q):
        ctx = wc.plant_context(q)
        for b, index in enumerate(arrays.body_indices):
            X = wc.plant.get_body(index).EvalPoseInWorld(ctx)
            np.testing.assert_allclose(R[n, b], X.rotation().matrix(), atol=1e-12, rtol=0)
            np.testing.assert_allclose(p[n, b], X.translation(), atol=1e-12, rtol=0)


@pytest.mark.parametrize("cell", ["automotive", "aerospace", "cobot", "franka", "mesh"])
def test_never_calls_free_where_drake_collides(cell, request, mesh_cell):
    """On random configurations (about half colliding), the kernel reports
    every configuration Drake finds in collision; and since every shape is
    represented exactly (meshes by their convex hulls, as Drake does), it
    calls nothing else a collision either."""
    wc = _cell(cell, request, mesh_cell)
    Q = _random_configs(wc, 3000, 2)
    drake_hit = ~np.array(wc.checker.CheckConfigsCollisionFree(Q, parallelize=True), bool)
    kernel_hit = wc.scene_arrays().may_collide(Q)
    assert 0.05 * len(Q) < drake_hit.sum() < 0.95 * len(Q)
    assert not (drake_hit & ~kernel_hit).any(), "the kernel called a colliding configuration free"
    assert (kernel_hit & ~drake_hit).sum() <= 0.002 * len(Q)


@pytest.mark.parametrize("cell", ["automotive", "mesh"])
def test_batch_check_answers_do_not_depend_on_the_batch(cell, request, mesh_cell):
    """A configuration's answer is the same alone (the calling thread's
    path), in a partial block, and in a large parallel batch, and agrees
    with Drake's checker, at a pad of 0 and of 2 cm (Drake's padding)."""
    wc = _cell(cell, request, mesh_cell)
    arrays = wc.scene_arrays()
    Q = _random_configs(wc, 600, 3)
    for pad in (0.0, 0.02):
        whole = arrays.may_collide(Q, pad)
        alone = np.array([arrays.may_collide(q[None], pad)[0] for q in Q[:80]])
        partial = arrays.may_collide(Q[: K.NB + 7], pad)
        np.testing.assert_array_equal(alone, whole[:80])
        np.testing.assert_array_equal(partial, whole[: K.NB + 7])
    checker = wc.checker
    for i in range(100):
        if not whole[i]:  # certified free at 2 cm: Drake finds no body within 2 cm
            assert checker.CalcRobotClearance(Q[i], 0.05).distances().min(initial=np.inf) >= 0.02 - 1e-9


def test_a_large_batch_is_checked_in_a_coherent_order_with_the_same_answers(automotive):
    """The batch check sorts a large batch so that neighbours are near (a
    Morton order): the order is a permutation whose consecutive
    configurations are nearer than the drawn order's, and every answer is
    the one the configuration gets on the serial path, whatever order the
    batch comes in."""
    arrays = automotive.scene_arrays()
    Q = _random_configs(automotive, 3000, 5)
    order = K.coherent_order(Q, K.COHERENT_DIMS, K.COHERENT_BITS)
    np.testing.assert_array_equal(np.sort(order), np.arange(len(Q)))
    odd = Q.copy()  # a constant joint, a NaN and infinities still give a permutation
    odd[:, 1], odd[5, 0], odd[7, 2], odd[9, 3] = 0.3, np.nan, np.inf, -np.inf
    np.testing.assert_array_equal(np.sort(K.coherent_order(odd, K.COHERENT_DIMS, K.COHERENT_BITS)), np.arange(len(Q)))
    step = np.linalg.norm(np.diff(Q[order][:, :4], axis=0), axis=1).mean()
    assert step < 0.5 * np.linalg.norm(np.diff(Q[:, :4], axis=0), axis=1).mean()
    whole = arrays.may_collide(Q, 0.02)
    perm = np.random.default_rng(0).permutation(len(Q))
    np.testing.assert_array_equal(arrays.may_collide(Q[perm], 0.02), whole[perm])
    serial = np.concatenate(
        [K.configs_may_collide_serial(Q[i : i + 200], arrays.model, arrays.blocks, 0.02) for i in range(0, len(Q), 200)]
    )
    np.testing.assert_array_equal(whole, serial)
    assert 0 < whole.sum() < len(Q)


def test_the_parallel_loops_answer_as_one_thread_on_the_model_given(automotive, mesh_cell):
    """The parallel entry points take the model into their loops flattened
    and rebuilt (kernel.flat_model): the rebuilt model holds the given
    arrays themselves, and on random regions and paths regions_hit and
    sweep_chains answer, bit for bit, as their compiled callees do on this
    thread with the model as given (the batch check: the test above)."""
    from drake_cfvol.algorithm.sweep import sweep_range, sweep_setup
    from drake_cfvol.kernel.flat_model import flatten_model, model_from_flat
    from drake_cfvol.kernel.regions import _region_hits, _region_workspace, sound_joint_bounding

    for wc in (automotive, mesh_cell):
        arrays = wc.scene_arrays()
        m = arrays.model
        back = model_from_flat(flatten_model(m))
        assert type(back) is K.Model and type(back.chain) is K.Chain
        for a, b in zip((*m.chain, *m[1:]), (*back.chain, *back[1:]), strict=True):
            # The same buffer (an empty array shares no memory, but keeps its pointer).
            assert a.ctypes.data == b.ctypes.data and a.shape == b.shape and a.dtype == b.dtype

        def workspace():
            B, O = m.chain.parent.shape[0], m.obstacles.shape[0]
            return K.new_scratch(), _region_workspace(B, k, O, m.shapes, m.verts, m.spheres, m.shape_spheres)

        k = wc.num_joints
        rng = np.random.default_rng(11)
        Q = _random_configs(wc, 400, 11)
        free = Q[~arrays.may_collide(Q, 0.02)]
        # Regions from free and from random configurations. 32 tasks: regions_hit runs chunks of 4,
        # each on one workspace, the quick pass tried on every task (QUICK_TRIALS = 8); so does this.
        n = 32
        A = np.where(np.arange(n)[:, None] % 2 == 0, free[:n], Q[:n])
        B = A + rng.normal(0.0, 0.05, A.shape)
        js = rng.integers(0, k, n)
        va = A[np.arange(n), js] - rng.uniform(0.0, 0.2, n)
        vb = A[np.arange(n), js] + rng.uniform(0.0, 0.2, n)
        nts = rng.integers(2, K.MAX_T_SAMPLES + 1, n)
        nvs = rng.integers(2, K.MAX_V_SAMPLES + 1, n)
        pads = rng.uniform(0.0, 0.03, n)
        hits = K.regions_hit(A, B, js, va, vb, nts, nvs, pads, m)
        ref = np.zeros(n, bool)
        for c in range(0, n, 4):
            sc, rs = workspace()
            for i in range(c, c + 4):
                W = np.ascontiguousarray(np.stack([A[i], B[i]]))
                ts, vs = (0.0, 1.0, nts[i]), (va[i], vb[i], nvs[i])
                ref[i] = _region_hits(W, 0, js[i], ts, vs, m, K.no_height_field(), sc, rs, pads[i])
        np.testing.assert_array_equal(hits, ref)
        assert 0 < hits.sum() < n
        # The sweep of a short random path from a free configuration, every chain cold.
        W = np.cumsum(np.vstack([free[-1], rng.normal(0.0, 0.03, (4, k))]), axis=0)
        lo, hi = np.tile(wc.position_lower, (4, 1)), np.tile(wc.position_upper, (4, 1))
        setup = sweep_setup(arrays, W, cf.VolumeParams(), lo, hi)
        field = volume_table(None)
        bounds, tests, fps = sweep_range(setup, arrays, W, field, 0, 3, np.full(len(setup.chains), np.nan))
        no_memo, changed = np.zeros((0, K.MEMO_W)), np.zeros((0, 6))
        for c, (j, sgn) in enumerate(setup.chains):
            sc, rs = workspace()
            guess, count = np.nan, 0
            for i in range(4):
                rs.fp[:3], rs.fp[3:] = np.inf, -np.inf
                grid = (setup.nts[i, j], setup.v_steps[j])
                lims = (setup.lim_lo, setup.lim_hi, setup.delta)
                guess, run, _ = sound_joint_bounding(
                    i,
                    j,
                    sgn,
                    guess,
                    W,
                    lims,
                    grid,
                    m,
                    K.HeightField(*field),
                    sc,
                    rs,
                    setup.margins[i],
                    no_memo,
                    0,
                    changed,
                )
                assert guess == bounds[c, i]
                # A search that runs no test (its limit inside the nominal's range) has no footprint:
                # sweep_chains reports the chain's previous one there (numba's parallel loop drops the
                # reset before it), a box no change of the scene can make matter.
                if run > 0:
                    np.testing.assert_array_equal(rs.fp, fps[c, i])
                count += run
            assert count == tests[c]


def test_sincos_matches_the_library():
    """The kernel's branch-free sine and cosine equal libm's within 3e-16
    over the angles a joint can have, quadrant boundaries included."""
    from numba import njit

    @njit
    def both(x):
        s = np.empty_like(x)
        c = np.empty_like(x)
        for i in range(x.shape[0]):
            s[i], c[i] = K.blocks.sincos(x[i])
        return s, c

    x = np.concatenate(
        [
            np.random.default_rng(0).uniform(-4 * np.pi, 4 * np.pi, 200_000),
            np.arange(-16, 17) * np.pi / 4,
            np.arange(-16, 17) * np.pi / 4 + 1e-12,
        ]
    )
    s, c = both(x)
    np.testing.assert_allclose(s, np.sin(x), atol=3e-16, rtol=0)
    np.testing.assert_allclose(c, np.cos(x), atol=3e-16, rtol=0)


def _box_row(c, half, R=np.eye(3)):
    row = np.zeros(K.SHAPE_W)
    row[0] = K.BOX
    row[1:4], row[4:13], row[13:16] = c, np.asarray(R).ravel(), half
    return row[None]


def _sphere_row(c, r):
    row = np.zeros(K.SHAPE_W)
    row[0] = K.SPHERE
    row[1:4], row[4:13], row[13] = c, np.eye(3).ravel(), r
    return row[None]


def _sat_overlap(A, B):
    """Box-box overlap by the 15-axis separating-axis theorem."""
    RA, RB = A[0, 4:13].reshape(3, 3), B[0, 4:13].reshape(3, 3)
    hA, hB, t = A[0, 13:16], B[0, 13:16], B[0, 1:4] - A[0, 1:4]
    axes = [RA[:, i] for i in range(3)] + [RB[:, i] for i in range(3)]
    axes += [np.cross(RA[:, i], RB[:, j]) for i in range(3) for j in range(3)]
    for L in axes:
        if np.linalg.norm(L) > 1e-9 and abs(L @ t) > np.abs(L @ RA) @ hA + np.abs(L @ RB) @ hB:
            return False
    return True


def test_gjk_agrees_with_exact_tests():
    """GJK equals the exact sphere-sphere distance test and the box-box
    separating-axis test on random pairs, with motion sets: a sphere grown
    by a ball of radius e is a sphere of radius r + e."""
    rng = np.random.default_rng(3)
    V = np.zeros((0, 3))
    for _ in range(3000):
        c1, c2 = rng.uniform(-1, 1, (2, 3))
        r1, r2, e = rng.uniform(0.05, 0.6, 3)
        A = _sphere_row(c1, r1)
        A[0, 18] = e  # e_iso
        assert K.gjk_intersect(A, V, _sphere_row(c2, r2), V) == (np.linalg.norm(c1 - c2) <= r1 + r2 + e)
    for _ in range(3000):
        A = _box_row(rng.uniform(-1, 1, 3), rng.uniform(0.05, 0.7, 3), Rotation.random(random_state=rng).as_matrix())
        B = _box_row(rng.uniform(-1, 1, 3), rng.uniform(0.05, 0.7, 3), Rotation.random(random_state=rng).as_matrix())
        assert K.gjk_intersect(A, V, B, V) == _sat_overlap(A, B)


def test_hull_of_two_poses_covers_the_segment_between():
    """An object of two rows is the convex hull of both: a small sphere
    halfway between two far poses of a box meets it, one beside it does not."""
    V = np.zeros((0, 3))
    two = np.concatenate([_box_row([-1, 0, 0], [0.1, 0.1, 0.1]), _box_row([1, 0, 0], [0.1, 0.1, 0.1])])
    assert K.gjk_intersect(two, V, _sphere_row([0, 0, 0], 0.05), V)
    assert not K.gjk_intersect(two, V, _sphere_row([0, 0.3, 0], 0.05), V)


@pytest.mark.slow  # 7 s: CI's slow group runs it
def test_height_field_test_matches_brute_force():
    """Shapes against the columns of V: the kernel's halving search equals
    testing every column as its own box."""
    rng = np.random.default_rng(4)
    hm = HeightMap((-1.0, -1.0), 2.0, 2.0, 400)
    heights = np.where(rng.random(hm.shape) < 0.5, rng.uniform(0.0, 1.0, hm.shape), 0.0)
    vol = Volume(hm, heights, heights.copy())
    table, ox, oy, side = volume_table(vol)
    X, Y = hm.centres()
    V = np.zeros((0, 3))
    ws, stack, box, tmp6 = K.new_workspace()
    aabb = np.empty(6)
    for _ in range(400):
        obj = _box_row(
            rng.uniform([-1, -1, 0.2], [1, 1, 1.4]),
            rng.uniform(0.02, 0.3, 3),
            Rotation.random(random_state=rng).as_matrix(),
        )
        K.row_aabb(obj[0], V, aabb)
        fast = K.object_hits_columns(obj, V, aabb, table, ox, oy, side, ws, stack, box)
        brute = any(
            K.gjk_intersect(
                obj, V, _box_row([X[i, j], Y[i, j], heights[i, j] / 2], [side / 2, side / 2, heights[i, j] / 2]), V
            )
            for i, j in zip(*np.nonzero(heights > 0))
        )
        assert fast == brute


def _drake_extent(wc, q, j, sign, step=0.005):
    """How far joint j alone can move from q (one direction) before Drake
    finds a collision with the real scene, sampled every ``step``."""
    limit = wc.position_upper[j] if sign > 0 else wc.position_lower[j]
    span = abs(limit - q[j])
    t = np.r_[np.arange(step, span, step), span]
    Q = np.repeat(q[None], len(t), axis=0)
    Q[:, j] = q[j] + sign * t
    free = np.array(wc.checker.CheckConfigsCollisionFree(Q, parallelize=True), bool)
    return span if free.all() else (t[np.argmin(free) - 1] if np.argmin(free) > 0 else 0.0)


def test_mesh_robot_compact_wrist_keeps_its_freedom(mesh_cell):
    """On the mesh robot (convex-hull links, a compact wrist whose links
    nearly touch), no joint gets zero width where Drake lets it move more
    than 0.1 rad alone, and every width is at least 60 % of Drake's
    single-joint extent (no volume: both against the real scene)."""
    rng = np.random.default_rng(5)
    checked = 0
    while checked < 6:
        q = rng.uniform(mesh_cell.position_lower, mesh_cell.position_upper)
        if not mesh_cell.is_free(q):
            continue
        checked += 1
        path = cf.NominalPath(np.array([q, q]), mesh_cell.joint_names, mesh_cell.name)
        table = cf.estimate_bounds(mesh_cell, path, h_max=0.0, clearance=0.0)  # Drake's extents: no padding
        for j in range(mesh_cell.num_joints):
            true_width = _drake_extent(mesh_cell, q, j, +1) + _drake_extent(mesh_cell, q, j, -1)
            width = table.upper[0, j] - table.lower[0, j]
            assert width <= true_width + 2 * table.params["delta"] + 0.01
            if true_width > 0.1:
                assert width > 0, f"joint {j} zeroed at {q}"
            assert width >= 0.6 * true_width, f"joint {j}: {width:.3f} of {true_width:.3f} rad at {q}"


def test_a_changed_kernel_source_clears_numbas_cache(tmp_path):
    """numba invalidates a function's cache only when its own file changes:
    the kernel clears its cache whenever any of its sources changed (its
    kinds' modules in a subfolder included; a hash kept beside the cache),
    and keeps it while they are unchanged."""
    from drake_cfvol.kernel import _clear_stale_cache

    src, cache = tmp_path / "kernel", tmp_path / "kernel" / "__pycache__"
    cache.mkdir(parents=True)
    (src / "a.py").write_text("x = 1\n")
    (src / "b.py").write_text("y = 2\n")
    entries = [cache / "a.f-1.py311.nbi", cache / "a.f-1.py311.1.nbc", cache / "b.g-3.py311.nbi"]

    def fill():
        for f in entries:
            f.write_bytes(b"compiled")

    fill()
    _clear_stale_cache(src, [cache])  # no hash yet: cleared, hash written
    assert not any(f.exists() for f in entries) and (cache / "kernel_sources.sha256").is_file()
    fill()
    _clear_stale_cache(src, [cache])  # unchanged sources: kept
    assert all(f.exists() for f in entries)
    (src / "b.py").write_text("y = 3\n")  # a callee's file changed
    _clear_stale_cache(src, [cache])
    assert not any(f.exists() for f in entries)
    fill()
    _clear_stale_cache(src, [cache])  # the changed sources' hash kept: kept
    assert all(f.exists() for f in entries)
    (src / "kinds").mkdir()
    (src / "kinds" / "box.py").write_text("z = 1\n")  # a kind's module (a subfolder) changed
    _clear_stale_cache(src, [cache])
    assert not any(f.exists() for f in entries)


def test_a_cache_folder_numba_makes_later_gets_the_hash_with_its_first_entry(tmp_path, monkeypatch):
    """The stale check does not make folders (numba's user-wide one, say);
    numba's first save into one, under the package's lock, writes the
    sources' hash beside the entry, so the next check keeps it."""
    from numba.core import caching

    from drake_cfvol.kernel import _clear_stale_cache, cache_lock

    src, cache = tmp_path / "kernel", tmp_path / "elsewhere" / "kernel_0123"
    src.mkdir()
    (src / "a.py").write_text("x = 1\n")
    monkeypatch.setattr(cache_lock, "STAMP", _clear_stale_cache(src, [cache]))
    assert not cache.exists()
    monkeypatch.setattr(cache_lock, "_folders", {str(cache)})
    cache.mkdir(parents=True)  # numba's ensure_cache_path
    f = caching.IndexDataCacheFile(cache_path=str(cache), filename_base="a.f-1.py311", source_stamp=(1.0, 2))
    f.save(("sig",), ("code",))
    assert (cache / "kernel_sources.sha256").read_text() == cache_lock.STAMP
    _clear_stale_cache(src, [cache])  # the same sources: the entry kept
    assert f.load(("sig",)) == ("code",)


def test_the_warm_up_file_is_not_part_of_the_cache_stamp(tmp_path):
    """warmup.py compiles nothing: editing it keeps the cache."""
    from drake_cfvol.kernel import _clear_stale_cache

    src, cache = tmp_path / "kernel", tmp_path / "kernel" / "__pycache__"
    cache.mkdir(parents=True)
    (src / "a.py").write_text("x = 1\n")
    (src / "warmup.py").write_text("steps = 1\n")
    entry = cache / "a.f-1.py311.nbi"
    _clear_stale_cache(src, [cache])
    entry.write_bytes(b"compiled")
    (src / "warmup.py").write_text("steps = 2\n")
    _clear_stale_cache(src, [cache])
    assert entry.exists()
    (src / "a.py").write_text("x = 2\n")
    _clear_stale_cache(src, [cache])
    assert not entry.exists()


def test_every_compiled_function_of_the_package_caches_under_the_lock():
    """Every numba function of the package (the kernel's, the filter's, the
    online map's, the certificate's) keeps its cache through the locked
    index, in a folder counted as the package's; numba's class for other
    libraries' functions is the subclass, which locks nothing for them."""
    import importlib
    import pkgutil

    from numba.core import caching
    from numba.core.registry import CPUDispatcher

    import drake_cfvol
    from drake_cfvol.kernel import cache_lock

    found = 0
    for info in pkgutil.walk_packages(drake_cfvol.__path__, "drake_cfvol."):
        if info.name.startswith("drake_cfvol.apps") or info.name.endswith("__main__"):
            continue  # command lines: nothing compiled
        module = importlib.import_module(info.name)
        for obj in vars(module).values():
            if isinstance(obj, CPUDispatcher) and obj.__module__ == info.name and obj._cache is not None:
                cache_file = getattr(obj._cache, "_cache_file", None)
                if cache_file is None:  # numba's "no cache" object
                    continue
                assert getattr(cache_file, "_drake_cfvol_locked", False), info.name
                assert cache_file._lock_folder is not None, (info.name, obj._cache.cache_path)
                found += 1
    assert found > 100  # the package's compiled functions, not a handful
    assert caching.IndexDataCacheFile._drake_cfvol_locked
    assert not cache_lock.is_ours("/tmp/elsewhere/__pycache__")


def test_the_package_cache_folders_are_where_numba_puts_them(monkeypatch, tmp_path):
    """The folders the stale-cache check clears and the lock covers are the
    ones numba's own locators give for a kernel function: beside its file,
    under NUMBA_CACHE_DIR and in numba's user-wide folder; another
    library's folders are not the package's."""
    import inspect

    import numba
    from numba.core import caching

    from drake_cfvol.kernel import cache_lock

    monkeypatch.setattr(numba.config, "CACHE_DIR", str(tmp_path / "numba_cache"))
    monkeypatch.setattr(cache_lock, "_folders", None)  # named again with this CACHE_DIR
    folders = {str(f) for f in cache_lock.package_cache_folders()}
    for fn in (K.fk, K.regions_hit):
        file = inspect.getsourcefile(fn.py_func)
        for locator in (caching.InTreeCacheLocator, caching.UserProvidedCacheLocator, caching.UserWideCacheLocator):
            path = locator(fn.py_func, file).get_cache_path()
            assert path in folders, (locator.__name__, path)
            assert cache_lock.is_ours(path)
    other = inspect.getsourcefile(numba.core.caching)
    for locator in (caching.InTreeCacheLocator, caching.UserWideCacheLocator):
        assert not cache_lock.is_ours(locator(caching.Cache.__init__, other).get_cache_path())


# The children load cache_lock.py alone (the package's import would take
# seconds): it installs the same class the package does.
_SAVER = """
import importlib.util, sys, time
from pathlib import Path
spec = importlib.util.spec_from_file_location("cache_lock", sys.argv[4])
cache_lock = importlib.util.module_from_spec(spec)
spec.loader.exec_module(cache_lock)
assert cache_lock.install()
from numba.core import caching

folder, tag, n = sys.argv[1], sys.argv[2], int(sys.argv[3])
cache_lock._folders = {folder}  # this folder counts as the package's
f = caching.IndexDataCacheFile(cache_path=folder, filename_base="f-1.py311", source_stamp=(1.0, 2))
(Path(folder) / ("ready-" + tag)).touch()
while not (Path(folder) / "go").exists():
    time.sleep(0.001)
for i in range(n):
    f.save((tag, i), (tag, i, "compiled for", tag, i))
"""


def test_two_processes_saving_one_functions_cache_at_once_keep_each_entry(tmp_path):
    """numba's own save is a read-modify-write of the index without a lock
    between processes (two processes could each take data file 1 for their
    own signature, and a later load would get the other's code). Under the
    package's lock, two processes saving 150 signatures each at the same
    time leave an index where every signature names a data file of its
    own, holding the code saved for that signature."""
    import subprocess
    import sys

    from numba.core import caching

    from drake_cfvol.kernel import cache_lock

    folder = tmp_path / "cache"
    folder.mkdir()
    n = 150
    procs = [
        subprocess.Popen([sys.executable, "-c", _SAVER, str(folder), tag, str(n), cache_lock.__file__])
        for tag in ("a", "b")
    ]
    deadline = time.monotonic() + 120
    while not all((folder / f"ready-{t}").exists() for t in ("a", "b")) and time.monotonic() < deadline:
        time.sleep(0.01)
    (folder / "go").touch()  # both start saving at once
    assert [p.wait(timeout=120) for p in procs] == [0, 0]
    old = cache_lock._folders
    try:
        cache_lock._folders = {str(folder)}
        f = caching.IndexDataCacheFile(cache_path=str(folder), filename_base="f-1.py311", source_stamp=(1.0, 2))
        index = f._load_index()
        assert len(index) == 2 * n and len(set(index.values())) == 2 * n
        for tag in ("a", "b"):
            for i in range(n):
                assert f.load((tag, i)) == (tag, i, "compiled for", tag, i)
    finally:
        cache_lock._folders = old


_ENTRY_POINTS = (
    "configs_may_collide",
    "configs_may_collide_serial",
    "coherent_order",
    "regions_hit",
    "sweep_chains",
    "fk",
    "fk_blocks",
)


def _signatures():
    return {name: list(getattr(K, name).signatures) for name in _ENTRY_POINTS}


def test_the_warm_up_compiles_the_signatures_the_package_calls(automotive, mesh_cell):
    """Every entry point's signature as the package calls it (read-only
    inputs, an optional argument given) is the one the warm-up compiled: a
    fresh cache compiles each once, not again at first use."""
    from drake_cfvol.algorithm.certificate.boundary_regions import regions_may_collide

    K.warm_up(jobs=1)
    before = _signatures()
    assert all(len(v) == 1 for v in before.values()), before
    for wc in (automotive, mesh_cell):
        arrays = wc.scene_arrays()
        rng = np.random.default_rng(0)
        Q = rng.uniform(wc.position_lower, wc.position_upper, (300, wc.num_joints))
        Q.flags.writeable = False
        arrays.may_collide(Q)  # blocks over the thread pool
        arrays.may_collide(Q[:2])  # on this thread
        arrays.fk(Q)
        A = np.broadcast_to(Q[0], (3, wc.num_joints))  # read-only views
        js = np.zeros(3, np.int64)
        regions_may_collide(arrays, A, Q[1:4], js, Q[:3, 0] - 0.1, Q[:3, 0], 0.02)
    # The sweep without a memo (bounding) and with one (the online bounds).
    path = cf.plan_nominal_path(mesh_cell, *mesh_cell.configuration("path1"), seed=0)
    table = cf.estimate_bounds(mesh_cell, path, resolution=200)
    online = OnlineBounds(mesh_cell, table)
    grid = MapGrid.covering(np.asarray(mesh_cell.height_map_origin), np.asarray(mesh_cell.height_map_size), 0.05)
    H = np.zeros(grid.shape)
    H[grid.shape[0] // 2, grid.shape[1] // 2] = 0.5
    online.update(ObstacleMap(grid, H))
    assert _signatures() == before


@pytest.mark.slow  # 3 s (a second Python process): CI's slow group runs it
def test_a_warm_up_with_a_helper_process_gives_the_same_kernels():
    """jobs=2: the helper compiles (here, on a warm cache, loads) its steps
    in another process; this one then loads them and reports one wait."""
    names = []
    K.warm_up(lambda name, s: names.append(name), jobs=2)
    assert names == [n for n in K.STEP_SHARES if n not in K.HELPER_STEPS] + ["helper"]
    assert list(K.PARALLEL_SHARES) == names
    assert all(len(v) == 1 for v in _signatures().values())


def _capsule_row(c, r, half, R):
    row = np.zeros(K.SHAPE_W)
    row[0] = K.CAPSULE
    row[1:4], row[4:13], row[13], row[14] = c, np.asarray(R).ravel(), r, half
    return row[None]


@pytest.mark.slow  # 4 s: CI's slow group runs it
def test_box_separation_before_gjk_is_exact_for_boxes_and_never_wrong():
    """The separating-axis broad phase ahead of GJK: for two boxes it says
    apart exactly when the 15-axis test (by hand) finds them apart, and for
    boxes, capsules and spheres, grown by random inflations, it never says
    apart where GJK finds them touching."""
    from drake_cfvol.kernel.shapes import obb_apart

    rng = np.random.default_rng(7)
    V = np.zeros((0, 3))
    for _ in range(3000):
        A = _box_row(rng.uniform(-1, 1, 3), rng.uniform(0.05, 0.7, 3), Rotation.random(random_state=rng).as_matrix())
        B = _box_row(rng.uniform(-1, 1, 3), rng.uniform(0.05, 0.7, 3), Rotation.random(random_state=rng).as_matrix())
        assert obb_apart(A[0], B[0]) == (not _sat_overlap(A, B))
    apart = 0
    for _ in range(6000):
        rows = [
            _box_row(rng.uniform(-1, 1, 3), rng.uniform(0.05, 0.5, 3), Rotation.random(random_state=rng).as_matrix()),
            _capsule_row(
                rng.uniform(-1, 1, 3),
                rng.uniform(0.05, 0.3),
                rng.uniform(0.0, 0.5),
                Rotation.random(random_state=rng).as_matrix(),
            ),
            _sphere_row(rng.uniform(-1, 1, 3), rng.uniform(0.05, 0.5)),
        ]
        a, b = rng.choice(3, 2)
        A, B = rows[a].copy(), rows[b].copy()
        A[0, 18], B[0, 18] = rng.uniform(0, 0.1, 2)  # inflations (a pad)
        if obb_apart(A[0], B[0]):
            apart += 1
            assert not K.gjk_intersect(A, V, B, V)
    assert apart > 1000  # the broad phase decides a good share


def _row(kind, centre, verts_range=(0, 0)):
    row = np.zeros(K.SHAPE_W)
    row[K.ROW_KIND] = kind
    row[K.ROW_CENTRE : K.ROW_CENTRE + 3] = centre
    row[K.ROW_ROTATION : K.ROW_ROTATION + 9] = np.eye(3).ravel()
    row[K.ROW_SIZE : K.ROW_SIZE + 3] = (0.2, 0.3, 0.25)
    row[K.ROW_FIRST_VERTEX], row[K.ROW_END_VERTEX] = verts_range
    return row


def test_every_kind_through_every_kernel_function():
    """Each shape kind's support, box and oriented box against hand-computed
    extents (a unit-free 0.2 / 0.3 / 0.25 shape at the origin), and GJK
    against a box 1 m away (apart) and one touching it (may collide); a kind
    the kernel does not know reaches everywhere: its box is infinite and
    nothing is ever apart from it (never a silent "free")."""
    from drake_cfvol.kernel.shapes import obb_apart, support

    cube = np.array([[x, y, z] for x in (-0.2, 0.2) for y in (-0.3, 0.3) for z in (-0.25, 0.25)])
    # extent along +x, +z, and the oriented box's half sizes (None: none) per kind
    expect = {
        K.BOX: (0.2, 0.25),
        K.SPHERE: (0.2, 0.2),
        K.CAPSULE: (0.2, 0.5),
        K.CYLINDER: (0.2, 0.3),
        K.ELLIPSOID: (0.2, 0.25),
        K.HULL: (0.2, 0.25),
    }
    far = _row(K.BOX, (1.2 + 0.2 + 0.05, 0.0, 0.0))
    for kind, (ex, ez) in expect.items():
        row = _row(kind, (0.0, 0.0, 0.0), (0, 8) if kind == K.HULL else (0, 0))
        out = np.empty(3)
        support(row, cube, 1.0, 0.0, 0.0, out)
        assert out[0] == pytest.approx(ex, abs=1e-12), kind
        support(row, cube, 0.0, 0.0, 1.0, out)
        assert out[2] == pytest.approx(ez, abs=1e-12), kind
        box = np.empty(6)
        K.row_aabb(row, cube, box)
        np.testing.assert_allclose(box[[3, 5]], [ex, ez], atol=1e-12)
        touching = _row(K.BOX, (ex + 0.2 - 1e-6, 0.0, 0.0))
        assert not K.gjk_intersect(row[None], cube, far[None], cube), kind
        assert K.gjk_intersect(row[None], cube, touching[None], cube), kind
        assert obb_apart(row, far) == (kind != K.HULL)  # a hull has no oriented box of its own
    unknown = _row(9, (0.0, 0.0, 0.0))
    box = np.empty(6)
    K.row_aabb(unknown, cube, box)
    assert np.all(box[:3] == -np.inf) and np.all(box[3:] == np.inf)
    assert K.gjk_intersect(unknown[None], cube, far[None], cube)
    assert not obb_apart(unknown, far)
    empty_hull = _row(K.HULL, (0.0, 0.0, 0.0))  # no vertices: not a shape, never free
    assert K.gjk_intersect(empty_hull[None], cube, far[None], cube)
