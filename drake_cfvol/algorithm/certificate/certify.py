"""Certified bounds: the whole box at every s, all joints at once.

The paper's bounds are per-joint extents, each found with the other joints
at nominal; moving several joints at once can still collide. What is
*proven* already (SPEC 6-7, by the kernel's region tests): every single-joint
motion from the nominal to its bound, at every s. Certification makes the
table "linear" (each bound linear in s between its waypoints,
:func:`drake_cfvol.algorithm.table.box_at`) and adds, for the whole box:

- a *proof* where a clamp lands: every edge and corner of the box at every
  s is free by the kernel's region tests (:mod:`drake_cfvol.algorithm.certificate.boundary`);
- a *sampled* guarantee for the faces and the interior: N consecutive
  samples, drawn as the Confidence Factor draws them (s uniform over the
  path, q uniform in the box at s), are all certified free by the compiled
  kernel, which never calls a configuration free where Drake finds a
  collision. With N >= ln(1 / (1 - confidence)) / epsilon (the test Drake's
  IrisZo uses): if the colliding share of that distribution were epsilon or
  more, N free samples in a row would occur with probability at most
  1 - confidence.

How the boxes shrink (cuts only tighten, so the proven single-joint
safety still holds; after every cut the waypoint boxes are rate-limited
again, :func:`drake_cfvol.algorithm.table.rate_limited`):

1. Search: rounds of samples stratified over the stretches (``batch`` per
   stretch, doubling each round), a share of their coordinates drawn in
   the outer tenth of the box, where several joints near their bounds
   collide. All colliding samples of a round are cut at once, per stretch,
   greedily: each cut scales one joint's deviation from the nominal on one
   side at both ends of the stretch, the one that loses the least
   log-width per colliding sample it removes.
2. Proof of the boundary (edges and corners), cutting where a region may
   collide (:func:`drake_cfvol.algorithm.certificate.boundary.prove_boundary`).
3. Certificate: N free samples of the whole path uniform in the box at s
   (and Nc where a clamp lands). A colliding sample is cut the same way,
   its stretch is searched again (``focus_samples`` per round until a
   round finds nothing) and the changed stretches are proven again; the
   run keeps its other samples, re-mapped into the cut box
   (:meth:`_Certification.certificate_run`).

Every test keeps the table's ``clearance`` margin (per stretch: less only
where the nominal itself is nearer, :func:`drake_cfvol.algorithm.sweep.stretch_margins`).

Certification draws from a seed stream of its own, distinct from the CF
evaluation's.
"""

import dataclasses
import math
import time
from typing import Any

import numpy as np
from numba import njit, prange

from drake_cfvol.algorithm.certificate.boundary import cut_point, cut_slacks, failures, prove_boundary, reaching_joints
from drake_cfvol.algorithm.certificate.cert_cache import cache_dir, cache_key, cache_load, cache_store
from drake_cfvol.algorithm.metrics import freedom
from drake_cfvol.algorithm.sweep import stretch_margins
from drake_cfvol.algorithm.table import rate_limited, within_stretches
from drake_cfvol.exceptions import ParameterError
from drake_cfvol.io.progress import Progress

__all__ = [
    "Certify",
    "CertificateReport",
    "BoundaryFigures",
    "certify_bounds",
    "certified_table",
    "certification_rng",
    "cache_dir",
    "clamp_draws",
]

#: Drake queries per stretch for the joints a sampled cut may use.
_REACH_QUERIES = 16
#: Point cuts per stretch and round for samples on a bound.
_POINT_CUTS = 16
#: Room a point cut of the sampled search leaves beyond the margin, m (its
#: neighbours on the same bound come free with it).
_POINT_SLACK = 0.005

#: Spawn key that separates certification draws from CF draws of the same seed.
_CERT_STREAM = 0xCE27

#: The face samples' stream: drawn after the run, so the run's own draws
#: are those of a certification without them.
_FACE_STREAM = 0xFACE


