"""Parts of the velocity damper (:class:`~drake_cfvol.systems.filter.damper.VelocityDamper`):
its broad phase (:class:`BroadPhase`), the pair sides' arrays for the
compiled rows (:func:`side_arrays`) and the rows of a pair assembled from
Drake's own point queries (:func:`drake_pair_rows`, for a probe against a
moving ellipsoid, which the compiled rows do not measure).
"""

from __future__ import annotations

import numpy as np

from drake_cfvol.systems.filter.damper_kernel import NO_POINT_QUERY, local_box, near_pairs, point_query_shape

__all__ = ["BroadPhase", "RowList", "convex_arrays", "side_arrays", "drake_pair_rows"]


class RowList:
    """The damper's rows as they are found: direction, the two points
    (world), their bodies' slots (-1: welded), right-hand side, pair and the
    round radii; :meth:`build` makes the rows, A from all of them at
    once."""

    def __init__(self):
        self.parts = []

    def add(self, dirs, p1, p2, s1, s2, rhs, pair, r1, r2) -> None:
        m = len(dirs)
        self.parts.append(
            (
                np.asarray(dirs, float),
                np.asarray(p1, float),
                np.asarray(p2, float),
                np.full(m, s1),
                np.full(m, s2),
                np.broadcast_to(np.asarray(rhs, float), (m,)),
                np.full(m, pair),
                np.full(m, float(r1)),
                np.full(m, float(r2)),
            )
        )

    def build(self, o, J_w, J_v, k) -> tuple:
        """(A, b, None, dirs, points, slots, rounds, pair) of the rows."""
        dirs, p1, p2, s1, s2, rhs, pair, r1, r2 = (np.concatenate(x) for x in zip(*self.parts))
        # A_i = n_i . (J(P1_i) - J(P2_i)), J(P) = J_v - [P - o]x J_w on a
        # moving body, 0 on a welded one: n . ([r]x J_w) = (r x n) . J_w.
        A = np.zeros((len(dirs), k))
        for s, p, sign in ((s1, p1, 1.0), (s2, p2, -1.0)):
            moving = s >= 0
            if not moving.any():
                continue
            slot = s[moving]
            r = p[moving] - o[slot]
            dn = dirs[moving]
            A[moving] += sign * (
                np.einsum("mi,mik->mk", dn, J_v[slot]) + np.einsum("mi,mik->mk", np.cross(r, dn), J_w[slot])
            )
        return (
            A,
            rhs.copy(),
            None,
            dirs,
            np.stack([p1, p2], axis=1),
            np.stack([s1, s2], axis=1).astype(int),
            np.stack([np.where(s1 >= 0, r1, 0.0), np.where(s2 >= 0, r2, 0.0)], axis=1),
            pair.astype(int),
        )


