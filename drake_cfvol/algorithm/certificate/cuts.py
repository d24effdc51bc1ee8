"""Cuts that free a failing region or a colliding point of a certified box:
scale one bound's (or a group's) deviation from the nominal at both ends
of a stretch, or at the nearer one, and keep the cut that loses the least
log-width (the rate limit's effect on the neighbours counted). See
:mod:`drake_cfvol.algorithm.certificate.boundary`.
"""

from __future__ import annotations

import functools

import numpy as np

from drake_cfvol.algorithm.certificate.boundary_regions import _box, _Item, _test, regions_may_collide

__all__ = ["reaching_joints", "cut_point", "cut_slacks"]


#: Scales of a bound's deviation tried by a cut, largest first.
CUT_SCALES = (0.95, 0.9, 0.8, 0.7, 0.6, 0.5, 0.4, 0.3, 0.2, 0.1, 0.0)


#: Room a cut leaves beyond the margin, m, so the region tests (whose grid
#: and growth bound need some clearance to prove anything) can pass.
SLACK = 0.02


#: Bisection steps that refine a cut's passing scale toward the failing one.
REFINE_STEPS = 3


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
    column = _columns(tuple(int(x) for x in arrays.body_indices))
    a = column.get(int(rc.robot_indices()[n]))
    b = column.get(int(rc.other_indices()[n]))
    ma = arrays.moved_by[:, a] if a is not None else np.zeros(k, bool)
    if b is not None and str(rc.collision_types()[n]).endswith("kSelfCollision"):
        return ma != arrays.moved_by[:, b]
    return ma.copy()


@functools.lru_cache(maxsize=16)
def _columns(body_indices: tuple[int, ...]) -> dict[int, int]:
    """The robot's body index -> its column in the kernel's arrays (the
    certificate asks for the nearest pair's bodies thousands of times)."""
    return {b: c for c, b in enumerate(body_indices)}


def _scaled(lower, upper, nominal, i, moves):
    """Copies of stretch i's waypoint bounds with the deviation of each
    (joint, side, lam) of ``moves`` scaled by lam at both ends:
    ((lo_i, lo_i1), (hi_i, hi_i1))."""
    lo, hi = lower[i : i + 2].copy(), upper[i : i + 2].copy()
    nom = nominal[i : i + 2]
    for l, side, lam in moves:
        if side > 0:
            hi[:, l] = nom[:, l] + lam * (hi[:, l] - nom[:, l])
        else:
            lo[:, l] = nom[:, l] - lam * (nom[:, l] - lo[:, l])
    return lo, hi


def _width_loss(lower, upper, nominal, rate, i, lo, hi):
    """Log-width the whole table loses if stretch i's two waypoint boxes
    became lo, hi (:func:`_width_losses` of one)."""
    return float(_width_losses(lower, upper, nominal, rate, i, lo[None], hi[None])[0])


def _width_losses(lower, upper, nominal, rate, i, LO, HI) -> np.ndarray:
    """(n,): per candidate, the log-width the whole table loses if stretch
    i's two waypoint boxes became LO[c], HI[c] ((n, 2, k) each): their own
    loss and what the rate limit then takes from the waypoints around them
    (:func:`drake_cfvol.algorithm.table.rate_limited`, applied from the two
    changed rows; the rest is rate-limited already). Every candidate in one
    array pass."""
    g = len(nominal)
    n = len(LO)
    lo_f = np.repeat(lower[None], n, axis=0)
    hi_f = np.repeat(upper[None], n, axis=0)
    lo_f[:, i : i + 2] = np.maximum(lo_f[:, i : i + 2], LO)
    hi_f[:, i : i + 2] = np.minimum(hi_f[:, i : i + 2], HI)
    lim = np.isfinite(rate)
    if lim.any():
        m = np.arange(g)[:, None]
        for e in (i, i + 1):
            d = np.abs(m - e) * np.where(lim, rate, 0.0)
            hi_f = np.where(lim, np.minimum(hi_f, hi_f[:, e : e + 1] + d), hi_f)
            lo_f = np.where(lim, np.maximum(lo_f, lo_f[:, e : e + 1] - d), lo_f)
    lo_f = np.minimum(lo_f, nominal)
    hi_f = np.maximum(hi_f, nominal)
    w0 = np.maximum(upper - lower, 1e-12)
    w1 = np.maximum(hi_f - lo_f, 1e-12)
    return np.log(w0 / w1).reshape(n, -1).sum(axis=1)


def _scaled_many(lower, upper, nominal, i, members, sides, lams):
    """:func:`_scaled` for many scales at once: the joints ``members``,
    each on its side ``sides[l]``, all scaled by each lam of ``lams`` (n,):
    (lo, hi), (n, 2, k) each (the same arithmetic, element by element)."""
    n = len(lams)
    lo = np.repeat(lower[None, i : i + 2], n, axis=0)
    hi = np.repeat(upper[None, i : i + 2], n, axis=0)
    nom = nominal[i : i + 2]
    lam = np.asarray(lams, float)[:, None]
    for l in members:
        if sides[l] > 0:
            hi[:, :, l] = nom[:, l] + lam * (hi[:, :, l] - nom[:, l])
        else:
            lo[:, :, l] = nom[:, l] - lam * (nom[:, l] - lo[:, :, l])
    return lo, hi


