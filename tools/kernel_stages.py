"""Where the kernel's time goes, stage by stage, on one thread: the batch
check (``Workcell.collision_free``) per configuration and the region test
(bounding, certification and online proofs) per test.

Each stage is timed by running the kernel's own compiled stage functions up
to it and no further (the loops below mirror ``batch._check_blocks`` and
``regions._region_hits``; at the last stage the verdicts must equal the
kernel's, or the mirror has drifted and the script stops). A stage's time
is the difference of two cumulative medians. The region tests are the
edges of every stretch's box of the path's bounds (what a boundary proof
tests first), at clearance ``--pad``.

    tools/dev.sh python tools/kernel_stages.py [--samples 100000] [--repeats 3]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numba
import numpy as np
from numba import njit

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import drake_cfvol as cf  # noqa: E402
from benchmarks.kernel import samples_in_bounds  # noqa: E402
from drake_cfvol.algorithm.certificate.boundary_regions import _grid, edge_tasks  # noqa: E402
from drake_cfvol.kernel import batch as Bt  # noqa: E402
from drake_cfvol.kernel import regions as Rg  # noqa: E402
from drake_cfvol.kernel.blocks import NB, _fk_scratch, fk_block  # noqa: E402
from drake_cfvol.kernel.heightfield import new_scratch, no_height_field  # noqa: E402
from drake_cfvol.kernel.swept import region_quick_free  # noqa: E402
from drake_cfvol.kernel.types import MAX_T_SAMPLES, MAX_V_SAMPLES  # noqa: E402

CASES = (("automotive", "path1"), ("aerospace", "path2"))
BATCH_STAGES = (
    "forward kinematics",
    "cover balls placed",
    "broad phase: obstacles",
    "broad phase: self pairs",
    "exact (GJK)",
)
REGION_STAGES = ("quick pass (lever-arm balls)", "grid poses", "shapes vs the scene", "self pairs")


@njit
def _batch_to(Q, m, blk, pad, stage, counts):
    """batch._check_blocks up to ``stage`` (Q in the order the kernel
    takes it: coherent_order); counts: undecided lanes and their
    candidates (at stage 3)."""
    N, k = Q.shape
    B, S, O, P = m.chain.parent.shape[0], m.shapes.shape[0], m.obstacles.shape[0], m.shape_pairs.shape[0]
    ws = _fk_scratch(B, k)
    X = ws[0]
    L = Bt._lanes(S, blk.balls.shape[0], S * O + P)
    E = Bt._exact(B, S, O, P)
    obs = Bt._obstacle_lanes(m)
    out = np.zeros(N, np.bool_)
    for b in range((N + NB - 1) // NB):
        start = b * NB
        n = min(NB, N - start)
        fk_block(Q, start, n, m.chain, blk.KR, blk.Kp, ws)
        if stage < 1:
            continue
        for s in range(S):
            Xb = X[m.shape_body[s]]
            Bt._place(Xb, blk.bounds[s, 0], blk.bounds[s, 1], blk.bounds[s, 2], L.SC[s], n)
            for q in range(blk.ranges[s, 0], blk.ranges[s, 1]):
                Bt._place(Xb, blk.balls[q, 0], blk.balls[q, 1], blk.balls[q, 2], L.BC[q], n)
        if stage < 2:
            continue
        L.posed[:] = False
        L.lane[:] = 0.0
        Bt._block_boxes(L, blk.bounds, n)
        nc = Bt._broad_obstacles(m, blk, obs, pad, L, n)
        if stage < 3:
            continue
        nc = Bt._broad_pairs(m, blk, X, pad, L, nc, n)
        if stage < 4:
            for i in range(n):
                if L.lane[i] > 0.0:
                    counts[0] += 1
                    for c in range(nc):
                        counts[1] += 1 if L.und[c, i] != 0.0 else 0
            continue
        for i in range(n):
            out[start + i] = L.lane[i] > 0.0 and Bt._lane_hits(m, X, i, pad, L, nc, E)
    return out


@njit
def _regions_to(A, B, js, va, vb, nts, nvs, pads, m, stage, counts):
    """regions_hit's tasks through regions._region_hits up to ``stage``;
    counts: tests the quick pass left, and their grid poses."""
    n_tasks, k = A.shape
    out = np.zeros(n_tasks, np.bool_)
    field, sc = no_height_field(), new_scratch()
    rs = Rg._region_workspace(
        m.chain.parent.shape[0], k, m.obstacles.shape[0], m.shapes, m.verts, m.spheres, m.shape_spheres
    )
    W = np.empty((2, k))
    for n in range(n_tasks):
        W[0] = A[n]
        W[1] = B[n]
        ts = (0.0, 1.0, min(nts[n], MAX_T_SAMPLES))
        vs = (va[n], vb[n], min(nvs[n], MAX_V_SAMPLES))
        if region_quick_free(W, 0, js[n], ts, vs, m, field, rs, pads[n]):
            continue
        counts[0] += 1
        counts[1] += ts[2] * vs[2]
        if stage < 1:
            continue
        Rg._region_poses(W, 0, js[n], ts, vs, m, rs, sc.ws[8:11])
        if stage < 2:
            continue
        if Rg._region_vs_scene(W, 0, js[n], ts, vs, m, field, sc, rs, pads[n]):
            out[n] = True
            continue
        if stage < 3:
            continue
        out[n] = Rg._region_self_pairs(W, 0, js[n], ts, vs, m, sc, rs, pads[n])
    return out


def _staged(run, n_stages, repeats, count_at):
    """Cumulative median seconds per stage, the last verdicts and the counts."""
    cum, counts, out = [], None, None
    for stage in range(n_stages):
        times = []
        for _ in range(repeats):
            c = np.zeros(2, np.int64)
            t0 = time.perf_counter()
            out = run(stage, c)
            times.append(time.perf_counter() - t0)
            if stage == count_at:
                counts = c
        cum.append(float(np.median(times)))
    return cum, out, counts


def _report(title, names, cum, n, unit):
    print(title)
    prev = 0.0
    for name, c in zip(names, cum):
        print(f"  {name:30s} {(c - prev) / n * 1e6:7.2f} {unit}")
        prev = c
    print(f"  {'in all':30s} {cum[-1] / n * 1e6:7.2f} {unit}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=100_000)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--pad", type=float, default=0.0, help="clearance of the region tests, m")
    args = ap.parse_args()
    numba.set_num_threads(1)
    for cell, label in CASES:
        wc = cf.load_workcell(cell)
        table = cf.estimate_bounds(wc, cf.plan_nominal_path(wc, *wc.configuration(label), seed=0), resolution=1000)
        arrays = wc.scene_arrays()
        m, blk = arrays.model, arrays.blocks
        print(
            f"\n{cell} {label}: {m.shapes.shape[0]} robot shapes, {m.obstacles.shape[0]} obstacles, "
            f"{m.shape_pairs.shape[0]} self pairs, {blk.balls.shape[0]} cover balls"
        )

        Q = samples_in_bounds(table, args.samples)
        Q = np.ascontiguousarray(Q[cf.kernel.coherent_order(Q, cf.kernel.COHERENT_DIMS, cf.kernel.COHERENT_BITS)])
        _batch_to(Q[:NB], m, blk, 0.0, 4, np.zeros(2, np.int64))  # compiled
        cum, out, (und, cands) = _staged(lambda s, c: _batch_to(Q, m, blk, 0.0, s, c), 5, args.repeats, 3)
        if not np.array_equal(out, arrays.may_collide(Q, 0.0)):
            raise SystemExit("the batch mirror's verdicts differ from the kernel's: update it")
        _report(
            f"batch check, {len(Q):,} samples in the bounds (1 thread)",
            BATCH_STAGES,
            cum,
            len(Q),
            "us per configuration",
        )
        print(
            f"  undecided after the broad phase: {und / len(Q):.3f} lanes per configuration, "
            f"{cands / max(und, 1):.2f} candidates each; exact test {(cum[4] - cum[3]) / max(und, 1) * 1e6:.2f} us per lane"
        )

        parts = [
            edge_tasks(table.lower[i], table.upper[i], table.lower[i + 1], table.upper[i + 1])
            for i in range(table.g - 1)
        ]
        A, B, js, va, vb = (np.ascontiguousarray(np.concatenate([p[f] for p in parts])) for f in range(5))
        js = js.astype(np.int64)
        nts, nvs = _grid(arrays, A, B, js, va, vb)
        pads = np.full(len(js), args.pad)
        _regions_to(A[:4], B[:4], js[:4], va[:4], vb[:4], nts[:4], nvs[:4], pads[:4], m, 3, np.zeros(2, np.int64))
        cum, out, (left, poses) = _staged(
            lambda s, c: _regions_to(A, B, js, va, vb, nts, nvs, pads, m, s, c), 4, args.repeats, 3
        )
        numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)
        kernel = cf.kernel.regions_hit(A, B, js, va, vb, nts, nvs, pads, m)
        numba.set_num_threads(1)
        agree = float((out == kernel).mean())
        if agree < 0.999:  # (GJK's warm start differs between chunkings: a few verdicts may)
            raise SystemExit(f"the region mirror agrees with the kernel on {agree:.4f} of the tests: update it")
        _report(
            f"region test, the box edges of {table.g - 1} stretches: {len(js):,} tests (1 thread)",
            REGION_STAGES,
            cum,
            len(js),
            "us per test",
        )
        print(
            f"  the quick pass decides {1 - left / len(js):.3f} of the tests; the rest hold "
            f"{poses / max(left, 1):.1f} grid poses each; {out.mean():.3f} may collide"
        )


if __name__ == "__main__":
    main()
