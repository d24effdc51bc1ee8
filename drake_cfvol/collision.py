"""Fast, conservative collision checks for joint bounding.

The robot is covered by spheres (from its Drake proximity shapes). Three
tests, all vectorised over many configurations at once:

- against the volume V: :meth:`drake_cfvol.heightmap.Volume.sphere_hits`
  (a range-max over the column heights, O(1) per sphere at any R);
- against the obstacles: the robot's exact primitives (oriented boxes by a
  separating-axis test, balls by exact distance) against the obstacles'
  boxes, pruned by per-body bounding spheres;
- against the robot itself: primitive pairs of the body pairs Drake does
  not filter, pruned the same way.

Every test is conservative: the geometry tested contains the real geometry
(exactly so for boxes, within 12 % of a capsule's radius for capsules) and
motion between samples is covered by growing each body by how far it can
move ("inflation"). Drake's own checker (the reference backend,
:mod:`drake_cfvol.reference`) is the ground truth in the tests.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from pydrake.geometry import (
    Box,
    Capsule,
    Convex,
    Cylinder,
    Ellipsoid,
    Mesh,
    Role,
    Sphere,
)

from drake_cfvol.exceptions import WorkcellError

__all__ = ["shape_spheres", "shape_box", "RobotModel", "robot_model", "Obstacles", "workcell_obstacles",
           "sphere_obb_distance", "obb_overlap", "SceneTester"]


def _box_spheres(half: np.ndarray, tol: float, surface_only: bool = True):
    """Spheres covering a box of half extents ``half`` (centred, axis
    aligned) that stick out of it by at most ``tol``.

    The box is cut into a grid of cells; each cell gets its circumscribed
    sphere. Only cells touching the boundary are kept when ``surface_only``:
    a motion that starts free (every nominal is) must touch the surface
    first, and the sound sweep checks the whole motion.
    """
    half = np.asarray(half, float)
    n = np.ones(3, int)
    while True:
        cell = 2 * half / n
        r = 0.5 * np.linalg.norm(cell)
        over = r - cell / 2
        if over.max() <= tol:
            break
        n[np.argmax(cell)] += 1
    axes = [(-half[i] + cell[i] * (np.arange(n[i]) + 0.5)) for i in range(3)]
    idx = np.stack(np.meshgrid(*[np.arange(v) for v in n], indexing="ij"), -1).reshape(-1, 3)
    if surface_only:
        edge = np.any((idx == 0) | (idx == n - 1), axis=1)
        idx = idx[edge]
    centres = np.stack([axes[i][idx[:, i]] for i in range(3)], axis=1)
    return centres, np.full(len(centres), r)


def _chain_spheres(r: float, length: float):
    """Spheres covering a capsule of radius r along z, |z| <= length / 2."""
    if length <= 1e-9:
        return np.zeros((1, 3)), np.array([r])
    count = int(np.ceil(length / r)) + 1
    z = np.linspace(-length / 2, length / 2, count)
    spacing = length / (count - 1)
    rr = np.sqrt(r * r + (spacing / 2) ** 2)
    return np.stack([np.zeros(count), np.zeros(count), z], axis=1), np.full(count, rr)


def _mesh_half_extents(shape):
    hull = shape.GetConvexHull()
    v = np.array([hull.vertex(i) for i in range(hull.num_vertices())])
    lo, hi = v.min(0), v.max(0)
    return (hi - lo) / 2, (hi + lo) / 2


def shape_box(shape) -> tuple[np.ndarray, np.ndarray]:
    """A box containing a Drake shape, in the shape's frame: (half extents,
    centre)."""
    if isinstance(shape, Box):
        return np.asarray(shape.size()) / 2, np.zeros(3)
    if isinstance(shape, Sphere):
        return np.full(3, shape.radius()), np.zeros(3)
    if isinstance(shape, Cylinder):
        return np.array([shape.radius(), shape.radius(), shape.length() / 2]), np.zeros(3)
    if isinstance(shape, Capsule):
        return np.array([shape.radius(), shape.radius(), shape.length() / 2 + shape.radius()]), np.zeros(3)
    if isinstance(shape, Ellipsoid):
        return np.array([shape.a(), shape.b(), shape.c()]), np.zeros(3)
    if isinstance(shape, (Mesh, Convex)):
        return _mesh_half_extents(shape)
    raise WorkcellError(
        f"shape {type(shape).__name__} is not supported by the fast backend; use boxes, spheres, "
        "cylinders, capsules, ellipsoids or meshes (or backend='drake').")


def shape_spheres(shape, tol: float) -> tuple[np.ndarray, np.ndarray]:
    """Spheres (centres in the shape's frame, radii) covering a Drake shape,
    sticking out by at most about ``tol`` (capsules: 12 % of their radius)."""
    if isinstance(shape, Sphere):
        return np.zeros((1, 3)), np.array([shape.radius()])
    if isinstance(shape, Capsule):
        return _chain_spheres(shape.radius(), shape.length())
    half, centre = shape_box(shape)
    c, r = _box_spheres(half, tol)
    return c + centre, r


@dataclasses.dataclass
class RobotModel:
    """The robot's geometry for the fast checks.

    Exact primitives: boxes (every box, cylinder, mesh... as its box) and
    balls (spheres, and capsules as chains of balls sticking out by 12 % of
    their radius at most). Cover spheres (boxes as grids of spheres, sticking
    out by at most ``tol``) for the test against the volume.

    Attributes:
        bodies, names: plant ``BodyIndex`` and name per robot body with
            geometry (B of them).
        box_body (Nb,), box_c (Nb, 3), box_R (Nb, 3, 3), box_half (Nb, 3):
            boxes in their body's frame.
        ball_body (Nl,), ball_c (Nl, 3), ball_r (Nl,): balls in body frames.
        cover_body (Nc,), cover_c (Nc, 3), cover_r (Nc,): cover spheres.
        bound_c (B, 3), bound_r (B,): a sphere containing each body.
        self_pairs: (P, 2) body pairs that Drake does not filter.
        moved_by: (k, B) True where joint j moves body b.
    """

    bodies: list
    names: list[str]
    box_body: np.ndarray
    box_c: np.ndarray
    box_R: np.ndarray
    box_half: np.ndarray
    ball_body: np.ndarray
    ball_c: np.ndarray
    ball_r: np.ndarray
    cover_body: np.ndarray
    cover_c: np.ndarray
    cover_r: np.ndarray
    bound_c: np.ndarray
    bound_r: np.ndarray
    self_pairs: np.ndarray
    moved_by: np.ndarray

    @property
    def num_bodies(self) -> int:
        return len(self.bodies)

    def body_poses(self, workcell, q) -> tuple[np.ndarray, np.ndarray]:
        """(R_WB (B, 3, 3), p_WB (B, 3)) at configuration q."""
        ctx = workcell.plant_context(q)
        plant = workcell.plant
        R = np.empty((len(self.bodies), 3, 3))
        p = np.empty((len(self.bodies), 3))
        for i, b in enumerate(self.bodies):
            X = plant.get_body(b).EvalPoseInWorld(ctx)
            R[i] = X.rotation().matrix()
            p[i] = X.translation()
        return R, p

    def batch_poses(self, workcell, Q) -> tuple[np.ndarray, np.ndarray]:
        """Body poses for many configurations: (N, B, 3, 3), (N, B, 3)."""
        Q = np.atleast_2d(Q)
        R = np.empty((len(Q), self.num_bodies, 3, 3))
        p = np.empty((len(Q), self.num_bodies, 3))
        for n, q in enumerate(Q):
            R[n], p[n] = self.body_poses(workcell, q)
        return R, p

    def cover_world(self, R, p) -> np.ndarray:
        """Cover-sphere centres in the world from body poses (..., B, ...)."""
        b = self.cover_body
        return np.einsum("...sij,sj->...si", R[..., b, :, :], self.cover_c) + p[..., b, :]


def robot_model(workcell, tol: float = 0.06) -> RobotModel:
    """Builds the robot's geometry model (``Workcell.robot_geometry`` caches it)."""
    plant = workcell.plant
    inspector = workcell.scene_graph.model_inspector()

    bodies, names = [], []
    boxes, balls, cover = [], [], []
    for bi in plant.GetBodyIndices(workcell.robot):
        fid = plant.GetBodyFrameIdIfExists(bi)
        gids = inspector.GetGeometries(fid, Role.kProximity) if fid is not None else []
        if not gids:
            continue
        b = len(bodies)
        bodies.append(bi)
        names.append(plant.get_body(bi).name())
        for gid in gids:
            X_BG = inspector.GetPoseInFrame(gid)
            R_BG, p_BG = X_BG.rotation().matrix(), X_BG.translation()
            shape = inspector.GetShape(gid)
            c, r = shape_spheres(shape, tol)
            cover.append((np.full(len(r), b), c @ R_BG.T + p_BG, r))
            if isinstance(shape, (Sphere, Capsule)):
                balls.append((np.full(len(r), b), c @ R_BG.T + p_BG, r))
            else:
                half, centre = shape_box(shape)
                boxes.append((b, R_BG @ centre + p_BG, R_BG, half))

    def cat(items, i, shape):
        return np.concatenate([it[i] for it in items]) if items else np.zeros(shape)

    box_body = np.array([x[0] for x in boxes], int)
    box_c = np.array([x[1] for x in boxes]).reshape(-1, 3)
    box_R = np.array([x[2] for x in boxes]).reshape(-1, 3, 3)
    box_half = np.array([x[3] for x in boxes]).reshape(-1, 3)
    ball_body = cat(balls, 0, (0,)).astype(int)
    ball_c = cat(balls, 1, (0, 3))
    ball_r = cat(balls, 2, (0,))
    cover_body = cat(cover, 0, (0,)).astype(int)
    cover_c = cat(cover, 1, (0, 3))
    cover_r = cat(cover, 2, (0,))
    B = len(bodies)
    bound_c = np.zeros((B, 3))
    bound_r = np.zeros(B)
    for b in range(B):
        # Corners of the boxes and extremes of the balls of body b.
        pts, rad = [], []
        for i in np.flatnonzero(box_body == b):
            signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)])
            pts.append(box_c[i] + (signs * box_half[i]) @ box_R[i].T)
            rad.append(np.zeros(8))
        sel = ball_body == b
        pts.append(ball_c[sel])
        rad.append(ball_r[sel])
        pts, rad = np.concatenate(pts), np.concatenate(rad)
        lo, hi = (pts - rad[:, None]).min(0), (pts + rad[:, None]).max(0)
        bound_c[b] = (lo + hi) / 2
        bound_r[b] = (np.linalg.norm(pts - bound_c[b], axis=1) + rad).max() + 1e-9
    checker = workcell.checker
    pairs = [(a, b) for a in range(B) for b in range(a + 1, B)
             if not checker.IsCollisionFilteredBetween(plant.get_body(bodies[a]), plant.get_body(bodies[b]))]
    joints = [plant.GetJointByName(n, workcell.robot) for n in workcell.joint_names]
    moved = np.zeros((len(joints), B), bool)
    for j, joint in enumerate(joints):
        affected = set(int(x) for x in plant.GetBodiesKinematicallyAffectedBy([joint.index()]))
        moved[j] = [int(b) in affected for b in bodies]
    model = RobotModel(bodies, names, box_body, box_c, box_R, box_half, ball_body, ball_c, ball_r,
                       cover_body, cover_c, cover_r, bound_c, bound_r,
                       np.array(pairs, int).reshape(-1, 2), moved)
    return model


