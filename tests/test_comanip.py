"""Co-manipulation runs from the bundled scenarios, end to end."""

import os
import re
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest

import drake_cfvol as cf
from drake_cfvol.comanip import build_comanipulation_diagram, load_scenario, run_scenario

#: Most tests run the bundled scenarios on uncertified bounds: certifying a
#: path takes tens of seconds, and what they test does not depend on it.
#: The scenarios' own default (certified) runs in the slow group.
FAST = "{bounds: {certify: null}}"

#: The scenario whose run writes the recording, the plot and the diagram
#: (the other writes its logs and summary only, as record=False asks).
RECORDED = "automotive_push"


# The aerospace run (14 s of a 7-DoF robot, about 10 s here) is in the slow group, which CI runs too.
@pytest.fixture(scope="module", params=["automotive_push", pytest.param("aerospace_push", marks=pytest.mark.slow)])
def run(request, tmp_path_factory):
    out = tmp_path_factory.mktemp(request.param)
    files = request.param == RECORDED
    return request.param, out, run_scenario(request.param, out, scenario_text=FAST, record=files, plot=files, svg=files)


def test_run_inside_bounds_and_free(run):
    """Commanded stays inside the bounds and, checked by Drake at every logged
    step, free of the real scene."""
    name, out, summary = run
    logs = np.load(out / "logs.npz")
    q, lo, hi = logs["commanded_position"], logs["lower"], logs["upper"]
    assert len(q) == summary.steps > 100
    # Inside to rounding: the filter's state was set against the bounds one
    # period ahead, looked up at a path index rounded differently.
    assert np.all(q >= lo - 1e-12) and np.all(q <= hi + 1e-12)
    wc = cf.load_workcell(summary.cell)
    q_update = logs["update_commanded_position"]
    free = np.array(wc.checker.CheckConfigsCollisionFree(q_update), bool)
    assert free.all(), f"{(~free).sum()} steps collide at the update rate"
    assert summary.collisions == 0 and summary.max_bound_violation <= 1e-12
    # The human really moved the robot off the nominal (Drake-independent:
    # the logged command against the logged nominal).
    assert np.abs(q - logs["nominal"]).max() > 0.2
    assert summary.filter_fallbacks == 0 and summary.faults == 0


def test_run_within_velocity_limits(run):
    """No joint of the commanded motion moves faster than its velocity
    limit (from the logs, against the workcell's limits), the summary says
    the same, and the path slowed down rather than let the bounds race."""
    name, out, summary = run
    logs = np.load(out / "logs.npz")
    t, q = logs["update_commanded_position_t"], logs["update_commanded_position"]
    wc = cf.load_workcell(summary.cell)
    np.testing.assert_allclose(np.diff(t), 0.01)  # every update
    ratio = (np.abs(np.diff(q, axis=0)) / 0.01 / wc.velocity_limits).max()
    assert ratio == pytest.approx(summary.max_velocity_ratio) and ratio <= 1.0
    scenario, _ = load_scenario(name)
    assert summary.path_duration_s >= scenario.path.duration - 1e-9
    assert summary.duration_s == pytest.approx(
        scenario.control.path_progress.start_time + summary.path_duration_s + scenario.path.end_hold
    )


def test_run_reports_volume_and_clearance(run):
    """The summary counts logged configurations touching the volume in the
    diagram's scene (merged boxes, conservative: at least the count against
    the exact columns in Drake's reference scene, recounted here), and the
    clearance of the moving links only, which the logged trace matches."""
    from drake_cfvol.algorithm.reference import ReferenceScene

    name, out, summary = run
    logs = np.load(out / "logs.npz")
    wc = cf.load_workcell(summary.cell)
    scenario, file = load_scenario(name, scenario_text=FAST)
    cm = build_comanipulation_diagram(scenario, base_dir=file.parent)
    hits = ReferenceScene(wc, cm.bounds.volume.volume).volume_hits(logs["commanded_position"])
    assert summary.volume_penetrations >= int(hits.sum())
    # The clearance, recounted by the workcell's own Drake scene at every
    # update (not the diagram's monitor that the summary read).
    recount = min(
        min(wc.obstacle_distances(q, 2.0, changeable_only=True).values()) for q in logs["update_commanded_position"]
    )
    assert summary.min_clearance_m == pytest.approx(recount, abs=1e-9)


def test_filter_count_matches_what_it_changed(run):
    """The filter's own count of the updates it acted on (its internal
    counter) matches what the logs show it did: the updates where its
    command differs from the admittance's request, both logged at the
    update rate."""
    name, out, summary = run
    logs = np.load(out / "logs.npz")
    # An update's command answers the request the admittance held before
    # that update (both are states updated at the same instant).
    q, desired = logs["update_commanded_position"], logs["update_desired_position"]
    changed = np.r_[False, np.abs(q[1:] - desired[:-1]).max(axis=1) > 1e-9]
    steps = np.diff(logs["update_filter_count"][:, 0], prepend=0.0)
    assert set(np.unique(steps)) <= {0.0, 1.0}
    acted = np.flatnonzero(steps > 0)
    assert len(acted) == summary.filter_steps
    np.testing.assert_array_equal(acted, np.flatnonzero(changed))


