"""The certificate's proof of the box boundary: every edge (and so every
corner) of the box at every s, free by the kernel's region tests.

A clamp pushed steadily lands on the box's faces, edges and corners, not on
uniform random points, so a uniformly sampled certificate says little
there. Edges are cheap to prove: an edge of joint j is the motion of joint
j alone over its whole box width with every other joint at one of its
bounds, the kind of region the kernel already certifies. Its ends are the
box's corners, so proving every edge proves every corner too.

Over a stretch [i, i+1] the box at s (docs/spec.md, SPEC 7: the stretch
box, rate-limited, held at the nominal) is piecewise linear in s: it is the
smallest/largest of a few lines (the stretch bound, the two rate
envelopes, the nominal). Between consecutive crossings of those lines
(:func:`pieces`) every bound is linear, so a corner's path is a straight
segment in configuration space and an edge of joint j over a piece lies
in the region {c(t) with joint j in [va, vb]}, c straight, [va, vb] the
joint's range at either end of the piece: exactly the kernel's region test
(:func:`drake_cfvol.kernel.regions_hit`). That test checks what joint j
moves relative to the rest; the rest sits at a corner, which the other
joints' edges check. Every region keeps the stretch's margin.

A region that may collide is halved (in s and along the joint) a few
times; what still fails is cut (:func:`cut_for`): the edge's own joint if
the failing part lies off the nominal, else one of the joints whose motion
reaches the nearest pair (read from Drake at the failing region's centre),
the one that loses the least. Cuts only tighten, so proven single-joint
motions stay proven; the boxes of neighbouring stretches change through
the rate envelopes, so the proof runs until no stretch's box changes.
"""

from __future__ import annotations

import itertools

import numpy as np

from drake_cfvol import kernel as K
from drake_cfvol.table import _stretch_envelopes

__all__ = ["pieces", "box_on", "edge_tasks", "prove_edges", "corner_pass"]

#: Halvings of a failing region (in s and along the joint) before it is cut.
MAX_SPLITS = 2
#: Second-order growth allowed between grid poses, m (as in the sweep).
MOTION_TOLERANCE = 0.01


def _lines(st_lo, st_hi, rate, W, i):
    """(a, b) of the lines a + b s whose min/max make the box on stretch i,
    per joint: the stretch bounds, the four rate envelopes, the nominal."""
    Au, Bu, Al, Bl = _stretch_envelopes(st_lo, st_hi, rate)
    r = np.where(np.isfinite(rate), rate, 0.0)
    d = W[i + 1] - W[i]
    zero = np.zeros_like(r)
    a = np.stack([st_hi[i], Au[i], Bu[i], -st_lo[i], Al[i], Bl[i], W[i] - i * d, -(W[i] - i * d)])
    b = np.stack([zero, r, -r, zero, r, -r, d, -d])
    return a, b


def pieces(st_lo, st_hi, rate, W, i) -> np.ndarray:
    """The s where some bound of the box on stretch i may bend: i, every
    crossing of two of its lines inside (i, i+1), i+1 (sorted)."""
    a, b = _lines(st_lo, st_hi, rate, W, i)
    cuts = [float(i), float(i + 1)]
    n = a.shape[0]
    with np.errstate(divide="ignore", invalid="ignore"):
        for p in range(n):
            for q in range(p + 1, n):
                db = b[q] - b[p]
                s = (a[p] - a[q]) / db
                ok = np.isfinite(s) & (db != 0) & (s > i) & (s < i + 1)
                cuts.extend(s[ok].tolist())
    cuts = np.unique(np.round(np.asarray(cuts), 12))
    if len(cuts) <= 2:
        return cuts
    # Keep only the crossings where some bound really bends (most crossings
    # are of lines that are not the smallest or largest there).
    lo, hi = box_on(st_lo, st_hi, rate, W, i, cuts)
    ds = np.diff(cuts)[:, None]
    slope = np.concatenate([np.diff(lo, axis=0) / ds, np.diff(hi, axis=0) / ds], axis=1)
    tol = 1e-9 * (1.0 + np.abs(slope[1:]) + np.abs(slope[:-1]))
    bends = np.any(np.abs(slope[1:] - slope[:-1]) > tol, axis=1)
    return np.concatenate([cuts[:1], cuts[1:-1][bends], cuts[-1:]])


