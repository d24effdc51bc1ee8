"""Running a scenario: simulate, log at the update rate, summarise, and the
run's problems (collision, margin, velocity).
"""

import dataclasses
import json
import time
from pathlib import Path

import numpy as np
from pydrake.common import RandomGenerator
from pydrake.geometry import Meshcat, MeshcatParams
from pydrake.systems.analysis import ApplySimulatorConfig, Simulator, SimulatorStatus
from pydrake.systems.framework import EventStatus

from drake_cfvol.algorithm.planning import NominalPath
from drake_cfvol.algorithm.table import BoundsTable
from drake_cfvol.comanip.diagram import CoManipulation, build_comanipulation_diagram
from drake_cfvol.comanip.online import online_figures, show_online_freedom
from drake_cfvol.comanip.report import missing_dot_notice, plot_run, write_diagram_svg
from drake_cfvol.comanip.run_summary import OnlineFigures, RunSummary, TrackingFigures
from drake_cfvol.comanip.scenario import load_scenario
from drake_cfvol.io.progress import Progress
from drake_cfvol.io.records import prepare_outputs
from drake_cfvol.systems.filter.safety import FAULTS

__all__ = ["bound_figures", "run_outputs", "run_scenario"]


def _log(sim_context, logger):
    log = logger.FindLog(sim_context)
    return log.sample_times().copy(), log.data().T.copy()


def _simulate(cm, scenario, meshcat, progress: bool):
    """Simulates the run (recording into ``meshcat`` if given); the random
    pushes' numbers live in the context, seeded Drake's way. Returns (the
    simulator's context, wall time s)."""
    sim = Simulator(cm.diagram)
    ApplySimulatorConfig(scenario.simulation.simulator_config, sim)
    ctx = sim.get_mutable_context()
    cm.diagram.SetRandomContext(ctx, RandomGenerator(scenario.random_seed))
    if meshcat is not None:
        meshcat.StartRecording(
            frames_per_second=1.0 / scenario.simulation.visualization.publish_period,
            set_visualizations_while_recording=False,
        )
    if cm.diagram.HasOutputPort("filter_fault"):
        # A faulted filter holds the robot for good (docs/safety.md, "Hold and faults"): the run ends there.
        fault = cm.diagram.GetOutputPort("filter_fault")
        sim.set_monitor(
            lambda root: (
                EventStatus.ReachedTermination(cm.diagram, "the safety filter faulted")
                if fault.Eval(root)[0]
                else EventStatus.Succeeded()
            )
        )
    t0 = time.perf_counter()
    duration = cm.duration
    with Progress(duration, "Simulating", enabled=progress, unit="simulated s") as bar:
        steps = 100
        for n in range(1, steps + 1):
            status = sim.AdvanceTo(duration * n / steps)
            bar.update(duration / steps)
            if status.reason() == SimulatorStatus.ReturnReason.kReachedTerminationCondition:
                break
    return ctx, time.perf_counter() - t0


def _write_files(cm, logs, out: Path, meshcat, plot: bool, svg: bool, ctx=None) -> dict:
    """The recording (self-contained HTML), the plot and the diagram's SVG."""
    files = {}
    if plot:  # first: within plotting.in_background it is drawn while the rest is written
        files["plot_png"] = str(plot_run(logs, cm, out / "run.png"))
    if meshcat is not None:
        meshcat.StopRecording()
        if cm.online is not None:
            show_online_freedom(meshcat, cm, logs, ctx)
        meshcat.PublishRecording()
        html = out / "recording.html"
        html.write_text(meshcat.StaticHtml())
        files["recording_html"] = str(html)
    if svg:
        files.update(write_diagram_svg(cm.diagram, out / "diagram"))
    return files


def _tracking(logs, scenario) -> TrackingFigures | None:
    """A dynamic run's tracking (None: a kinematic run): per update, the
    largest joint error between the measured position and the command it
    was to reach (the previous update's), rad (m)."""
    pc = scenario.simulation.plant_config
    if pc is None:
        return None
    m, c = logs["update_measured_position"][1], logs["update_commanded_position"][1]
    n = min(len(m), len(c))
    err = np.abs(m[1:n] - c[: n - 1]).max(axis=1) if n > 1 else np.zeros(1)
    return TrackingFigures(pc.time_step, float(err.max()), float(np.median(err)))


