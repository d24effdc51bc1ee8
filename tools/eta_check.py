#!/usr/bin/env python3
"""Measures how right the progress bars' time-left estimates are.

Runs each long step with its bar enabled (drawn only on a terminal; the
history is kept either way) and prints, per bar, the relative error of the
time left it showed at 25 %, 50 % and 75 % of the step's duration
(drake_cfvol.io.progress.eta_errors). Usage:

    tools/dev.sh python tools/eta_check.py [--skip-bench] [--compile]

``--compile`` adds the kernel's first compile, on an empty numba cache in a
fresh process (about a minute on 2 cores), and prints each compile step's
seconds: the measured shares of drake_cfvol.kernel.warmup.STEP_SHARES.
"""

import argparse
import json
import tempfile
import time

import drake_cfvol as cf
from drake_cfvol.apps.cli import bench_harness
from drake_cfvol.comanip import run_scenario
from drake_cfvol.io import progress

BenchConfig, run_bench = bench_harness().BenchConfig, bench_harness().run_bench


fresh_compile = bench_harness("kernel").fresh_compile


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--skip-bench", action="store_true", help="skip bench --quick (about a minute)")
    ap.add_argument("--compile", action="store_true", help="also the kernel's first compile (about a minute)")
    ap.add_argument("--compile-only", action="store_true", help="only the kernel's first compile")
    args = ap.parse_args()
    results = {}
    if args.compile or args.compile_only:
        run = fresh_compile()
        results["compile"] = {
            "seconds": round(run["seconds"], 2),
            "steps_s": run["steps_s"],
            "eta_error_percent": {f: round(100 * e, 1) for f, e in run["eta_error"].items()},
        }
        print(f"kernel compile: {run['seconds']:.1f} s", flush=True)
        if args.compile_only:
            print(json.dumps(results, indent=1))
            return

    def record(name, fn):
        t0 = time.perf_counter()
        fn()
        wall = time.perf_counter() - t0
        for desc, hist in progress.finished():
            if desc not in results and hist:
                errs = progress.eta_errors(hist)
                results[desc] = {
                    "step": name,
                    "seconds": round(hist[-1][0], 2),
                    "eta_error_percent": {f"{int(100 * f)}%": round(100 * e, 1) for f, e in errs.items()},
                }
        print(f"{name}: {wall:.1f} s", flush=True)

    wc = cf.load_workcell("automotive")
    path = cf.plan_nominal_path(wc, *wc.configuration("path1"), seed=0, label="path1")
    record(
        "bounds --backend drake (automotive path 1, R = 1000)",
        lambda: cf.estimate_bounds(wc, path, resolution=1000, backend="drake", progress=True),
    )
    table = cf.estimate_bounds(wc, path, resolution=1000)
    record("CF, 30 x 10000 samples", lambda: cf.confidence_factor(wc, table, seed=0, progress=True))
    with tempfile.TemporaryDirectory() as d:
        record(
            "simulate aerospace_push",
            lambda: run_scenario("aerospace_push", d, record=False, plot=False, svg=False, progress=True),
        )
    if not args.skip_bench:
        with tempfile.TemporaryDirectory():
            record("bench --quick", lambda: run_bench(BenchConfig.quick(), progress=True))
    print(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
