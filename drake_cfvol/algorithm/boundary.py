"""The certificate's proof of the box boundary: every edge, and so every
corner, of a certified box at every s, free by the kernel's region tests.

A clamp pushed steadily lands on the box's faces, edges and corners, not on
uniform random points, so a uniformly sampled certificate says little
there. A certified table uses the "linear" box-at-s rule
(:func:`drake_cfvol.algorithm.table.box_at`): over a stretch [i, i+1] every bound
goes linearly from its value at waypoint i to its value at i + 1. So a
corner of the box moves on a straight segment in configuration space, and
the edge of joint j (joint j over its whole width, every other joint at
one of its bounds) sweeps the region {c(t) with joint j in [va, vb]}, c
straight, [va, vb] the joint's range at either end: exactly the kernel's
region test (:func:`drake_cfvol.kernel.regions_hit`, a grid of poses plus
a second-order growth bound, every shape grown by the margin). That test
checks what joint j moves relative to the rest; the rest sits on a corner
path, which the other joints' edges check. An edge's ends are corners, so
proving every edge proves every corner too.

A region that may collide is halved (in s and along the joint) a few
times. Where a configuration of the failing part really comes nearer than
the margin (a 9 x 9 grid of kernel point checks) it is cut as a point
(:func:`cut_point`); else the region is cut (:func:`cut_for`) by scaling
one bound's deviation from the nominal at both ends of the stretch: the
edge's own joint if the failing part lies off the nominal, else one of the
joints whose motion reaches the nearest pair (Drake's clearance query at
the failing region's centre), each candidate tried at a few scales against
the failing region. Every cut aims SLACK beyond the margin (as far as the
nominal has room, :func:`cut_slacks`), since a region test needs some
clearance to prove anything, and the cut kept is the one that loses the
least log-width, counting what the rate limit then takes from the
neighbouring waypoints. Cuts only
tighten: single-joint motions proven by the sweep stay proven. After the
cuts the waypoint boxes are rate-limited again
(:func:`drake_cfvol.algorithm.table.rate_limited`), which may tighten neighbours;
the proof runs until no stretch's box changes.
"""

from __future__ import annotations

import itertools

import numpy as np

from drake_cfvol import kernel as K
from drake_cfvol.exceptions import ParameterError
from drake_cfvol.algorithm.table import rate_limited

__all__ = ["edge_tasks", "regions_may_collide", "prove_boundary", "corner_pass", "corner_points", "reaching_joints",
           "cut_point", "cut_slacks"]

#: Halvings of a failing region before it is cut: along the joint, and in
#: the last S_SPLITS of them in s too.
MAX_SPLITS = 8
S_SPLITS = 3
#: Second-order growth allowed between grid poses, m (as in the sweep).
MOTION_TOLERANCE = 0.01
#: Scales of a bound's deviation tried by a cut, largest first.
CUT_SCALES = (0.95, 0.9, 0.8, 0.7, 0.6, 0.5, 0.4, 0.3, 0.2, 0.1, 0.0)
#: Room a cut leaves beyond the margin, m, so the region tests (whose grid
#: and growth bound need some clearance to prove anything) can pass.
SLACK = 0.02
#: Bisection steps that refine a cut's passing scale toward the failing one.
REFINE_STEPS = 3


def _signs(k: int, j: int) -> np.ndarray:
    """(2^(k-1), k) corner patterns of the joints other than j (1 upper,
    0 lower; column j unused)."""
    rows = np.array(list(itertools.product((0, 1), repeat=k - 1)), np.int64).reshape(-1, k - 1)
    return np.insert(rows, j, 0, axis=1)


def edge_tasks(lo_a, hi_a, lo_b, hi_b):
    """Every edge of a stretch whose box goes linearly from [lo_a, hi_a]
    to [lo_b, hi_b]: (A, B, j, va, vb, sign rows), one row per edge, A and
    B its corner path's ends. A joint of zero width at both ends has no
    edge of its own (its edges are corners of the others')."""
    k = len(lo_a)
    A, B, js, va, vb, sig = [], [], [], [], [], []
    for j in range(k):
        if hi_a[j] <= lo_a[j] and hi_b[j] <= lo_b[j]:
            continue
        S = _signs(k, j)
        A.append(np.where(S == 1, hi_a, lo_a))
        B.append(np.where(S == 1, hi_b, lo_b))
        js.append(np.full(len(S), j))
        va.append(np.full(len(S), min(lo_a[j], lo_b[j])))
        vb.append(np.full(len(S), max(hi_a[j], hi_b[j])))
        sig.append(S)
    if not A:
        k0 = np.zeros((0, k))
        return k0, k0, np.zeros(0, np.int64), np.zeros(0), np.zeros(0), np.zeros((0, k), np.int64)
    return (np.concatenate(A), np.concatenate(B), np.concatenate(js).astype(np.int64), np.concatenate(va),
            np.concatenate(vb), np.concatenate(sig))


