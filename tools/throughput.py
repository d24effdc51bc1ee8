"""Configurations per second: the kernel's public batch check
(``Workcell.collision_free``) against Drake's ``SceneGraphCollisionChecker``
(2 threads) on the same samples, drawn uniformly from the boxes of a path's
bounds (where a planner or a certificate samples). Medians over repeats,
and their ratio, measured in one run.

    python tools/throughput.py [--samples 100000] [--repeats 5]
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

import drake_cfvol as cf

CASES = (("automotive", "path1"), ("aerospace", "path2"))


def samples_in_bounds(table, n: int, seed: int = 0) -> np.ndarray:
    """(n, k) configurations, uniform in the boxes at uniform path positions."""
    rng = np.random.default_rng(seed)
    lo, hi, _ = table.boxes_at(rng.uniform(0, table.g - 1, n))
    return lo + rng.random(lo.shape) * (hi - lo)


def rate(fn, Q, repeats: int) -> tuple[float, np.ndarray]:
    """(median configurations per second, the last answer)."""
    times, out = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn(Q)
        times.append(time.perf_counter() - t0)
    return len(Q) / statistics.median(times), out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=100_000)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    for cell, label in CASES:
        wc = cf.load_workcell(cell)
        table = cf.estimate_bounds(wc, cf.plan_nominal_path(wc, *wc.configuration(label), seed=0), resolution=1000)
        Q = samples_in_bounds(table, args.samples)
        wc.collision_free(Q[:100])  # compiled and warm
        kernel, free = rate(wc.collision_free, Q, args.repeats)
        drake, ok = rate(lambda X: np.array(wc.checker.CheckConfigsCollisionFree(X, parallelize=True), bool), Q,
                         args.repeats)
        wrong = int((free & ~ok).sum())
        print(f"{cell} {label}: kernel {kernel:,.0f}/s, Drake {drake:,.0f}/s, ratio {kernel / drake:.1f}x "
              f"(medians of {args.repeats}; {len(Q):,} samples, {int((~ok).sum()):,} colliding, "
              f"{wrong} called free where Drake collides)")


if __name__ == "__main__":
    main()
