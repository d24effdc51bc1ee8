"""Joint bounding (SPEC 6-7) against geometry worked out by hand."""

import numpy as np
import pytest
from conftest import write_arm_cell

import drake_cfvol as cf
from drake_cfvol.algorithm.pipeline import estimate_bounds
from drake_cfvol.algorithm.table import BoundsTable, box_at

L, W, Z = 1.0, 0.05, 0.5  # link length, half width, height of the arm


def arm(tmp_path, obstacles, lower=-3.0, upper=3.0):
    path = write_arm_cell(
        tmp_path, links=[{"length": L, "half_width": W, "lower": lower, "upper": upper}], obstacles=obstacles, base_z=Z
    )
    return cf.load_workcell(path)


def still_path(wc, theta):
    return cf.NominalPath(np.array([[theta], [theta]]), wc.joint_names, wc.name)


@pytest.mark.parametrize("clearance", [0.0, 0.02, 0.05])
def test_wall_at_known_distance(tmp_path, clearance):
    """A wall at y = d stops the link when its far corner comes within the
    clearance c of it: L sin(t) + W cos(t) = d - c; the bound is within
    delta below that angle."""
    d = 0.6
    wc = arm(tmp_path, {"wall": ((1.8, 0.2, 1.0), (1.1, d + 0.1, Z))})
    table = estimate_bounds(wc, still_path(wc, 0.0), h_max=0.0, clearance=clearance)
    theta = np.arcsin((d - clearance) / np.hypot(L, W)) - np.arctan2(W, L)
    delta = table.params["delta"]
    assert theta - delta <= table.upper[0, 0] <= theta
    assert table.lower[0, 0] == pytest.approx(-3.0)  # nothing on the other side
    # Drake agrees (its collision padding is the margin): free just below
    # the bound, "colliding" just past theta.
    checker = wc.padded_checker(clearance)
    assert checker.CheckConfigCollisionFree([table.upper[0, 0]])
    assert not checker.CheckConfigCollisionFree([theta + 1e-3])


def _paper_bisection(wc, q0, limit, delta):
    """Algorithm 2 of the paper: tests only end values."""
    if wc.is_free([limit]):
        return limit
    free, coll = q0, limit
    while abs(coll - free) >= delta:
        mid = (free + coll) / 2
        if wc.is_free([mid]):
            free = mid
        else:
            coll = mid
    return free


def test_no_jump_over(tmp_path):
    """A post between the nominal and a free joint limit: the paper's
    end-value bisection jumps over it, ours stops before it."""
    wc = arm(tmp_path, {"post": ((0.1, 0.1, 1.0), (0.0, 0.7, Z))})
    assert wc.is_free([3.0])  # the limit itself is free
    assert _paper_bisection(wc, 0.0, 3.0, 0.01) == 3.0
    table = estimate_bounds(wc, still_path(wc, 0.0), h_max=0.0, clearance=0.0)  # the paper's checks: no padding
    # The link's upper edge (offset W) meets the post's corner (0.05, 0.65).
    r = np.hypot(0.05, 0.65)
    contact = np.arctan2(0.65, 0.05) - np.arcsin(W / r)
    assert contact - 0.01 <= table.upper[0, 0] <= contact
    assert all(wc.is_free([t]) for t in np.linspace(0.0, table.upper[0, 0], 400))


def test_limits_when_nothing_around(tmp_path):
    """No obstacle near and no volume: the bounds are the joint limits."""
    wc = arm(tmp_path, {}, lower=-2.5, upper=2.0)
    table = estimate_bounds(wc, still_path(wc, 0.3), h_max=0.0)
    assert table.lower[0, 0] == -2.5 and table.upper[0, 0] == 2.0


def test_joint_without_limits_uses_pi(tmp_path):
    """A continuous joint is bounded at nominal +- pi (SPEC 2)."""
    wc = arm(tmp_path, {}, lower=None, upper=None)
    table = estimate_bounds(wc, still_path(wc, 0.3), h_max=0.0)
    assert table.lower[0, 0] == pytest.approx(0.3 - np.pi)
    assert table.upper[0, 0] == pytest.approx(0.3 + np.pi)


def test_volume_stops_the_link(tmp_path):
    """With the volume on, the bound is no wider than without it, and the
    swept link stays free of the real scene."""
    wc = arm(tmp_path, {"post": ((0.3, 0.3, 1.5), (-1.5, 1.5, 0.75))})
    path = cf.NominalPath(np.linspace([0.0], [0.6], 13), wc.joint_names, wc.name)
    with_v = estimate_bounds(wc, path, resolution=2000)
    without = estimate_bounds(wc, path, resolution=2000, h_max=0.0)
    assert np.all(with_v.upper <= without.upper + 1e-12) and np.all(with_v.lower >= without.lower - 1e-12)
    assert np.any(with_v.widths() < without.widths() - 0.1)


