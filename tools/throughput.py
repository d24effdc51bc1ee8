"""Configurations per second: the kernel's public batch check
(``Workcell.collision_free``) against Drake's ``SceneGraphCollisionChecker``
(2 threads) on the same samples, drawn uniformly from the boxes of a path's
bounds (where a planner or a certificate samples). Medians over repeats,
and their ratio, measured in one run (the first part of ``cfvol bench
--kernel``, benchmarks/kernel.py).

    python tools/throughput.py [--samples 100000] [--repeats 5]
"""

import argparse

import drake_cfvol as cf
from drake_cfvol.apps.cli import bench_harness

throughput = bench_harness("kernel").throughput

CASES = (("automotive", "path1"), ("aerospace", "path2"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=100_000)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    for cell, label in CASES:
        wc = cf.load_workcell(cell)
        table = cf.estimate_bounds(wc, cf.plan_nominal_path(wc, *wc.configuration(label), seed=0), resolution=1000)
        r = throughput(wc, table, args.samples, args.repeats)
        print(
            f"{cell} {label}: kernel {r['kernel_per_s']:,.0f}/s, Drake {r['drake_per_s']:,.0f}/s, ratio "
            f"{r['ratio']:.1f}x, forward kinematics alone {r['fk_per_s']:,.0f}/s (medians of {args.repeats}; "
            f"{r['samples']:,} samples, {r['colliding']:,} colliding, {r['wrong']} called free where Drake collides)"
        )


if __name__ == "__main__":
    main()