def _grid(arrays, A, B, js, va, vb):
    """Grid sizes along t and v for each task (as the sweep chooses them)."""
    dq = np.abs(B - A)
    dq[np.arange(len(js)), js] = 0.0
    growth = np.einsum("nk,nl,klb->nb", dq, dq, arrays.curvature).max(axis=1) / 8.0
    nts = np.clip(1 + np.ceil(np.sqrt(growth / MOTION_TOLERANCE)), 2, K.MAX_T_SAMPLES).astype(np.int64)
    reach_j = np.where(arrays.revolute, arrays.reach.max(axis=1), 0.0)[js]
    v_step = np.where(reach_j > 0, np.sqrt(8 * MOTION_TOLERANCE / np.maximum(reach_j, 1e-9)), np.inf)
    nvs = np.clip(2 + np.floor((vb - va) / v_step), 2, K.MAX_V_SAMPLES).astype(np.int64)
    return nts, nvs


def regions_may_collide(arrays, A, B, js, va, vb, pads) -> np.ndarray:
    """(n,) True where region n ({c(t) with joint js[n] in [va[n], vb[n]]},
    c from A[n] to B[n]) may come nearer than pads[n] (m) to the obstacles
    or the robot itself; False: proven free."""
    if not len(js):
        return np.zeros(0, bool)
    A, B = np.ascontiguousarray(A, float), np.ascontiguousarray(B, float)
    js = np.ascontiguousarray(js, np.int64)
    va, vb = np.ascontiguousarray(va, float), np.ascontiguousarray(vb, float)
    nts, nvs = _grid(arrays, A, B, js, va, vb)
    a = arrays
    return K.regions_hit(A, B, js, va, vb, nts, nvs, np.ascontiguousarray(np.broadcast_to(pads, js.shape), float),
                         a.parent, a.jtype, a.qidx, a.axis, a.R_PF, a.p_PF, a.R_MB, a.p_MB, a.shapes,
                         a.shape_body, a.verts, a.obstacles, a.obstacle_aabb, a.self_pairs, a.moved_by, a.reach,
                         a.curvature, a.revolute, a.joint_body)


def _box(lower, upper, nominal, i, s):
    """(lo, hi, nom) of the linear rule on stretch i at path parameters s (n,)."""
    t = (np.asarray(s, float) - i)[:, None]
    lo = (1 - t) * lower[i] + t * lower[i + 1]
    hi = (1 - t) * upper[i] + t * upper[i + 1]
    nom = (1 - t) * nominal[i] + t * nominal[i + 1]
    return lo, hi, nom


def corner_points(lower, upper, nominal, s):
    """Every corner of the box at each path parameter s (n,) of a linear
    table: (n * 2^k, k) configurations, the n boxes one after the other."""
    g, k = nominal.shape
    s = np.asarray(s, float)
    i = np.clip(np.floor(s).astype(int), 0, g - 2)
    t = (s - i)[:, None]
    lo = (1 - t) * lower[i] + t * lower[i + 1]
    hi = (1 - t) * upper[i] + t * upper[i + 1]
    pat = np.array(list(itertools.product((0, 1), repeat=k)), bool)
    return np.where(pat[None], hi[:, None], lo[:, None]).reshape(-1, k)


class _Item:
    """A region of an edge: s in [sa, sb] of stretch i, joint j in
    [va, vb], the other joints on the bounds of sign row S."""

    __slots__ = ("i", "sa", "sb", "j", "va", "vb", "S", "A", "B", "root")

    def __init__(self, i, sa, sb, j, va, vb, S, A, B, root=-1):
        self.i, self.sa, self.sb, self.j, self.va, self.vb, self.S, self.A, self.B = i, sa, sb, j, va, vb, S, A, B
        self.root = root  # the whole edge this region was halved from (an index of _failures' edges)

    def ends(self, lower, upper):
        """Four configurations of the box's edge in this region: at either
        end in s, joint j at either end of the region's range clipped to
        the box's range there (a region's range may reach beyond the box
        where the joint's width changes along the stretch)."""
        out = []
        t = np.array([self.sa, self.sb]) - self.i
        lo_j = (1 - t) * lower[self.i, self.j] + t * lower[self.i + 1, self.j]
        hi_j = (1 - t) * upper[self.i, self.j] + t * upper[self.i + 1, self.j]
        for e, c in enumerate((self.A, self.B)):
            for v in (self.va, self.vb):
                q = c.copy()
                q[self.j] = min(max(v, lo_j[e]), hi_j[e])
                out.append(q)
        return out