def test_outputs_written(run):
    """The run writes a self-contained HTML, a PNG plot and the diagram; a
    run asked for none writes none (logs and summary only)."""
    name, out, summary = run
    if name != RECORDED:
        assert summary.recording_html is summary.plot_png is summary.diagram_dot is None
        assert sorted(p.name for p in out.iterdir()) == ["logs.npz", "summary.json"]
        return
    html = Path(summary.recording_html).read_text()
    assert "<script" in html and not re.search(r"<script[^>]+src=", html)
    assert not re.search(r"<link[^>]+stylesheet", html)
    # (three.js's inlined code mentions URLs in strings; no tag loads one.)
    assert not re.search(r"<(script|link|img|iframe)[^>]+(src|href)=\"https?://", html)
    assert Path(summary.plot_png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "admittance" in Path(summary.diagram_dot).read_text()


def test_the_filter_warm_up_compiles_what_a_run_uses(run):
    """The safety filter's compiled parts, as the made-up two-link station
    of :func:`drake_cfvol.systems.filter.compile_ahead.warm_up` calls them, have the
    signatures a real run (the cell's robot and obstacles) used: one each,
    so a fresh cache compiles each once, ahead of the run."""
    from drake_cfvol.systems.filter import compile_ahead

    compiled = compile_ahead._COMPILED
    used = {f.py_func.__name__: list(f.signatures) for f in compiled}
    # The run called each at most once (the braking parts only under acceleration limits).
    assert all(len(v) <= 1 for v in used.values()) and sum(map(len, used.values())) >= 8, used
    compile_ahead._two_link_run()  # the warm-up's station, run whether cached or not
    after = {f.py_func.__name__: list(f.signatures) for f in compiled}
    assert all(after[name] == v for name, v in used.items() if v) and all(len(v) == 1 for v in after.values())


def _chromium():
    for exe in ("chromium", "chromium-browser", "google-chrome"):
        if shutil.which(exe):
            return shutil.which(exe)
    return None


def _screenshot(cmd, shot, *, tries=3, timeout_s=90.0):
    """Runs headless Chromium until it has written ``shot``. Chromium on a
    loaded 2-core machine sometimes writes the screenshot and then never
    exits, or hangs before it: the file is taken once its size is steady,
    the process is killed, and a hung try is repeated with a fresh profile."""
    for _ in range(tries):
        shot.unlink(missing_ok=True)
        profile = tempfile.mkdtemp()
        proc = subprocess.Popen(
            [c if not c.startswith("--user-data-dir=") else f"--user-data-dir={profile}" for c in cmd],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        deadline, last = time.monotonic() + timeout_s, -1
        try:
            while time.monotonic() < deadline:
                exited = proc.poll() is not None
                size = shot.stat().st_size if shot.is_file() else -1
                if size > 0 and (size == last or exited):
                    return True
                if exited and size <= 0:
                    break
                last = size
                time.sleep(0.5)
        finally:
            if proc.poll() is None:
                proc.kill()
            proc.wait()
            shutil.rmtree(profile, ignore_errors=True)
    return False


@pytest.mark.slow  # headless Chromium: 5-10 s per recording at 400 x 300 (50-150 s at 800 x 600)
def test_recording_renders_in_headless_chromium(run):
    """The recording, opened offline in headless Chromium, shows a non-blank
    scene (many distinct colours, not one background)."""
    name, out, summary = run
    if name != RECORDED:
        pytest.skip(f"only {RECORDED}'s run is recorded")
    exe = _chromium()
    if exe is None:
        if os.environ.get("CI"):
            pytest.fail("CI must install Debian's chromium (see .ci/run)")
        pytest.skip("chromium is not installed")
    shot = out / "shot.png"
    cmd = [
        exe,
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-quic",
        "--no-first-run",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--enable-unsafe-swiftshader",
        f"--user-data-dir={tempfile.mkdtemp()}",
        "--window-size=400,300",
        "--virtual-time-budget=1000",
        f"--screenshot={shot}",
        Path(summary.recording_html).as_uri(),
    ]
    assert _screenshot(cmd, shot), f"headless Chromium wrote no screenshot in 3 tries: {' '.join(cmd)}"
    from matplotlib.image import imread

    img = imread(shot)[..., :3]
    colours = np.unique((img.reshape(-1, 3) * 255).astype(np.uint8), axis=0)
    assert len(colours) > 200
    # The robot is violet (no category is): enough clearly violet pixels that
    # the camera frames it, not a speck in the distance.
    r, g, b = img[..., 0], img[..., 1], img[..., 2]
    violet = (b > 0.45) & (r > 0.3) & (g < 0.8 * r) & (r < b)
    assert np.count_nonzero(violet) > 0.01 * violet.size


@pytest.mark.slow
def test_volume_in_the_diagrams_scene_at_r20000():
    """At R = 20000 the whole volume is proximity geometry of the diagram's
    own SceneGraph, merged into at most 1500 boxes that hold every column,
    and the scene's query port is exported."""
    import dataclasses

    from pydrake.geometry import Role

    scenario, file = load_scenario("aerospace_push", scenario_text=FAST)
    scenario = dataclasses.replace(scenario, bounds=dataclasses.replace(scenario.bounds, resolution=20000))
    cm = build_comanipulation_diagram(scenario, base_dir=file.parent)
    vol = cm.bounds.volume.volume
    assert vol.n_boxes > 1500 and cm.volume_boxes["count"] <= 1500
    inspector = cm.scene_graph.model_inspector()
    names = [inspector.GetName(g) for g in inspector.GetAllGeometryIds(Role.kProximity)]
    assert sum(n.startswith("cfvol_volume_") for n in names) == cm.volume_boxes["count"]
    centres, sizes, _ = vol.merged_boxes(1500)
    lo, hi = centres - sizes / 2, centres + sizes / 2
    cc, cs = vol.boxes()
    for c, s in zip(cc, cs):
        assert np.any(np.all((lo <= c - s / 2 + 1e-9) & (hi >= c + s / 2 - 1e-9), axis=1))
    ports = {cm.diagram.get_output_port(i).get_name() for i in range(cm.diagram.num_output_ports())}
    assert "query_object" in ports


def test_every_system_named():
    """Every system of a built diagram (log sinks, adders, the visualizer,
    SceneGraph) has a chosen name, so the diagram's SVG names them all."""
    scenario, file = load_scenario(
        "automotive_random", scenario_text="{human: {reactive: {gain: 10.0}}, bounds: {certify: null}}"
    )
    cm = build_comanipulation_diagram(scenario, base_dir=file.parent, meshcat=None)
    names = [sys.get_name() for sys in cm.diagram.GetSystems()]
    assert len(names) == len(set(names)) and not any(n.startswith("drake/") or "@" in n for n in names)
    assert {
        "admittance",
        "joint_bounds",
        "joint_bounds_now",
        "safety_filter",
        "clearance_monitor",
        "reactive_coworker",
        "random_pushes",
        "push_sum",
        "log_commanded_position",
        "scene_graph",
    } <= set(names)


def test_scenario_diagram_is_built_by_add_comanipulation(monkeypatch):
    """The scenario runner wires the control chain with the same
    AddCoManipulation call a user's station makes: called once, with the
    scenario's control section (its period, gains and filter), and the
    systems it returns are the diagram's."""
    import drake_cfvol.comanip.diagram as C

    calls = []
    real = C.AddCoManipulation

    def spy(builder, **kw):
        calls.append(kw)
        return real(builder, **kw)

    monkeypatch.setattr(C, "AddCoManipulation", spy)
    scenario, file = load_scenario(
        "automotive_push",
        scenario_text="{bounds: {certify: null}, control: {period: "
        "0.02, admittance: {mass: 4.0}, safety_filter: {damper_gain: 0.7}}}",
    )
    cm = build_comanipulation_diagram(scenario, base_dir=file.parent)
    (kw,) = calls
    assert kw["period"] == 0.02 and not kw["measured_state"]
    assert kw["config"].admittance == scenario.control.admittance and kw["config"].admittance.mass == 4.0
    assert kw["config"].safety_filter == scenario.control.safety_filter
    assert cm.diagram.GetSubsystemByName("safety_filter") is cm.control.safety
    assert cm.control.safety.damper_gain == 0.7 and cm.control.admittance.period == 0.02
    assert cm.progress is cm.control.progress


def test_diagram_ports_named():
    """The factory's diagram exports its ports by name."""
    scenario, file = load_scenario("automotive_push", scenario_text=FAST)
    cm = build_comanipulation_diagram(scenario, base_dir=file.parent)
    names = {cm.diagram.get_output_port(i).get_name() for i in range(cm.diagram.num_output_ports())}
    assert {"path_index", "lower", "upper", "nominal", "commanded_position", "min_distance"} <= names


def test_table_loaded_from_disk_builds_a_diagram(tmp_path):
    """A bounds table saved and loaded again (no volume kept) still builds a
    co-manipulation diagram: its volume is grown again, with the same columns."""
    from pydrake.systems.analysis import Simulator

    scenario, file = load_scenario("automotive_push", scenario_text=FAST)
    wc = cf.load_workcell(scenario.cell.name)
    path = cf.plan_nominal_path(wc, *wc.configuration(scenario.path.name), seed=scenario.random_seed)
    table = cf.estimate_bounds(wc, path, resolution=scenario.bounds.resolution)
    loaded = cf.BoundsTable.load(table.save(tmp_path / "b.npz"))
    assert loaded.volume is None
    cm = build_comanipulation_diagram(scenario, base_dir=file.parent, path=path, bounds=loaded)
    assert cm.bounds.volume.volume.n_boxes == table.volume.volume.n_boxes
    np.testing.assert_array_equal(cm.bounds.volume.volume.heights, table.volume.volume.heights)
    sim = Simulator(cm.diagram)
    sim.AdvanceTo(0.2)
    q = cm.diagram.GetOutputPort("commanded_position").Eval(sim.get_context())
    np.testing.assert_allclose(q, path.waypoints[0])  # before start_time the robot holds the start


def test_unknown_scenario():
    """An unknown scenario lists the bundled ones."""
    with pytest.raises(cf.CfvolError, match="automotive_push"):
        load_scenario("nope")


@pytest.mark.parametrize(
    "text, field, says",
    [
        ("bounds:\n  resolution: abc\n", "bounds.resolution", "must be an integer, got 'abc'"),
        ("cell:\n  name: nocell\n", "cell.name", "neither a built-in cell"),
        ("cell:\n  name: ../nope.yaml\n", "cell.name", "does not exist"),
        ("control:\n  admittance:\n    mass: x\n", "control.admittance.mass", "must be a number"),
        ("resolutoin: 5\n", "resolutoin", "not a field of Scenario"),
        ("simulation:\n  log_period: 0\n", "simulation.log_period", "must be > 0"),
        ("bounds:\n  params:\n    h_maks: 1.0\n", "bounds.params.h_maks", "not a field of VolumeParamsConfig"),
    ],
)
def test_scenario_field_errors(tmp_path, text, field, says):
    """Each bad scenario field is named with its file and the fix, at load time
    (before anything is planned)."""
    f = tmp_path / "s.yaml"
    f.write_text(text)
    with pytest.raises(cf.ScenarioError, match=says) as e:
        load_scenario(f)
    assert e.value.field == field and str(f) in str(e.value)


def test_scenario_missing_file(tmp_path):
    """A scenario path that does not exist is named as a missing file."""
    with pytest.raises(cf.ScenarioError, match="does not exist"):
        load_scenario(tmp_path / "nope.yaml")


def test_missing_dot_notice(tmp_path, monkeypatch):
    """Without Graphviz the diagram's source is written and a one-line
    notice names what was skipped and how to get it."""
    from pydrake.systems.framework import DiagramBuilder
    from pydrake.systems.primitives import ConstantVectorSource

    from drake_cfvol.comanip import missing_dot_notice, write_diagram_svg

    b = DiagramBuilder()
    b.AddSystem(ConstantVectorSource([1.0]))
    monkeypatch.setenv("PATH", str(tmp_path))  # no dot here
    files = write_diagram_svg(b.Build(), tmp_path / "diagram")
    assert "diagram_svg" not in files and (tmp_path / "diagram.dot").is_file()
    note = missing_dot_notice(tmp_path / "diagram")
    assert "\n" not in note and "diagram.svg" in note and "install graphviz" in note.lower()


def test_scenario_text_overrides_the_file():
    """--scenario-text is read over the file (Drake's yaml_load_typed with
    defaults): the named fields change, every other field keeps the file's
    value, nested configs merge."""
    base, _ = load_scenario("automotive_push")
    s, _ = load_scenario(
        "automotive_push",
        scenario_text="{bounds: {resolution: 2000}, simulation: {simulator_config: "
        "{target_realtime_rate: 0.5}}, human: {random_pushes: "
        "{max_torque: 11.0}}, control: {admittance: {mass: 3.0}}}",
    )
    assert s.bounds.resolution == 2000 and s.simulation.simulator_config.target_realtime_rate == 0.5
    assert s.human.random_pushes.max_torque == 11.0 and s.human.random_pushes.count == base.human.random_pushes.count
    assert s.human.pushes == base.human.pushes and s.path == base.path
    assert s.control.admittance.mass == 3.0 and s.control.admittance.damping == base.control.admittance.damping
    assert s.control.safety_filter == base.control.safety_filter and s.bounds.certify == base.bounds.certify
    assert s.simulation.simulator_config.integration_scheme == base.simulation.simulator_config.integration_scheme


def test_minimal_scenario_gets_the_defaults(tmp_path):
    """A file naming only its cell gets every other field from Scenario()'s
    defaults, including Drake's SimulatorConfig and our VisualizationConfig."""
    from drake_cfvol.comanip import Scenario

    f = tmp_path / "mini.yaml"
    f.write_text("cell: {name: aerospace}\n")
    s, _ = load_scenario(f)
    d = Scenario()
    assert s.cell.name == "aerospace" and s.bounds.resolution == d.bounds.resolution and s.human.pushes == []
    assert s.simulation.simulator_config.max_step_size == d.simulation.simulator_config.max_step_size
    vis = s.simulation.visualization
    assert vis.publish_period == d.simulation.visualization.publish_period and not vis.publish_contacts


@pytest.mark.slow
def test_random_pushes_seeded_through_the_context():
    """The random pushes come from the context: the same generator seed gives
    the same torques, another seed other torques, on one built diagram."""
    from pydrake.common import RandomGenerator
    from pydrake.systems.analysis import Simulator

    scenario, file = load_scenario(
        "automotive_push", scenario_text="{human: {pushes: [], random_pushes: {count: 6}}, bounds: {certify: null}}"
    )
    cm = build_comanipulation_diagram(scenario, base_dir=file.parent)
    port = cm.diagram.GetOutputPort("human_torque")

    def torques(seed):
        sim = Simulator(cm.diagram)
        ctx = sim.get_mutable_context()
        cm.diagram.SetRandomContext(ctx, RandomGenerator(seed))
        out = []
        for t in np.arange(0.25, 6.0, 0.5):
            sim.AdvanceTo(t)
            out.append(port.Eval(ctx).copy())
        return np.array(out)

    a, b, c = torques(1), torques(1), torques(2)
    np.testing.assert_array_equal(a, b)
    assert np.abs(a).max() > 0 and not np.array_equal(a, c)


_KEYS = ("max_velocity_ratio", "volume_penetrations", "filter_steps", "faults", "min_clearance_m")


@pytest.mark.slow
@pytest.mark.parametrize("name", ["automotive_random", "aerospace_random", "automotive_reactive", "aerospace_reactive"])
def test_every_bundled_scenario_runs_safely(name, tmp_path):
    """The random and reactive scenarios of both cells (the push ones run in
    the fixture): every logged configuration inside the bounds and free
    (Drake, recounted), joint speeds within the limits, the summary's keys
    reported; the co-worker really moves the robot."""
    s = run_scenario(name, tmp_path, record=False, plot=False, svg=False, scenario_text=FAST)
    d = s.to_dict()  # the keys summary.json holds
    assert all(k in d and d[k] is not None for k in _KEYS)
    logs = np.load(tmp_path / "logs.npz")
    q, lo, hi = logs["commanded_position"], logs["lower"], logs["upper"]
    assert np.all(q >= lo - 1e-12) and np.all(q <= hi + 1e-12)
    wc = cf.load_workcell(s.cell)
    q = logs["update_commanded_position"]
    assert np.array(wc.checker.CheckConfigsCollisionFree(q), bool).all()
    assert (np.abs(np.diff(q, axis=0)) / 0.01 / wc.velocity_limits).max() <= 1.0
    assert s.max_deviation > 0.05 and np.abs(logs["human_torque"]).max() > 0


def test_push_toward_nearest_obstacle_points_at_it():
    """A toward_nearest_obstacle push becomes a tool force of that size along
    the line from the robot's witness point to the nearest obstacle's, at the
    nominal when the push starts (recomputed here from the workcell)."""
    from drake_cfvol.comanip.diagram import _resolve_pushes

    scenario, file = load_scenario("automotive_push", scenario_text=FAST)
    cm = build_comanipulation_diagram(scenario, base_dir=file.parent)
    i = next(n for n, p in enumerate(scenario.human.pushes) if p.toward_nearest_obstacle)
    push = _resolve_pushes(scenario, cm.workcell, cm.path, cm.progress)[i]
    q = cm.path.at(cm.progress.index_at(push.start))
    _, dist, p_WR, p_WO = cm.workcell.nearest_obstacle(q)
    f = np.asarray(push.wrench[3:])
    assert np.linalg.norm(f) == pytest.approx(scenario.human.pushes[i].toward_nearest_obstacle)
    np.testing.assert_allclose(f / np.linalg.norm(f), (p_WO - p_WR) / np.linalg.norm(p_WO - p_WR), atol=1e-9)
    assert dist == pytest.approx(min(cm.workcell.obstacle_distances(q, 5.0, changeable_only=True).values()))


def test_scenario_certify_asks_for_certified_bounds(monkeypatch):
    """bounds.certify given builds the diagram on certified bounds (Certify
    with those settings, seeded with the scenario's seed); null, on the
    paper's."""
    import drake_cfvol.comanip.diagram as C
    from drake_cfvol.algorithm.certificate.certify import Certify

    asked = []
    real = C.estimate_bounds

    def spy(*a, certify=None, **kw):
        asked.append(certify)
        return real(*a, **kw)  # the uncertified table: only the request is under test

    monkeypatch.setattr(C, "estimate_bounds", spy)
    for flag in ("{}", "{confidence: 0.9}", "null"):
        scenario, file = load_scenario(
            "automotive_reactive", scenario_text=f"{{bounds: {{certify: {flag}, resolution: 200}}, random_seed: 3}}"
        )
        build_comanipulation_diagram(scenario, base_dir=file.parent)
    assert asked == [Certify(seed=3), Certify(seed=3, confidence=0.9), None]


# Certifies automotive path 1 with the boundary proof (~170 s, shared within the
# run); aerospace's proof takes ~8 min, so its certified runs are measured in the
# benchmark's adversarial section instead.
@pytest.mark.slow
@pytest.mark.parametrize("name", ["automotive_push", "automotive_random"])
def test_certified_scenarios_run_safely_with_the_filter(name, tmp_path):
    """The bundled scenarios as shipped run on certified bounds with the
    safety filter: it never falls back, never has to miss a damper row,
    and every configuration at the update rate is free (Drake, recounted)
    and inside the bounds at the logged samples."""
    scenario, _ = load_scenario(name)
    assert scenario.bounds.certify is not None and scenario.control.safety_filter is not None
    s = run_scenario(name, tmp_path, record=False, plot=False, svg=False)
    assert s.collisions == 0 and s.filter_fallbacks == 0 and s.filter_damper_misses == 0
    assert s.max_velocity_ratio <= 1.0
    logs = np.load(tmp_path / "logs.npz")
    q = logs["commanded_position"]
    assert np.all(q >= logs["lower"] - 1e-12) and np.all(q <= logs["upper"] + 1e-12)
    wc = cf.load_workcell(s.cell)
    assert np.array(wc.checker.CheckConfigsCollisionFree(logs["update_commanded_position"]), bool).all()


@pytest.mark.slow  # 4.5 s: CI's slow group runs it
def test_sensor_faults_are_held_and_reported(tmp_path, monkeypatch):
    """A NaN torque (0.5 s), a 1e6 N m torque (0.3 s) and an infinite tool
    force (0.2 s) in a run: no exception, every command finite, and the
    summary counts exactly the faulted updates (50 + 30 + 20). A scenario
    file with a non-finite push is refused (tests/test_bad_inputs.py); here
    the scripted pushes stand in for a faulty sensor at run time, so the
    file's check of them is bypassed."""
    import drake_cfvol.comanip.scenario_checks as checks

    monkeypatch.setattr(checks, "_check_pushes", lambda human, where: None)
    s = run_scenario(
        "automotive_push",
        tmp_path,
        record=False,
        plot=False,
        svg=False,
        scenario_text=(
            "{bounds: {certify: null}, control: {safety_filter: null}, human: {pushes: ["
            "{start: 1.0, duration: 0.5, joint_torque: [.nan, 0, 0, 0, 0, 0]}, "
            "{start: 2.0, duration: 0.3, joint_torque: [0, 1.0e6, 0, 0, 0, 0]}, "
            "{start: 3.0, duration: 0.2, wrench: [0, 0, 0, 0, .inf, 0]}]}}"
        ),
    )
    assert s.faults == 100 and s.collisions == 0
    logs = np.load(tmp_path / "logs.npz")
    assert np.isfinite(logs["update_commanded_position"]).all()
    t, fault = logs["fault_t"], logs["fault"][:, 0]
    assert fault[(t > 1.05) & (t < 1.5)].all() and not fault[(t > 1.6) & (t < 1.95)].any()


@pytest.mark.slow  # a whole run at the update rate, recounted by Drake: about 10 s
def test_steady_push_into_an_obstacle_keeps_the_margin(tmp_path):
    """Uncertified bounds (the box alone does not keep the robot safe), a
    300 N tool force towards the nearest obstacle from 1 s to the end, the
    filter's margin 2 cm: every configuration commanded at the update rate
    is free by the workcell's own Drake checker, its clearance (Drake's
    distances in the workcell's scene, not the run's) is >= 2 cm - 2 mm, no
    joint moves faster than its limit, and the co-worker still deforms the
    motion."""
    scenario_text = (
        "{bounds: {certify: null}, control: {safety_filter: {clearance: 0.02}}, "
        "human: {pushes: [{start: 1.0, duration: 1.0e9, toward_nearest_obstacle: 300.0}]}}"
    )
    s = run_scenario("automotive_push", tmp_path, record=False, plot=False, svg=False, scenario_text=scenario_text)
    logs = np.load(tmp_path / "logs.npz")
    q = logs["update_commanded_position"]
    wc = cf.load_workcell("automotive")
    assert np.array(wc.checker.CheckConfigsCollisionFree(q), bool).all()
    clearance = np.array([min(wc.obstacle_distances(x, 2.0, moving_only=True).values(), default=2.0) for x in q])
    assert clearance.min() >= 0.02 - 0.002
    assert (np.abs(np.diff(q, axis=0)) / 0.01 / wc.velocity_limits).max() <= 1.0
    assert s.max_deviation > 0.1 and s.filter_steps > 0


@pytest.mark.slow  # four adversarial runs: about 40 s
def test_steady_corner_pushes_keep_the_margin():
    """Steady corner-seeking pushes (1500 N m on every joint, random signs,
    the whole run; seeds 0-1, both cells, uncertified bounds, margin 2 cm),
    recounted by Drake (drake_cfvol.comanip.adversarial): no collision, the
    clearance never more than 2 mm below min(margin, the nominal's own),
    velocity ratio <= 1 at the update rate; without the filter the same
    pushes collide."""
    from drake_cfvol.comanip.adversarial import steady_push_runs

    for cell in ("automotive", "aerospace"):
        rows = steady_push_runs(cell, 2, clearance=0.02)
        for r in rows:
            assert r["collisions"] == 0 and r["drake_colliding_updates"] == 0, r
            assert r["margin_kept"] and r["max_velocity_ratio"] <= 1.0, r
    off = steady_push_runs("automotive", seeds=[0], safety_filter=False)
    assert off[0]["drake_colliding_updates"] > 0


def test_run_problems_name_what_went_wrong(run):
    """A run is unsafe when it collided, came nearer than min(margin, the
    nominal's own) - 2 mm, or exceeded a velocity limit; otherwise nothing."""
    import dataclasses

    from drake_cfvol.comanip import run_problems

    ok = dataclasses.replace(
        run[2],
        collisions=0,
        clearance_m=0.02,
        nominal_min_clearance_m=0.05,
        min_clearance_m=0.0185,
        max_velocity_ratio=1.0,
        max_acceleration_ratio=0.0,
        max_jerk_ratio=0.0,
        max_bound_violation=0.0,
        filter_fault=None,
    )
    assert run_problems(ok) == []
    assert run_problems(dataclasses.replace(ok, nominal_min_clearance_m=0.01, min_clearance_m=0.0085)) == []
    assert "collided" in run_problems(dataclasses.replace(ok, collisions=3))[0]
    assert "below the margin" in run_problems(dataclasses.replace(ok, min_clearance_m=0.0175))[0]
    assert "velocity limit" in run_problems(dataclasses.replace(ok, max_velocity_ratio=1.01))[0]


#: The keys of a kinematic run's summary.json with fixed bounds, as tests, tools and users read them
#: (recorded from the dict the summary was before it was typed).
SUMMARY_KEYS = (
    "scenario cell path resolution g steps duration_s path_duration_s sim_wall_s min_clearance_m "
    "max_velocity_ratio max_acceleration_ratio max_jerk_ratio volume_penetrations collisions max_bound_violation "
    "live_box_excess_max live_box_catchup_s filter_steps filter_fallbacks filter_damper_misses braking_faults guard_stops "
    "filter_box_exits filter_holds tracking_faults faults filter_fault ended_s safety_filter filter_clearance_m "
    "max_deviation n_boxes volume_boxes_in_scene bounds_time_ms build_ms recording_html plot_png diagram_svg "
    "diagram_dot notices clearance_m nominal_min_clearance_m dynamic problems"
).split()


def test_the_summary_is_typed_and_its_json_written_from_it(run):
    """run_scenario returns a RunSummary, every field described in its
    docstring; summary.json is its to_dict, with the keys it always had in
    their order (the online and tracking figures flat among them only where
    the run has them), each field's value as the attribute holds it."""
    import dataclasses
    import importlib.util
    import json

    from drake_cfvol.comanip import OnlineFigures, RunSummary, TrackingFigures

    name, out, summary = run
    assert isinstance(summary, RunSummary) and summary.online is None and summary.tracking is None
    written = json.loads((out / "summary.json").read_text())
    assert list(written) == SUMMARY_KEYS
    assert written == json.loads(json.dumps(summary.to_dict()))
    for f in dataclasses.fields(RunSummary):
        if f.name not in ("online", "tracking"):
            assert written[f.name] == json.loads(json.dumps(getattr(summary, f.name))), f.name
    assert written["dynamic"] is False and written["cell"] == summary.cell == name.split("_")[0]
    online = OnlineFigures("truth", 3, 1.5, 2.5, 3, None, 1.0, ["cart"], 0)
    tracking = TrackingFigures(0.001, 0.01, 0.002)
    both = dataclasses.replace(summary, online=online, tracking=tracking, volume_penetrations=None).to_dict()
    at = SUMMARY_KEYS.index("dynamic")
    extra = [f.name for f in dataclasses.fields(OnlineFigures)]
    track = [f.name for f in dataclasses.fields(TrackingFigures)]
    assert list(both) == SUMMARY_KEYS[:at] + extra + ["dynamic"] + track + ["problems"]
    assert both["dynamic"] is True and both["bounds_latency_s"] is None and both["tracking_error_max"] == 0.01
    spec = importlib.util.spec_from_file_location("docs_pages", Path(__file__).parents[1] / "tools" / "docs_pages.py")
    tool = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tool)
    assert tool.undocumented([RunSummary, OnlineFigures, TrackingFigures]) == []


#: A trolley that is not in the repository, rolled next to path 1's start
#: and back while the co-worker pushes (the automotive cell).
TROLLEY = (
    "{bounds: {certify: null}, cell: {moving_obstacles: [{name: trolley, box: [0.6, 1.0, 1.0], waypoints: "
    "[[0.0, -2.4, 2.5, 0.5], [1.0, -2.4, 2.5, 0.5], [4.5, -0.8, 2.5, 0.5], [5.0, -0.8, 2.5, 0.5], "
    "[7.5, -2.4, 2.5, 0.5]]}]}}"
)


@pytest.mark.slow  # about 45 s: a depth camera at 20 Hz and the bounds re-estimated online
def test_moving_obstacle_run_meets_its_targets(tmp_path):
    """A moving obstacle given in the scenario text, seen by the camera: no
    collision, the margin kept against it (checked again by the kernel at
    every update, the trolley where it was then), bounds following within
    0.2 s (simulated time) and the freedom back at the end. Compute time is
    the benchmark's (tools/online_bench.py), not a test's."""
    summary = run_scenario(
        "automotive_moving_obstacle", tmp_path, scenario_text=TROLLEY, record=False, plot=False, svg=False
    )
    assert summary.online.moving_obstacles == ["trolley"] and summary.online.perception == "camera"
    assert summary.collisions == 0 and summary.problems == []
    assert summary.min_clearance_m >= summary.clearance_m - 0.002
    assert summary.online.bounds_latency_s <= 0.2 and summary.online.bounds_updates > 10
    assert summary.online.freedom_end_ratio > 0.999
    scenario, _ = load_scenario("automotive_moving_obstacle", scenario_text=TROLLEY)
    ob = scenario.cell.moving_obstacles[0]
    logs = np.load(tmp_path / "logs.npz")
    t, q = logs["update_commanded_position_t"], logs["update_commanded_position"]
    arrays = cf.load_workcell("automotive").scene_arrays()
    near = []
    for tk, qk in zip(t, q):
        alone = arrays.with_boxes(ob.position(tk)[None], np.asarray(ob.box)[None])
        near.append(bool(alone.may_collide(qk[None], summary.clearance_m - 0.005)[0]))
    assert not any(near), f"{sum(near)} updates nearer than the margin to the trolley (kernel)"


@pytest.mark.slow  # about 20 s
def test_truth_perception_run_keeps_the_margin(tmp_path):
    """With the boxes' own map (perception truth) the bundled cart run keeps
    the margin too: the filter measures the map's columns, whose dilation
    covers the cart's motion between maps."""
    summary = run_scenario(
        "automotive_moving_obstacle",
        tmp_path,
        scenario_text="{bounds: {certify: null}, perception: {mode: truth}}",
        record=False,
        plot=False,
        svg=False,
    )
    assert summary.online.perception == "truth" and summary.collisions == 0 and summary.problems == []
    assert summary.min_clearance_m >= summary.clearance_m - 0.002 and summary.online.bounds_latency_s <= 0.2


#: A cart that rolls onto the robot's base (its centre at the base's axis at 4 s) and parks there.
PARKED_OVER_THE_BASE = (
    "{bounds: {certify: null}, cell: {moving_obstacles: [{name: cart, box: [0.8, 0.8, 1.2], "
    "waypoints: [[0.0, 3.6, 3.3, 0.6], [4.0, 0.0, 0.0, 0.6]]}]}}"
)


@pytest.mark.slow  # about 30 s
def test_an_obstacle_parked_over_the_robot_ends_the_run_with_the_filter_fault(tmp_path):
    """Under camera perception, a cart parked over the robot's base (issue 49: each update took 0.6-10 s in the
    filter's rounds, and the run was killed after 300 s): the filter faults before the cart arrives (its rows
    past the cap, or the perceived cart overlapping the robot deeper than the map's margin), holds the last
    command from then on, and the run ends there, reporting it; nothing collided before. The wall time is
    bounded generously (the figure is the benchmark's, not this test's): it ends, it does not hang."""
    summary = run_scenario(
        "automotive_moving_obstacle", tmp_path, scenario_text=PARKED_OVER_THE_BASE, record=False, plot=False, svg=False
    )
    assert summary.online.perception == "camera"
    assert summary.filter_fault in ("too_many_rows", "perceived_overlap")
    assert 0 < summary.ended_s < 4.0
    assert any("safety filter faulted" in p for p in summary.problems)
    assert summary.collisions == 0
    assert summary.sim_wall_s < 240.0
    logs = np.load(tmp_path / "logs.npz")
    t, q = logs["update_commanded_position_t"], logs["update_commanded_position"]
    assert t[-1] == pytest.approx(summary.ended_s)  # the run ended at the fault
    fault_t, fault = logs["filter_fault_t"], logs["filter_fault"][:, 0]
    held = t >= fault_t[np.argmax(fault > 0)] - 1e-9 if (fault > 0).any() else t >= summary.ended_s - 1e-9
    assert np.ptp(q[held], axis=0).max() == 0.0  # the last command held
