"""Online re-estimation: compute time per update, incremental against full;
the mapper's time per camera image; a run's wall time per part.

Replays a bundled moving-obstacle scenario's obstacles (their true map at
the bounds' rate, the path index advancing as the nominal does) through
``OnlineBounds`` twice in the same run: incrementally over the scenario's
horizon (what a run does) and with a full re-estimation of the whole path
at every change (the reference: no footprints, no horizon). Reports medians over repeats of each update's time (only
updates whose map changed), their ratio, and the median over repeats of each replay's worst update.

The run: the scenario's diagram simulated for ``--mapper-seconds`` with
its camera. Per image, the renders (the camera and the model's images, a
stand-in for a real camera) and the mapper's own work (classify the pixels,
update the map) timed apart; medians and maxima over the images. Per
simulated second, the wall time of each part (our systems; the renders,
the monitor and the simulated world apart; the rest is Drake's: the
framework, the plant, the loggers).

    tools/dev.sh python tools/online_bench.py [--repeats 3] [--json]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pydrake.geometry import SceneGraph  # noqa: E402

from drake_cfvol.comanip import load_scenario  # noqa: E402
from drake_cfvol.comanip.diagram import _workcell_path_bounds, build_comanipulation_diagram  # noqa: E402
from drake_cfvol.comanip.online import map_grid, perception_params  # noqa: E402
from drake_cfvol.online import OnlineBounds  # noqa: E402
from drake_cfvol.systems import MovingBoxes  # noqa: E402

SCENARIOS = ("automotive_moving_obstacle", "aerospace_moving_obstacle")


def replay(name: str, full: bool) -> list[float]:
    """Update times (ms) of the updates whose map changed."""
    scenario, file = load_scenario(name, scenario_text="{bounds: {certify: null}}")
    wc, path, bounds, _ = _workcell_path_bounds(scenario, None, file, None, None, False)
    o = scenario.bounds.online
    grid = map_grid(wc, scenario.perception.cell)
    boxes = MovingBoxes(SceneGraph(), scenario.cell.moving_obstacles, grid=grid, params=perception_params(scenario))
    online = OnlineBounds(wc, bounds, horizon=None if full else o.horizon)
    rate = (path.g - 1) / scenario.path.duration
    times, last = [], None
    for t in np.arange(0.0, scenario.duration, o.period):
        m = boxes.obstacle_map(float(t))
        s = float(np.clip((t - scenario.control.path_progress.start_time) * rate, 0.0, path.g - 1.0))
        t0 = time.perf_counter()
        online.update(m, s, full=full and not m.same_as(last))
        ms = (time.perf_counter() - t0) * 1e3
        if not m.same_as(last):
            times.append(ms)
        last = m
    return times


#: The run's Python callbacks timed, (module, class, method, part): our own
#: systems, the monitor and the stand-ins for the world (the scripted
#: co-worker, the moving boxes), each reported apart.
_PARTS = (
    ("filter.safety", "SafetyFilter", "_update", "safety filter"),
    ("admittance", "AdmittanceDeformation_", "_update", "admittance"),
    ("admittance", "AdmittanceDeformation_", "_calc_commanded", "admittance"),
    ("human_input", "HumanInputCheck_", "_update", "input check"),
    ("human_input", "HumanInputCheck_", "_torque", "input check"),
    ("human_input", "HumanInputCheck_", "_wrench", "input check"),
    ("bounds_source", "JointBoundsSource_", "_at", "bounds"),
    ("online_bounds", "OnlineBoundsEstimator", "_update", "online bounds"),
    ("perception", "ObstacleMapper", "_update", "mapper"),
    ("columns", "PerceivedColumns", "_tiles", "perceived columns"),
    ("columns", "PerceivedColumns", "_calc_poses", "perceived columns"),
    ("columns", "PerceivedColumns", "_log_tiles", "perceived columns"),
    ("monitor", "ClearanceMonitor", "min_distance", "monitor"),
    ("monitor", "ClearanceMonitor", "_contacts", "monitor"),
    ("moving_boxes", "MovingBoxes", "_calc_poses", "world"),
    ("humans", "ScriptedHuman", "at", "world"),
)

#: Parts that are not our systems' work: the camera's renders (a stand-in
#: for a real camera), the monitor (the run's independent check, at the log
#: rate) and the simulated world.
NOT_OURS = ("renders", "monitor", "world")


def run_budget(name: str, seconds: float) -> dict:
    """The scenario's diagram simulated for ``seconds``: wall time per
    simulated second of each part (exclusive: a timed callback inside
    another counts for the inner one), the renders (the camera's and the
    model's images, evaluated ahead of the mapper's update) apart; the
    mapper's and the renders' ms per camera image."""
    import importlib

    from pydrake.systems.analysis import Simulator

    from benchmarks.realtime import _Timers

    timers, saved, per_image = _Timers(), [], {"renders": [], "mapper": []}

    def renders(self, context):
        for port in (
            self.point_cloud_input,
            self.depth_image_input,
            self.model_depth_image_input,
            self.model_label_image_input,
        ):
            port.Eval(context)  # cached for the update

    timed_renders = timers.wrap("renders", renders)
    for module, cls_name, method, part in _PARTS:
        cls = getattr(importlib.import_module(f"drake_cfvol.systems.{module}"), cls_name)
        cls = cls[float] if cls_name.endswith("_") else cls
        original = cls.__dict__[method]
        saved.append((cls, method, original))
        if part == "mapper":

            def mapper(self, context, state, _update=original):
                t0 = time.perf_counter()
                timed_renders(self, context)
                t1 = time.perf_counter()
                _update(self, context, state)
                per_image["renders"].append((t1 - t0) * 1e3)
                per_image["mapper"].append((time.perf_counter() - t1) * 1e3)

            setattr(cls, method, timers.wrap(part, mapper))
        else:
            setattr(cls, method, timers.wrap(part, original))
    try:
        scenario, file = load_scenario(name, scenario_text="{bounds: {certify: null}}")
        cm = build_comanipulation_diagram(scenario, scenario_file=file)
        sim = Simulator(cm.diagram)
        sim.Initialize()
        timers.total.clear()
        t0 = time.perf_counter()
        sim.AdvanceTo(seconds)
        wall = time.perf_counter() - t0
    finally:
        for cls, method, original in saved:
            setattr(cls, method, original)
    parts = {k: v / seconds for k, v in sorted(timers.total.items())}
    ours = sum(v for k, v in parts.items() if k not in NOT_OURS)
    return {
        "per_sim_s": parts,
        "ours_per_sim_s": ours,
        "wall_per_sim_s": wall / seconds,
        "rest_per_sim_s": wall / seconds - sum(parts.values()),
        "renders_ms": per_image["renders"],
        "mapper_ms": per_image["mapper"],
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--mapper-seconds", type=float, default=4.0)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    rows = []
    for name in SCENARIOS:
        runs = [replay(name, False) for _ in range(args.repeats)]
        inc = [np.median(r) for r in runs]
        ref = [np.median(replay(name, True)) for _ in range(args.repeats)]
        budget = run_budget(name, args.mapper_seconds)
        renders, mapper = budget["renders_ms"], budget["mapper_ms"]
        rows.append(
            {
                "scenario": name,
                "incremental_ms": float(np.median(inc)),
                "incremental_max_ms": float(np.median([max(r) for r in runs])),  # each replay's worst
                "full_ms": float(np.median(ref)),
                "ratio": float(np.median(inc) / np.median(ref)),
                "repeats": args.repeats,
                "images": len(mapper),
                "mapper_ms": float(np.median(mapper)),
                "mapper_max_ms": float(np.max(mapper)),
                "renders_ms": float(np.median(renders)),
                "simulated_s": args.mapper_seconds,
                "ours_per_sim_s": budget["ours_per_sim_s"],
                "wall_per_sim_s": budget["wall_per_sim_s"],
                "rest_per_sim_s": budget["rest_per_sim_s"],
                "parts_per_sim_s": budget["per_sim_s"],
            }
        )
    if args.json:
        print(json.dumps(rows, indent=1))
    else:
        print(
            "| scenario | median update, incremental (ms) | its max (ms) | full re-estimation (ms) | ratio "
            "| images | mapper median (max) ms | renders median ms |\n|---|---|---|---|---|---|---|---|"
        )
        for r in rows:
            print(
                f"| {r['scenario']} | {r['incremental_ms']:.1f} | {r['incremental_max_ms']:.1f} "
                f"| {r['full_ms']:.1f} | {r['ratio']:.2f} "
                f"| {r['images']} | {r['mapper_ms']:.1f} ({r['mapper_max_ms']:.1f}) | {r['renders_ms']:.1f} |"
            )
        parts = sorted({p for r in rows for p in r["parts_per_sim_s"]})
        print(
            "\nWall time per simulated second (s), over the run's first "
            f"{rows[0]['simulated_s']:g} s:\n\n| scenario | ours | "
            + " | ".join(parts)
            + " | rest (Drake) | all |\n|---|"
            + "---|" * (len(parts) + 3)
        )
        for r in rows:
            cols = " | ".join(f"{r['parts_per_sim_s'].get(p, 0.0):.3f}" for p in parts)
            print(
                f"| {r['scenario']} | {r['ours_per_sim_s']:.3f} | {cols} | {r['rest_per_sim_s']:.3f} "
                f"| {r['wall_per_sim_s']:.3f} |"
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