def _edge_regions(fail: _Item, lo, hi, pad, arrays) -> np.ndarray:
    """(n,) True where the failing region's edge, its stretch's waypoint
    boxes replaced by lo[n], hi[n] ((n, 2, k) each), may still come nearer
    than ``pad``: the other joints on the corner path of sign row fail.S
    between fail.sa and fail.sb."""
    t = (np.array([fail.sa, fail.sb]) - fail.i)[None, :, None]
    a_lo = (1 - t) * lo[:, 0:1] + t * lo[:, 1:2]
    a_hi = (1 - t) * hi[:, 0:1] + t * hi[:, 1:2]
    ca = np.where(fail.S == 1, a_hi, a_lo)
    n = len(lo)
    return regions_may_collide(
        arrays,
        ca[:, 0],
        ca[:, 1],
        np.full(n, fail.j, np.int64),
        np.full(n, fail.va),
        np.full(n, fail.vb),
        np.full(n, float(pad)),
    )


def _joint_scale_options(arrays, lower, upper, nominal, rate, fail: _Item, reach, pad: float) -> list:
    """Cut options (loss, lo, hi, key) of a failing region: each other joint
    on its bound in the region whose motion reaches the nearest pair, and
    all of them together (a collision that two bounds make at once), each
    at CUT_SCALES of its deviation, the largest passing scale bisected
    toward the failing one above it; the region must keep ``pad``. All
    candidates' scales go to the kernel in one batch, each bisection step
    in another."""
    i, j = fail.i, fail.j
    group = [int(l) for l in np.flatnonzero(reach) if l != j]
    sides = {l: 1 if fail.S[l] == 1 else -1 for l in group}
    members_of = dict([((l, sides[l]), [l]) for l in group] + ([((-1, 0), group)] if len(group) > 1 else []))
    if not members_of:
        return []
    lams = np.array(CUT_SCALES)
    keys: list[tuple[int, int]] = []
    lo_parts: list[np.ndarray] = []
    hi_parts: list[np.ndarray] = []
    lam_parts: list[np.ndarray] = []
    for key, members in members_of.items():
        lo, hi = _scaled_many(lower, upper, nominal, i, members, sides, lams)
        changed = ~(np.all(lo == lower[i : i + 2], axis=(1, 2)) & np.all(hi == upper[i : i + 2], axis=(1, 2)))
        keys += [key] * int(changed.sum())
        lo_parts.append(lo[changed])
        hi_parts.append(hi[changed])
        lam_parts.append(lams[changed])
    if not keys:
        return []
    LO, HI, LAM = np.concatenate(lo_parts), np.concatenate(hi_parts), np.concatenate(lam_parts)
    ok = ~_edge_regions(fail, LO, HI, pad, arrays)
    best_l, failing = {}, {}  # key -> (passing scale, lo, hi); key -> largest failing scale
    for n, key in enumerate(keys):
        if key in best_l:
            continue
        if ok[n]:  # scales run largest first: the first pass is the best of the list
            best_l[key] = (LAM[n], LO[n], HI[n])
        else:
            failing[key] = LAM[n]
    # Cut no deeper than needed: bisect each passing scale toward the
    # failing one above it (as cut_point does), all keys in one batch.
    bracket = {key: (failing.get(key, 1.0), best_l[key][0]) for key in best_l}
    for _ in range(REFINE_STEPS if bracket else 0):
        mids = {key: 0.5 * (f + p_) for key, (f, p_) in bracket.items()}
        tried = [_scaled_many(lower, upper, nominal, i, members_of[key], sides, [lam]) for key, lam in mids.items()]
        good = ~_edge_regions(
            fail, np.concatenate([t[0] for t in tried]), np.concatenate([t[1] for t in tried]), pad, arrays
        )
        for (key, (lo, hi)), gd in zip(zip(mids, tried), good):
            f, p_ = bracket[key]
            if gd:
                bracket[key] = (f, mids[key])
                best_l[key] = (mids[key], lo[0], hi[0])
            else:
                bracket[key] = (mids[key], p_)
    if not best_l:
        return []
    found = [(lo, hi, (i, int(l), side) if l >= 0 else (i, -2, 0)) for (l, side), (_, lo, hi) in best_l.items()]
    losses = _width_losses(
        lower, upper, nominal, rate, i, np.array([f[0] for f in found]), np.array([f[1] for f in found])
    )
    return [(float(loss), lo, hi, key) for loss, (lo, hi, key) in zip(losses, found)]