def test_bounds_contain_nominal_on_a_real_path(automotive):
    """lower <= nominal <= upper at every waypoint of a built-in path."""
    path = cf.plan_nominal_path(automotive, *automotive.configuration("path3"), seed=2)
    table = estimate_bounds(automotive, path, resolution=500)
    assert np.all(table.lower <= table.nominal) and np.all(table.nominal <= table.upper)
    assert np.all(table.lower >= table.limit_lower - 1e-12) and np.all(table.upper <= table.limit_upper + 1e-12)
    assert table.timing_ms["total"] >= table.timing_ms["bounding"] > 0


def test_interpolation_between_waypoints():
    """SPEC 7: integer s gives the waypoint; fractional s the intersection of
    the neighbours, widened to hold the interpolated nominal."""
    lower = np.array([[-1.0, 0.0], [-0.5, 0.2]])
    upper = np.array([[1.0, 1.0], [2.0, 0.4]])
    nominal = np.array([[0.0, 0.5], [0.0, 0.3]])
    lo, hi, nom = box_at(lower, upper, nominal, 0.0)
    assert lo.tolist() == [-1.0, 0.0] and hi.tolist() == [1.0, 1.0]
    lo, hi, nom = box_at(lower, upper, nominal, 0.5)
    np.testing.assert_allclose(nom, [0.0, 0.4])
    np.testing.assert_allclose(lo, [-0.5, 0.2])
    # min(1.0, 0.4) = 0.4 already holds the nominal 0.4.
    np.testing.assert_allclose(hi, [1.0, 0.4])
    lo, hi, nom = box_at(lower, upper, nominal, 1.0)
    assert lo.tolist() == [-0.5, 0.2]
    with pytest.raises(cf.ParameterError, match="outside"):
        box_at(lower, upper, nominal, 1.5)


def test_interpolation_widens_to_nominal():
    """Where the intersection excludes the interpolated nominal, it is widened."""
    lower = np.array([[0.0], [0.9]])
    upper = np.array([[0.1], [1.0]])
    nominal = np.array([[0.0], [1.0]])
    lo, hi, nom = box_at(lower, upper, nominal, 0.5)
    assert lo[0] <= nom[0] <= hi[0] and nom[0] == 0.5


def test_wrong_dof_path(automotive, aerospace, planned):
    """A path of the wrong DoF is refused with the expected size."""
    path = planned("automotive")
    with pytest.raises(cf.DimensionError, match="expected 7"):
        estimate_bounds(aerospace, path)


def test_save_load(tmp_path):
    """A bounds table saves to .npz and .json and loads back equal."""
    wc = arm(tmp_path, {"post": ((0.1, 0.1, 1.0), (0.0, 0.7, Z))})
    table = estimate_bounds(wc, still_path(wc, 0.0), h_max=0.0)
    for suffix in (".npz", ".json"):
        f = table.save(tmp_path / f"b{suffix}")
        back = BoundsTable.load(f)
        np.testing.assert_array_equal(back.upper, table.upper)
        assert back.params == table.params and back.joint_names == table.joint_names
        with pytest.raises(FileExistsError):
            table.save(f)


def test_box_at_sees_stretch_bounds_changed_in_place():
    """The rate rule's envelopes are reused between lookups of the same
    bounds, compared by value: tightening a stretch bound in place changes
    the next lookup exactly as a fresh table would."""
    from drake_cfvol.algorithm.table import box_at

    g, k = 6, 2
    nominal = np.zeros((g, k))
    st_lo, st_hi = np.full((g - 1, k), -1.0), np.full((g - 1, k), 1.0)
    rate = np.array([0.1, 0.1])
    lower, upper = np.full((g, k), -1.0), np.full((g, k), 1.0)
    before = box_at(lower, upper, nominal, 2.5, stretch_lower=st_lo, stretch_upper=st_hi, rate=rate)
    assert before[1][0] == 1.0
    st_hi[3, 0] = 0.5  # stretch [3, 4]: s = 2.5 lies 0.5 before it, so the cap is 0.5 + 0.1 * 0.5
    after = box_at(lower, upper, nominal, 2.5, stretch_lower=st_lo, stretch_upper=st_hi, rate=rate)
    fresh = box_at(lower, upper, nominal, 2.5, stretch_lower=st_lo.copy(), stretch_upper=st_hi.copy(), rate=rate)
    assert after[1][0] == pytest.approx(0.55) and after[1][0] == fresh[1][0]


