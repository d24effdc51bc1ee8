"""A torque-sensing arm under Drake's ``IiwaDriver``: the simulated station
(``ApplyDriverConfigs``: Drake's simulated iiwa driver on the plant, its LCM
command receiver and status sender) and the co-manipulation controller's
side of the same LCM interface (``IiwaCommandSender``,
``IiwaStatusReceiver``). In a run the two talk over an in-memory LCM
(``DrakeLcm("memq://")``, a loopback); on hardware the controller side is
the same and the bus is the robot's network.

The co-worker's hand pushes the tool through contact
(:class:`~drake_cfvol.systems.hand.CoworkerHand`), so that the driver's
external-torque estimate (the plant's contact forces on the arm, low-pass
filtered) is what feeds the admittance, as on a real arm.
"""

from __future__ import annotations

import numpy as np
from drake import lcmt_iiwa_command, lcmt_iiwa_status
from pydrake.lcm import DrakeLcm
from pydrake.manipulation import ApplyDriverConfigs, IiwaCommandSender, IiwaControlMode, IiwaStatusReceiver
from pydrake.systems.lcm import LcmBuses, LcmInterfaceSystem
from pydrake.systems.primitives import ConstantVectorSource, Demultiplexer

from drake_cfvol.comanip.robot_status import add_lcm_controller, add_status_watchdog, publish_on_lcm, subscribe_on_lcm
from drake_cfvol.systems.hand import CoworkerHand
from drake_cfvol.systems.station import CoManipulationConfig

__all__ = [
    "IIWA_STATUS_PERIOD",
    "add_iiwa_controller",
    "add_iiwa_station",
    "add_iiwa_controller_interface",
    "add_iiwa_status_watchdog",
    "add_hand",
    "grip_point",
    "tool_radius",
]

#: The iiwa's LCM status and command period, s (Drake's kIiwaLcmStatusPeriod).
IIWA_STATUS_PERIOD = 0.005


def add_iiwa_station(builder, driver, robot_name: str, plant, models, lcm=None):
    """The simulated side: Drake's ``ApplyDriverConfigs`` with the scenario's
    ``IiwaDriver`` on the plant (finalized), on an LCM bus ``driver.lcm_bus``
    (default: an in-memory one). Returns the LCM instance."""
    lcm = lcm or DrakeLcm("memq://")
    builder.AddNamedSystem("lcm_interface", LcmInterfaceSystem(lcm))
    buses = LcmBuses()
    buses.Add(driver.lcm_bus, lcm)
    ApplyDriverConfigs(
        driver_configs={robot_name: driver},
        sim_plant=plant,
        models_from_directives=models,
        lcm_buses=buses,
        builder=builder,
    )
    return lcm


def add_iiwa_controller_interface(
    builder, lcm, desired_state, k: int = 7, prefix: str = "", status_channel: str = "IIWA_STATUS"
):
    """The controller's side of the iiwa's LCM interface: the desired
    position (the first k of ``desired_state``) sent as ``IIWA_COMMAND`` at
    the driver's period with zero feed-forward torque; the status received
    on ``status_channel``. Returns the ``IiwaStatusReceiver`` (ports
    ``position_measured``, ``velocity_estimated``, ``torque_external``, ...)."""
    split = builder.AddNamedSystem(f"{prefix}desired_position", Demultiplexer([k, k]))
    builder.Connect(desired_state, split.get_input_port(0))
    sender = builder.AddNamedSystem(
        f"{prefix}iiwa_command_sender", IiwaCommandSender(k, IiwaControlMode.kPositionAndTorque)
    )
    zero = builder.AddNamedSystem(f"{prefix}iiwa_feedforward_torque", ConstantVectorSource(np.zeros(k)))
    builder.Connect(split.get_output_port(0), sender.get_position_input_port())
    builder.Connect(zero.get_output_port(), sender.get_torque_input_port())
    publish_on_lcm(
        builder,
        sender.get_output_port(),
        name=f"{prefix}iiwa_command_publisher",
        channel="IIWA_COMMAND",
        lcm_type=lcmt_iiwa_command,
        lcm=lcm,
        period=IIWA_STATUS_PERIOD,
    )
    receiver = builder.AddNamedSystem(f"{prefix}iiwa_status_receiver", IiwaStatusReceiver(k))
    subscribe_on_lcm(
        builder,
        receiver.get_input_port(),
        name=f"{prefix}iiwa_status_subscriber",
        channel=status_channel,
        lcm_type=lcmt_iiwa_status,
        lcm=lcm,
    )
    return receiver


def add_iiwa_status_watchdog(
    builder,
    *,
    lcm,
    safety,
    status_channel: str = "IIWA_STATUS",
    timeout: float = 3 * IIWA_STATUS_PERIOD,
    prefix: str = "",
):
    """:func:`~drake_cfvol.comanip.robot_status.add_status_watchdog` on the
    iiwa's status (``lcmt_iiwa_status`` every :data:`IIWA_STATUS_PERIOD`).
    Returns the watchdog."""
    return add_status_watchdog(
        builder,
        lcm=lcm,
        safety=safety,
        status_type=lcmt_iiwa_status,
        status_channel=status_channel,
        period=IIWA_STATUS_PERIOD,
        timeout=timeout,
        prefix=prefix,
    )


