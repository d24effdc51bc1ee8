"""Compiling the safety filter's compiled parts once (or loading them from
numba's cache) before a run needs them.

A fresh cache compiles them at a run's first filter update (about a
minute on 2 cores); :func:`warm_up` does it ahead, on a made-up scene, so
that a caller can overlap it with other work (``cfvol demo`` does it while
a helper process compiles the collision kernel). The scene is built with
the public systems, so the compiled signatures are the ones a run uses.
"""

from __future__ import annotations

import time

import numpy as np
from pydrake.geometry import Box, SceneGraph, Sphere
from pydrake.math import RigidTransform
from pydrake.multibody.plant import CoulombFriction, MultibodyPlant
from pydrake.multibody.tree import FixedOffsetFrame, RevoluteJoint, SpatialInertia
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.rendering import MultibodyPositionToGeometryPose

from drake_cfvol.kernel.warmup import cached
from drake_cfvol.systems.filter import damper_kernel, distance_kernel, filter_kernel, stop_guard
from drake_cfvol.systems.filter.safety import SafetyFilter

__all__ = ["warm_up", "WARM_UP_SHARE"]

#: Its share of a fresh compile, s (measured with the kernel's shares,
#: :data:`drake_cfvol.kernel.STEP_SHARES`).
WARM_UP_SHARE = 55.0


def _two_link_station():
    """A planar two-link arm (links 0.5 and 0.4 m) whose tip, a sphere of
    radius 0.05 m, reaches a wall whose face is at x = 0.8 m, and a safety
    filter at 1 ms posing the arm in the SceneGraph: the diagram and the
    filter, its inputs exported."""
    builder = DiagramBuilder()
    sg = builder.AddSystem(SceneGraph())
    plant = MultibodyPlant(0.0)
    plant.RegisterAsSourceForSceneGraph(sg)
    arm = plant.AddModelInstance("arm")
    inertia = SpatialInertia.SolidSphereWithMass(1.0, 0.05)
    link1 = plant.AddRigidBody("link1", arm, inertia)
    link2 = plant.AddRigidBody("link2", arm, inertia)
    plant.AddJoint(RevoluteJoint("j1", plant.world_frame(), link1.body_frame(), [0, 0, 1]))
    elbow = plant.AddFrame(FixedOffsetFrame("elbow", link1.body_frame(), RigidTransform([0.5, 0, 0])))
    plant.AddJoint(RevoluteJoint("j2", elbow, link2.body_frame(), [0, 0, 1]))
    friction = CoulombFriction(0.5, 0.5)
    plant.RegisterCollisionGeometry(link2, RigidTransform([0.4, 0, 0]), Sphere(0.05), "tip", friction)
    plant.RegisterCollisionGeometry(link1, RigidTransform([0.25, 0, 0]), Box(0.5, 0.05, 0.05), "link", friction)
    wall = RigidTransform([1.3, 0, 0])
    plant.RegisterCollisionGeometry(plant.world_body(), wall, Box(1.0, 4.0, 1.0), "wall", friction)
    plant.Finalize()
    sf = builder.AddSystem(
        SafetyFilter(
            plant,
            sg,
            arm,
            velocity_limits=[1.0, 1.5],
            acceleration_limits=[10.0, 15.0],  # limited: the braking parts compile too
            jerk_limits=[500.0, 750.0],
            period=1e-3,
            clearance=0.02,
            influence_distance=0.15,
        )
    )
    to_pose = builder.AddSystem(MultibodyPositionToGeometryPose(plant))
    builder.Connect(sf.commanded_position_output, to_pose.get_input_port())
    builder.Connect(to_pose.get_output_port(), sg.get_source_pose_port(plant.get_source_id()))
    builder.Connect(sg.get_query_output_port(), sf.query_object_input)
    for port in (sf.desired_position_input, sf.lower_input, sf.upper_input, sf.nominal_input):
        builder.ExportInput(port, port.get_name())
    return builder.Build(), sf


#: The filter's compiled functions an update calls (all cached: nothing to do).
_COMPILED = (
    filter_kernel.filter_rounds,
    filter_kernel.stack_rows,
    filter_kernel.budget_after,
    filter_kernel.request,
    filter_kernel.hard_interval,
    filter_kernel.braked_rows_at,  # braked_rows, brake_rows and plane_bends compile into it
    filter_kernel.update_kinematics,  # braking_lead, the poses, levers and pair speeds compile into it
    filter_kernel.finish,
    filter_kernel.outside,
    damper_kernel.pair_rows,
    damper_kernel.near_pairs,
    distance_kernel.convex_rows,  # GJK compiles into it
    stop_guard.stop_rows,  # brake_path's walk (_brake_joint) compiles into it
)


def _two_link_run() -> None:
    """50 updates of the two-link station's filter with the tip swung into
    the wall (every compiled part of an update called)."""
    diagram, sf = _two_link_station()
    sim = Simulator(diagram)
    ctx = sim.get_mutable_context()
    q0 = [np.arccos(0.7 / 0.9), 0.0]  # the tip 0.05 m off the wall
    sf.set_initial_position(sf.GetMyMutableContextFromRoot(ctx), q0)
    for name, value in (("desired_position", [-0.3, 0.0]), ("lower", [-3.0, -3.0]), ("upper", [3.0, 3.0])):
        diagram.GetInputPort(name).FixValue(ctx, np.asarray(value, float))
    diagram.GetInputPort("nominal").FixValue(ctx, np.asarray(q0, float))
    sim.AdvanceTo(0.05)
    # The rows of pairs only Drake measured, where GJK left a pair that
    # touches: made from Python (the update's other rows in convex_rows).
    sf._damper._kernel_rows(
        np.zeros(0, np.int64),
        np.zeros(0),
        np.zeros((0, 3)),
        np.zeros((0, 2, 3)),
        *sf._damper.kinematics.poses_and_jacobians(np.zeros(2)),
    )
    # A hold's braking calls this from Python (the update only from compiled code).
    filter_kernel.hard_interval(np.ones(2), 1e-3, np.zeros(2), np.zeros(2), np.full(2, 10.0), np.full(2, 500.0))


def warm_up() -> float:
    """Compiles the filter's parts by a short run of a made-up station
    (:func:`_two_link_run`), unless numba's cache already holds them all
    (then they load at a run's first update). Returns the seconds it took."""
    t0 = time.perf_counter()
    if not all(cached(f) for f in _COMPILED):
        _two_link_run()
    return time.perf_counter() - t0
