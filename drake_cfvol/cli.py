"""The ``cfvol`` command line: thin wrappers over library functions."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from drake_cfvol._version import __version__
from drake_cfvol.exceptions import CfvolError


def _quiet_drake() -> None:
    import logging

    from pydrake.common import configure_logging

    configure_logging()
    logging.getLogger("drake").setLevel(logging.WARNING)


def _path_name(n: str) -> str:
    return n if n.startswith("path") or not n.isdigit() else f"path{n}"


def _emit(summary: dict, as_json: bool) -> None:
    """Prints a command's summary: one JSON object, or aligned key: value lines."""
    if as_json:
        print(json.dumps(summary, default=float))
        return
    width = max(len(k) for k in summary) + 2
    for k, v in summary.items():
        print(f"{k:>{width}}: {v}")


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
    _emit(summary, args.json)
    return 0


def cmd_bounds(args) -> int:
    from drake_cfvol.metrics import confidence_factor, freedom
    from drake_cfvol.params import VolumeParams
    from drake_cfvol.pipeline import estimate_bounds
    from drake_cfvol.planning import plan_nominal_path
    from drake_cfvol.volume import height_map_of
    from drake_cfvol.workcell import load_workcell

    if args.plot and not args.out:
        print("cfvol: error: --plot needs --out DIR (the folder to write the plot to)", file=sys.stderr)
        return 2
    wc = load_workcell(args.cell)
    label = _path_name(args.path)
    # Check the resolution (and its memory) before planning.
    height_map_of(wc, VolumeParams.for_workcell(wc, resolution=args.resolution))
    path = plan_nominal_path(wc, *wc.configuration(label), seed=args.seed, label=label)
    certify = None
    if args.certify:
        from drake_cfvol.certify import Certify

        certify = Certify(epsilon=args.epsilon, confidence=args.confidence, seed=args.seed)
    table = estimate_bounds(wc, path, resolution=args.resolution, backend=args.backend, certify=certify)
    cf = confidence_factor(wc, table, windows=args.cf_windows, samples=args.cf_samples, seed=args.seed)
    fr = freedom(table, wc.revolute)
    out = None
    files = {}
    if args.out:
        out = Path(args.out)
        stem = f"{wc.name}_{label}_R{args.resolution}"
        files["bounds_npz"] = str(table.save(out / f"{stem}_bounds.npz", overwrite=args.force))
        files["bounds_json"] = str(table.save(out / f"{stem}_bounds.json", overwrite=args.force))
        files["path_json"] = str(path.save(out / f"{stem}_path.json", overwrite=args.force))
        if args.plot:
            from drake_cfvol.plotting import plot_bounds

            files["plot_png"] = str(plot_bounds(table, out / f"{stem}_bounds.png", revolute=wc.revolute,
                                                title=f"{wc.name} {label}, R = {args.resolution}"))
    summary = {
        "cell": wc.name, "path": label, "seed": args.seed, "resolution": args.resolution,
        "backend": args.backend, "g": table.g, "k": table.k,
        "time_ms": round(table.timing_ms["total"], 3),
        "timing_ms": {k: round(v, 3) for k, v in table.timing_ms.items()},
        "cf_percent": round(cf.percent, 4), "cf_samples": cf.samples, "cf_colliding": cf.colliding,
        "freedom": round(fr.mean, 5),
        "median_width": dict(zip(table.joint_names, [round(float(x), 3) for x in fr.median_width])),
        "median_width_units": dict(zip(table.joint_names, fr.units)),
        "n_boxes": table.info["n_boxes"], "lowered_columns": table.info["lowered_columns"],
        "dropped_columns": table.info["dropped_columns"], "categories": table.info["categories"],
        "out": str(out) if out else None, "files": files,
    }
    if certify is not None:
        summary["certify_ms"] = round(table.timing_ms["certify"], 3)
        summary["certificate"] = table.info["certificate"]
    _emit(summary, args.json)
    return 0


def cmd_simulate(args) -> int:
    from drake_cfvol.comanip import run_scenario

    out = Path(args.out) if args.out else Path("out") / Path(args.scenario).stem
    summary = run_scenario(args.scenario, out, record=not args.no_record)
    _emit(summary, args.json)
    return 0


