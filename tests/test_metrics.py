"""Confidence Factor and freedom (SPEC 8) on boxes of known collision share."""

import numpy as np
import pytest
from conftest import write_arm_cell

import drake_cfvol as cf
from drake_cfvol.algorithm.table import BoundsTable

L, W, Z, D = 1.0, 0.05, 0.5, 0.6


@pytest.fixture(scope="module")
def wall_arm(tmp_path_factory):
    folder = tmp_path_factory.mktemp("wall")
    return cf.load_workcell(
        write_arm_cell(
            folder,
            links=[{"length": L, "half_width": W, "lower": -3.0, "upper": 3.0}],
            obstacles={"wall": ((1.8, 0.2, 1.0), (1.1, D + 0.1, Z))},
            base_z=Z,
        )
    )


def _table(lo, hi, nominal=0.0):
    g = 3
    return BoundsTable(
        np.full((g, 1), lo),
        np.full((g, 1), hi),
        np.full((g, 1), nominal),
        ["joint1"],
        np.array([-3.0]),
        np.array([3.0]),
    )


def test_cf_free_box(wall_arm):
    """A box known free (below the contact angle) gives CF = 100 %."""
    res = cf.confidence_factor(wall_arm, _table(-0.5, 0.5), windows=5, samples=400, seed=1)
    assert res.percent == 100.0 and res.colliding == 0 and res.samples == 2000


def test_cf_half_box(wall_arm):
    """A box centred on the contact angle is half in collision: CF ~ 50 %."""
    theta = np.arcsin(D / np.hypot(L, W)) - np.arctan2(W, L)
    a = 0.3
    res = cf.confidence_factor(wall_arm, _table(theta - a, theta + a, theta - a), windows=10, samples=1000, seed=2)
    # Binomial standard error at n = 10000: 0.5 %; allow 4 sigma.
    assert res.percent == pytest.approx(50.0, abs=2.0)


def test_cf_seeded(wall_arm):
    """The same seed gives the same CF; windows are reported."""
    t = _table(0.2, 0.9)
    a = cf.confidence_factor(wall_arm, t, windows=4, samples=300, seed=5)
    b = cf.confidence_factor(wall_arm, t, windows=4, samples=300, seed=5)
    assert a.percent == b.percent and len(a.per_window) == 4


def test_freedom_by_hand():
    """Freedom: geometric mean of width / range; median width in degrees."""
    t = BoundsTable(
        np.array([[-1.0, 0.0], [-0.5, 0.0]]),
        np.array([[1.0, 0.5], [0.5, 0.5]]),
        np.zeros((2, 2)),
        ["a", "b"],
        np.array([-2.0, -1.0]),
        np.array([2.0, 1.0]),
    )
    fr = cf.freedom(t, [True, False])
    # waypoint 0: sqrt(0.5 * 0.25); waypoint 1: sqrt(0.25 * 0.25)
    assert fr.mean == pytest.approx((np.sqrt(0.125) + 0.25) / 2)
    np.testing.assert_allclose(fr.median_width, [np.degrees(1.5), 0.5])
    assert fr.units == ["deg", "m"]


def test_zero_width_box_has_zero_freedom():
    """A box of zero width has CF 100 % trivially, and freedom 0 says so."""
    t = BoundsTable(np.zeros((2, 1)), np.zeros((2, 1)), np.zeros((2, 1)), ["a"], np.array([-1.0]), np.array([1.0]))
    assert cf.freedom(t).mean == 0.0


def test_bad_cf_arguments(wall_arm):
    """Windows or samples below 1 are refused."""
    with pytest.raises(cf.ParameterError, match="windows"):
        cf.confidence_factor(wall_arm, _table(0, 0.1), windows=0)


def test_cf_with_kernel_prefilter_is_drakes_answer(automotive, bounded):
    """The kernel only certifies free samples; Drake judges the rest: the
    result equals Drake judging every sample, window by window, on the same
    draws, and Drake judged only a fraction of them."""
    table = bounded("automotive", "path1", 1000)
    fast = cf.confidence_factor(automotive, table, windows=6, samples=1500, seed=3)
    full = cf.confidence_factor(automotive, table, windows=6, samples=1500, seed=3, prefilter=False)
    assert fast.colliding == full.colliding > 0
    np.testing.assert_array_equal(fast.per_window, full.per_window)
    assert full.drake_checked == full.samples and fast.drake_checked < 0.5 * fast.samples


def test_cf_judged_by_the_kernel_is_drakes_within_its_grazing_calls(automotive, bounded):
    """Judged by the kernel, on the same draws: every sample Drake finds
    colliding counts as colliding, the CF is at most Drake's and within
    0.2 % of it, and the cross-check counts what it says."""
    table = bounded("automotive", "path1", 1000)
    fast = cf.confidence_factor(automotive, table, windows=6, samples=1500, seed=3, judge="kernel", cross_check=4000)
    full = cf.confidence_factor(automotive, table, windows=6, samples=1500, seed=3, prefilter=False)
    assert fast.judge == "kernel" and fast.cross_checked == fast.drake_checked == 4000
    assert full.colliding <= fast.colliding <= full.colliding + 0.002 * full.samples
    assert fast.percent <= full.percent and np.all(fast.per_window <= full.per_window)
    assert 0 <= fast.kernel_only_colliding <= fast.colliding - full.colliding


def test_cf_judged_by_the_kernel_stops_on_a_sample_it_wrongly_calls_free(automotive, bounded, monkeypatch):
    """A kernel that called everything free (a planted defect) is caught by
    Drake's cross-check, not reported as a CF."""
    table = bounded("automotive", "path1", 1000)
    arrays = automotive.scene_arrays()
    monkeypatch.setattr(type(arrays), "may_collide", lambda self, Q, pad=0.0: np.zeros(len(Q), bool))
    with pytest.raises(cf.WorkcellError, match="cross-checked samples free"):
        cf.confidence_factor(automotive, table, windows=6, samples=1500, seed=3, judge="kernel")
    with pytest.raises(cf.ParameterError, match="judge"):
        cf.confidence_factor(automotive, table, judge="oracle")


def test_shown_percent_never_rounds_a_collision_to_100():
    """One colliding sample in 10^7 is shown below 100 %; none is 100 %."""
    from drake_cfvol.algorithm.metrics import shown_percent

    pct = 100.0 * (1 - 1e-7)
    assert shown_percent(pct, 1, 4) == 99.9999 and round(pct, 4) == 100.0
    assert shown_percent(100.0, 0, 4) == 100.0
    assert shown_percent(87.65432, 3, 2) == 87.65


def test_boundary_check_counts_corners_by_hand(wall_arm):
    """The one-joint arm's box [-0.5, 1.2] has two corners per position; the
    upper one lies past the contact angle (about 0.55 rad), the lower is free."""
    from drake_cfvol.algorithm.metrics import boundary_check

    res = boundary_check(wall_arm, _table(-0.5, 1.2), edge_points=8)
    assert res.positions == 5 and res.corners == 10
    assert res.corners_colliding == 5
