"""Moving boxes (drake_cfvol.systems.moving_boxes): piecewise-linear motion,
held at the ends, checked input, and their true obstacle map."""

import numpy as np
import pytest
from pydrake.geometry import SceneGraph

from drake_cfvol.exceptions import ParameterError
from drake_cfvol.online import MapGrid, PerceptionParams
from drake_cfvol.systems import MovingBoxes, MovingObstacle


def test_motion_is_piecewise_linear_and_held_at_the_ends():
    """Halfway between waypoints the centre is halfway; before the first and
    after the last it holds; the first motion is the first waypoint that
    moves."""
    ob = MovingObstacle("cart", [1, 1, 1], [[0.0, 0, 0, 0.5], [1.0, 0, 0, 0.5], [3.0, 2, 4, 0.5]])
    np.testing.assert_allclose(ob.position(2.0), [1, 2, 0.5])
    np.testing.assert_allclose(ob.position(-1.0), [0, 0, 0.5])
    np.testing.assert_allclose(ob.position(9.0), [2, 4, 0.5])
    assert ob.first_motion() == 1.0
    assert MovingObstacle("still", [1, 1, 1], [[0.0, 1, 1, 0.5]]).first_motion() is None


@pytest.mark.parametrize(
    "bad, match",
    [
        (dict(box=[1, 1]), "3 sides"),
        (dict(box=[1, 0, 1]), "3 sides"),
        (dict(waypoints=[]), "at least one"),
        (dict(waypoints=[[0, 1, 2]]), r"\[t, x, y, z\]"),
        (dict(waypoints=[[1, 0, 0, 0], [1, 1, 0, 0]]), "increase"),
    ],
)
def test_bad_obstacles_are_named(bad, match):
    """Wrong sides or waypoints raise a ParameterError naming the obstacle."""
    kw = dict(name="cart", box=[1, 1, 1], waypoints=[[0, 0, 0, 0.5]])
    kw.update(bad)
    with pytest.raises(ParameterError, match=f"cart.*{match}"):
        MovingObstacle(**kw).check()


def test_true_map_covers_the_footprint_at_the_top():
    """The true map at t: the cells under the box at its top (rounded up),
    lent to one neighbour each way, nothing else."""
    grid = MapGrid((0.0, 0.0), 0.1, (30, 30))
    ob = MovingObstacle("cart", [0.4, 0.2, 1.0], [[0.0, 1.0, 1.0, 0.5], [2.0, 2.0, 1.0, 0.5]])
    boxes = MovingBoxes(SceneGraph(), [ob], grid=grid, params=PerceptionParams(cell=0.1, dilation=1))
    m = boxes.obstacle_map(1.0)  # centre (1.5, 1.0): x 1.3..1.7, y 0.9..1.1
    occupied = np.argwhere(m.heights > 0)
    assert occupied.min(axis=0).tolist() == [12, 8] and occupied.max(axis=0).tolist() == [18, 12]
    assert np.all(m.heights[m.heights > 0] == pytest.approx(1.0))
