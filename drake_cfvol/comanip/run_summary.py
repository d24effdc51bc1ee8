"""A simulated run's summary (:func:`~drake_cfvol.comanip.run_scenario`):
its figures as a typed record, and ``summary.json`` written from it
(docs/safety.md, "What a run reports").
"""

from __future__ import annotations

import dataclasses
from typing import Any

__all__ = ["OnlineFigures", "RunSummary", "TrackingFigures"]


@dataclasses.dataclass(frozen=True)
class OnlineFigures:
    """A run's bounds re-estimated online (with moving obstacles), at its end.

    Attributes:
        perception: how the bounds and the filter learn of the moving
            obstacles: ``camera`` or ``truth``.
        bounds_updates: re-estimations (updates whose map had changed).
        bounds_update_ms: their median compute time, ms (0: none).
        bounds_update_ms_max: their longest compute time, ms (0: none).
        bounds_versions: bounds published after the first.
        bounds_latency_s: worst over the moving obstacles, from its first
            motion to the first bounds in force computed from an image taken
            after it, s (simulated); inf: never; None: none moves.
        freedom_end_ratio: at the end of the run, where the robot is on its
            path, the live box's width over the known cell's (the first
            bounds), averaged over the joints (1.0: the freedom came back).
        moving_obstacles: the moving obstacles' names.
        column_overflow: perceived tiles no column level had room for.
    """

    perception: str
    bounds_updates: int
    bounds_update_ms: float
    bounds_update_ms_max: float
    bounds_versions: int
    bounds_latency_s: float | None
    freedom_end_ratio: float
    moving_obstacles: list[str]
    column_overflow: int


@dataclasses.dataclass(frozen=True)
class TrackingFigures:
    """A dynamic run's tracking (a time-stepping plant under its driver).

    Attributes:
        time_step_s: the plant's time step, s.
        tracking_error_max: per update, the largest joint error between the
            measured position and the command it was to reach (the previous
            update's): its largest value over the run, rad (m).
        tracking_error_median: that error's median over the run, rad (m).
    """

    time_step_s: float
    tracking_error_max: float
    tracking_error_median: float


