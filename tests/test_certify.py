"""Certified bounds (sampled safety certificate for the whole box)."""

import numpy as np
import pytest
from conftest import write_arm_cell

import drake_cfvol as cf
from drake_cfvol.algorithm.certificate.certify import Certify, certification_rng


def _corner_cell(folder, mesh_links=False):
    wc = cf.load_workcell(
        write_arm_cell(
            folder,
            links=[
                {"length": 1.0, "half_width": 0.05, "lower": -0.4, "upper": 0.4},
                {"length": 0.8, "half_width": 0.05, "lower": -0.8, "upper": 0.8},
            ],
            obstacles={"post": ((0.3, 0.3, 1.0), (1.15, 1.0, 0.5))},
            base_z=0.5,
            mesh_links=mesh_links,
        )
    )
    return wc, cf.NominalPath(np.zeros((3, 2)), wc.joint_names, wc.name)


@pytest.fixture(scope="module")
def corner_mesh(tmp_path_factory):
    """The corner cell with STL mesh links behind package:// URIs."""
    return _corner_cell(tmp_path_factory.mktemp("corner_mesh"), mesh_links=True)


@pytest.fixture(scope="module")
def corner(tmp_path_factory):
    """A 2-link planar arm (1.0 m + 0.8 m) at (0, 0) rad with a 0.3 m post at
    (1.15, 1.0) that neither joint reaches alone but both together do.

    Joint 1 alone (up to 0.4 rad) keeps the straight arm >= 0.25 m below the
    post (x 1.0-1.3, y 0.85-1.15); joint 2 alone sweeps 0.802 m around
    (1, 0), and the post's nearest corner is 0.85 m away. At the corner (0.4, 0.8) link 2 runs from
    (0.921, 0.389) to (1.211, 1.135) and crosses y = 1.0 at x = 1.158,
    inside the post."""
    return _corner_cell(tmp_path_factory.mktemp("corner"))


def test_corner_is_excluded(corner):
    """The uncertified box's corner collides (two joints together, though each
    alone is free to its bound); the certified box excludes that corner, and an
    independent CF check of it finds at most ~epsilon colliding."""
    wc, path = corner
    plain = cf.estimate_bounds(wc, path, h_max=0.0)
    cert = cf.estimate_bounds(wc, path, h_max=0.0, certify=Certify(epsilon=1e-3, confidence=0.99))
    up, upc = plain.upper[1], cert.upper[1]
    np.testing.assert_allclose(up, [0.4, 0.8])  # each joint alone reaches its limit
    assert not wc.is_free(up)  # the corner collides
    assert not (np.all(up <= upc) and np.all(up >= cert.lower[1]))  # ... and is excluded
    before = cf.confidence_factor(wc, plain, windows=2, samples=10000, seed=3)
    after = cf.confidence_factor(wc, cert, windows=2, samples=10000, seed=3)
    assert before.colliding > 200  # the plain box collides often
    assert after.colliding <= 40  # <= 0.2 %: the certificate (0.1 %) with slack
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


def test_clamp_samples_default_to_ten_times_epsilon():
    """N_c = ceil(ln(100) / (10 epsilon)) by default, or for the clamp_epsilon given."""
    assert Certify().n_clamp_samples == 46052
    assert Certify(epsilon=1e-3).n_clamp_samples == 461
    assert Certify(clamp_epsilon=1e-5).n_clamp_samples == Certify().n_samples


def test_n_samples_formula():
    """N = ceil(ln(1 / (1 - C)) / epsilon): 4606 for 1e-3 at 99 %."""
    assert Certify(epsilon=1e-3, confidence=0.99).n_samples == 4606
    assert Certify(epsilon=0.05, confidence=0.95).n_samples == 60


def test_seed_stream_differs_from_cf():
    """Certification draws differ from CF's draws of the same seed."""
    assert certification_rng(0).random() != np.random.default_rng(0).random()


@pytest.mark.parametrize(
    "kwargs",
    [
        {"epsilon": 0.0},
        {"epsilon": 1.0},
        {"confidence": 1.0},
        {"confidence": -0.1},
        {"epsilon": 2},
        {"clamp_epsilon": 0.0},
        {"clamp_epsilon": 1.5},
    ],
)
def test_invalid_certificate(kwargs):
    """epsilon, clamp_epsilon or confidence outside (0, 1) raise a clear error."""
    with pytest.raises(cf.ParameterError, match="must lie in"):
        Certify(**kwargs)


