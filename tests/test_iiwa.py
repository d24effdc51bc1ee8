"""The torque-sensing cobot cell: the iiwa under Drake's IiwaDriver, the
controller talking LCM to the simulated station over an in-memory bus, the
co-worker's hand felt through the driver's external-torque estimate."""

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator

import drake_cfvol as cf
from drake_cfvol.comanip import load_scenario, run_scenario
from drake_cfvol.comanip.diagram import build_comanipulation_diagram


def test_cobot_cell_model_from_public_data():
    """The cobot cell loads with the iiwa's published joint ranges and
    speeds, 7 actuated joints, the published mass, and collision-free
    named configurations."""
    wc = cf.load_workcell("cobot")
    assert wc.num_joints == 7 and wc.plant.num_actuated_dofs() == 7
    np.testing.assert_allclose(np.degrees(wc.position_upper), [170, 120, 170, 120, 170, 120, 175])
    np.testing.assert_allclose(np.degrees(wc.velocity_limits), [85, 85, 100, 75, 130, 135, 135], rtol=1e-6)
    arm = sum(
        wc.plant.get_body(b).default_mass()
        for b in wc.plant.GetBodyIndices(wc.robot)
        if wc.plant.get_body(b).name() not in ("gripper", "tcp")
    )
    assert arm == pytest.approx(29.9, abs=0.1)
    for name in ("path1", "path2", "path3"):
        assert all(wc.is_free(q) for q in wc.configuration(name))


def test_lcm_loopback_between_controller_and_simulated_station():
    """Over DrakeLcm("memq://") the controller's command reaches the
    simulated driver (its commanded position is ours) and the driver's status
    comes back (measured position equal to the plant's, external torque equal
    to the plant's filtered contact forces: zero before any contact)."""
    scenario, file = load_scenario(
        "cobot_push", scenario_text="{bounds: {certify: null, resolution: 300}, human: {pushes: []}}"
    )
    cm = build_comanipulation_diagram(scenario, scenario_file=file)
    sim = Simulator(cm.diagram)
    ctx = sim.get_mutable_context()
    sim.AdvanceTo(1.0)  # the path starts at 0.5 s
    status = cm.diagram.GetSubsystemByName("iiwa_status_receiver")
    sctx = status.GetMyContextFromRoot(ctx)
    plant = cm.plant
    q_plant = plant.GetPositions(plant.GetMyContextFromRoot(ctx), plant.GetModelInstanceByName("iiwa"))
    q_status = status.get_position_measured_output_port().Eval(sctx)
    v = np.abs(plant.GetVelocities(plant.GetMyContextFromRoot(ctx))).max()
    assert np.abs(q_status - q_plant).max() <= 2 * 0.005 * v + 1e-9  # at most two status periods old
    commanded = status.get_position_commanded_output_port().Eval(sctx)
    ours = cm.diagram.GetSubsystemByName("safety_filter").desired_state_output.Eval(
        cm.diagram.GetSubsystemByName("safety_filter").GetMyContextFromRoot(ctx)
    )[:7]
    assert np.abs(commanded - ours).max() < 0.02 and np.abs(commanded - q_plant).max() < 0.02
    np.testing.assert_array_equal(status.get_torque_external_output_port().Eval(sctx), np.zeros(7))
    assert np.abs(q_plant - cm.path.waypoints[0]).max() > 1e-3  # the robot moved along its path


def test_joint_torque_pushes_refused_for_a_torque_sensing_arm(tmp_path):
    """A joint-torque push in the cobot cell is refused before loading: the
    arm feels pushes through contact only."""
    with pytest.raises(cf.ScenarioError, match="pushes item 1: joint_torque.*tool wrenches"):
        load_scenario("cobot_push", scenario_text="{human: {pushes: [{joint_torque: [1, 0, 0, 0, 0, 0, 0]}]}}")


@pytest.mark.slow
def test_cobot_push_runs_under_the_iiwa_driver(tmp_path):
    """The bundled cobot scenario runs dynamic under the IiwaDriver with 0
    collisions: the hand's pushes reach the admittance only through the
    driver's external-torque estimate, deform the motion, and the path ends."""
    s = run_scenario("cobot_push", tmp_path, record=False, plot=False, svg=False)
    assert s.dynamic and s.collisions == 0 and s.problems == []
    logs = np.load(tmp_path / "logs.npz")
    t, tau = logs["human_torque_t"], logs["human_torque"]
    pushing = (t > 1.2) & (t < 2.5)
    assert np.abs(tau[pushing]).max() > 5.0  # N m, felt by the arm's torque sensing
    assert np.abs(tau[t < 0.9]).max() == 0.0  # nothing before the first push
    assert s.max_deviation > 0.02
    assert np.abs(logs["update_measured_position"][-1] - logs["nominal"][-1]).max() < 0.01


