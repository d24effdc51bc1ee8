"""A Franka arm over drake-franka-driver's LCM (drake_cfvol.comanip.franka):
the controller's side and the simulated station talking over an in-memory
LCM loopback, every message captured on the bus and decoded on its own
(``drake.lcmt_panda_*.decode``), not through the systems under test."""

import numpy as np
import pytest
from drake import lcmt_panda_command, lcmt_panda_status
from pydrake.lcm import DrakeLcm
from pydrake.manipulation import PandaControlMode
from pydrake.multibody.plant import AddMultibodyPlant, MultibodyPlantConfig
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource, LogVectorOutput

import drake_cfvol as cf
from drake_cfvol.comanip.dynamics import _control_plant
from drake_cfvol.comanip.franka import (
    FRANKA_PERIOD,
    PANDA_COMMAND_CHANNEL,
    PANDA_STATUS_CHANNEL,
    add_franka_controller_interface,
    add_franka_station,
    panda_control_mode,
)

# A 7-joint arm of the repository (the iiwa of the cobot cell): the wiring
# does not depend on the arm.
CELL = "cobot"


def _station(builder: DiagramBuilder, wc, q0: np.ndarray, mode: str):
    """A time-stepping plant of ``wc`` (its robot at ``q0``) and the
    simulated Franka station on a fresh memq LCM. Returns (plant, robot,
    lcm, station)."""
    plant, _ = AddMultibodyPlant(MultibodyPlantConfig(time_step=FRANKA_PERIOD), builder)
    wc.add_models(plant)
    plant.Finalize()
    robot = plant.GetModelInstanceByName(wc.robot_name)
    plant.SetDefaultPositions(robot, q0)
    lcm = DrakeLcm("memq://")
    station = add_franka_station(
        builder,
        plant=plant,
        robot=robot,
        controller_plant=_control_plant(wc, FRANKA_PERIOD),
        lcm=lcm,
        control_mode=mode,
    )
    return plant, robot, lcm, station


def _loopback(mode: str, desired, *, status_channel: str = PANDA_STATUS_CHANNEL, v0=None):
    """Station and controller interface on one memq LCM, the desired state a
    constant; the bus's messages captured raw. Returns (diagram, parts)."""
    wc = cf.load_workcell(CELL)
    builder = DiagramBuilder()
    q0 = wc.configuration("path1")[0]
    plant, robot, lcm, station = _station(builder, wc, q0, mode)
    source = builder.AddSystem(ConstantVectorSource(np.asarray(desired(q0), float)))
    interface = add_franka_controller_interface(
        builder, lcm=lcm, desired_state=source.get_output_port(), control_mode=mode, status_channel=status_channel
    )
    truth = LogVectorOutput(plant.get_state_output_port(robot), builder, publish_period=FRANKA_PERIOD)
    fault = LogVectorOutput(interface.watchdog.fault_output, builder, publish_period=FRANKA_PERIOD)
    diagram = builder.Build()
    sent = {PANDA_COMMAND_CHANNEL: [], PANDA_STATUS_CHANNEL: []}
    for channel, kind in ((PANDA_COMMAND_CHANNEL, lcmt_panda_command), (PANDA_STATUS_CHANNEL, lcmt_panda_status)):
        lcm.Subscribe(channel, lambda data, out=sent[channel], kind=kind: out.append(kind.decode(data)))
    sim = Simulator(diagram)
    if v0 is not None:
        plant.SetVelocities(plant.GetMyMutableContextFromRoot(sim.get_mutable_context()), robot, v0)
    return sim, dict(
        lcm=lcm,
        plant=plant,
        robot=robot,
        q0=q0,
        station=station,
        interface=interface,
        truth=truth,
        fault=fault,
        sent=sent,
    )


# Distinct values per joint, so that a swapped or dropped joint shows.
OFFSET = np.linspace(0.01, 0.07, 7)
VELOCITY = np.linspace(-0.3, 0.3, 7)