def _stretch(lo, hi, nominal):
    """A two-waypoint linear table's boxes: the same box at both ends."""
    return np.array([lo, lo], float), np.array([hi, hi], float), np.array([nominal, nominal], float)


def test_greedy_cut_by_hand():
    """One colliding sample at (0.9, 0.2) in [-1, 1]^2 around a nominal at the
    origin (the same box at both ends of the stretch): cutting joint 0's
    upper bound to 0.9 loses log(2 / 1.9) per end, joint 1's to 0.2 loses
    log(2 / 1.2); the cheaper cut is taken, at both ends, and only it."""
    from drake_cfvol.algorithm.certificate.certify import _greedy_cut

    L, U, N = _stretch([-1.0, -1.0], [1.0, 1.0], [0.0, 0.0])
    n = _greedy_cut(np.array([[0.9, 0.2]]), np.array([0.5]), L, U, N, 0)
    assert n == 1
    assert np.all(U[:, 0] < 0.9) and U[:, 0] == pytest.approx([0.9, 0.9], rel=1e-5) and np.all(U[:, 1] == 1.0)
    np.testing.assert_array_equal(L, -np.ones((2, 2)))


def test_greedy_cut_removes_many_at_once():
    """Ten samples at x = 0.5 .. 0.95 and one at y = -0.95: the ten go by
    cuts of x's upper bound (the losses telescope to log(2 / 1.5), cheaper
    than any cut of y that would remove them), the lone one by y's lower
    bound to -0.95 (log(2 / 1.95), cheaper than x's lower bound to 0.05)."""
    from drake_cfvol.algorithm.certificate.certify import _greedy_cut

    X = np.vstack([np.column_stack([np.linspace(0.5, 0.95, 10), np.full(10, 0.1)]), [[0.05, -0.95]]])
    L, U, N = _stretch([-1.0, -1.0], [1.0, 1.0], [0.0, 0.0])
    assert _greedy_cut(X, np.full(len(X), 0.3), L, U, N, 0) >= 2
    assert U[0, 0] == pytest.approx(0.5, rel=1e-5) and U[0, 0] < 0.5
    assert L[0, 1] == pytest.approx(-0.95, rel=1e-5) and L[0, 1] > -0.95
    assert U[0, 1] == 1.0 and L[0, 0] == -1.0


def test_greedy_cut_in_a_changing_box_by_hand():
    """A box that widens along the stretch, upper bound of joint 0 from 0.5
    to 1.5 (nominal 0): a sample at x = 0.9, halfway (the bound there is
    1.0), goes when joint 0's deviation is scaled below 0.9 at both ends:
    0.45 and 1.35."""
    from drake_cfvol.algorithm.certificate.certify import _greedy_cut

    L = np.array([[-1.0], [-1.0]])
    U = np.array([[0.5], [1.5]])
    N = np.zeros((2, 1))
    assert _greedy_cut(np.array([[0.9]]), np.array([0.5]), L, U, N, 0) == 1
    assert U[:, 0] == pytest.approx([0.45, 1.35], rel=1e-5) and np.all(U[:, 0] < [0.45, 1.35])


def test_greedy_cut_moves_a_bound_a_few_ulps_wide():
    """A deviation of 8e-5 rad on a bound near 1.4 rad, a sample on it: the
    cut still moves the bound below the sample (it terminates, and the
    sample is out), and nothing else changes."""
    from drake_cfvol.algorithm.certificate.certify import _greedy_cut

    L, U, N = _stretch([0.0, -1.0], [1.39891897 + 8e-5, 1.0], [1.39891897, 0.0])
    x = np.array([[U[0, 0], 0.0]])
    assert _greedy_cut(x, np.array([0.0]), L, U, N, 0) == 1
    assert U[0, 0] < x[0, 0] and U[0, 0] >= N[0, 0]
    np.testing.assert_array_equal(U[:, 1], [1.0, 1.0])


def test_greedy_cut_refuses_a_sample_at_its_nominal():
    """A colliding sample at its own nominal cannot be cut away: -1."""
    from drake_cfvol.algorithm.certificate.certify import _greedy_cut

    L, U, N = _stretch([-1.0, -1.0], [1.0, 1.0], [0.3, 0.3])
    assert _greedy_cut(np.array([[0.3, 0.3]]), np.array([0.5]), L, U, N, 0) == -1


