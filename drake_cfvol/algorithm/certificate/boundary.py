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
times, until a 5 x 5 grid of kernel point checks in it finds a point
that may come nearer than the margin (the edge then fails there, and its
other regions are not halved further). Where a configuration of the
failing part really comes nearer than the margin (a 9 x 9 grid of kernel
point checks) it is cut as a point
(:func:`cut_point`); else the region is cut (:func:`cut_for`) by scaling
one bound's deviation from the nominal at both ends of the stretch: the
edge's own joint if the failing part lies off the nominal, else one of the
joints whose motion reaches the nearest pair (Drake's clearance query at
the failing region's centre), each candidate tried at a few scales against
the failing region. Every cut aims SLACK beyond the margin (as far as the
nominal has room, :func:`cut_slacks`), since a region test needs some
clearance to prove anything, and the cut kept is the one that loses the
least log-width, counting what the rate limit then takes from the
neighbouring waypoints. A round cuts the first failing region of each
failing edge, skipping one an earlier cut of the round freed already;
then the same regions' grid points are checked again against the cut box
and a point still nearer is cut again, up to POINT_ROUNDS times (points
are cheap; a region round tests again every edge a cut changed). The rest
is tested again against the cut box next round. Cuts only
tighten: single-joint motions proven by the sweep stay proven. After the
cuts the waypoint boxes are rate-limited again
(:func:`drake_cfvol.algorithm.table.rate_limited`), which may tighten neighbours;
the proof runs until no stretch's box changes.

The regions are :mod:`drake_cfvol.algorithm.certificate.boundary_regions`; the cuts
:mod:`drake_cfvol.algorithm.certificate.cuts`.
"""

from __future__ import annotations

import itertools

import numpy as np

from drake_cfvol.algorithm.certificate.boundary_regions import (
    MAX_SPLITS,
    S_SPLITS,
    _box,
    _Item,
    corner_points,
    edge_tasks,
    regions_may_collide,
)
from drake_cfvol.algorithm.certificate.cuts import cut_for, cut_point, cut_slacks, reaching_joints
from drake_cfvol.algorithm.table import rate_limited
from drake_cfvol.exceptions import ParameterError

__all__ = [
    "prove_boundary",
    "corner_pass",
    "edge_tasks",
    "regions_may_collide",
    "corner_points",
    "reaching_joints",
    "cut_point",
    "cut_slacks",
    "colliding_points",
    "failures",
]


def failures(arrays, lower, upper, nominal, stretches, margins, memo: dict | None = None):
    """The edge regions of the given stretches (``margins``: (g-1,) array,
    m) that still may collide after MAX_SPLITS halvings (a region with a point of its REAL_GRID x REAL_GRID
    grid that may collide is not halved further, nor is the rest of its
    edge). Returns (failed items, region tests run).

    ``memo`` (updated in place) holds the whole edges proven so far: an
    edge whose other joints sit exactly where a proven edge's did, with its
    own range inside that edge's and a margin no larger, is a subset of a
    proven region and is not tested again (cuts only tighten, so after a
    cut on one bound most of a stretch's edges are such subsets). It also
    holds the edges that failed, with their failing regions: an edge asked
    again exactly as it was fails in the same regions, without a test; and,
    for an edge that passed only in pieces, how many halvings along its
    joint it needed (at most START_SPLITS): tested again, it starts from
    that many pieces (automotive path 1's certification: 454k region tests
    instead of 515k)."""
    stretch_tasks: list[tuple] = []
    keys: list[tuple | None] = []
    again: list[_Item] = []
    if memo is None:  # nothing remembered or kept: every edge tested whole, its own root
        for i in stretches:
            A, B, js, va, vb, sig = edge_tasks(lower[i], upper[i], lower[i + 1], upper[i + 1])
            if len(js):
                roots = range(len(keys), len(keys) + len(js))
                keys += [None] * len(js)
                stretch_tasks.append((i, A, B, js, sig, list(zip(range(len(js)), va, vb, roots, [0] * len(js)))))
        return _failures_of(arrays, lower, upper, nominal, stretch_tasks, margins, None, keys, again)
    for i in stretches:
        A, B, js, va, vb, sig = edge_tasks(lower[i], upper[i], lower[i + 1], upper[i + 1])
        if not len(js):
            continue
        first = []  # (edge, joint range, root, depth) of the regions tested first
        # What fixes an edge besides its own joint's range: the stretch, the
        # joint, the other joints' bound pattern and their values at both
        # ends (every edge of the stretch at once).
        rows = np.arange(len(js))
        ends = np.concatenate([A, B], axis=1)
        ends[rows, js] = ends[rows, js + A.shape[1]] = 0.0
        lo0, lo1, hi0, hi1 = lower[i].tolist(), lower[i + 1].tolist(), upper[i].tolist(), upper[i + 1].tolist()
        margin = float(margins[i])
        for n, j in enumerate(js.tolist()):
            key = (i, j, sig[n].tobytes(), ends[n].tobytes())
            # The joint's own range at both ends: the edge is a subset of a
            # proven one if both ranges lie inside (the rule is linear in s).
            lo_j, hi_j = (lo0[j], lo1[j]), (hi0[j], hi1[j])
            known = memo.get(key)
            if (
                known is not None
                and known[0][0] <= lo_j[0]
                and known[0][1] <= lo_j[1]
                and hi_j[0] <= known[1][0]
                and hi_j[1] <= known[1][1]
                and margin <= known[2]
            ):
                continue
            # The same edge failed before exactly as it is now (its result
            # is a function of the key, its own range and the margin): the
            # same regions fail again.
            seen = memo.get(("failed",) + key)
            if seen is not None and seen[0] == lo_j and seen[1] == hi_j and seen[2] == margin:
                again += [
                    _Item(it.i, it.sa, it.sb, it.j, it.va, it.vb, it.S, it.A, it.B, ("again", len(again)))
                    for it in seen[3]
                ]  # a root of its own (_one_per_edge)
                continue
            keys.append((key, lo_j, hi_j, margin))
            # Split along the joint at once as far as this edge needed last
            # time (the pieces cover the same region; after a small cut the
            # whole edge mostly fails again, so its test is saved).
            d = memo.get(("depth",) + key[:3], 0)
            root = len(keys) - 1
            if d == 0:
                first.append((n, va[n], vb[n], root, 0))
                continue
            v = va[n] + (vb[n] - va[n]) * np.arange(2**d + 1) / 2**d
            v[-1] = vb[n]
            first += [(n, v[m], v[m + 1], root, d) for m in range(2**d)]
        stretch_tasks.append((i, A, B, js, sig, first))
    return _failures_of(arrays, lower, upper, nominal, stretch_tasks, margins, memo, keys, again)


def _failures_of(arrays, lower, upper, nominal, stretch_tasks, margins, memo, keys, again):
    """:func:`failures` from its first regions on: tests them, halves the
    failing ones and (with a ``memo``) records each edge's outcome under
    its key in ``keys``."""
    # The first test of every region as arrays (most pass whole): an item
    # object only for those that fail, halved further by _halvings.
    hit, tests = _first_test(arrays, stretch_tasks, margins)
    passed_at: dict = {}
    bad: list[tuple] = []
    at = 0
    for i, A, B, js, sig, first in stretch_tasks:
        for n, u0, u1, root, d in first:
            if hit[at]:
                bad.append((i, n, u0, u1, root, d, js, sig, A, B))
            elif passed_at.get(root, MAX_SPLITS + 1) > d:
                passed_at[root] = d
            at += 1
    failed, more, deeper = _halvings(arrays, lower, upper, nominal, _Regions.of_first(bad, lower.shape[1]), margins)
    tests += more
    for r, d in deeper.items():
        passed_at[r] = min(passed_at.get(r, MAX_SPLITS + 1), d)
    if memo is None:
        return failed + again, tests
    by_root: dict = {}
    for it in failed:
        by_root.setdefault(it.root, []).append(it)
    for r, (key, lo_j, hi_j, m) in enumerate(keys):
        if passed_at.get(r, 0) > 0 and r not in by_root:  # (an edge that passed whole needs no entry)
            memo[("depth",) + key[:3]] = min(passed_at[r], START_SPLITS)
        if r in by_root:
            memo[("failed",) + key] = (lo_j, hi_j, m, by_root[r])
        else:
            memo[key] = (lo_j, hi_j, m)
            memo.pop(("failed",) + key, None)  # a failure of a wider range: stale
    return failed + again, tests


#: Rounds of point checks and cuts on a round's failing regions before the
#: region tests run again (see :func:`prove_boundary`).
POINT_ROUNDS = 8

#: The most halvings along the joint an edge tested again starts with (the
#: depth at which it passed last time): 2^START_SPLITS pieces at most.
START_SPLITS = 3

#: A failing region whose REAL_GRID x REAL_GRID grid of points (s and the
#: joint) has one that may collide fails for real: it is not halved
#: further (automotive path 2 at epsilon 1e-4: 757k region tests against
#: 1.18M with the region's four corners only).
REAL_GRID = 5


def _first_test(arrays, stretch_tasks, margins):
    """The region test of every first region of ``stretch_tasks`` ((i, A,
    B, js, sig, first) per stretch, ``first`` its regions as (edge, va, vb,
    root, depth)), in their order: (hit (n,), tests)."""
    parts = [
        (A[[f[0] for f in first]], B[[f[0] for f in first]], js[[f[0] for f in first]], first, i)
        for i, A, B, js, sig, first in stretch_tasks
        if first
    ]
    if not parts:
        return np.zeros(0, bool), 0
    A = np.concatenate([p[0] for p in parts])
    B = np.concatenate([p[1] for p in parts])
    js = np.concatenate([p[2] for p in parts])
    va = np.array([f[1] for p in parts for f in p[3]], float)
    vb = np.array([f[2] for p in parts for f in p[3]], float)
    pads = np.concatenate([np.full(len(p[3]), float(margins[p[4]])) for p in parts])
    return regions_may_collide(arrays, A, B, js, va, vb, pads), len(js)


class _Regions:
    """Edge regions as arrays, one row each (what _Item holds for one): the
    halvings make about a million of them on the mesh robot's proof."""

    __slots__ = ("I", "SA", "SB", "J", "VA", "VB", "S", "A", "B", "root", "depth", "halved")

    def __init__(self, I, SA, SB, J, VA, VB, S, A, B, root, depth, halved=None):
        self.I, self.SA, self.SB, self.J, self.VA, self.VB = I, SA, SB, J, VA, VB
        self.S, self.A, self.B, self.root, self.depth = S, A, B, root, depth
        # True: a half along the joint of a region whose grid points were
        # all free (its even grid columns lie on the parent's).
        self.halved = np.zeros(len(I), bool) if halved is None else halved

    @classmethod
    def of_first(cls, bad: list[tuple], k: int) -> "_Regions":
        """The failing first regions: (i, edge row n, va, vb, root, depth, js,
        sig, A, B) each, whole stretches in s."""
        if not bad:
            z, zk = np.zeros(0), np.zeros((0, k))
            return cls(
                z.astype(np.int64),
                z,
                z,
                z.astype(np.int64),
                z,
                z,
                zk.astype(np.int64),
                zk,
                zk,
                z.astype(np.int64),
                z.astype(np.int64),
            )
        I = np.array([b[0] for b in bad], np.int64)
        rows = [b[1] for b in bad]
        return cls(
            I,
            I.astype(float),
            (I + 1).astype(float),
            np.array([b[6][n] for b, n in zip(bad, rows)], np.int64),
            np.array([b[2] for b in bad], float),
            np.array([b[3] for b in bad], float),
            np.array([b[7][n] for b, n in zip(bad, rows)]),
            np.array([b[8][n] for b, n in zip(bad, rows)], float),
            np.array([b[9][n] for b, n in zip(bad, rows)], float),
            np.array([b[4] for b in bad], np.int64),
            np.array([b[5] for b in bad], np.int64),
        )

    @classmethod
    def of_items(cls, items: list[_Item]) -> "_Regions":
        """The rows of these items, in order (int roots)."""
        return cls(
            np.array([it.i for it in items], np.int64),
            np.array([it.sa for it in items], float),
            np.array([it.sb for it in items], float),
            np.array([it.j for it in items], np.int64),
            np.array([it.va for it in items], float),
            np.array([it.vb for it in items], float),
            np.array([it.S for it in items]),
            np.array([it.A for it in items], float),
            np.array([it.B for it in items], float),
            np.array([it.root for it in items], np.int64),
            np.array([it.depth for it in items], np.int64),
        )

    def __len__(self) -> int:
        return len(self.I)

    def take(self, rows) -> "_Regions":
        return _Regions(*(getattr(self, f)[rows] for f in self.__slots__))

    def items(self) -> list[_Item]:
        """One _Item per row (for the few that fail)."""
        return [
            _Item(
                int(self.I[r]),
                float(self.SA[r]),
                float(self.SB[r]),
                int(self.J[r]),
                float(self.VA[r]),
                float(self.VB[r]),
                self.S[r],
                self.A[r].copy(),
                self.B[r].copy(),
                int(self.root[r]),
                int(self.depth[r]),
            )
            for r in range(len(self))
        ]


def _halvings(arrays, lower, upper, nominal, items: "_Regions", margins):
    """Halves the failing regions ``items`` (each failed its test already,
    the caller's; see :func:`failures`), testing the halves, until each
    whole edge (a region's ``root``) is proven or has a failing region: the
    shallowest halving's first, in order (the others of that edge are not
    halved further). A region's ``depth`` counts the halvings from its
    whole edge: along the joint first, in s and the joint past MAX_SPLITS -
    S_SPLITS, none past MAX_SPLITS. Returns (failed items, region tests
    run, root -> the smallest depth at which one of its pieces passed)."""
    tests = 0
    failed: list = []
    failed_roots: set = set()
    passed_at: dict = {}
    hit = np.ones(len(items), bool)  # the caller tested these already: every one failed
    while len(items):
        ok = np.flatnonzero(~hit)
        if len(ok):
            # The smallest passing depth per root.
            order = np.lexsort((items.depth[ok], items.root[ok]))
            roots, first = np.unique(items.root[ok][order], return_index=True)
            for r, d in zip(roots.tolist(), items.depth[ok][order][first].tolist()):
                if passed_at.get(r, MAX_SPLITS + 1) > d:
                    passed_at[r] = d
        bad = items.take(np.flatnonzero(hit))
        deep = bad.depth >= MAX_SPLITS
        if deep.any():
            out = bad.take(np.flatnonzero(deep))
            failed += out.items()
            failed_roots.update(out.root.tolist())
        bad = bad.take(np.flatnonzero(~deep))
        if not len(bad):
            break
        real = _grid_hits(arrays, lower, upper, nominal, bad, margins, REAL_GRID)
        if real.any():
            out = bad.take(np.flatnonzero(real))
            failed += out.items()
            failed_roots.update(out.root.tolist())
        # An edge with a failing region is failed: a round cuts its first
        # failing region only (prove_boundary), so its others are not halved.
        rest = bad.take(np.flatnonzero(~real & ~np.isin(bad.root, np.array(sorted(failed_roots), np.int64))))
        items = _halves(lower, upper, nominal, rest)
        if not len(items):
            break
        hit = _test_regions(arrays, items, margins)
        tests += len(items)
    return failed, tests, passed_at


def _test_regions(arrays, r: "_Regions", margins) -> np.ndarray:
    return regions_may_collide(arrays, r.A, r.B, r.J, r.VA, r.VB, np.asarray(margins, float)[r.I])


def _halves(lower, upper, nominal, r: "_Regions") -> "_Regions":
    """Each region's two halves along the joint (depth < MAX_SPLITS -
    S_SPLITS: the region's hull of poses bulges inwards by about reach *
    width^2 / 8, the usual false alarm), else its halves in s, each halved
    along the joint; in the regions' order, depth one more."""
    by_joint = r.depth < MAX_SPLITS - S_SPLITS
    parent: list[np.ndarray] = []
    sub: list[np.ndarray] = []
    cols: dict[str, list[np.ndarray]] = {f: [] for f in _Regions.__slots__}

    def add(rows, sub_id, SA, SB, VA, VB, A, B):
        parent.append(rows)
        sub.append(np.full(len(rows), sub_id))
        halved = np.full(len(rows), sub_id < 2)
        for f, v in (("SA", SA), ("SB", SB), ("VA", VA), ("VB", VB), ("A", A), ("B", B), ("halved", halved)):
            cols[f].append(v)
        for f in ("I", "J", "S", "root"):
            cols[f].append(getattr(r, f)[rows])
        cols["depth"].append(r.depth[rows] + 1)

    jr = np.flatnonzero(by_joint)
    if len(jr):
        vm = 0.5 * (r.VA[jr] + r.VB[jr])
        add(jr, 0, r.SA[jr], r.SB[jr], r.VA[jr], vm, r.A[jr], r.B[jr])
        add(jr, 1, r.SA[jr], r.SB[jr], vm, r.VB[jr], r.A[jr], r.B[jr])
    sr = np.flatnonzero(~by_joint)
    if len(sr):
        I, J = r.I[sr], r.J[sr]
        ss = np.stack([r.SA[sr], 0.5 * (r.SA[sr] + r.SB[sr]), r.SB[sr]], axis=1)  # (m, 3)
        lo, hi, _ = _box(lower, upper, nominal, I[:, None], ss)  # (m, 3, k)
        c = np.where((r.S[sr] == 1)[:, None, :], hi, lo)
        rows = np.arange(len(sr))
        for half in range(2):
            lo_a, lo_b, hi_a, hi_b = lo[rows, half, J], lo[rows, half + 1, J], hi[rows, half, J], hi[rows, half + 1, J]
            v_lo = np.maximum(np.minimum(lo_a, lo_b), r.VA[sr])
            v_hi = np.minimum(np.maximum(hi_a, hi_b), r.VB[sr])
            # The edge's range over this half misses the piece's (the bound
            # is linear in s): no point of the edge lies here. An inverted
            # range would be tested as if it did, and fail.
            keep = ~(v_lo > v_hi)
            at = np.flatnonzero(keep)
            vm = 0.5 * (v_lo[at] + v_hi[at])
            for which, (u0, u1) in enumerate(((v_lo[at], vm), (vm, v_hi[at]))):
                add(
                    sr[at],
                    2 + 2 * half + which,
                    ss[at, half],
                    ss[at, half + 1],
                    u0,
                    u1,
                    c[at, half],
                    c[at, half + 1],
                )
    if not parent:
        return r.take(np.zeros(0, np.int64))
    order = np.lexsort((np.concatenate(sub), np.concatenate(parent)))
    return _Regions(*(np.concatenate(cols[f])[order] for f in _Regions.__slots__))


def _grid_hits(arrays, lower, upper, nominal, r: "_Regions", margins, n: int) -> np.ndarray:
    """(m,) True where a point of the region's n x n grid (s and the joint)
    on the box's edge may come nearer than its margin (:func:`colliding_points`'
    points, tested as one batch per margin)."""
    Q, owner, _, col = _edge_grid(lower, upper, nominal, r.I, r.J, r.SA, r.SB, r.VA, r.VB, r.S, n)
    if n % 2 == 1 and r.halved.any():
        # A half along the joint of a region whose points were all free:
        # its even columns are the parent's points (to rounding), checked.
        new = ~(r.halved[owner] & (col % 2 == 0))
        Q, owner = Q[new], owner[new]
    pads = np.asarray(margins, float)[r.I][owner]
    bad = np.zeros(len(Q), bool)
    for p in np.unique(pads):
        sel = pads == p
        bad[sel] = arrays.may_collide(Q[sel], float(p))
    out = np.zeros(len(r), bool)
    out[owner[bad]] = True
    return out


def _edge_grid(lower, upper, nominal, I, J, SA, SB, VA, VB, S, n: int):
    """The n x n grid points (s-major) of each region on its box edge, those
    outside the box at their s left out: (Q (P, k), owner (P,), s (P,), the
    point's column along the joint (P,))."""
    u = np.linspace(0.0, 1.0, n)
    s = SA[:, None] + u[None] * (SB - SA)[:, None]  # (F, n)
    v = VA[:, None] + u[None] * (VB - VA)[:, None]
    lo, hi, _ = _box(lower, upper, nominal, I[:, None], s)  # (F, n, k)
    c = np.where(S[:, None] == 1, hi, lo)
    F = len(I)
    Q = np.repeat(c[:, :, None], n, axis=2)  # (F, s, v, k)
    Q[np.arange(F)[:, None, None], np.arange(n)[None, :, None], np.arange(n)[None, None], J[:, None, None]] = v[
        :, None, :
    ]
    rows = np.arange(F)
    lo_j, hi_j = lo[rows, :, J], hi[rows, :, J]  # (F, n)
    ok = (v[:, None, :] >= lo_j[:, :, None]) & (v[:, None, :] <= hi_j[:, :, None])
    owner, _, col = np.nonzero(ok)
    return Q[ok], owner, np.broadcast_to(s[:, :, None], ok.shape)[ok], col


def corner_pass(
    workcell, arrays, lower, upper, nominal, rate, margins, slacks=None, *, per_stretch: int = 4, max_rounds: int = 50
) -> dict:
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
                cut_point(
                    workcell,
                    arrays,
                    lower,
                    upper,
                    nominal,
                    rate,
                    int(i),
                    float(s[r // len(pat)]),
                    Q[r],
                    float(margins[i]),
                    float(slacks[i]),
                    taken,
                )
        cuts += len(taken)
        lower[:], upper[:] = rate_limited(lower, upper, nominal, rate)
    return {"corner_rounds": rounds, "corner_cuts": cuts}


def colliding_points(arrays, lower, upper, nominal, fails, margins, slacks, n: int = 9):
    """For each failing region, a configuration of the box's edge in it
    that may collide, (s, q), or None: an n x n grid over the region (s
    and joint j; the first colliding point in s-major order), points
    outside the box at their s left out. All regions' points in one batch
    per margin."""
    out: list[tuple[float, np.ndarray] | None] = [None] * len(fails)
    if not fails:
        return out
    I = np.array([f.i for f in fails], np.int64)
    ab = np.array([[f.sa, f.sb, f.va, f.vb] for f in fails], float)
    Q, owner, where, _ = _edge_grid(
        lower,
        upper,
        nominal,
        I,
        np.array([f.j for f in fails], np.int64),
        ab[:, 0],
        ab[:, 1],
        ab[:, 2],
        ab[:, 3],
        np.array([f.S for f in fails]),
        n,
    )
    pads = (margins[I] + slacks[I])[owner]
    bad = np.zeros(len(Q), bool)
    for p in np.unique(pads):
        sel = pads == p
        bad[sel] = arrays.may_collide(Q[sel], float(p))
    for m in np.flatnonzero(bad):
        if out[owner[m]] is None:
            out[owner[m]] = (float(where[m]), Q[m].copy())
    return out


def _one_per_edge(fails):
    """The first failing region of each whole edge (in the order found:
    shallowest halving first). A cut changes its stretch's box, so the
    edge's other failing regions are stale: they were mostly cut by a key
    already taken (automotive path 2: 12,799 failing regions of 1,580
    edges computed for 559 cuts in the first round). Whatever still fails
    is found again, against the cut box, in the next round."""
    seen, out = set(), []
    for it in fails:
        if (it.i, it.root) not in seen:
            seen.add((it.i, it.root))
            out.append(it)
    return out


def _signature(lower, upper, i) -> bytes:
    return np.concatenate([lower[i], lower[i + 1], upper[i], upper[i + 1]]).tobytes()


def prove_boundary(
    workcell,
    arrays,
    lower,
    upper,
    nominal,
    rate,
    margins,
    proven: dict | None = None,
    *,
    max_rounds: int = 200,
    memo: dict | None = None,
) -> dict:
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
        fails, t = failures(arrays, lower, upper, nominal, todo, margins, memo)
        tests += t
        fails = _one_per_edge(fails)
        failing = {f.i for f in fails}
        for i in todo:
            if i not in failing:  # a failing one is asked again, even if its cut changed nothing
                proven[i] = _signature(lower, upper, i)
        stuck = set()
        round_cuts = 0
        todo_fails = fails
        # The failing regions' edge points are checked again after the cuts
        # and cut again, up to POINT_ROUNDS times, before the region tests
        # run again: what the next round's tests would find there, points
        # find, without testing every edge the cuts changed (automotive
        # path 1: 262k region tests instead of 455k, in 12 rounds instead of 24).
        for point_round in range(POINT_ROUNDS):
            points = colliding_points(arrays, lower, upper, nominal, todo_fails, margins, slacks)
            if point_round > 0:
                found = [(f, p) for f, p in zip(todo_fails, points) if p is not None]
                if not found:
                    break
                todo_fails, points = [f for f, _ in found], [p for _, p in found]
            round_taken: set = set()
            for fail, hit in zip(todo_fails, points):
                if fail.i in stuck:
                    continue
                box = (workcell, arrays, lower, upper, nominal, rate)
                room = (float(margins[fail.i]), float(slacks[fail.i]), round_taken)
                if hit is not None:
                    # A real collision on the edge: cut as at a corner, the edge's
                    # own joint one of the candidates.
                    cut_point(*box, fail.i, hit[0], hit[1], *room, own=fail.j)
                elif not cut_for(*box, fail, *room):
                    stuck.add(fail.i)
            round_cuts += len(round_taken)
            lower[:], upper[:] = rate_limited(lower, upper, nominal, rate)
        for i in stuck:
            # Nothing cut passes: the region sits on the nominal, which comes
            # nearer than this stretch's margin between the points where
            # stretch_margins proved it. Lower the margin (as certification does).
            if margins[i] == 0.0:
                raise ParameterError(
                    f"boundary proof: the nominal of stretch {i} may collide between its waypoints; the path is "
                    "not collision-free there (plan with a finer max_step)."
                )
            margins[i] = 0.5 * margins[i] if margins[i] > 1e-4 else 0.0
            proven.pop(i, None)
            lowered += 1
        cuts += round_cuts
        new_lo, new_hi = rate_limited(lower, upper, nominal, rate)
        lower[:], upper[:] = new_lo, new_hi
    unproven = [i for i in range(n_st) if proven.get(i) != _signature(lower, upper, i)]
    return {
        "edge_tests": tests,
        "edge_cuts": cuts,
        "edge_rounds": rounds,
        "margins_lowered": lowered,
        "unproven": unproven,
    }