@pytest.mark.slow
def test_hardware_controller_drives_the_simulated_station_over_lcm_only():
    """The controller that runs beside a real iiwa (its SceneGraph posed from
    the status, never from the simulated plant) drives Drake's simulated
    station with no port between them, only LCM over memq: the true robot
    never collides, the hand's push is felt through the external torque and
    deforms the command, and the robot reaches the goal."""
    from pydrake.manipulation import IiwaDriver
    from pydrake.math import RigidTransform
    from pydrake.multibody.plant import AddMultibodyPlant, MultibodyPlantConfig
    from pydrake.systems.framework import DiagramBuilder
    from pydrake.systems.primitives import LogVectorOutput

    from drake_cfvol.comanip.iiwa import add_hand, add_iiwa_controller, add_iiwa_station, grip_point, tool_radius
    from drake_cfvol.systems import AdmittanceConfig, CoManipulationConfig, PathProgressConfig, Push, ScriptedHuman
    from drake_cfvol.systems.hand import add_hand_body, waiting_point

    wc = cf.load_workcell("cobot")
    table = cf.estimate_bounds(wc, cf.plan_nominal_path(wc, *wc.configuration("path1"), seed=0), resolution=1000)
    builder = DiagramBuilder()
    plant, _ = AddMultibodyPlant(MultibodyPlantConfig(time_step=0.001), builder)
    models = wc.add_models(plant)
    hand = add_hand_body(plant)
    plant.Finalize()
    iiwa = plant.GetModelInstanceByName(wc.robot_name)
    plant.SetDefaultPositions(iiwa, table.nominal[0])
    p_WG = wc.tool_frame.body().EvalPoseInWorld(wc.plant_context(table.nominal[0])).multiply(grip_point(wc))
    plant.SetDefaultFloatingBaseBodyPose(hand, RigidTransform(waiting_point(p_WG, [0, 1, 0], tool_radius(wc))))
    lcm = add_iiwa_station(builder, IiwaDriver(), wc.robot_name, plant, models)
    human = builder.AddSystem(ScriptedHuman(7, [Push(1.0, 1.5, [], [0, 0, 0, 0, 40.0, 0])]))
    add_hand(
        builder,
        plant,
        hand,
        plant.GetFrameByName(wc.tool_frame.name(), iiwa),
        human.human_wrench_output,
        tool_radius=tool_radius(wc),
        initial_direction=[0, 1, 0],
        p_BG=grip_point(wc),
    )
    config = CoManipulationConfig(
        admittance=AdmittanceConfig(mass=2.0, damping=80.0, stiffness=300.0),
        path_progress=PathProgressConfig(start_time=0.5),
    )
    cm, status = add_iiwa_controller(builder, workcell=wc, table=table, lcm=lcm, config=config)
    truth = LogVectorOutput(plant.get_state_output_port(iiwa), builder, publish_period=0.01)
    felt = LogVectorOutput(status.get_torque_external_output_port(), builder, publish_period=0.01)
    commanded = LogVectorOutput(cm.commanded_position_output, builder, publish_period=0.01)
    nominal = LogVectorOutput(cm.bounds.nominal_output, builder, publish_period=0.01)
    diagram = builder.Build()
    # No port joins the controller to the station: only LCM does.
    crossing = [
        (f.get_name(), t.get_name())
        for (t, _), (f, _) in diagram.connection_map().items()
        if "LogSink" not in type(t).__name__  # the test's own loggers read both sides
        and t.get_name().startswith("controller") != f.get_name().startswith("controller")
    ]
    assert crossing == []
    sim = Simulator(diagram)
    sim.AdvanceTo(cm.duration + 1.0)
    ctx = sim.get_context()
    q = truth.FindLog(ctx).data().T[:, :7]
    assert np.array(wc.checker.CheckConfigsCollisionFree(q), bool).all()
    t, tau = felt.FindLog(ctx).sample_times(), felt.FindLog(ctx).data().T
    assert np.abs(tau[(t > 1.1) & (t < 2.5)]).max() > 5.0 and np.abs(tau[t < 0.9]).max() == 0.0
    assert np.abs(commanded.FindLog(ctx).data() - nominal.FindLog(ctx).data()).max() > 0.02
    np.testing.assert_allclose(q[-1], table.nominal[-1], atol=0.01)


