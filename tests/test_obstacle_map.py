"""The obstacle map's rules (drake_cfvol.online.obstacle_map), on points placed by hand."""

import numpy as np
import pytest

from drake_cfvol.exceptions import ParameterError
from drake_cfvol.online import MapGrid, ObstacleMap, PerceptionParams

GRID = MapGrid((0.0, 0.0), 0.1, (20, 10))  # 2 m x 1 m, 10 cm cells


def _points(xyz) -> np.ndarray:
    return np.asarray(xyz, float).reshape(-1, 3).T


def test_new_points_occupy_their_cell_at_the_rounded_up_top():
    """A point at (0.35, 0.55, 0.51) makes cell (3, 5) 0.52 m high (0.02 m
    steps); without dilation no other cell is occupied."""
    p = PerceptionParams(cell=0.1, height_step=0.02, dilation=0)
    m = ObstacleMap.empty(GRID).integrate(_points([0.35, 0.55, 0.51]), _points([]), 1.0, p)
    assert m.heights[3, 5] == pytest.approx(0.52)
    assert m.occupied == 1 and m.stamp == 1.0


def test_dilation_lends_the_height_to_the_neighbours():
    """Dilation 2 makes the 5 x 5 block around the cell as high, nothing else."""
    p = PerceptionParams(cell=0.1, dilation=2)
    m = ObstacleMap.empty(GRID).integrate(_points([1.05, 0.45, 1.0]), _points([]), 0.0, p)
    occupied = np.argwhere(m.heights > 0)
    assert occupied.min(axis=0).tolist() == [8, 2] and occupied.max(axis=0).tolist() == [12, 6]
    assert m.occupied == 25 and np.all(m.heights[m.heights > 0] == pytest.approx(1.0))


def test_floor_points_are_not_obstacles():
    """Points at most ``floor`` high (the floor seen) occupy nothing."""
    p = PerceptionParams(cell=0.1, floor=0.02, dilation=0)
    m = ObstacleMap.empty(GRID).integrate(_points([[0.5, 0.5, 0.01], [0.7, 0.5, 0.0]]), _points([]), 0.0, p)
    assert m.occupied == 0


def test_seen_cells_clear_unseen_cells_hold():
    """A cell seen as the model has it is cleared; a cell not seen keeps its
    height."""
    p = PerceptionParams(cell=0.1, dilation=0)
    m = ObstacleMap.empty(GRID).integrate(_points([[0.15, 0.15, 0.5], [1.55, 0.55, 0.7]]), _points([]), 0.0, p)
    m2 = m.integrate(_points([]), _points([0.15, 0.15, 0.0]), 0.1, p)
    assert m2.heights[1, 1] == 0.0
    assert m2.heights[15, 5] == pytest.approx(0.7)


def test_occupancy_spreads_under_the_robot_at_the_assumed_speed():
    """A cell last seen occupied 0.4 s ago spreads, at 0.5 m/s, 0.2 m = 2
    cells into the cells the robot hides, not into cells out of view, and
    not farther."""
    p = PerceptionParams(cell=0.1, dilation=0, speed=0.5, spread_time=1.0)
    m = ObstacleMap.empty(GRID).integrate(_points([1.05, 0.55, 0.8]), _points([]), 0.0, p)
    hidden = _points([[x, 0.55, 1.0] for x in np.arange(0.05, 2.0, 0.1)])  # the robot over row j = 5
    m2 = m.integrate(_points([]), _points([]), 0.4, p, hidden)
    assert m2.heights[10, 5] == pytest.approx(0.8)  # held where it was last seen
    # Hidden cells (row 5, +-1 by the hiding margin) within 2 cells get it.
    for i in (8, 9, 11, 12):
        assert m2.heights[i, 5] == pytest.approx(0.8)
    assert m2.heights[7, 5] == 0.0 and m2.heights[13, 5] == 0.0
    assert m2.heights[10, 8] == 0.0  # out of view, not hidden: no spread


