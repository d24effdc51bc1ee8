"""The perceived columns (drake_cfvol.systems.columns): tiles cover every
occupied cell at its height, never leave the occupied cells unless a level
runs out, and stand where the map says in the SceneGraph."""

import numpy as np
import pytest
from pydrake.common.value import AbstractValue
from pydrake.geometry import SceneGraph
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantValueSource

from drake_cfvol.online import MapGrid, ObstacleMap
from drake_cfvol.systems import PerceivedColumns
from drake_cfvol.systems.columns import PARKED_Z, tile_rectangles


def _random_map(rng, shape=(40, 30)) -> np.ndarray:
    H = np.zeros(shape)
    for _ in range(6):
        i, j = rng.integers(0, shape[0] - 8), rng.integers(0, shape[1] - 8)
        H[i : i + rng.integers(1, 9), j : j + rng.integers(1, 9)] = np.round(rng.uniform(0.1, 2.0), 2)
    return H


def _cover(tiles, shape):
    top = np.zeros(shape)
    for level, i, j, h in tiles:
        t = 1 << level
        top[i : i + t, j : j + t] = np.maximum(top[i : i + t, j : j + t], h)
    return top


@pytest.mark.parametrize("seed", range(5))
def test_tiles_cover_every_occupied_cell_and_nothing_else(seed):
    """With room in every level, the tiles cover exactly the occupied cells,
    each at least as high as the cell (and no higher than its block's top)."""
    H = _random_map(np.random.default_rng(seed))
    tiles, overflow = tile_rectangles(H, levels=5, per_level=1000)
    top = _cover(tiles, H.shape)
    assert overflow == 0
    assert np.all(top[H > 0] >= H[H > 0]) and np.all(top[H == 0] == 0.0)


def test_a_full_level_hands_its_tiles_to_the_next():
    """One 1-cell tile allowed: the other cells get 2-cell tiles (covering
    more, never less); with no level left they are counted as overflow."""
    H = np.zeros((8, 8))
    H[0, 0] = H[4, 4] = H[6, 1] = 1.0
    tiles, overflow = tile_rectangles(H, levels=2, per_level=1)
    assert overflow == 1 and len(tiles) == 2
    assert sorted(t[0] for t in tiles) == [0, 1]
    top = _cover(tiles, H.shape)
    assert np.count_nonzero(top[H > 0]) == 2


def test_columns_stand_where_the_map_says():
    """A 2 x 2-cell block 0.7 m high: one column whose top is at 0.7 m over
    that block; every other column parked below PARKED_Z."""
    grid = MapGrid((0.0, 0.0), 0.1, (10, 10))
    H = np.zeros(grid.shape)
    H[4:6, 2:4] = 0.7
    builder = DiagramBuilder()
    sg = builder.AddSystem(SceneGraph())
    cols = builder.AddSystem(PerceivedColumns(sg, grid, levels=3, per_level=4))
    src = builder.AddSystem(ConstantValueSource(AbstractValue.Make(ObstacleMap(grid, H))))
    builder.Connect(src.get_output_port(), cols.obstacle_map_input)
    builder.Connect(cols.geometry_pose_output, sg.get_source_pose_port(cols.source_id))
    diagram = builder.Build()
    ctx = diagram.CreateDefaultContext()
    query = sg.get_query_output_port().Eval(sg.GetMyContextFromRoot(ctx))
    active = [g for g in cols.geometry_ids if query.GetPoseInWorld(g).translation()[2] > PARKED_Z / 2]
    assert len(active) == 1
    p = query.GetPoseInWorld(active[0]).translation()
    np.testing.assert_allclose(p[:2], [0.5, 0.3], atol=1e-12)
    assert p[2] + cols.depth / 2 == pytest.approx(0.7)