def test_edge_biased_share():
    """With share s, a coordinate lies in the outer tenth with probability
    s + 0.2 (1 - s) (the snapped ones plus uniform ones that land there)."""
    from drake_cfvol.algorithm.certificate.certify import _edge_biased

    U = _edge_biased(np.random.default_rng(0), (200000, 2), 0.5)
    outer = ((U < 0.1) | (U > 0.9)).mean()
    assert abs(outer - (0.5 + 0.2 * 0.5)) < 0.005
    assert U.min() >= 0.0 and U.max() <= 1.0


@pytest.mark.parametrize("kwargs", [{"search_rounds": -1}, {"edge_share": 1.5}])
def test_invalid_search_settings(kwargs):
    """Search settings out of range raise a clear error."""
    with pytest.raises(cf.ParameterError, match="Certify: "):
        Certify(**kwargs)


def test_certificate_run_is_n_consecutive(corner):
    """The report counts at least N samples after the search, and the same
    seed gives the same certified boxes."""
    wc, path = corner
    c = Certify(epsilon=1e-3, confidence=0.99, batch=200, search_rounds=2)
    a = cf.estimate_bounds(wc, path, h_max=0.0, certify=c)
    b = cf.estimate_bounds(wc, path, h_max=0.0, certify=c)
    rep = a.info["certificate"]
    search = min((200 + 400) * (path.g - 1), 8 * rep["n_samples"])
    assert rep["samples"] >= search + rep["n_samples"]
    np.testing.assert_array_equal(a.stretch_upper, b.stretch_upper)
    np.testing.assert_array_equal(a.stretch_lower, b.stretch_lower)


def test_certificate_run_keeps_exact_draws_across_cuts(corner):
    """Without a search, the certificate run meets the corner's collisions
    itself and cuts during the run. Its samples at the end are N uniform and
    Nc clamp draws, each exactly its own random draws mapped into the final
    (cut) box, inside it, and free by the kernel and by Drake's checker."""
    from drake_cfvol.algorithm.certificate.certify import _Certification, _clamp_q
    from drake_cfvol.io.progress import Progress

    wc, path = corner
    table = cf.estimate_bounds(wc, path, h_max=0.0)
    c = Certify(epsilon=1e-3, confidence=0.99, search_rounds=0, boundary=False, cache=False)
    job = _Certification(wc, wc.scene_arrays(), table, c)
    run = job.certificate_run(Progress(1, "test", enabled=False))
    assert job.shrinks >= 1  # cuts happened during the run
    assert job.samples > c.n_samples + c.n_clamp_samples  # focus searches and re-checks
    assert run.counts() == (c.n_samples, c.n_clamp_samples)
    lo, hi, nom = job.current.boxes_at(run.s)
    u = ~run.clamp
    np.testing.assert_array_equal(run.Q[u], lo[u] + run.U[u] * (hi[u] - lo[u]))
    cl = run.clamp
    np.testing.assert_array_equal(run.Q[cl], _clamp_q((run.pushed[cl], run.up[cl], run.U[cl]), lo[cl], hi[cl], nom[cl]))
    assert np.all((run.Q >= lo) & (run.Q <= hi))
    assert not wc.scene_arrays().may_collide(run.Q).any()
    assert np.asarray(wc.padded_checker(0.0).CheckConfigsCollisionFree(run.Q, parallelize=False)).all()
    # The box the run certified is smaller than where it started.
    assert np.any(job.current.upper < table.upper) or np.any(job.current.lower > table.lower)