@pytest.mark.parametrize("mode", ["position", "velocity"])
def test_command_arrives_decoded_intact_in_its_mode(mode):
    """Every command on the bus carries the controller's values bit for bit,
    the mode's bit in control_mode_expected and only that mode's vector (what
    drake-franka-driver checks before it moves the arm), stamped at 1 kHz;
    the station's decoder outputs the same values."""
    sim, p = _loopback(mode, lambda q0: np.concatenate([q0 + OFFSET, VELOCITY]))
    sim.AdvanceTo(0.02)
    commands = p["sent"][PANDA_COMMAND_CHANNEL]
    assert len(commands) >= 20
    expected = p["q0"] + OFFSET if mode == "position" else VELOCITY
    bit = PandaControlMode.kPosition if mode == "position" else PandaControlMode.kVelocity
    for m in commands:
        assert m.control_mode_expected == bit and m.num_joint_torque == 0
        if mode == "position":
            assert m.num_joint_position == 7 and m.num_joint_velocity == 0
            np.testing.assert_array_equal(m.joint_position, expected)
        else:
            assert m.num_joint_velocity == 7 and m.num_joint_position == 0
            np.testing.assert_array_equal(m.joint_velocity, expected)
    np.testing.assert_array_equal(np.diff([m.utime for m in commands]), 1000)  # us: Franka's 1 kHz
    receiver = p["station"].command_receiver
    port = (
        receiver.get_commanded_position_output_port()
        if mode == "position"
        else receiver.get_commanded_velocity_output_port()
    )
    np.testing.assert_array_equal(port.Eval(receiver.GetMyContextFromRoot(sim.get_context())), expected)


def test_status_decodes_to_the_plant_state():
    """Every status on the bus holds the plant's state at its time stamp (the
    logged state at that instant, moving: the arm starts with a velocity),
    and the controller's receiver reports the last one that arrived."""
    v0 = np.linspace(0.2, -0.2, 7)
    sim, p = _loopback("position", lambda q0: np.concatenate([q0, np.zeros(7)]), v0=v0)
    sim.AdvanceTo(0.02)
    ctx = sim.get_context()
    log = p["truth"].FindLog(ctx)
    times, states = log.sample_times(), log.data().T
    status = p["sent"][PANDA_STATUS_CHANNEL]
    assert len(status) >= 20
    for m in status:
        (i,) = np.flatnonzero(np.isclose(times, m.utime * 1e-6, rtol=0, atol=1e-9))
        assert m.num_joints == 7
        np.testing.assert_array_equal(m.joint_position, states[i, :7])
        np.testing.assert_array_equal(m.joint_velocity, states[i, 7:])
    assert np.abs(status[0].joint_velocity - v0).max() == 0.0 and np.abs(status[-1].joint_position - p["q0"]).max() > 0
    receiver = p["interface"].status_receiver
    rctx = receiver.GetMyContextFromRoot(ctx)
    delivered = [m for m in status if m.utime <= ctx.get_time() * 1e6]
    latest = receiver.get_position_measured_output_port().Eval(rctx)
    assert any(np.array_equal(latest, m.joint_position) for m in delivered[-2:])  # the bus's latency: one period


def test_a_stopped_status_raises_the_watchdog_within_its_timeout_and_resumed_status_clears_it():
    """The controller reads its status through a relay that stops for 10 ms
    (10 status periods): the watchdog's fault rises once the last status
    relayed is more than its timeout (3 ms) old when it arrives: the status
    reaches the watchdog's update two periods after the relay (the bus's
    hop, then the update that reads it), and the fault is raised at the
    first check strictly past the timeout, before the relay resumes; it
    falls again within those two periods of the next status."""
    sim, p = _loopback("position", lambda q0: np.concatenate([q0, np.zeros(7)]), status_channel="RELAY")
    stop, resume = 0.020, 0.030
    timeout = p["interface"].watchdog.timeout
    relayed = []

    def relay(data):
        now = sim.get_context().get_time()
        if not stop <= now < resume:
            relayed.append(now)
            p["lcm"].Publish("RELAY", data)

    p["lcm"].Subscribe(PANDA_STATUS_CHANNEL, relay)
    sim.AdvanceTo(0.045)
    log = p["fault"].FindLog(sim.get_context())
    t, fault = log.sample_times(), log.data()[0]
    last = max(u for u in relayed if u < stop)
    first_again = min(u for u in relayed if u >= resume)
    assert timeout == pytest.approx(3 * FRANKA_PERIOD)
    assert fault[t <= last + timeout].max() == 0.0  # not before the timeout
    risen = t[fault > 0.5]
    assert risen.min() <= last + 2 * FRANKA_PERIOD + timeout + FRANKA_PERIOD + 1e-9
    assert risen.max() <= first_again + 2 * FRANKA_PERIOD + 1e-9 and fault[t > risen.max()].max() == 0.0
    assert np.ptp(risen) == pytest.approx(FRANKA_PERIOD * (len(risen) - 1))  # one stretch