def box_on(st_lo, st_hi, rate, W, i, s) -> tuple[np.ndarray, np.ndarray]:
    """The box at path parameters s (n,) of stretch i (closed), (n, k) each:
    the stretch rule of :func:`drake_cfvol.table.box_at`, evaluated with the
    stretch given (at s = i + 1 too)."""
    Au, Bu, Al, Bl = _stretch_envelopes(st_lo, st_hi, rate)
    r = np.where(np.isfinite(rate), rate, 0.0)
    sc = np.asarray(s, float)[:, None]
    hi = np.minimum(np.minimum(st_hi[i], Au[i] + r * sc), Bu[i] - r * sc)
    lo = -np.minimum(np.minimum(-st_lo[i], Al[i] + r * sc), Bl[i] - r * sc)
    nom = W[i] + (sc - i) * (W[i + 1] - W[i])
    return np.minimum(lo, nom), np.maximum(hi, nom)


def _signs(k: int, j: int) -> np.ndarray:
    """(2^(k-1), k) corner patterns of the joints other than j (1 upper,
    0 lower; column j unused)."""
    rows = np.array(list(itertools.product((0, 1), repeat=k - 1)), np.int64).reshape(-1, k - 1)
    return np.insert(rows, j, 0, axis=1)


def edge_tasks(lo_a, hi_a, lo_b, hi_b, *, skip_flat: bool = True):
    """Every edge of a piece whose box goes linearly from [lo_a, hi_a] to
    [lo_b, hi_b]: (A, B, j, va, vb, sign rows). Joints of zero width at both
    ends need no edge of their own (their edges are corners of the others)."""
    k = len(lo_a)
    A, B, js, va, vb, sig = [], [], [], [], [], []
    for j in range(k):
        if skip_flat and hi_a[j] <= lo_a[j] and hi_b[j] <= lo_b[j]:
            continue
        S = _signs(k, j)
        ca = np.where(S == 1, hi_a, lo_a)
        cb = np.where(S == 1, hi_b, lo_b)
        A.append(ca)
        B.append(cb)
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
    growth = np.einsum("nk,nl,klb->nb", dq, dq, arrays.curvature).max(axis=1) / 8.0 if len(js) else np.zeros(0)
    nts = np.clip(1 + np.ceil(np.sqrt(growth / MOTION_TOLERANCE)), 2, K.MAX_T_SAMPLES).astype(np.int64)
    reach_j = np.where(arrays.revolute, arrays.reach.max(axis=1), 0.0)[js]
    v_step = np.where(reach_j > 0, np.sqrt(8 * MOTION_TOLERANCE / np.maximum(reach_j, 1e-9)), np.inf)
    nvs = np.clip(2 + np.floor((vb - va) / v_step), 2, K.MAX_V_SAMPLES).astype(np.int64)
    return nts, nvs


def _hits(arrays, A, B, js, va, vb, pads) -> np.ndarray:
    if not len(js):
        return np.zeros(0, bool)
    nts, nvs = _grid(arrays, A, B, js, va, vb)
    a = arrays
    return K.regions_hit(np.ascontiguousarray(A), np.ascontiguousarray(B), js, np.ascontiguousarray(va),
                         np.ascontiguousarray(vb), nts, nvs, np.ascontiguousarray(pads, dtype=np.float64),
                         a.parent, a.jtype, a.qidx, a.axis, a.R_PF, a.p_PF, a.R_MB, a.p_MB, a.shapes,
                         a.shape_body, a.verts, a.obstacles, a.obstacle_aabb, a.self_pairs, a.moved_by, a.reach,
                         a.curvature, a.revolute, a.joint_body)


def _stretch_failures(arrays, st_lo, st_hi, rate, W, i, margin):
    """The regions of stretch i's edges that still may collide after
    MAX_SPLITS halvings: a list of (s_a, s_b, j, v_a, v_b, sign row, tests)."""
    cuts = pieces(st_lo, st_hi, rate, W, i)
    lo, hi = box_on(st_lo, st_hi, rate, W, i, cuts)
    # Work items: (s_a, s_b, j, v range, sign row), per piece.
    items = []
    for p in range(len(cuts) - 1):
        A, B, js, va, vb, sig = edge_tasks(lo[p], hi[p], lo[p + 1], hi[p + 1])
        for n in range(len(js)):
            items.append((cuts[p], cuts[p + 1], int(js[n]), va[n], vb[n], sig[n], A[n], B[n]))
    tests = 0
    for depth in range(MAX_SPLITS + 1):
        if not items:
            return [], tests
        A = np.array([it[6] for it in items])
        B = np.array([it[7] for it in items])
        js = np.array([it[2] for it in items], np.int64)
        va = np.array([it[3] for it in items])
        vb = np.array([it[4] for it in items])
        hit = _hits(arrays, A, B, js, va, vb, np.full(len(items), margin))
        tests += len(items)
        failed = [it for it, h in zip(items, hit) if h]
        if depth == MAX_SPLITS or not failed:
            return [it[:6] for it in failed], tests
        # A region whose own corner configurations collide needs no halving.
        ends = []
        for it in failed:
            for c in (it[6], it[7]):
                for v in (it[3], it[4]):
                    q = c.copy()
                    q[it[2]] = v
                    ends.append(q)
        real = arrays.may_collide(np.array(ends), margin).reshape(len(failed), 4).any(axis=1)
        if real.any():
            return [it[:6] for it, r in zip(failed, real) if r], tests
        items = []
        for sa, sb, j, a0, b0, S, _, _ in failed:
            sm = 0.5 * (sa + sb)
            ss = np.array([sa, sm, sb])
            blo, bhi = box_on(st_lo, st_hi, rate, W, i, ss)
            c = np.where(S == 1, bhi, blo)
            for h in range(2):
                v_lo = min(blo[h, j], blo[h + 1, j])
                v_hi = max(bhi[h, j], bhi[h + 1, j])
                v_lo, v_hi = max(v_lo, a0), min(v_hi, b0)
                vm = 0.5 * (v_lo + v_hi)
                for u0, u1 in ((v_lo, vm), (vm, v_hi)):
                    items.append((ss[h], ss[h + 1], j, u0, u1, S, c[h], c[h + 1]))
    return [], tests


