"""Certified bounds: the whole box at every s, all joints at once.

The paper's bounds are per-joint extents, each found with the other joints
at nominal; moving several joints at once can still collide. What is
*proven* already (SPEC 6-7, by the kernel's region tests): every single-joint
motion from the nominal to its bound, at every s. Certification adds a
*sampled* guarantee for the whole box: it shrinks the stretch boxes until N
consecutive samples, drawn as the Confidence Factor draws them (s uniform
over the path, q uniform in the box at s), are all certified free by the
compiled kernel, which never calls a configuration free where Drake finds a
collision. With N >= ln(1 / (1 - confidence)) / epsilon (the test Drake's
IrisZo uses): if the colliding share of that distribution were epsilon or
more, N free samples in a row would occur with probability at most
1 - confidence.

A colliding sample is cut off as a region, not a point: each joint in turn
is swept from the sample back towards the nominal until the configuration
is free, and the one bound of the sample's stretch that excludes the sample
and the colliding region beyond it along that axis, at the least loss of
freedom (log of the joint's width), is moved there. Cuts only tighten, so the proven single-joint
safety still holds. Samples are drawn in growing batches; the count of
consecutive free samples restarts after every cut. Certification draws
from a seed stream of its own, distinct from the CF evaluation's.
"""

import dataclasses
import math
import time

import numpy as np

from drake_cfvol.exceptions import ParameterError
from drake_cfvol.metrics import freedom
from drake_cfvol.progress import Progress
from drake_cfvol.table import box_at, waypoint_boxes

__all__ = ["Certify", "CertificateReport", "certify_bounds", "certification_rng"]

#: Spawn key that separates certification draws from CF draws of the same seed.
_CERT_STREAM = 0xCE27
#: Points checked along the segment from the nominal to a colliding sample.
_LINE_STEPS = 16


@dataclasses.dataclass(frozen=True)
class Certify:
    """Certificate settings.

    Attributes:
        epsilon: the largest colliding share allowed, in (0, 1).
        confidence: probability that the certificate is right, in (0, 1).
        seed: seed of the certification samples (a stream distinct from CF's).
        batch: samples in the first batch (batches double up to N).
    """

    epsilon: float = 1e-5
    confidence: float = 0.99
    seed: int = 0
    batch: int = 20000

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
    """What certification did, in words and figures.

    Attributes:
        epsilon, confidence, n_samples: the sampled certificate.
        time_ms: time spent certifying.
        samples: samples checked in all.
        shrinks: bounds moved (cuts).
        freedom_before, freedom_after: mean freedom (SPEC 8).
        proven: what holds for certain.
        sampled: what the sampled certificate says.
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

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


def certification_rng(seed: int) -> np.random.Generator:
    """The certification sampler (distinct from CF's ``default_rng(seed)``)."""
    return np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(_CERT_STREAM,)))