def test_control_mode_names():
    """Position and velocity are the modes; torque (and anything else) is
    refused with what to give."""
    assert panda_control_mode("position") == PandaControlMode.kPosition
    assert panda_control_mode(PandaControlMode.kVelocity) == PandaControlMode.kVelocity
    for bad in ("torque", PandaControlMode.kTorque, "Position", 3):
        with pytest.raises(cf.ParameterError, match="'position' or 'velocity'"):
            panda_control_mode(bad)


def _dropped_status_run(cell: str, mode: str, stop: float, resume: float, until: float, **limits):
    """The controller that runs beside a real arm (add_franka_controller: its
    own SceneGraph, posed from the status) on path 1 of ``cell``, at 1 ms,
    driving the simulated station over LCM only, its status relayed through
    a channel that stops in [stop, resume). ``limits``: the
    CoManipulationConfig's limit fields. Returns (commands sent, the
    watchdog's fault log as (times, values), the controller's systems, the
    root context)."""
    from drake_cfvol.comanip.franka import add_franka_controller
    from drake_cfvol.systems import CoManipulationConfig, PathProgressConfig

    wc = cf.load_workcell(cell)
    table = cf.estimate_bounds(wc, cf.plan_nominal_path(wc, *wc.configuration("path1"), seed=0), resolution=300)
    builder = DiagramBuilder()
    _, _, lcm, _ = _station(builder, wc, table.nominal[0], mode)
    config = CoManipulationConfig(path_progress=PathProgressConfig(start_time=0.1), **limits)
    cm, _ = add_franka_controller(
        builder, workcell=wc, table=table, lcm=lcm, control_mode=mode, config=config, status_channel="RELAY"
    )
    watchdog = builder.GetSubsystemByName("controller_status_watchdog")
    fault_log = LogVectorOutput(watchdog.fault_output, builder, publish_period=FRANKA_PERIOD)
    sim = Simulator(builder.Build())
    commands = []

    def relay(data):
        if not stop <= sim.get_context().get_time() < resume:
            lcm.Publish("RELAY", data)

    lcm.Subscribe(PANDA_STATUS_CHANNEL, relay)
    lcm.Subscribe(PANDA_COMMAND_CHANNEL, lambda data: commands.append(lcmt_panda_command.decode(data)))
    sim.AdvanceTo(until)
    log = fault_log.FindLog(sim.get_context())
    return commands, (log.sample_times(), log.data()[0]), cm, sim.get_context()


@pytest.mark.slow
@pytest.mark.parametrize("mode", ["position", "velocity"])
def test_a_stopped_status_holds_the_safety_filter_and_every_command_keeps_the_limits(mode):
    """On an arm without acceleration limits (the cobot cell's iiwa), the
    status stopping for 40 ms while the path moves holds the command (the
    sent position constant, the sent velocity zero) from the first update
    after the fault until the status resumes, and it moves along the path
    before and after; every command sent is within the arm's position and
    velocity limits (a position command's step over 1 ms included)."""
    wc = cf.load_workcell(CELL)
    stop, resume = 0.30, 0.34
    commands, (t, fault), cm, ctx = _dropped_status_run(CELL, mode, stop, resume, 0.5)
    raised = t[fault > 0.5]
    assert len(raised) and stop < raised.min() < resume and raised.max() < resume + 3 * FRANKA_PERIOD
    stamp = np.array([m.utime * 1e-6 for m in commands])
    if mode == "position":
        sent = np.array([m.joint_position for m in commands])
        step = np.abs(np.diff(sent, axis=0)) / FRANKA_PERIOD
        assert (sent >= wc.position_lower - 1e-9).all() and (sent <= wc.position_upper + 1e-9).all()
        assert (step <= wc.velocity_limits * (1 + 1e-6)).all()
        held = (stamp > raised.min() + FRANKA_PERIOD) & (stamp <= raised.max())
        assert held.sum() >= 20 and np.abs(sent[held] - sent[held][0]).max() == 0.0
        moving = sent
    else:
        sent = np.array([m.joint_velocity for m in commands])
        assert (np.abs(sent) <= wc.velocity_limits * (1 + 1e-6)).all()
        held = (stamp > raised.min() + FRANKA_PERIOD) & (stamp <= raised.max())
        assert held.sum() >= 20 and np.abs(sent[held]).max() == 0.0
        moving = np.cumsum(sent, axis=0)
    before, after = (stamp > stop - 0.05) & (stamp < stop), stamp > resume + 0.05
    assert np.abs(np.diff(moving[before], axis=0)).max() > 0 and np.abs(np.diff(moving[after], axis=0)).max() > 0
    assert cm.safety.hold_count_output.Eval(cm.safety.GetMyContextFromRoot(ctx))[0] >= 20