@pytest.mark.slow
def test_a_stale_status_holds_the_last_command_and_raises_the_fault():
    """The controller of the hardware test, its status relayed through a
    channel that drops every message for 60 ms (12 status periods) while the
    path moves: the watchdog raises its fault three periods after the last
    message, the safety filter holds its last command until a message
    comes again, and then the run goes on; the true robot never collides."""
    from pydrake.manipulation import IiwaDriver
    from pydrake.multibody.plant import AddMultibodyPlant, MultibodyPlantConfig
    from pydrake.systems.framework import DiagramBuilder
    from pydrake.systems.primitives import LogVectorOutput

    from drake_cfvol.comanip.iiwa import IIWA_STATUS_PERIOD, add_iiwa_controller, add_iiwa_station
    from drake_cfvol.systems import CoManipulationConfig, PathProgressConfig

    wc = cf.load_workcell("cobot")
    table = cf.estimate_bounds(wc, cf.plan_nominal_path(wc, *wc.configuration("path1"), seed=0), resolution=300)
    builder = DiagramBuilder()
    plant, _ = AddMultibodyPlant(MultibodyPlantConfig(time_step=0.001), builder)
    models = wc.add_models(plant)
    plant.Finalize()
    iiwa = plant.GetModelInstanceByName(wc.robot_name)
    plant.SetDefaultPositions(iiwa, table.nominal[0])
    lcm = add_iiwa_station(builder, IiwaDriver(), wc.robot_name, plant, models)
    config = CoManipulationConfig(path_progress=PathProgressConfig(start_time=0.2))
    cm, _ = add_iiwa_controller(builder, workcell=wc, table=table, lcm=lcm, config=config, status_channel="RELAY")
    watchdog = builder.GetSubsystemByName("controller_status_watchdog")
    logs = {
        name: LogVectorOutput(port, builder, publish_period=0.001)
        for name, port in (
            ("commanded", cm.commanded_position_output),
            ("fault", watchdog.fault_output),
            ("truth", plant.get_state_output_port(iiwa)),
        )
    }
    diagram = builder.Build()
    sim = Simulator(diagram)
    drop = (0.5, 0.56)

    def relay(data):
        if not drop[0] <= sim.get_context().get_time() < drop[1]:
            lcm.Publish("RELAY", data)

    lcm.Subscribe("IIWA_STATUS", relay)
    sim.AdvanceTo(0.8)
    ctx = sim.get_context()
    t = logs["fault"].FindLog(ctx).sample_times()
    fault = logs["fault"].FindLog(ctx).data()[0]
    q_c = logs["commanded"].FindLog(ctx).data().T
    raised = t[fault > 0.5]
    # Raised more than three periods after the last message before the drop, cleared within a period of its end.
    assert len(raised) and raised.min() > drop[0] + 3 * IIWA_STATUS_PERIOD - 1e-9
    assert raised.max() < drop[1] + 2 * IIWA_STATUS_PERIOD + 1e-9
    assert fault[t > drop[1] + 3 * IIWA_STATUS_PERIOD].max() == 0.0
    # The command is held from the first update that saw the fault until a status came again ...
    update = cm.safety.period
    held = (t >= raised.min() + update) & (t <= raised.max())
    assert held.sum() >= 20 and np.abs(q_c[held] - q_c[held][0]).max() == 0.0
    # ... and moved along the path before and after.
    before, after = (t > drop[0] - 0.05) & (t < drop[0]), t > drop[1] + 0.05
    assert np.abs(np.diff(q_c[before], axis=0)).max() > 0 and np.abs(np.diff(q_c[after], axis=0)).max() > 0
    sctx = cm.safety.GetMyContextFromRoot(ctx)
    assert cm.safety.hold_count_output.Eval(sctx)[0] >= 2
    assert watchdog.fault_count_output.Eval(watchdog.GetMyContextFromRoot(ctx))[0] >= 4
    q = logs["truth"].FindLog(ctx).data().T[::10, :7]
    assert np.array(wc.checker.CheckConfigsCollisionFree(q), bool).all()
