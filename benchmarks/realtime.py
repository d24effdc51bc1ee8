"""Control-rate benchmark: the co-manipulation control stack alone, timed
per update.

A kinematic station built the way a Drake user would: the cell's models in
a ``MultibodyPlant`` (no dynamics), :func:`~drake_cfvol.systems.AddCoManipulation`
for the stack (path progress, the bounds one period ahead, the push's
check, the admittance, the safety filter with its SceneGraph queries), the
SceneGraph posed from the filter's command. Pushes: a steady joint torque
of the same size on every joint with seeded signs (a co-worker leaning on
the robot drives the command into a corner of the box, so the filter
works), or seeded random pushes (Drake's ``RandomSource`` through
:class:`~drake_cfvol.systems.RandomPushShaper`).

Per run: wall time per simulator step (one control update; median, p99,
max), each system's own time per update (its Python callbacks, time spent
in systems it evaluates taken out), the filter's QP solves and measured
distance pairs per update, and the run's safety figures (smallest distance
the filter measured, largest velocity ratio). ``cfvol bench --realtime``
runs it.
"""

import dataclasses
import json
import statistics
import time
from pathlib import Path

import numpy as np
from pydrake.common import RandomDistribution, RandomGenerator
from pydrake.geometry import SceneGraph
from pydrake.multibody.plant import MultibodyPlant
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder, LeafSystem
from pydrake.systems.primitives import ConstantVectorSource, RandomSource
from pydrake.systems.rendering import MultibodyPositionToGeometryPose

from drake_cfvol.algorithm.pipeline import estimate_bounds
from drake_cfvol.algorithm.planning import plan_nominal_path
from drake_cfvol.scene.workcell import load_workcell
from drake_cfvol.systems import AddCoManipulation, CoManipulationConfig, RandomPushShaper

__all__ = [
    "RealtimeBenchConfig",
    "TARGETS",
    "CELLS",
    "station",
    "run_case",
    "iiwa_case",
    "run_realtime_bench",
    "realtime_targets",
    "realtime_markdown",
    "write_realtime_outputs",
]

#: The issue's targets at a 1 ms period, whole stack per step (s).
TARGETS = {"median_s": 0.5e-3, "p99_s": 1.0e-3}

#: Cell name -> workcell file (the mesh test robot's from the tests' data).
CELLS = {
    "automotive": "automotive",
    "aerospace": "aerospace",
    "cobot": "cobot",
    "mesh": str(Path(__file__).resolve().parents[1] / "tests" / "data" / "mesh_cell.yaml"),
}


@dataclasses.dataclass
class RealtimeBenchConfig:
    """What the control-rate benchmark runs.

    Attributes:
        cells: keys of :data:`CELLS`.
        periods: control periods, s.
        pushes: "steady" (seeded signs, ``torque`` on every joint) and/or
            "random" (seeded random pushes up to ``torque``).
        updates: control updates (simulator steps) per run.
        repeats: runs per (cell, period, push), seeds 0 .. repeats-1.
        torque: N m (N) per joint.
        resolution: the bounds' R.
        path: the cell's path.
        iiwa: also time the iiwa's controller beside a loopback robot at the
            driver's 5 ms status period (:func:`iiwa_case`).
    """

    cells: list = dataclasses.field(default_factory=lambda: list(CELLS))
    periods: list = dataclasses.field(default_factory=lambda: [0.01, 0.001])
    pushes: list = dataclasses.field(default_factory=lambda: ["steady", "random"])
    updates: int = 500
    repeats: int = 2
    torque: float = 1500.0
    resolution: int = 1000
    path: str = "path1"
    iiwa: bool = True

    @classmethod
    def quick(cls) -> "RealtimeBenchConfig":
        return cls(cells=["automotive"], periods=[0.001], pushes=["steady"], updates=200, repeats=1, iiwa=False)


class _Timers:
    """Exclusive wall time per label of wrapped callbacks (time spent in a
    nested wrapped callback counts for the inner one only)."""

    def __init__(self):
        self.total, self._stack, self.counts = {}, [], {}

    def wrap(self, label, fn):
        def timed(*args, **kwargs):
            t0 = time.perf_counter()
            self._stack.append(0.0)
            try:
                return fn(*args, **kwargs)
            finally:
                inner = self._stack.pop()
                dt = time.perf_counter() - t0
                self.total[label] = self.total.get(label, 0.0) + dt - inner
                if self._stack:
                    self._stack[-1] += dt

        return timed

    def count(self, label, n=1):
        self.counts[label] = self.counts.get(label, 0) + n