def _test(arrays, items, margins):
    A = np.array([it.A for it in items])
    B = np.array([it.B for it in items])
    js = np.array([it.j for it in items], np.int64)
    va = np.array([it.va for it in items])
    vb = np.array([it.vb for it in items])
    pads = np.array([margins[it.i] for it in items], float)
    return regions_may_collide(arrays, A, B, js, va, vb, pads)


def _edge_key(i, j, S, A, B) -> tuple:
    """What fixes an edge region besides its joint's range: the stretch, the
    joint, the other joints' bound pattern and their values at both ends."""
    a, b = A.copy(), B.copy()
    a[j] = b[j] = 0.0
    return (i, j, S.tobytes(), a.tobytes(), b.tobytes())


def _failures(arrays, lower, upper, nominal, stretches, margins, memo: dict | None = None):
    """The edge regions of the given stretches that still may collide after
    MAX_SPLITS halvings (a region whose own corner configurations collide
    is not halved further). Returns (failed items, region tests run).

    ``memo`` (updated in place) holds the whole edges proven so far: an
    edge whose other joints sit exactly where a proven edge's did, with its
    own range inside that edge's and a margin no larger, is a subset of a
    proven region and is not tested again (cuts only tighten, so after a
    cut on one bound most of a stretch's edges are such subsets)."""
    memo = {} if memo is None else memo
    items, keys = [], []
    for i in stretches:
        A, B, js, va, vb, sig = edge_tasks(lower[i], upper[i], lower[i + 1], upper[i + 1])
        for n in range(len(js)):
            j = int(js[n])
            key = _edge_key(i, j, sig[n], A[n], B[n])
            # The joint's own range at both ends: the edge is a subset of a
            # proven one if both ranges lie inside (the rule is linear in s).
            lo_j, hi_j = lower[i:i + 2, j], upper[i:i + 2, j]
            known = memo.get(key)
            if (known is not None and np.all(known[0] <= lo_j) and np.all(hi_j <= known[1])
                    and margins[i] <= known[2]):
                continue
            keys.append((key, lo_j.copy(), hi_j.copy(), float(margins[i])))
            items.append(_Item(i, float(i), float(i + 1), j, va[n], vb[n], sig[n], A[n], B[n], root=len(keys) - 1))
    failed, tests = _halvings(arrays, lower, upper, nominal, items, margins)
    bad = {it.root for it in failed}
    for r, (key, lo_j, hi_j, m) in enumerate(keys):
        if r not in bad:
            memo[key] = (lo_j, hi_j, m)
    return failed, tests


def _halvings(arrays, lower, upper, nominal, items, margins):
    """Tests the regions, halving the failing ones (see :func:`_failures`).
    Returns (failed items, region tests run)."""
    tests = 0
    failed: list = []
    for depth in range(MAX_SPLITS + 1):
        if not items:
            break
        hit = _test(arrays, items, margins)
        tests += len(items)
        bad = [it for it, h in zip(items, hit) if h]
        if depth == MAX_SPLITS or not bad:
            failed += bad
            break
        ends = np.array([q for it in bad for q in it.ends(lower, upper)])
        pads = np.repeat([margins[it.i] for it in bad], 4)
        real = np.zeros(len(ends), bool)
        for p in np.unique(pads):
            sel = pads == p
            real[sel] = arrays.may_collide(ends[sel], float(p))
        real = real.reshape(len(bad), 4).any(axis=1)
        failed += [it for it, r in zip(bad, real) if r]
        items = []
        for it in (it for it, r in zip(bad, real) if not r):
            if depth < MAX_SPLITS - S_SPLITS:
                # Halved along the joint: the region's hull of poses bulges
                # inwards by about reach * width^2 / 8, the usual false alarm.
                vm = 0.5 * (it.va + it.vb)
                items += [_Item(it.i, it.sa, it.sb, it.j, it.va, vm, it.S, it.A, it.B, it.root),
                          _Item(it.i, it.sa, it.sb, it.j, vm, it.vb, it.S, it.A, it.B, it.root)]
                continue
            ss = np.array([it.sa, 0.5 * (it.sa + it.sb), it.sb])
            lo, hi, _ = _box(lower, upper, nominal, it.i, ss)
            c = np.where(it.S == 1, hi, lo)
            for h in range(2):
                v_lo = max(min(lo[h, it.j], lo[h + 1, it.j]), it.va)
                v_hi = min(max(hi[h, it.j], hi[h + 1, it.j]), it.vb)
                vm = 0.5 * (v_lo + v_hi)
                for u0, u1 in ((v_lo, vm), (vm, v_hi)):
                    items.append(_Item(it.i, ss[h], ss[h + 1], it.j, u0, u1, it.S, c[h].copy(), c[h + 1].copy(),
                                       it.root))
    return failed, tests


