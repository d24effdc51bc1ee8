"""Region tests: a straight piece of the nominal with one joint swept over a
range, proven free by a grid of poses and a second-order growth bound; the
sweep's adaptive search for each joint's bound (the paper's Algorithm 2,
made sound: :func:`sound_joint_bounding`), and many regions at once.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from drake_cfvol.kernel.cells import (
    _ball_box_in_frame,
    _balls_clear_over_region,
    _cells_hit_row,
    _cells_vs_scene,
    _row_boxes,
    _scene_clear_of_box,
    shape_bounds,
)
from drake_cfvol.kernel.flat_model import flatten_model, model_from_flat
from drake_cfvol.kernel.heightfield import new_scratch, no_height_field
from drake_cfvol.kernel.kinematics import _axis_rotation, fk_into
from drake_cfvol.kernel.shapes import _aabb_apart, pose_shape_inline, row_aabb_inline, set_motion
from drake_cfvol.kernel.swept import region_quick_free
from drake_cfvol.kernel.types import (
    MAX_T_SAMPLES,
    MAX_V_SAMPLES,
    MEMO_W,
    SHAPE_W,
    HeightField,
    Model,
    RegionScratch,
    Scratch,
)

__all__ = ["sweep_chains", "regions_hit", "sound_joint_bounding"]


@njit(cache=True)
def _relative_growth(W, i, j, a, b, L_t, L_v, moved, curvature, reach, revolute):
    """Second-order growth of body b's shapes relative to body a over the
    region (joints that move both alike do not count)."""
    k = W.shape[1]
    a_t = 0.0
    for kk in range(k):
        if kk == j or not moved[kk, b] or (a >= 0 and moved[kk, a]):
            continue
        dk = abs(W[i + 1, kk] - W[i, kk])
        if dk == 0.0:
            continue
        for ll in range(k):
            if ll == j or not moved[ll, b] or (a >= 0 and moved[ll, a]):
                continue
            a_t += dk * abs(W[i + 1, ll] - W[i, ll]) * curvature[kk, ll, b]
    grow = a_t * L_t * L_t / 8.0
    if moved[j, b] and revolute[j] and L_v > 0:
        # |d^2 p / dv^2| = distance from j's axis <= reach (any pose).
        grow += reach[j, b] * L_v * L_v / 8.0
    return grow


@njit(cache=True)
def _region_poses(W, i, j, ts, vs, m, rs, Rot):
    """Body poses at the region's nt x nv grid points into rs.RP, rs.pP:
    forward kinematics at each t (joint j at va), then joint j's motion
    applied about (along) its axis for the other v."""
    ta, tb, nt = ts
    va, vb, nv = vs
    B = m.chain.parent.shape[0]
    R_MB, p_MB, axis = m.chain.R_MB, m.chain.p_MB, m.chain.axis
    moved, revolute = m.moved, m.revolute
    RP, pP, q_c = rs.RP, rs.pP, rs.q_c
    k = W.shape[1]
    jb = m.joint_body[j]
    for ti in range(nt):
        t = ta if nt == 1 else ta + (tb - ta) * ti / (nt - 1)
        for kk in range(k):
            q_c[kk] = W[i, kk] + t * (W[i + 1, kk] - W[i, kk])
        q_c[j] = va
        c0 = ti * nv
        fk_into(q_c, m.chain, RP[c0], pP[c0])
        if nv == 1:
            continue
        # Joint j's axis in the world (through its child frame's origin):
        # p_WM = p_WB - R_WB R_MB^T p_MB, u = R_WB R_MB^T axis.
        RB = RP[c0, jb]
        RM = R_MB[jb]
        pm = p_MB[jb]
        ax = axis[jb]
        cw0 = pP[c0, jb, 0]
        cw1 = pP[c0, jb, 1]
        cw2 = pP[c0, jb, 2]
        u0 = 0.0
        u1 = 0.0
        u2 = 0.0
        for r in range(3):
            tr = RM[0, r] * pm[0] + RM[1, r] * pm[1] + RM[2, r] * pm[2]
            ar = RM[0, r] * ax[0] + RM[1, r] * ax[1] + RM[2, r] * ax[2]
            cw0 -= RB[0, r] * tr
            cw1 -= RB[1, r] * tr
            cw2 -= RB[2, r] * tr
            u0 += RB[0, r] * ar
            u1 += RB[1, r] * ar
            u2 += RB[2, r] * ar
        un = np.array([u0, u1, u2])
        for vi in range(1, nv):
            c = c0 + vi
            dv = (vb - va) * vi / (nv - 1)
            if revolute[j]:
                _axis_rotation(un, dv, Rot)
            for b in range(B):  # element by element: a row view per body costs a reference count
                if not moved[j, b]:
                    for r in range(3):
                        for cc in range(3):
                            RP[c, b, r, cc] = RP[c0, b, r, cc]
                        pP[c, b, r] = pP[c0, b, r]
                elif revolute[j]:
                    for r in range(3):
                        g0 = Rot[r, 0]
                        g1 = Rot[r, 1]
                        g2 = Rot[r, 2]
                        for cc in range(3):
                            RP[c, b, r, cc] = g0 * RP[c0, b, 0, cc] + g1 * RP[c0, b, 1, cc] + g2 * RP[c0, b, 2, cc]
                    x0 = pP[c0, b, 0] - cw0
                    x1 = pP[c0, b, 1] - cw1
                    x2 = pP[c0, b, 2] - cw2
                    pP[c, b, 0] = cw0 + Rot[0, 0] * x0 + Rot[0, 1] * x1 + Rot[0, 2] * x2
                    pP[c, b, 1] = cw1 + Rot[1, 0] * x0 + Rot[1, 1] * x1 + Rot[1, 2] * x2
                    pP[c, b, 2] = cw2 + Rot[2, 0] * x0 + Rot[2, 1] * x1 + Rot[2, 2] * x2
                else:
                    for r in range(3):
                        for cc in range(3):
                            RP[c, b, r, cc] = RP[c0, b, r, cc]
                    pP[c, b, 0] = pP[c0, b, 0] + u0 * dv
                    pP[c, b, 1] = pP[c0, b, 1] + u1 * dv
                    pP[c, b, 2] = pP[c0, b, 2] + u2 * dv


@njit(cache=True)
def _region_vs_scene(W, i, j, ts, vs, m, field, sc, rs, pad):
    """The shapes joint j moves, over the region's grid (grown by the
    second-order bound and ``pad``), against the obstacles and V."""
    ta, tb, nt = ts
    va, vb, nv = vs
    P = nt * nv
    S = m.shapes.shape[0]
    shapes, shape_body, verts = m.shapes, m.shape_body, m.verts
    moved, reach, curvature, revolute = m.moved, m.reach, m.curvature, m.revolute
    RP, pP, objs, aabbs = rs.RP, rs.pP, rs.objs, rs.aabbs
    L_t = (tb - ta) / max(nt - 1, 1)
    L_v = (vb - va) / max(nv - 1, 1)
    for s in range(S):
        b = shape_body[s]
        if not moved[j, b]:
            continue
        grow = _relative_growth(W, i, j, -1, b, L_t, L_v, moved, curvature, reach, revolute)
        if _balls_clear_over_region(s, nt, nv, m, grow + pad, field, rs, sc.tmp6):
            continue
        for c in range(P):
            pose_shape_inline(shapes[s], RP[c, b], pP[c, b], objs[s, c])
            set_motion(objs[s, c], grow + pad, 0.0, 0.0, 1.0, 0.0, 0.0)
        obj = objs[s, :P]
        _row_boxes(obj, verts, rs.rowbox, aabbs[s])
        for r in range(3):  # what the scene can change: tests that read only boxes outside fp stay the same
            rs.fp[r] = min(rs.fp[r], aabbs[s, r])
            rs.fp[r + 3] = max(rs.fp[r + 3], aabbs[s, r + 3])
        if _scene_clear_of_box(aabbs[s], m.obstacle_aabb, field):
            continue
        if _cells_vs_scene(obj, nt, nv, rs, m, field, sc, rs.dirs[s]):
            return True
    return False


@njit(cache=True)
def _region_self_pairs(W, i, j, ts, vs, m, sc, rs, pad):
    """The robot's self pairs that joint j moves apart, over the region's
    grid, in the frame of the body j does not move."""
    ta, tb, nt = ts
    va, vb, nv = vs
    P = nt * nv
    S = m.shapes.shape[0]
    O = m.obstacles.shape[0]
    shapes, shape_body, verts, pairs = m.shapes, m.shape_body, m.verts, m.body_pairs
    moved, reach, curvature, revolute = m.moved, m.reach, m.curvature, m.revolute
    RP, pP, rel, rel_aabb = rs.RP, rs.pP, rs.rel, rs.rel_aabb
    ws = sc.ws
    L_t = (tb - ta) / max(nt - 1, 1)
    L_v = (vb - va) / max(nv - 1, 1)
    R_fm = np.empty((3, 3))
    p_fm = np.empty(3)
    dp = np.empty(3)
    relP = rel[:P]
    for p in range(pairs.shape[0]):
        a = pairs[p, 0]
        bb = pairs[p, 1]
        if moved[j, a] == moved[j, bb]:
            continue
        f = a if not moved[j, a] else bb  # the body j does not move
        mb = bb if f == a else a
        for kk in range(W.shape[1]):
            if kk != j and moved[kk, f] and not moved[kk, mb] and W[i + 1, kk] != W[i, kk]:
                # A tree's other branch (a second finger) moves body f along
                # the stretch: f's frame turns under mb, and nothing bounds
                # that between grid poses. May collide (conservative).
                return True
        grow = _relative_growth(W, i, j, f, mb, L_t, L_v, moved, curvature, reach, revolute)
        for sm in range(S):
            if shape_body[sm] != mb:
                continue
            _ball_box_in_frame(rs, P, f, mb, rs.bound[sm], grow + pad, rel_aabb)
            near = False
            for sf in range(S):
                if shape_body[sf] == f:
                    near = near or not _aabb_apart(rel_aabb, rs.local_box[sf])
            if not near:
                continue
            q0, q1 = m.shape_spheres[sm, 0], m.shape_spheres[sm, 1]
            for q in range(q0, q1):
                rs.cover_r[q - q0] = m.spheres[q, 3] + grow + pad
            for c in range(P):
                # X_fm = X_Wf^-1 X_Wm at grid point c.
                Rf = RP[c, f]
                Rm = RP[c, mb]
                for r in range(3):
                    for cc in range(3):
                        R_fm[r, cc] = Rf[0, r] * Rm[0, cc] + Rf[1, r] * Rm[1, cc] + Rf[2, r] * Rm[2, cc]
                    dp[r] = pP[c, mb, r] - pP[c, f, r]
                for r in range(3):
                    p_fm[r] = Rf[0, r] * dp[0] + Rf[1, r] * dp[1] + Rf[2, r] * dp[2]
                pose_shape_inline(shapes[sm], R_fm, p_fm, relP[c])
                set_motion(relP[c], grow + pad, 0.0, 0.0, 1.0, 0.0, 0.0)
                for q in range(q0, q1):  # the cover balls in f's frame, for the cells' ball test
                    b0, b1, b2 = m.spheres[q, 0], m.spheres[q, 1], m.spheres[q, 2]
                    for r in range(3):
                        rs.cover_cen[q - q0, c, r] = p_fm[r] + R_fm[r, 0] * b0 + R_fm[r, 1] * b1 + R_fm[r, 2] * b2
            _row_boxes(relP, verts, rs.rowbox, rel_aabb)
            for sf in range(S):
                if shape_body[sf] != f:
                    continue
                # Body f's shape in its own frame: the local row as it is.
                if _aabb_apart(rel_aabb, rs.local_box[sf]):
                    continue
                if _cells_hit_row(
                    relP, nt, nv, rs, shapes[sf : sf + 1], rs.local_box[sf], verts, ws, rs.dirs[sm, O + sf], q1 - q0
                ):
                    return True
    return False


@njit(cache=True)
def _region_hits(W, i, j, ts, vs, m, field, sc, rs, pad):
    """May the robot collide (or come closer than ``pad``, m) anywhere in the region R = {nom(i + t) with
    joint j replaced by v : t in [ta, tb], v in [va, vb]}?

    R is the image of a rectangle under an affine map into configuration
    space. The rectangle is sampled on an nt x nv grid; each shape's
    positions over R lie in the convex hull of its poses at the grid points
    grown by a ball (a second-order bound): along a segment of length L
    where |d^2 p / ds^2| <= A, a point stays within A L^2 / 8 of the chord,
    and the chord lies in the hull of its ends. For the nominal's direction
    dq' (dq without joint j), A = sum_kl |dq'_k| |dq'_l| curvature[k, l, b];
    for joint j's direction, A = the shape's distance from j's axis <= reach
    (revolute) or 0 (prismatic).

    Shapes that joint j moves are tested in the world against the obstacles
    and V. A self-collision pair that joint j moves apart is tested in the
    frame of its body that j does not move, where only the joints between
    the two bodies move anything: a common motion would smear both hulls
    over each other. Everything else keeps its pose relative to the nominal,
    which is free.

    ``ts`` = (ta, tb, nt), ``vs`` = (va, vb, nv); ``m`` a :class:`Model`,
    ``field`` a :class:`HeightField`, ``sc`` and ``rs`` the thread's
    :class:`Scratch` and :class:`RegionScratch`.
    """
    if region_quick_free(W, i, j, ts, vs, m, field, rs, pad):
        return False
    return _region_grid_hits(W, i, j, ts, vs, m, field, sc, rs, pad)


@njit(cache=True)
def _region_grid_hits(W, i, j, ts, vs, m, field, sc, rs, pad):
    """:func:`_region_hits` without its quick pass: the grid poses, the
    shapes against the scene, the self pairs."""
    _region_poses(W, i, j, ts, vs, m, rs, sc.ws[8:11])  # ws rows 8-10 as a 3x3 (free outside GJK)
    if _region_vs_scene(W, i, j, ts, vs, m, field, sc, rs, pad):
        return True
    return _region_self_pairs(W, i, j, ts, vs, m, sc, rs, pad)


@njit(cache=True)
def _memo_fits(memo, n_old, k, va, vb, nv, changed):
    """Whether test k of the search may take entry k of its memo: the same
    region (va, vb, nv) and no changed box meeting that test's footprint."""
    if k >= n_old or memo[k, 0] != va or memo[k, 1] != vb or memo[k, 2] != nv:
        return False
    for c in range(changed.shape[0]):
        if (
            memo[k, 4] <= changed[c, 3]
            and changed[c, 0] <= memo[k, 7]
            and memo[k, 5] <= changed[c, 4]
            and changed[c, 1] <= memo[k, 8]
            and memo[k, 6] <= changed[c, 5]
            and changed[c, 2] <= memo[k, 9]
        ):
            return False
    return True