def _margins(cm, scenario) -> tuple[float, float]:
    """The margin in force, and the nominal's own clearance (moving links
    against the obstacles, Drake, at every waypoint): a run keeps the margin
    if it never comes nearer than min(margin, the nominal's own)."""
    margin = (
        cm.filter_clearance if cm.filter_clearance is not None else float(cm.bounds.params.get("clearance", 0.0) or 0.0)
    )
    nominal_own = min(
        (
            min(d.values(), default=1.0)
            for d in (cm.workcell.obstacle_distances(qn, 1.0, changeable_only=True) for qn in cm.path.waypoints)
        ),
        default=1.0,
    )
    return margin, float(nominal_own)


def run_outputs(out_dir: str | Path, *, record: bool = True, plot: bool = True, svg: bool = True) -> list[Path]:
    """The files a run writes into ``out_dir`` (:func:`run_scenario`): its
    summary and logs, and as asked the plot, the recording and the diagram
    (its source, and its SVG where Graphviz is installed)."""
    names = ["summary.json", "logs.npz"]
    names += ["run.png"] * plot + ["recording.html"] * record + ["diagram.dot", "diagram.svg"] * svg
    return [Path(out_dir) / name for name in names]


def run_scenario(
    scenario_name_or_path: str | Path,
    out_dir: str | Path,
    *,
    record: bool = True,
    plot: bool = True,
    svg: bool = True,
    path: NominalPath | None = None,
    bounds: BoundsTable | None = None,
    progress: bool = False,
    scenario_text: str | None = None,
    overrides: dict | None = None,
    overwrite: bool = False,
) -> RunSummary:
    """Loads a scenario, builds its diagram, simulates it and writes the
    recording (self-contained HTML), plots and a summary.

    With ``progress``, a bar on a terminal counts simulated seconds.
    ``scenario_text`` and ``overrides`` change fields (see :func:`load_scenario`).

    Returns:
        The run's summary (also written as ``summary.json``, from
        :meth:`RunSummary.to_dict`).

    Raises:
        OutputExistsError: a file of :func:`run_outputs` exists and
            ``overwrite`` is False (checked before anything is built).
    """
    scenario, file = load_scenario(scenario_name_or_path, scenario_text=scenario_text, overrides=overrides)
    out = Path(out_dir)
    prepare_outputs(out, [f.name for f in run_outputs(out, record=record, plot=plot, svg=svg)], overwrite=overwrite)
    meshcat = None
    if record:
        meshcat = Meshcat(MeshcatParams(host="localhost"))
    cm = build_comanipulation_diagram(
        scenario, meshcat=meshcat, scenario_file=file, path=path, bounds=bounds, progress=progress
    )
    ctx, sim_s = _simulate(cm, scenario, meshcat, progress)
    logs = {name: _log(ctx, lg) for name, lg in cm.loggers.items()}
    t, q = logs["commanded_position"]
    _, lo = logs["lower"]
    _, hi = logs["upper"]
    _, nom = logs["nominal"]
    _, s_log = logs["path_index"]
    rates = update_rate_figures(logs, cm)
    files = _write_files(cm, logs, out, meshcat, plot, svg, ctx)
    np.savez(out / "logs.npz", **{f"{k}_t": v[0] for k, v in logs.items()}, **{k: v[1] for k, v in logs.items()})
    clearance, nominal_own = _margins(cm, scenario)
    online = None
    if cm.online is not None:
        online = OnlineFigures(
            **online_figures(cm.online, ctx, scenario),
            moving_obstacles=[o.name for o in scenario.cell.moving_obstacles],
            column_overflow=_count(cm, ctx, "column_overflow"),
        )
    tracking = _tracking(logs, scenario)
    notices = list(cm.workcell.notes)
    if svg and files.get("diagram_svg") is None:
        notices.append(missing_dot_notice(out / "diagram"))
    summary = RunSummary(
        scenario=str(file) if file else str(scenario_name_or_path),
        cell=cm.workcell.name,
        path=scenario.path.name,
        resolution=scenario.bounds.resolution,
        g=cm.path.g,
        steps=int(len(t)),
        duration_s=cm.duration,
        path_duration_s=cm.progress.duration - cm.progress.start_time,
        sim_wall_s=sim_s,
        min_clearance_m=rates["min_clearance_m"],
        max_velocity_ratio=rates["max_velocity_ratio"],
        max_acceleration_ratio=rates["max_acceleration_ratio"],
        max_jerk_ratio=rates["max_jerk_ratio"],
        # A dynamic run draws the volume's boxes only (no proximity geometry of its plant): not counted.
        volume_penetrations=None if tracking is not None else int(logs["in_volume"][1].sum()),
        collisions=rates["collisions"],
        **bound_figures(t, q, *cm.bounds.boxes_at(np.clip(s_log[:, 0], 0.0, cm.bounds.g - 1))[:2], lo, hi),
        filter_steps=_count(cm, ctx, "filter_count"),
        filter_fallbacks=_count(cm, ctx, "filter_fallbacks"),
        filter_damper_misses=_count(cm, ctx, "filter_damper_misses"),
        braking_faults=_count(cm, ctx, "filter_braking_faults"),
        guard_stops=_count(cm, ctx, "filter_guard_stops"),
        filter_box_exits=_count(cm, ctx, "filter_box_exits"),
        filter_holds=_count(cm, ctx, "filter_holds"),
        tracking_faults=_count(cm, ctx, "tracking_faults"),
        faults=_count(cm, ctx, "fault_count"),
        filter_fault=FAULTS.get(_count(cm, ctx, "filter_fault")),
        ended_s=ctx.get_time(),
        safety_filter=cm.control is not None and cm.control.safety is not None,
        filter_clearance_m=cm.filter_clearance,
        max_deviation=float(np.max(np.abs(q - nom))) if len(q) else 0.0,
        n_boxes=cm.bounds.info["n_boxes"],
        volume_boxes_in_scene=cm.volume_boxes["count"],
        bounds_time_ms=cm.bounds.timing_ms["total"],
        build_ms=cm.build_ms,
        recording_html=files.get("recording_html"),
        plot_png=files.get("plot_png"),
        diagram_svg=files.get("diagram_svg"),
        diagram_dot=files.get("diagram_dot"),
        notices=notices,
        clearance_m=clearance,
        nominal_min_clearance_m=nominal_own,
        online=online,
        tracking=tracking,
    )
    summary = dataclasses.replace(summary, problems=run_problems(summary))
    (out / "summary.json").write_text(json.dumps(summary.to_dict(), indent=1))
    return summary