def cmd_bench(args) -> int:
    from drake_cfvol.bench import BenchConfig, run_bench, write_outputs

    if args.report_only:
        saved = Path(args.out) / "results.json"
        if not saved.is_file():
            print(f"cfvol: error: --report-only needs {saved} from an earlier run", file=sys.stderr)
            return 2
        files = write_outputs(json.loads(saved.read_text()), args.out)
        print(f"Rewrote {', '.join(Path(f).name for f in files.values())} in {Path(args.out).resolve()}")
        return 0
    cfg = BenchConfig.quick() if args.quick else BenchConfig()
    if args.cells:
        cfg.cells = args.cells
    if args.paths:
        cfg.paths = [_path_name(p) for p in args.paths]
    if args.resolutions:
        cfg.resolutions = args.resolutions
    if args.trials:
        cfg.trials = args.trials
    if args.cf_samples:
        cfg.cf_samples = args.cf_samples
    if args.no_iris:
        cfg.iris = False
    if args.no_engine:
        cfg.engine = False
    result = run_bench(cfg, progress=not args.json)
    files = write_outputs(result, args.out)
    if args.json:
        print(json.dumps({"rows": result["rows"], "files": files, "wall_s": result["wall_s"]}, default=float))
    else:
        print(Path(files["markdown"]).read_text())
        print(f"Written to {Path(args.out).resolve()}")
    return 0


def cmd_demo(args) -> int:
    from drake_cfvol.demo import run_demo

    return run_demo(out_dir=Path(args.out), seed=args.seed, quick=args.quick)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="cfvol", description=__doc__)
    p.add_argument("--version", action="version", version=f"cfvol (drake_cfvol) {__version__}")
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

    b = sub.add_parser("bounds", help="plan a path and compute its joint bounds, CF and freedom")
    b.add_argument("cell", help="built-in cell name or a workcell YAML path")
    b.add_argument("--path", default="1", help="configuration pair: 1, 2, 3 or a name (default 1)")
    b.add_argument("--resolution", "-R", type=int, default=1000, help="height-map cells R (default 1000)")
    b.add_argument("--seed", type=int, default=0, help="planner and CF seed (default 0)")
    b.add_argument("--backend", choices=["fast", "drake"], default="fast",
                   help="fast (any R) or drake (reference, one SceneGraph box per column)")
    b.add_argument("--cf-windows", type=int, default=30, help="CF time windows N_tw (default 30)")
    b.add_argument("--cf-samples", type=int, default=10000, help="CF samples per window N_m (default 10000)")
    b.add_argument("--certify", action="store_true",
                   help="shrink the boxes until each stretch holds a sampled safety certificate")
    b.add_argument("--epsilon", type=float, default=1e-5, help="certificate: colliding share allowed (1e-5)")
    b.add_argument("--confidence", type=float, default=0.99, help="certificate: confidence (0.99)")
    b.add_argument("--out", help="folder for bounds (.npz, .json), path and plot")
    b.add_argument("--plot", action="store_true", help="write a PNG of the bounds (needs --out)")
    b.add_argument("--force", action="store_true", help="overwrite existing files in --out")
    b.add_argument("--json", action="store_true", help="print one JSON object")
    b.set_defaults(func=cmd_bounds)

    m = sub.add_parser("simulate", help="run a co-manipulation scenario and record it")
    m.add_argument("scenario", help="bundled scenario name (automotive_push, aerospace_push) or a YAML path")
    m.add_argument("--out", help="output folder (default out/<scenario>)")
    m.add_argument("--no-record", action="store_true", help="skip the Meshcat recording")
    m.add_argument("--json", action="store_true", help="print one JSON object")
    m.set_defaults(func=cmd_simulate)

    n = sub.add_parser("bench", help="reproduce the paper's Tables I and II side by side")
    n.add_argument("--quick", action="store_true", help="a small run (a few minutes)")
    n.add_argument("--cells", nargs="+", help="cells (default both)")
    n.add_argument("--paths", nargs="+", help="paths, e.g. 1 2 3 (default all)")
    n.add_argument("--resolutions", nargs="+", type=int, help="R values (default the paper's)")
    n.add_argument("--trials", type=int, help="timed trials per row (default 20)")
    n.add_argument("--cf-samples", type=int, help="CF samples per window N_m (default 10000)")
    n.add_argument("--no-iris", action="store_true", help="skip Drake's IrisZo comparison")
    n.add_argument("--no-engine", action="store_true",
                   help="skip the kernel's fresh-cache compile and command wall-time measurements")
    n.add_argument("--out", default="out/bench", help="output folder (default out/bench)")
    n.add_argument("--report-only", action="store_true",
                   help="rewrite tables and plots from --out/results.json without running")
    n.add_argument("--json", action="store_true", help="print one JSON object")
    n.set_defaults(func=cmd_bench)

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