def test_spread_is_measured_from_what_was_seen_not_from_what_was_assumed():
    """Spread cells do not spread again at the next image: after 0.4 s and
    another 0.2 s the spread is 3 cells from the seen cell, not 5."""
    p = PerceptionParams(cell=0.1, dilation=0, speed=0.5)
    m = ObstacleMap.empty(GRID).integrate(_points([1.05, 0.55, 0.8]), _points([]), 0.0, p)
    hidden = _points([[x, 0.55, 1.0] for x in np.arange(0.05, 2.0, 0.1)])
    m = m.integrate(_points([]), _points([]), 0.4, p, hidden)
    m = m.integrate(_points([]), _points([]), 0.6, p, hidden)
    row = np.nonzero(m.heights[:, 5] > 0)[0]
    assert row.min() == 7 and row.max() == 13


def test_boxes_cover_exactly_the_occupied_cells():
    """Merged boxes stand on the floor over exactly the occupied cells, each
    as high as its cells."""
    H = np.zeros(GRID.shape)
    H[2:5, 3:7] = 0.5
    H[10, 1] = 1.2
    centres, sizes = ObstacleMap(GRID, H).boxes()
    covered = np.zeros(GRID.shape)
    for c, s in zip(centres, sizes):
        i0, i1 = int(round((c[0] - s[0] / 2) / 0.1)), int(round((c[0] + s[0] / 2) / 0.1))
        j0, j1 = int(round((c[1] - s[1] / 2) / 0.1)), int(round((c[1] + s[1] / 2) / 0.1))
        assert c[2] - s[2] / 2 == pytest.approx(0.0)
        covered[i0:i1, j0:j1] = np.maximum(covered[i0:i1, j0:j1], s[2])
    np.testing.assert_allclose(covered, H)


def test_bad_parameters_name_the_field():
    """A non-positive cell or a fractional dilation is refused by name."""
    with pytest.raises(ParameterError, match="cell"):
        PerceptionParams(cell=0.0)
    with pytest.raises(ParameterError, match="dilation"):
        PerceptionParams(dilation=1.5)
    with pytest.raises(ParameterError, match="speed"):
        PerceptionParams(speed=-1.0)


def test_dilation_is_the_neighbourhood_max_by_brute_force():
    """The compiled dilation equals the max over each cell's (2r+1) x
    (2r+1) neighbourhood taken cell by cell, for height maps (dilated
    around their occupied block only), maps with negative values and an
    empty map, at r = 0..7."""
    from drake_cfvol.online.obstacle_map import dilate

    rng = np.random.default_rng(5)
    for shape in ((1, 1), (7, 3), (30, 41)):
        maps = [
            rng.random(shape) * (rng.random(shape) < 0.1),
            rng.normal(size=shape),
            np.zeros(shape),
        ]
        for H in maps:
            for r in range(8):
                want = np.array(
                    [
                        [H[max(i - r, 0) : i + r + 1, max(j - r, 0) : j + r + 1].max() for j in range(shape[1])]
                        for i in range(shape[0])
                    ]
                )
                assert np.array_equal(dilate(H, r), want)


def test_an_image_taken_by_masks_equals_its_gathered_points():
    """integrate_sources (each kind of point as the image's pixels and a
    mask, nothing gathered) makes the same map as integrate on the gathered
    points, spreading under the robot included."""
    rng = np.random.default_rng(9)
    grid = MapGrid.covering((-1.0, -1.0), (2.0, 1.5), 0.05)
    params = PerceptionParams(cell=0.05, dilation=2, speed=0.5, spread_time=1.0)
    m = ObstacleMap.empty(grid)
    for t in range(1, 30):
        X = rng.uniform(-1.2, 1.2, (3, 400))
        X[2] = rng.uniform(-0.1, 1.0, 400)
        X[:, rng.random(400) < 0.05] = np.nan
        kind = rng.integers(0, 3, 400)  # 0 new, 1 seen, 2 robot
        kind[: 40 * (t % 3)] = 1  # some images see much of the cell
        floor = rng.uniform(-1.2, 1.2, (3, 400))
        none = rng.random(400) < 0.3
        gathered = m.integrate(
            X[:, kind == 0],
            np.concatenate([X[:, kind == 1], floor[:, none]], axis=1),
            0.1 * t,
            params,
            np.concatenate([X[:, kind == 2], floor[:, kind == 2]], axis=1),
        )
        masked = m.integrate_sources(
            [(X, kind == 0)], [(X, kind == 1), (floor, none)], 0.1 * t, params, [(X, kind == 2), (floor, kind == 2)]
        )
        for field in ("heights", "observed", "seen_at"):
            assert np.array_equal(getattr(masked, field), getattr(gathered, field))
        m = masked
    assert m.occupied > 0
