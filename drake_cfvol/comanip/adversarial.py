"""Adversarial co-manipulation runs: steady corner-seeking pushes, pushes
toward the nearest obstacle, and seeded random push sequences.

A constant joint torque of the same size on every joint, with seeded random
signs, for the whole run, drives the admittance into a corner of the box at
every path position; on uncertified bounds the corners often collide, so
what keeps the robot safe there is the runtime safety filter. Each run is
recounted against independent facts: Drake's collision checker of the
workcell's own scene at every update, and the nominal's own clearance
(Drake's distances) at the same path positions.
:func:`adversarial_suite` runs every pattern on certified and uncertified
bounds with the filter on and off, and counts the colliding corners and
edge points of both kinds of boxes by Drake (the benchmark's adversarial
section).
"""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from drake_cfvol.algorithm.certificate.certify import Certify
from drake_cfvol.algorithm.pipeline import estimate_bounds
from drake_cfvol.algorithm.planning import plan_nominal_path
from drake_cfvol.comanip.push_patterns import PATTERNS
from drake_cfvol.comanip.run import MARGIN_TOLERANCE, run_scenario
from drake_cfvol.comanip.scenario import load_scenario
from drake_cfvol.exceptions import ParameterError
from drake_cfvol.scene.params import VolumeParams
from drake_cfvol.scene.workcell import load_workcell

__all__ = [
    "steady_push_runs",
    "summarize_runs",
    "nearest_obstacle_signs",
    "adversarial_suite",
    "PATTERNS",
    "MARGIN_TOLERANCE",
]


#: A run's summary figures each row carries as they are.
_SUMMARY_KEYS = (
    "collisions",
    "min_clearance_m",
    "max_velocity_ratio",
    "filter_steps",
    "filter_damper_misses",
    "filter_fallbacks",
    "faults",
    "filter_box_exits",
    "max_bound_violation",
    "max_deviation",
    "sim_wall_s",
)


def _signs(seed: int, k: int) -> np.ndarray:
    return np.random.default_rng(seed).choice([-1.0, 1.0], size=k)


def nearest_obstacle_signs(workcell, q) -> np.ndarray:
    """(k,) signs of a joint push that drives configuration q toward its
    nearest obstacle (or the nearest pair of its own links) among the
    distances a joint motion changes: minus the sign of that distance's
    gradient by Drake's clearance query (a joint that does not change it
    pushes +1)."""
    rc = workcell.checker.CalcRobotClearance(np.asarray(q, float), 10.0)
    d = np.asarray(rc.distances())
    k = len(q)
    if not d.size:
        return np.ones(k)
    J = np.asarray(rc.jacobians()).reshape(len(d), k)
    movable = np.linalg.norm(J, axis=1) > 1e-9  # a distance no joint changes cannot be pushed closer
    if not movable.any():
        return np.ones(k)
    grad = J[np.flatnonzero(movable)[int(np.argmin(d[movable]))]]
    return np.where(grad > 0, -1.0, 1.0)