def cut_for(
    workcell, arrays, lower, upper, nominal, rate, fail: _Item, margin: float, slack: float, taken: set
) -> bool:
    """Tightens the waypoint boxes of a failing region's stretch (in place)
    so that the region, recomputed, passes: the candidates are the edge's
    own joint (its failing range off the nominal cut away) and every joint
    on its bound in the region whose motion reaches the nearest pair, each
    at CUT_SCALES of its deviation, the largest passing scale then bisected
    REFINE_STEPS times toward the failing one above it (no deeper than the
    region test needs); the passing candidate that loses the least width
    is applied; if none passes, the whole stretch box moves
    halfway to the nominal. ``taken`` holds the (stretch, joint, side)
    already cut this round (not cut again before the stretch is tested
    anew). Returns False (nothing cut) only if the region on the nominal
    itself fails the margin."""
    i, j = fail.i, fail.j
    if taken and not _edge_regions(fail, lower[None, i : i + 2], upper[None, i : i + 2], margin, arrays)[0]:
        return True  # an earlier cut of this round freed the region already
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
    options += _joint_scale_options(arrays, lower, upper, nominal, rate, fail, reach, margin + slack)
    options = [
        o for o in options if not (np.array_equal(o[1], lower[i : i + 2]) and np.array_equal(o[2], upper[i : i + 2]))
    ]
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
        nom2 = nominal[i : i + 2]
        lo = nom2 - 0.5 * (nom2 - lower[i : i + 2])
        hi = nom2 + 0.5 * (upper[i : i + 2] - nom2)
        options.append((0.0, lo, hi, key))
    _, lo, hi, key = min(options, key=lambda o: o[0])
    if key in taken:
        return True  # this bound moved already this round: test again first
    taken.add(key)
    lower[i : i + 2] = np.maximum(lower[i : i + 2], lo)
    upper[i : i + 2] = np.minimum(upper[i : i + 2], hi)
    return True


def _variants(lower, upper, nominal, i, t, moves):
    """Ways to scale, at s = i + t, the deviations from the nominal of the
    (joint, side, lam) ``moves`` (each deviation at s becomes lam times
    what it was): both ends of stretch i scaled by lam, or only the nearer
    end, moved just enough (when that is possible). Returns a list of
    (lo, hi), stretch i's two waypoint boxes, (2, k) each."""
    out = [_scaled(lower, upper, nominal, i, moves)]
    nom2 = nominal[i : i + 2]
    e = 0 if t <= 0.5 else 1
    w = max((1 - t) if e == 0 else t, 1e-12)
    lo, hi = lower[i : i + 2].copy(), upper[i : i + 2].copy()
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
        # Every group at every scale in one batch (rows group-major, scales
        # largest first): x = nom + lam (q - nom) on the group's joints.
        lams = np.array(CUT_SCALES)
        n_l = len(lams)
        Q = np.repeat(q[None], len(cands) * n_l, axis=0)
        for g, group in enumerate(cands):
            Q[g * n_l : (g + 1) * n_l, group] = nom[group] + lams[:, None] * (q[group] - nom[group])
        ok = ~arrays.may_collide(Q, margin + slack).reshape(len(cands), n_l)
        bracket: dict[tuple, tuple[float, float]] = {}  # group -> (largest failing scale, largest passing scale)
        for group, row in zip(cands, ok):
            key = tuple(group)
            if key in bracket or not row.any():
                continue
            first = int(np.argmax(row))  # scales run largest first
            bracket[key] = (float(lams[first - 1]) if first else 1.0, float(lams[first]))
        keys = list(bracket)
        for _ in range(REFINE_STEPS if keys else 0):  # bisect each passing scale toward the failing one
            X = np.repeat(q[None], len(keys), axis=0)
            mids = [0.5 * sum(bracket[key]) for key in keys]
            for r, (key, mid) in enumerate(zip(keys, mids)):
                X[r, list(key)] = nom[list(key)] + mid * (q[list(key)] - nom[list(key)])
            good = ~arrays.may_collide(X, margin + slack)
            for key, mid, gd in zip(keys, mids, good):
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
    variants = [(lo, hi, (i,) + key) for key, mv in moves for lo, hi in _variants(lower, upper, nominal, i, t, mv)]
    options = []
    if variants:
        losses = _width_losses(
            lower, upper, nominal, rate, i, np.array([v[0] for v in variants]), np.array([v[1] for v in variants])
        )
        options = [(float(loss), lo, hi, key) for loss, (lo, hi, key) in zip(losses, variants)]
    if not options:
        nom2 = nominal[i : i + 2]
        options.append((0.0, nom2 - 0.5 * (nom2 - lower[i : i + 2]), nom2 + 0.5 * (upper[i : i + 2] - nom2), (i, -1)))
    _, lo, hi, key = min(options, key=lambda o: o[0])
    if key in taken:
        return
    taken.add(key)
    lower[i : i + 2] = np.maximum(lower[i : i + 2], lo)
    upper[i : i + 2] = np.minimum(upper[i : i + 2], hi)


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