#: A run may come this much nearer than min(margin, the nominal's own
#: clearance) before it counts as below the margin, m.
MARGIN_TOLERANCE = 0.002


def bound_figures(t, q, base_lower, base_upper, lower, upper) -> dict:
    """The command against the bounds, from the logs (times t (n,),
    commands q (n, k); the static table's box at the logged path indices
    and the live box, lower / upper (n, k) each):

    - ``max_bound_violation``: how far the command ever left the base
      table's box at its path index, rad (m): 0, unless the safety filter
      gave the box way to a damper row (``filter_box_exits``: dodging a
      moving obstacle);
    - ``live_box_excess_max``: how far it ever lay outside the live box
      (after a tightening it catches up at its velocity limits, by design);
    - ``live_box_catchup_s``: the longest time it stayed outside the live
      box, s (from the first sample outside to the first back inside, or
      to the end of the run)."""
    if not len(q):
        return {"max_bound_violation": 0.0, "live_box_excess_max": 0.0, "live_box_catchup_s": 0.0}
    base_excess = np.maximum(np.maximum(base_lower - q, q - base_upper), 0.0).max(axis=1)
    live_excess = np.maximum(np.maximum(lower - q, q - upper), 0.0).max(axis=1)
    outside = live_excess > 1e-9
    longest, start = 0.0, None
    for i, out in enumerate(outside):
        if out and start is None:
            start = i
        elif not out and start is not None:
            longest, start = max(longest, t[i] - t[start]), None
    if start is not None:
        longest = max(longest, t[-1] - t[start])
    return {
        "max_bound_violation": float(base_excess.max()),
        "live_box_excess_max": float(live_excess.max()),
        "live_box_catchup_s": float(longest),
    }