def steady_push_runs(
    cell: str,
    runs: int = 16,
    *,
    torque: float = 1500.0,
    safety_filter: bool = True,
    certify: bool = False,
    clearance: float | None = None,
    seeds=None,
    path=None,
    bounds=None,
    on_run=None,
    pattern: str = "random",
) -> list[dict]:
    """Steady corner-seeking pushes on a cell's ``<cell>_push`` scenario
    (its defaults, its scripted pushes replaced): joint torque ``torque``
    x random signs (seed n: ``numpy.random.default_rng(n)``) on every
    joint, from t = 0 to the end of the run.

    Args:
        cell: ``automotive`` or ``aerospace`` (the scenario ``<cell>_push``).
        runs: seeds 0 .. runs-1 (unless ``seeds`` is given).
        torque: N m (N for a prismatic joint) per joint.
        safety_filter: the runtime safety filter on or off (the
            scenario's ``control.safety_filter``).
        certify: certified bounds (the scenario's default) or not.
        clearance: the filter's margin, m (None: the bounds' own).
        seeds: explicit push seeds.
        path, bounds: a planned path and its bounds (else planned and
            estimated here, once for all runs).
        on_run: called with each row as it is done.
        pattern: "random" (seeded signs) or "nearest": seed n of ``runs``
            pushes toward the nearest obstacle of the nominal at waypoint
            round(n (g-1) / (runs-1)) (:func:`nearest_obstacle_signs`), the
            push held for the whole run; or "random_pushes": the
            ``<cell>_random`` scenario (same cell, path and resolution) with
            push seed n, ``torque`` unused.

    Returns:
        One row per run: ``cell``, ``seed``, ``signs``, ``safety_filter``,
        ``certify``, ``margin_m`` (the filter's margin; for a run without
        the filter, the margin it would have kept), ``collisions`` (updates
        in collision, the run's own monitor), ``drake_colliding_updates``
        (the workcell's Drake checker on every update's configuration,
        self-collision included), ``min_clearance_m`` (moving links to the
        obstacles, every update), ``nominal_min_clearance_m`` (the nominal's
        own at the same path positions), ``worst_shortfall_m`` (the largest
        amount, over the updates, by which the clearance fell below
        min(margin, the nominal's own clearance there); <= 0 if never),
        ``margin_kept`` (shortfall <= ``MARGIN_TOLERANCE``),
        ``max_velocity_ratio`` (every update), ``filter_steps``,
        ``filter_damper_misses``, ``filter_fallbacks``, ``faults``,
        ``max_deviation`` (rad or m, from the nominal), ``mean_deviation``
        (the largest joint's deviation from the nominal, averaged over the
        updates: what the co-worker achieved), ``sim_wall_s``.
    """
    if pattern not in PATTERNS:
        raise ParameterError(f"pattern must be one of {', '.join(map(repr, PATTERNS))}, got {pattern!r}.")
    name = f"{cell}_random" if pattern == "random_pushes" else f"{cell}_push"
    scenario, _ = load_scenario(name)
    wc = load_workcell(scenario.cell.name)
    overrides = scenario.bounds.overrides()
    if path is None:
        path = plan_nominal_path(
            wc,
            *wc.configuration(scenario.path.name),
            seed=scenario.random_seed,
            label=scenario.path.name,
            clearance=VolumeParams.for_workcell(wc, **overrides).clearance,
        )
    if bounds is None:
        bounds = estimate_bounds(wc, path, **overrides, certify=Certify(seed=scenario.random_seed) if certify else None)
    seeds = list(range(runs)) if seeds is None else list(seeds)
    margin_default = float(bounds.params.get("clearance", 0.0)) if clearance is None else float(clearance)
    nominal_clearance: dict[float, float] = {}
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in seeds:
            signs, text = _push_text(wc, path, pattern, seed, len(seeds), torque, certify, safety_filter, clearance)
            # Logs only, in its own temporary folder: each run replaces the last one's files.
            s = run_scenario(
                name,
                tmp,
                path=path,
                bounds=bounds,
                scenario_text=text,
                record=False,
                plot=False,
                svg=False,
                overwrite=True,
            )
            logs = np.load(Path(tmp) / "logs.npz")
            margin = s.filter_clearance_m if s.filter_clearance_m is not None else margin_default
            row = {
                "cell": cell,
                "seed": seed,
                "pattern": pattern,
                "signs": signs.tolist(),
                "torque": float(torque),
                "safety_filter": bool(safety_filter),
                "certify": bool(certify),
                "margin_m": margin,
                **{key: getattr(s, key) for key in _SUMMARY_KEYS},
                **_recount(wc, path, bounds, scenario, s, logs, margin, nominal_clearance),
            }
            rows.append(row)
            if on_run is not None:
                on_run(row)
    return rows