@dataclasses.dataclass(frozen=True)
class Certify:
    """Certificate settings.

    Attributes:
        epsilon: the largest colliding share allowed, in (0, 1), of
            configurations uniform in the box. With ``confidence`` it sets
            the certificate's sample count N = ceil(ln(1 / (1 -
            confidence)) / epsilon).
        clamp_epsilon: the same, in (0, 1), for where a clamp lands
            (:func:`clamp_draws`); None: 10 x epsilon (at most 0.5). The
            boundary proof, when on, covers the box's edges and corners
            for certain.
        confidence: probability that the certificate is right, in (0, 1).
        seed: seed of the certification samples (a stream distinct from CF's).
        batch: search samples per stretch in the first search round, a
            count (>= 1); each round doubles it.
        search_rounds: search rounds before the certificate run, a count
            (>= 0; 0: no search).
        search_factor: the search draws at most this many times N samples
            in all, no unit (>= 0; a small N needs little search).
        edge_share: share of search coordinates drawn in the outer tenth
            of their range (either end), in [0, 1].
        focus_samples, focus_rounds: after a colliding sample in the
            certificate run, its stretch is searched again with this many
            samples per round (a count, at most N), until a round finds
            nothing (at most ``focus_rounds`` rounds, a count; 0: none).
        boundary: prove every edge and corner of the box at every s
            (:mod:`drake_cfvol.algorithm.certificate.boundary`), where a clamp pushed steadily
            lands (default). False: the sampled certificate only, a little
            faster and a little wider, but a corner may then come nearer
            than the margin, and only the runtime safety filter keeps the
            margin there; the report says so.
        regrow: after the certificate, widen each cut bound back by half of
            what it lost where the stretches on both sides stay proven, then
            run the sampled certificate again (needs ``boundary``). Cuts are
            chosen one failing region at a time; this gives back what later
            cuts made unneeded, for a little more freedom at about twice
            the time.
        cache: reuse a certificate computed before for exactly the same
            inputs (scene, path, bounds, settings; see :func:`cache_dir`).
            Certification is deterministic, so a cached result is the
            result; the report says it was cached and how long the original
            run took.
    """

    epsilon: float = 1e-5
    clamp_epsilon: float | None = None
    confidence: float = 0.99
    seed: int = 0
    batch: int = 1000
    search_rounds: int = 5
    edge_share: float = 0.5
    focus_samples: int = 20000
    focus_rounds: int = 4
    search_factor: float = 8.0
    boundary: bool = True
    regrow: bool = False
    cache: bool = dataclasses.field(default=True, compare=False)

    def __post_init__(self):
        for name in ("epsilon", "clamp_epsilon", "confidence"):
            v = getattr(self, name)
            if name == "clamp_epsilon" and v is None:
                continue
            if not (isinstance(v, (int, float)) and 0.0 < v < 1.0):
                raise ParameterError(f"Certify: {name} must lie in (0, 1), got {v!r}.")
        if self.batch < 1:
            raise ParameterError(f"Certify: batch must be >= 1, got {self.batch}.")
        if self.search_rounds < 0:
            raise ParameterError(f"Certify: search_rounds must be >= 0, got {self.search_rounds}.")
        if not self.search_factor >= 0.0:
            raise ParameterError(f"Certify: search_factor must be >= 0, got {self.search_factor!r}.")
        if not isinstance(self.boundary, bool):
            raise ParameterError(f"Certify: boundary must be True or False, got {self.boundary!r}.")
        if not isinstance(self.regrow, bool):
            raise ParameterError(f"Certify: regrow must be True or False, got {self.regrow!r}.")
        if self.regrow and not self.boundary:
            raise ParameterError(
                "Certify: regrow=True widens bounds where the boundary proof still holds; it needs boundary=True."
            )
        if not 0.0 <= self.edge_share <= 1.0:
            raise ParameterError(f"Certify: edge_share must lie in [0, 1], got {self.edge_share!r}.")

    @property
    def n_samples(self) -> int:
        """N = ceil(ln(1 / (1 - confidence)) / epsilon)."""
        return int(math.ceil(math.log(1.0 / (1.0 - self.confidence)) / self.epsilon))

    @property
    def clamp_share(self) -> float:
        """The clamp distribution's epsilon: ``clamp_epsilon``, by default
        10 x epsilon (at most 0.5)."""
        return self.clamp_epsilon if self.clamp_epsilon is not None else min(10.0 * self.epsilon, 0.5)

    @property
    def n_clamp_samples(self) -> int:
        """N for the clamp distribution: ceil(ln(1 / (1 - confidence)) / clamp_share)."""
        return int(math.ceil(math.log(1.0 / (1.0 - self.confidence)) / self.clamp_share))


@dataclasses.dataclass
class BoundaryFigures:
    """What the boundary proof did (:func:`drake_cfvol.algorithm.certificate.boundary.prove_boundary`).

    Attributes:
        edge_tests: region tests run, a count.
        edge_cuts: bounds the proof cut, a count.
        edge_rounds: rounds of region tests and cuts, a count.
        margins_lowered: stretches whose margin was lowered because the
            nominal itself comes nearer between its waypoints, a count.
        unproven: the stretches left unproven (empty unless the proof ran
            out of rounds).
        regrown: bounds widened back by ``Certify(regrow=True)``, a count.
        unstarved: joints given back room at a waypoint where the cuts had
            starved them (:meth:`_Certification.unstarve`), a count.
    """

    edge_tests: int = 0
    edge_cuts: int = 0
    edge_rounds: int = 0
    margins_lowered: int = 0
    unproven: list[int] = dataclasses.field(default_factory=list)
    regrown: int = 0
    unstarved: int = 0


@dataclasses.dataclass
class CertificateReport:
    """What certification did, in words and figures.

    Attributes:
        epsilon, confidence, n_samples: the sampled certificate.
        time_ms: time spent certifying.
        samples: samples checked in all.
        shrinks: bounds moved (cuts).
        freedom_before, freedom_after: mean freedom (SPEC 8).
        proven: what holds for certain.
        sampled: what the sampled certificate says.
        cached: the result was read from the cache.
        clearance_m: the margin certified, m.
        boundary: the boundary proof's figures.
        proven_share: the share of the certificate run's clamp landings
            that lie where a proof holds: at most one joint off the nominal
            (a single-joint motion, proven by the sweep) or, with the
            boundary proof, at most one joint off its bounds (an edge or a
            corner). The rest of them, on the box's faces, is sampled.
    """

    epsilon: float
    confidence: float
    n_samples: int
    time_ms: float
    samples: int
    shrinks: int
    freedom_before: float
    freedom_after: float
    proven: str = ""
    sampled: str = ""
    cached: bool = False
    clearance_m: float = 0.0
    boundary: BoundaryFigures = dataclasses.field(default_factory=BoundaryFigures)
    proven_share: float = 0.0

    def to_dict(self) -> dict[str, Any]:
        """The report as JSON-ready values (``table.info["certificate"]``)."""
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "CertificateReport":
        """The report :meth:`to_dict` gave (a cached certificate's)."""
        return cls(**{**d, "boundary": BoundaryFigures(**d.get("boundary", {}))})