def _instrument(timers, cm):
    """Wraps the stack's Python callbacks on the instances' classes (before
    the systems are built) and counts the filter's QP solves and measured
    pairs. Returns an undo function."""
    from drake_cfvol.systems import admittance, bounds_source, human_input, safety

    patches = [
        (admittance.AdmittanceDeformation_[float], "_update", "admittance"),
        (admittance.AdmittanceDeformation_[float], "_calc_commanded", "admittance"),
        (human_input.HumanInputCheck_[float], "_update", "input check"),
        (human_input.HumanInputCheck_[float], "_torque", "input check"),
        (human_input.HumanInputCheck_[float], "_wrench", "input check"),
        (human_input.HumanInputCheck_[float], "plausible", "input check"),
        (bounds_source.JointBoundsSource_[float], "_at", "bounds"),
        (safety.SafetyFilter, "_update", "safety filter"),
    ]
    saved = []
    for cls, name, label in patches:
        if name in cls.__dict__:
            saved.append((cls, name, cls.__dict__[name]))
            setattr(cls, name, timers.wrap(label, cls.__dict__[name]))
    for cls, name, counter in cm:
        original = cls.__dict__[name]
        saved.append((cls, name, original))
        setattr(cls, name, counter(original))

    def undo():
        for cls, name, fn in saved:
            setattr(cls, name, fn)

    return undo


def _counters(timers):
    """(class, method, wrapper factory) that count the filter's QP solves
    and the pairs its damper measured."""
    from drake_cfvol.systems import damper

    def solves(fn):
        def counted(*args, **kwargs):
            timers.count("qp_solves")
            return fn(*args, **kwargs)

        return counted

    def pairs(fn):
        def counted(*args, **kwargs):
            rows = fn(*args, **kwargs)
            measured = getattr(rows, "measured", None)  # before the broad phase: every non-NaN distance
            timers.count(
                "distance_pairs", int(np.count_nonzero(~np.isnan(rows.distances) if measured is None else measured))
            )
            timers.count("rows", len(rows.b))
            return rows

        return counted

    try:  # the QP class of this checkout (StagedQP before the constraint interface)
        from drake_cfvol.systems.constraints import PriorityQP as qp
    except ImportError:
        from drake_cfvol.systems.safety import StagedQP as qp
    return [(qp, "solve", solves), (damper.VelocityDamper, "rows", pairs)]


def station(wc, table, *, period: float, push: str, torque: float, seed: int):
    """A kinematic station of the workcell with the control stack added by
    AddCoManipulation, pushed steadily (seeded signs) or randomly.
    Returns (diagram, the CoManipulationSystems, the push's seed or None)."""
    builder = DiagramBuilder()
    sg = builder.AddSystem(SceneGraph())
    plant = MultibodyPlant(0.0)  # posed from the command: no state of its own in the diagram
    plant.RegisterAsSourceForSceneGraph(sg)
    wc.add_to_plant(plant)
    plant.Finalize()
    cm = AddCoManipulation(
        builder,
        plant=plant,
        scene_graph=sg,
        robot=wc.robot_name,
        table=table,
        tool_frame=wc.tool_frame.name(),
        period=period,
        measured_state=False,
        config=CoManipulationConfig(velocity_limits=list(wc.velocity_limits)),
    )
    to_pose = builder.AddSystem(MultibodyPositionToGeometryPose(plant))
    builder.Connect(cm.commanded_position_output, to_pose.get_input_port())
    builder.Connect(to_pose.get_output_port(), sg.get_source_pose_port(plant.get_source_id()))
    k = table.k
    builder.Connect(builder.AddSystem(ConstantVectorSource(np.zeros(6))).get_output_port(), cm.human_wrench_input)
    if push == "steady":
        signs = np.random.default_rng(seed).choice([-1.0, 1.0], size=k)
        builder.Connect(
            builder.AddSystem(ConstantVectorSource(torque * signs)).get_output_port(), cm.human_torque_input
        )
    else:
        source = builder.AddSystem(RandomSource(RandomDistribution.kUniform, k + 1, sampling_interval_sec=0.5))
        shaper = builder.AddSystem(RandomPushShaper(k, probability=0.7, max_torque=torque))
        builder.Connect(source.get_output_port(), shaper.get_input_port(0))
        builder.Connect(shaper.get_output_port(0), cm.human_torque_input)
    return builder.Build(), cm