def sphere_obb_distance(p, r, c, R, half):
    """Distance between spheres and boxes (negative when overlapping; the
    box's interior counts as distance -r).

    Args:
        p: (..., 3) sphere centres; r: (...) radii.
        c: (..., 3) box centres; R: (..., 3, 3) box rotations (columns are
            the box axes in the world); half: (..., 3) half extents.
    """
    local = np.einsum("...ji,...j->...i", R, p - c)
    q = np.abs(local) - half
    outside = np.linalg.norm(np.maximum(q, 0.0), axis=-1)
    inside = np.minimum(q.max(axis=-1), 0.0)
    return outside + inside - r


def motion_support(L, e, u=None, prismatic=False):
    """How far a body can move along axis L (not necessarily unit) when each
    of its points moves by at most ``e``:

    - ``u`` None: any direction (a ball of radius e): e |L|;
    - revolute about unit axis ``u``: points move in the plane normal to u,
      e sqrt(|L|^2 - (L.u)^2);
    - prismatic along ``u``: e |L.u|.
    """
    e = np.asarray(e)
    if u is None:
        return e * np.linalg.norm(L, axis=-1)
    Lu = np.einsum("...i,...i->...", L, u)
    if prismatic:
        return e * np.abs(Lu)
    return e * np.sqrt(np.maximum(np.einsum("...i,...i->...", L, L) - Lu * Lu, 0.0))