def reaching_joints(workcell, arrays, q, margin) -> np.ndarray:
    """(k,) the joints whose motion moves the nearest pair at q apart
    (Drake's clearance query): for a robot body against the scene, the
    joints that move it; for two robot bodies, the joints that move one but
    not the other. All joints if no pair is near."""
    k = len(q)
    rc = workcell.checker.CalcRobotClearance(np.asarray(q, float), max(margin, 0.0) + 0.05)
    d = np.asarray(rc.distances())
    if d.size:
        # A distance no joint changes (a rail carriage above the floor) is
        # not what a cut can help.
        J = np.asarray(rc.jacobians()).reshape(len(d), k)
        d = np.where(np.linalg.norm(J, axis=1) > 1e-9, d, np.inf)
    if not d.size or not np.isfinite(d).any():
        return np.ones(k, bool)
    n = int(np.argmin(d))
    plant = workcell.plant
    names = list(arrays.body_names)
    a = plant.get_body(rc.robot_indices()[n]).name()
    b = plant.get_body(rc.other_indices()[n]).name()
    ma = arrays.moved_by[:, names.index(a)] if a in names else np.zeros(k, bool)
    if str(rc.collision_types()[n]).endswith("kSelfCollision") and b in names:
        return ma != arrays.moved_by[:, names.index(b)]
    return ma.copy()


def _scaled(lower, upper, nominal, i, moves):
    """Copies of stretch i's waypoint bounds with the deviation of each
    (joint, side, lam) of ``moves`` scaled by lam at both ends:
    ((lo_i, lo_i1), (hi_i, hi_i1))."""
    lo, hi = lower[i:i + 2].copy(), upper[i:i + 2].copy()
    nom = nominal[i:i + 2]
    for l, side, lam in moves:
        if side > 0:
            hi[:, l] = nom[:, l] + lam * (hi[:, l] - nom[:, l])
        else:
            lo[:, l] = nom[:, l] - lam * (nom[:, l] - lo[:, l])
    return lo, hi


def _width_loss(lower, upper, nominal, rate, i, lo, hi):
    """Log-width the whole table loses if stretch i's two waypoint boxes
    became lo, hi: their own loss and what the rate limit then takes from
    the waypoints around them (:func:`drake_cfvol.algorithm.table.rate_limited`,
    applied from the two changed rows; the rest is rate-limited already)."""
    g = len(nominal)
    lo_f = lower.copy()
    hi_f = upper.copy()
    lo_f[i:i + 2] = np.maximum(lo_f[i:i + 2], lo)
    hi_f[i:i + 2] = np.minimum(hi_f[i:i + 2], hi)
    lim = np.isfinite(rate)
    if lim.any():
        m = np.arange(g)[:, None]
        for e in (i, i + 1):
            d = np.abs(m - e) * np.where(lim, rate, 0.0)
            hi_f = np.where(lim, np.minimum(hi_f, hi_f[e] + d), hi_f)
            lo_f = np.where(lim, np.maximum(lo_f, lo_f[e] - d), lo_f)
    lo_f = np.minimum(lo_f, nominal)
    hi_f = np.maximum(hi_f, nominal)
    w0 = np.maximum(upper - lower, 1e-12)
    w1 = np.maximum(hi_f - lo_f, 1e-12)
    return float(np.sum(np.log(w0 / w1)))