def certification_rng(seed: int, stream: int = _CERT_STREAM) -> np.random.Generator:
    """The certification sampler (distinct from CF's ``default_rng(seed)``);
    ``stream`` another of its streams (the face samples')."""
    return np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(int(stream),)))


#: The compiled cuts' share of a fresh compile, s (in the terms of
#: :data:`drake_cfvol.kernel.STEP_SHARES`).
CUTS_SHARE = 6.8


def warm_up_cuts() -> None:
    """Compiles (or loads from numba's cache) the certificate's cuts: one
    cut of a made-up one-joint stretch."""
    lower, upper, nominal = np.full((2, 1), -1.0), np.full((2, 1), 1.0), np.zeros((2, 1))
    _greedy_cut(np.array([[0.5]]), np.array([0.5]), lower, upper, nominal, 0)


def _greedy_cut(X, t, lower, upper, nominal, i, allowed=None):
    """Cuts stretch i of a linear table (its waypoint boxes ``lower[i:i+2]``,
    ``upper[i:i+2]``, in place) until no colliding sample X (n, k), at
    fractions t (n,) of the stretch, is left in its box. Each cut scales
    one joint's deviation from the nominal on one side, at both ends, by a
    factor lam (the box's bound at every s moves to nom + lam (bound - nom)),
    just enough to drop some samples: the cut chosen loses the least
    log-width per sample it removes. ``allowed`` (n, k) bool: the joints
    that may cut each sample (those whose motion reaches its colliding
    pair); a sample that no allowed joint can cut may be cut by any.
    Returns the number of cuts, or -1 if a sample cannot be cut (it lies
    at its own nominal in every joint). Compiled (:func:`_greedy_cut_rows`)."""
    X = np.ascontiguousarray(X, float)
    allowed = np.ones(X.shape, np.bool_) if allowed is None else np.ascontiguousarray(allowed, np.bool_)
    L, U = lower[i : i + 2].copy(), upper[i : i + 2].copy()
    cuts = _greedy_cut_rows(X, np.ascontiguousarray(t, float), L, U, np.ascontiguousarray(nominal[i : i + 2]), allowed)
    lower[i : i + 2], upper[i : i + 2] = L, U
    return int(cuts)


@njit(cache=True)
def _greedy_cut_rows(X, t, L, U, N, allowed):
    """:func:`_greedy_cut` on the stretch's waypoint rows L, U (2, k), in
    place, nominal rows N; the same arithmetic, sample by sample."""
    n, k = X.shape
    keep = np.ones(n, np.bool_)
    cuts = 0
    while True:
        # The samples still inside the box (each at its own s).
        count = 0
        for s in range(n):
            if not keep[s]:
                continue
            a, b = 1.0 - t[s], t[s]
            for j in range(k):
                lo = a * L[0, j] + b * L[1, j]
                hi = a * U[0, j] + b * U[1, j]
                nom = a * N[0, j] + b * N[1, j]
                if not (X[s, j] >= min(lo, nom) and X[s, j] <= max(hi, nom)):
                    keep[s] = False
                    break
            if keep[s]:
                count += 1
        if count == 0:
            break
        idx = np.flatnonzero(keep)
        lo_s, hi_s, nom_s = np.empty((count, k)), np.empty((count, k)), np.empty((count, k))
        ok = np.empty((count, k), np.bool_)
        for r in range(count):
            s = idx[r]
            a, b = 1.0 - t[s], t[s]
            any_ok = False
            for j in range(k):
                lo_s[r, j] = a * L[0, j] + b * L[1, j]
                hi_s[r, j] = a * U[0, j] + b * U[1, j]
                nom_s[r, j] = a * N[0, j] + b * N[1, j]
                if allowed[s, j] and X[s, j] != nom_s[r, j]:
                    any_ok = True
            for j in range(k):
                ok[r, j] = allowed[s, j] if any_ok else True
        best_score, best_j, best_side, best_lam = np.inf, -1, 0, 1.0
        lam = np.empty(count)
        for j in range(k):
            w0a, w0b = U[0, j] - L[0, j], U[1, j] - L[1, j]
            for side in (1, -1):
                m = 0
                for r in range(count):
                    s = idx[r]
                    if side > 0:
                        D, e = hi_s[r, j] - nom_s[r, j], X[s, j] - nom_s[r, j]
                    else:
                        D, e = nom_s[r, j] - lo_s[r, j], nom_s[r, j] - X[s, j]
                    if e > 0 and D > 0 and ok[r, j]:
                        lam[m] = min(e / D, 1.0)
                        m += 1
                if m == 0:
                    continue
                lams = np.sort(lam[:m])[::-1]
                if side > 0:
                    dev_a, dev_b = U[0, j] - N[0, j], U[1, j] - N[1, j]
                else:
                    dev_a, dev_b = N[0, j] - L[0, j], N[1, j] - L[1, j]
                for c in range(m):
                    w1a = max(w0a - (1 - lams[c]) * dev_a, 1e-12)
                    w1b = max(w0b - (1 - lams[c]) * dev_b, 1e-12)
                    loss = np.log(max(w0a, 1e-12) / w1a) + np.log(max(w0b, 1e-12) / w1b)
                    score = loss / (c + 1)
                    if score < best_score:
                        best_score, best_j, best_side, best_lam = score, j, side, lams[c]
        if best_j < 0:
            return -1
        j, side = best_j, best_side
        # Just below the sample's threshold, by a relative 1e-6: a cut of a
        # deviation a few ulps wide must still move the bound.
        lam_c = max(0.0, best_lam * (1 - 1e-6))
        B = U if side > 0 else L
        before0, before1 = B[0, j], B[1, j]
        while True:
            if side > 0:
                U[0, j] = N[0, j] + lam_c * (before0 - N[0, j])
                U[1, j] = N[1, j] + lam_c * (before1 - N[1, j])
            else:
                L[0, j] = N[0, j] - lam_c * (N[0, j] - before0)
                L[1, j] = N[1, j] - lam_c * (N[1, j] - before1)
            if lam_c == 0.0 or B[0, j] != before0 or B[1, j] != before1:
                break
            lam_c = 0.5 * lam_c if lam_c > 1e-3 else 0.0
        cuts += 1
    return cuts