@njit(cache=True)
def sound_joint_bounding(
    i: int,
    j: int,
    sgn: int,
    guess: float,
    W: np.ndarray,
    lims: tuple[np.ndarray, np.ndarray, np.ndarray],
    grid: tuple[int, float],
    m: Model,
    field: HeightField,
    sc: Scratch,
    rs: RegionScratch,
    pad: float,
    memo: np.ndarray,
    n_old: int,
    changed: np.ndarray,
) -> tuple[float, int, int]:
    """The paper's Algorithm 2 (Joint Bounding, section III-C "Joint Space
    Exploration"), made sound (docs/spec.md, SPEC 6 and SPEC 7).

    The bound v of joint j over stretch i (upper for sgn +1, lower for -1).
    What it proves: for every t in [0, 1] and every value between the
    stretch's nominal range and v, moving joint j alone from nom(i + t) to
    that value, the other joints on the nominal, keeps the robot at least
    ``pad`` (m) from V, the obstacles and itself. The paper bisects on end
    values only and can jump over an obstacle; here each test proves a whole
    interval of v free (:func:`_region_hits`, conservative), so v may stop
    short of the true bound but never goes past it; the search ends where
    an interval no wider than ``delta[j]`` beyond v may collide, or at the
    absolute bound.

    An adaptive search from the stretch's nominal range outwards:
    test [F, F + w]; free -> certified, advance and double w; possible
    collision -> halve w; stop once a possibly colliding interval is no
    wider than delta[j]. From a neighbour's bound: [F, its bound - delta]
    first, then one delta past it. Each test samples nt poses along t and one pose
    per ``v_step`` along v (at most MAX_V_SAMPLES). ``guess`` is an
    absolute bound to start from (the previous stretch's; NaN: cold).
    ``lims`` = (lim_lo, lim_hi, delta), ``grid`` = (nt, v_step).

    ``memo`` (T, MEMO_W): the search's tests as run last time, its first
    ``n_old`` rows valid (T = 0: none kept): per test va, vb, nv, the
    verdict and the test's footprint (min xyz, max xyz). A test the same as
    last time's k-th whose footprint no box of ``changed`` (C, 6) meets
    takes its verdict (what the scene can change lies inside the
    footprint); the rows are rewritten with this search's tests. The
    search's footprint (their union) is left in ``rs.fp``.

    Returns:
        (bound, tests run, tests kept in the memo)
    """
    lim_lo, lim_hi, delta = lims
    nt, v_step = grid
    bound = lim_hi[i, j] if sgn > 0 else lim_lo[i, j]
    dj = delta[j]
    if sgn > 0:
        v0 = min(W[i, j], W[i + 1, j])
        T = bound - v0
    else:
        v0 = max(W[i, j], W[i + 1, j])
        T = v0 - bound
    if T <= 0:
        return v0, 0, 0
    count = 0
    kept = 0  # tests written into the memo
    T_memo = memo.shape[0]
    fp = np.empty(6)  # the search's footprint
    for r in range(3):
        fp[r] = np.inf
        fp[r + 3] = -np.inf
    F = 0.0
    start = T
    if not np.isnan(guess):
        start = sgn * (guess - v0) - dj  # just short of the neighbour's bound
    if start >= dj and start < T:
        w = start
        w_next = dj  # then the neighbour's bound itself: one test when it holds
    else:
        w = T
        w_next = -1.0
    while True:
        X = min(F + w, T)
        if sgn > 0:
            va = v0 + F
            vb = v0 + X
        else:
            va = v0 - X
            vb = v0 - F
        nv = 2 + int((X - F) / v_step)
        if nv > MAX_V_SAMPLES:
            nv = MAX_V_SAMPLES
        k = kept
        if _memo_fits(memo, n_old, k, va, vb, nv, changed):
            hit = memo[k, 3] != 0.0
            for r in range(6):
                rs.fp[r] = memo[k, 4 + r]
        else:
            for r in range(3):
                rs.fp[r] = np.inf
                rs.fp[r + 3] = -np.inf
            count += 1
            hit = _region_hits(W, i, j, (0.0, 1.0, nt), (va, vb, nv), m, field, sc, rs, pad)
        for r in range(3):
            fp[r] = min(fp[r], rs.fp[r])
            fp[r + 3] = max(fp[r + 3], rs.fp[r + 3])
        if k < T_memo:
            memo[k, 0] = va
            memo[k, 1] = vb
            memo[k, 2] = nv
            memo[k, 3] = 1.0 if hit else 0.0
            for r in range(6):
                memo[k, 4 + r] = rs.fp[r]
            kept += 1
        else:
            kept = T_memo + 1  # past the memo's room: no later test can take a row
        if not hit:
            F = X
            if F >= T:
                break
            if w_next > 0:
                w = w_next
                w_next = -1.0
            else:
                w = 2.0 * w
        else:
            width = X - F
            w_next = -1.0
            if width <= dj:
                break
            w = 0.5 * width
    for r in range(6):
        rs.fp[r] = fp[r]
    return v0 + sgn * F, count, min(kept, T_memo)


