"""Height map geometry, eq. 1 by hand, the range-max table, the column test."""

import numpy as np
import pytest

import drake_cfvol as cf
from drake_cfvol import kernel as K
from drake_cfvol.algorithm.heightmap import HeightMap, height_function
from drake_cfvol.scene.params import VolumeParams


@pytest.mark.parametrize(
    "x,y,R,side,m,n",
    [
        (5.6, 5.6, 100, 0.56, 10, 10),
        (5.6, 5.6, 1000, np.sqrt(5.6 * 5.6 / 1000), 31, 31),
        (11.8, 6.0, 100, np.sqrt(11.8 * 6.0 / 100), 14, 7),
        (4.0, 1.0, 4, 1.0, 4, 1),
    ],
)
def test_side_rows_columns(x, y, R, side, m, n):
    """side = sqrt(x y / R), m = floor(x / side), n = floor(y / side), m n <= R."""
    hm = HeightMap((0.0, 0.0), x, y, R)
    assert hm.side == pytest.approx(side)
    assert (hm.m, hm.n) == (m, n)
    assert hm.m * hm.n <= R
    X, Y = hm.centres()
    assert X[0, 0] == pytest.approx(side / 2) and Y[0, -1] == pytest.approx((n - 0.5) * side)


def test_height_function_by_hand():
    """Each Delta term, the clamping and the activation, worked by hand."""
    p = VolumeParams()  # d_t 0.35..1.5, d_g 0.1..2.0, d_ng_ub 0.5, h_max 1.5
    # Delta_t = (0.925 - 0.35) / 1.15 = 0.5; Delta_g = (1.05 - 0.1) / 1.9 = 0.5;
    # Delta_ng = (0.5 - 0.25) / 0.5 = 0.5 -> h = 1.5 * 1.5 = 2.25.
    assert height_function(0.925, 1.05, 0.25, True, p) == pytest.approx(2.25)
    # Clamping: far from everything -> 1 + 1 + 0.
    assert height_function(10.0, 10.0, 10.0, True, p) == pytest.approx(3.0)
    # On a no-goal footprint and at the goal's floor: 1 + 0 + 1.
    assert height_function(5.0, 0.0, 0.0, True, p) == pytest.approx(3.0)
    # Activation: nearer the trail than d_t,LB, or out of reach -> 0.
    assert height_function(0.3499, 10.0, 0.0, True, p) == 0.0
    assert height_function(1.0, 10.0, 0.0, False, p) == 0.0
    # Empty sets (inf): Delta_t = Delta_g = 1, Delta_ng = 0.
    assert height_function(np.inf, np.inf, np.inf, True, p) == pytest.approx(3.0)
    # Exponents: alpha_t = 2 squares Delta_t = 0.5.
    p2 = p.replace(alpha_t=2.0)
    assert height_function(0.925, 0.1, 0.5, True, p2) == pytest.approx(1.5 * 0.25)


def test_height_function_vectorised():
    """Arrays in, arrays out, same values as scalar calls."""
    p = VolumeParams()
    d = np.linspace(0, 3, 50)
    h = height_function(d, d[::-1], d, d > 0.5, p)
    assert h.shape == (50,)
    for i in (0, 13, 49):
        assert h[i] == pytest.approx(height_function(d[i], d[::-1][i], d[i], d[i] > 0.5, p))


def test_range_max_matches_brute_force():
    """The kernel's range-max table equals numpy's max over the clipped block."""
    rng = np.random.default_rng(0)
    v = rng.random((23, 41))
    t = K.range_max_table(v)
    for _ in range(500):
        i0, i1 = sorted(rng.integers(-3, 26, 2))
        j0, j1 = sorted(rng.integers(-3, 44, 2))
        a, b, c, d = max(i0, 0), min(i1, 22), max(j0, 0), min(j1, 40)
        ref = v[a : b + 1, c : d + 1].max() if a <= b and c <= d else -np.inf
        assert K.range_max(t, int(i0), int(i1), int(j0), int(j1)) == ref


def test_distance_map_is_exact():
    """The kernel's distance transform equals scipy's exact one."""
    from scipy.ndimage import distance_transform_edt

    rng = np.random.default_rng(1)
    mask = rng.random((120, 77)) < 0.01
    np.testing.assert_allclose(K.distance_map(mask), distance_transform_edt(~mask), atol=1e-12)
    assert np.isinf(K.distance_map(np.zeros((5, 6), bool))).all()