def certify_bounds(workcell, table, certify: Certify, *, progress: bool = False):
    """Shrinks a bounds table's stretch boxes until N consecutive samples of
    the whole box are free (see the module docs).

    Returns:
        (stretch_lower, stretch_upper, CertificateReport): the certified
        stretch boxes (the waypoint boxes follow from them,
        :func:`drake_cfvol.table.waypoint_boxes`); the input table is not
        changed.

    With ``progress``, a bar on a terminal shows the run of consecutive
    free samples against N and the cuts so far; the run restarts after a
    cut, so the bar shows no time-left estimate.
    """
    t0 = time.perf_counter()
    arrays = workcell.scene_arrays()
    lower, upper, nominal, rate = table.lower, table.upper, table.nominal, table.rate
    st_lo, st_hi = table.stretch_lower.copy(), table.stretch_upper.copy()
    g, k = nominal.shape
    trajectory = table.trajectory
    rng = certification_rng(certify.seed)
    N = certify.n_samples
    ts = np.arange(1, _LINE_STEPS + 1) / _LINE_STEPS

    def boxes(s):
        return box_at(lower, upper, nominal, s, stretch_lower=st_lo, stretch_upper=st_hi, rate=rate,
                      trajectory=trajectory)

    samples = shrinks = run = 0
    batch = min(certify.batch, N)
    bar = Progress(N, "Certifying whole boxes", enabled=progress, unit="free samples in a row", eta=False)
    while run < N and g > 1:
        n = min(batch, N - run)
        s = rng.uniform(0.0, g - 1, n)
        lo, hi, _ = boxes(s)
        Q = lo + rng.random(lo.shape) * (hi - lo)
        flagged = np.flatnonzero(arrays.may_collide(Q))
        samples += n
        batch = min(2 * batch, N)
        if not len(flagged):
            run += n
            bar.set(run, cuts=shrinks)
            continue
        run = 0
        for m in flagged:
            lo_m, hi_m, nom_m = boxes(s[m])
            q = Q[m]
            if np.any(q < lo_m - 1e-12) or np.any(q > hi_m + 1e-12):
                continue  # an earlier cut already excluded it
            i = min(int(np.floor(s[m])), g - 2)
            # Sweep each joint from the sample back towards the nominal: how
            # far must it move for the configuration to be free? Cutting that
            # joint's bound there excludes the sample and the colliding region
            # beyond it along that axis.
            lines = np.repeat(q[None], k * _LINE_STEPS, axis=0).reshape(k, _LINE_STEPS, k)
            for j in range(k):
                lines[j, :, j] = q[j] + ts * (nom_m[j] - q[j])
            hits = arrays.may_collide(lines.reshape(-1, k)).reshape(k, _LINE_STEPS)
            samples += k * _LINE_STEPS
            best = None
            for j in range(k):
                if q[j] == nom_m[j] or hits[j].all():
                    continue
                cut = lines[j, int(np.argmin(hits[j])), j]
                if q[j] > nom_m[j]:
                    old, new, side = st_hi[i, j] - st_lo[i, j], cut - st_lo[i, j], "upper"
                else:
                    old, new, side = st_hi[i, j] - st_lo[i, j], st_hi[i, j] - cut, "lower"
                if old <= 0:
                    continue
                loss = math.log(old / max(new, 1e-12))
                if best is None or loss < best[0]:
                    best = (loss, j, side, cut)
            if best is None:
                # No single joint frees it: cut the joint whose bound moves least
                # in log-width all the way to the nominal at s.
                for j in range(k):
                    if q[j] == nom_m[j]:
                        continue
                    side = "upper" if q[j] > nom_m[j] else "lower"
                    old = st_hi[i, j] - st_lo[i, j]
                    new = (nom_m[j] - st_lo[i, j]) if side == "upper" else (st_hi[i, j] - nom_m[j])
                    loss = math.log(old / max(new, 1e-12)) if old > 0 else 0.0
                    if best is None or loss < best[0]:
                        best = (loss, j, side, nom_m[j])
            if best is None:
                raise ParameterError(
                    f"certification: the nominal at s = {s[m]:.4f} may collide; the path is not collision-free "
                    "between waypoints (plan with a finer max_step).")
            _, j, side, cut = best
            if side == "upper":
                st_hi[i, j] = min(st_hi[i, j], cut)
            else:
                st_lo[i, j] = max(st_lo[i, j], cut)
            shrinks += 1
        bar.set(0, cuts=shrinks)
    bar.close()
    w_lo, w_hi = waypoint_boxes(st_lo, st_hi, nominal, rate)
    before = freedom(table).mean
    after = freedom(dataclasses.replace(table, lower=w_lo, upper=w_hi, stretch_lower=st_lo,
                                        stretch_upper=st_hi)).mean
    proven = ("Every single-joint motion from the nominal to that joint's bound, at every s along the path, is "
              "free of the obstacles, the robot itself and the volume (the kernel's region tests).")
    sampled = (f"The whole box, all joints at once: {N} consecutive samples (s uniform over the path, q uniform in "
               f"the box at s) were all free, so with probability {certify.confidence:g} at most a share "
               f"{certify.epsilon:g} of such configurations collides (about {certify.epsilon * 3e5:g} of 300,000).")
    report = CertificateReport(certify.epsilon, certify.confidence, N, (time.perf_counter() - t0) * 1e3,
                               samples, shrinks, before, after, proven, sampled)
    return st_lo, st_hi, report
