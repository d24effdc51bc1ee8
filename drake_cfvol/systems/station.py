"""Co-manipulation in a user's own Drake station: :func:`AddCoManipulation`
adds path progress, the bounds, the push's plausibility check, the
admittance and the runtime safety filter to the user's ``DiagramBuilder``,
wired to the plant's measured state and the SceneGraph's query port; and
:class:`ToolPushForce` applies a push at the tool to a simulated plant as a
real force.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.multibody.math import SpatialForce
from pydrake.multibody.plant import ExternallyAppliedSpatialForce
from pydrake.multibody.tree import ModelInstanceIndex
from pydrake.systems.framework import LeafSystem
from pydrake.systems.primitives import Demultiplexer

from drake_cfvol.exceptions import StationError
from drake_cfvol.scene.robot import RobotSlice, robot_instances
from drake_cfvol.systems.admittance import AdmittanceDeformation
from drake_cfvol.systems.bounds_source import JointBoundsSource
from drake_cfvol.systems.human_input import HumanInputCheck
from drake_cfvol.systems.path import PathProgress, safe_path_rate
from drake_cfvol.systems.safety import SafetyFilter

__all__ = ["AddCoManipulation", "CoManipulationSystems", "ToolPushForce"]


@dataclasses.dataclass
class CoManipulationSystems:
    """What :func:`AddCoManipulation` added to a builder.

    Attributes:
        human_wrench_input: 6 values, [torque N m; force N] at the tool
            frame's origin, world frame (a wrist force-torque sensor).
        human_torque_input: k joint torques, N m (N for a prismatic joint):
            a torque-sensing arm's external-torque estimate.
        desired_state_output: 2k, the commanded position and velocity (for
            Drake's ``InverseDynamicsController`` or a driver): the straight
            line between consecutive commands, continuous in time (the
            safety filter's ``desired_state``).
        commanded_position_output: k, rad (m).
        path_index_output: 1, the path index s.
        duration: seconds to run the path at its safe rate, the start time
            included.
        progress, bounds, check, admittance, safety: the systems themselves
            (their other ports: the filter's status, the check's fault
            count, the bounds).
    """

    human_wrench_input: object
    human_torque_input: object
    desired_state_output: object
    commanded_position_output: object
    path_index_output: object
    duration: float
    progress: PathProgress
    bounds: JointBoundsSource
    check: HumanInputCheck
    admittance: object
    safety: SafetyFilter


def _robot_instance(plant, robot):
    if isinstance(robot, ModelInstanceIndex):
        return robot
    if not plant.HasModelInstanceNamed(str(robot)):
        names = [plant.GetModelInstanceName(ModelInstanceIndex(i)) for i in range(plant.num_model_instances())]
        raise StationError(f"AddCoManipulation: robot '{robot}' is not a model instance of the plant "
                           f"(there are: {', '.join(names)}).")
    return plant.GetModelInstanceByName(str(robot))


def _check_table(table, robot_slice, plant, robot) -> None:
    names = list(table.joint_names)
    if names != robot_slice.joint_names:
        raise StationError(
            f"AddCoManipulation: the bounds table is for joints {names}, but model instance "
            f"'{plant.GetModelInstanceName(robot)}' of the plant has {robot_slice.joint_names}. Compute the bounds "
            "on a workcell of the same robot (Workcell.FromRobotDiagram of the same models).")


def _wire(builder, progress, bounds, check, adm, safety, scene_graph) -> None:
    """Connects the added systems among themselves and to the SceneGraph."""
    builder.Connect(progress.path_index_ahead_output, bounds.path_index_input)
    for port in ("nominal", "lower", "upper"):
        builder.Connect(bounds.GetOutputPort(port), adm.GetInputPort(port))
        builder.Connect(bounds.GetOutputPort(port), safety.GetInputPort(port))
    builder.Connect(check.human_torque_output, adm.human_torque_input)
    builder.Connect(check.human_wrench_output, adm.human_wrench_input)
    builder.Connect(check.fault_output, adm.hold_input)
    builder.Connect(adm.commanded_position_output, safety.desired_position_input)
    builder.Connect(scene_graph.get_query_output_port(), safety.query_object_input)


def _resolve(plant, robot, table, tool_frame, velocity_limits, clearance, share, max_path_rate):
    """AddCoManipulation's arguments checked and defaulted: (robot, k,
    tool frame, velocity limits, margin, path rate)."""
    robot = _robot_instance(plant, robot)
    rs = RobotSlice(plant, robot)
    _check_table(table, rs, plant, robot)
    k = rs.k
    if isinstance(tool_frame, str):
        owner = next((i for i in robot_instances(plant, robot) if plant.HasFrameNamed(tool_frame, i)), None)
        if owner is None:
            raise StationError(f"AddCoManipulation: tool_frame '{tool_frame}' is not a frame of "
                               f"'{plant.GetModelInstanceName(robot)}' (or of a body it carries).")
        tool_frame = plant.GetFrameByName(tool_frame, owner)
    limits = (plant.GetVelocityUpperLimits()[rs.vidx] if velocity_limits is None
              else np.asarray(velocity_limits, float))
    margin = float(table.params.get("clearance", 0.0)) if clearance is None else float(clearance)
    rate = safe_path_rate(table, limits, share=share)
    if max_path_rate is not None:
        rate = min(rate, float(max_path_rate))
    return robot, k, tool_frame, limits, margin, rate


def AddCoManipulation(builder, *, plant, scene_graph, robot, table, tool_frame, period: float = 0.01,
                      clearance: float | None = None, velocity_limits=None, path_velocity_share: float = 0.5,
                      max_path_rate: float | None = None, start_time: float = 0.0, mass=10.0, damping=200.0,
                      stiffness=400.0, measured_state: bool = True, obstacle_ids=None,
                      influence_distance: float = 0.15, damper_gain: float = 1.0,
                      name: str = "cfvol") -> CoManipulationSystems:
    """Adds co-manipulation to a user's builder: path progress, the bounds
    of ``table`` one control period ahead, the push's check, the admittance
    and the runtime safety filter (velocity limits, the box, the clearance
    margin by the SceneGraph's signed distances).

    The plant may hold more than the robot (a gripper, free parts, other
    machines). With ``measured_state`` the plant's state output for the
    robot's model instance feeds the admittance (the wrench's Jacobian at
    the measured configuration) and the safety filter (its rows taken where
    the robot is, constraining the command's own step): for a
    time-stepping plant under a controller. Without it the plant is posed
    from ``commanded_position_output`` (a kinematic run; the caller wires
    the poses).

    Args:
        builder: the user's ``DiagramBuilder`` (the plant and the SceneGraph
            in it, e.g. from ``AddMultibodyPlantSceneGraph``).
        plant: the finalized ``MultibodyPlant``.
        scene_graph: its ``SceneGraph``.
        robot: the robot's model instance (or its name).
        table: the :class:`~drake_cfvol.BoundsTable` for the robot's joints.
        tool_frame: the frame the human's wrench acts at (a ``Frame`` or a
            frame name of ``robot``).
        period: the control period, s.
        clearance: the safety filter's margin, m (default: the table's).
        velocity_limits: (k,) rad/s (m/s); default: the plant's.
        path_velocity_share: the share of the velocity limits the path may
            use (:func:`safe_path_rate`); the rest is the push's.
        max_path_rate: a cap on the path's rate, waypoints/s.
        start_time: when the path starts, s.
        mass, damping, stiffness: the admittance's gains (scalars or (k,)).
        measured_state: wire the plant's state output (see above).
        obstacle_ids: the geometries the filter keeps the margin to
            (default: every proximity geometry not on the robot).
        influence_distance, damper_gain: the filter's damper.
        name: prefix of the added systems' names (unique per builder).

    Returns:
        The :class:`CoManipulationSystems`.

    Raises:
        StationError: an unknown robot or frame, or a table for other joints.
    """
    if not plant.is_finalized():
        raise StationError("AddCoManipulation: finalize the plant first (plant.Finalize()).")
    robot, k, tool_frame, limits, margin, rate = _resolve(plant, robot, table, tool_frame, velocity_limits,
                                                          clearance, path_velocity_share, max_path_rate)
    progress = builder.AddNamedSystem(f"{name}_path_progress", PathProgress(
        table.g, rate=rate, start_time=start_time, lead=period))
    bounds = builder.AddNamedSystem(f"{name}_joint_bounds", JointBoundsSource(table, clamp=True))
    check = builder.AddNamedSystem(f"{name}_human_input_check", HumanInputCheck(k, period=period))
    adm = builder.AddNamedSystem(f"{name}_admittance", AdmittanceDeformation(
        k, mass=mass, damping=damping, stiffness=stiffness, period=period, plant=plant, tool_frame=tool_frame,
        velocity_limits=limits, path_share=path_velocity_share, robot=robot))
    safety = builder.AddNamedSystem(f"{name}_safety_filter", SafetyFilter(
        plant, scene_graph, robot, velocity_limits=limits, obstacle_ids=obstacle_ids, clearance=margin,
        influence_distance=influence_distance, damper_gain=damper_gain, period=period,
        initial_position=table.nominal[0]))
    _wire(builder, progress, bounds, check, adm, safety, scene_graph)
    if measured_state:
        split = builder.AddNamedSystem(f"{name}_measured_state", Demultiplexer([k, k]))
        builder.Connect(plant.get_state_output_port(robot), split.get_input_port(0))
        builder.Connect(split.get_output_port(0), adm.measured_position_input)
        builder.Connect(split.get_output_port(0), safety.measured_position_input)
    return CoManipulationSystems(
        human_wrench_input=check.human_wrench_input, human_torque_input=check.human_torque_input,
        desired_state_output=safety.desired_state_output, commanded_position_output=safety.commanded_position_output,
        path_index_output=progress.path_index_output, duration=progress.duration, progress=progress,
        bounds=bounds, check=check, admittance=adm, safety=safety)


class ToolPushForce(LeafSystem):
    """A push at the tool as a real force on a simulated plant: the wrench
    [torque N m; force N] at a frame's origin, world frame, as an
    ``ExternallyAppliedSpatialForce`` on the frame's body (for the plant's
    ``applied_spatial_force`` input).

    .. pydrake_system::

        name: ToolPushForce
        input_ports:
        - wrench
        output_ports:
        - spatial_forces

    Args:
        frame: the frame (e.g. the tool's) whose origin the wrench acts at.
    """

    def __init__(self, frame):
        super().__init__()
        self._body = frame.body().index()
        self._p_BoFo_B = frame.GetFixedPoseInBodyFrame().translation().copy()
        self.wrench_input = self.DeclareVectorInputPort(name="wrench", size=6)
        self.spatial_forces_output = self.DeclareAbstractOutputPort(
            "spatial_forces", lambda: AbstractValue.Make([ExternallyAppliedSpatialForce()]), self._calc)

    def _calc(self, context, output) -> None:
        w = np.asarray(self.wrench_input.Eval(context), float)
        force = ExternallyAppliedSpatialForce()
        force.body_index = self._body
        force.p_BoBq_B = self._p_BoFo_B
        force.F_Bq_W = SpatialForce(w[:3], w[3:])
        output.set_value([force])