@dataclasses.dataclass(frozen=True)
class RunSummary:
    """A simulated run's summary: what ``cfvol simulate --json`` prints and
    ``summary.json`` holds (:meth:`to_dict`; docs/safety.md, "What a run
    reports"). Figures at the control update rate unless said otherwise.

    Attributes:
        scenario: the scenario's file (or the name it was given by).
        cell: the workcell's name.
        path: the cell's named start/goal pair.
        resolution: the volume's resolution R.
        g: the nominal path's waypoints.
        steps: the logged samples (every ``simulation.log_period``).
        duration_s: the run's planned simulated time, s.
        path_duration_s: the time from start to goal along the path, as
            slowed for the velocity limits, s.
        sim_wall_s: the simulation's wall time, s.
        min_clearance_m: the smallest distance of the moving links to the
            real obstacles (the distances a joint motion can change), m;
            None: no update logged.
        max_velocity_ratio: the largest joint step over its velocity limit
            x the control period.
        max_acceleration_ratio: likewise the change of that velocity over
            the acceleration limit (the joints that have one; 0: none).
        max_jerk_ratio: likewise the change of that acceleration over the
            jerk limit (0: none).
        volume_penetrations: logged configurations touching a volume
            column (Drake); None in a dynamic run (the volume is drawn only).
        collisions: updates in collision.
        max_bound_violation: how far the command ever left the base table's
            box at its path index, rad (m) (:func:`~drake_cfvol.comanip.run.bound_figures`).
        live_box_excess_max: how far the command ever lay outside the live
            box, rad (m).
        live_box_catchup_s: the longest time the command stayed outside the
            live box, s.
        filter_steps: updates where the safety filter changed the
            admittance's request.
        filter_fallbacks: updates where the filter's QP fell back.
        filter_damper_misses: updates where the limits left no way to keep a
            damper row.
        braking_faults: updates where a damper row could not be kept within
            the acceleration and jerk limits.
        guard_stops: updates whose command the stop-path guard refused
            (the filter braked on the stop it had checked before).
        filter_box_exits: updates where the filter gave the bounds' box way
            to a damper row.
        filter_holds: updates held by a stale robot status.
        tracking_faults: updates at which the measured robot drifted from
            its command faster than the command could counter.
        faults: updates at which the human's input was non-finite or beyond
            its limit (held).
        filter_fault: the filter's latched fault (``too_many_rows`` or
            ``perceived_overlap``: the run ended there); None: none.
        ended_s: the simulated time at the run's end, s.
        safety_filter: whether the safety filter ran.
        filter_clearance_m: the filter's margin, m; None: no filter.
        max_deviation: the largest distance of the command from the
            nominal, joint by joint, rad (m).
        n_boxes: the volume's boxes.
        volume_boxes_in_scene: the volume's boxes registered in the
            diagram's SceneGraph.
        bounds_time_ms: the bounds' compute time, ms.
        build_ms: the build's steps' wall times (planning, bounding, the
            diagram), ms.
        recording_html: the recording's file; None: not recorded.
        plot_png: the plot's file; None: not plotted.
        diagram_svg: the diagram's SVG; None: not drawn.
        diagram_dot: the diagram's Graphviz source; None: not written.
        notices: notes for the user (printed as ``cfvol: note:``).
        clearance_m: the margin in force, m.
        nominal_min_clearance_m: the nominal path's own clearance (moving
            links to the obstacles at its waypoints), m.
        online: the online bounds' figures; None: fixed bounds (their keys
            are left out of the JSON).
        tracking: a dynamic run's tracking; None: a kinematic run (the
            JSON's ``dynamic`` is false, the tracking keys left out).
        problems: what went wrong, one sentence each (empty: a safe run;
            :func:`~drake_cfvol.comanip.run_problems`).
    """

    scenario: str
    cell: str
    path: str
    resolution: int
    g: int
    steps: int
    duration_s: float
    path_duration_s: float
    sim_wall_s: float
    min_clearance_m: float | None
    max_velocity_ratio: float
    max_acceleration_ratio: float
    max_jerk_ratio: float
    volume_penetrations: int | None
    collisions: int
    max_bound_violation: float
    live_box_excess_max: float
    live_box_catchup_s: float
    filter_steps: int
    filter_fallbacks: int
    filter_damper_misses: int
    braking_faults: int
    guard_stops: int
    filter_box_exits: int
    filter_holds: int
    tracking_faults: int
    faults: int
    filter_fault: str | None
    ended_s: float
    safety_filter: bool
    filter_clearance_m: float | None
    max_deviation: float
    n_boxes: int
    volume_boxes_in_scene: int
    bounds_time_ms: float
    build_ms: dict[str, float]
    recording_html: str | None
    plot_png: str | None
    diagram_svg: str | None
    diagram_dot: str | None
    notices: list[str]
    clearance_m: float
    nominal_min_clearance_m: float
    online: OnlineFigures | None = None
    tracking: TrackingFigures | None = None
    problems: list[str] = dataclasses.field(default_factory=list)

    @property
    def dynamic(self) -> bool:
        """Whether the run was dynamic (a time-stepping plant under its driver)."""
        return self.tracking is not None

    def to_dict(self) -> dict[str, Any]:
        """The summary as ``summary.json`` holds it: one key per figure, the
        online and tracking figures flat among them (left out where there
        are none), ``dynamic`` before the tracking's."""
        out = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        online, tracking, problems = out.pop("online"), out.pop("tracking"), out.pop("problems")
        if online is not None:
            out.update(dataclasses.asdict(online))
        out["dynamic"] = tracking is not None
        if tracking is not None:
            out.update(dataclasses.asdict(tracking))
        out["problems"] = problems
        return out