def grip_point(wc) -> np.ndarray:
    """Where a hand pushes the tool: the centre of the proximity shape
    nearest the tool frame's origin among the bodies welded to its body (a
    TCP frame's body has none of its own), in the tool body's frame, m."""
    plant, body = wc.plant, wc.tool_frame.body()
    inspector = wc.scene_graph.model_inspector()
    ctx = wc.plant_context(wc.slice.q_default[wc.slice.qidx])
    X_TW = body.EvalPoseInWorld(ctx).inverse()
    p_T = wc.tool_frame.GetFixedPoseInBodyFrame().translation()
    centres = [
        X_TW @ other.EvalPoseInWorld(ctx) @ inspector.GetPoseInFrame(g).translation()
        for other in plant.GetBodiesWeldedTo(body)
        for g in plant.GetCollisionGeometriesForBody(other)
    ]
    return min(centres, key=lambda c: np.linalg.norm(c - p_T)) if centres else p_T.copy()


def tool_radius(wc) -> float:
    """How far the tool's surface lies from its grip point (:func:`grip_point`),
    m: the point's depth inside the tool body's geometry (Drake's signed
    distance to a point, at the default configuration), at least 1 cm."""
    p_BG = grip_point(wc)
    ctx = wc.plant_context(wc.slice.q_default[wc.slice.qidx])
    p_WT = wc.tool_frame.body().EvalPoseInWorld(ctx).multiply(p_BG)
    sg = wc.scene_graph
    query = sg.get_query_output_port().Eval(sg.GetMyContextFromRoot(wc.context))
    mine = {
        g for b in wc.plant.GetBodiesWeldedTo(wc.tool_frame.body()) for g in wc.plant.GetCollisionGeometriesForBody(b)
    }
    depths = [-r.distance for r in query.ComputeSignedDistanceToPoint(p_WT, threshold=1.0) if r.id_G in mine]
    return max([0.01] + depths)


def add_hand(builder, plant, hand_body, tool_frame, wrench, *, tool_radius: float, initial_direction, p_BG=None):
    """The co-worker's hand pushing the tool with ``wrench``'s force, through
    contact. Returns the :class:`CoworkerHand`."""
    hand = builder.AddNamedSystem(
        "coworker_hand",
        CoworkerHand(
            plant, hand_body, tool_frame, tool_radius=tool_radius, initial_direction=initial_direction, p_BG=p_BG
        ),
    )
    builder.Connect(wrench, hand.wrench_input)
    builder.Connect(plant.get_body_poses_output_port(), hand.body_poses_input)
    builder.Connect(plant.get_body_spatial_velocities_output_port(), hand.body_spatial_velocities_input)
    builder.Connect(hand.spatial_forces_output, plant.get_applied_spatial_force_input_port())
    return hand


def add_iiwa_controller(
    builder,
    *,
    workcell,
    table,
    lcm,
    period: float = 0.01,
    config: CoManipulationConfig = CoManipulationConfig(),
    name: str = "controller",
    status_channel: str = "IIWA_STATUS",
    status_timeout: float = 3 * IIWA_STATUS_PERIOD,
):
    """The co-manipulation controller of a torque-sensing iiwa, talking to
    it over LCM only: what runs beside the real robot. Its SceneGraph holds
    the workcell (a plant posed from the status's measured positions, never
    simulated); :func:`~drake_cfvol.systems.AddCoManipulation` on it, fed the
    measured position and the driver's external-torque estimate; its
    desired state sent as the iiwa's command. A
    :class:`~drake_cfvol.systems.StatusWatchdog` (``{name}_status_watchdog``)
    holds the last command while no new status has come for
    ``status_timeout``. On the robot, ``lcm`` is the
    robot's network; in a test, ``DrakeLcm("memq://")`` shared with a
    simulated station (:func:`add_iiwa_station`).

    Args:
        workcell: a workcell of the cell (a file's: its models are added).
        table: the bounds table.
        lcm: the LCM instance (a ``LcmInterfaceSystem`` on it must be in
            the diagram, as :func:`add_iiwa_station` adds).
        period: the control period, s.
        config: the gains and limits (``AddCoManipulation``'s); the safety
            filter is needed (its desired state is the iiwa's command).
        name: prefix of the added systems' names.
        status_channel: the LCM channel of the robot's status.
        status_timeout: how long without a new status holds the command, s
            (three status periods).

    Returns:
        (the :class:`~drake_cfvol.systems.CoManipulationSystems`, the
        ``IiwaStatusReceiver``)
    """
    k = workcell.num_joints

    def interface(cm):
        status = add_iiwa_controller_interface(
            builder, lcm, cm.desired_state_output, k, prefix=f"{name}_", status_channel=status_channel
        )
        add_iiwa_status_watchdog(
            builder, lcm=lcm, safety=cm.safety, status_channel=status_channel, timeout=status_timeout, prefix=f"{name}_"
        )
        return status

    return add_lcm_controller(
        builder,
        workcell=workcell,
        table=table,
        period=period,
        config=config,
        name=name,
        status_period=IIWA_STATUS_PERIOD,
        add_interface=interface,
        who="add_iiwa_controller: the iiwa",
    )
