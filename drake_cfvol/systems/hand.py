"""The co-worker's hand as a body in a simulated plant: it pushes the robot's
tool through contact, so that a torque-sensing arm feels the push the way a
real one does (Drake's simulated iiwa reports the plant's contact forces as
its external torque), and it can only push, never pull.
"""

from __future__ import annotations

import math

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.geometry import Sphere
from pydrake.math import RigidTransform
from pydrake.multibody.math import SpatialForce, SpatialVelocity
from pydrake.multibody.plant import CoulombFriction, ExternallyAppliedSpatialForce
from pydrake.multibody.tree import SpatialInertia
from pydrake.systems.framework import LeafSystem

__all__ = ["CoworkerHand", "add_hand_body", "first_push_direction", "waiting_point"]

#: The hand: a sphere of this radius (m) and mass (kg).
HAND_RADIUS = 0.03
HAND_MASS = 0.5

#: The largest force (N) the hand spends holding its place beside the tool,
#: beside the push itself and its own weight.
GRIP = 60.0

#: How far (m) the hand may get past its contact point before its push fades.
SLIP = 0.01


def waiting_point(p_WT, direction, tool_radius: float, standoff: float = 0.05) -> np.ndarray:
    """Where the hand's centre waits beside a tool point p_WT before a push
    along ``direction``, m."""
    u = np.asarray(direction, float) / np.linalg.norm(direction)
    return np.asarray(p_WT, float) - u * (tool_radius + HAND_RADIUS + standoff)


def first_push_direction(pushes, default=(1.0, 0.0, 0.0)) -> np.ndarray:
    """The direction of the first push with a force (the hand's side at the start)."""
    for p in pushes:
        f = np.asarray(p.wrench, float)[3:] if len(p.wrench) else np.zeros(3)
        if np.linalg.norm(f) > 0:
            return f / np.linalg.norm(f)
    return np.asarray(default, float)


def add_hand_body(plant, name: str = "coworker_hand"):
    """Adds the hand (a free sphere with proximity geometry) to an
    unfinalized plant, in a model instance of its own. Returns the body."""
    instance = plant.AddModelInstance(name)
    body = plant.AddRigidBody("hand", instance, SpatialInertia.SolidSphereWithMass(HAND_MASS, HAND_RADIUS))
    plant.RegisterCollisionGeometry(body, RigidTransform(), Sphere(HAND_RADIUS), "hand", CoulombFriction(0.6, 0.5))
    plant.RegisterVisualGeometry(body, RigidTransform(), Sphere(HAND_RADIUS), "hand", [0.95, 0.75, 0.6, 1.0])
    return body


