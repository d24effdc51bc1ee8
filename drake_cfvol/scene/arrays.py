"""The robot and its obstacles as plain arrays for the compiled kernel
(:mod:`drake_cfvol.kernel`), read from Drake once per workcell.

- The kinematic chain: every body of the robot in topological order, its
  parent, its inboard joint (type, axis, position index) and the fixed poses
  around the joint, so that ``kernel.fk`` reproduces Drake's X_WB.
- The shapes: each proximity geometry as an exact convex shape (box,
  sphere, capsule, cylinder, ellipsoid) or, for a mesh or convex shape, its
  convex hull (what Drake uses for a mesh in point-pair queries). Nothing is
  approximated, so no excess needs reporting.
- Axis-aligned boxes of the obstacles, the self-collision pairs Drake does
  not filter, which joints move which bodies, and a bound on how far
  any point of a body can be from each joint's axis (``reach``), the same at
  every configuration.
"""

from __future__ import annotations

import dataclasses
import hashlib

import numba
import numpy as np
from pydrake.geometry import Role
from pydrake.multibody.tree import JointIndex

from drake_cfvol import kernel as K
from drake_cfvol.exceptions import WorkcellError
from drake_cfvol.kernel import kinds
from drake_cfvol.scene.covers import robot_covers
from drake_cfvol.scene.robot import robot_bodies

__all__ = [
    "SceneArrays",
    "cell_fingerprint",
    "chain_curvature",
    "chain_reach",
    "fingerprint_differences",
    "fingerprint_problem",
    "moved_by",
    "robot_chain",
    "scene_arrays",
    "shape_row",
]


def shape_row(shape, R_BG: np.ndarray, p_BG: np.ndarray, verts: list) -> tuple[np.ndarray, float, np.ndarray]:
    """A Drake shape posed at X_BG as a kernel shape row (its kind's
    :class:`~drake_cfvol.kernel.kinds.ShapeKind` reads it).

    Args:
        shape: the Drake shape.
        R_BG, p_BG: its pose in the body (or world) frame.
        verts: the list of vertex arrays so far; a hull appends to it.

    Returns:
        (row (SHAPE_W,), bounding radius about the returned centre, centre in B)

    Raises:
        WorkcellError: an unsupported shape, or a mesh without a proper hull.
    """
    g = kinds.geometry(shape)
    assert g is not None  # strict: an unsupported shape raised
    row = np.zeros(K.SHAPE_W)
    R = np.asarray(R_BG, float)
    c = np.asarray(p_BG, float) + R @ g.centre
    if len(g.verts):
        start = sum(len(x) for x in verts)
        verts.append(g.verts)
        row[K.ROW_FIRST_VERTEX], row[K.ROW_END_VERTEX] = start, start + len(g.verts)
    row[K.ROW_KIND] = g.kind.code
    row[K.ROW_CENTRE : K.ROW_CENTRE + 3] = c
    row[K.ROW_ROTATION : K.ROW_ROTATION + 9] = R.ravel()
    row[K.ROW_SIZE : K.ROW_SIZE + 3] = g.sizes
    return row, g.kind.radius(g.sizes, g.verts), c


#: Batches up to this size are checked on the calling thread: waking numba's
#: thread pool costs more than checking them one by one.
_SERIAL_MAX = 256


