"""Certified bounds (sampled safety certificate for the whole box)."""

import numpy as np
import pytest

import drake_cfvol as cf
from drake_cfvol.certify import Certify, certification_rng
from conftest import write_arm_cell


@pytest.fixture(scope="module")
def corner(tmp_path_factory):
    """A 2-link planar arm (1.0 m + 0.8 m) at (0, 0) rad with a 0.3 m post at
    (1.15, 1.0) that neither joint reaches alone but both together do.

    Joint 1 alone (up to 0.4 rad) keeps the straight arm >= 0.25 m below the
    post (x 1.0-1.3, y 0.85-1.15); joint 2 alone sweeps 0.802 m around
    (1, 0), and the post's nearest corner is 0.85 m away. At the corner (0.4, 0.8) link 2 runs from
    (0.921, 0.389) to (1.211, 1.135) and crosses y = 1.0 at x = 1.158,
    inside the post."""
    folder = tmp_path_factory.mktemp("corner")
    wc = cf.load_workcell(write_arm_cell(
        folder, links=[{"length": 1.0, "half_width": 0.05, "lower": -0.4, "upper": 0.4},
                       {"length": 0.8, "half_width": 0.05, "lower": -0.8, "upper": 0.8}],
        obstacles={"post": ((0.3, 0.3, 1.0), (1.15, 1.0, 0.5))}, base_z=0.5))
    path = cf.NominalPath(np.zeros((3, 2)), wc.joint_names, wc.name)
    return wc, path


def test_corner_is_excluded(corner):
    """The uncertified box's corner collides (two joints together, though each
    alone is free to its bound); the certified box excludes that corner, and an
    independent CF check of it finds at most ~epsilon colliding."""
    wc, path = corner
    plain = cf.estimate_bounds(wc, path, h_max=0.0)
    cert = cf.estimate_bounds(wc, path, h_max=0.0, certify=Certify(epsilon=1e-3, confidence=0.99))
    up, upc = plain.upper[1], cert.upper[1]
    np.testing.assert_allclose(up, [0.4, 0.8])       # each joint alone reaches its limit
    assert not wc.is_free(up)                        # the corner collides
    assert not (np.all(up <= upc) and np.all(up >= cert.lower[1]))  # ... and is excluded
    before = cf.confidence_factor(wc, plain, windows=2, samples=10000, seed=3)
    after = cf.confidence_factor(wc, cert, windows=2, samples=10000, seed=3)
    assert before.colliding > 200                    # the plain box collides often
    assert after.colliding <= 40                     # <= 0.2 %: the certificate (0.1 %) with slack
    rep = cert.info["certificate"]
    assert rep["shrinks"] >= 1 and rep["n_samples"] == 4606
    assert rep["freedom_after"] < rep["freedom_before"]


def test_certified_inside_uncertified(corner):
    """Certification only shrinks, and the nominal stays inside."""
    wc, path = corner
    cert = cf.estimate_bounds(wc, path, h_max=0.0, certify=Certify(epsilon=1e-2, confidence=0.9))
    lo0, hi0 = cert.info["uncertified_lower"], cert.info["uncertified_upper"]
    assert np.all(cert.lower >= lo0) and np.all(cert.upper <= hi0)
    assert np.all(cert.lower <= cert.nominal) and np.all(cert.nominal <= cert.upper)


def test_n_samples_formula():
    """N = ceil(ln(1 / (1 - C)) / epsilon): 4606 for 1e-3 at 99 %."""
    assert Certify(epsilon=1e-3, confidence=0.99).n_samples == 4606
    assert Certify(epsilon=0.05, confidence=0.95).n_samples == 60


def test_seed_stream_differs_from_cf():
    """Certification draws differ from CF's draws of the same seed."""
    assert certification_rng(0).random() != np.random.default_rng(0).random()


@pytest.mark.parametrize("kwargs", [{"epsilon": 0.0}, {"epsilon": 1.0}, {"confidence": 1.0},
                                    {"confidence": -0.1}, {"epsilon": 2}])
def test_invalid_certificate(kwargs):
    """epsilon or confidence outside (0, 1) raise a clear error."""
    with pytest.raises(cf.ParameterError, match="must lie in"):
        Certify(**kwargs)