def _spread(times) -> dict:
    """Median, p99 and max of wall times (s)."""
    times = np.asarray(times, float)
    return {
        "median_s": float(np.median(times)),
        "p99_s": float(np.percentile(times, 99)),
        "max_s": float(times.max()),
    }


def run_case(wc, table, *, period: float, push: str, updates: int, torque: float, seed: int) -> dict:
    """One timed run: the stack's figures (see the module's documentation)."""
    timers = _Timers()
    undo = _instrument(timers, _counters(timers))
    try:
        diagram, cm = station(wc, table, period=period, push=push, torque=torque, seed=seed)
        sim = Simulator(diagram)
        ctx = sim.get_mutable_context()
        if push == "random":
            diagram.SetRandomContext(ctx, RandomGenerator(seed))
        sim.Initialize()
        sctx = cm.safety.GetMyContextFromRoot(ctx)
        steps = int(updates)
        wall, cpu, dmin, ratio = np.zeros(steps), np.zeros(steps), np.inf, 0.0
        per_step = {}
        for i in range(steps):
            before = dict(timers.total)
            t0, c0 = time.perf_counter(), time.thread_time()
            sim.AdvanceTo((i + 1) * period)
            wall[i], cpu[i] = time.perf_counter() - t0, time.thread_time() - c0
            for label, t in timers.total.items():
                per_step.setdefault(label, []).append(t - before.get(label, 0.0))
            dmin = min(dmin, float(cm.safety.min_distance_output.Eval(sctx)[0]))
            ratio = max(ratio, float(cm.safety.velocity_ratio_output.Eval(sctx)[0]))
        if hasattr(cm.safety, "qp_solves"):  # the filter counts its own (its rounds are one compiled call)
            timers.counts["qp_solves"] = cm.safety.qp_solves
        status = {
            n: float(cm.safety.GetOutputPort(n).Eval(sctx)[0])
            for n in ("filter_count", "fallback_count", "damper_misses", "box_exits")
        }
    finally:
        undo()
    updates = steps  # one filter update per step
    return {
        "cell": wc.name,
        "period_s": period,
        "push": push,
        "seed": seed,
        "steps": steps,
        **_spread(wall),
        "cpu_median_s": float(np.median(cpu)),
        "cpu_p99_s": float(np.percentile(cpu, 99)),
        "per_system": {label: _spread(ts) for label, ts in per_step.items()},
        "qp_solves_per_update": timers.counts.get("qp_solves", 0) / updates,
        "distance_pairs_per_update": timers.counts.get("distance_pairs", 0) / updates,
        "rows_per_update": timers.counts.get("rows", 0) / updates,
        "num_pairs": cm.safety.num_pairs,
        "min_distance_m": dmin,
        "max_velocity_ratio": ratio,
        "filter_active_share": status["filter_count"] / updates,
        "fallbacks": status["fallback_count"],
        "damper_misses": status["damper_misses"],
        "box_exits": status["box_exits"],
        "wall_per_sim_s": float(wall.sum()) / (steps * period),
    }


