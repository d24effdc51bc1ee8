"""``cfvol demo``: the main job, end to end on the automotive cell."""

from __future__ import annotations

import time
from pathlib import Path


def run_demo(*, out_dir: Path, seed: int = 0, quick: bool = False) -> int:
    """Plans the automotive cell's three paths and prints a summary table.

    Args:
        out_dir: folder for the outputs (created).
        seed: planner seed.
        quick: fewer samples where sampling is involved.

    Returns:
        Process exit code (0).
    """
    from drake_cfvol.planning import plan_nominal_path
    from drake_cfvol.workcell import load_workcell

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    wc = load_workcell("automotive")
    load_ms = (time.perf_counter() - t0) * 1e3
    print(f"Loaded cell '{wc.name}' ({wc.robot_name}, k = {wc.num_joints}, "
          f"{len(wc.obstacles)} obstacles) in {load_ms:.0f} ms\n")
    rows = []
    for label in wc.configurations:
        start, goal = wc.configuration(label)
        path = plan_nominal_path(wc, start, goal, seed=seed, label=label)
        saved = path.save(out_dir / f"{wc.name}_{label}.json", overwrite=True)
        rows.append((label, path, saved))
    print(f"{'path':<6} {'g':>4} {'length':>8} {'plan ms':>8} {'total ms':>9} {'attempts':>8}  sha256[:12]")
    for label, path, _ in rows:
        s = path.stats
        print(f"{label:<6} {path.g:>4} {path.length:>8.3f} {s['plan_time_ms']:>8.1f} "
              f"{s['total_time_ms']:>9.1f} {s['attempts']:>8}  {path.sha256[:12]}")
    print(f"\nPaths written to {out_dir.resolve()}")
    return 0