@pytest.mark.parametrize("interpolation", ["stretch", "linear"])
def test_box_at_one_s_equals_many_bit_for_bit(interpolation):
    """The box at one s (the bounds source's lookup, its own code) is the
    box the vectorised rule gives at that s, bit for bit: random bounds with
    a rate limit, random s and every waypoint; and the waypoint box it
    returns is a copy, not a view of the table."""
    rng = np.random.default_rng(4)
    g, k = 7, 3
    nominal = rng.normal(size=(g, k))
    lower = nominal - rng.uniform(0.1, 1.0, (g, k))
    upper = nominal + rng.uniform(0.1, 1.0, (g, k))
    kw = dict(
        stretch_lower=np.maximum(lower[:-1], lower[1:]) - 0.05,
        stretch_upper=np.minimum(upper[:-1], upper[1:]) + 0.05,
        rate=np.array([0.2, np.inf, 0.5]),
        interpolation=interpolation,
    )
    S = np.concatenate([rng.uniform(0, g - 1, 500), np.arange(g, dtype=float)])
    many = box_at(lower, upper, nominal, S, **kw)
    for n, x in enumerate(S):
        for a, b in zip(box_at(lower, upper, nominal, float(x), **kw), many):
            assert np.array_equal(a, b[n])
    box_at(lower, upper, nominal, 2.0, **kw)[0][:] = 99.0
    assert not np.any(lower == 99.0)
    with pytest.raises(cf.ParameterError, match="outside"):
        box_at(lower, upper, nominal, float("nan"), **kw)


def test_linear_rule_by_hand():
    """The "linear" rule: each bound linear between its waypoints (a quarter
    of the way from [-1, 1] to [-2, 3] is [-1.25, 1.5]); waypoints exact."""
    lower = np.array([[-1.0], [-2.0]])
    upper = np.array([[1.0], [3.0]])
    nominal = np.zeros((2, 1))
    lo, hi, nom = box_at(lower, upper, nominal, np.array([0.0, 0.25, 1.0]), interpolation="linear")
    np.testing.assert_allclose(lo[:, 0], [-1.0, -1.25, -2.0])
    np.testing.assert_allclose(hi[:, 0], [1.0, 1.5, 3.0])
    with pytest.raises(cf.ParameterError, match="interpolation"):
        box_at(lower, upper, nominal, 0.5, interpolation="cubic")


def test_rate_limited_by_hand():
    """Upper bounds 1, 5, 1 with rate 1 become 1, 2, 1 (min over i' of
    U[i'] + |i - i'|); lower bounds mirror; nothing widens; a joint without
    a rate is left alone."""
    from drake_cfvol.algorithm.table import rate_limited

    upper = np.array([[1.0, 1.0], [5.0, 5.0], [1.0, 1.0]])
    lo, hi = rate_limited(-upper, upper, np.zeros((3, 2)), np.array([1.0, np.inf]))
    np.testing.assert_allclose(hi[:, 0], [1.0, 2.0, 1.0])
    np.testing.assert_allclose(lo[:, 0], [-1.0, -2.0, -1.0])
    np.testing.assert_allclose(hi[:, 1], upper[:, 1])


def test_linear_table_round_trips(tmp_path):
    """A "linear" table saved and loaded keeps its rule; a file of a newer
    format version is refused with a message that says so."""
    import json

    t = BoundsTable(
        np.array([[-1.0], [-2.0]]),
        np.array([[1.0], [3.0]]),
        np.zeros((2, 1)),
        ["j"],
        np.array([-3.0]),
        np.array([3.0]),
        interpolation="linear",
    )
    f = t.save(tmp_path / "b.json")
    assert BoundsTable.load(f).interpolation == "linear"
    np.testing.assert_allclose(BoundsTable.load(f).at(0.5)[1], [2.0])
    d = json.loads(f.read_text())
    d["version"] = 99
    f.write_text(json.dumps(d))
    with pytest.raises(cf.RecordFormatError, match="version 99"):
        BoundsTable.load(f)


def test_within_stretches_by_hand():
    """Nominal from 2 to 0 over one stretch whose proven upper bound is 1:
    the waypoint bounds 2 (held at the nominal) and 1.5 would put the line
    at 1.75 where the nominal crosses 1 (t = 0.5), above what is proven; the
    far end is lowered to the nominal (0), so the line is the nominal's own
    and lies within max(1, nom(s)) everywhere. A stretch that needs nothing
    is left as it is."""
    from drake_cfvol.algorithm.table import within_stretches

    nominal = np.array([[2.0], [0.0]])
    lo, hi = within_stretches(
        np.array([[-1.0], [-1.0]]), np.array([[2.0], [1.5]]), nominal, np.array([[-1.0]]), np.array([[1.0]])
    )
    np.testing.assert_allclose(hi[:, 0], [2.0, 0.0])
    np.testing.assert_allclose(lo[:, 0], [-1.0, -1.0])
    t = np.linspace(0, 1, 11)
    assert np.all((1 - t) * hi[0, 0] + t * hi[1, 0] <= np.maximum(1.0, 2.0 - 2.0 * t) + 1e-12)
    lo2, hi2 = within_stretches(
        np.array([[-1.0], [-1.0]]), np.array([[0.5], [0.8]]), np.zeros((2, 1)), np.array([[-1.0]]), np.array([[1.0]])
    )
    np.testing.assert_array_equal(hi2[:, 0], [0.5, 0.8])