def _edge_biased(rng, shape, share):
    """Unit-cube draws in which a ``share`` of the coordinates lie in the
    outer tenth of their range (either end): where whole-box collisions
    live, so the search finds them with fewer samples."""
    # The four draws in this order are the search's random stream; one
    # compiled pass mixes them (np.where's temporaries cost more).
    U, snap, end, depth = (rng.random(shape).reshape(-1) for _ in range(4))
    return _edge_mix(U, snap, end, depth, float(share)).reshape(shape)


@njit(cache=True, parallel=True)
def _edge_mix(U, snap, end, depth, share):
    """:func:`_edge_biased` from its uniform draws (flat arrays): a
    coordinate with snap < share lies in the outer tenth, at the upper end
    if end < 0.5, 0.1 depth from it; the others are U."""
    out = np.empty_like(U)
    for n in prange(len(U)):  # elements apart: the same values on any thread
        if snap[n] < share:
            tenth = 0.1 * depth[n]
            out[n] = 1.0 - tenth if end[n] < 0.5 else tenth
        else:
            out[n] = U[n]
    return out


def clamp_draws(rng, lo, hi, nom) -> np.ndarray:
    """Configurations where an admittance clamp lands: the nominal nom
    (n, k) pushed on a random subset of its joints (each joint with
    probability 1/2, to a random side, by up to twice its deviation to
    that side's bound) and clamped into [lo, hi]; so about half of the
    pushed joints sit on a bound, the others inside, the unpushed at the
    nominal."""
    return _clamp_q(_clamp_uniforms(rng, np.shape(nom)), lo, hi, nom)


def _clamp_uniforms(rng, shape):
    """The random part of :func:`clamp_draws`: (pushed, up, amount)."""
    return rng.random(shape) < 0.5, rng.random(shape) < 0.5, 2.0 * rng.random(shape)


def _clamp_q(draws, lo, hi, nom) -> np.ndarray:
    """:func:`clamp_draws` from its random part, in the box [lo, hi] at the
    nominal nom: the same draws give the same landing in any box."""
    pushed, up, amount = draws
    q = np.where(up, nom + amount * (hi - nom), nom - amount * (nom - lo))
    return np.where(pushed, np.clip(q, lo, hi), nom)


def certified_table(table, lower, upper):
    """The table with certified waypoint boxes and the "linear" rule; its
    stretch boxes are the hulls of their two waypoint boxes (within the
    sweep's, so its single-joint proof still holds)."""
    return dataclasses.replace(
        table,
        lower=lower,
        upper=upper,
        interpolation="linear",
        stretch_lower=np.minimum(lower[:-1], lower[1:]),
        stretch_upper=np.maximum(upper[:-1], upper[1:]),
    )


def certify_bounds(workcell, table, certify: Certify, *, progress: bool = False):
    """Shrinks a bounds table's boxes until every edge and corner of the box
    at every s is proven free and N consecutive uniform samples of the whole
    box are free (see the module docs).

    Returns:
        (lower, upper, CertificateReport): the certified waypoint boxes, for
        the "linear" box-at-s rule (:func:`certified_table` makes the
        table); the input table is not changed.

    With ``progress``, a bar on a terminal shows the search rounds, then
    the run's free samples against N, and the cuts; a cut's proof takes
    an unforeseeable time, so the bar shows no time-left estimate.
    """
    t0 = time.perf_counter()
    arrays = workcell.scene_arrays()
    folder = cache_dir() if certify.cache else None
    file = folder / "certificates" / f"{cache_key(arrays, table, certify)}.npz" if folder else None
    if file is not None and file.is_file():
        hit = cache_load(file, CertificateReport)
        if hit is not None:
            hit[2].cached = True
            return hit
    job = _Certification(workcell, arrays, table, certify)
    run = None
    bar = Progress(certify.search_rounds + job.N, "Certifying whole boxes", enabled=progress, unit="steps", eta=False)
    try:
        if job.g > 1:
            job.search_rounds(bar)
            job.prove()
            run = job.certificate_run(bar)
            if job.regrow():
                run = job.certificate_run(bar)
            run = job.unstarve(run, bar)
            run = job.face_run(run, bar)
    finally:
        bar.close()
    report = job.report((time.perf_counter() - t0) * 1e3, run)
    if file is not None:
        cache_store(file, job.current.lower, job.current.upper, report)
    return job.current.lower, job.current.upper, report