def obb_overlap(cA, RA, hA, cB, RB, hB, e, u=None, prismatic=False) -> np.ndarray:
    """Separating-axis test of two oriented boxes where box A may be anywhere
    within its motion set (see :func:`motion_support`; ``e`` 0 for a fixed
    pose). Broadcasts over leading dimensions. True where none of the 15
    axes separates them: conservative, never misses an overlap.
    """
    LA = np.swapaxes(RA, -1, -2)  # rows: A's axes in the world
    LB = np.swapaxes(RB, -1, -2)
    LA, LB = np.broadcast_arrays(LA, LB)
    cross = np.cross(LA[..., :, None, :], LB[..., None, :, :]).reshape(LA.shape[:-2] + (9, 3))
    L = np.concatenate([LA, LB, cross], axis=-2)  # (..., 15, 3)
    radius = ((np.abs(L @ RA) @ np.asarray(hA)[..., None])[..., 0]
              + (np.abs(L @ RB) @ np.asarray(hB)[..., None])[..., 0])
    t = (cB - cA)[..., None, :]
    dist = np.abs((L @ np.swapaxes(t, -1, -2))[..., 0])
    ee = np.asarray(e)[..., None]
    uu = None if u is None else np.asarray(u)[..., None, :]
    sep = dist > radius + motion_support(L, ee, uu, prismatic) + 1e-12
    return ~sep.any(axis=-1)