def _push_text(wc, path, pattern, seed, n_seeds, torque, certify, safety_filter, clearance):
    """(signs, scenario text) of one run: the push of its pattern and seed."""
    k = wc.num_joints
    sf = "null" if not safety_filter else "{}" if clearance is None else f"{{clearance: {float(clearance)!r}}}"
    text = f"{{bounds: {{certify: {'{}' if certify else 'null'}}}, control: {{safety_filter: {sf}}}, "
    if pattern == "random_pushes":
        signs = np.zeros(k)
        text += f"random_seed: {int(seed)}"
    else:
        if pattern == "nearest":
            at = int(round(seed * (path.g - 1) / max(n_seeds - 1, 1))) % path.g
            signs = nearest_obstacle_signs(wc, path.waypoints[at])
        else:
            signs = _signs(seed, k)
        tau = ", ".join(f"{x:.6g}" for x in torque * signs)
        text += f"human: {{pushes: [{{start: 0.0, duration: 1.0e9, joint_torque: [{tau}]}}]}}"
    return signs, text + "}"


def _recount(wc, path, bounds, scenario, summary, logs, margin, nominal_clearance: dict) -> dict:
    """A run recounted against independent facts at every update: Drake's
    checker of the workcell's own scene, and the nominal's own clearance
    (Drake's distances, cached by path position in ``nominal_clearance``)."""
    t = logs["update_commanded_position_t"]
    q = logs["update_commanded_position"]
    dist = logs["update_min_distance"][:, 0]
    # The path index at each update, as PathProgress has it.
    rate = (path.g - 1) / summary.path_duration_s if summary.path_duration_s > 0 else np.inf
    s_at = np.clip((t - scenario.control.path_progress.start_time) * rate, 0.0, path.g - 1.0)
    s_at = np.round(s_at, 9)
    q_nom = bounds.boxes_at(s_at)[2] if len(t) else np.empty_like(q)
    nom = np.empty(len(t))
    for i, si in enumerate(s_at):
        if si not in nominal_clearance:
            nominal_clearance[si] = min(
                wc.obstacle_distances(q_nom[i], 2.0, changeable_only=True).values(), default=2.0
            )
        nom[i] = nominal_clearance[si]
    shortfall = float(np.max(np.minimum(margin, nom) - dist)) if len(t) else 0.0
    free = np.array(wc.checker.CheckConfigsCollisionFree(q), bool)
    return {
        "drake_colliding_updates": int((~free).sum()),
        "nominal_min_clearance_m": float(nom.min()),
        "worst_shortfall_m": shortfall,
        "margin_kept": shortfall <= MARGIN_TOLERANCE,
        "mean_deviation": float(np.mean(np.max(np.abs(q - q_nom), axis=1))) if len(t) else 0.0,
        "updates": int(len(t)),
    }


def summarize_runs(rows: list[dict]) -> list[dict]:
    """Per (cell, push pattern, certified or not, filter on/off, margin):
    runs, runs with collisions (the
    run's monitor or Drake's checker), runs that kept the margin, the
    smallest clearance, the largest velocity ratio, filter steps (median and
    largest), damper misses, the largest and median largest deviation, and
    the median mean deviation (what the co-worker achieved)."""
    groups: dict[tuple, list[dict]] = {}
    for r in rows:
        groups.setdefault(
            (r["cell"], r.get("pattern", "random"), r["certify"], r["safety_filter"], r["margin_m"]), []
        ).append(r)
    out = []
    for (cell, pattern, certified, on, margin), g in groups.items():
        out.append(
            {
                "cell": cell,
                "pattern": pattern,
                "certify": certified,
                "safety_filter": on,
                "margin_m": margin,
                "runs": len(g),
                "runs_with_collisions": sum(r["collisions"] > 0 or r["drake_colliding_updates"] > 0 for r in g),
                "runs_margin_kept": sum(r["margin_kept"] for r in g),
                "min_clearance_m": min(r["min_clearance_m"] for r in g),
                "nominal_min_clearance_m": min(r["nominal_min_clearance_m"] for r in g),
                "worst_shortfall_m": max(r["worst_shortfall_m"] for r in g),
                "max_velocity_ratio": max(r["max_velocity_ratio"] for r in g),
                "filter_steps_median": float(np.median([r["filter_steps"] for r in g])),
                "filter_steps_max": max(r["filter_steps"] for r in g),
                "damper_misses_max": max(r["filter_damper_misses"] for r in g),
                "box_exits_max": max(r["filter_box_exits"] for r in g),
                "max_bound_violation": max(r["max_bound_violation"] for r in g),
                "fallbacks_max": max(r["filter_fallbacks"] for r in g),
                "max_deviation": max(r["max_deviation"] for r in g),
                "median_max_deviation": float(np.median([r["max_deviation"] for r in g])),
                "median_mean_deviation": float(np.median([r.get("mean_deviation", np.nan) for r in g])),
                "sim_wall_s_median": float(np.median([r["sim_wall_s"] for r in g])),
            }
        )
    return out