def run_problems(summary: RunSummary) -> list[str]:
    """What went wrong in a run, one sentence each (empty: nothing): it
    collided, came nearer than min(margin, the nominal's own clearance) -
    MARGIN_TOLERANCE, or moved a joint faster than its limit (measured at
    the control update rate), or left the base table's box where the
    filter did not give the box way to a damper row (``filter_box_exits``),
    or the safety filter faulted (``filter_fault``: the run ended there)."""
    out = []
    if summary.filter_fault:
        out.append(
            f"the safety filter faulted at {summary.ended_s:.2f} s ({summary.filter_fault}): it held "
            "the last command and the run ended there"
        )
    if summary.collisions > 0:
        out.append(f"the robot collided at {summary.collisions} update(s)")
    need = min(summary.clearance_m, summary.nominal_min_clearance_m)
    low = summary.min_clearance_m
    if low is not None and low < need - MARGIN_TOLERANCE:
        out.append(f"the clearance fell to {low * 1e3:.1f} mm, below the margin of {need * 1e3:.1f} mm")
    limits = (
        ("velocity", "moved at", summary.max_velocity_ratio),
        ("acceleration", "accelerated at", summary.max_acceleration_ratio),
        ("jerk", "jerked at", summary.max_jerk_ratio),
    )
    for key, what, ratio in limits:
        if ratio > 1.0 + 1e-6 and summary.safety_filter:
            out.append(f"a joint {what} {ratio:.2f} x its {key} limit")
    if summary.max_bound_violation > 1e-6 and not summary.filter_box_exits:
        out.append(
            f"the command left the bounds table by {summary.max_bound_violation:.2e} rad (m) "
            "without the filter giving the box way to a damper row"
        )
    return out


def _count(cm: CoManipulation, context, name: str) -> int:
    """A counter exported by the diagram, at the end of the run (0 if the
    diagram has no such port: the filter is off)."""
    if not cm.diagram.HasOutputPort(name):
        return 0
    return int(cm.diagram.GetOutputPort(name).Eval(context)[0])


def update_rate_figures(logs: dict, cm: CoManipulation) -> dict:
    """Speed, clearance and collisions from the logs at the control update
    rate (``update_*``): the largest |dq_j| / (period x velocity_limit_j)
    between consecutive updates (one update period apart by construction,
    so the period is the time step, not the difference of two rounded
    sample times), likewise the largest change of that velocity over the
    acceleration limit's and of that acceleration over the jerk limit's
    (the finite ones; 0: none), the smallest clearance (moving links to the
    obstacles, m) and the number of updates in collision."""
    _, q = logs["update_commanded_position"]
    _, dist = logs["update_min_distance"]
    _, coll = logs["update_in_collision"]
    h = cm.scenario.control.period
    vmax = np.asarray(cm.workcell.velocity_limits, float)
    c = cm.scenario.control
    amax = np.asarray(list(c.acceleration_limits) or list(cm.workcell.acceleration_limits), float)
    jmax = np.asarray(list(c.jerk_limits) or list(cm.workcell.jerk_limits), float)
    ratios = []
    for n, limit in enumerate((vmax, amax, jmax), start=1):
        change = np.abs(np.diff(q, n=n, axis=0)) / h**n if len(q) > n else np.zeros((0, len(limit)))
        ratios.append(float(np.max(np.where(np.isfinite(limit), change / limit, 0.0), initial=0.0)))
    return {
        "max_velocity_ratio": ratios[0],
        "max_acceleration_ratio": ratios[1],
        "max_jerk_ratio": ratios[2],
        "min_clearance_m": float(dist.min()) if len(dist) else None,
        "collisions": int(coll.sum()),
    }