def test_cache_reuses_exact_inputs_only(corner, tmp_path, monkeypatch):
    """A second identical certification loads the first one's boxes (same
    arrays, report marked cached); another seed computes anew; cache=False
    and DRAKE_CFVOL_CACHE=off never read the cache."""
    from drake_cfvol.algorithm.certificate.certify import cache_dir

    wc, path = corner
    monkeypatch.setenv("DRAKE_CFVOL_CACHE", str(tmp_path))
    assert cache_dir() == tmp_path
    c = Certify(epsilon=1e-3, confidence=0.99, batch=200, search_rounds=1)
    a = cf.estimate_bounds(wc, path, h_max=0.0, certify=c)
    b = cf.estimate_bounds(wc, path, h_max=0.0, certify=c)
    assert not a.info["certificate"]["cached"] and b.info["certificate"]["cached"]
    np.testing.assert_array_equal(a.stretch_upper, b.stretch_upper)
    np.testing.assert_array_equal(a.upper, b.upper)
    assert b.info["certificate"]["time_ms"] == a.info["certificate"]["time_ms"]  # the original run's
    assert len(list((tmp_path / "certificates").glob("*.npz"))) == 1
    other = cf.estimate_bounds(
        wc, path, h_max=0.0, certify=Certify(epsilon=1e-3, confidence=0.99, batch=200, search_rounds=1, seed=5)
    )
    assert not other.info["certificate"]["cached"]
    fresh = cf.estimate_bounds(
        wc, path, h_max=0.0, certify=Certify(epsilon=1e-3, confidence=0.99, batch=200, search_rounds=1, cache=False)
    )
    assert not fresh.info["certificate"]["cached"]
    monkeypatch.setenv("DRAKE_CFVOL_CACHE", "off")
    assert cache_dir() is None
    assert not cf.estimate_bounds(wc, path, h_max=0.0, certify=c).info["certificate"]["cached"]


def test_damaged_cache_entry_is_recomputed(corner, tmp_path, monkeypatch):
    """A truncated cache file is ignored and replaced, not an error."""
    wc, path = corner
    monkeypatch.setenv("DRAKE_CFVOL_CACHE", str(tmp_path))
    c = Certify(epsilon=1e-3, confidence=0.99, batch=200, search_rounds=1)
    a = cf.estimate_bounds(wc, path, h_max=0.0, certify=c)
    (f,) = (tmp_path / "certificates").glob("*.npz")
    f.write_bytes(f.read_bytes()[:50])
    b = cf.estimate_bounds(wc, path, h_max=0.0, certify=c)
    assert not b.info["certificate"]["cached"]
    np.testing.assert_array_equal(a.stretch_upper, b.stretch_upper)


def test_certificate_report_in_words(corner):
    """The report says what is proven and what is sampled, with the
    certificate's own epsilon, confidence and N in the words."""
    wc, path = corner
    c = Certify(epsilon=1e-3, confidence=0.95, batch=200, search_rounds=1)
    rep = cf.estimate_bounds(wc, path, h_max=0.0, certify=c).info["certificate"]
    assert rep["n_samples"] == c.n_samples == 2996
    assert "single-joint motion" in rep["proven"] and "every s" in rep["proven"]
    assert f"{c.n_samples} samples uniform" in rep["sampled"]
    assert "probability 0.95" in rep["sampled"] and "share 0.001" in rep["sampled"]
    assert rep["samples"] >= rep["n_samples"] and rep["time_ms"] > 0


def test_certificate_report_is_typed_and_its_json_comes_from_it(corner, tmp_path, monkeypatch):
    """``info["certificate"]`` is the typed report's dict: its boundary
    figures a :class:`BoundaryFigures`, counted as the proof counts them,
    and the report read back from the cache (its JSON) equals the one
    written."""
    import json

    from drake_cfvol.algorithm.certificate.certify import BoundaryFigures, CertificateReport

    monkeypatch.setenv("DRAKE_CFVOL_CACHE", str(tmp_path))
    wc, path = corner
    c = Certify(epsilon=1e-3, batch=200, search_rounds=1)
    rep = cf.estimate_bounds(wc, path, h_max=0.0, certify=c).info["certificate"]
    typed = CertificateReport.from_dict(json.loads(json.dumps(rep)))
    assert isinstance(typed.boundary, BoundaryFigures)
    assert typed.to_dict() == rep
    assert typed.boundary.edge_tests > 0 and typed.boundary.unproven == []
    cached = cf.estimate_bounds(wc, path, h_max=0.0, certify=c).info["certificate"]
    assert cached["cached"] and {**cached, "cached": False} == rep


def _clamp_proven_share(k: int, edges: bool) -> float:
    """The share of clamp landings (:func:`clamp_draws`) on a proven part, by
    enumerating each joint's three states: not pushed (1/2: at the nominal),
    pushed but inside (1/4: the push amount under the deviation) or pushed
    onto its bound (1/4). Proven: at most one joint off the nominal, or (the
    edges proven) at most one joint off its bounds."""
    import itertools

    total = 0.0
    for states in itertools.product(range(3), repeat=k):
        p = np.prod([(0.5, 0.25, 0.25)[x] for x in states])
        off_nominal = sum(x > 0 for x in states)
        off_bounds = sum(x < 2 for x in states)
        if off_nominal <= 1 or (edges and off_bounds <= 1):
            total += p
    return total