@dataclasses.dataclass
class _Draws:
    """The certificate run's samples with their random draws: path
    parameter s (n,), whether each is a clamp's landing (n,), the unit
    draws U (n, k) (a uniform sample's coordinates in the box; a clamp's
    push amounts), a clamp's pushed joints and sides (n, k) bool (for a
    sample that is not a clamp's: the joint it holds on a bound, if any,
    and which bound: a face sample), and the configuration Q (n, k) they
    map to in the current box."""

    s: np.ndarray
    clamp: np.ndarray
    U: np.ndarray
    pushed: np.ndarray
    up: np.ndarray
    Q: np.ndarray

    @classmethod
    def empty(cls, k: int) -> "_Draws":
        z = np.zeros((0, k))
        return cls(np.zeros(0), np.zeros(0, bool), z, z.astype(bool), z.astype(bool), z.copy())

    def _arrays(self):
        return [getattr(self, f.name) for f in dataclasses.fields(self)]

    def joined(self, other: "_Draws") -> "_Draws":
        return _Draws(*(np.concatenate([a, b]) for a, b in zip(self._arrays(), other._arrays())))

    def without(self, rows) -> "_Draws":
        keep = np.ones(len(self.s), bool)
        keep[rows] = False
        return _Draws(*(a[keep] for a in self._arrays()))

    def mapped(self, rows, lo, hi, nom) -> np.ndarray:
        """The configurations the draws of ``rows`` give in the boxes
        [lo, hi] at nominals nom (each (len(rows), k)): a uniform draw
        lo + U (hi - lo), a face sample's joint on its bound exactly, a
        clamp's landing by :func:`_clamp_q`."""
        pushed, up = self.pushed[rows], self.up[rows]
        inside = lo + self.U[rows] * (hi - lo)
        return np.where(
            self.clamp[rows, None],
            _clamp_q((pushed, up, self.U[rows]), lo, hi, nom),
            np.where(pushed, np.where(up, hi, lo), inside),
        )

    @property
    def face(self) -> np.ndarray:
        """(n,) the face samples."""
        return ~self.clamp & self.pushed.any(axis=1)

    def counts(self) -> tuple[int, int]:
        """(uniform samples, clamp samples)."""
        nc, nf = int(self.clamp.sum()), int(self.face.sum())
        return len(self.s) - nc - nf, nc


