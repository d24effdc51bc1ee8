"""A dynamic co-manipulation run: a time-stepping ``MultibodyPlant`` (the
scenario's ``simulation.plant_config``), the robot under its driver (Drake's
``InverseDynamicsController`` on a plant of the robot alone), and the
co-worker's push acting on the plant as real forces: joint torques as
generalized forces, the tool wrench as a spatial force at the tool.
"""

from __future__ import annotations

import numpy as np
from pydrake.multibody.plant import AddMultibodyPlant, MultibodyPlant
from pydrake.systems.controllers import InverseDynamicsController
from pydrake.systems.primitives import (
    Adder,
    ConstantVectorSource,
    Demultiplexer,
    MatrixGain,
    StateInterpolatorWithDiscreteDerivative,
)

from drake_cfvol.comanip.drivers import InverseDynamicsDriver
from drake_cfvol.exceptions import ScenarioError
from drake_cfvol.scene.robot import RobotSlice
from drake_cfvol.systems.hand import add_hand_body
from drake_cfvol.systems.station import ToolPushForce

__all__ = ["add_simulated_plant", "add_driver", "driver_of"]


def driver_of(scenario, wc):
    """The robot's driver config (default :class:`InverseDynamicsDriver`).

    Raises:
        ScenarioError: a driver named for a model that is not the robot.
    """
    drivers = scenario.simulation.model_drivers
    unknown = sorted(set(drivers) - {wc.robot_name})
    if unknown:
        raise ScenarioError(
            "scenario",
            f"simulation.model_drivers.{unknown[0]}",
            f"names no robot of cell '{wc.name}' (its robot is '{wc.robot_name}')",
        )
    return drivers.get(wc.robot_name, InverseDynamicsDriver())


def add_simulated_plant(builder, wc, plant_config, *, hand: bool = False):
    """The time-stepping plant and its SceneGraph with the workcell's
    models (unfinalized), and the co-worker's hand if asked. Returns
    (plant, scene_graph, robot, Drake's ModelInstanceInfo list, hand body
    or None)."""
    plant, scene_graph = AddMultibodyPlant(plant_config, builder)
    models = wc.add_models(plant)
    body = add_hand_body(plant) if hand else None
    return plant, scene_graph, plant.GetModelInstanceByName(wc.robot_name), models, body


def _control_plant(wc, time_step: float):
    """The robot alone, every joint actuated: the controller's model."""
    control = MultibodyPlant(time_step)
    robot = wc.add_robot_to_plant(control)
    # Every actuator (the plant holds only the robot): a model instance's
    # own list is empty before Finalize.
    actuated = {control.get_joint_actuator(a).joint().index() for a in control.GetJointActuatorIndices()}
    for joint in (control.get_joint(j) for j in control.GetJointIndices(robot)):
        if joint.type_name() in ("revolute", "prismatic") and joint.index() not in actuated:
            control.AddJointActuator(f"cfvol_{joint.name()}", joint)
    control.Finalize()
    return control


def add_driver(builder, scenario, wc, plant, robot, *, commanded, torque, wrench, period: float, desired_state=None):
    """The robot's driver in a finalized time-stepping plant, and the push as
    real forces.

    Args:
        commanded: the commanded position's port (k).
        torque: the co-worker's joint torques' port (k), applied as
            generalized forces.
        wrench: the co-worker's tool wrench port (6), applied at the tool.
        period: the command's update period, s.
        desired_state: a port of the desired state (2k; the safety filter's),
            or None: made from the command (its discrete derivative).

    Returns:
        The measured position's port (k).
    """
    driver = driver_of(scenario, wc)
    rs = RobotSlice(plant, robot)
    k = rs.k
    control = _control_plant(wc, plant.time_step())
    idc = builder.AddNamedSystem(
        "inverse_dynamics_controller",
        InverseDynamicsController(
            control, kp=[driver.kp] * k, ki=[driver.ki] * k, kd=[driver.kd] * k, has_reference_acceleration=False
        ),
    )
    if desired_state is None:
        desired = builder.AddNamedSystem(
            "desired_state", StateInterpolatorWithDiscreteDerivative(k, period, suppress_initial_transient=True)
        )
        builder.Connect(commanded, desired.get_input_port())
        desired_state = desired.get_output_port()
    builder.Connect(desired_state, idc.get_input_port_desired_state())
    builder.Connect(plant.get_state_output_port(robot), idc.get_input_port_estimated_state())
    total = builder.AddNamedSystem("joint_forces", Adder(2, k))
    builder.Connect(idc.get_output_port_control(), total.get_input_port(0))
    builder.Connect(torque, total.get_input_port(1))
    select = np.zeros((plant.num_velocities(), k))
    select[rs.vidx, np.arange(k)] = 1.0
    to_plant = builder.AddNamedSystem("to_generalized_forces", MatrixGain(select))
    builder.Connect(total.get_output_port(), to_plant.get_input_port())
    builder.Connect(to_plant.get_output_port(), plant.get_applied_generalized_force_input_port())
    if plant.num_actuated_dofs() > 0:
        idle = builder.AddNamedSystem("no_actuation", ConstantVectorSource(np.zeros(plant.num_actuated_dofs())))
        builder.Connect(idle.get_output_port(), plant.get_actuation_input_port())
    push = builder.AddNamedSystem("push_force", ToolPushForce(plant.GetFrameByName(wc.tool_frame.name(), robot)))
    builder.Connect(wrench, push.wrench_input)
    builder.Connect(push.spatial_forces_output, plant.get_applied_spatial_force_input_port())
    split = builder.AddNamedSystem("measured_state", Demultiplexer([k, k]))
    builder.Connect(plant.get_state_output_port(robot), split.get_input_port(0))
    return split.get_output_port(0)