@pytest.mark.parametrize("boundary", [True, False])
def test_proven_share_is_where_a_clamp_lands_on_a_proof(corner, boundary):
    """The report's proven share is the share of the run's clamp landings on
    a single-joint motion or (with the boundary proof) an edge or corner:
    15/16 for two joints with the edges, 3/4 without, by enumeration of the
    clamp's draws, within 4 standard deviations of the run's sample."""
    wc, path = corner
    c = Certify(epsilon=1e-3, batch=200, search_rounds=1, boundary=boundary, cache=False)
    rep = cf.estimate_bounds(wc, path, h_max=0.0, certify=c).info["certificate"]
    expected = _clamp_proven_share(2, boundary)
    assert expected == (15 / 16 if boundary else 3 / 4)
    n = c.n_clamp_samples
    assert abs(rep["proven_share"] - expected) <= 4 * np.sqrt(expected * (1 - expected) / n), (rep, n)
    assert f"a share {rep['proven_share']:.3f} lies where the proofs above hold" in rep["sampled"]


# Automotive at the defaults, boundary proof included (~170 s, the certificate
# the README example, the certified scenario runs and the adversarial test
# share within the run); aerospace with the sampled certificate only at
# epsilon 1e-4 (its proof takes ~6 min; 1e-5 alone ~2 min).
@pytest.mark.slow
@pytest.mark.parametrize("cell, settings", [("automotive", {}), ("aerospace", {"boundary": False, "epsilon": 1e-4})])
def test_independent_cf_of_certified_bounds(cell, settings, bounded, planned, request):
    """Certified bounds, checked by Drake on a seed stream certification
    never used (60,000 samples): no more collide than the certificate's
    epsilon allows (on average at most 60,000 x epsilon: 0.6 or 6; a
    Poisson count at that mean exceeds 3, resp. 15, with probability 0.3 %,
    resp. 0.05 %), and the boxes only shrank."""
    wc = request.getfixturevalue(cell)
    plain = bounded(cell, "path1", 1000)
    certify = Certify(seed=0, **settings)
    cert = cf.estimate_bounds(wc, planned(cell, "path1"), resolution=1000, certify=certify)
    res = cf.confidence_factor(wc, cert, windows=30, samples=2000, seed=424242)
    assert res.colliding <= {1e-5: 3, 1e-4: 15}[certify.epsilon]
    # What the sweep proved still covers the certified box: at every s
    # (waypoints, quarters, and just either side of them) each bound lies
    # within the plain table's stretch box or at the nominal.
    s = np.unique(
        np.clip(np.concatenate([np.arange(0.0, cert.g - 1 + 1e-9, 0.25) + d for d in (-1e-6, 0, 1e-6)]), 0, cert.g - 1)
    )
    lo_c, hi_c, nom = cert.boxes_at(s)
    i = np.clip(np.floor(s).astype(int), 0, cert.g - 2)
    for st in (i, np.clip(np.ceil(s).astype(int) - 1, 0, cert.g - 2)):  # a waypoint belongs to both stretches
        inside_hi = hi_c <= np.maximum(plain.stretch_upper[st], nom) + 1e-9
        inside_lo = lo_c >= np.minimum(plain.stretch_lower[st], nom) - 1e-9
        on_waypoint = (s == np.round(s))[:, None]
        assert np.all((inside_hi & inside_lo) | on_waypoint & (st != i)[:, None])
    assert cert.info["certificate"]["freedom_after"] < cert.info["certificate"]["freedom_before"]