# Franka's published joint limits, joints 1-7 (its robot and interface
# specification; tests/test_franka.py checks the model's against them):
# written here as the independent fact, never read from the model.
PANDA_Q_MIN = np.array([-2.8973, -1.7628, -2.8973, -3.0718, -2.8973, -0.0175, -2.8973])  # rad
PANDA_Q_MAX = np.array([2.8973, 1.7628, 2.8973, -0.0698, 2.8973, 3.7525, 2.8973])  # rad
PANDA_LIMITS = {  # per derivative of the joint position: velocity, acceleration, jerk
    "velocity": np.array([2.1750, 2.1750, 2.1750, 2.1750, 2.6100, 2.6100, 2.6100]),  # rad/s
    "acceleration": np.array([15, 7.5, 10, 12.5, 15, 20, 20.0]),  # rad/s^2
    "jerk": np.array([7500, 3750, 5000, 6250, 7500, 10000, 10000.0]),  # rad/s^3
}


def _commanded_velocity(commands: list, mode: str) -> np.ndarray:
    """The joint velocities the commands ask for, one row per 1 ms, the arm
    at rest before the first (as Franka's interface requires a motion to
    start): a position command's step over the period, or the sent
    velocity. Checks the commands' modes and their 1 ms spacing."""
    assert len(commands) > 1 and all(m.control_mode_expected == panda_control_mode(mode) for m in commands)
    us = np.array([m.utime for m in commands])  # the sender truncates the time to whole us
    ms = (us + 500) // 1000
    assert np.abs(us - 1000 * ms).max() <= 1 and (np.diff(ms) == 1).all()
    if mode == "position":
        q = np.array([m.joint_position for m in commands])
        assert (q >= PANDA_Q_MIN).all() and (q <= PANDA_Q_MAX).all()
        return np.diff(np.vstack([q[:1], q]), axis=0) / FRANKA_PERIOD
    return np.array([m.joint_velocity for m in commands])


def _limit_ratios(v: np.ndarray) -> dict[str, float]:
    """The largest |velocity|, |acceleration| and |jerk| of the commanded
    velocities ``v`` (finite differences over 1 ms, from rest) as shares of
    Franka's limits, per quantity."""
    ratios, x = {}, np.vstack([np.zeros((2, v.shape[1])), v])
    for name, limit in PANDA_LIMITS.items():
        ratios[name] = float((np.abs(x) / limit).max())
        x = np.diff(x, axis=0) / FRANKA_PERIOD
    return ratios


