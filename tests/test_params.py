"""VolumeParams: defaults from the paper, overrides, validation."""

import pytest

import drake_cfvol as cf
from drake_cfvol.scene.params import VolumeParams


def test_defaults_are_the_papers():
    """Defaults match section IV-A of the paper."""
    p = VolumeParams()
    assert (p.alpha_t, p.alpha_g, p.alpha_ng) == (1, 1, 1)
    assert (p.d_t_lb, p.d_t_ub, p.d_g_lb, p.d_g_ub, p.d_ng_ub, p.h_max) == (0.35, 1.5, 0.10, 2.0, 0.5, 1.5)


def test_workcell_reach_and_overrides(automotive, aerospace):
    """The cell's reach fills in; keyword overrides win."""
    assert VolumeParams.for_workcell(automotive).reach == 2.8
    assert VolumeParams.for_workcell(aerospace).reach == 3.0
    assert VolumeParams.for_workcell(automotive, reach=2.0, resolution=500).resolution == 500


@pytest.mark.parametrize(
    "kwargs,match",
    [
        ({"resolution": 0}, "resolution"),
        ({"resolution": -5}, "resolution"),
        ({"d_t_lb": 1.5, "d_t_ub": 1.5}, "d_t_lb"),
        ({"d_g_lb": 3.0}, "d_g_lb"),
        ({"h_max": -0.1}, "h_max"),
        ({"delta": 0.0}, "delta"),
        ({"delta_prismatic": -1e-3}, "delta_prismatic"),
        ({"alpha_t": 0}, "alpha_t"),
        ({"d_ng_ub": 0}, "d_ng_ub"),
        ({"h_max": float("nan")}, "h_max"),
    ],
)
def test_invalid_parameters(kwargs, match):
    """Invalid parameters raise a ParameterError naming the field."""
    with pytest.raises(cf.ParameterError, match=match):
        VolumeParams(**kwargs)


def test_unknown_parameter(automotive):
    """A misspelt parameter is named, with the known ones listed."""
    with pytest.raises(cf.ParameterError, match="h_maxx.*h_max"):
        VolumeParams.for_workcell(automotive, h_maxx=1.0)