@pytest.mark.parametrize("cell, sampled", [("corner", True), ("corner_mesh", True), ("corner", False)])
def test_boundary_proof_frees_every_edge_by_drake(cell, sampled, request):
    """With boundary=True every corner and edge of the certified box, at
    every quarter of every stretch, keeps the margin by Drake's padded
    checker (edges densely: 41 points along each), and the report says the
    edges are proven; also on mesh links, and with no sampled search (the
    proof's own cuts)."""
    from drake_cfvol.algorithm.metrics import boundary_check

    wc, path = request.getfixturevalue(cell)
    # Without the sampled search (one sample in the run), the proof's own cuts do the work.
    settings = dict(epsilon=1e-3, confidence=0.99) if sampled else dict(epsilon=0.5, confidence=0.1, search_rounds=0)
    cert = cf.estimate_bounds(wc, path, h_max=0.0, certify=Certify(**settings, boundary=True, cache=False))
    assert cert.interpolation == "linear"
    margin = cert.info["certificate"]["clearance_m"]
    checker = wc.padded_checker(max(0.0, margin - 1e-3))
    s = np.arange(0.0, cert.g - 1 + 1e-9, 0.25)
    lo, hi, _ = cert.boxes_at(s)
    u = np.linspace(0.0, 1.0, 41)
    edges = []
    for a in range(len(s)):
        for j in range(2):
            for other in (lo[a, 1 - j], hi[a, 1 - j]):
                E = np.empty((len(u), 2))
                E[:, j] = lo[a, j] + u * (hi[a, j] - lo[a, j])
                E[:, 1 - j] = other
                edges.append(E)
    free = np.asarray(checker.CheckConfigsCollisionFree(np.concatenate(edges), parallelize=False), bool)
    assert free.all()
    assert boundary_check(wc, cert, clearance=max(0.0, margin - 1e-3)).corners_colliding == 0
    rep = cert.info["certificate"]
    assert "every edge of the box" in rep["proven"] and rep["boundary"]["edge_tests"] > 0
    assert rep["boundary"]["unproven"] == []
    if not sampled:
        assert rep["boundary"]["edge_cuts"] >= 1  # the colliding corner was the proof's to cut
    # The corner that collides is excluded, and the box is not shrunk to nothing.
    assert np.all(cert.upper[1] - cert.lower[1] > 0.1)


@pytest.mark.parametrize("cell", ["corner", "corner_mesh"])
def test_the_face_samples_hold_one_joint_on_a_bound_and_keep_the_margin(cell, request):
    """The certificate's face samples: N_c of them beside the run's N
    uniform and N_c clamp samples; each holds exactly one joint exactly on
    one of its bounds in the certified box at its s (the upper about half
    the time), its other joints inside; every joint is held about equally
    often; and every sample of the run, faces included, is free by Drake's
    checker padded to the margin less 1 mm."""
    from drake_cfvol.algorithm.certificate.certify import _Certification
    from drake_cfvol.io.progress import Progress

    wc, path = request.getfixturevalue(cell)
    table = cf.estimate_bounds(wc, path, h_max=0.0)
    job = _Certification(wc, wc.scene_arrays(), table, Certify(epsilon=1e-3, clamp_epsilon=1e-3, cache=False))
    job.prove()
    bar = Progress(1, "test", enabled=False)
    run = job.face_run(job.certificate_run(bar), bar)
    assert run.counts() == (job.N, job.Nc) and int(run.face.sum()) == job.Nc
    lo, hi, _ = job.current.boxes_at(run.s)
    Q = run.Q[run.face]
    lo, hi = lo[run.face], hi[run.face]
    on_hi, on_lo = (Q == hi) & (hi > lo), (Q == lo) & (hi > lo)
    held = run.pushed[run.face]
    assert np.all(held.sum(axis=1) == 1)
    assert np.all((on_hi | on_lo)[held])
    assert on_hi[held].mean() == pytest.approx(0.5, abs=0.05)
    assert held.mean(axis=0) == pytest.approx(np.full(table.k, 1 / table.k), abs=0.05)
    assert np.all((Q >= lo) & (Q <= hi))
    margin = float(job.margins.min())
    free = np.asarray(wc.padded_checker(max(0.0, margin - 1e-3)).CheckConfigsCollisionFree(run.Q), bool)
    assert free.all()