def iiwa_case(wc, table, *, updates: int, torque: float, seed: int) -> dict:
    """The iiwa's controller as it runs beside the robot
    (:func:`~drake_cfvol.comanip.iiwa.add_iiwa_controller`, its period the
    driver's 5 ms status period) against a loopback robot over in-memory
    LCM: each period the robot reports a new status (its position the last
    command received, exactly tracked; a steady external torque of
    ``torque`` N m per joint with seeded signs), then the controller's
    diagram advances one period. Wall time per period (the status received,
    the update, the command sent) and the headroom: the period over it."""
    from drake import lcmt_iiwa_command, lcmt_iiwa_status
    from pydrake.lcm import DrakeLcm
    from pydrake.systems.lcm import LcmInterfaceSystem

    from drake_cfvol.comanip.iiwa import IIWA_STATUS_PERIOD, add_iiwa_controller

    k = table.k
    lcm = DrakeLcm("memq://")
    builder = DiagramBuilder()
    builder.AddSystem(LcmInterfaceSystem(lcm))
    config = CoManipulationConfig(velocity_limits=list(wc.velocity_limits))
    cm, _ = add_iiwa_controller(builder, workcell=wc, table=table, lcm=lcm, period=IIWA_STATUS_PERIOD, config=config)
    sim = Simulator(builder.Build())
    commanded = np.array(table.nominal[0], float)

    def on_command(data):
        commanded[:] = lcmt_iiwa_command.decode(data).joint_position

    lcm.Subscribe("IIWA_COMMAND", on_command)
    tau = torque * np.random.default_rng(seed).choice([-1.0, 1.0], size=k)
    steps = int(updates)
    wall = np.zeros(steps)
    for i in range(steps):
        status = lcmt_iiwa_status()
        status.utime, status.num_joints = int((i + 1) * IIWA_STATUS_PERIOD * 1e6), k
        status.joint_position_measured = list(commanded)
        status.joint_position_commanded = list(commanded)
        status.joint_position_ipo = list(commanded)
        for name in ("joint_velocity_estimated", "joint_torque_measured", "joint_torque_commanded"):
            setattr(status, name, [0.0] * k)
        status.joint_torque_external = list(tau)
        lcm.Publish("IIWA_STATUS", status.encode())
        t0 = time.perf_counter()
        sim.AdvanceTo((i + 1) * IIWA_STATUS_PERIOD)
        wall[i] = time.perf_counter() - t0
        lcm.HandleSubscriptions(0)
    sctx = cm.safety.GetMyContextFromRoot(sim.get_context())
    spread = _spread(wall)
    return {
        "cell": wc.name,
        "seed": seed,
        "steps": steps,
        "period_s": IIWA_STATUS_PERIOD,
        **spread,
        "headroom_median": IIWA_STATUS_PERIOD / spread["median_s"],
        "headroom_p99": IIWA_STATUS_PERIOD / spread["p99_s"],
        "holds": float(cm.safety.hold_count_output.Eval(sctx)[0]),
        "filter_active_share": float(cm.safety.filter_count_output.Eval(sctx)[0]) / steps,
    }


def _cell(name: str, cfg: RealtimeBenchConfig):
    wc = load_workcell(CELLS[name])
    path = plan_nominal_path(wc, *wc.configuration(cfg.path), seed=0)
    return wc, estimate_bounds(wc, path, resolution=cfg.resolution)


def reference_step(steps: int = 2000) -> float:
    """The machine's speed at the moment, in the framework's own terms: the
    median wall time (s) of a 1 ms simulator step of a diagram holding one
    Python LeafSystem whose periodic update reads and writes a 6-vector
    (no work of ours). Taken before and after the rows, so that runs on a
    shared machine can be told apart from changes of the code."""

    class Reference(LeafSystem):
        def __init__(self):
            super().__init__()
            self.DeclareDiscreteState(6)
            self.DeclarePeriodicDiscreteUpdateEvent(period_sec=1e-3, offset_sec=0.0, update=self._update)

        def _update(self, context, state):
            state.get_mutable_vector(0).SetFromVector(context.get_discrete_state(0).CopyToVector() + 1.0)

    builder = DiagramBuilder()
    builder.AddSystem(Reference())
    sim = Simulator(builder.Build())
    sim.Initialize()
    times, t = [], 0.0
    for _ in range(steps):
        t += 1e-3
        t0 = time.perf_counter()
        sim.AdvanceTo(t)
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def run_realtime_bench(cfg: RealtimeBenchConfig, *, progress: bool = True) -> dict:
    """Every (cell, period, push, seed) of ``cfg``; rows and their medians."""
    reference = [reference_step()]
    runs = []
    for name in cfg.cells:
        wc, table = _cell(name, cfg)
        for period in cfg.periods:
            for push in cfg.pushes:
                for seed in range(cfg.repeats):
                    row = run_case(
                        wc, table, period=period, push=push, updates=cfg.updates, torque=cfg.torque, seed=seed
                    )
                    row["cell"] = name
                    runs.append(row)
                    if progress:
                        print(
                            f"{name} {period * 1e3:g} ms {push} seed {seed}: median {row['median_s'] * 1e3:.3f} "
                            f"ms, p99 {row['p99_s'] * 1e3:.3f} ms, max {row['max_s'] * 1e3:.3f} ms",
                            flush=True,
                        )
    iiwa = []
    if cfg.iiwa:
        wc, table = _cell("cobot", cfg)
        for seed in range(cfg.repeats):
            iiwa.append(iiwa_case(wc, table, updates=cfg.updates, torque=cfg.torque, seed=seed))
            if progress:
                row = iiwa[-1]
                print(
                    f"iiwa controller 5 ms seed {seed}: median {row['median_s'] * 1e3:.3f} ms, headroom "
                    f"{row['headroom_median']:.1f}x",
                    flush=True,
                )
    reference.append(reference_step())
    return {
        "config": dataclasses.asdict(cfg),
        "runs": runs,
        "summary": _summary(runs),
        "iiwa": iiwa,
        "reference_step_s": reference,
    }