class BroadPhase:
    """The damper's broad phase: lower bounds of its pairs' distances from
    bounding balls and boxes, so that only pairs within the influence
    distance are measured."""

    def __init__(self, damper, inspector):
        """Per pair, each side's bounding shape for the broad phase
        (:meth:`lower_bounds`) of a damper's pairs: a geometry on a moving body of the robot, a
        ball about its box's centre (in the body frame); any other
        geometry, its box (:func:`~.damper_kernel.local_box`) posed in the world, fixed
        (anchored geometry) or by the query at each update (geometry that
        moves on its own, or on a body that other joints than the robot's
        move too, e.g. a gripper's finger)."""
        world = inspector.world_frame_id()
        plant, self._pairs = damper._plant, damper._pairs
        others = [j for j in plant.GetJointIndices() if j not in set(plant.GetJointIndices(damper._robot))]
        carried = set(plant.GetBodiesKinematicallyAffectedBy(others)) if others else set()
        jointed = set(plant.GetBodiesKinematicallyAffectedBy(list(plant.GetJointIndices()))) | {
            b for b in plant.GetFloatingBaseBodies()
        }
        defaults = plant.CreateDefaultContext()
        P = len(self._pairs)
        #: (P, 2, 3, 3) / (P, 2, 3): each pair side's box pose in the world
        #: (a side on no moving body of the robot: its geometry's pose, fixed
        #: or posed by the query at the last :meth:`lower_bounds` that looked
        #: at the pair).
        self._ball_slot = np.full((P, 2), -1, np.int64)
        self._ball_centre = np.zeros((P, 2, 3))  # moving: in the body frame; else the box's centre, geometry frame
        self._ball_half = np.zeros((P, 2, 3))  # the box's half extents (a ball's radius: their norm)
        self.box_R = np.tile(np.eye(3), (P, 2, 1, 1))
        self.box_p = np.zeros((P, 2, 3))
        #: (pair, side, geometry id) of the boxes posed by the query: geometry
        #: that moves on its own or with other joints than the robot's.
        self.query_posed = []
        for n, (a, b, sa, sb) in enumerate(self._pairs):
            for j, (gid, side) in enumerate(((a, sa), (b, sb))):
                centre, half = local_box(inspector.GetShape(gid))
                self._ball_half[n, j] = half
                if side[0] is not None and side[0].index() not in carried:
                    self._ball_slot[n, j] = damper._slot[side[0].index()]
                    self._ball_centre[n, j] = side[1].multiply(centre)
                    continue
                self._ball_centre[n, j] = centre
                body = plant.GetBodyFromFrameId(inspector.GetFrameId(gid))
                if inspector.GetFrameId(gid) == world or (body is not None and body.index() not in jointed):
                    # Anchored, or on a body welded to the world: its pose never changes.
                    X = inspector.GetPoseInFrame(gid)
                    if inspector.GetFrameId(gid) != world:
                        X = plant.EvalBodyPoseInWorld(defaults, body).multiply(X)
                    self.box_R[n, j], self.box_p[n, j] = X.rotation().matrix(), X.translation()
                else:
                    self.query_posed.append((n, j, gid))
        # The same as arrays: per entry its pair, side and geometry (an index
        # into the geometries, each once, whose last poses are kept).
        self._posed_ids = list(dict.fromkeys(g for _, _, g in self.query_posed))
        index = {g: i for i, g in enumerate(self._posed_ids)}
        self._posed_pair = np.array([n for n, _, _ in self.query_posed], np.int64)
        self._posed_side = np.array([j for _, j, _ in self.query_posed], np.int64)
        self._posed_geometry = np.array([index[g] for _, _, g in self.query_posed], np.int64)
        self._posed_R = np.tile(np.eye(3), (len(self._posed_ids), 1, 1))
        self._posed_p = np.zeros((len(self._posed_ids), 3))

    def near(self, query, R, o, measure, influence: np.ndarray, poses=None) -> tuple[np.ndarray, np.ndarray]:
        """The pairs of ``measure`` ((P,) bools) to measure, by lower bounds
        of their distances: between two balls, their gap; between a ball
        and a box, the ball centre's distance from the box less its radius;
        between two boxes, -inf. Returns (per pair the lower bound where it
        is at least ``influence`` (m), NaN elsewhere; the indices of the
        pairs whose bound lies below it). The bodies posed at R, o; a
        geometry's pose taken from ``poses`` ({geometry id: pose}, looked
        up in ``query`` at this update) where it is there."""
        if self.query_posed:  # boxes that move on their own: one pose look-up per geometry measured
            sel = np.flatnonzero(measure[self._posed_pair])
            if len(sel):
                poses = {} if poses is None else poses
                for i in np.unique(self._posed_geometry[sel]):
                    gid = self._posed_ids[i]
                    X = poses.get(gid)
                    if X is None:
                        X = query.GetPoseInWorld(gid)
                    self._posed_R[i], self._posed_p[i] = X.rotation().matrix(), X.translation()
                n, j, g = self._posed_pair[sel], self._posed_side[sel], self._posed_geometry[sel]
                self.box_R[n, j], self.box_p[n, j] = self._posed_R[g], self._posed_p[g]
        return near_pairs(
            measure,
            self._ball_slot,
            self._ball_centre,
            self._ball_half,
            self.box_R,
            self.box_p,
            R,
            o,
            np.asarray(influence, float),
        )