def _reaching_joints(workcell, arrays, q, margin) -> np.ndarray:
    """(k,) joints whose motion moves the nearest pair apart at q (Drake's
    clearance query): for a robot body against the scene, the joints that
    move it; for two robot bodies, the joints that move one but not the
    other. All joints if no pair is near."""
    k = len(q)
    rc = workcell.checker.CalcRobotClearance(np.asarray(q, float), max(margin, 0.0) + 0.05)
    d = np.asarray(rc.distances())
    if not d.size:
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


def cut_for(workcell, arrays, st_lo, st_hi, rate, W, i, fail, margin, taken=None, *, corner: bool = False) -> bool:
    """Tightens stretch i's box (in place) to remove a failing edge region.
    ``taken`` holds the (joint, side) pairs already cut this round: those
    are not cut again before the stretch is tested anew. Returns False if
    nothing can be cut."""
    taken = set() if taken is None else taken
    sa, sb, j, va, vb, S = fail
    lo_nom = np.minimum(W[i], W[i + 1])
    hi_nom = np.maximum(W[i], W[i + 1])
    width = st_hi[i] - st_lo[i]
    options = []  # (log-width lost, joint, side, new value)
    if corner:
        pass  # a corner point: every joint sits on a bound; halve one below
    elif va > hi_nom[j] and va < st_hi[i, j]:
        options.append((np.log(width[j] / max(va - st_lo[i, j], 1e-12)), j, 1, np.nextafter(va, -np.inf)))
    if not corner and vb < lo_nom[j] and vb > st_lo[i, j]:
        options.append((np.log(width[j] / max(st_hi[i, j] - vb, 1e-12)), j, -1, np.nextafter(vb, np.inf)))
    sm = 0.5 * (sa + sb)
    blo, bhi = box_on(st_lo, st_hi, rate, W, i, np.array([sm]))
    q = np.where(S == 1, bhi[0], blo[0])
    q[j] = 0.5 * (va + vb)
    reach = _reaching_joints(workcell, arrays, q, margin)
    # Another joint's bound: halfway from the nominal to where the box has
    # it at the failing region (the stretch bound may lie farther out than
    # the rate envelope that holds the box there).
    for l in np.flatnonzero(reach):
        if l == j and not corner:
            continue
        if S[l] == 1 and bhi[0, l] > hi_nom[l]:
            new = hi_nom[l] + 0.5 * (bhi[0, l] - hi_nom[l])
            options.append((np.log(width[l] / max(new - st_lo[i, l], 1e-12)), l, 1, new))
        elif S[l] == 0 and blo[0, l] < lo_nom[l]:
            new = lo_nom[l] - 0.5 * (lo_nom[l] - blo[0, l])
            options.append((np.log(width[l] / max(st_hi[i, l] - new, 1e-12)), l, -1, new))
    if not options:
        return False
    _, l, side, new = min(options, key=lambda o: o[0])
    if (l, side) in taken:
        return True  # this bound moved already this round: test again first
    taken.add((l, side))
    if side > 0:
        st_hi[i, l] = min(st_hi[i, l], new)
    else:
        st_lo[i, l] = max(st_lo[i, l], new)
    return True


