"""Co-manipulation in a user's own Drake station: :func:`AddCoManipulation`
adds path progress, the bounds, the push's plausibility check, the
admittance and the runtime safety filter to the user's ``DiagramBuilder``,
wired to the plant's measured state and the SceneGraph's query port; and
:class:`ToolPushForce` applies a push at the tool to a simulated plant as a
real force.
"""

import dataclasses
import math
import typing
from collections.abc import Iterable

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.geometry import GeometryId, SceneGraph
from pydrake.multibody.math import SpatialForce
from pydrake.multibody.plant import ExternallyAppliedSpatialForce, MultibodyPlant
from pydrake.multibody.tree import Frame, ModelInstanceIndex
from pydrake.systems.framework import DiagramBuilder, InputPort, LeafSystem, OutputPort
from pydrake.systems.primitives import Adder, Demultiplexer

from drake_cfvol.algorithm.table import BoundsTable, check_table
from drake_cfvol.exceptions import ParameterError, StationError
from drake_cfvol.io.arguments import instance, real_number
from drake_cfvol.scene.robot import RobotSlice, robot_instances
from drake_cfvol.systems.admittance import AdmittanceConfig, AdmittanceDeformation
from drake_cfvol.systems.bounds_source import JointBoundsSource
from drake_cfvol.systems.filter.constraints import ToolSpeedLimit
from drake_cfvol.systems.filter.filter_kernel import return_time
from drake_cfvol.systems.filter.safety import SafetyFilter, SafetyFilterConfig
from drake_cfvol.systems.human_input import HumanInputCheck
from drake_cfvol.systems.path import PathProgress, PathProgressConfig, path_ramp, safe_path_rate

