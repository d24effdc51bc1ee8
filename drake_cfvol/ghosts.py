"""Collision checks of configurations the robot is not in, through the
diagram's own SceneGraph.

A query port answers for the geometry as it is posed now. The collision
guard must judge configurations the robot is about to take. So
:class:`GhostGuard` registers copies ("ghosts") of the robot's collision
geometry in the same SceneGraph, poses each at a configuration it is given,
and reads back through the ``query_object`` port which ghosts penetrate an
obstacle or themselves. Ghosts are proximity geometry only (never drawn),
and they are filtered against the real robot, the volume V and each other,
so nothing else in the diagram sees them; within a ghost, the robot's own
self-collision filters apply.
"""

from __future__ import annotations

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.geometry import (CollisionFilterDeclaration, FramePoseVector, GeometryFrame, GeometryInstance,
                              GeometrySet, ProximityProperties, QueryObject)
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.systems.framework import LeafSystem

from drake_cfvol.exceptions import ParameterError

__all__ = ["GhostGuard"]


class GhostGuard(LeafSystem):
    """Ghost copies of the robot's collision geometry in a SceneGraph, posed
    at given configurations, and which of them collide.

    .. pydrake_system::

        name: GhostGuard
        input_ports:
        - configurations
        - query_object
        output_ports:
        - geometry_pose
        - free

    ``configurations`` holds ``count`` configurations of the workcell's
    robot, one after another (count k values). ``geometry_pose`` poses the
    ghosts there (connect it to ``scene_graph.get_source_pose_port(
    ghost.source_id)``); ``free`` is 1 for each ghost that penetrates no
    obstacle and no other part of itself (Drake's point-pair penetration on
    the SceneGraph's ``query_object``), else 0.

    Args:
        scene_graph: the diagram's SceneGraph (before any context is made).
        workcell: the workcell whose robot the ghosts copy.
        count: number of ghosts.
        exclude_ids: geometry ids the ghosts ignore (the real robot, V).
        name: the geometry source's name.
    """

    def __init__(self, scene_graph, workcell, count: int, *, exclude_ids=(), name: str = "ghost_robots"):
        super().__init__()
        if int(count) < 1:
            raise ParameterError(f"GhostGuard: count must be >= 1 ghost, got {count}.")
        self.count = int(count)
        self.k = workcell.num_joints
        arrays = workcell.scene_arrays()
        self._arrays = arrays
        plant = workcell.plant
        inspector = workcell.scene_graph.model_inspector()
        self.source_id = scene_graph.RegisterSource(name)
        moving = arrays.moved_by.any(axis=0)
        # Robot bodies with collision geometry, in the kernel's body order.
        bodies = []
        for b, index in enumerate(arrays.body_indices):
            gids = plant.GetCollisionGeometriesForBody(plant.get_body(index))
            if gids:
                bodies.append((b, gids))
        self._frames = []  # per ghost: [(kernel body index, frame id)]
        self.ghost_ids = []  # per ghost: set of geometry ids
        per_body = []  # per ghost: {kernel body: geometry ids}
        for n in range(self.count):
            frames, ids, by_body = [], set(), {}
            for b, gids in bodies:
                fid = scene_graph.RegisterFrame(self.source_id, GeometryFrame(f"{name}_{n}_{arrays.body_names[b]}"))
                frames.append((b, fid))
                by_body[b] = []
                for m, gid in enumerate(gids):
                    inst = GeometryInstance(inspector.GetPoseInFrame(gid), inspector.GetShape(gid),
                                            f"{name}_{n}_{arrays.body_names[b]}_{m}")
                    new = scene_graph.RegisterGeometry(self.source_id, fid, inst)
                    props = inspector.GetProximityProperties(gid)
                    scene_graph.AssignRole(self.source_id, new, ProximityProperties(props) if props is not None
                                           else ProximityProperties())
                    ids.add(new)
                    by_body[b].append(new)
            self._frames.append(frames)
            self.ghost_ids.append(ids)
            per_body.append(by_body)
        self._owner = {gid: n for n, ids in enumerate(self.ghost_ids) for gid in ids}
        # Filters: ghosts ignore what they are told to, each other, and the
        # body pairs the robot's checker filters; a body no joint moves is
        # checked only against its own ghost's moving bodies (like the real
        # robot's base, welded to the world).
        fm = scene_graph.collision_filter_manager()
        allowed = {(int(a), int(b)) for a, b in arrays.self_pairs} | {(int(b), int(a)) for a, b in arrays.self_pairs}
        exclude = GeometrySet(list(exclude_ids))
        for n in range(self.count):
            mine = GeometrySet(list(self.ghost_ids[n]))
            decl = CollisionFilterDeclaration().ExcludeBetween(mine, exclude)
            others = [g for m in range(self.count) if m != n for g in self.ghost_ids[m]]
            if others:
                decl.ExcludeBetween(mine, GeometrySet(others))
            items = list(per_body[n].items())
            for i, (a, ga) in enumerate(items):
                for b, gb in items[i:]:
                    if a == b or (a, b) not in allowed:
                        decl.ExcludeBetween(GeometrySet(ga), GeometrySet(gb))
            fm.Apply(decl)
            fixed = [g for b, gs in per_body[n].items() if not moving[b] for g in gs]
            if fixed:
                fm.Apply(CollisionFilterDeclaration().ExcludeBetween(
                    GeometrySet(fixed), GeometrySet(self._non_ghost_ids(scene_graph, n))))
        self.configurations_input = self.DeclareVectorInputPort(name="configurations", size=self.count * self.k)
        self.query_object_input = self.DeclareAbstractInputPort(
            name="query_object", model_value=AbstractValue.Make(QueryObject()))
        self.geometry_pose_output = self.DeclareAbstractOutputPort(
            name="geometry_pose", alloc=lambda: AbstractValue.Make(FramePoseVector()), calc=self._calc_poses,
            prerequisites_of_calc={self.configurations_input.ticket()})
        self.free_output = self.DeclareVectorOutputPort(
            name="free", size=self.count, calc=self._calc_free,
            prerequisites_of_calc={self.query_object_input.ticket()})

    def _non_ghost_ids(self, scene_graph, n: int) -> list:
        inspector = scene_graph.model_inspector()
        return [g for g in inspector.GetAllGeometryIds() if g not in self.ghost_ids[n]
                and inspector.GetProximityProperties(g) is not None]

    def _calc_poses(self, context, output):
        Q = np.asarray(self.configurations_input.Eval(context), float).reshape(self.count, self.k)
        if not np.all(np.isfinite(Q)):
            raise ParameterError("GhostGuard: 'configurations' holds a non-finite value.")
        R, p = self._arrays.fk(Q)
        poses = output.get_mutable_value()
        poses.clear()
        for n, frames in enumerate(self._frames):
            for b, fid in frames:
                poses.set_value(fid, RigidTransform(RotationMatrix(R[n, b]), p[n, b]))

    def _calc_free(self, context, output):
        output.SetFromVector(self.free_flags(context).astype(float))

    def free_flags(self, context) -> np.ndarray:
        """(count,) True for each ghost that penetrates nothing."""
        query = self.query_object_input.Eval(context)
        free = np.ones(self.count, bool)
        for pp in query.ComputePointPairPenetration():
            for gid in (pp.id_A, pp.id_B):
                n = self._owner.get(gid)
                if n is not None:
                    free[n] = False
        return free