def corner_pass(workcell, arrays, st_lo, st_hi, rate, W, margins, *, max_rounds: int = 30) -> dict:
    """Cheap first pass before the proof: the box's corners at the ends and
    middles of every piece of every stretch, checked as points by the
    kernel; a colliding corner moves one bound of one joint whose motion
    reaches the nearest pair halfway to the nominal (as :func:`cut_for`),
    round after round until no corner point collides. It proves nothing
    (the region proof does), but removes most of what the proof would
    otherwise find one region at a time."""
    rate = np.asarray(rate, float)
    n_st = len(W) - 1
    k = W.shape[1]
    pat = np.array(list(itertools.product((0, 1), repeat=k)), np.int64)
    cuts = rounds = 0
    for _ in range(max_rounds):
        rounds += 1
        Q, idx, ss = [], [], []
        for i in range(n_st):
            c = pieces(st_lo, st_hi, rate, W, i)
            s = np.unique(np.concatenate([c, 0.5 * (c[:-1] + c[1:])]))
            lo, hi = box_on(st_lo, st_hi, rate, W, i, s)
            for a in range(len(s)):
                Q.append(np.where(pat == 1, hi[a], lo[a]))
                idx.append(np.full(len(pat), i))
                ss.append(np.full(len(pat), s[a]))
        Q, idx, ss = np.concatenate(Q), np.concatenate(idx), np.concatenate(ss)
        bad = np.zeros(len(Q), bool)
        pads = margins[idx]
        for p in np.unique(pads):
            sel = pads == p
            bad[sel] = arrays.may_collide(Q[sel], p)
        if not bad.any():
            break
        changed = False
        for i in np.unique(idx[bad]):
            taken: set = set()
            rows = np.flatnonzero(bad & (idx == i))
            for r in rows[:: max(1, len(rows) // 8)][:8]:  # a few corners per stretch and round
                S = pat[r % len(pat)]
                q = Q[r]
                j = int(np.argmax(np.abs(q - (W[i] + (ss[r] - i) * (W[i + 1] - W[i])))))
                fail = (ss[r], ss[r], j, q[j], q[j], S)
                before = (st_lo[i].copy(), st_hi[i].copy())
                cut_for(workcell, arrays, st_lo, st_hi, rate, W, i, fail, float(margins[i]), taken, corner=True)
                changed |= not (np.array_equal(before[0], st_lo[i]) and np.array_equal(before[1], st_hi[i]))
            cuts += len(taken)
        if not changed:
            break
    return {"corner_rounds": rounds, "corner_cuts": cuts}


def _signature(st_lo, st_hi, rate, i) -> bytes:
    Au, Bu, Al, Bl = _stretch_envelopes(st_lo, st_hi, rate)
    return np.concatenate([st_lo[i], st_hi[i], Au[i], Bu[i], Al[i], Bl[i]]).tobytes()


def prove_edges(workcell, arrays, st_lo, st_hi, rate, W, margins, proven: dict | None = None, *,
                max_rounds: int = 500) -> dict:
    """Proves every edge of the box at every s, cutting (in place) where a
    region may collide, until every stretch's box is proven as it is.

    Args:
        workcell, arrays: the scene (Drake for the nearest pair; kernel arrays).
        st_lo, st_hi: (g-1, k) stretch boxes, tightened in place.
        rate: (k,) the bounds' rate limit; W: (g, k) the nominal.
        margins: (g-1,) each stretch's margin, m.
        proven: stretch -> the box signature proven last time (updated in
            place): pass the same dict again after other cuts and only the
            stretches whose box changed are proven again.

    Returns:
        stats: ``edge_tests`` (region tests), ``edge_cuts``, ``edge_rounds``,
        ``edge_unproven`` (stretches with a region that could not be cut:
        empty unless the nominal itself fails its margin).
    """
    rate = np.asarray(rate, float)
    proven = {} if proven is None else proven
    n_st = len(W) - 1
    tests = cuts = rounds = 0
    stuck = set()
    while rounds < max_rounds:
        todo = [i for i in range(n_st) if proven.get(i) != _signature(st_lo, st_hi, rate, i)]
        if not todo:
            break
        rounds += 1
        for i in todo:
            for _ in range(max_rounds):  # this stretch until it passes
                fails, t = _stretch_failures(arrays, st_lo, st_hi, rate, W, i, float(margins[i]))
                tests += t
                taken: set = set()
                before = (st_lo[i].copy(), st_hi[i].copy())
                for fail in fails:
                    cut_for(workcell, arrays, st_lo, st_hi, rate, W, i, fail, float(margins[i]), taken)
                cuts += len(taken)
                if not fails or (np.array_equal(before[0], st_lo[i]) and np.array_equal(before[1], st_hi[i])):
                    break
            if fails:
                stuck.add(i)
            proven[i] = _signature(st_lo, st_hi, rate, i)
    return {"edge_tests": tests, "edge_cuts": cuts, "edge_rounds": rounds, "edge_unproven": sorted(stuck)}
