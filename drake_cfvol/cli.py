"""The ``cfvol`` command line: thin wrappers over library functions."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from drake_cfvol.exceptions import CfvolError


def _quiet_drake() -> None:
    import logging

    from pydrake.common import configure_logging

    configure_logging()
    logging.getLogger("drake").setLevel(logging.WARNING)


def _path_name(n: str) -> str:
    return n if n.startswith("path") or not n.isdigit() else f"path{n}"


def cmd_plan(args) -> int:
    from drake_cfvol.planning import plan_nominal_path
    from drake_cfvol.workcell import load_workcell

    wc = load_workcell(args.cell)
    label = _path_name(args.path)
    start, goal = wc.configuration(label)
    path = plan_nominal_path(wc, start, goal, seed=args.seed, time_limit=args.time_limit, label=label)
    out = None
    if args.out:
        out = str(path.save(args.out, overwrite=args.force))
    summary = {
        "cell": wc.name, "path": label, "seed": args.seed, "g": path.g, "k": path.k,
        "plan_time_ms": round(path.stats["plan_time_ms"], 3),
        "total_time_ms": round(path.stats["total_time_ms"], 3),
        "attempts": path.stats["attempts"], "path_length": round(path.length, 6),
        "waypoints_sha256": path.sha256, "out": out,
    }
    if args.json:
        print(json.dumps(summary))
    else:
        for k, v in summary.items():
            print(f"{k:>18}: {v}")
    return 0


def cmd_demo(args) -> int:
    from drake_cfvol.demo import run_demo

    return run_demo(out_dir=Path(args.out), seed=args.seed, quick=args.quick)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="cfvol", description=__doc__)
    sub = p.add_subparsers(dest="command", required=True)

    q = sub.add_parser("plan", help="plan a nominal path (RRT-Connect) for a named start/goal pair")
    q.add_argument("cell", help="built-in cell name (automotive, aerospace) or a workcell YAML path")
    q.add_argument("--path", default="1", help="configuration pair: 1, 2, 3 or a name (default 1)")
    q.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    q.add_argument("--time-limit", type=float, default=10.0, help="planning time limit, s (default 10)")
    q.add_argument("--out", help="save the path (.npz or .json)")
    q.add_argument("--force", action="store_true", help="overwrite --out if it exists")
    q.add_argument("--json", action="store_true", help="print one JSON object")
    q.set_defaults(func=cmd_plan)

    d = sub.add_parser("demo", help="the main job: plan, bound and run the automotive cell")
    d.add_argument("--out", default="out/demo", help="output folder (default out/demo)")
    d.add_argument("--seed", type=int, default=0)
    d.add_argument("--quick", action="store_true", help="fewer CF samples")
    d.set_defaults(func=cmd_demo)
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    _quiet_drake()
    try:
        return int(args.func(args) or 0)
    except CfvolError as e:
        print(f"cfvol: error: {e}", file=sys.stderr)
        return 2
    except FileExistsError as e:
        print(f"cfvol: error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