@dataclasses.dataclass
class SceneArrays:
    """Everything the kernel needs about a workcell.

    Attributes:
        body_names, body_indices: the robot's bodies (B), topological order.
        parent (B,): parent body index, -1 for a body fixed to the world.
        jtype (B,): 0 fixed, 1 revolute, 2 prismatic (the inboard joint).
        qidx (B,): the joint's position index (0 for fixed joints).
        axis (B, 3): the joint's unit axis in its frames.
        R_PF, p_PF (B, 3, 3), (B, 3): joint frame F in the parent body (the
            parent's world pose folded in for a parent outside the chain).
        R_MB, p_MB: the body in the joint's child frame M.
        shapes (S, SHAPE_W): robot shapes in their body's frame.
        shape_body (S,): their body.
        obstacles (O, SHAPE_W): obstacle shapes in the world.
        obstacle_names (O,): the obstacle each belongs to.
        obstacle_aabb (O, 6): their axis-aligned boxes [min xyz, max xyz].
        verts (V, 3): hull vertices (shape frames) of every hull.
        self_pairs (P, 2): robot body pairs that Drake does not filter.
        moved_by (k, B): True where joint j moves body b.
        reach (k, B): bound on the distance from joint j's axis point to any
            point of body b, at every configuration, m (0 if not moved).
        curvature (k, k, B): bound on |d^2 p / dq_k dq_l| for any point p of
            body b at any configuration, m (see :func:`chain_curvature`).
        revolute (k,): joint types.
        joint_body (k,): the body whose inboard joint each joint is.
    """

    body_names: list
    body_indices: list
    parent: np.ndarray
    jtype: np.ndarray
    qidx: np.ndarray
    axis: np.ndarray
    R_PF: np.ndarray
    p_PF: np.ndarray
    R_MB: np.ndarray
    p_MB: np.ndarray
    shapes: np.ndarray
    shape_body: np.ndarray
    obstacles: np.ndarray
    obstacle_names: list
    obstacle_aabb: np.ndarray
    verts: np.ndarray
    self_pairs: np.ndarray
    moved_by: np.ndarray
    reach: np.ndarray
    curvature: np.ndarray
    revolute: np.ndarray
    joint_body: np.ndarray

    def __post_init__(self):
        kinds.check_rows(self.shapes, self.verts, "robot shape")
        kinds.check_rows(self.obstacles, self.verts, "obstacle shape")
        self._model = None  # the kernel's Model, built once
        self._covers = None
        self._blocks = None

    @property
    def covers(self) -> tuple[np.ndarray, np.ndarray]:
        """The robot shapes' outer sphere covers, checked when built
        (:func:`drake_cfvol.scene.covers.robot_covers`): (balls (N, 4) in
        body frames, shape_spheres (S, 2) row ranges)."""
        if self._covers is None:
            self._covers = robot_covers(self.shapes, self.verts)
        return self._covers

    @property
    def num_bodies(self) -> int:
        return len(self.body_names)

    def fk(self, Q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Body poses (N, B, 3, 3), (N, B, 3) for configurations (N, k)."""
        Q = np.require(np.atleast_2d(Q), np.float64, ("C", "W"))  # read-only: another signature to numba
        return K.fk_blocks(Q, self.chain, self.blocks.KR, self.blocks.Kp)

    def may_collide(self, Q: np.ndarray, pad: float = 0.0) -> np.ndarray:
        """(N,) True where a configuration may collide with the obstacles or
        itself, or come nearer to them than ``pad`` (m); False is certified
        free (the kernel is conservative)."""
        Q = np.require(np.atleast_2d(Q), np.float64, ("C", "W"))  # read-only: another signature to numba
        # A few configurations (a guard's checks): on this thread, since
        # waking numba's thread pool costs milliseconds.
        if len(Q) <= _SERIAL_MAX:
            return K.configs_may_collide_serial(Q, self.model, self.blocks, float(pad))
        # About two tasks per thread, each with its own scratch; in an order
        # whose blocks are coherent (K.coherent_order): a block of neighbours
        # clears most obstacles at once, so the check is faster. Answers do
        # not depend on the order.
        tasks = 2 * numba.get_num_threads()
        per = max(4, -(-len(Q) // (K.NB * tasks)))
        order = K.coherent_order(Q, K.COHERENT_DIMS, K.COHERENT_BITS)
        return K.configs_may_collide(Q, order, self.model, self.blocks, float(pad), per)

    def with_boxes(self, centres: np.ndarray, sizes: np.ndarray, name: str = "perceived") -> "SceneArrays":
        """These arrays with axis-aligned boxes added to the obstacles (the
        robot and its own obstacles unchanged).

        Args:
            centres, sizes: (N, 3) box centres and full side lengths in the
                world, m.
            name: the obstacle name the boxes take.
        """
        centres = np.asarray(centres, float).reshape(-1, 3)
        sizes = np.asarray(sizes, float).reshape(-1, 3)
        rows = np.zeros((len(centres), K.SHAPE_W))
        rows[:, K.ROW_KIND] = K.BOX
        rows[:, K.ROW_CENTRE : K.ROW_CENTRE + 3] = centres
        rows[:, K.ROW_ROTATION : K.ROW_ROTATION + 9] = np.eye(3).ravel()
        rows[:, K.ROW_SIZE : K.ROW_SIZE + 3] = sizes / 2
        aabb = np.concatenate([centres - sizes / 2, centres + sizes / 2], axis=1)
        out = dataclasses.replace(
            self,
            obstacles=np.ascontiguousarray(np.concatenate([self.obstacles, rows])),
            obstacle_names=list(self.obstacle_names) + [name] * len(rows),
            obstacle_aabb=np.ascontiguousarray(np.concatenate([self.obstacle_aabb, aabb])),
        )
        out._covers = self.covers  # the robot is the same: its covers made once, here
        out._blocks = self._blocks
        return out

    def robot_only(self) -> "SceneArrays":
        """These arrays without obstacles and without self pairs: the robot
        alone, sharing its covers (for tests against other obstacles only,
        added by :meth:`with_boxes`)."""
        out = dataclasses.replace(
            self,
            obstacles=np.zeros((0, K.SHAPE_W)),
            obstacle_names=[],
            obstacle_aabb=np.zeros((0, 6)),
            self_pairs=np.zeros((0, 2), np.int64),
        )
        out._covers = self.covers
        out._blocks = self._blocks
        return out

    @property
    def model(self) -> K.Model:
        """The kernel's typed view of these arrays (built once)."""
        if self._model is None:
            spheres, shape_spheres = self.covers
            self._model = K.Model(
                self.chain,
                self.shapes,
                self.shape_body,
                self.verts,
                self.obstacles,
                self.obstacle_aabb,
                self.self_pairs,
                self.shape_pairs,
                np.asarray(self.moved_by.any(axis=0)),  # numpy's stub: any() may give a scalar
                self.moved_by,
                self.reach,
                self.curvature,
                self.revolute,
                self.joint_body,
                spheres,
                shape_spheres,
            )
        return self._model

    @property
    def blocks(self) -> K.Blocks:
        """What the block kernel adds to :attr:`model` (built once): the
        chain's affine terms, the block check's covers (a capsule's balls
        along its segment, :func:`~drake_cfvol.scene.covers.robot_covers`
        with ``tight``) and their bounding balls, and each shape's closed-form
        kind."""
        if self._blocks is None:
            balls, ranges = robot_covers(self.shapes, self.verts, tight=True)
            KR, Kp = K.block_chain(self.chain)
            kind = np.array([int(k) if int(k) in K.EXACT_KINDS else -1 for k in self.shapes[:, K.ROW_KIND]], np.int64)
            self._blocks = K.Blocks(KR, Kp, balls, ranges, K.shape_bounds(balls, ranges), kind)
        return self._blocks

    @property
    def shape_pairs(self) -> np.ndarray:
        """(P, 2) robot shape pairs of the body pairs Drake does not filter."""
        body_pairs = {(int(a), int(b)) for a, b in self.self_pairs}
        S = len(self.shapes)
        pairs = [
            (a, b)
            for a in range(S)
            for b in range(a + 1, S)
            if (int(self.shape_body[a]), int(self.shape_body[b])) in body_pairs
            or (int(self.shape_body[b]), int(self.shape_body[a])) in body_pairs
        ]
        return np.array(pairs, np.int64).reshape(-1, 2)

    @property
    def chain(self) -> K.Chain:
        """The kinematic chain (:class:`drake_cfvol.kernel.Chain`)."""
        return K.Chain(self.parent, self.jtype, self.qidx, self.axis, self.R_PF, self.p_PF, self.R_MB, self.p_MB)


def _pose(X) -> tuple[np.ndarray, np.ndarray]:
    return X.rotation().matrix().copy(), X.translation().copy()


def robot_chain(plant, robot, robot_slice) -> tuple[list, K.Chain, np.ndarray]:
    """The robot's kinematic chain for the kernel's forward kinematics
    (:func:`~drake_cfvol.kernel.kinematics.fk_into`), every degree of
    freedom but the robot's held where ``robot_slice`` holds it.

    Args:
        plant: a finalized MultibodyPlant.
        robot: the robot's model instance.
        robot_slice: its :class:`~drake_cfvol.scene.robot.RobotSlice`.

    Returns:
        (order, chain, joint_body): the robot's bodies in the chain's order
        (parents first), the :class:`~drake_cfvol.kernel.Chain`, and each of
        the k joints' index in that order.
    """
    order, inboard = _chain_order(plant, robot)
    chain, joint_body = _chain_arrays(plant, robot, robot_slice, order, inboard)
    return order, K.Chain(*chain), joint_body


def _chain_order(plant, robot):
    """The robot's bodies in topological order (parents before children)
    and each body's inboard joint (by body index)."""
    mine = robot_bodies(plant, robot)
    robot_set = {int(b) for b in mine}
    robot_bodies_ = [plant.get_body(b) for b in mine]
    inboard = {}
    for i in range(plant.num_joints()):
        joint = plant.get_joint(JointIndex(i))
        inboard[int(joint.child_body().index())] = joint
    order, placed = [], set()
    pending = list(robot_bodies_)
    while pending:
        progressed = False
        for body in list(pending):
            joint = inboard.get(int(body.index()))
            if joint is None:
                raise WorkcellError(
                    f"robot body '{body.name()}' has no inboard joint (a floating base?); weld the robot's "
                    "base to the world with add_weld."
                )
            par = joint.parent_body()
            if int(par.index()) not in robot_set or int(par.index()) in placed:
                order.append(body)
                placed.add(int(body.index()))
                pending.remove(body)
                progressed = True
        if not progressed:
            raise WorkcellError("the robot's kinematic tree has a loop; only trees are supported.")
    return order, inboard


def _chain_arrays(plant, robot, robot_slice, order, inboard):
    """The chain in ``kernel.fk`` order (parent, jtype, qidx, axis, R_PF,
    p_PF, R_MB, p_MB; a parent outside the robot folded into X_PF, a weld's
    X_FM folded too) and each joint's body (joint_body)."""
    ctx = plant.CreateDefaultContext()
    plant.SetPositions(ctx, robot_slice.q_default)  # held degrees of freedom where the slice holds them
    robot_slice.set_positions(ctx, np.zeros(robot_slice.k))
    index_of = {int(b.index()): n for n, b in enumerate(order)}
    B = len(order)
    parent = np.full(B, -1, np.int64)
    jtype = np.zeros(B, np.int64)
    qidx = np.zeros(B, np.int64)
    axis = np.zeros((B, 3))
    R_PF, p_PF = np.zeros((B, 3, 3)), np.zeros((B, 3))
    R_MB, p_MB = np.zeros((B, 3, 3)), np.zeros((B, 3))
    joint_names = list(robot_slice.joint_names)
    joint_body = np.full(len(joint_names), -1, np.int64)
    for n, body in enumerate(order):
        joint = inboard[int(body.index())]
        X_PF = joint.frame_on_parent().GetFixedPoseInBodyFrame()
        X_BM = joint.frame_on_child().GetFixedPoseInBodyFrame()
        par = joint.parent_body()
        if int(par.index()) in index_of:
            parent[n] = index_of[int(par.index())]
        else:
            X_PF = par.EvalPoseInWorld(ctx) @ X_PF  # fixed: only the robot moves
        if joint.num_positions() == 0 or joint.name() not in joint_names or joint.model_instance() != robot:
            # Fold the weld's (or a held joint's, e.g. a gripper finger's) fixed X_FM into X_PF.
            X_FM = joint.frame_on_child().CalcPose(ctx, joint.frame_on_parent())
            X_PF = X_PF @ X_FM
        else:
            kind = joint.type_name()
            if kind not in ("revolute", "prismatic"):
                raise WorkcellError(
                    f"joint '{joint.name()}' is a {kind} joint; the robot's joints must be revolute or "
                    "prismatic (weld or hold the others)."
                )
            jtype[n] = {"revolute": 1, "prismatic": 2}[kind]
            qidx[n] = joint_names.index(joint.name())  # the robot's own position order
            ax = joint.revolute_axis() if kind == "revolute" else joint.translation_axis()
            axis[n] = np.asarray(ax, float) / np.linalg.norm(ax)
            joint_body[joint_names.index(joint.name())] = n
        R_PF[n], p_PF[n] = _pose(X_PF)
        R_MB[n], p_MB[n] = _pose(X_BM.inverse())
    return (parent, jtype, qidx, axis, R_PF, p_PF, R_MB, p_MB), joint_body


def _robot_shapes(workcell, order, verts):
    """The robot's proximity shapes as kernel rows (hull vertices appended
    to ``verts``): rows, their bodies, bounding-ball centres and radii."""
    workcell.require_collision_geometry("the bounds")
    plant, inspector = workcell.plant, workcell.scene_graph.model_inspector()
    rows, bodies, bcs, brs = [], [], [], []
    for n, body in enumerate(order):
        fid = plant.GetBodyFrameIdIfExists(body.index())
        if fid is None:
            continue
        for gid in inspector.GetGeometries(fid, Role.kProximity):
            X_BG = inspector.GetPoseInFrame(gid)
            row, radius, centre = shape_row(inspector.GetShape(gid), *_pose(X_BG), verts)
            rows.append(row)
            bodies.append(n)
            bcs.append(centre)
            brs.append(radius)
    return np.array(rows), np.array(bodies, np.int64), np.array(bcs), np.array(brs)


def _obstacle_shapes(workcell, verts):
    """The obstacles' shapes as kernel rows, posed in the world, and their names."""
    inspector = workcell.scene_graph.model_inspector()
    obs_rows, obs_names = [], []
    sg_ctx = workcell.scene_graph.GetMyContextFromRoot(workcell.context)
    query = workcell.scene_graph.get_query_output_port().Eval(sg_ctx)
    for obs in workcell.obstacles.values():
        for gid in obs.geometry_ids:
            obs_rows.append(shape_row(inspector.GetShape(gid), *_pose(query.GetPoseInWorld(gid)), verts)[0])
            obs_names.append(obs.name)
    return np.array(obs_rows).reshape(-1, K.SHAPE_W), obs_names


def moved_by(parent, joint_body, B) -> np.ndarray:
    """(k, B): True where joint j moves body b (b at or below the joint's body)."""
    moved = np.zeros((len(joint_body), B), bool)
    for j, b in enumerate(joint_body):
        stack = [b]
        while stack:
            x = stack.pop()
            moved[j, x] = True
            stack.extend(np.flatnonzero(parent == x).tolist())
    return moved


def scene_arrays(workcell) -> SceneArrays:
    """Reads the workcell's robot chain, robot shapes and obstacle shapes
    from Drake (``Workcell.scene_arrays`` caches the result)."""
    order, chain, joint_body = robot_chain(workcell.plant, workcell.robot, workcell.slice)
    parent, jtype, qidx, axis, R_PF, p_PF, R_MB, p_MB = chain
    B = len(order)
    verts: list[np.ndarray] = []
    shapes, shape_body, shape_bc, shape_br = _robot_shapes(workcell, order, verts)
    obstacles, obs_names = _obstacle_shapes(workcell, verts)
    checker = workcell.checker
    has_geometry = [bool((shape_body == b).any()) for b in range(B)]
    pairs = [
        (a, b)
        for a in range(B)
        for b in range(a + 1, B)
        if has_geometry[a] and has_geometry[b] and not checker.IsCollisionFilteredBetween(order[a], order[b])
    ]
    moved = moved_by(parent, joint_body, B)
    all_verts = np.concatenate(verts) if verts else np.zeros((0, 3))
    obs_aabb = np.zeros((len(obstacles), 6))
    for o in range(len(obstacles)):
        K.row_aabb(obstacles[o], all_verts, obs_aabb[o])
    reach = _reach(
        parent,
        jtype,
        axis,
        p_PF,
        R_MB,
        p_MB,
        shape_body,
        shape_bc,
        shape_br,
        joint_body,
        moved,
        workcell.position_lower,
        workcell.position_upper,
        qidx,
    )
    revolute = np.asarray(workcell.revolute, bool)
    return SceneArrays(
        [b.name() for b in order],
        [b.index() for b in order],
        *chain,
        shapes,
        shape_body,
        obstacles,
        obs_names,
        obs_aabb,
        all_verts,
        np.array(pairs, np.int64).reshape(-1, 2),
        moved,
        reach,
        chain_curvature(reach, moved, revolute),
        revolute,
        joint_body,
    )


def _reach(
    parent, jtype, axis, p_PF, R_MB, p_MB, shape_body, shape_bc, shape_br, joint_body, moved, lower, upper, qidx
) -> np.ndarray:
    """reach[j, b] (:func:`chain_reach`) with each body's own extent from its
    shapes (centres ``shape_bc`` and radii ``shape_br`` in the body frame)."""
    B = len(parent)
    own = np.zeros(B)  # max |p - anchor_b| over body b's shapes
    for b in range(B):
        sel = shape_body == b
        if sel.any():
            anchor = -R_MB[b].T @ p_MB[b]  # M origin in body b's frame
            own[b] = (np.linalg.norm(shape_bc[sel] - anchor, axis=1) + shape_br[sel]).max()
    return chain_reach((parent, jtype, qidx, axis, p_PF, R_MB, p_MB), joint_body, moved, own, lower, upper)


def chain_reach(chain, joint_body, moved, own, lower, upper) -> np.ndarray:
    """reach[j, b] (k, B): a configuration-independent bound on |p - c_j| for
    any point p of body b, c_j the origin of joint j's child frame M (on its
    axis); 0 where joint j does not move body b. Triangle inequality along
    the chain: the distance between consecutive joint origins is fixed in
    the body between them (plus the travel of a prismatic joint, within its
    position limits ``lower``, ``upper`` (by position index)), and each
    body's points lie within ``own[b]`` of its own joint origin.

    Args:
        chain: (parent, jtype, qidx, axis, p_PF, R_MB, p_MB) of a
            :class:`~drake_cfvol.kernel.Chain` (or the chain itself).
        joint_body: (k,) each joint's body in the chain.
        moved: (k, B) bools, joint j moves body b.
        own: (B,) per body, the largest distance of its points from its
            joint frame's origin M.
    """
    if isinstance(chain, K.Chain):
        chain = (chain.parent, chain.jtype, chain.qidx, chain.axis, chain.p_PF, chain.R_MB, chain.p_MB)
    parent, jtype, qidx, _, p_PF, R_MB, p_MB = chain
    B = len(parent)
    anchor = np.array([-R_MB[b].T @ p_MB[b] for b in range(B)]).reshape(B, 3)  # M origin in body b's frame
    step = np.zeros(B)  # |anchor_b - anchor_parent| bound, in the parent's frame
    for b in range(B):
        par = parent[b]
        if par < 0:
            continue
        step[b] = np.linalg.norm(p_PF[b] - anchor[par])
        if jtype[b] == 2:
            q = qidx[b]
            travel = max(abs(lower[q]), abs(upper[q]))
            step[b] += travel if np.isfinite(travel) else np.inf
    k = len(joint_body)
    reach = np.zeros((k, B))
    for j in range(k):
        for b in np.flatnonzero(moved[j]).tolist():
            total, x = own[b], b
            while x != joint_body[j]:
                total += step[x]
                x = parent[x]
            reach[j, b] = total
    return reach


def chain_curvature(reach: np.ndarray, moved: np.ndarray, revolute: np.ndarray) -> np.ndarray:
    """curvature[k, l, b] >= |d^2 p / dq_k dq_l| for every point p of body b.

    With c_l, u_l joint l's axis point and direction, for joint k upstream of
    l (both revolute): d/dq_k (u_l x (p - c_l)) = (u_k x u_l) x (p - c_l) +
    u_l x (u_k x (p - c_l)), at most 2 |p - c_l|; for k = l, |p - c_k|. A
    revolute and a prismatic joint: at most 1 (the prismatic axis turns
    with the revolute joint upstream of it; a translation turns nothing). Two
    prismatic joints: 0.
    """
    k, B = reach.shape
    out = np.zeros((k, k, B))
    for a in range(k):
        for c in range(k):
            both = moved[a] & moved[c]
            if revolute[a] and revolute[c]:
                val = reach[a] if a == c else 2.0 * np.maximum(reach[a], reach[c])
            elif revolute[a] or revolute[c]:
                val = np.ones(B)
            else:
                val = np.zeros(B)
            out[a, c] = np.where(both, val, 0.0)
    return out


#: The version of :func:`cell_fingerprint`'s record (a saved file's
#: fingerprint of another version is not compared).
FINGERPRINT_VERSION = 1


def _digest(*arrays) -> str:
    """A short hash of arrays' values, rounded to 1e-9 (a cell loaded twice
    gives the same values; -0.0 and 0.0 count as one)."""
    h = hashlib.sha256()
    for a in arrays:
        a = np.round(np.asarray(a, float), 9) + 0.0
        h.update(str(a.shape).encode())
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()[:16]


def _rows_digest(rows: np.ndarray, verts: np.ndarray) -> str:
    """The hash of shape rows with their hull vertices (not the vertices'
    place in the scene's array, which another shape may shift)."""
    parts = []
    for row in rows:
        r = row.copy()
        v0, v1 = int(r[K.ROW_FIRST_VERTEX]), int(r[K.ROW_END_VERTEX])
        r[K.ROW_FIRST_VERTEX] = r[K.ROW_END_VERTEX] = 0.0
        parts += [r, verts[v0:v1] if v1 > v0 else np.zeros((0, 3))]
    return _digest(*parts)


def cell_fingerprint(workcell) -> dict:
    """What a path or a table made in this cell depends on, for checking it
    against the cell it meets later: the robot (its chain and shapes), its
    joints and limits, and each obstacle's shapes and poses (a hash and its
    bounding box, so that a difference can be named).

    Returns:
        A JSON-ready dict (:func:`fingerprint_differences` compares two).
    """
    A = workcell.scene_arrays()
    names = list(dict.fromkeys(A.obstacle_names))
    obstacles = {}
    for name in names:
        idx = [i for i, n in enumerate(A.obstacle_names) if n == name]
        box = A.obstacle_aabb[idx]
        obstacles[name] = {
            "sha": _rows_digest(A.obstacles[idx], A.verts),
            "box": np.round(np.concatenate([box[:, :3].min(0), box[:, 3:].max(0)]), 6).tolist(),
        }
    finite = [
        [float(x) if np.isfinite(x) else None for x in v] for v in (workcell.position_lower, workcell.position_upper)
    ]
    return {
        "version": FINGERPRINT_VERSION,
        "robot": workcell.robot_name,
        "robot_sha": _digest(A.parent, A.jtype, A.qidx, A.axis, A.R_PF, A.p_PF, A.R_MB, A.p_MB, A.shape_body)
        + _rows_digest(A.shapes, A.verts),
        "joints": list(workcell.joint_names),
        "limits": finite,
        "obstacles": obstacles,
    }


def _numbers(values, size: int, *, none: bool = False) -> bool:
    """A list of ``size`` numbers (or None where ``none``)."""
    return (
        isinstance(values, list)
        and len(values) == size
        and all((x is None and none) or (isinstance(x, (int, float)) and not isinstance(x, bool)) for x in values)
    )


def fingerprint_problem(saved) -> str | None:
    """What makes a saved fingerprint unreadable, as one phrase, or None:
    another version, or a field that is missing or not of the form
    :func:`cell_fingerprint` writes (a file edited by hand)."""
    if not isinstance(saved, dict):
        return f"is a {type(saved).__name__}, not a mapping"
    if saved.get("version") != FINGERPRINT_VERSION:
        return f"is of version {saved.get('version')!r} (this drake_cfvol reads version {FINGERPRINT_VERSION})"
    for key, kind in (("robot", str), ("robot_sha", str), ("joints", list), ("limits", list), ("obstacles", dict)):
        if not isinstance(saved.get(key), kind):
            return f"has no valid '{key}' (a {kind.__name__})"
    joints = saved["joints"]
    if not all(isinstance(j, str) for j in joints):
        return "has no valid 'joints' (their names)"
    if len(saved["limits"]) != 2 or not all(_numbers(side, len(joints), none=True) for side in saved["limits"]):
        return f"has no valid 'limits' (lower and upper, {len(joints)} numbers each)"
    for name, ob in saved["obstacles"].items():
        if not (isinstance(ob, dict) and isinstance(ob.get("sha"), str) and _numbers(ob.get("box"), 6)):
            return f"has no valid entry for obstacle '{name}' (its sha and box)"
    return None


def fingerprint_differences(saved: dict, current: dict) -> list[str]:
    """How the cell a file was made in (``saved``) differs from ``current``
    (both :func:`cell_fingerprint`), one phrase each; empty if the same."""
    if saved.get("version") != current["version"]:
        return []
    out = []
    if saved.get("robot") != current["robot"] or saved.get("robot_sha") != current["robot_sha"]:
        what = "another robot" if saved.get("robot") != current["robot"] else "the same robot with other geometry"
        out.append(f"it was made for {what} ('{saved.get('robot')}'; this cell has '{current['robot']}')")
    if saved.get("joints") != current["joints"]:
        out.append(f"it was made for joints {saved.get('joints')}, this cell has {current['joints']}")
    elif saved.get("limits") != current["limits"]:
        lo, hi = saved.get("limits") or [[], []]
        changed = [
            f"{j} [{lo[n]}, {hi[n]}] -> [{current['limits'][0][n]}, {current['limits'][1][n]}]"
            for n, j in enumerate(current["joints"])
            if n < len(lo) and (lo[n], hi[n]) != (current["limits"][0][n], current["limits"][1][n])
        ]
        out.append(f"the joint limits changed ({'; '.join(changed)})")
    old, new = saved.get("obstacles", {}), current["obstacles"]
    for name in new:
        if name not in old:
            out.append(f"obstacle '{name}' was added (its box {new[name]['box']})")
    for name in old:
        if name not in new:
            out.append(f"obstacle '{name}' was removed")
        elif old[name].get("sha") != new[name]["sha"]:
            a, b = np.asarray(old[name].get("box"), float), np.asarray(new[name]["box"], float)
            size_a, size_b = a[3:] - a[:3], b[3:] - b[:3]
            if a.shape == b.shape == (6,) and np.allclose(size_a, size_b, atol=1e-6):
                shift = np.round((b[:3] - a[:3]), 4)
                moved = f"moved (by {shift.tolist()} m)" if shift.any() else "turned or reshaped in place"
                out.append(f"obstacle '{name}' was {moved}")
            else:
                out.append(f"obstacle '{name}' was changed (its shape or pose)")
    return out