@pytest.mark.parametrize("cell", ["corner", "corner_mesh"])
def test_a_starved_joint_gets_room_back_and_the_certificate_holds(cell, request):
    """A joint cut to nothing at a waypoint (joint 1 at waypoint 1, by
    hand: only safer) though its uncut box had room gets at least the
    bisection delta back from unstarve where the proof still holds: the
    report counts it, no other bound moves, every corner and edge point of
    the box at every waypoint and stretch midpoint keeps the margin by
    Drake's padded checker, and the run carried on holds N uniform and Nc
    clamp samples, every one free by Drake too."""
    import dataclasses

    from drake_cfvol.algorithm.certificate.certify import _Certification
    from drake_cfvol.algorithm.metrics import boundary_check
    from drake_cfvol.io.progress import Progress

    wc, path = request.getfixturevalue(cell)
    table = dataclasses.replace(cf.estimate_bounds(wc, path, h_max=0.0), rate=None)
    job = _Certification(wc, wc.scene_arrays(), table, Certify(epsilon=1e-3, cache=False))
    job.prove()
    job.lower[1, 0] = job.upper[1, 0] = job.nominal[1, 0]
    job.refresh()
    job.prove()
    bar = Progress(1, "test", enabled=False)
    run = job.certificate_run(bar)
    before_lo, before_hi = job.lower.copy(), job.upper.copy()
    run = job.unstarve(run, bar)
    delta = table.params["delta"]
    assert job.upper[1, 0] - job.lower[1, 0] >= delta - 1e-12
    assert job.boundary.unstarved >= 1
    moved = (job.lower != before_lo) | (job.upper != before_hi)
    assert moved[1, 0] and moved.sum() == 1
    margin = float(job.margins.min())
    check = boundary_check(wc, job.current, clearance=max(0.0, margin - 1e-3))
    assert check.corners_colliding == 0 and check.edges_colliding == 0 and check.corners > 0
    assert run.counts() == (job.N, job.Nc)
    free = np.asarray(wc.padded_checker(max(0.0, margin - 1e-3)).CheckConfigsCollisionFree(run.Q), bool)
    assert free.all()


@pytest.mark.parametrize("cell", ["corner", "corner_mesh"])
def test_regrow_gives_back_an_unneeded_cut_and_keeps_the_proof(cell, request):
    """After the proof, a cut made unneeded (joint 1's lower deviation
    shrunk to a fifth everywhere: only safer) is given back by regrow where
    the proof still holds: that bound widens at some waypoint, no bound
    narrows, the report counts it, and every corner and edge point of the
    box at every waypoint and stretch midpoint still keeps the margin by
    Drake's padded checker. Regrow without the proof is refused."""
    import dataclasses

    from drake_cfvol.algorithm.certificate.certify import _Certification
    from drake_cfvol.algorithm.metrics import boundary_check

    wc, path = request.getfixturevalue(cell)
    # Without a rate limit (as a table of the reference backend): this path
    # stands still, so a rate-limited bound could not differ between waypoints.
    table = dataclasses.replace(cf.estimate_bounds(wc, path, h_max=0.0), rate=None)
    job = _Certification(wc, wc.scene_arrays(), table, Certify(epsilon=1e-3, regrow=True, cache=False))
    job.prove()
    nom = job.nominal
    job.lower[:, 0] = nom[:, 0] - 0.2 * (nom[:, 0] - job.lower[:, 0])
    job.refresh()
    before_lo, before_hi = job.lower.copy(), job.upper.copy()
    assert job.regrow() >= 1
    assert np.any(job.lower[:, 0] < before_lo[:, 0] - 1e-9)
    assert np.all(job.lower <= before_lo + 1e-12) and np.all(job.upper >= before_hi - 1e-12)
    assert job.boundary.regrown >= 1
    margin = float(job.margins.min())
    check = boundary_check(wc, job.current, clearance=max(0.0, margin - 1e-3))
    assert check.corners_colliding == 0 and check.edges_colliding == 0 and check.corners > 0
    with pytest.raises(cf.ParameterError, match="regrow"):
        Certify(boundary=False, regrow=True)


def test_greedy_cut_uses_only_allowed_joints():
    """The by-hand sample (0.9, 0.2) whose colliding pair only joint 1
    reaches: joint 0 (the cheaper cut) may not cut it, so joint 1's upper
    bound goes to just below 0.2 and joint 0 keeps its width."""
    from drake_cfvol.algorithm.certificate.certify import _greedy_cut

    L, U, N = _stretch([-1.0, -1.0], [1.0, 1.0], [0.0, 0.0])
    assert _greedy_cut(np.array([[0.9, 0.2]]), np.array([0.5]), L, U, N, 0, np.array([[False, True]])) == 1
    assert np.all(U[:, 0] == 1.0) and U[:, 1] == pytest.approx([0.2, 0.2], rel=1e-5) and np.all(U[:, 1] < 0.2)


