"""Online re-estimation (drake_cfvol.online.reestimate): incremental equals
full, tightening at once, widening only when certified."""

import dataclasses

import numpy as np
import pytest

import drake_cfvol as cf
from drake_cfvol.exceptions import ParameterError
from drake_cfvol.online import MapGrid, ObstacleMap, OnlineBounds

MESH_CELL = "tests/data/mesh_cell.yaml"


def _grid(wc) -> MapGrid:
    return MapGrid.covering(np.asarray(wc.height_map_origin) - 1.0, np.asarray(wc.height_map_size) + 2.0, 0.05)


def _box_map(grid: MapGrid, centre, half, top: float) -> ObstacleMap:
    """A map with one box: the cells its footprint meets, at ``top``."""
    H = np.zeros(grid.shape)
    i, j, _ = grid.cells_of(
        np.array([centre[0] - half, centre[0] + half]), np.array([centre[1] - half, centre[1] + half])
    )
    H[i[0] : i[1] + 1, j[0] : j[1] + 1] = top
    return ObstacleMap(grid, H)


def _near_tool(wc, path, index: int, offset) -> np.ndarray:
    return np.asarray(wc.tool_position(path.waypoints[index]))[:2] + np.asarray(offset)


@pytest.fixture(scope="module")
def mesh_setup():
    wc = cf.load_workcell(MESH_CELL)
    path = cf.plan_nominal_path(wc, *wc.configuration("path1"), seed=0)
    return wc, path, cf.estimate_bounds(wc, path, resolution=400)


@pytest.mark.parametrize("cell", [pytest.param("automotive", marks=pytest.mark.slow), "mesh"])
def test_incremental_equals_full(cell, bounded, planned, automotive, mesh_setup):
    """After a box appears and then moves, the incremental estimate equals a
    full re-estimation of the same scene, bound for bound (near the path the
    searches of these robots all reach the box: see the next tests for
    what is left out)."""
    if cell == "mesh":
        wc, path, table = mesh_setup
        first, second, half, top = (0.25, 0.0), (0.3, 0.05), 0.1, 0.9
    else:
        wc, path, table = automotive, planned("automotive"), bounded("automotive")
        first, second, half, top = (0.6, 0.0), (0.65, 0.1), 0.3, 1.2
    grid = _grid(wc)
    mid = path.g // 2
    m1 = _box_map(grid, _near_tool(wc, path, mid, first), half, top)
    m2 = _box_map(grid, _near_tool(wc, path, mid, second), half, top)
    online = OnlineBounds(wc, table)
    online.update(m1)
    u = online.update(m2)
    full = OnlineBounds(wc, table)
    uf = full.update(m2, full=True)
    for a, b in zip(online.candidate, full.candidate):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(online.heights, full.heights)
    assert 0 < u.searches <= uf.searches == 2 * wc.num_joints * (path.g - 1)


def test_a_search_keeps_the_tests_no_change_reached(mesh_setup):
    """A box moving a little: the stretches it dirties are searched again,
    each test whose own footprint the change missed taking its verdict from
    the last run. The bounds are those of the same update with nothing kept
    (every test run again), and of a full re-estimation; it runs fewer
    tests."""
    wc, path, table = mesh_setup
    grid = _grid(wc)
    mid = path.g // 2
    maps = [_box_map(grid, _near_tool(wc, path, mid, (0.25 + 0.02 * n, 0.0)), 0.1, 0.9) for n in range(3)]
    kept, rerun = OnlineBounds(wc, table), OnlineBounds(wc, table)
    for m in maps[:-1]:
        kept.update(m)
        rerun.update(m)
    rerun._memo_n[:] = 0  # nothing kept: every test of a dirty search runs
    u_kept, u_rerun = kept.update(maps[-1]), rerun.update(maps[-1])
    full = OnlineBounds(wc, table)
    full.update(maps[-1], full=True)
    for a, b, c in zip(kept.candidate, rerun.candidate, full.candidate):
        np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(a, c)
    assert u_kept.searches == u_rerun.searches > 0
    assert u_kept.tests < u_rerun.tests