@njit(cache=True)
def _local_boxes(shapes, verts, out):
    """Each shape's axis-aligned box in its body's frame into out (S, 6)
    (the fixed body's side of a self pair: the same for every region)."""
    for s in range(shapes.shape[0]):
        row_aabb_inline(shapes[s], verts, out[s])


@njit(cache=True)
def _region_workspace(B, k, O, shapes, verts, spheres, ranges):
    """Scratch arrays of one thread's region tests (:func:`_region_hits`)
    for B bodies, k joints, O obstacles and the robot's shapes and cover
    balls, with what depends on the shapes alone filled in (each shape's
    bounding ball and its box in its body's frame)."""
    P = MAX_T_SAMPLES * MAX_V_SAMPLES
    S = shapes.shape[0]
    Q = 1  # the most cover balls of one shape
    for s in range(ranges.shape[0]):
        Q = max(Q, ranges[s, 1] - ranges[s, 0])
    rs = RegionScratch(
        np.empty((P, B, 3, 3)),
        np.empty((P, B, 3)),
        np.empty((S, P, SHAPE_W)),
        np.empty((S, 6)),
        np.empty((P, SHAPE_W)),
        np.empty(6),
        np.empty(k),
        np.zeros((S, O + S, 3)),
        np.empty(6),
        np.empty((P, 6)),
        np.empty((4, SHAPE_W)),
        np.empty((P, 3)),
        np.empty(k),
        np.empty((spheres.shape[0], 4)),
        np.empty(6),
        np.empty((S, 4)),
        np.empty((S, 6)),
        np.empty((Q, P, 3)),
        np.empty(Q),
    )
    shape_bounds(spheres, ranges, rs.bound)
    _local_boxes(shapes, verts, rs.local_box)
    return rs