def side_arrays(damper, inspector) -> tuple[tuple, np.ndarray]:
    """Each pair side's data for :func:`~.damper_kernel.pair_rows` (its
    ``sides``: body slot, X_BG, probes, their count and radii, point-query
    shape, round radius), and per pair whether its rows need Drake's point
    query (a probe against a moving ellipsoid)."""
    P = len(damper._pairs)
    most = max([len(side[3]) for _, _, sa, sb in damper._pairs for side in (sa, sb)] + [0])
    out_slot = np.full((P, 2), -1, np.int64)
    out_R, out_t = np.tile(np.eye(3), (P, 2, 1, 1)), np.zeros((P, 2, 3))
    out_probes, out_radii = np.zeros((P, 2, most, 3)), np.zeros((P, 2, most))
    out_count = np.zeros((P, 2), np.int64)
    out_kind, out_prm = np.full((P, 2), NO_POINT_QUERY, np.int64), np.zeros((P, 2, 3))
    out_round = np.zeros((P, 2))
    drake_rows = np.zeros(P, bool)
    for n, (a, b, sa, sb) in enumerate(damper._pairs):
        for j, (gid, side) in enumerate(((a, sa), (b, sb))):
            out_kind[n, j], out_prm[n, j] = point_query_shape(inspector.GetShape(gid))
            out_round[n, j] = damper._round[gid]
            if side[0] is None:
                continue
            out_slot[n, j] = damper._slot[side[0].index()]
            out_R[n, j], out_t[n, j] = side[1].rotation().matrix(), side[1].translation()
            m = len(side[3])
            out_probes[n, j, :m], out_radii[n, j, :m], out_count[n, j] = side[2], side[3], m
        for j in range(2):  # a probe of side j against side 1 - j, moving, that only Drake measures
            if (
                out_count[n, j]
                and out_slot[n, 1 - j] >= 0
                and out_kind[n, 1 - j] == NO_POINT_QUERY
                and damper._point_query[(a, b)[1 - j]]
            ):
                drake_rows[n] = True
    return (out_slot, out_R, out_t, out_probes, out_count, out_radii, out_kind, out_prm, out_round), drake_rows


