"""The control-rate benchmark (benchmarks/realtime.py) on a tiny run: its
figures are consistent with the run they come from (no timing is asserted)."""

import numpy as np
import pytest

from benchmarks.realtime import RealtimeBenchConfig, realtime_markdown, realtime_targets, run_realtime_bench


@pytest.fixture(scope="module")
def tiny():
    cfg = RealtimeBenchConfig(cells=["automotive"], periods=[0.001], pushes=["steady"], updates=40, repeats=1)
    return run_realtime_bench(cfg, progress=False)


def test_rows_are_consistent(tiny):
    """One row per (cell, period, push, seed); median <= p99 <= max of the
    step times; each system's own time is at most the step's; the filter
    measured at most its pairs and kept the velocity limits."""
    (row,) = tiny["runs"]
    assert row["steps"] == 40 and row["period_s"] == 0.001 and row["push"] == "steady"
    assert 0 < row["median_s"] <= row["p99_s"] <= row["max_s"]
    assert set(row["per_system"]) >= {"safety filter", "admittance", "bounds", "input check"}
    assert sum(s["median_s"] for s in row["per_system"].values()) <= row["max_s"]
    assert 0 <= row["distance_pairs_per_update"] <= row["num_pairs"]
    assert row["max_velocity_ratio"] <= 1.0 and np.isfinite(row["min_distance_m"])


def test_targets_and_markdown(tiny):
    """A target line per 1 ms (cell, push), met iff both figures are within
    the targets; the table has a line per summary row."""
    ((name, met, text),) = realtime_targets(tiny)
    s = tiny["summary"][0]
    assert met == (s["median_s"] <= 0.5e-3 and s["p99_s"] <= 1e-3) and "automotive steady" in name
    md = realtime_markdown(tiny)
    assert md.count("| automotive | 1 ms | steady |") == 1