@njit(cache=True, parallel=True)
def sweep_chains(
    chains: np.ndarray,
    lims: tuple[np.ndarray, np.ndarray, np.ndarray],
    nts: np.ndarray,
    v_steps: np.ndarray,
    W: np.ndarray,
    m: Model,
    field: HeightField,
    pads: np.ndarray,
    guesses: np.ndarray,
    memo: np.ndarray,
    memo_n: np.ndarray,
    changed: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Certified single-joint bounds of every stretch (:func:`sound_joint_bounding`),
    keeping stretch i at least ``pads[i]`` (m) from the scene and itself.
    Chain n = (j, sign) walks the stretches in order, each search starting
    from the previous stretch's bound (the first from ``guesses[n]``; NaN:
    cold); the chains run in parallel. ``lims`` = (lim_lo (g-1, k), lim_hi,
    delta (k,)); ``m`` a :class:`Model`; ``field`` a :class:`HeightField`.

    ``memo`` (n, g-1, T, MEMO_W) and ``memo_n`` (n, g-1): each search's
    tests as run last time and how many rows are valid, read and rewritten
    (:func:`sound_joint_bounding`; a memo of no chains, (0, 0, 0, MEMO_W), keeps none);
    ``changed`` (C, 6): the boxes (min xyz, max xyz) where the obstacles or
    V changed since.

    Returns:
        (bounds (n, g-1), tests (n,), footprints (n, g-1, 6)): a search's
        footprint is the union of the boxes (min xyz, max xyz) its tests
        held against the obstacles and V; obstacles and columns outside it
        cannot change the search's result. ``tests``: the tests run (not
        taken from the memo).
    """
    n_chains = chains.shape[0]
    n_st = W.shape[0] - 1
    out = np.zeros((n_chains, n_st))
    fps = np.empty((n_chains, n_st, 6))
    tests = np.zeros(n_chains, np.int64)
    B = m.chain.parent.shape[0]
    k = W.shape[1]
    # numba passes no named tuples into a parallel loop: the model goes in
    # as a plain tuple of its arrays and is rebuilt inside.
    flat = flatten_model(m)
    lim_lo, lim_hi, delta = lims
    table, ox, oy, side = field
    for n in prange(n_chains):
        mm = model_from_flat(flat)
        fld = HeightField(table, ox, oy, side)
        lm = (lim_lo, lim_hi, delta)
        j = chains[n, 0]
        sgn = chains[n, 1]
        sc = new_scratch()
        rs = _region_workspace(B, k, mm.obstacles.shape[0], mm.shapes, mm.verts, mm.spheres, mm.shape_spheres)
        guess = guesses[n]
        count = 0
        no_memo = np.zeros((0, MEMO_W))
        for i in range(n_st):
            for r in range(3):
                rs.fp[r] = np.inf
                rs.fp[r + 3] = -np.inf
            if memo.shape[0] > 0:
                mem = memo[n, i]
                n_old = memo_n[n, i]
            else:
                mem = no_memo
                n_old = 0
            bound, c, kept = sound_joint_bounding(
                i, j, sgn, guess, W, lm, (nts[i, j], v_steps[j]), mm, fld, sc, rs, pads[i], mem, n_old, changed
            )
            if memo.shape[0] > 0:
                memo_n[n, i] = kept
            out[n, i] = bound
            fps[n, i] = rs.fp
            count += c
            guess = bound
        tests[n] = count
    return out, tests, fps


#: regions_hit tries the quick pass on a chunk's first QUICK_TRIALS tests,
#: then only while it decides at least one test in QUICK_TRIALS.
QUICK_TRIALS = 8


@njit(cache=True, parallel=True)
def regions_hit(
    A: np.ndarray,
    B: np.ndarray,
    js: np.ndarray,
    va: np.ndarray,
    vb: np.ndarray,
    nts: np.ndarray,
    nvs: np.ndarray,
    pads: np.ndarray,
    m: Model,
) -> np.ndarray:
    """Region tests of many straight pieces (the certificate's box edges).

    Task n is the region {c(t) with joint js[n] replaced by v : t in [0, 1],
    v in [va[n], vb[n]]}, where c(t) = A[n] + t (B[n] - A[n]), tested as in
    :func:`_region_hits` (nts[n] x nvs[n] grid poses, second-order growth)
    against the obstacles and the robot itself, kept ``pads[n]`` (m) away;
    no volume V. As there, only what joint js[n] moves relative to the rest
    is tested: the rest is the pose at c(t), proven by the other joints'
    tasks. The quick pass is tried while it pays (:data:`QUICK_TRIALS`):
    either way a "free" is proven.

    Returns:
        (n,) True where the region may collide (False: proven free).
    """
    n_tasks = A.shape[0]
    out = np.zeros(n_tasks, np.bool_)
    B_n = m.chain.parent.shape[0]
    k = A.shape[1]
    # Chunks of tasks share a workspace; eight or more per call keep both
    # threads busy on a boundary proof's ~200 edges (64 left one thread a third idle).
    chunk = min(64, max(4, n_tasks // 8))
    n_chunks = (n_tasks + chunk - 1) // chunk
    # numba passes no named tuples into a parallel loop: the model goes in
    # as a plain tuple of its arrays and is rebuilt inside.
    flat = flatten_model(m)
    for c in prange(n_chunks):
        mm = model_from_flat(flat)
        no_field = no_height_field()
        sc = new_scratch()
        rs = _region_workspace(B_n, k, mm.obstacles.shape[0], mm.shapes, mm.verts, mm.spheres, mm.shape_spheres)
        W = np.empty((2, k))
        tried = 0
        decided = 0
        for n in range(c * chunk, min(n_tasks, (c + 1) * chunk)):
            W[0] = A[n]
            W[1] = B[n]
            ts = (0.0, 1.0, min(nts[n], MAX_T_SAMPLES))
            vs = (va[n], vb[n], min(nvs[n], MAX_V_SAMPLES))
            # The quick pass while it pays: a box edge by the static scene
            # is almost never decided by it (automotive path 1's
            # certification: 8 of 72k tests, at a tenth of a test's time
            # each), one by perceived boxes alone often is (a quarter).
            if tried < QUICK_TRIALS or QUICK_TRIALS * decided >= tried:
                tried += 1
                if region_quick_free(W, 0, js[n], ts, vs, mm, no_field, rs, pads[n]):
                    decided += 1
                    continue
            out[n] = _region_grid_hits(W, 0, js[n], ts, vs, mm, no_field, sc, rs, pads[n])
    return out