def drake_pair_rows(damper, query, index, pair, R, o, out) -> None:
    """The rows of a pair :func:`~.damper_kernel.pair_rows` cannot make
    (a probe against a moving ellipsoid: Drake's point query), the same
    way. Appends one near pair's rows to ``out``: its witness row, then A's
    probes against B and B's against A. The plane through the other's
    witness (normal n, resp. -n) bounds from below the distance of every
    point of a probing shape from a static shape (an obstacle), to first
    order in the motion: those rows are the plane's. Against a moving
    shape (a robot link) the plane moves too, so a probe gets its own
    distance from the shape (Drake's point query) and its gradient
    instead; a probe whose plane gap
    exceeds the influence distance is skipped either way (the plane gap
    is a lower bound)."""
    id_a, id_b, side_a, side_b = damper._pairs[index]
    n = np.asarray(pair.nhat_BA_W, float).reshape(3)
    d = pair.distance
    ends = []
    for gid, side, p_GC in ((id_a, side_a, pair.p_ACa), (id_b, side_b, pair.p_BCb)):
        slot = -1 if side[0] is None else damper._slot[side[0].index()]
        p_GC = np.asarray(p_GC, float).reshape(3)
        if slot < 0:
            ends.append((slot, query.GetPoseInWorld(gid).multiply(p_GC), np.zeros((0, 3))))
        else:
            w = R[slot] @ (side[1].multiply(p_GC)) + o[slot]
            ends.append((slot, w, side[2] @ R[slot].T + o[slot]))
    (sa, wa, probes_a), (sb, wb, probes_b) = ends
    out.add(
        n[None],
        wa[None],
        wb[None],
        sa,
        sb,
        -damper.rate * (d - damper.target_distance),
        index,
        damper._round[id_a],
        damper._round[id_b],
    )
    for side, sign, id_other, slot, P, s_other, other in (
        (side_a, 1.0, id_b, sa, probes_a, sb, wb),
        (side_b, -1.0, id_a, sb, probes_b, sa, wa),
    ):
        if not len(P):
            continue
        radii = side[3]
        gaps = sign * (P - other) @ n - radii
        close = np.flatnonzero(gaps < damper.reach)
        if not len(close):
            continue
        if s_other < 0:  # a static obstacle: the plane's rows
            out.add(
                np.broadcast_to(sign * n, (len(close), 3)),
                P[close],
                np.broadcast_to(other, (len(close), 3)),
                slot,
                -1,
                -damper.rate * (gaps[close] - damper.target_distance),
                index,
                0.0,
                0.0,
            )
            continue
        if not damper._point_query[id_other]:
            continue  # a moving shape without a point query: the witness row only
        X_WO = query.GetPoseInWorld(id_other)
        dist, grad, p_near = _drake_distances(damper, query, id_other, X_WO, P[close], radii[close])
        keep = dist - radii[close] < damper.reach
        if keep.any():
            out.add(
                grad[keep],
                P[close][keep],
                p_near[keep],
                slot,
                s_other,
                -damper.rate * (dist[keep] - radii[close][keep] - damper.target_distance),
                index,
                0.0,
                0.0,
            )


def _drake_distances(damper, query, gid, X_WO, P, radii):
    """Drake's signed distances (m,), unit gradients (m, 3) and nearest
    points (m, 3, world) of points P (m, 3, world) from geometry
    ``gid`` posed at X_WO (inf: not found within the influence
    distance)."""
    d, g, near = np.full(len(P), np.inf), np.zeros((len(P), 3)), np.zeros((len(P), 3))
    for i, point in enumerate(P):
        found = [r for r in query.ComputeSignedDistanceToPoint(point, damper.reach + radii[i]) if r.id_G == gid]
        if found:
            d[i], g[i] = found[0].distance, np.asarray(found[0].grad_W, float).reshape(3)
            near[i] = X_WO.multiply(np.asarray(found[0].p_GN, float).reshape(3))
    return d, g, near


def convex_arrays(pairs, inspector) -> tuple[np.ndarray, ...]:
    """Each pair side's shape for :func:`~.distance_kernel.gjk_pairs`:
    kind (P, 2) (-1: one GJK does not measure), sizes (P, 2, 3), centre
    (P, 2, 3) in the geometry frame, a hull's vertices about it (P, 2, V,
    3) and their count (P, 2)."""
    from drake_cfvol.kernel import kinds
    from drake_cfvol.systems.filter.distance_kernel import GJK_KINDS

    P = len(pairs)
    found = []
    for a, b, _, _ in pairs:
        for gid in (a, b):
            g = kinds.geometry(inspector.GetShape(gid), strict=False)
            found.append(None if g is None or g.kind.unbounded or g.kind.code not in GJK_KINDS else g)
    most = max([len(g.verts) for g in found if g is not None] + [1])
    kind = np.full((P, 2), -1, np.int64)
    sizes, centre = np.zeros((P, 2, 3)), np.zeros((P, 2, 3))
    verts, count = np.zeros((P, 2, most, 3)), np.zeros((P, 2), np.int64)
    for n, g in enumerate(found):
        if g is None:
            continue
        p, j = divmod(n, 2)
        kind[p, j], sizes[p, j], centre[p, j] = g.kind.code, g.sizes, g.centre
        verts[p, j, : len(g.verts)], count[p, j] = g.verts, len(g.verts)
    return kind, sizes, centre, verts, count