@pytest.mark.slow
@pytest.mark.parametrize("mode", ["position", "velocity"])
def test_franka_stopped_status_brakes_the_command_to_a_hold_within_franka_limits(mode):
    """The Franka cell under Franka's limits: the status stops for 60 ms
    while the path moves; once the watchdog's fault rises the command brakes
    (the filter brakes at its limits on a hold) until its velocity is 0, and
    stays 0 until the fault falls; after the status resumes it moves along
    the path again. Every command sent, before, during and after,
    keeps Franka's published position, velocity, acceleration and jerk
    limits (1e-6 relative)."""
    wc = cf.load_workcell("franka")
    # 60 ms: the arm moves at up to 0.55 rad/s when the fault rises (5 ms
    # after the status stops), and braking at 15 rad/s^2 takes 37 ms.
    stop, resume = 0.30, 0.36
    commands, (t, fault), cm, ctx = _dropped_status_run(
        "franka",
        mode,
        stop,
        resume,
        0.5,
        acceleration_limits=list(wc.acceleration_limits),
        jerk_limits=list(wc.jerk_limits),
    )
    raised = t[fault > 0.5]
    assert len(raised) and stop < raised.min() < resume and raised.max() < resume + 3 * FRANKA_PERIOD
    v = _commanded_velocity(commands, mode)
    ratios = _limit_ratios(v)
    assert all(r <= 1 + 1e-6 for r in ratios.values()), ratios
    stamp = np.array([m.utime * 1e-6 for m in commands])
    speed = np.abs(v).max(axis=1)
    held = speed[(stamp > raised.min()) & (stamp <= raised.max())]
    # Braking under the jerk limit may pass through 0 and come back (the
    # acceleration cannot vanish in one tick): the hold is the zero stretch
    # that ends the fault's window.
    moving = np.flatnonzero(held > 0.0)
    assert held[0] > 0.0 and len(held) - 1 - moving[-1] >= 5, held
    assert speed[(stamp > stop - 0.05) & (stamp < stop)].max() > 0 and speed[stamp > resume + 0.05].max() > 0
    assert cm.safety.hold_count_output.Eval(cm.safety.GetMyContextFromRoot(ctx))[0] >= 20


def test_a_scenario_names_the_franka_driver_checked():
    """``!FrankaDriver`` in a scenario's model_drivers loads; a mode that is
    not position or velocity, and a joint-torque push (the arm feels pushes
    through contact), are refused naming the field."""
    from drake_cfvol.comanip import load_scenario
    from drake_cfvol.comanip.scenario import FrankaDriver

    drivers = "simulation: {model_drivers: {iiwa: !FrankaDriver {control_mode: %s}}}"
    scenario, _ = load_scenario("cobot_push", scenario_text="{%s}" % (drivers % "velocity"))
    assert scenario.simulation.model_drivers["iiwa"] == FrankaDriver(control_mode="velocity")
    with pytest.raises(cf.ScenarioError, match="model_drivers.iiwa.control_mode.*'position' or 'velocity'"):
        load_scenario("cobot_push", scenario_text="{%s}" % (drivers % "torque"))
    with pytest.raises(cf.ScenarioError, match="pushes item 1: joint_torque.*FrankaDriver"):
        load_scenario(
            "cobot_push",
            scenario_text="{%s, human: {pushes: [{joint_torque: [1, 0, 0, 0, 0, 0, 0]}]}}" % (drivers % "position"),
        )


@pytest.mark.slow
def test_franka_lcm_push_run_sends_only_commands_within_franka_limits(tmp_path, monkeypatch):
    """The bundled franka_lcm scenario (the Franka cell dynamic over the
    in-memory LCM, position mode, the co-worker's hand pushing the tool):
    every lcmt_panda_command on the bus, captured on the run's own LCM,
    keeps Franka's published position, velocity, acceleration and jerk
    limits (1e-6 relative), from rest, one every 1 ms; the run is clean (no
    collision, the margin kept) and the pushes, felt through the status's
    external torque, deform it."""
    import drake_cfvol.comanip.diagram as diagram
    from drake_cfvol.comanip import run_scenario

    buses, commands = [], []

    def recording_lcm(url: str) -> DrakeLcm:
        lcm = DrakeLcm(url)
        lcm.Subscribe(PANDA_COMMAND_CHANNEL, lambda data: commands.append(lcmt_panda_command.decode(data)))
        buses.append(lcm)
        return lcm

    monkeypatch.setattr(diagram, "DrakeLcm", recording_lcm)
    s = run_scenario("franka_lcm", tmp_path, record=False, plot=False, svg=False)
    assert len(buses) == 1 and s.dynamic
    assert s.collisions == 0 and s.problems == []
    ratios = _limit_ratios(_commanded_velocity(commands, "position"))
    assert all(r <= 1 + 1e-6 for r in ratios.values()), ratios
    assert commands[-1].utime * 1e-6 >= s.ended_s - 2 * FRANKA_PERIOD  # every tick of the run
    logs = np.load(tmp_path / "logs.npz")
    t, tau = logs["human_torque_t"], logs["human_torque"]
    assert np.abs(tau[(t > 1.2) & (t < 2.5)]).max() > 5.0  # N m, felt by the arm's torque sensing
    assert s.max_deviation > 0.01