class CoworkerHand(LeafSystem):
    """Forces on the hand body: it follows a point beside the tool (springs
    and a damper D relative to the tool's motion, its weight carried), and
    while the wrench's force F is non-zero it moves to touch the tool on the
    side facing away from F and presses with F: along F only F and a soft
    spring act (the push's force reaches the tool through the contact),
    across F a stiff spring holds the hand on the tool (a hand does not slip
    off what it pushes). Between pushes it waits ``standoff`` (m) away from
    the tool along the last push's direction, out of contact.

    .. pydrake_system::

        name: CoworkerHand
        input_ports:
        - wrench
        - body_poses
        - body_spatial_velocities
        output_ports:
        - spatial_forces

    Args:
        plant: the finalized plant holding ``hand`` and the tool frame.
        hand: the hand's body (:func:`add_hand_body`).
        tool_frame: the tool's frame.
        tool_radius: how far the tool's surface lies from the grip point, m.
        p_BG: the grip point, where the hand pushes, in the tool body's frame
            (default: the tool frame's origin).
        stiffness, damping: N/m and N s/m of the follow spring along the push.
        lateral_stiffness: N/m, across the push.
        initial_direction: the direction it waits along before the first
            push (the first push's, so that it starts on the right side).
        standoff: m, the gap kept between pushes.
    """

    def __init__(
        self,
        plant,
        hand,
        tool_frame,
        *,
        tool_radius: float,
        stiffness: float = 150.0,
        damping: float = 60.0,
        standoff: float = 0.05,
        lateral_stiffness: float = 3000.0,
        initial_direction=(0.0, 0.0, -1.0),
        p_BG=None,
    ):
        super().__init__()
        self._hand = hand.index()
        self._tool = tool_frame.body().index()
        self._hand_i, self._tool_i = int(self._hand), int(self._tool)  # list positions in the ports' values
        self._p_BT = (
            tool_frame.GetFixedPoseInBodyFrame().translation().copy()
            if p_BG is None
            else np.asarray(p_BG, float).copy()
        )
        self._reach = float(tool_radius) + HAND_RADIUS
        self._k, self._d, self._gap = float(stiffness), float(damping), float(standoff)
        self._k_lat = float(lateral_stiffness)
        self._weight = HAND_MASS * np.linalg.norm(plant.gravity_field().gravity_vector())
        self._up = -plant.gravity_field().gravity_vector() / max(
            np.linalg.norm(plant.gravity_field().gravity_vector()), 1e-12
        )
        u0 = np.asarray(initial_direction, float)
        self._side = self.DeclareDiscreteState(u0 / np.linalg.norm(u0))  # the last push's direction
        self.DeclarePerStepDiscreteUpdateEvent(self._remember)
        self.wrench_input = self.DeclareVectorInputPort(name="wrench", size=6)
        self.body_poses_input = self.DeclareAbstractInputPort("body_poses", AbstractValue.Make([RigidTransform()]))
        self.body_spatial_velocities_input = self.DeclareAbstractInputPort(
            "body_spatial_velocities", AbstractValue.Make([SpatialVelocity()])
        )
        self.spatial_forces_output = self.DeclareAbstractOutputPort(
            "spatial_forces", lambda: AbstractValue.Make([ExternallyAppliedSpatialForce()]), self._calc
        )

    def push_direction(self, context) -> np.ndarray:
        """The current push's unit direction (the last one between pushes)."""
        return self._direction(context, np.asarray(self.wrench_input.Eval(context), float)[3:])

    def _direction(self, context, f) -> np.ndarray:
        n = math.sqrt(f @ f)
        return f / n if n > 0 else context.get_discrete_state(self._side).CopyToVector()

    def _remember(self, context, discrete_state) -> None:
        f = np.asarray(self.wrench_input.Eval(context), float)[3:]
        n = math.sqrt(f @ f)
        if n > 0:  # between pushes the state keeps the last push's direction as it is
            discrete_state.get_mutable_vector(self._side).SetFromVector(f / n)

    def _calc(self, context, output) -> None:
        # Evaluated at every plant step: scalar arithmetic where numpy's
        # per-call cost would dominate (the same values as the array forms).
        f = np.asarray(self.wrench_input.Eval(context), float)[3:]
        pushing = math.sqrt(f @ f) > 0
        u = self._direction(context, f)
        poses = self.body_poses_input.Eval(context)
        vels = self.body_spatial_velocities_input.Eval(context)
        X_WT = poses[self._tool_i]
        p_WT = X_WT.rotation().matrix() @ self._p_BT + X_WT.translation()
        p_WH = poses[self._hand_i].translation()
        v_tool, v_hand = vels[self._tool_i].translational(), vels[self._hand_i].translational()
        w_hand = vels[self._hand_i].rotational()
        target = p_WT - u * (self._reach + (0.0 if pushing else self._gap))
        e = target - p_WH
        along = u * (u @ e)
        k_along = self._k if pushing else self._k_lat  # between pushes it follows the tool firmly
        guide = k_along * along + self._k_lat * (e - along) + self._d * (v_tool - v_hand)
        # A hand's grip is limited: the guiding part never exceeds GRIP.
        guide *= min(1.0, GRIP / max(math.sqrt(guide @ guide), 1e-12))
        # A hand that slipped past the tool stops pushing: the push fades out
        # between SLIP and 3 SLIP beyond its target along the push.
        past = float(u @ (p_WH - target))
        f = f * min(max((3 * SLIP - past) / (2 * SLIP), 0.0), 1.0)
        force = guide + self._weight * self._up + f
        spatial = ExternallyAppliedSpatialForce()
        spatial.body_index = self._hand
        spatial.p_BoBq_B = _ORIGIN
        spatial.F_Bq_W = SpatialForce(-1e-3 * w_hand, force)
        output.set_value([spatial])


#: The hand's force acts at its centre.
_ORIGIN = np.zeros(3)