def cut_for(workcell, arrays, lower, upper, nominal, rate, fail: _Item, margin: float, slack: float,
            taken: set) -> bool:
    """Tightens the waypoint boxes of a failing region's stretch (in place)
    so that the region, recomputed, passes: the candidates are the edge's
    own joint (its failing range off the nominal cut away) and every joint
    on its bound in the region whose motion reaches the nearest pair, each
    at CUT_SCALES of its deviation; the passing candidate that loses the
    least width is applied; if none passes, the whole stretch box moves
    halfway to the nominal. ``taken`` holds the (stretch, joint, side)
    already cut this round (not cut again before the stretch is tested
    anew). Returns False (nothing cut) only if the region on the nominal
    itself fails the margin."""
    i, j = fail.i, fail.j
    sm = 0.5 * (fail.sa + fail.sb)
    lo_m, hi_m, nom_m = _box(lower, upper, nominal, i, np.array([sm]))
    q = np.where(fail.S == 1, hi_m[0], lo_m[0])
    q[j] = 0.5 * (fail.va + fail.vb)
    reach = reaching_joints(workcell, arrays, q, margin)
    ss = np.array([fail.sa, fail.sb])
    options = []  # (loss, stretch-local lo, hi, key)
    # The edge's own joint: its failing range cut away where it lies off the nominal.
    lo_ab, hi_ab, nom_ab = _box(lower, upper, nominal, i, ss)
    for side in (1, -1):
        if side > 0 and fail.va > nom_ab[:, j].max():
            dev = hi_ab[:, j] - nom_ab[:, j]
            lam = float(np.min((fail.va - nom_ab[:, j]) / np.maximum(dev, 1e-300)))
        elif side < 0 and fail.vb < nom_ab[:, j].min():
            dev = nom_ab[:, j] - lo_ab[:, j]
            lam = float(np.min((nom_ab[:, j] - fail.vb) / np.maximum(dev, 1e-300)))
        else:
            continue
        lam = float(np.clip(lam * (1 - 1e-6), 0.0, 1.0))
        lo, hi = _scaled(lower, upper, nominal, i, [(j, side, lam)])
        options.append((_width_loss(lower, upper, nominal, rate, i, lo, hi), lo, hi, (i, j, side)))
    # Another joint on its bound in the region, and all of them together (a
    # collision that two bounds make at once), tried at a few scales.
    group = [int(l) for l in np.flatnonzero(reach) if l != j]
    sides = {l: 1 if fail.S[l] == 1 else -1 for l in group}
    cands = [((l, sides[l]), [l]) for l in group] + ([((-1, 0), group)] if len(group) > 1 else [])
    trials = []
    for (l, side), members in cands:
        for lam in CUT_SCALES:
            lo, hi = _scaled(lower, upper, nominal, i, [(m, sides[m], lam) for m in members])
            if np.array_equal(lo, lower[i:i + 2]) and np.array_equal(hi, upper[i:i + 2]):
                continue
            a_lo, a_hi, _ = _box(lo, hi, nominal[i:i + 2], 0, ss - i)
            ca = np.where(fail.S == 1, a_hi, a_lo)
            trials.append((l, side, lam, lo, hi, _Item(i, fail.sa, fail.sb, j, fail.va, fail.vb, fail.S, ca[0], ca[1])))
    if trials:
        ok = ~_test(arrays, [t[5] for t in trials], {i: margin + slack})
        best_l = {}
        for (l, side, lam, lo, hi, _), good in zip(trials, ok):
            if good and (l, side) not in best_l:  # scales run largest first: the first pass is the best
                best_l[(l, side)] = (lo, hi)
        for (l, side), (lo, hi) in best_l.items():
            key = (i, int(l), side) if l >= 0 else (i, -2, 0)
            options.append((_width_loss(lower, upper, nominal, rate, i, lo, hi), lo, hi, key))
    options = [o for o in options
               if not (np.array_equal(o[1], lower[i:i + 2]) and np.array_equal(o[2], upper[i:i + 2]))]
    if not options:
        # No single bound clears it: if the nominal's own stretch keeps the
        # margin here, every bound of the stretch moves halfway to it (the
        # box shrinks to the nominal, proven by the sweep); else the margin
        # is what fails.
        na, nb = nom_ab
        on_nominal = _Item(i, fail.sa, fail.sb, j, min(na[j], nb[j]), max(na[j], nb[j]), fail.S, na, nb)
        if _test(arrays, [on_nominal], {i: margin})[0]:
            return False
        key = (i, -1, 0)
        nom2 = nominal[i:i + 2]
        lo = nom2 - 0.5 * (nom2 - lower[i:i + 2])
        hi = nom2 + 0.5 * (upper[i:i + 2] - nom2)
        options.append((0.0, lo, hi, key))
    _, lo, hi, key = min(options, key=lambda o: o[0])
    if key in taken:
        return True  # this bound moved already this round: test again first
    taken.add(key)
    lower[i:i + 2] = np.maximum(lower[i:i + 2], lo)
    upper[i:i + 2] = np.minimum(upper[i:i + 2], hi)
    return True