def ball_box_overlap(pc, r, c, R, half, e, u=None, prismatic=False) -> np.ndarray:
    """Whether a ball may touch a box while one of them moves (motion set of
    :func:`motion_support` with size ``e``). Separating axes tried: the box's
    three axes and the direction from the box's closest point to the ball's
    centre. Conservative. Broadcasts over leading dimensions.

    Args:
        pc: (..., 3) ball centres; r: (...) radii.
        c, R, half: the box (centre, rotation, half extents).
        e: (...) motion size; u: (..., 3) motion axis or None. Either of the
            two may be the one moving: the test is symmetric.
    """
    d = pc - c
    local = np.einsum("...ji,...j->...i", R, d)
    sep = np.zeros(np.broadcast_shapes(local.shape[:-1], np.shape(r), np.shape(e)), bool)
    for i in range(3):
        L = R[..., :, i]
        sep |= np.abs(local[..., i]) > half[..., i] + r + motion_support(L, e, u, prismatic) + 1e-12
    closest_local = np.clip(local, -half, half)
    gap = local - closest_local
    dist = np.linalg.norm(gap, axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        n_local = gap / np.where(dist > 0, dist, 1.0)[..., None]
    n = np.einsum("...ij,...j->...i", R, n_local)
    sep |= (dist > 0) & (dist > r + motion_support(n, e, u, prismatic) + 1e-12)
    return ~sep


@dataclasses.dataclass
class Obstacles:
    """The workcell's obstacles as oriented boxes (exact for boxes; the
    bounding box of any other shape).

    Attributes:
        names: obstacle name per box.
        centre: (O, 3), R: (O, 3, 3), half: (O, 3).
    """

    names: list[str]
    centre: np.ndarray
    R: np.ndarray
    half: np.ndarray

    def sphere_distance(self, p, r):
        """(..., O) distances of spheres (p (..., 3), r (...)) to each box."""
        return sphere_obb_distance(p[..., None, :], np.asarray(r)[..., None], self.centre, self.R, self.half)


def workcell_obstacles(workcell) -> Obstacles:
    """The obstacles of a workcell as boxes (``Workcell.obstacle_boxes`` caches them)."""
    inspector = workcell.scene_graph.model_inspector()
    sg_ctx = workcell.scene_graph.GetMyContextFromRoot(workcell.context)
    query = workcell.scene_graph.get_query_output_port().Eval(sg_ctx)
    names, cs, Rs, hs = [], [], [], []
    for obs in workcell.obstacles.values():
        for gid in obs.geometry_ids:
            half, centre = shape_box(inspector.GetShape(gid))
            X = query.GetPoseInWorld(gid)
            R = X.rotation().matrix()
            names.append(obs.name)
            cs.append(X.translation() + R @ centre)
            Rs.append(R)
            hs.append(half)
    return Obstacles(names, np.array(cs), np.array(Rs), np.array(hs))


class SceneTester:
    """Batched conservative collision tests of robot poses.

    Args:
        model: the robot model.
        obstacles: the obstacles as boxes (None: no obstacle test).
        volume: the volume V (None: no volume test).
    """

    def __init__(self, model: RobotModel, obstacles: Obstacles | None, volume=None):
        self.model = model
        self.obstacles = obstacles
        self.volume = volume
        m = model
        self._boxes_of = [np.flatnonzero(m.box_body == b) for b in range(m.num_bodies)]
        self._balls_of = [np.flatnonzero(m.ball_body == b) for b in range(m.num_bodies)]
        self._cover_of = [np.flatnonzero(m.cover_body == b) for b in range(m.num_bodies)]
        #: Counters of primitive tests done (for the benchmark's floor).
        self.counts = {"batches": 0, "poses": 0}

    def hits(self, R, p, e, moving, pairs=None, *, axis=None, prismatic=False,
             env=True, self_collision=True, volume=True) -> np.ndarray:
        """Which poses may collide.

        Args:
            R: (N, B, 3, 3) body rotations in the world.
            p: (N, B, 3) body origins in the world, m.
            e: (N, B) inflation per body (how far any of its points may be
                from where these poses put it), m.
            moving: (B,) bool, the bodies to test against obstacles and V
                (bodies that stay put are not tested there).
            pairs: (P, 2) body pairs to test for self-collision (default: all
                unfiltered pairs).
            axis: (N, 3) unit axis of the motion behind ``e`` (see
                :func:`motion_support`), or None for any direction. With an
                axis, only the bodies in ``moving`` may have e > 0.
            prismatic: the motion is a translation along ``axis``.

        Returns:
            (N,) bool, True where a collision is possible.
        """
        N = R.shape[0]
        self.counts["batches"] += 1
        self.counts["poses"] += N
        hit = np.zeros(N, bool)
        m = self.model
        moving_bodies = np.flatnonzero(moving)
        self._axis, self._prismatic = axis, prismatic
        if env and self.obstacles is not None:
            for b in moving_bodies:
                hit |= self._env_body(R[:, b], p[:, b], e[:, b], b, ~hit)
        if volume and self.volume is not None and len(moving_bodies):
            hit |= self._volume(R, p, e, moving_bodies, ~hit, axis, prismatic)
        if self_collision:
            pairs = m.self_pairs if pairs is None else pairs
            if len(pairs):
                live = np.flatnonzero(~hit)
                if len(live):
                    bc = np.einsum("nbij,bj->nbi", R[live], m.bound_c) + p[live]
                    a_, b_ = pairs[:, 0], pairs[:, 1]
                    gap = np.linalg.norm(bc[:, a_] - bc[:, b_], axis=-1)
                    near = gap < m.bound_r[a_] + m.bound_r[b_] + e[live][:, a_] + e[live][:, b_]
                    for k in np.flatnonzero(near.any(axis=0)):
                        rows = live[near[:, k]]
                        rows = rows[~hit[rows]]
                        if len(rows):
                            hit[rows] |= self._pair(R[rows], p[rows], e[rows], pairs[k, 0], pairs[k, 1],
                                                    None if axis is None else axis[rows])
        return hit

    def _volume(self, R, p, e, moving_bodies, live_mask, axis, prismatic) -> np.ndarray:
        """Cover spheres against V, pruned per body by its bounding sphere."""
        m, vol = self.model, self.volume
        out = np.zeros(len(R), bool)
        live = np.flatnonzero(live_mask)
        if not len(live):
            return out

        def grow(ee, rows):
            if axis is None:
                return ee, ee
            uz = np.abs(axis[rows, 2])
            if ee.ndim == 2:
                uz = uz[:, None]
            side = np.sqrt(np.maximum(1 - uz * uz, 0))
            return (ee * side, ee * uz) if prismatic else (ee, ee * side)

        for b in moving_bodies:
            rows = live[~out[live]]
            if not len(rows):
                break
            bc = np.einsum("nij,j->ni", R[rows, b], m.bound_c[b]) + p[rows, b]
            exy, ez = grow(e[rows, b], rows)
            flagged = vol.sphere_hits(bc, m.bound_r[b], exy, ez)
            rows = rows[flagged]
            idx = self._cover_of[b]
            if not len(rows) or not len(idx):
                continue
            c = np.einsum("nij,sj->nsi", R[rows, b], m.cover_c[idx]) + p[rows, b][:, None]
            exy, ez = grow(e[rows, b][:, None], rows)
            out[rows] |= vol.sphere_hits(c, m.cover_r[idx], exy, ez).any(axis=1)
        return out

    def _env_body(self, Rb, pb, eb, b, live_mask) -> np.ndarray:
        m, obs = self.model, self.obstacles
        out = np.zeros(len(Rb), bool)
        live = np.flatnonzero(live_mask)
        if not len(live):
            return out
        c = np.einsum("nij,j->ni", Rb[live], m.bound_c[b]) + pb[live]
        near = obs.sphere_distance(c, m.bound_r[b] + eb[live]) < 0  # (n, O)
        rows = np.flatnonzero(near.any(axis=1))
        if not len(rows):
            return out
        n_idx = live[rows]
        near = near[rows]
        Rn, pn, en = Rb[n_idx], pb[n_idx], eb[n_idx]
        un = None if self._axis is None else self._axis[n_idx][:, None]
        res = np.zeros(len(n_idx), bool)
        for i in self._boxes_of[b]:
            cw = np.einsum("nij,j->ni", Rn, m.box_c[i]) + pn
            Rw = Rn @ m.box_R[i]
            ov = obb_overlap(cw[:, None], Rw[:, None], m.box_half[i], obs.centre[None], obs.R[None],
                             obs.half[None], en[:, None], un, self._prismatic)
            res |= (ov & near).any(axis=1)
        balls = self._balls_of[b]
        if len(balls):
            cw = np.einsum("nij,sj->nsi", Rn, m.ball_c[balls]) + pn[:, None]  # (n, s, 3)
            uu = None if un is None else un[:, None]
            ov = ball_box_overlap(cw[:, :, None], m.ball_r[balls][None, :, None], obs.centre[None, None],
                                  obs.R[None, None], obs.half[None, None], en[:, None, None], uu,
                                  self._prismatic)  # (n, s, O)
            res |= (ov & near[:, None, :]).any(axis=(1, 2))
        out[n_idx] = res
        return out

    def _pair(self, R, p, e, a, b, u=None) -> np.ndarray:
        m = self.model
        ca = np.einsum("nij,j->ni", R[:, a], m.bound_c[a]) + p[:, a]
        cb = np.einsum("nij,j->ni", R[:, b], m.bound_c[b]) + p[:, b]
        margin = e[:, a] + e[:, b]
        near = np.linalg.norm(ca - cb, axis=1) < m.bound_r[a] + m.bound_r[b] + margin
        out = np.zeros(len(R), bool)
        rows = np.flatnonzero(near)
        if not len(rows):
            return out
        R, p, margin = R[rows], p[rows], margin[rows]
        u = None if u is None else u[rows]
        res = np.zeros(len(rows), bool)

        def boxes(body):
            out = []
            for i in self._boxes_of[body]:
                out.append((np.einsum("nij,j->ni", R[:, body], m.box_c[i]) + p[:, body],
                            R[:, body] @ m.box_R[i], m.box_half[i]))
            return out

        def balls(body):
            idx = self._balls_of[body]
            if not len(idx):
                return None
            return np.einsum("nij,sj->nsi", R[:, body], m.ball_c[idx]) + p[:, body][:, None], m.ball_r[idx]

        bx_a, bx_b, bl_a, bl_b = boxes(a), boxes(b), balls(a), balls(b)
        prism = self._prismatic
        u3 = None if u is None else u[:, None]
        for ca_, Ra_, ha_ in bx_a:
            for cb_, Rb_, hb_ in bx_b:
                res |= obb_overlap(ca_, Ra_, ha_, cb_, Rb_, hb_, margin, u, prism)
            if bl_b is not None:
                res |= ball_box_overlap(bl_b[0], bl_b[1][None], ca_[:, None], Ra_[:, None], ha_,
                                        margin[:, None], u3, prism).any(axis=1)
        if bl_a is not None:
            for cb_, Rb_, hb_ in bx_b:
                res |= ball_box_overlap(bl_a[0], bl_a[1][None], cb_[:, None], Rb_[:, None], hb_,
                                        margin[:, None], u3, prism).any(axis=1)
            if bl_b is not None:
                diff = bl_a[0][:, :, None] - bl_b[0][:, None, :]  # (n, sa, sb, 3)
                dist = np.linalg.norm(diff, axis=-1)
                with np.errstate(invalid="ignore", divide="ignore"):
                    nrm = diff / np.where(dist > 0, dist, 1.0)[..., None]
                uu = None if u is None else u[:, None, None]
                sup = motion_support(nrm, margin[:, None, None], uu, prism)
                res |= (dist <= bl_a[1][:, None] + bl_b[1][None, :] + sup).any(axis=(1, 2))
        out[rows] = res
        return out