__all__ = ["AddCoManipulation", "CoManipulationConfig", "CoManipulationSystems", "ToolPushForce"]


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
            safety filter's ``desired_state``; None without the filter).
        commanded_position_output: k, rad (m): the safety filter's (without
            it, the admittance's).
        path_index_output: 1, the path index s.
        duration: seconds to run the path at its safe rate, the start time
            included.
        progress, bounds, check, admittance, safety: the systems themselves
            (their other ports: the filter's status, the check's fault
            count, the bounds); ``safety`` is None without the filter.
    """

    human_wrench_input: InputPort
    human_torque_input: InputPort
    desired_state_output: OutputPort
    commanded_position_output: OutputPort
    path_index_output: OutputPort
    duration: float
    progress: PathProgress
    bounds: JointBoundsSource
    check: HumanInputCheck
    admittance: LeafSystem  # an AdmittanceDeformation (a template's instantiation: no static type)
    safety: SafetyFilter | None


def _robot_instance(plant, robot):
    if isinstance(robot, ModelInstanceIndex):
        return robot
    if not plant.HasModelInstanceNamed(str(robot)):
        names = [plant.GetModelInstanceName(ModelInstanceIndex(i)) for i in range(plant.num_model_instances())]
        raise StationError(
            f"AddCoManipulation: robot '{robot}' is not a model instance of the plant (there are: {', '.join(names)})."
        )
    return plant.GetModelInstanceByName(str(robot))


def _check_table(table, robot_slice, plant, robot) -> None:
    check_table(table, "AddCoManipulation: table")
    names = list(table.joint_names)
    if names != robot_slice.joint_names:
        raise StationError(
            f"AddCoManipulation: the bounds table is for joints {names}, but model instance "
            f"'{plant.GetModelInstanceName(robot)}' of the plant has {robot_slice.joint_names}. Compute the bounds "
            "on a workcell of the same robot (Workcell.FromRobotDiagram of the same models)."
        )
    check_table(
        table,
        "AddCoManipulation: table",
        plant.GetPositionLowerLimits()[robot_slice.qidx],
        plant.GetPositionUpperLimits()[robot_slice.qidx],
    )


@dataclasses.dataclass
class CoManipulationConfig:
    """The gains and limits of :func:`AddCoManipulation` (its rate and wiring
    are its keyword arguments).

    Attributes:
        admittance: the admittance's gains.
        safety_filter: the runtime safety filter's margin and damper; None:
            no filter (the admittance's command drives the robot).
        path_progress: the path's share of the velocity limits, start time
            and rate cap.
        velocity_limits: (k,) rad/s (m/s); empty: the plant's.
        acceleration_limits: (k,) rad/s^2 (m/s^2; .inf: none) every command
            keeps; empty: the plant's (inf where it has none).
        jerk_limits: (k,) rad/s^3 (m/s^3; .inf: none) every command keeps;
            empty: none.
    """

    admittance: AdmittanceConfig = dataclasses.field(default_factory=AdmittanceConfig)
    safety_filter: typing.Optional[SafetyFilterConfig] = dataclasses.field(default_factory=SafetyFilterConfig)
    path_progress: PathProgressConfig = dataclasses.field(default_factory=PathProgressConfig)
    velocity_limits: list[float] = dataclasses.field(default_factory=list)
    acceleration_limits: list[float] = dataclasses.field(default_factory=list)
    jerk_limits: list[float] = dataclasses.field(default_factory=list)


def _check_arguments(builder, plant, scene_graph, tool_frame, period, config) -> None:
    """AddCoManipulation's arguments of the wrong type refused by name (the table and the robot are checked
    against the plant by :func:`_resolve`)."""
    instance(builder, DiagramBuilder, "AddCoManipulation: builder", "pydrake.systems.framework.DiagramBuilder")
    instance(plant, MultibodyPlant, "AddCoManipulation: plant", "e.g. from AddMultibodyPlantSceneGraph")
    instance(scene_graph, SceneGraph, "AddCoManipulation: scene_graph", "the plant's, from AddMultibodyPlantSceneGraph")
    if not isinstance(tool_frame, str):
        instance(tool_frame, Frame, "AddCoManipulation: tool_frame", "a Frame of the plant, or a frame's name")
    if not 0 < real_number(period, "AddCoManipulation: period") < math.inf:
        raise ParameterError(f"AddCoManipulation: period must be a finite number of seconds > 0, got {period}.")
    instance(config, CoManipulationConfig, "AddCoManipulation: config")


def _named(name: str, what: str) -> str:
    return f"{name}_{what}" if name else what


def _resolve(plant, robot, table, tool_frame, config):
    """AddCoManipulation's arguments checked and defaulted: (robot, k,
    tool frame, velocity limits, path rate)."""
    robot = _robot_instance(plant, robot)
    rs = RobotSlice(plant, robot)
    _check_table(table, rs, plant, robot)
    if isinstance(tool_frame, str):
        owner = next((i for i in robot_instances(plant, robot) if plant.HasFrameNamed(tool_frame, i)), None)
        if owner is None:
            raise StationError(
                f"AddCoManipulation: tool_frame '{tool_frame}' is not a frame of "
                f"'{plant.GetModelInstanceName(robot)}' (or of a body it carries)."
            )
        tool_frame = plant.GetFrameByName(tool_frame, owner)
    limits = (
        np.asarray(config.velocity_limits, float)
        if len(config.velocity_limits)
        else plant.GetVelocityUpperLimits()[rs.vidx]
    )
    pp = config.path_progress
    rate = safe_path_rate(table, limits, share=pp.velocity_share)
    if pp.max_rate is not None:
        rate = min(rate, float(pp.max_rate))
    acceleration = (
        np.asarray(config.acceleration_limits, float)
        if len(config.acceleration_limits)
        else plant.GetAccelerationUpperLimits()[rs.vidx]
    )
    jerk = np.asarray(config.jerk_limits, float) if len(config.jerk_limits) else np.full(rs.k, np.inf)
    return robot, rs.k, tool_frame, (limits, acceleration, jerk), rate


def _safety_filter(f: SafetyFilterConfig, scene, table, limits, period, watched, tool_frame=None) -> SafetyFilter:
    """The filter of a config (``scene``: the plant, its SceneGraph and the robot; ``watched``: the obstacles'
    ids, those moving on their own, the overlap depth that faults it): its margin the table's where the config
    leaves it None."""
    margin = float(table.params.get("clearance", 0.0)) if f.clearance is None else float(f.clearance)
    obstacle_ids, dynamic_ids, overlap_depth = watched
    dynamic = list(dynamic_ids)
    velocity, acceleration, jerk = limits
    return SafetyFilter(
        *scene,
        velocity_limits=velocity,
        acceleration_limits=acceleration,
        jerk_limits=jerk,
        obstacle_ids=None if obstacle_ids is None else list(obstacle_ids) + dynamic,
        clearance=margin,
        influence_distance=f.influence_distance,
        damper_gain=f.damper_gain,
        allowance=f.allowance,
        period=period,
        initial_position=table.nominal[0],
        dynamic_ids=dynamic,
        constraints=[] if f.tool_speed is None else [ToolSpeedLimit(tool_frame, f.tool_speed)],
        overlap_depth=overlap_depth,
    )


def _lookahead(limits, rate: float, period: float) -> float:
    """How far ahead (path index units) the safety filter brakes for the
    box's faces: the path's travel in twice the slowest joint's braking
    time (from its velocity limit, the jerk's ramp and an update
    included); 0 without acceleration limits."""
    # The braking time is the filter's own (its return to the box ahead).
    times = [return_time(v, a, j, period) for v, a, j in zip(*limits)]
    braking = max((t for t in times if math.isfinite(t)), default=None)
    return 0.0 if braking is None else rate * 2.0 * braking


def AddCoManipulation(
    builder: DiagramBuilder,
    *,
    plant: MultibodyPlant,
    scene_graph: SceneGraph,
    robot: ModelInstanceIndex | str,
    table: BoundsTable,
    tool_frame: Frame | str,
    period: float = 0.01,
    measured_state: bool = True,
    config: CoManipulationConfig = CoManipulationConfig(),
    obstacle_ids: Iterable[GeometryId] | None = None,
    dynamic_ids: Iterable[GeometryId] = (),
    name: str = "cfvol",
    overlap_depth: float | None = None,
) -> CoManipulationSystems:
    """Adds co-manipulation to a user's builder: path progress, the bounds
    of ``table`` one control period ahead, the push's check, the admittance
    and the runtime safety filter (velocity limits, the box, the clearance
    margin by the SceneGraph's signed distances), wired among themselves and
    to the SceneGraph's query port.

    The plant may hold more than the robot (a gripper, free parts, other
    machines). With ``measured_state`` the plant's state output for the
    robot's model instance feeds the admittance (the wrench's Jacobian at
    the measured configuration) and the safety filter (its rows taken where
    the robot is, constraining the command's own step; its tracking fault
    holds the admittance, beside the push's check): for a time-stepping
    plant under a controller. Without it the caller poses the
    plant from ``commanded_position_output`` (a kinematic run) or connects
    a measured position to ``admittance.measured_position_input`` and
    ``safety.measured_position_input`` itself.

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
        measured_state: wire the plant's state output (see above).
        config: the gains and limits (:class:`CoManipulationConfig`).
        obstacle_ids: the geometries the filter keeps the margin to
            (default: every proximity geometry not on the robot).
        dynamic_ids: those of them that move on their own (measured at every update).
        name: prefix of the added systems' names (unique per builder; empty: none).
        overlap_depth: m: a geometry of ``dynamic_ids`` overlapping the robot
            deeper than this faults the filter, which then holds (the
            safety filter's ``filter_fault_output``); None: never.

    Returns:
        The :class:`CoManipulationSystems`.

    Raises:
        StationError: an unknown robot or frame, or a table for other joints.
    """
    _check_arguments(builder, plant, scene_graph, tool_frame, period, config)
    if not plant.is_finalized():
        raise StationError("AddCoManipulation: finalize the plant first (plant.Finalize()).")
    robot, k, tool_frame, limits, rate = _resolve(plant, robot, table, tool_frame, config)
    a, f = config.admittance, config.safety_filter
    progress = builder.AddNamedSystem(
        _named(name, "path_progress"),
        PathProgress(
            table.g,
            rate=rate,
            start_time=config.path_progress.start_time,
            lead=period,
            ramp=path_ramp(table, rate, limits[1], share=config.path_progress.velocity_share),
        ),
    )
    bounds = builder.AddNamedSystem(
        _named(name, "joint_bounds"),
        JointBoundsSource(table, clamp=True, lookahead=_lookahead(limits, rate, period)),
    )
    check = builder.AddNamedSystem(_named(name, "human_input_check"), HumanInputCheck(k, period=period))
    adm = builder.AddNamedSystem(
        _named(name, "admittance"),
        AdmittanceDeformation(
            k,
            mass=a.mass,
            damping=a.damping,
            stiffness=a.stiffness,
            period=period,
            plant=plant,
            tool_frame=tool_frame,
            velocity_limits=limits[0],
            acceleration_limits=limits[1],
            path_share=config.path_progress.velocity_share,
            robot=robot,
        ),
    )
    builder.Connect(progress.path_index_ahead_output, bounds.path_index_input)
    for port in ("nominal", "lower", "upper"):
        builder.Connect(bounds.GetOutputPort(port), adm.GetInputPort(port))
    builder.Connect(check.human_torque_output, adm.human_torque_input)
    builder.Connect(check.human_wrench_output, adm.human_wrench_input)
    safety, commanded = None, adm.commanded_position_output
    if f is not None:
        safety = builder.AddNamedSystem(
            _named(name, "safety_filter"),
            _safety_filter(
                f,
                (plant, scene_graph, robot),
                table,
                limits,
                period,
                (obstacle_ids, dynamic_ids, overlap_depth),
                tool_frame,
            ),
        )
        ports = ("nominal", "lower", "upper") + (("lower_ahead", "upper_ahead") if bounds.lookahead > 0 else ())
        for port in ports:
            builder.Connect(bounds.GetOutputPort(port), safety.GetInputPort(port))
        builder.Connect(adm.commanded_position_output, safety.desired_position_input)
        builder.Connect(scene_graph.get_query_output_port(), safety.query_object_input)
        commanded = safety.commanded_position_output
    if safety is not None:
        # The admittance holds while the push is implausible or while the
        # measured robot drifts faster than the command can counter (the
        # filter's tracking fault, 0 unless a measured position reaches the
        # filter: here or by the caller): either one above 0.5 holds it.
        holds = builder.AddNamedSystem(_named(name, "admittance_hold"), Adder(2, 1))
        builder.Connect(check.fault_output, holds.get_input_port(0))
        builder.Connect(safety.tracking_fault_output, holds.get_input_port(1))
        builder.Connect(holds.get_output_port(), adm.hold_input)
    else:
        builder.Connect(check.fault_output, adm.hold_input)
    if measured_state:
        split = builder.AddNamedSystem(_named(name, "measured_state"), Demultiplexer([k, k]))
        builder.Connect(plant.get_state_output_port(robot), split.get_input_port(0))
        builder.Connect(split.get_output_port(0), adm.measured_position_input)
        if safety is not None:
            builder.Connect(split.get_output_port(0), safety.measured_position_input)
    return CoManipulationSystems(
        human_wrench_input=check.human_wrench_input,
        human_torque_input=check.human_torque_input,
        desired_state_output=safety.desired_state_output if safety is not None else None,
        commanded_position_output=commanded,
        path_index_output=progress.path_index_output,
        duration=progress.duration,
        progress=progress,
        bounds=bounds,
        check=check,
        admittance=adm,
        safety=safety,
    )


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

    def __init__(self, frame: Frame):
        super().__init__()
        self._body = frame.body().index()
        self._p_BoFo_B = frame.GetFixedPoseInBodyFrame().translation().copy()
        self.wrench_input = self.DeclareVectorInputPort(name="wrench", size=6)
        self.spatial_forces_output = self.DeclareAbstractOutputPort(
            "spatial_forces", lambda: AbstractValue.Make([ExternallyAppliedSpatialForce()]), self._calc
        )

    def _calc(self, context, output) -> None:
        w = np.asarray(self.wrench_input.Eval(context), float)
        force = ExternallyAppliedSpatialForce()
        force.body_index = self._body
        force.p_BoBq_B = self._p_BoFo_B
        force.F_Bq_W = SpatialForce(w[:3], w[3:])
        output.set_value([force])