def test_a_horizon_defers_the_stretches_beyond_it(mesh_setup):
    """With a horizon of 5 stretches an update searches at most 6 stretches
    from the path index; the rest stay dirty until the index comes near,
    and walking the index to the end gives the full estimate."""
    wc, path, table = mesh_setup
    m = _box_map(_grid(wc), _near_tool(wc, path, path.g // 2, (0.25, 0.0)), 0.1, 0.9)
    online = OnlineBounds(wc, table, horizon=5)
    u = online.update(m, 0.0)
    assert u.recomputed <= 6 and u.dirty > 0
    for s in range(0, path.g, 3):
        online.update(m, float(s))
    assert online.update(m, path.g - 2).dirty == 0
    full = OnlineBounds(wc, table)
    full.update(m, full=True)
    for a, b in zip(online.candidate, full.candidate):
        np.testing.assert_array_equal(a, b)


def test_a_box_out_of_every_search_changes_nothing(mesh_setup):
    """A box beyond everything the searches tested (2.5 m from a 1.2 m arm)
    dirties no stretch, and the estimate stays the full one's."""
    wc, path, table = mesh_setup
    grid = _grid(wc)
    m = _box_map(grid, (-2.0, -2.0), 0.1, 1.0)
    online = OnlineBounds(wc, table)
    first = [a.copy() for a in online.candidate]
    u = online.update(m)
    assert u.changed_boxes == 1 and u.searches == 0
    full = OnlineBounds(wc, table)
    full.update(m, full=True)
    for a, b, c in zip(online.candidate, full.candidate, first):
        np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(a, c)


def test_an_unchanged_map_recomputes_nothing(bounded, planned, automotive):
    """The same map twice: the second update searches no stretch."""
    wc, path = automotive, planned("automotive")
    online = OnlineBounds(wc, bounded("automotive"))
    m = _box_map(_grid(wc), _near_tool(wc, path, path.g // 2, (0.6, 0.0)), 0.3, 1.2)
    online.update(m)
    u = online.update(m)
    assert u.recomputed == 0 and u.tests == 0 and u.changed_cells == 0 and u.changed_boxes == 0


def _chains(online):
    lower, upper = online.live.stretch_lower, online.live.stretch_upper
    return lower, upper


def test_tightening_is_immediate(bounded, planned, automotive):
    """In the update that sees a box, every bound the estimate tightens is
    published tightened, and the live box at every waypoint lies within the
    estimate's stretch bounds there."""
    wc, path = automotive, planned("automotive")
    online = OnlineBounds(wc, bounded("automotive"))
    lo0, up0 = (a.copy() for a in _chains(online))
    u = online.update(_box_map(_grid(wc), _near_tool(wc, path, path.g // 2, (0.6, 0.0)), 0.3, 1.2))
    lo_c, up_c = online.candidate
    tighter_up, tighter_lo = up_c < up0, lo_c > lo0
    assert tighter_up.any() or tighter_lo.any(), "the box tightened nothing: the test says nothing"
    assert u.tightened > 0 and u.version == 1
    lo1, up1 = _chains(online)
    np.testing.assert_array_equal(up1[tighter_up], up_c[tighter_up])
    np.testing.assert_array_equal(lo1[tighter_lo], lo_c[tighter_lo])
    for i in range(path.g - 1):
        lo, hi, nom = online.live.at(i + 0.5)
        assert np.all(hi <= np.maximum(up_c[i], nom) + 1e-12) and np.all(lo >= np.minimum(lo_c[i], nom) - 1e-12)


@pytest.mark.parametrize("cell", [pytest.param("automotive", marks=pytest.mark.slow), "mesh"])
def test_widening_only_when_certified(cell, bounded, planned, automotive, mesh_setup, monkeypatch):
    """A bound widens only in stretches whose certificate held in that
    update; with every certificate refused nothing widens even after the box
    is gone; with them granted the live bounds return to the first ones."""
    if cell == "mesh":
        wc, path, table = mesh_setup
        offset, half, top = 0.25, 0.1, 0.9
    else:
        wc, path, table = automotive, planned("automotive"), bounded("automotive")
        offset, half, top = 0.6, 0.3, 1.2
    grid = _grid(wc)
    maps = [_box_map(grid, _near_tool(wc, path, path.g // 2, (offset, dy)), half, top) for dy in (0.0, 0.1, 0.2)]
    maps.append(ObstacleMap.empty(grid))

    def run(refuse: bool):
        online = OnlineBounds(wc, table)
        first = [a.copy() for a in _chains(online)]
        real = online._certified
        granted: list = []

        def spy(i, chains, proofs):
            ok = False if refuse else real(i, chains, proofs)
            if ok:
                granted.append(i)
            return ok

        monkeypatch.setattr(online, "_certified", spy)
        for m in maps:
            before = [a.copy() for a in _chains(online)]
            granted.clear()
            online.update(m)
            lo, up = _chains(online)
            widened = np.nonzero(((up > before[1]) | (lo < before[0])).any(axis=1))[0]
            assert set(widened.tolist()) <= set(granted)
        return online, first

    online, first = run(refuse=True)
    lo, up = _chains(online)
    assert np.all(up <= first[1]) and np.all(lo >= first[0])
    assert (up < first[1]).any() or (lo > first[0]).any()
    online, first = run(refuse=False)
    for a, b in zip(_chains(online), first):
        np.testing.assert_array_equal(a, b)


def test_refuses_a_table_without_its_volume(bounded, automotive):
    """A table loaded from disk has no volume: a clear error says how to grow it."""
    table = dataclasses.replace(bounded("automotive"), volume=None)
    with pytest.raises(ParameterError, match="build_volume"):
        OnlineBounds(automotive, table)
    with pytest.raises(ParameterError, match="horizon"):
        OnlineBounds(automotive, bounded("automotive"), horizon=0)


def test_no_goal_distance_equals_the_raster_transform(mesh_setup):
    """The no-goal distance at V's columns with perceived boxes (the cell's
    part transformed once, each box's rectangle in closed form) equals the
    exact distance transform of the whole raster with the boxes marked in
    it, bit for bit: boxes inside, across the raster's edges and wholly
    outside it (nothing marked), of random sizes."""
    from drake_cfvol import kernel as K

    wc, _, table = mesh_setup
    online = OnlineBounds(wc, table)
    fp = online._fp
    X, Y = online._vb.volume.heightmap.centres()
    ix, iy = fp.indices(X, Y)
    shape = fp.masks["no_goal"].shape
    span = np.array([fp.x0, fp.y0]), np.array([fp.x0, fp.y0]) + np.array(shape) * fp.pixel
    rng = np.random.default_rng(5)
    for n in (0, 1, 3, 6):
        centres = np.c_[rng.uniform(span[0] - 0.5, span[1] + 0.5, (n, 2)), rng.uniform(0.2, 1.0, n)]
        sizes = rng.uniform(0.02, 0.8, (n, 3))
        mask = fp.masks["no_goal"].copy()
        for c, s in zip(centres, sizes):  # rasterised as the pixels the box's footprint meets
            i0, j0 = np.floor((c[:2] - s[:2] / 2 - (fp.x0, fp.y0)) / fp.pixel).astype(int)
            i1, j1 = np.ceil((c[:2] + s[:2] / 2 - (fp.x0, fp.y0)) / fp.pixel).astype(int)
            i0, j0, i1, j1 = np.clip([i0, j0, i1, j1], 0, [shape[0], shape[1], shape[0], shape[1]])
            mask[i0:i1, j0:j1] = True
        expected = K.distance_map(mask)[ix, iy] * fp.pixel if mask.any() else np.full(X.shape, np.inf)
        np.testing.assert_array_equal(online._no_goal_distance(centres, sizes), expected)
