"""Certified bounds: a sampled safety certificate for the whole box.

The paper's bounds are per-joint extents found with the other joints at
nominal; moving several joints at once can still collide. Certification
shrinks the boxes until, for every stretch [i, i+1] of the path, a run of N
consecutive samples drawn as the Confidence Factor draws them (s uniform in
the stretch, q uniform in the box at s, SPEC 7) is free of collision with
the real scene (Drake). With N >= ln(1 / (1 - confidence)) / epsilon, the
standard sampled test (also used by Drake's IrisZo): if the colliding share
of a stretch's sampling distribution were at least epsilon, N free samples in
a row would occur with probability at most 1 - confidence.

When a sample collides, the segment from the nominal to it is scanned for
where the collision begins, and the one bound that excludes that point at the
least loss of freedom (log of the joint's width) is moved to it, at both
waypoints of the stretch, and every stretch whose box changed runs again from zero; the loop
ends when a full pass changes nothing. Certification draws from a seed
stream of its own, distinct from the CF evaluation's.
"""

import dataclasses
import math
import time

import numpy as np

from drake_cfvol.exceptions import ParameterError
from drake_cfvol.metrics import freedom
from drake_cfvol.table import box_at, waypoint_boxes

__all__ = ["Certify", "CertificateReport", "certify_bounds", "certification_rng"]

#: Spawn key that separates certification draws from CF draws of the same seed.
_CERT_STREAM = 0xCE27


@dataclasses.dataclass(frozen=True)
class Certify:
    """Certificate settings.

    Attributes:
        epsilon: the largest colliding share allowed, in (0, 1).
        confidence: probability that the certificate is right, in (0, 1).
        seed: seed of the certification samples (a stream distinct from CF's).
        batch: samples checked per Drake call.
    """

    epsilon: float = 1e-3
    confidence: float = 0.99
    seed: int = 0
    batch: int = 512

    def __post_init__(self):
        for name in ("epsilon", "confidence"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and 0.0 < v < 1.0):
                raise ParameterError(f"Certify: {name} must lie in (0, 1), got {v!r}.")
        if self.batch < 1:
            raise ParameterError(f"Certify: batch must be >= 1, got {self.batch}.")

    @property
    def n_samples(self) -> int:
        """N = ceil(ln(1 / (1 - confidence)) / epsilon)."""
        return int(math.ceil(math.log(1.0 / (1.0 - self.confidence)) / self.epsilon))


@dataclasses.dataclass
class CertificateReport:
    """What certification did.

    Attributes:
        epsilon, confidence, n_samples: the certificate.
        time_ms: time spent certifying.
        samples: samples checked in all.
        shrinks: bounds moved.
        freedom_before, freedom_after: mean freedom (SPEC 8).
    """

    epsilon: float
    confidence: float
    n_samples: int
    time_ms: float
    samples: int
    shrinks: int
    freedom_before: float
    freedom_after: float

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


def certification_rng(seed: int) -> np.random.Generator:
    """The certification sampler (distinct from CF's ``default_rng(seed)``)."""
    return np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(_CERT_STREAM,)))


def certify_bounds(workcell, table, certify: Certify, *, checker=None):
    """Shrinks a bounds table's boxes until every stretch holds the sampled
    certificate.

    Returns:
        (stretch_lower, stretch_upper, CertificateReport): the certified
        stretch boxes (the waypoint boxes follow from them,
        :func:`drake_cfvol.table.waypoint_boxes`); the input table is not
        changed.
    """
    checker = checker or workcell.checker
    t0 = time.perf_counter()
    lower, upper, nominal = table.lower, table.upper, table.nominal
    st_lower, st_upper, rate = table.stretch_lower.copy(), table.stretch_upper.copy(), table.rate
    g = table.g
    trajectory = table.trajectory
    rng = certification_rng(certify.seed)
    N = certify.n_samples
    dirty = np.ones(max(g - 1, 0), bool)
    samples = 0
    shrinks = 0
    while dirty.any():
        for i in np.flatnonzero(dirty):
            run = 0
            while run < N:
                n = min(certify.batch, N - run)
                s = rng.uniform(i, i + 1, n)
                lo, hi, nom = box_at(lower, upper, nominal, s, stretch_lower=st_lower, stretch_upper=st_upper,
                                     rate=rate, trajectory=trajectory)
                Q = lo + rng.random(lo.shape) * (hi - lo)
                free = np.array(checker.CheckConfigsCollisionFree(Q, parallelize=True), bool)
                if free.all():
                    samples += n
                    run += n
                    continue
                first = int(np.argmin(free))
                samples += first + 1
                qn = nom[first]
                # Walk back from the sample towards the (free) nominal to where
                # the collision begins: cutting there removes the colliding
                # region around the sample, not just the sample.
                d = Q[first] - qn
                ts = np.linspace(0.0, 1.0, 17)[1:]
                line_free = np.array(checker.CheckConfigsCollisionFree(qn + ts[:, None] * d, parallelize=True), bool)
                samples += len(ts)
                t_hit = ts[int(np.argmin(line_free))] if not line_free.all() else 1.0
                q = qn + t_hit * d
                # The cut that excludes q at the least loss of log-width.
                best = None
                for j in range(table.k):
                    if q[j] > qn[j]:
                        old, new = hi[first, j] - lo[first, j], q[j] - lo[first, j]
                        side = "upper"
                    elif q[j] < qn[j]:
                        old, new = hi[first, j] - lo[first, j], hi[first, j] - q[j]
                        side = "lower"
                    else:
                        continue
                    if new <= 0 or old <= 0:
                        continue
                    loss = math.log(old / new)
                    if best is None or loss < best[0]:
                        best = (loss, j, side)
                if best is None:  # q == nominal: the nominal itself collides.
                    raise ParameterError(
                        f"certification: the nominal at s = {s[first]:.4f} collides; the path is not "
                        "collision-free between waypoints (plan with a finer max_step).")
                _, j, side = best
                if side == "upper":
                    st_upper[i, j] = min(st_upper[i, j], q[j])
                else:
                    st_lower[i, j] = max(st_lower[i, j], q[j])
                shrinks += 1
                run = 0
                for stretch in (i - 1, i + 1):
                    if 0 <= stretch < g - 1:
                        dirty[stretch] = True
            dirty[i] = False
    before = freedom(table).mean
    w_lower, w_upper = waypoint_boxes(st_lower, st_upper, nominal, rate)
    after_table = dataclasses.replace(table, lower=w_lower, upper=w_upper, stretch_lower=st_lower,
                                      stretch_upper=st_upper)
    after = freedom(after_table).mean
    report = CertificateReport(certify.epsilon, certify.confidence, N, (time.perf_counter() - t0) * 1e3,
                               samples, shrinks, before, after)
    return st_lower, st_upper, report