def test_polygon_fill_marks_pixel_centres_inside():
    """An axis-aligned rectangle marks exactly the pixels whose centres lie
    inside it (plus the pixels under its corners)."""
    mask = np.zeros((100, 100), bool)
    K.fill_convex_polygon(mask, np.array([[1.0, 1.0], [3.0, 1.0], [3.0, 2.0], [1.0, 2.0]]), 0.0, 0.0, 0.05)
    xs = (np.arange(100) + 0.5) * 0.05
    X, Y = np.meshgrid(xs, xs, indexing="ij")
    inside = (X >= 1) & (X <= 3) & (Y >= 1) & (Y <= 2)
    assert not (inside & ~mask).any() and (mask & ~inside).sum() <= 4


def test_bad_height_map():
    """Non-positive sides or R raise clear errors."""
    with pytest.raises(cf.ParameterError, match="sides"):
        HeightMap((0, 0), 0.0, 1.0, 10)
    with pytest.raises(cf.ParameterError, match="positive"):
        HeightMap((0, 0), 1.0, 1.0, 0)


def test_huge_resolution_is_refused_up_front():
    """A resolution whose tables would not fit in memory is refused when the
    height map is made, with the estimate; the paper's largest R is fine."""
    assert HeightMap((0, 0), 5.6, 5.6, 20000).memory_bytes < 50e6
    with pytest.raises(cf.ParameterError, match=r"R = 1000000000 would need about \d+\.\d GB"):
        HeightMap((0, 0), 5.6, 5.6, 10**9)


def test_cli_refuses_huge_resolution_before_planning(capsys):
    """cfvol bounds with an absurd R stops with one error line, exit code 2."""
    from drake_cfvol.apps.cli import main

    assert main(["bounds", "automotive", "-R", "1000000000", "--json"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("cfvol: error: R = 1000000000 would need")


def _volume(heights, side=0.1, origin=(1.0, -2.0)):
    from drake_cfvol.algorithm.heightmap import Volume

    m, n = heights.shape
    hm = HeightMap(np.array([origin[0], origin[1]]), m * side, n * side, m * n)
    assert hm.shape == (m, n) and hm.side == pytest.approx(side)
    return Volume(hm, heights, heights.copy())


def _contained(centres, sizes, vol):
    """Each column's eight corners lie in one merged box (a box holds its
    corners' hull)."""
    cc, cs = vol.boxes()
    lo, hi = centres - sizes / 2, centres + sizes / 2
    for c, s in zip(cc, cs):
        a, b = c - s / 2, c + s / 2
        inside = np.all((lo <= a + 1e-9) & (hi >= b - 1e-9), axis=1)
        if not inside.any():
            return False
    return True


def test_merged_boxes_exact_when_they_fit():
    """Equal neighbours merge, nothing is added: two plateaus by hand."""
    H = np.zeros((4, 3))
    H[0:2, 0:3] = 0.5  # one 2 x 3 plateau
    H[3, 1] = 0.2  # a single column
    c, s, info = _volume(H).merged_boxes(10)
    assert len(c) == 2 and info["added_volume_m3"] == pytest.approx(0.0)
    order = np.argsort(s[:, 2])
    np.testing.assert_allclose(s[order], [[0.1, 0.1, 0.2], [0.2, 0.3, 0.5]])
    np.testing.assert_allclose(c[order][1], [1.0 + 0.1, -2.0 + 0.15, 0.25])


def test_merged_boxes_fit_and_contain_their_columns():
    """A rough random height map merged into few boxes: the count fits,
    every column lies inside a box, and the volume only grows."""
    rng = np.random.default_rng(0)
    H = np.where(rng.random((40, 30)) < 0.7, rng.uniform(0.1, 1.0, (40, 30)), 0.0)
    vol = _volume(H)
    for limit in (1000, 200, 40):
        c, s, info = vol.merged_boxes(limit)
        assert len(c) <= limit and _contained(c, s, vol)
        assert np.prod(s, axis=1).sum() == pytest.approx(info["column_volume_m3"] + info["added_volume_m3"])
        assert info["added_volume_m3"] >= -1e-9
    with pytest.raises(ValueError, match="max_boxes"):
        vol.merged_boxes(0)