def _variants(lower, upper, nominal, i, t, moves):
    """Ways to scale, at s = i + t, the deviations from the nominal of the
    (joint, side, lam) ``moves`` (each deviation at s becomes lam times
    what it was): both ends of stretch i scaled by lam, or only the nearer
    end, moved just enough (when that is possible). Returns a list of
    (lo, hi), stretch i's two waypoint boxes, (2, k) each."""
    out = [_scaled(lower, upper, nominal, i, moves)]
    nom2 = nominal[i:i + 2]
    e = 0 if t <= 0.5 else 1
    w = max((1 - t) if e == 0 else t, 1e-12)
    lo, hi = lower[i:i + 2].copy(), upper[i:i + 2].copy()
    for l, side, lam in moves:
        d = (hi[:, l] - nom2[:, l]) if side > 0 else (nom2[:, l] - lo[:, l])
        new_e = d[e] - (1 - lam) * ((1 - t) * d[0] + t * d[1]) / w
        if new_e < 0:
            return out  # the nearer end alone cannot do it
        if side > 0:
            hi[e, l] = nom2[e, l] + new_e
        else:
            lo[e, l] = nom2[e, l] - new_e
    out.append((lo, hi))
    return out


def cut_point(workcell, arrays, lower, upper, nominal, rate, i, s, q, margin, slack, taken, own=None) -> None:
    """Tightens stretch i (in place) so that the colliding configuration q
    of the box at s comes free, with ``slack`` (m) beyond the margin. q may
    be a corner, an edge point (``own``: the edge's joint) or any point of
    the box, such as where a clamp lands: each joint at its nominal, on a
    bound, or inside. Candidates: each joint off its nominal whose motion
    reaches the nearest pair (Drake), all of them together, and the edge's
    own joint; each moves q's deviation toward the nominal by the largest
    scale that frees it (CUT_SCALES, then REFINE_STEPS bisections; checked
    as points), and the bound on that side is cut to match (a joint on its
    bound moves with it; a joint inside is cut just below q). Each at both
    ends of the stretch or at the nearer end only; the cut that loses the
    least width, counting what the rate limit then takes from the
    neighbours, is applied, else the stretch's box moves halfway to the
    nominal. ``taken`` holds the cuts of this round (a key is cut once)."""
    t = s - i
    (lo_s,), (hi_s,), (nom,) = _box(lower, upper, nominal, i, np.array([s]))
    # Cuts only tighten: an earlier cut this round may have moved (or freed)
    # the point already.
    q_now = np.clip(q, np.minimum(lo_s, nom), np.maximum(hi_s, nom))
    if not np.array_equal(q_now, q):
        q = q_now
        if not arrays.may_collide(q[None], margin + slack)[0]:
            return
    off = q != nom
    reach = [int(l) for l in np.flatnonzero(reaching_joints(workcell, arrays, q, margin) & off) if l != own]
    cands = [[l] for l in reach] + ([reach] if len(reach) > 1 else [])
    if own is not None and off[own]:
        cands.append([own])
    moves = []
    if cands:
        trials, Q = [], []
        for group in cands:
            for lam in CUT_SCALES:
                x = q.copy()
                x[group] = nom[group] + lam * (q[group] - nom[group])
                trials.append((tuple(group), lam))
                Q.append(x)
        ok = ~arrays.may_collide(np.array(Q), margin + slack)
        bracket, failing = {}, {}  # group -> (largest failing scale, largest passing scale)
        for (key, lam), good in zip(trials, ok):
            if key in bracket:
                continue
            if good:  # scales run largest first
                bracket[key] = (failing.get(key, 1.0), lam)
            else:
                failing[key] = lam
        keys = list(bracket)
        for _ in range(REFINE_STEPS if keys else 0):  # bisect each passing scale toward the failing one
            X = []
            for key in keys:
                x = q.copy()
                x[list(key)] = nom[list(key)] + 0.5 * sum(bracket[key]) * (q[list(key)] - nom[list(key)])
                X.append(x)
            good = ~arrays.may_collide(np.array(X), margin + slack)
            for key, gd in zip(keys, good):
                mid = 0.5 * sum(bracket[key])
                bracket[key] = (bracket[key][0], mid) if gd else (mid, bracket[key][1])
        for key, (_, lam) in bracket.items():
            mv = []
            for l in key:
                side = 1 if q[l] > nom[l] else -1
                dev = (hi_s[l] - nom[l]) if side > 0 else (nom[l] - lo_s[l])
                if dev > 0:  # q's deviation scaled by lam is this share of the bound's
                    mv.append((l, side, min(1.0, lam * abs(q[l] - nom[l]) / dev)))
            if mv:
                moves.append((key, mv))
    options = []
    for key, mv in moves:
        for lo, hi in _variants(lower, upper, nominal, i, t, mv):
            options.append((_width_loss(lower, upper, nominal, rate, i, lo, hi), lo, hi, (i,) + key))
    if not options:
        nom2 = nominal[i:i + 2]
        options.append((0.0, nom2 - 0.5 * (nom2 - lower[i:i + 2]), nom2 + 0.5 * (upper[i:i + 2] - nom2), (i, -1)))
    _, lo, hi, key = min(options, key=lambda o: o[0])
    if key in taken:
        return
    taken.add(key)
    lower[i:i + 2] = np.maximum(lower[i:i + 2], lo)
    upper[i:i + 2] = np.minimum(upper[i:i + 2], hi)


