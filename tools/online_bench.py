"""Online re-estimation: compute time per update, incremental against full;
and the mapper's time per camera image.

Replays a bundled moving-obstacle scenario's obstacles (their true map at
the bounds' rate, the path index advancing as the nominal does) through
``OnlineBounds`` twice in the same run: incrementally over the scenario's
horizon (what a run does) and with a full re-estimation of the whole path
at every change (the reference: no footprints, no horizon). Reports medians over repeats of each update's time (only
updates whose map changed), and their ratio.

The mapper: the scenario's diagram simulated for ``--mapper-seconds`` with
its camera; per image, the renders (the camera and the model's images, a
stand-in for a real camera) and the mapper's own work (classify the pixels,
update the map) timed apart; medians and maxima over the images.

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
from drake_cfvol.systems.perception import ObstacleMapper  # noqa: E402

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


def mapper_times(name: str, seconds: float) -> tuple[list[float], list[float]]:
    """(renders, mapper) ms per camera image over ``seconds`` of the
    scenario's run (its camera perception)."""
    from pydrake.systems.analysis import Simulator

    renders, mapper = [], []
    update = ObstacleMapper._update

    def timed(self, context, state):
        t0 = time.perf_counter()
        for port in (
            self.point_cloud_input,
            self.depth_image_input,
            self.model_depth_image_input,
            self.model_label_image_input,
        ):
            port.Eval(context)  # the renders (cached for the update)
        t1 = time.perf_counter()
        update(self, context, state)
        renders.append((t1 - t0) * 1e3)
        mapper.append((time.perf_counter() - t1) * 1e3)

    ObstacleMapper._update = timed  # bound by the system built next
    try:
        scenario, file = load_scenario(name, scenario_text="{bounds: {certify: null}}")
        cm = build_comanipulation_diagram(scenario, scenario_file=file)
        Simulator(cm.diagram).AdvanceTo(seconds)
    finally:
        ObstacleMapper._update = update
    return renders, mapper


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--mapper-seconds", type=float, default=4.0)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    rows = []
    for name in SCENARIOS:
        inc = [np.median(replay(name, False)) for _ in range(args.repeats)]
        ref = [np.median(replay(name, True)) for _ in range(args.repeats)]
        renders, mapper = mapper_times(name, args.mapper_seconds)
        rows.append(
            {
                "scenario": name,
                "incremental_ms": float(np.median(inc)),
                "full_ms": float(np.median(ref)),
                "ratio": float(np.median(inc) / np.median(ref)),
                "repeats": args.repeats,
                "images": len(mapper),
                "mapper_ms": float(np.median(mapper)),
                "mapper_max_ms": float(np.max(mapper)),
                "renders_ms": float(np.median(renders)),
            }
        )
    if args.json:
        print(json.dumps(rows, indent=1))
    else:
        print(
            "| scenario | median update, incremental (ms) | full re-estimation (ms) | ratio "
            "| images | mapper median (max) ms | renders median ms |\n|---|---|---|---|---|---|---|"
        )
        for r in rows:
            print(
                f"| {r['scenario']} | {r['incremental_ms']:.1f} | {r['full_ms']:.1f} | {r['ratio']:.2f} "
                f"| {r['images']} | {r['mapper_ms']:.1f} ({r['mapper_max_ms']:.1f}) | {r['renders_ms']:.1f} |"
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