def _summary(runs) -> list[dict]:
    """Per (cell, period, push): the medians over the repeats."""
    keys = sorted({(r["cell"], r["period_s"], r["push"]) for r in runs}, key=lambda x: (x[0], -x[1], x[2]))
    out = []
    for cell, period, push in keys:
        rs = [r for r in runs if (r["cell"], r["period_s"], r["push"]) == (cell, period, push)]
        med = lambda f: statistics.median(f(r) for r in rs)  # noqa: E731
        labels = sorted({label for r in rs for label in r["per_system"]})
        out.append(
            {
                "cell": cell,
                "period_s": period,
                "push": push,
                "repeats": len(rs),
                "median_s": med(lambda r: r["median_s"]),
                "p99_s": med(lambda r: r["p99_s"]),
                "max_s": max(r["max_s"] for r in rs),
                "cpu_median_s": med(lambda r: r["cpu_median_s"]),
                "cpu_p99_s": med(lambda r: r["cpu_p99_s"]),
                "per_system_median_s": {
                    lb: med(lambda r: r["per_system"].get(lb, {}).get("median_s", 0.0)) for lb in labels
                },
                "per_system_p99_s": {lb: med(lambda r: r["per_system"].get(lb, {}).get("p99_s", 0.0)) for lb in labels},
                "qp_solves_per_update": med(lambda r: r["qp_solves_per_update"]),
                "distance_pairs_per_update": med(lambda r: r["distance_pairs_per_update"]),
                "rows_per_update": med(lambda r: r["rows_per_update"]),
                "num_pairs": rs[0]["num_pairs"],
                "filter_active_share": med(lambda r: r["filter_active_share"]),
                "min_distance_m": min(r["min_distance_m"] for r in rs),
                "max_velocity_ratio": max(r["max_velocity_ratio"] for r in rs),
                "fallbacks": sum(r["fallbacks"] for r in rs),
                "damper_misses": sum(r["damper_misses"] for r in rs),
                "wall_per_sim_s": med(lambda r: r["wall_per_sim_s"]),
            }
        )
    return out


def realtime_targets(result: dict) -> list[tuple[str, bool, str]]:
    """The 1 ms targets per (cell, push): (name, met, figures)."""
    out = []
    for s in result["summary"]:
        if abs(s["period_s"] - 1e-3) > 1e-12:
            continue
        met = s["median_s"] <= TARGETS["median_s"] and s["p99_s"] <= TARGETS["p99_s"]
        out.append(
            (
                f"{s['cell']} {s['push']} 1 ms",
                met,
                f"median {s['median_s'] * 1e3:.3f} ms (<= 0.5), p99 {s['p99_s'] * 1e3:.3f} ms (<= 1.0)",
            )
        )
    return out


