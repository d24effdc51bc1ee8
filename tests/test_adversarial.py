"""Adversarial pushes: sign patterns and run summaries."""

import numpy as np
from conftest import write_arm_cell

import drake_cfvol as cf
from drake_cfvol.comanip.adversarial import nearest_obstacle_signs, summarize_runs


def _post_distance(wc, q):
    return wc.obstacle_distances(np.asarray(q, float), 2.0, moving_only=True)["post"]


def test_nearest_obstacle_signs_push_toward_the_post(tmp_path):
    """A two-link arm along +x with a post at (1.15, 1.0), nearer the floor
    (which no joint of the planar arm moves toward): the push signs make the
    distance to the post by Drake shrink for a small step along them and
    grow for a step against them (a finite difference, independent of the
    gradient the signs came from)."""
    wc = cf.load_workcell(
        write_arm_cell(
            tmp_path,
            links=[
                {"length": 1.0, "half_width": 0.05, "lower": -0.4, "upper": 0.4},
                {"length": 0.8, "half_width": 0.05, "lower": -0.8, "upper": 0.8},
            ],
            obstacles={"post": ((0.3, 0.3, 1.0), (1.15, 1.0, 0.5))},
            base_z=0.5,
        )
    )
    q = np.zeros(2)
    signs = nearest_obstacle_signs(wc, q)
    assert set(np.unique(signs)) <= {-1.0, 1.0}
    d0 = _post_distance(wc, q)
    assert _post_distance(wc, q + 0.02 * signs) < d0 < _post_distance(wc, q - 0.02 * signs)


def _row(cell, seed, *, on=True, collisions=0, clearance=0.03, ratio=0.5, pattern="random"):
    return {
        "cell": cell,
        "seed": seed,
        "pattern": pattern,
        "certify": False,
        "safety_filter": on,
        "margin_m": 0.02,
        "collisions": collisions,
        "drake_colliding_updates": 0,
        "min_clearance_m": clearance,
        "nominal_min_clearance_m": 0.05,
        "worst_shortfall_m": 0.02 - clearance,
        "margin_kept": clearance >= 0.018,
        "max_velocity_ratio": ratio,
        "filter_steps": seed,
        "filter_damper_misses": 0,
        "filter_box_exits": 0,
        "max_bound_violation": 0.0,
        "filter_fallbacks": 0,
        "max_deviation": 0.1 * (seed + 1),
        "sim_wall_s": 1.0,
    }


def test_summary_by_hand():
    """Rows group by cell, pattern, certification, filter and margin; the
    counts, extremes and medians are those of the rows."""
    rows = [
        _row("a", 0),
        _row("a", 1, collisions=3, clearance=-0.01, ratio=0.9),
        _row("a", 2, on=False),
        _row("a", 3, pattern="nearest"),
    ]
    out = {(s["pattern"], s["safety_filter"]): s for s in summarize_runs(rows)}
    assert set(out) == {("random", True), ("random", False), ("nearest", True)}
    on = out[("random", True)]
    assert on["runs"] == 2 and on["runs_with_collisions"] == 1 and on["runs_margin_kept"] == 1
    assert on["min_clearance_m"] == -0.01 and on["max_velocity_ratio"] == 0.9
    assert on["filter_steps_median"] == 0.5 and on["max_deviation"] == 0.2