def corner_pass(workcell, arrays, lower, upper, nominal, rate, margins, slacks=None, *, per_stretch: int = 4,
                max_rounds: int = 50) -> dict:
    """A cheap pass before the proof: the box's corners at every quarter of
    every stretch, checked as points by the kernel; colliding ones are cut
    (:func:`cut_point`, at most ``per_stretch`` per stretch and round),
    round after round until none collides. It proves nothing (the region
    proof does) but removes what the proof would otherwise find one region
    at a time, with cuts chosen by exact point checks."""
    g, k = nominal.shape
    slacks = np.zeros(g - 1) if slacks is None else slacks
    pat = np.array(list(itertools.product((0, 1), repeat=k)), bool)
    s = np.arange(0.0, g - 1 + 1e-9, 0.25)
    st = np.clip(np.floor(s).astype(int), 0, g - 2)
    cuts = rounds = 0
    for _ in range(max_rounds):
        rounds += 1
        Q = corner_points(lower, upper, nominal, s)
        rows_st = np.repeat(st, len(pat))
        pads = margins[rows_st] + slacks[rows_st]
        bad = np.zeros(len(Q), bool)
        for p in np.unique(pads):
            sel = pads == p
            bad[sel] = arrays.may_collide(Q[sel], float(p))
        if not bad.any():
            break
        taken: set = set()
        for i in np.unique(rows_st[bad]):
            rows = np.flatnonzero(bad & (rows_st == i))
            for r in rows[:: max(1, len(rows) // per_stretch)][:per_stretch]:
                cut_point(workcell, arrays, lower, upper, nominal, rate, int(i), float(s[r // len(pat)]), Q[r],
                          float(margins[i]), float(slacks[i]), taken)
        cuts += len(taken)
        lower[:], upper[:] = rate_limited(lower, upper, nominal, rate)
    return {"corner_rounds": rounds, "corner_cuts": cuts}


def _colliding_points(arrays, lower, upper, nominal, fails, margins, slacks, n: int = 9):
    """For each failing region, a configuration of the box's edge in it
    that may collide, (s, q), or None: an n x n grid over the region (s
    and joint j), points outside the box at their s left out."""
    Q, owner, where = [], [], []
    u = np.linspace(0.0, 1.0, n)
    for r, f in enumerate(fails):
        s = f.sa + u * (f.sb - f.sa)
        lo, hi, _ = _box(lower, upper, nominal, f.i, s)
        c = np.where(f.S == 1, hi, lo)
        v = f.va + u * (f.vb - f.va)
        for a in range(n):
            ok = (v >= lo[a, f.j]) & (v <= hi[a, f.j])
            if not ok.any():
                continue
            q = np.repeat(c[a][None], ok.sum(), axis=0)
            q[:, f.j] = v[ok]
            Q.append(q)
            owner.append(np.full(len(q), r))
            where.append(np.full(len(q), s[a]))
    out = [None] * len(fails)
    if not Q:
        return out
    Q, owner, where = np.concatenate(Q), np.concatenate(owner), np.concatenate(where)
    pads = np.array([margins[fails[r].i] + slacks[fails[r].i] for r in owner], float)
    bad = np.zeros(len(Q), bool)
    for p in np.unique(pads):
        sel = pads == p
        bad[sel] = arrays.may_collide(Q[sel], float(p))
    for m in np.flatnonzero(bad):
        if out[owner[m]] is None:
            out[owner[m]] = (float(where[m]), Q[m].copy())
    return out


def cut_slacks(arrays, nominal, margins, slack: float | None = None) -> np.ndarray:
    """(g-1,) the room each stretch's cuts leave beyond its margin, m: the
    largest of ``slack`` (default SLACK) halved up to three times, or 0, at
    which the nominal's two waypoints and midpoint keep margin + room (a
    cut can never clear more room than the nominal has)."""
    slack = SLACK if slack is None else float(slack)
    n_st = len(nominal) - 1
    out = np.zeros(n_st)
    if slack <= 0 or n_st < 1:
        return out
    Q = np.concatenate([nominal[:-1], nominal[1:], 0.5 * (nominal[:-1] + nominal[1:])])
    pads = np.tile(np.asarray(margins, float), 3)
    for rung in (0.125, 0.25, 0.5, 1.0):  # from small up: a rung that holds at every point is kept
        room = rung * slack
        free = np.zeros(len(Q), bool)
        for p in np.unique(pads):
            sel = pads == p
            free[sel] = ~arrays.may_collide(Q[sel], float(p) + room)
        out = np.where(free.reshape(3, n_st).all(axis=0), room, out)
    return out


def _signature(lower, upper, i) -> bytes:
    return np.concatenate([lower[i], lower[i + 1], upper[i], upper[i + 1]]).tobytes()


def prove_boundary(workcell, arrays, lower, upper, nominal, rate, margins, proven: dict | None = None, *,
                   max_rounds: int = 200, memo: dict | None = None) -> dict:
    """Proves every edge (and corner) of the linear table's box at every s,
    cutting the waypoint boxes (in place) where a region may collide, until
    every stretch is proven as it is.

    Args:
        workcell, arrays: the scene (Drake for the nearest pair; kernel arrays).
        lower, upper: (g, k) waypoint boxes, tightened in place.
        nominal: (g, k) the nominal; rate: (k,) the bounds' rate limit.
        margins: (g-1,) each stretch's margin, m (lowered in place for a
            stretch whose nominal itself fails it, as certification does).
        proven: stretch -> the box signature proven last time (updated in
            place): pass the same dict again after other cuts and only the
            stretches whose box changed are proven again.
        max_rounds: rounds of proof and cuts before giving up.
        memo: the whole edges proven so far (updated in place; pass the
            same dict again): an edge inside a proven one is not tested
            again.

    Returns:
        stats: ``edge_tests`` (region tests), ``edge_cuts``, ``edge_rounds``,
        ``margins_lowered`` (stretches whose margin had to be lowered),
        ``unproven`` (stretches left unproven after ``max_rounds``: empty
        unless the proof ran out of rounds).
    """
    proven = {} if proven is None else proven
    memo = {} if memo is None else memo
    n_st = len(nominal) - 1
    slacks = cut_slacks(arrays, nominal, margins)
    tests = cuts = rounds = lowered = 0
    while rounds < max_rounds:
        todo = [i for i in range(n_st) if proven.get(i) != _signature(lower, upper, i)]
        if not todo:
            break
        rounds += 1
        cp = corner_pass(workcell, arrays, lower, upper, nominal, rate, margins, slacks)
        cuts += cp["corner_cuts"]
        todo = [i for i in range(n_st) if proven.get(i) != _signature(lower, upper, i)]
        fails, t = _failures(arrays, lower, upper, nominal, todo, margins, memo)
        tests += t
        for i in todo:
            proven[i] = _signature(lower, upper, i)
        taken: set = set()
        stuck = set()
        points = _colliding_points(arrays, lower, upper, nominal, fails, margins, slacks)
        for fail, hit in zip(fails, points):
            if fail.i in stuck:
                continue
            if hit is not None:
                # A real collision on the edge: cut as at a corner, the edge's
                # own joint one of the candidates.
                s_hit, q = hit
                cut_point(workcell, arrays, lower, upper, nominal, rate, fail.i, s_hit, q, float(margins[fail.i]),
                          float(slacks[fail.i]), taken, own=fail.j)
            elif not cut_for(workcell, arrays, lower, upper, nominal, rate, fail, float(margins[fail.i]),
                             float(slacks[fail.i]), taken):
                stuck.add(fail.i)
        for i in stuck:
            # Nothing cut passes: the region sits on the nominal, which comes
            # nearer than this stretch's margin between the points where
            # stretch_margins proved it. Lower the margin (as certification does).
            if margins[i] == 0.0:
                raise ParameterError(
                    f"boundary proof: the nominal of stretch {i} may collide between its waypoints; the path is "
                    "not collision-free there (plan with a finer max_step).")
            margins[i] = 0.5 * margins[i] if margins[i] > 1e-4 else 0.0
            proven.pop(i, None)
            lowered += 1
        cuts += len(taken)
        new_lo, new_hi = rate_limited(lower, upper, nominal, rate)
        lower[:], upper[:] = new_lo, new_hi
        for i in {f.i for f in fails} - {key[0] for key in taken} - stuck:
            proven.pop(i, None)  # a failure left for the next round (its bound was taken)
    unproven = [i for i in range(n_st) if proven.get(i) != _signature(lower, upper, i)]
    return {"edge_tests": tests, "edge_cuts": cuts, "edge_rounds": rounds, "margins_lowered": lowered,
            "unproven": unproven}
