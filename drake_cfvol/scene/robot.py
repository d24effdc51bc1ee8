"""The robot inside a plant that may hold more: its bodies (a gripper
welded to its flange moves with it), its k joints' places in the plant's
position and velocity vectors, and the map from the robot's k positions to
the plant's (every other degree of freedom held where the plant's default
context puts it: a gripper's fingers, a free part lying on a table).

A station's ``MultibodyPlant`` rarely holds the robot alone; these helpers
let the workcell, the kernel's arrays and the systems read and pose the
robot's k joints in any plant.
"""

from __future__ import annotations

import numpy as np

from drake_cfvol.exceptions import DimensionError, WorkcellError

__all__ = ["RobotSlice", "robot_bodies", "robot_instances", "robot_joints"]


def robot_joints(plant, robot) -> list:
    """The robot's joints with positions, in the plant's position order.

    Raises:
        WorkcellError: a joint with more than one position (a ball or free
            joint): only revolute and prismatic joints are supported.
    """
    joints = [plant.get_joint(j) for j in plant.GetJointIndices(robot)]
    joints = sorted((j for j in joints if j.num_positions() > 0), key=lambda j: j.position_start())
    for j in joints:
        if j.num_positions() != 1:
            raise WorkcellError(
                f"joint '{j.name()}' of model instance '{plant.GetModelInstanceName(robot)}' has "
                f"{j.num_positions()} positions ({j.type_name()}); only revolute and prismatic joints are "
                "supported. Weld a floating base to the world, or give the robot as the model instance of its "
                "arm alone."
            )
    return joints


def robot_bodies(plant, robot) -> list:
    """Indices of the bodies that belong to the robot: its model instance's
    and every other body its joints move (a gripper or a tool welded to the
    flange, in a model instance of its own). The world body is never one."""
    joints = list(plant.GetJointIndices(robot))
    moved = set(plant.GetBodiesKinematicallyAffectedBy(joints)) if joints else set()
    world = plant.world_body().index()
    out = {b for b in plant.GetBodyIndices(robot)} | moved
    out.discard(world)
    return sorted(out, key=int)


def robot_instances(plant, robot) -> list:
    """The robot's model instance first, then every other instance one of
    whose bodies the robot's joints move (a gripper): the robot of Drake's
    collision checkers."""
    out = [robot]
    for b in robot_bodies(plant, robot):
        inst = plant.get_body(b).model_instance()
        if inst not in out:
            out.append(inst)
    return out


class RobotSlice:
    """The robot's k joints inside a plant of n positions and m velocities.

    Args:
        plant: a finalized ``MultibodyPlant``.
        robot: the robot's model instance.
        default_positions: (n,) the plant's positions the robot's map starts
            from (default: the plant's default context).

    Attributes:
        k: the robot's number of joints.
        qidx: (k,) the robot's joints' indices in the plant's positions.
        vidx: (k,) and in its velocities.
        q_default: (n,) the plant's positions at which every other degree of
            freedom is held.
        extra: True when the plant holds degrees of freedom beyond the robot's.
    """

    def __init__(self, plant, robot, default_positions=None):
        joints = robot_joints(plant, robot)
        self.plant, self.robot = plant, robot
        self.k = len(joints)
        self.joint_names = [j.name() for j in joints]
        self.qidx = np.array([j.position_start() for j in joints], int)
        self.vidx = np.array([j.velocity_start() for j in joints], int)
        self._local_velocity = {int(j.index()): n for n, j in enumerate(joints)}
        n = plant.num_positions()
        if default_positions is None:
            default_positions = plant.GetPositions(plant.CreateDefaultContext())
        self.q_default = np.asarray(default_positions, float).copy()
        if self.q_default.shape != (n,):
            raise DimensionError("default_positions", n, self.q_default.shape)
        self.extra = n != self.k or plant.num_velocities() != self.k

    def velocity_index(self, joint) -> int | None:
        """A robot joint's index among the k (None: not a robot joint)."""
        return self._local_velocity.get(int(joint.index()))

    def full(self, q) -> np.ndarray:
        """(n,) or (N, n): the plant's positions with the robot at ``q``
        ((k,) or (N, k)) and everything else held."""
        q = np.asarray(q, float)
        if q.shape[-1] != self.k:
            raise DimensionError("q", self.k, q.shape[-1], f"The robot's joints are {', '.join(self.joint_names)}.")
        if not self.extra:
            return q
        out = np.broadcast_to(self.q_default, q.shape[:-1] + (len(self.q_default),)).copy()
        out[..., self.qidx] = q
        return out

    def set_positions(self, plant_context, q) -> None:
        """Poses the robot's joints in a context of the plant (nothing else changes)."""
        if self.extra:
            self.plant.SetPositions(plant_context, self.robot, np.asarray(q, float))
        else:
            self.plant.SetPositions(plant_context, np.asarray(q, float))

    def positions(self, plant_context) -> np.ndarray:
        """(k,) the robot's positions in a context of the plant."""
        return np.asarray(self.plant.GetPositions(plant_context), float)[self.qidx]

    def columns(self, J, wrt: str = "v") -> np.ndarray:
        """The robot's columns of a Jacobian taken with respect to the
        plant's velocities (``"v"``) or position derivatives (``"qdot"``)."""
        return np.asarray(J)[..., self.vidx if wrt == "v" else self.qidx]
