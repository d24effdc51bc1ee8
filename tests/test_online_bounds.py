"""The online bounds estimator (drake_cfvol.systems.online_bounds) and the
bounds source's ``bounds`` input."""

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantValueSource, ConstantVectorSource

from drake_cfvol.online import MapGrid, ObstacleMap, OnlineBounds
from drake_cfvol.systems import JointBoundsSource, OnlineBoundsEstimator


def _box_map(grid, wc, path):
    H = np.zeros(grid.shape)
    c = np.asarray(wc.tool_position(path.waypoints[path.g // 2]))[:2] + (0.6, 0.0)
    i, j, _ = grid.cells_of(np.array([c[0] - 0.3, c[0] + 0.3]), np.array([c[1] - 0.3, c[1] + 0.3]))
    H[i[0] : i[1] + 1, j[0] : j[1] + 1] = 1.2
    return ObstacleMap(grid, H, 0.0)


def test_estimator_publishes_one_period_later_and_the_source_follows(bounded, planned, automotive):
    """Bounds computed from a map at an update are in force from the next
    update on; JointBoundsSource with its ``bounds`` input connected reads
    them (the base table's box before), at every path index."""
    wc, path, table = automotive, planned("automotive"), bounded("automotive")
    grid = MapGrid.covering(np.asarray(wc.height_map_origin) - 1, np.asarray(wc.height_map_size) + 2, 0.05)
    builder = DiagramBuilder()
    est = builder.AddSystem(OnlineBoundsEstimator(OnlineBounds(wc, table), grid, period=0.1))
    m = builder.AddSystem(ConstantValueSource(AbstractValue.Make(_box_map(grid, wc, path))))
    s = builder.AddSystem(ConstantVectorSource([path.g / 2]))
    src = builder.AddSystem(JointBoundsSource(table))
    builder.Connect(m.get_output_port(), est.obstacle_map_input)
    builder.Connect(s.get_output_port(), est.path_index_input)
    builder.Connect(s.get_output_port(), src.path_index_input)
    builder.Connect(est.bounds_output, src.bounds_input)
    diagram = builder.Build()
    sim = Simulator(diagram)
    ctx = sim.get_mutable_context()
    first = est.initial_bounds
    sim.AdvanceTo(0.05)  # after the first update: computed, not yet in force
    e_ctx = est.GetMyContextFromRoot(ctx)
    assert est.bounds_version_output.Eval(e_ctx)[0] == 0
    sim.AdvanceTo(0.15)  # the second update published it
    live = est.bounds_output.Eval(e_ctx)
    assert live.version == 1 and est.bounds_version_output.Eval(e_ctx)[0] == 1
    lo, hi = src.lower_output.Eval(src.GetMyContextFromRoot(ctx)), src.upper_output.Eval(src.GetMyContextFromRoot(ctx))
    np.testing.assert_array_equal(lo, live.at(path.g / 2)[0])
    np.testing.assert_array_equal(hi, live.at(path.g / 2)[1])
    narrower = [
        np.any(live.at(v)[1] - live.at(v)[0] < first.at(v)[1] - first.at(v)[0] - 1e-12)
        for v in np.arange(path.g - 1) + 0.5
    ]
    assert any(narrower)
    for v in np.linspace(0, path.g - 1, 37):
        lo_b, hi_b, nom = table.at(v)
        lo_l, hi_l, nom_l = live.at(v)
        np.testing.assert_array_equal(nom_l, nom)
        assert np.all(lo_l >= np.minimum(lo_b, nom) - 1e-12) and np.all(hi_l <= np.maximum(hi_b, nom) + 1e-12)
    log = est.log(e_ctx)
    assert log.shape == (2, len(est.LOG_FIELDS)) and log[0, -1] == 1.0 and log[1, -1] == 0.0
