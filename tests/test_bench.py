"""The benchmark harness (benchmarks/harness.py) on a tiny configuration."""

import csv
import json

import pytest

from benchmarks.harness import PAPER, BenchConfig, markdown, run_bench, write_outputs


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    cfg = BenchConfig(
        cells=["automotive"],
        paths=["path1"],
        resolutions=[100, 500],
        trials=2,
        cf_windows=3,
        cf_samples=100,
        reference_resolutions=[],
        iris=False,
        certify_resolutions=[],
        adversarial_runs=0,
        engine=False,
    )
    result = run_bench(cfg, progress=False)
    out = tmp_path_factory.mktemp("bench")
    return result, write_outputs(result, out)


def test_rows_hold_paper_and_ours(tiny):
    """Each row carries the paper's figures for its (cell, path, R) and ours,
    and paper / ours is the ratio of the two medians."""
    result, _ = tiny
    rows = result["rows"]
    assert [(r["cell"], r["path"], r["resolution"]) for r in rows] == [
        ("automotive", "path1", 100),
        ("automotive", "path1", 500),
    ]
    for r in rows:
        t, c = PAPER[("automotive", "path1")][r["resolution"]]
        assert r["paper_time_ms"] == t and r["paper_cf_percent"] == c
        assert r["paper_over_ours"] == pytest.approx(t / r["time_ms_median"])
        assert 0 < r["freedom"] <= 1 and 0 <= r["cf_percent"] <= 100 and r["g"] > 2


def test_trials_csv_has_every_trial(tiny):
    """trials.csv has one line per timed run; their median is the row's."""
    result, files = tiny
    with open(files["trials_csv"]) as f:
        lines = list(csv.DictReader(f))
    assert len(lines) == 4
    import numpy as np

    for r in result["rows"]:
        ts = [float(x["total_ms"]) for x in lines if int(x["resolution"]) == r["resolution"]]
        assert r["time_ms_median"] == pytest.approx(float(np.median(ts)))


def test_markdown_table_matches_rows(tiny):
    """The Markdown table prints the paper's time and our median per row."""
    result, files = tiny
    md = open(files["markdown"]).read()
    assert md == markdown(result)
    for r in result["rows"]:
        line = next(x for x in md.splitlines() if x.startswith(f"| {r['resolution']} | {r['g']} |"))
        cells = [c.strip() for c in line.strip("|").split("|")]
        assert cells[2] == f"{r['time_ms_median']:.0f}" and cells[3] == str(r["paper_time_ms"])
        assert float(cells[4]) == pytest.approx(r["paper_time_ms"] / r["time_ms_median"], abs=1e-3)
    assert json.load(open(files["machine"]))["cores"] >= 1
    assert open(files["plot_0"], "rb").read(4) == b"\x89PNG"


def test_step_plan_matches_the_run(tiny):
    """The progress clock's step list is the run's: every finished step was
    planned (else ``done`` would fail) and none is left over."""
    from benchmarks.harness import _bench_steps

    result, _ = tiny
    cfg = BenchConfig(**result["config"])
    kinds = [k for k, _ in _bench_steps(cfg)]
    assert kinds == [("plan",)] + ([("trial", 100)] * 2 + [("cf",)]) + ([("trial", 500)] * 2 + [("cf",)])
    assert set(result["progress"]["eta_error"]) <= {0.25, 0.5, 0.75}


def test_clock_uses_measured_time_of_a_kind(monkeypatch):
    """After one step of a kind has run, the steps left of that kind are
    estimated by its measured time, not by the prior."""
    import benchmarks.harness as B

    cfg = BenchConfig(
        cells=["automotive"],
        paths=["path1"],
        resolutions=[100],
        trials=3,
        cf_windows=1,
        cf_samples=1,
        reference_resolutions=[],
        iris=False,
        certify_resolutions=[],
        adversarial_runs=0,
        engine=False,
    )
    now = [100.0]
    monkeypatch.setattr(B.time, "perf_counter", lambda: now[0])
    clock = B._BenchClock(cfg, enabled=False, tick_s=3600)
    try:
        prior_trial = dict(B._bench_steps(cfg))[("trial", 100)]
        now[0] += 1.0
        clock.done(("plan",))
        now[0] += 2.0  # one trial took 2 s
        clock.done(("trial", 100))
        cf_prior = dict(B._bench_steps(cfg))[("cf",)]
        # spent 3 s; left: two trials of 2 s each and the CF's prior
        assert clock.bar.total == pytest.approx(3.0 + 2 * 2.0 + cf_prior)
        assert prior_trial != pytest.approx(2.0)
    finally:
        clock.close()


@pytest.mark.slow  # certifies the scenario's path (cached after the first run) and simulates 4 runs
def test_adversarial_suite_on_automotive():
    """One steady corner-seeking push per kind of bounds and filter setting:
    four runs; with the filter on nothing collides by Drake's checker and no
    joint ever moves faster than its limit; the certified boxes' corners and
    edge points are all free by Drake (the boundary proof), and the
    certified bounds are narrower than the uncertified ones."""
    from drake_cfvol.comanip.adversarial import adversarial_suite

    sec = adversarial_suite("automotive", 1, ["random"])
    rows = sec["rows"]
    assert sorted((r["certify"], r["safety_filter"]) for r in rows) == [
        (False, False),
        (False, True),
        (True, False),
        (True, True),
    ]
    for r in rows:
        if r["safety_filter"]:
            assert r["collisions"] == 0 and r["drake_colliding_updates"] == 0
            assert r["max_velocity_ratio"] <= 1.0 + 1e-9
    b = sec["boundary"]["certified"]
    assert b["corners"] > 0 and b["corners_colliding"] == 0 and b["edges_colliding"] == 0
    assert sec["freedom"]["certified"] < sec["freedom"]["uncertified"]
    assert {(s["certify"], s["safety_filter"]) for s in sec["summary"]} == {(c, f) for c in (0, 1) for f in (0, 1)}