def test_greedy_cut_falls_back_when_no_allowed_joint_can_cut():
    """A sample off the nominal only in joint 0 while only joint 1 is
    allowed: it is still cut (by joint 0), never left in the box."""
    from drake_cfvol.algorithm.certificate.certify import _greedy_cut

    L, U, N = _stretch([-1.0, -1.0], [1.0, 1.0], [0.0, 0.0])
    assert _greedy_cut(np.array([[0.7, 0.0]]), np.array([0.5]), L, U, N, 0, np.array([[False, True]])) == 1
    assert U[:, 0] == pytest.approx([0.7, 0.7], rel=1e-5) and np.all(U[:, 1] == 1.0)


def test_clamp_draws_land_where_a_clamp_does():
    """Clamp draws stay in the box; each joint sits at its nominal about half
    the time (not pushed), on a bound about a quarter (pushed past it), and
    strictly inside otherwise; both sides are pushed alike."""
    from drake_cfvol.algorithm.certificate.certify import clamp_draws

    rng = np.random.default_rng(7)
    n = 40000
    lo, hi, nom = np.full((n, 3), -1.0), np.full((n, 3), 2.0), np.zeros((n, 3))
    Q = clamp_draws(rng, lo, hi, nom)
    assert np.all((Q >= lo) & (Q <= hi))
    at_nom, on_bound = Q == nom, (Q == lo) | (Q == hi)
    assert at_nom.mean() == pytest.approx(0.5, abs=0.01)
    assert on_bound.mean() == pytest.approx(0.25, abs=0.01)
    assert (Q == hi).mean() == pytest.approx((Q == lo).mean(), abs=0.01)


def test_certificate_report_names_both_distributions(corner):
    """The sampled certificate speaks of uniform samples and of where a clamp
    lands, each N free."""
    wc, path = corner
    cert = cf.estimate_bounds(wc, path, h_max=0.0, certify=Certify(epsilon=1e-3, confidence=0.99, cache=False))
    text = cert.info["certificate"]["sampled"]
    assert "uniform in the box" in text and "where a clamp lands" in text
    assert "4606 samples uniform" in text and "461 samples where" in text  # epsilon 1e-3 and the clamp's 1e-2


def test_halving_in_s_drops_pieces_the_edge_never_reaches(corner, monkeypatch):
    """A failing region halved in s keeps only the pieces where the edge's
    joint range (linear in s) meets the region's: a piece it misses holds
    no point of the edge. By hand: joint 0's box moves from [0, 0.1] at
    waypoint 0 to [0.3, 0.4] at waypoint 1, so over s in [0.5, 1] it spans
    [0.15, 0.4], which misses the region's [0, 0.1]. Before, that piece was
    tested with its range inverted ([0.15, 0.1]) and could fail forever (the
    mesh robot's proof then cut its box to 0.26 of the joint ranges instead
    of 0.36)."""
    from drake_cfvol.algorithm.certificate import boundary
    from drake_cfvol.algorithm.certificate.boundary_regions import MAX_SPLITS, S_SPLITS, _Item

    wc, _ = corner
    arrays = wc.scene_arrays()
    nominal = np.array([[0.05, 0.0], [0.35, 0.0]])
    lower = np.array([[0.0, -0.05], [0.3, -0.05]])
    upper = np.array([[0.1, 0.05], [0.4, 0.05]])
    S = np.array([0, 0])
    A, B = np.array([0.0, -0.05]), np.array([0.3, -0.05])
    depth = MAX_SPLITS - S_SPLITS  # the next halving is in s
    item = _Item(0, 0.0, 1.0, 0, 0.0, 0.1, S, A, B, root=0, depth=depth)
    tested = []
    real_test = boundary._test_regions

    def recording(arrays, regions, margins):
        tested.extend(regions.items())
        return real_test(arrays, regions, margins)

    monkeypatch.setattr(boundary, "_test_regions", recording)
    failed, _, _ = boundary._halvings(arrays, lower, upper, nominal, boundary._Regions.of_items([item]), np.zeros(1))
    assert tested, "the item was not halved"
    assert all(it.va <= it.vb for it in tested + failed)
    assert all(it.sb <= 0.5 for it in tested if it.depth == depth + 1), [(it.sa, it.sb) for it in tested]
    assert not failed  # the arm is far from the post here