class _Certification:
    """One certification's state: the waypoint boxes being cut (in place),
    the stretches' margins, the sample stream and the counts."""

    def __init__(self, workcell, arrays, table, certify: Certify):
        self.workcell, self.arrays, self.table, self.certify = workcell, arrays, table, certify
        nominal, rate = table.nominal, table.rate
        self.nominal = nominal
        self.rate = np.full(nominal.shape[1], np.inf) if rate is None else rate
        self.g = nominal.shape[0]
        self.lower, self.upper = rate_limited(
            *within_stretches(table.lower, table.upper, nominal, table.stretch_lower, table.stretch_upper),
            nominal,
            self.rate,
        )
        self.clearance = float(table.params.get("clearance", 0.0) or 0.0)
        self.margins = stretch_margins(arrays, nominal, self.clearance)
        self.point_slacks = cut_slacks(arrays, nominal, self.margins, _POINT_SLACK)
        self.rng = certification_rng(certify.seed)
        self.N, self.Nc = certify.n_samples, certify.n_clamp_samples
        self.face_rng = certification_rng(certify.seed, _FACE_STREAM)
        self.samples = self.shrinks = 0
        self.proven: dict = {}
        self.memo: dict = {}
        self.boundary = BoundaryFigures()
        self.start_lower, self.start_upper = self.lower.copy(), self.upper.copy()  # before any cut
        self.current = certified_table(table, self.lower, self.upper)

    def _stretch_of(self, s):
        return np.minimum(np.floor(s).astype(int), self.g - 2)

    def flagged(self, s, Q) -> np.ndarray:
        """Indices of the samples that may collide or come nearer than
        their stretch's margin."""
        pads = self.margins[self._stretch_of(s)]
        out = np.zeros(len(Q), bool)
        for p in np.unique(pads):
            sel = pads == p
            out[sel] = self.arrays.may_collide(Q[sel], p)
        return np.flatnonzero(out)

    def refresh(self):
        """Rate-limits the waypoint boxes again and remakes the table."""
        self.lower[:], self.upper[:] = rate_limited(self.lower, self.upper, self.nominal, self.rate)
        self.current = certified_table(self.table, self.lower.copy(), self.upper.copy())

    def cut(self, s, Q, flagged):
        """Cuts the flagged samples away: those on a bound as points, the
        others by the greedy cut."""
        sf = s[flagged]
        i = self._stretch_of(sf)
        t = sf - i
        X = Q[flagged]
        # Samples on a bound (where a clamp lands) are cut as points: a cut
        # just below them would barely move the bound they sit on.
        T = t[:, None]
        lo = (1 - T) * self.lower[i] + T * self.lower[i + 1]
        hi = (1 - T) * self.upper[i] + T * self.upper[i + 1]
        nom = (1 - T) * self.nominal[i] + T * self.nominal[i + 1]
        on_bound = (((X == lo) | (X == hi)) & (X != nom)).any(axis=1)
        taken: set = set()
        for st in np.unique(i[on_bound]):
            rows = np.flatnonzero(on_bound & (i == st))
            for r in rows[:: max(1, len(rows) // _POINT_CUTS)][:_POINT_CUTS]:
                cut_point(
                    self.workcell,
                    self.arrays,
                    self.lower,
                    self.upper,
                    self.nominal,
                    self.rate,
                    int(st),
                    float(sf[r]),
                    X[r],
                    float(self.margins[st]),
                    float(self.point_slacks[st]),
                    taken,
                )
        self.shrinks += len(taken)
        keep = ~on_bound
        self._cut_inner(X[keep], i[keep], t[keep])

    def _cut_inner(self, X, i, t):
        # Only joints whose motion reaches the colliding pair may cut a sample
        # (Drake's nearest pair at it): a bare flange is not pinched for a
        # collision of the forearm.
        allowed = np.ones(X.shape, bool)

        def reach(r, st):
            return reaching_joints(self.workcell, self.arrays, X[r], float(self.margins[st]))

        for st in np.unique(i):
            rows = np.flatnonzero(i == st)
            if len(rows) <= _REACH_QUERIES:
                allowed[rows] = [reach(r, st) for r in rows]
            else:  # many samples: the joints reaching any of a few of them
                pick = rows[:: len(rows) // _REACH_QUERIES][:_REACH_QUERIES]
                allowed[rows] = np.any([reach(r, st) for r in pick], axis=0)
        for st in np.unique(i):
            sel = i == st
            n = _greedy_cut(X[sel], t[sel], self.lower, self.upper, self.nominal, st, allowed[sel])
            if n < 0 and self.margins[st] > 0:
                # The nominal itself comes nearer than this stretch's margin
                # between the points stretch_margins looked at: lower it.
                self.margins[st] = 0.5 * self.margins[st] if self.margins[st] > 1e-4 else 0.0
                continue
            if n < 0:
                raise ParameterError(
                    f"certification: a configuration at the nominal of stretch {st} may collide; the path is not "
                    "collision-free between waypoints (plan with a finer max_step)."
                )
            self.shrinks += n

    def prove(self):
        """The boundary proof (when asked), from where it stopped last."""
        if not self.certify.boundary:
            return
        stats = prove_boundary(
            self.workcell,
            self.arrays,
            self.lower,
            self.upper,
            self.nominal,
            self.rate,
            self.margins,
            self.proven,
            memo=self.memo,
        )
        b = self.boundary
        b.edge_tests += stats["edge_tests"]
        b.edge_cuts += stats["edge_cuts"]
        b.edge_rounds += stats["edge_rounds"]
        b.margins_lowered += stats["margins_lowered"]
        b.unproven = list(stats["unproven"])
        self.refresh()

    def regrow(self, share: float = 0.5) -> int:
        """After the cuts: each bound that was cut widens back by ``share``
        of what it lost where the stretches on both sides of its waypoint
        stay proven (every edge of their boxes by the region test, so every
        corner too), as far as the rate limit allows; one pass over the bounds,
        in waypoint order. Cuts are chosen one failing region at a time and
        never revisited: this gives back what a later cut made unneeded.
        The certificate's samples run again afterwards. Returns how many
        bounds widened."""
        if not (self.certify.regrow and self.certify.boundary) or self.g < 2:
            return 0
        g, k = self.nominal.shape
        grown = 0
        for w in range(g):
            stretches = [st for st in (w - 1, w) if 0 <= st < g - 1]
            for j in range(k):
                for side, now, start in ((1, self.upper, self.start_upper), (-1, self.lower, self.start_lower)):
                    gap = side * (start[w, j] - now[w, j])
                    if gap <= 1e-9:
                        continue
                    step = min(share * gap, self._rate_room(w, j, side))
                    if step <= 1e-9:
                        continue
                    grown += self._widen_if_proven(w, j, side, step, stretches)
        if grown:
            self.refresh()
        self.boundary.regrown += grown
        return grown

    def _rate_room(self, w: int, j: int, side: int) -> float:
        """How far bound (w, j) on ``side`` may widen before it differs from
        a neighbouring waypoint's by more than the rate limit."""
        now = self.upper if side > 0 else self.lower
        near = [x for x in (w - 1, w + 1) if 0 <= x < self.g]
        return float((side * (now[near, j] - now[w, j]) + self.rate[j]).min()) if near else math.inf

    def _widen_if_proven(self, w: int, j: int, side: int, step: float, stretches: list) -> bool:
        """Widens bound (w, j) on ``side`` by ``step`` if every edge of the
        ``stretches`` beside it is then proven (the region tests, counted);
        whether it did."""
        lower, upper = self.lower.copy(), self.upper.copy()
        (upper if side > 0 else lower)[w, j] += side * step
        failed, tests = failures(self.arrays, lower, upper, self.nominal, stretches, self.margins, self.memo)
        self.boundary.edge_tests += tests
        if failed:
            return False
        self.lower[:], self.upper[:] = lower, upper
        return True

    def search(self, stretches, per, clamp=None) -> int:
        """One edge-biased search round, ``per`` samples in each of the
        stretches, every colliding sample cut. Returns how many collided."""
        rng, N, Nc = self.rng, self.N, self.Nc
        s = np.repeat(stretches, per) + rng.random(len(stretches) * per)
        lo, hi, nom = self.current.boxes_at(s)
        # Edge-biased in the box, and where a clamp lands in the share the
        # certificate run draws them.
        Q = lo + _edge_biased(rng, lo.shape, self.certify.edge_share) * (hi - lo)
        h = len(s) - int(round(len(s) * (Nc / (N + Nc) if clamp is None else clamp)))
        Q[h:] = clamp_draws(rng, lo[h:], hi[h:], nom[h:])
        flagged = self.flagged(s, Q)
        self.samples += len(Q)
        if len(flagged):
            self.cut(s, Q, flagged)
            self.refresh()
        return len(flagged)

    def search_rounds(self, bar):
        """Search: stratified over the stretches, edge-biased, every
        colliding sample of a round cut at once."""
        per = self.certify.batch
        budget = self.certify.search_factor * self.N  # a search much longer than the certificate buys nothing
        for _ in range(self.certify.search_rounds):
            per = min(per, int(budget // (self.g - 1)))
            if per < 1:
                break
            budget -= per * (self.g - 1)
            self.search(np.arange(self.g - 1), per)
            per *= 2
            bar.update(1)

    def certificate_run(self, bar, run: "_Draws | None" = None, recheck: np.ndarray | None = None):
        """N free samples of the whole path uniform in the box at s and,
        drawn alongside, Nc where a clamp lands (see :class:`_Draws`).

        A colliding sample is cut (its stretch searched again and the
        boxes proven again, as in the search), and it leaves the run. The
        other samples stay: each keeps its random draws, which map to its
        configuration in the cut box (a uniform draw lo + u (hi - lo), a
        clamp's push by the same amount), so it is still an exact draw of
        the cut box's distribution; the cut was chosen from other draws,
        so it is independent of them. Those whose configuration moved are
        checked again. So a cut costs the samples of the stretches it
        changed, not the run (the earlier rule restarted it). ``run``,
        ``recheck``: a run to carry on, and its samples to check first."""
        rng, N, Nc = self.rng, self.N, self.Nc
        k = self.nominal.shape[1]
        run = _Draws.empty(k) if run is None else run
        batch = max(1, N // 64)
        share = Nc / N  # clamp draws per uniform draw
        while True:
            n_u, n_c = run.counts()
            if recheck is not None and len(recheck):
                # A run carried on: its samples that moved are checked first.
                run, recheck = self._settle(run, recheck, bar), None
                continue
            if n_u >= N and n_c >= Nc:
                break
            n = min(batch, N - n_u)
            nc = min(Nc - n_c, int(math.ceil(batch * share)))
            batch = min(2 * batch, max(1, N // 4))
            s = rng.uniform(0.0, self.g - 1, n + nc)
            lo, hi, nom = self.current.boxes_at(s)
            U = rng.random((n, k))
            clamp = _clamp_uniforms(rng, (nc, k))
            new = _Draws(
                s,
                np.r_[np.zeros(n, bool), np.ones(nc, bool)],
                np.concatenate([U, clamp[2]]),
                np.concatenate([np.zeros((n, k), bool), clamp[0]]),
                np.concatenate([np.zeros((n, k), bool), clamp[1]]),
                np.empty((n + nc, k)),
            )
            new.Q[:] = new.mapped(slice(None), lo, hi, nom)
            run = run.joined(new)
            run = self._settle(run, np.arange(len(run.s) - len(s), len(run.s)), bar)
        return run

    def _settle(self, run: "_Draws", check: np.ndarray, bar) -> "_Draws":
        """Checks the run's samples ``check``: a colliding one is cut (its
        stretch searched again and the boxes proven again, as in the
        search), and it leaves the run; the samples the cuts moved are
        checked again. Returns the run left."""
        certify, N = self.certify, self.N
        while len(check):
            flagged = check[self.flagged(run.s[check], run.Q[check])]
            self.samples += len(check)
            if not len(flagged):
                break
            before = self.lower.copy(), self.upper.copy()
            self.cut(run.s, run.Q, flagged)
            self.refresh()
            # The stretches that still collide get a search of their own
            # (cheaper than another run over the whole path), from the
            # distribution that collided: a clamp's landing has
            # neighbours on the same bound.
            hit = np.unique(self._stretch_of(run.s[flagged]))
            focus = max(1, min(certify.focus_samples, N))
            clamp_share = 0.5 if run.clamp[flagged].any() else None
            for _ in range(certify.focus_rounds):
                if not self.search(hit, focus, clamp_share):
                    break
            self.prove()
            run = run.without(flagged)
            check = self._moved(run, *before)
        bar.set(certify.search_rounds + min(run.counts()[0], N), cuts=self.shrinks + self.boundary.edge_cuts)
        return run

    def unstarve(self, run: "_Draws", bar) -> "_Draws":
        """Gives a starved joint its room back: where the cuts left a joint
        under the bisection delta at a waypoint though its box before the
        cuts had over 10 delta there, the joint alone widens on one side by
        the largest of 1/2, 1/4, 1/8 of what that side lost, or delta (at
        least delta, and within the rate limit of the neighbouring waypoints) at
        which both stretches beside the waypoint stay proven (every edge by
        the region tests, so every corner). The run's samples it moved are
        checked again and the run carried on to N free (a collision is cut
        as in the run). Cuts go one failing region at a time and may take a
        joint's whole width for what another joint's later cut clears.
        Returns the run."""
        if not self.certify.boundary or self.g < 2:
            return run
        params = self.table.params
        delta = np.where(
            np.asarray(self.workcell.revolute, bool),
            float(params.get("delta", 0.0) or 0.0),
            float(params.get("delta_prismatic", 0.0) or 0.0),
        )
        starved = (self.upper - self.lower < delta) & (self.start_upper - self.start_lower > 10 * delta)
        if not starved.any():
            return run
        before = self.lower.copy(), self.upper.copy()
        grown = 0
        for w, j in zip(*np.nonzero(starved)):
            stretches = [st for st in (w - 1, w) if 0 <= st < self.g - 1]
            for side, now, start in ((1, self.upper, self.start_upper), (-1, self.lower, self.start_lower)):
                gap = side * (start[w, j] - now[w, j])
                room = self._rate_room(w, j, side)
                steps = sorted({min(share * gap, room) for share in (0.5, 0.25, 0.125)} | {delta[j]}, reverse=True)
                if any(
                    self._widen_if_proven(w, j, side, step, stretches)
                    for step in steps
                    if delta[j] <= step <= min(gap, room)
                ):
                    grown += 1
                    break
        if not grown:
            return run
        self.boundary.unstarved += grown
        self.refresh()
        return self.certificate_run(bar, run, self._moved(run, *before))

    def face_run(self, run: "_Draws", bar) -> "_Draws":
        """Nc free samples on the box's faces, beside the run's: s uniform,
        one joint (uniform) on one of its two bounds (either, 1/2), the
        others uniform in the box at s; from a stream of their own, drawn
        after the run. A steady push on one joint lands on a face, which
        has no volume: the uniform samples never hold a joint on a bound.
        A colliding face sample is cut as a point (as in the run) and the
        run carried on until every kind holds its count free. Returns the
        run."""
        rng, Nf, k = self.face_rng, self.Nc, self.nominal.shape[1]
        batch = max(1, Nf // 8)
        while True:
            have = int(run.face.sum())
            if have >= Nf:
                n_u, n_c = run.counts()
                if n_u >= self.N and n_c >= self.Nc:
                    return run
                run = self.certificate_run(bar, run)  # a cut took some of the run's samples
                continue
            n = min(batch, Nf - have)
            s = rng.uniform(0.0, self.g - 1, n)
            U = rng.random((n, k))
            joint = rng.integers(0, k, n)
            up = rng.random(n) < 0.5
            pushed = np.zeros((n, k), bool)
            pushed[np.arange(n), joint] = True
            new = _Draws(s, np.zeros(n, bool), U, pushed, pushed & up[:, None], np.empty((n, k)))
            new.Q[:] = new.mapped(slice(None), *self.current.boxes_at(s))
            run = run.joined(new)
            run = self._settle(run, np.arange(len(run.s) - n, len(run.s)), bar)

    def _moved(self, run: "_Draws", lower, upper) -> np.ndarray:
        """The run's samples whose configuration the cuts since the boxes
        (lower, upper) moved, re-mapped into the current boxes (in place);
        their indices."""
        changed = np.flatnonzero(
            np.any((self.lower != lower) | (self.upper != upper), axis=1)
        )  # waypoints; a stretch changes with either end
        st = self._stretch_of(run.s)
        rows = np.flatnonzero(np.isin(st, changed) | np.isin(st + 1, changed))
        if not len(rows):
            return rows
        Q = run.mapped(rows, *self.current.boxes_at(run.s[rows]))
        moved = np.any(Q != run.Q[rows], axis=1)
        run.Q[rows[moved]] = Q[moved]
        return rows[moved]

    def report(self, time_ms: float, run: "_Draws | None" = None) -> "CertificateReport":
        """The report, in words; ``run`` the certificate run's samples."""
        certify, clearance, margins, boundary = self.certify, self.clearance, self.margins, self.boundary
        margin = (
            f"{clearance * 1e3:g} mm from the obstacles and the robot itself (less only where the nominal "
            f"itself is nearer: {int((margins < clearance).sum())} of {len(margins)} stretches)"
            if clearance > 0
            else "free of collision with the obstacles and the robot itself (clearance 0)"
        )
        unproven = boundary.unproven
        single = (
            "Every single-joint motion from the nominal to that joint's bound, at every s along the path, "
            f"keeps {margin} and the volume."
        )
        if not certify.boundary:
            proven = single + (
                " The box's edges and corners are NOT proven (Certify(boundary=False) asked for the "
                "sampled certificate only); the runtime safety filter keeps the margin where a clamp "
                "lands."
            )
        elif not unproven:
            proven = single + (
                " So does every edge of the box (one joint over its whole width, every other joint at "
                "one of its bounds), and so every corner, at every s: the kernel's region tests "
                f"({boundary.edge_tests} regions)."
            )
        else:
            proven = single + (
                " So does every edge and corner of the box at every s except on stretches "
                f"{unproven}, where the proof ran out of rounds."
            )
        share = self.proven_share(run)
        sampled = (
            f"Of where the run's clamps landed, a share {share:.3f} lies where the proofs above hold; "
            f"the faces and the interior, all joints at once, sampled from three distributions (s uniform over "
            f"the path): {self.N} samples uniform in the box at s, and alongside them {self.Nc} "
            "samples where a clamp lands (the nominal pushed on a random half of its joints, "
            f"clamped into the box, so about half of the pushed joints on a bound) and {self.Nc} on the "
            "box's faces (one joint on one of its bounds, the others uniform), all kept the margin; "
            "each an exact draw of the certified box's distribution, independent of the cuts (a cut keeps "
            "the run's other samples, their draws mapped into the cut box, and checks again those that "
            "moved). So "
            f"with probability {certify.confidence:g} at most a share {certify.epsilon:g} of the uniform "
            f"configurations comes nearer (about {certify.epsilon * 3e5:g} of 300,000), and at most a share "
            f"{certify.clamp_share:g} of the clamp's, and of the faces'. Beyond the box, the runtime safety "
            "filter keeps the "
            "margin."
        )
        return CertificateReport(
            certify.epsilon,
            certify.confidence,
            self.N,
            time_ms,
            self.samples,
            self.shrinks + boundary.edge_cuts,
            freedom(self.table).mean,
            freedom(self.current).mean,
            proven,
            sampled,
            clearance_m=clearance,
            boundary=dataclasses.replace(boundary, unproven=list(boundary.unproven)),
            proven_share=share,
        )

    def proven_share(self, run: "_Draws | None") -> float:
        """The share of the run's clamp landings that lie where a proof
        holds: at most one joint off the nominal (a single-joint motion) or,
        with the boundary proof (all of it proven), at most one joint off
        its bounds (an edge or a corner). 0 without a run."""
        if run is None or not run.clamp.any():
            return 0.0
        Q = run.Q[run.clamp]
        lo, hi, nom = self.current.boxes_at(run.s[run.clamp])
        single = (Q != nom).sum(axis=1) <= 1
        edge = ((Q != lo) & (Q != hi)).sum(axis=1) <= 1
        proven_edges = self.certify.boundary and not self.boundary.unproven
        return float(np.mean(single | (edge & proven_edges)))
