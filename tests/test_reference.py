"""The reference backend (SceneGraph boxes + Drake's checker) against the
fast one on the same volume."""

import numpy as np
import pytest
from conftest import write_arm_cell

import drake_cfvol as cf
from drake_cfvol.algorithm.reference import MAX_REFERENCE_BOXES, ReferenceScene


def test_fast_bounds_inside_reference_bounds(tmp_path):
    """Fast bounds are conservative: never wider than Drake's (beyond the
    sampling tolerance delta), and close to them (a slow nominal, so that
    the rate limit does not narrow the fast bounds)."""
    wc = cf.load_workcell(
        write_arm_cell(
            tmp_path,
            links=[
                {"length": 1.0, "half_width": 0.05, "lower": -3.0, "upper": 3.0},
                {"length": 0.8, "half_width": 0.05, "lower": -2.5, "upper": 2.5},
            ],
            obstacles={"post": ((0.3, 0.3, 1.5), (-1.2, 1.2, 0.75)), "crate": ((0.6, 0.4, 0.6), (1.4, -1.0, 0.3))},
            base_z=0.5,
        )
    )
    path = cf.NominalPath(np.linspace([0.0, 0.3], [0.8, -0.4], 9), wc.joint_names, wc.name)
    fast = cf.estimate_bounds(wc, path, resolution=400, waypoint_time=10.0)
    ref = cf.estimate_bounds(wc, path, resolution=400, backend="drake")
    delta = fast.params["delta"]
    assert np.all(fast.upper <= ref.upper + delta + 1e-9)
    assert np.all(fast.lower >= ref.lower - delta - 1e-9)
    assert np.median(np.abs(fast.widths() - ref.widths())) < 0.1
    assert ref.info["drake_checks"] > 0


def test_reference_refuses_huge_volumes(automotive, planned):
    """Beyond its practical size the reference says so instead of stalling."""
    path = planned("automotive")
    table = cf.estimate_bounds(automotive, path, resolution=20000)
    assert table.volume.volume.n_boxes > MAX_REFERENCE_BOXES
    with pytest.raises(cf.ParameterError, match="backend='fast'"):
        ReferenceScene(automotive, table.volume.volume)