def _section(corners_bad=0, collisions=0, ratio=0.9, kept=2):
    def summ(certify, on, dev):
        return {
            "cell": "automotive",
            "pattern": "random",
            "certify": certify,
            "safety_filter": on,
            "margin_m": 0.02,
            "runs": 2,
            "runs_with_collisions": collisions if on else 1,
            "runs_margin_kept": kept,
            "min_clearance_m": 0.019,
            "nominal_min_clearance_m": 0.05,
            "worst_shortfall_m": 0.001,
            "max_velocity_ratio": ratio,
            "filter_steps_median": 3.0,
            "median_mean_deviation": dev,
            "max_deviation": 0.4,
        }

    b = {
        "positions": 3,
        "corners": 192,
        "corners_colliding": corners_bad,
        "edge_points": 192,
        "edges_colliding": 0,
        "clearance": 0.019,
    }
    return {
        "cell": "automotive",
        "clearance_m": 0.02,
        "freedom": {"certified": 0.3, "uncertified": 0.5},
        "boundary": {"certified": b, "uncertified": dict(b, corners_colliding=50)},
        "summary": [summ(True, True, 0.1), summ(True, False, 0.2), summ(False, True, 0.15)],
        "rows": [],
    }


def test_adversarial_targets_by_hand():
    """The safety targets read met only when the certified corners and
    edges are all free and the filter-on corner-seeking runs neither collide
    nor lose the margin nor exceed a velocity limit; the filter's cost in
    deviation is the ratio of the two medians."""
    from benchmarks.harness import adversarial_markdown, adversarial_targets

    good = adversarial_targets([_section()])
    assert sum("-> met" in x for x in good) == 2 and not any("MISSED" in x for x in good)
    assert any("0.100 with the filter, 0.200 without (0.50x)" in x for x in good)
    assert "MISSED" in adversarial_targets([_section(corners_bad=1)])[0]
    for bad in (_section(collisions=1), _section(ratio=1.01), _section(kept=1)):
        assert "MISSED" in adversarial_targets([bad])[1]
    md = "\n".join(adversarial_markdown([_section()]))
    assert "| random | certified | on | 2 | 0 | 2 |" in md and "50 of 192 corners" in md


def test_kernel_targets_say_met_or_by_how_much_missed():
    """The kernel benchmark's targets: a figure past its threshold is met; one
    short of it is missed by threshold / figure, with the measured reason."""
    from benchmarks.kernel import kernel_targets

    result = {
        "throughput": [
            {
                "cell": "a",
                "path": "path1",
                "kernel_per_s": 4.0e6,
                "drake_per_s": 4.0e4,
                "ratio": 100.0,
                "fk_per_s": 8.0e6,
                "fk_ratio": 200.0,
                "fk_one_at_a_time_per_s": 1.6e6,
                "fk_blocks_over_one_at_a_time": 5.0,
            },
            {
                "cell": "b",
                "path": "path2",
                "kernel_per_s": 4.0e5,
                "drake_per_s": 5.0e4,
                "ratio": 8.0,
                "fk_per_s": 2.0e6,
                "fk_ratio": 40.0,
                "fk_one_at_a_time_per_s": 1.0e6,
                "fk_blocks_over_one_at_a_time": 2.0,
            },
        ],
        "bounding": [
            {
                "cell": "a",
                "path": "path1",
                "resolution": 100,
                "time_ms": 8.0,
                "paper_ms": 82,
                "paper_over_ours": 10.25,
                "region_tests": 100,
                "us_per_test": 80.0,
            },
            {
                "cell": "a",
                "path": "path1",
                "resolution": 20000,
                "time_ms": 574.5,
                "paper_ms": 1149,
                "paper_over_ours": 2.0,
                "region_tests": 14000,
                "us_per_test": 41.0,
            },
        ],
        "certify": [
            {
                "cell": "a",
                "path": "path1",
                "certify_ms": 5000.0,
                "certify_region_tests": 10,
                "certify_samples": 20,
                "certify_n_samples": 5,
                "certify_shrinks": 1,
            }
        ],
        "cf": [
            {
                "cell": "a",
                "path": "path1",
                "samples": 300000,
                "seconds": 0.25,
                "drake_checked": 10,
                "percent": 99.0,
                "drake_floor_s": 0.01,
            }
        ],
        "compile": {"seconds": 60.0, "eta_error": {"25%": 0.1, "50%": 0.4}},
    }
    got = {name: (ok, text) for name, ok, text in kernel_targets(result)}
    flags = [ok for ok, _ in got.values()]
    assert flags == [True, True, False, False, True, False, False, False, True, False, False]
    assert "2.0x" in got["b path2: forward kinematics in blocks >= 4x one configuration at a time"][1]
    assert "2.0x over" in got["first compile <= 30 s"][1]
    assert "10.0x short" in got["b path2: configurations per second >= 80x Drake's checker"][1]
    assert "5.0x short" in got["a path1 R = 20000: bounding <= 114.9 ms (10x below the paper's 1149 ms)"][1]
    assert "71.81" in got["a path1: growth t(20000) / t(100) <= 2"][1]  # 574.5 / 8.0
    assert "2.5x over" in got["a path1: certification <= 2 s"][1]
