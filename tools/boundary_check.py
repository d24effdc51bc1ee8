"""Counts colliding corners, edge points and face points of a path's boxes, by Drake
(thin CLI over drake_cfvol.algorithm.metrics.boundary_check).

    tools/dev.sh python tools/boundary_check.py automotive path1 [--certify [--no-boundary-proof] [--no-cache]] [--clearance 0.02]
"""

import argparse
import dataclasses
import json
import time

import drake_cfvol as cf
from drake_cfvol.algorithm.metrics import boundary_check, judged_margins


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("cell")
    p.add_argument("path")
    p.add_argument("--certify", action="store_true")
    p.add_argument("--no-boundary-proof", action="store_true", help="certify without the edge and corner proof")
    p.add_argument("--no-cache", action="store_true", help="certify anew even if the certificate is cached")
    p.add_argument("--clearance", type=float, default=None, help="margin, m (default: the workcell's, 0.02)")
    p.add_argument("-R", "--resolution", type=int, default=1000)
    a = p.parse_args()
    wc = cf.load_workcell(a.cell)
    params = cf.VolumeParams.for_workcell(wc, resolution=a.resolution, clearance=a.clearance)
    path = cf.plan_nominal_path(wc, *wc.configuration(a.path), seed=0, clearance=params.clearance)
    t0 = time.perf_counter()
    table = cf.estimate_bounds(
        wc,
        path,
        params,
        certify=cf.Certify(cache=not a.no_cache, boundary=not a.no_boundary_proof) if a.certify else None,
    )
    t1 = time.perf_counter()
    out = {
        "cell": a.cell,
        "path": a.path,
        "certified": a.certify,
        "boundary_proof": a.certify and not a.no_boundary_proof,
        "clearance_m": params.clearance,
        "bounds_s": round(t1 - t0, 2),
        "freedom": round(cf.freedom(table).mean, 4),
    }
    # Judged at the margin each stretch keeps (the nominal's own where it is nearer), less 1 mm.
    margins = judged_margins(wc, table)
    out["checked_at_m"] = float(margins.min()) if len(margins) else max(0.0, params.clearance - 1e-3)
    out["certificate"] = {k: v for k, v in table.info.get("certificate", {}).items() if k not in ("proven", "sampled")}
    out.update(dataclasses.asdict(boundary_check(wc, table, clearance=margins)))
    print(json.dumps(out))


if __name__ == "__main__":
    main()