def adversarial_suite(cell: str, runs: int = 16, patterns=PATTERNS, *, torque: float = 1500.0, on_run=None) -> dict:
    """The benchmark's adversarial section for one cell: every push pattern
    (``runs`` seeds each) on the uncertified and the certified bounds of the
    ``<cell>_push`` scenario's path (its resolution, parameters and seed;
    certified with ``Certify(seed=...)`` at its defaults), with the safety
    filter on and off; and the colliding corners and edge points of both
    kinds of boxes by Drake's checker, at the bounds' margin less 1 mm, at
    every waypoint and stretch midpoint (:func:`~drake_cfvol.algorithm.metrics.boundary_check`).

    Args:
        cell: ``automotive`` or ``aerospace``.
        runs: seeds per (pattern, bounds, filter).
        patterns: some of :data:`PATTERNS`.
        torque: N m per joint of the steady pushes.
        on_run: called with each run's row as it is done.

    Returns:
        ``{"cell", "clearance_m", "freedom": {kind: ...}, "certify_s",
        "boundary": {kind: BoundaryCheck as a dict}, "rows", "summary"}``
        with kind ``"uncertified"`` / ``"certified"``.
    """
    import dataclasses
    import time

    from drake_cfvol.algorithm.metrics import boundary_check, freedom

    unknown = [p for p in patterns if p not in PATTERNS]
    if unknown:
        raise ParameterError(f"unknown push pattern(s) {unknown}; choose from {', '.join(PATTERNS)}.")
    if runs < 1:
        raise ParameterError(f"runs must be >= 1, got {runs}.")
    scenario, _ = load_scenario(f"{cell}_push")
    wc = load_workcell(scenario.cell.name)
    params = scenario.bounds.overrides()
    path = plan_nominal_path(
        wc,
        *wc.configuration(scenario.path.name),
        seed=scenario.random_seed,
        label=scenario.path.name,
        clearance=VolumeParams.for_workcell(wc, **params).clearance,
    )
    tables = {"uncertified": estimate_bounds(wc, path, **params)}
    t0 = time.perf_counter()
    tables["certified"] = estimate_bounds(wc, path, **params, certify=Certify(seed=scenario.random_seed))
    certify_s = time.perf_counter() - t0
    out: dict[str, Any] = {
        "cell": cell,
        "clearance_m": float(tables["certified"].params.get("clearance", 0.0)),
        "certify_s": certify_s,
        "certificate_cached": bool(tables["certified"].info["certificate"].get("cached")),
        "freedom": {kind: freedom(t).mean for kind, t in tables.items()},
        "boundary": {},
        "rows": [],
    }
    for kind, table in tables.items():
        margin = float(table.info.get("min_margin_m", table.params.get("clearance", 0.0)))
        out["boundary"][kind] = dataclasses.asdict(boundary_check(wc, table, clearance=max(0.0, margin - 1e-3)))
    for pattern in patterns:
        for kind, table in tables.items():
            for on in (True, False):
                out["rows"] += steady_push_runs(
                    cell,
                    runs,
                    torque=torque,
                    safety_filter=on,
                    certify=kind == "certified",
                    path=path,
                    bounds=table,
                    pattern=pattern,
                    on_run=on_run,
                )
    out["summary"] = summarize_runs(out["rows"])
    return out