def realtime_markdown(result: dict, machine: dict | None = None) -> str:
    cfg = result["config"]
    lines = [
        "# Control-rate benchmark",
        "",
        f"The control stack alone on a kinematic station built with `AddCoManipulation` ({cfg['updates']} "
        f"updates per run, {cfg['repeats']} seeded runs per row, medians over the runs; p99 is the median "
        f"of the runs' p99s, max the largest step of any run; pushes {cfg['torque']:g} N m per joint). "
        "Wall time per simulator step (one control update; and the step's CPU time, the thread's own, which "
        "other work on a shared machine disturbs less), each system's own wall time per update, the filter's "
        "QP solves and measured distance pairs per update. `cfvol bench --realtime` writes it; paired runs "
        "against the code before the filter's rework: [before_after.md](before_after.md).",
        "",
    ]
    if machine:
        lines += [
            f"Machine: {machine.get('cpu', '?')}, {machine.get('cores', '?')} cores, shared with other work "
            "while measured (timings are noisy).",
            "",
        ]
    if result.get("reference_step_s"):
        ref = ", ".join(f"{x * 1e6:.1f}" for x in result["reference_step_s"])
        lines += [
            f"The machine's speed in the same run (`reference_step`: a 1 ms step of a diagram of one Python "
            f"LeafSystem that reads and writes a 6-vector, before and after the rows): {ref} us. Compare runs "
            "by it: the same code measures slower on a machine whose reference step is slower.",
            "",
        ]
    labels = sorted({lb for s in result["summary"] for lb in s["per_system_median_s"]})
    head = (
        "| cell | period | push | step median ms | p99 ms | max ms | CPU median ms | CPU p99 ms | "
        + " | ".join(f"{lb} ms" for lb in labels)
        + " | QP solves/upd | pairs/upd | rows/upd | active | min dist mm | v ratio | wall/sim s |"
    )
    lines += [head, "|" + "---|" * (head.count("|") - 1)]
    for s in result["summary"]:
        sys_cols = " | ".join(f"{s['per_system_median_s'].get(lb, 0.0) * 1e3:.3f}" for lb in labels)
        lines.append(
            f"| {s['cell']} | {s['period_s'] * 1e3:g} ms | {s['push']} | {s['median_s'] * 1e3:.3f} | "
            f"{s['p99_s'] * 1e3:.3f} | {s['max_s'] * 1e3:.3f} | {s['cpu_median_s'] * 1e3:.3f} | "
            f"{s['cpu_p99_s'] * 1e3:.3f} | {sys_cols} | {s['qp_solves_per_update']:.2f} | "
            f"{s['distance_pairs_per_update']:.1f} / {s['num_pairs']} | {s['rows_per_update']:.1f} | "
            f"{s['filter_active_share']:.2f} | {s['min_distance_m'] * 1e3:.1f} | {s['max_velocity_ratio']:.3f} | "
            f"{s['wall_per_sim_s']:.2f} |"
        )
    lines += ["", "## Targets at 1 ms (median <= 0.5 ms, p99 <= 1.0 ms per step)", ""]
    lines += [f"- {name}: {'met' if met else 'missed'} ({text})" for name, met, text in realtime_targets(result)]
    iiwa = result.get("iiwa") or []
    if iiwa:
        med = statistics.median(r["median_s"] for r in iiwa)
        p99 = statistics.median(r["p99_s"] for r in iiwa)
        lines += [
            "",
            "## The iiwa's controller at the driver's 5 ms status period",
            "",
            "`add_iiwa_controller` (period 5 ms) against a loopback robot over in-memory LCM that reports a new "
            "status every period (the last command as its position, a steady external torque of "
            f"{cfg['torque']:g} N m per joint with seeded signs, as the steady pushes above): wall time per "
            "period, the status "
            f"received, the update and the command sent ({len(iiwa)} runs of {iiwa[0]['steps']} periods, medians).",
            "",
            "| median ms | p99 ms | max ms | headroom (median) | headroom (p99) | filter active | holds |",
            "|---|---|---|---|---|---|---|",
            f"| {med * 1e3:.3f} | {p99 * 1e3:.3f} | {max(r['max_s'] for r in iiwa) * 1e3:.3f} | "
            f"{5e-3 / med:.1f}x | {5e-3 / p99:.1f}x | "
            f"{statistics.median(r['filter_active_share'] for r in iiwa):.2f} | "
            f"{max(r['holds'] for r in iiwa):g} |",
            "",
            f"- headroom >= 5x at the 5 ms status period: {'met' if 5e-3 / med >= 5.0 else 'missed'} "
            f"(median {5e-3 / med:.1f}x)",
        ]
    return "\n".join(lines) + "\n"


def write_realtime_outputs(result: dict, out_dir, machine: dict | None = None) -> dict:
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "results.json").write_text(json.dumps(result, indent=1, default=float))
    (out / "results.md").write_text(realtime_markdown(result, machine))
    return {"json": str(out / "results.json"), "markdown": str(out / "results.md")}
