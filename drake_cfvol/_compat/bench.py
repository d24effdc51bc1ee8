"""Old name of the benchmark harness, now ``benchmarks/harness.py`` of a
development checkout (:func:`drake_cfvol.apps.cli.bench_harness`)."""
import sys

from drake_cfvol.apps.cli import bench_harness

sys.modules[__name__] = bench_harness()
