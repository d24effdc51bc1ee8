"""The ``cfvol`` command line: thin wrappers over library functions."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from drake_cfvol._version import __version__
from drake_cfvol.comanip.push_patterns import PATTERNS
from drake_cfvol.exceptions import CfvolError, ParameterError
from drake_cfvol.io.records import output_stem, path_label, prepare_output, prepare_outputs

_DESCRIPTION = (
    "Joint bounds that tell a robot how far a co-worker may push it off its planned path "
    "without hitting anything (plan, bound, simulate, benchmark)."
)


def _quiet_drake() -> None:
    import logging

    from pydrake.common import configure_logging

    configure_logging()
    logging.getLogger("drake").setLevel(logging.WARNING)


#: Plain-output labels: what each summary key means, with its unit.
_LABELS = {
    "cell": "cell",
    "path": "path",
    "seed": "seed",
    "g": "waypoints (g)",
    "k": "joints (k)",
    "plan_time_ms": "planning time",
    "total_time_ms": "planning + checks",
    "attempts": "planner attempts",
    "path_length": "path length (joint space)",
    "waypoints_sha256": "waypoints sha256",
    "out": "written to",
    "resolution": "height-map cells (R)",
    "backend": "backend",
    "time_ms": "time to compute the bounds",
    "timing_ms": "time per step",
    "cf_percent": "confidence factor (CF)",
    "cf_samples": "CF samples",
    "cf_colliding": "CF samples colliding",
    "freedom": "freedom (mean geometric width share)",
    "median_width": "median width per joint",
    "n_boxes": "volume columns",
    "lowered_columns": "columns lowered",
    "dropped_columns": "columns dropped",
    "categories": "obstacle categories",
    "files": "files",
    "certify_ms": "certification time",
    "certificate": "certificate",
}
_UNITS = {
    "plan_time_ms": " ms",
    "total_time_ms": " ms",
    "time_ms": " ms",
    "certify_ms": " ms",
    "cf_percent": " %",
    "sim_wall_s": " s",
    "duration_s": " s",
    "min_clearance_m": " m",
    "bounds_time_ms": " ms",
    "build_ms": " ms",
    "max_bound_violation": " rad/m",
    "max_deviation": " rad/m",
    "path_length": " rad/m",
    "live_box_excess_max": " rad/m",
    "live_box_catchup_s": " s",
}


def _fmt(v, unit: str = "") -> str:
    if v is None:
        return "-"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        return f"{v:.4g}{unit}" if abs(v) < 1e4 else f"{v:.0f}{unit}"
    if isinstance(v, (list, tuple)):
        return ", ".join(_fmt(x) for x in v) or "-"
    return f"{v}{unit}"


def _emit(summary: dict, as_json: bool) -> None:
    """Prints a command's summary: one JSON object, or one line per fact
    for people (names, units, no Python reprs)."""
    if as_json:
        print(json.dumps(summary, default=float))
        return
    units = summary.pop("median_width_units", None)
    lines = []
    for key, v in summary.items():
        label = _LABELS.get(key, key.replace("_", " "))
        if key == "timing_ms" and isinstance(v, dict):
            text = ", ".join(f"{n} {x:.1f} ms" for n, x in v.items())
        elif key == "median_width" and isinstance(v, dict):
            text = ", ".join(f"{n} {x:.3g} {(units or {}).get(n, '')}".rstrip() for n, x in v.items())
        elif key == "categories" and isinstance(v, dict):
            text = "; ".join(f"{n.replace('_', '-')}: {', '.join(x) or '-'}" for n, x in v.items())
        elif key == "certificate" and isinstance(v, dict):
            lines.append(
                (
                    "certificate",
                    ("cached; " if v.get("cached") else "")
                    + f"{v.get('shrinks', 0)} cuts, freedom {v.get('freedom_before', 0):.3f} -> "
                    f"{v.get('freedom_after', 0):.3f}",
                )
            )
            lines.append(("  proven", v.get("proven", "")))
            lines.append(("  sampled", v.get("sampled", "")))
            continue
        elif key == "files" and isinstance(v, dict):
            for n, f in v.items():
                lines.append((f"  {n.replace('_', ' ')}", f))
            continue
        elif isinstance(v, dict):
            text = ", ".join(f"{n} {_fmt(x)}" for n, x in v.items()) or "-"
        else:
            text = _fmt(v, _UNITS.get(key, ""))
        lines.append((label, text))
    width = max(len(a) for a, _ in lines) + 1
    for a, b in lines:
        print(f"{a:<{width}} {b}")


def _out_path(p: str | None) -> Path | None:
    """A path the user gave, resolved against their current folder (None: none given)."""
    return _given_path(p) if p else None


def _given_path(p: str) -> Path:
    """A path the user gave, resolved against their current folder."""
    return Path(p).expanduser().resolve()


def _load_cell(load_workcell, cell: str):
    """The workcell, its loader's notes (mesh conversions, fixed URDF
    quirks, held degrees of freedom) printed to stderr, one line each."""
    wc = load_workcell(cell)
    for note in wc.notes:
        print(f"cfvol: note: {note}", file=sys.stderr)
    return wc


def cmd_plan(args) -> int:
    from drake_cfvol.algorithm.planning import plan_nominal_path
    from drake_cfvol.scene.workcell import load_workcell

    out = _out_path(args.out)
    if out is not None:
        prepare_output(out, overwrite=args.force)
    wc = _load_cell(load_workcell, args.cell)
    label = path_label(args.path)
    start, goal = wc.configuration(label)
    path = plan_nominal_path(
        wc, start, goal, seed=args.seed, time_limit=args.time_limit, label=label, clearance=args.clearance
    )
    if out is not None:
        from drake_cfvol.algorithm.reuse import fingerprint_of

        path.fingerprint = fingerprint_of(wc, path)
        saved_to: str | None = str(path.save(out, overwrite=args.force))
    else:
        saved_to = None
    summary = {
        "cell": wc.name,
        "path": label,
        "seed": args.seed,
        "g": path.g,
        "k": path.k,
        "clearance_m": path.stats["clearance_m"],
        "plan_time_ms": round(path.stats["plan_time_ms"], 3),
        "total_time_ms": round(path.stats["total_time_ms"], 3),
        "attempts": path.stats["attempts"],
        "path_length": round(path.length, 6),
        "waypoints_sha256": path.sha256,
        "out": saved_to,
    }
    _emit(summary, args.json)
    return 0


def _bundled_scenarios() -> list[str]:
    """The bundled scenarios' names (the package's diagrams folder), read
    without importing Drake."""
    from importlib import resources

    return sorted(p.name[:-5] for p in resources.files("drake_cfvol.diagrams").iterdir() if p.name.endswith(".yaml"))


def _notes(notes: list) -> None:
    """Notices of the library's checks, one line each on stderr."""
    for note in notes:
        print(f"cfvol: note: {note}", file=sys.stderr)


def _bounds_label(args) -> str:
    """The path the bounds are for: ``--path``; else the saved path's or
    table's own label (so that a file is never named for another path)."""
    if args.path is not None:
        return path_label(args.path)
    from drake_cfvol.algorithm.planning import NominalPath
    from drake_cfvol.algorithm.table import BoundsTable

    saved = ""
    if args.path_file:
        saved = NominalPath.load(_given_path(args.path_file)).label
    elif args.bounds_file:
        saved = str(BoundsTable.load(_given_path(args.bounds_file)).info.get("path", ""))
    return path_label(saved or "1")


def _path_to_bound(args, wc, label: str, clearance: float):
    """The saved path of ``--path-file`` (checked against the cell), or one planned."""
    if args.path_file:
        from drake_cfvol.algorithm.reuse import load_path_for

        notes: list = []
        path = load_path_for(
            wc, _given_path(args.path_file), label=label if args.path is not None else None, notes=notes
        )
        _notes(notes)
        return path
    from drake_cfvol.algorithm.planning import plan_nominal_path

    wc.configuration(label)
    return plan_nominal_path(wc, *wc.configuration(label), seed=args.seed, label=label, clearance=clearance)


def _path_and_table(args, wc, label: str, params, bars: bool):
    """The path (saved, or planned) and its table: loaded from
    ``--bounds-file`` (checked against the cell and the path), or computed."""
    if args.bounds_file:
        from drake_cfvol.algorithm.planning import NominalPath
        from drake_cfvol.algorithm.reuse import load_bounds_for

        path = _path_to_bound(args, wc, label, params.clearance) if args.path_file else None
        notes: list = []
        named = label if args.path is not None else None
        table = load_bounds_for(wc, _given_path(args.bounds_file), path, label=named, notes=notes)
        _notes(notes)
        if path is None:
            path = NominalPath(table.nominal, list(table.joint_names), wc.name, label, args.seed)
        return path, table
    from drake_cfvol.algorithm.pipeline import estimate_bounds

    path = _path_to_bound(args, wc, label, params.clearance)
    certify = None
    if args.certify:
        from drake_cfvol.algorithm.certificate.certify import Certify

        given = {
            n: getattr(args, n) for n in ("epsilon", "clamp_epsilon", "confidence") if getattr(args, n) is not None
        }
        certify = Certify(
            **given, seed=args.seed, cache=not args.no_cache, boundary=not args.no_boundary_proof, regrow=args.regrow
        )
    return path, estimate_bounds(wc, path, params, backend=args.backend, certify=certify, progress=bars)


#: The CF's samples may take at most this much memory (bytes): they are
#: drawn at once, a path parameter and k joint values each, with copies.
MAX_CF_BYTES = 2 * 1024**3


def _check_cf_memory(windows: int, samples: int, k: int) -> None:
    """Refuses CF sample counts whose arrays would not fit, before any work."""
    need = 4.0 * windows * samples * (k + 1) * 8  # the draws, their checks' copies
    if need > MAX_CF_BYTES:
        raise ParameterError(
            f"--cf-windows {windows} x --cf-samples {samples} would need about {need / 1e9:.1f} GB for the CF's "
            f"samples (at most {MAX_CF_BYTES / 1e9:.1f} GB): lower --cf-samples (default 10000)."
        )


def cmd_bounds(args) -> int:
    from drake_cfvol.algorithm.metrics import confidence_factor, freedom, shown_percent
    from drake_cfvol.algorithm.volume import height_map_of
    from drake_cfvol.scene.params import VolumeParams
    from drake_cfvol.scene.workcell import load_workcell

    if args.plot and not args.out:
        raise ParameterError("--plot needs --out DIR (the folder to write the plot to).")
    lonely = [
        f"--{n.replace('_', '-')}"
        for n in ("epsilon", "clamp_epsilon", "confidence", "no_cache", "no_boundary_proof", "regrow")
        if getattr(args, n) not in (None, False)
    ]
    if lonely and not args.certify:
        raise ParameterError(
            f"{', '.join(lonely)} only apply{'s' if len(lonely) == 1 else ''} to certified bounds: "
            "add --certify, or leave them out."
        )
    if args.bounds_file and args.certify:
        raise ParameterError(
            "--bounds-file evaluates a saved table as it is: leave out --certify (certify when you compute the table)."
        )
    if args.regrow and args.no_boundary_proof:
        raise ParameterError("--regrow widens bounds where the boundary proof holds: leave out --no-boundary-proof.")
    if args.cf_windows < 1 or args.cf_samples < 1:
        raise ParameterError(
            f"--cf-windows and --cf-samples must be >= 1, got {args.cf_windows} and {args.cf_samples}."
        )
    out = _out_path(args.out)
    wc = _load_cell(load_workcell, args.cell)
    _check_cf_memory(args.cf_windows, args.cf_samples, wc.num_joints)
    label = _bounds_label(args)
    stem = output_stem(wc.name, label, args.resolution, certified=args.certify)
    if out is not None:  # every output checked before any work (a second --certify refuses at once)
        kinds = ("bounds.npz", "bounds.json", "path.json") + (("bounds.png",) if args.plot else ())
        prepare_outputs(out, [f"{stem}_{kind}" for kind in kinds], overwrite=args.force)
    # Check the configuration pair and the resolution (and its memory) before planning.
    params = VolumeParams.for_workcell(wc, resolution=args.resolution, clearance=args.clearance)
    height_map_of(wc, params)
    bars = not args.json
    path, table = _path_and_table(args, wc, label, params, bars)
    cf = confidence_factor(
        wc, table, windows=args.cf_windows, samples=args.cf_samples, seed=args.seed, judge=args.cf_judge, progress=bars
    )
    fr = freedom(table, wc.revolute)
    files = {}
    if out is not None:
        files["bounds_npz"] = str(table.save(out / f"{stem}_bounds.npz", overwrite=args.force))
        files["bounds_json"] = str(table.save(out / f"{stem}_bounds.json", overwrite=args.force))
        path.fingerprint = path.fingerprint or table.info.get("fingerprint", {})
        files["path_json"] = str(path.save(out / f"{stem}_path.json", overwrite=args.force))
        if args.plot:
            from drake_cfvol.io.plotting import plot_bounds

            files["plot_png"] = str(
                plot_bounds(
                    table,
                    out / f"{stem}_bounds.png",
                    revolute=wc.revolute,
                    title=f"{wc.name} {label}, R = {args.resolution}" + (", certified" if args.certify else ""),
                )
            )
    summary = {
        "cell": wc.name,
        "path": label,
        "seed": args.seed,
        "resolution": table.info.get("resolution", args.resolution),
        "backend": table.info.get("backend", args.backend),
        "g": table.g,
        "k": table.k,
        "time_ms": round(table.timing_ms["total"], 3),
        "timing_ms": {k: round(v, 3) for k, v in table.timing_ms.items()},
        "certified": "certificate" in table.info,
        "clearance_m": table.params.get("clearance", params.clearance),
        "cf_percent": shown_percent(cf.percent, cf.colliding, 4),
        "cf_samples": cf.samples,
        "cf_colliding": cf.colliding,
        "cf_judge": cf.judge,
        "cf_drake_checked": cf.drake_checked,
        "cf_kernel_only_colliding": cf.kernel_only_colliding,
        "freedom": round(fr.mean, 5),
        "median_width": dict(zip(table.joint_names, [round(float(x), 3) for x in fr.median_width])),
        "median_width_units": dict(zip(table.joint_names, fr.units)),
        "n_boxes": table.info["n_boxes"],
        "lowered_columns": table.info["lowered_columns"],
        "dropped_columns": table.info["dropped_columns"],
        "categories": table.info["categories"],
        "out": str(out) if out else None,
        "files": files,
        "bounds_file": str(_out_path(args.bounds_file)) if args.bounds_file else None,
    }
    if "certificate" in table.info:
        summary["certify_ms"] = round(table.timing_ms.get("certify", float("nan")), 3)
        summary["certificate"] = table.info["certificate"]
    _emit(summary, args.json)
    return 0


def cmd_simulate(args) -> int:
    from drake_cfvol.comanip import load_scenario, run_scenario

    files = {
        key: str(_out_path(value))
        for key, value in (("path.file", args.path_file), ("bounds.file", args.bounds_file))
        if value
    }
    # Every field checked before planning.
    load_scenario(args.scenario, scenario_text=args.scenario_text, overrides=files)
    out = _out_path(args.out) or Path("out").resolve() / Path(args.scenario).stem
    created = not out.exists()
    prepare_output(out, overwrite=True, folder=True)
    try:
        summary = run_scenario(
            args.scenario,
            out,
            record=not args.no_record,
            progress=not args.json,
            scenario_text=args.scenario_text,
            overrides=files,
            overwrite=args.force,  # every output checked before the run is built
        )
    except BaseException:
        if created and out.is_dir() and not any(out.iterdir()):
            out.rmdir()  # a failed run leaves no empty folder behind
        raise
    for note in summary.notices:
        print(f"cfvol: note: {note}", file=sys.stderr)
    _emit(summary.to_dict(), args.json)
    if summary.problems:
        print(f"cfvol: unsafe run: {'; '.join(summary.problems)}.", file=sys.stderr)
        return 1
    return 0


def bench_harness(module: str = "harness"):
    """The benchmark harness (the paper's tables, the adversarial section):
    ``benchmarks/harness.py`` of the development checkout this package runs
    from (``module="kernel"``: the kernel benchmark). It is not part of the
    library (nor of the wheel).

    Raises:
        CfvolError: the package is not running from a development checkout.
    """
    import importlib

    root = Path(__file__).resolve().parents[2]
    if not (root / "benchmarks" / "harness.py").is_file():
        raise CfvolError(
            f"cfvol bench runs from a development checkout of drake_cfvol (its benchmarks/ folder); "
            f"this one is installed at {root}. Clone the repository and run tools/dev.sh cfvol bench."
        )
    if str(root) not in sys.path:
        sys.path.insert(0, str(root))
    return importlib.import_module(f"benchmarks.{module}")


def _bench_targets(args, module: str, config: str, trials: str, folder: str) -> int:
    """A target benchmark of the checkout's ``benchmarks/<module>.py``: its
    ``config`` dataclass (``--quick``: its ``quick()``; ``--trials`` sets
    its field ``trials``; ``--cells`` its ``cells``), run, written to
    ``--out`` (default ``out/<folder>``) and its targets printed."""
    bench = bench_harness(module)
    out = _out_path(args.out if args.out != "out/bench" else f"out/{folder}")
    prepare_output(out, overwrite=True, folder=True)
    cls = getattr(bench, config)
    cfg = cls.quick() if args.quick else cls()
    if args.trials:
        setattr(cfg, trials, args.trials)
    if args.cells and hasattr(cfg, "cells"):
        cfg.cells = list(args.cells)
    result = getattr(bench, f"run_{module}_bench")(cfg)
    files = getattr(bench, f"write_{module}_outputs")(result, out, bench_harness().machine_info())
    if args.json:
        print(json.dumps({"targets": getattr(bench, f"{module}_targets")(result), "files": files}, default=float))
    else:
        print(Path(files["markdown"]).read_text())
        print(f"Written to {out}")
    return 0


def cmd_bench(args) -> int:
    if args.kernel:  # the kernel issue's targets in one run
        return _bench_targets(args, "kernel", "KernelBenchConfig", "trials", "bench-kernel")
    if args.realtime:  # the control stack's wall time per update
        return _bench_targets(args, "realtime", "RealtimeBenchConfig", "repeats", "bench-realtime")
    if args.iris:  # the certified box beside the best box inside Drake's IrisZo region
        return _bench_targets(args, "iris", "IrisBenchConfig", "repeats", "bench-iris")
    harness = bench_harness()
    BenchConfig, run_bench, write_outputs = harness.BenchConfig, harness.run_bench, harness.write_outputs

    if args.report_only:
        saved = Path(args.out) / "results.json"
        if not saved.is_file():
            print(f"cfvol: error: --report-only needs {saved} from an earlier run", file=sys.stderr)
            return 2
        files = write_outputs(json.loads(saved.read_text()), args.out)
        print(f"Rewrote {', '.join(Path(f).name for f in files.values())} in {Path(args.out).resolve()}")
        return 0
    prepare_output(_out_path(args.out), overwrite=True, folder=True)
    cfg = BenchConfig.quick() if args.quick else BenchConfig()
    if args.cells:
        cfg.cells = args.cells
    if args.paths:
        cfg.paths = [path_label(p) for p in args.paths]
    if args.resolutions:
        cfg.resolutions = args.resolutions
    if args.trials:
        cfg.trials = args.trials
    if args.cf_samples:
        cfg.cf_samples = args.cf_samples
    if args.no_iris:
        cfg.iris = False
    if args.no_reference:
        cfg.reference_resolutions = []
    if args.certify_resolutions is not None:
        cfg.certify_resolutions = args.certify_resolutions
    if args.adversarial_runs is not None:
        if args.adversarial_runs < 0:
            print(f"cfvol: error: --adversarial-runs must be >= 0, got {args.adversarial_runs}", file=sys.stderr)
            return 2
        cfg.adversarial_runs = args.adversarial_runs
    if args.adversarial_patterns:
        cfg.adversarial_patterns = args.adversarial_patterns
    if args.adversarial_only:
        if not cfg.adversarial_runs:
            print("cfvol: error: --adversarial-only needs --adversarial-runs >= 1", file=sys.stderr)
            return 2
        cfg.paths, cfg.iris, cfg.engine = [], False, False
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
    from drake_cfvol.apps.demo import run_demo

    out = _given_path(args.out)
    prepare_output(out, overwrite=True, folder=True)
    return run_demo(out_dir=out, seed=args.seed, quick=args.quick)


def _add_plan(sub) -> None:
    """The ``plan`` command."""
    q = sub.add_parser("plan", help="plan a nominal path (RRT-Connect) for a named start/goal pair")
    q.add_argument("cell", help="built-in cell name (automotive, aerospace) or a workcell YAML path")
    q.add_argument("--path", default="1", help="configuration pair: 1, 2, 3 or a name (default 1)")
    q.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    q.add_argument("--time-limit", type=float, default=10.0, help="planning time limit, s (default 10)")
    q.add_argument(
        "--clearance",
        type=float,
        default=None,
        help="margin kept from obstacles and the robot itself, m (default 0.02; 0: the paper's)",
    )
    q.add_argument("--out", help="save the path (.npz or .json)")
    q.add_argument("--force", action="store_true", help="overwrite --out if it exists")
    q.add_argument("--json", action="store_true", help="print one JSON object")
    q.set_defaults(func=cmd_plan)


def _add_bounds(sub) -> None:
    """The ``bounds`` command."""
    b = sub.add_parser("bounds", help="plan a path and compute its joint bounds, CF and freedom")
    b.add_argument("cell", help="built-in cell name or a workcell YAML path")
    b.add_argument(
        "--path", help="configuration pair: 1, 2, 3 or a name (default 1, or the label of --path-file/--bounds-file)"
    )
    b.add_argument("--resolution", "-R", type=int, default=1000, help="height-map cells R (default 1000)")
    b.add_argument("--seed", type=int, default=0, help="planner and CF seed (default 0)")
    b.add_argument(
        "--path-file", help="a saved path (cfvol plan --out) to bound instead of planning one; checked against the cell"
    )
    b.add_argument(
        "--bounds-file",
        help="a saved bounds table to evaluate (CF, freedom) instead of computing one; checked against the cell",
    )
    b.add_argument(
        "--backend",
        choices=["fast", "drake"],
        default="fast",
        help="fast (any R) or drake (reference, one SceneGraph box per column)",
    )
    b.add_argument("--cf-windows", type=int, default=30, help="CF time windows N_tw (default 30)")
    b.add_argument("--cf-samples", type=int, default=10000, help="CF samples per window N_m (default 10000)")
    b.add_argument(
        "--cf-judge",
        choices=("kernel", "drake"),
        default="kernel",
        help="who judges the CF's samples: the kernel, with Drake cross-checking 10,000 of them "
        "(default), or Drake's checker on every sample the kernel cannot certify free",
    )
    b.add_argument(
        "--certify", action="store_true", help="shrink the boxes until each stretch holds a sampled safety certificate"
    )
    b.add_argument(
        "--epsilon", type=float, default=None, help="certificate: colliding share allowed (1e-5; needs --certify)"
    )
    b.add_argument(
        "--clamp-epsilon",
        type=float,
        default=None,
        help="certificate: colliding share allowed where a clamp lands (10 x epsilon; needs --certify)",
    )
    b.add_argument(
        "--no-cache",
        action="store_true",
        help="certify again even if the same certificate is cached (see DRAKE_CFVOL_CACHE; needs --certify)",
    )
    b.add_argument("--confidence", type=float, default=None, help="certificate: confidence (0.99; needs --certify)")
    b.add_argument(
        "--no-boundary-proof",
        action="store_true",
        help="certificate: sampled only, without the proof of every edge and corner of the box (faster, "
        "but a clamp may land nearer than the margin; needs --certify)",
    )
    b.add_argument(
        "--regrow",
        action="store_true",
        help="certificate: afterwards widen cut bounds back where the proof still holds (more freedom, "
        "about twice the time; needs --certify, not with --no-boundary-proof)",
    )
    b.add_argument(
        "--clearance",
        type=float,
        default=None,
        help="safety margin kept from obstacles and the robot itself, m (default 0.02; 0: the paper's)",
    )
    b.add_argument("--out", help="folder for bounds (.npz, .json), path and plot")
    b.add_argument("--plot", action="store_true", help="write a PNG of the bounds (needs --out)")
    b.add_argument("--force", action="store_true", help="overwrite existing files in --out")
    b.add_argument("--json", action="store_true", help="print one JSON object")
    b.set_defaults(func=cmd_bounds)


def _add_simulate(sub) -> None:
    """The ``simulate`` command."""
    m = sub.add_parser("simulate", help="run a co-manipulation scenario and record it")
    m.add_argument("scenario", help=f"bundled scenario name ({', '.join(_bundled_scenarios())}) or a YAML path")
    m.add_argument("--out", help="output folder (default out/<scenario>)")
    m.add_argument("--no-record", action="store_true", help="skip the Meshcat recording")
    m.add_argument(
        "--force", action="store_true", help="overwrite the files of an earlier run in --out (summary, logs, plots)"
    )
    m.add_argument(
        "--path-file",
        help="a saved path (cfvol plan/bounds --out) instead of planning; checked against the scenario's cell",
    )
    m.add_argument(
        "--bounds-file", help="a saved bounds table (cfvol bounds --out) instead of bounding; checked against the cell"
    )
    m.add_argument(
        "--scenario-text",
        help="YAML overriding the scenario's fields, e.g. '{bounds: {resolution: 2000}, random_seed: 3}'",
    )
    m.add_argument("--json", action="store_true", help="print one JSON object")
    m.set_defaults(func=cmd_simulate)


def _add_bench(sub) -> None:
    """The ``bench`` command (the harness of a development checkout)."""
    n = sub.add_parser("bench", help="reproduce the paper's Tables I and II side by side")
    n.add_argument("--quick", action="store_true", help="a small run (a few minutes)")
    n.add_argument(
        "--kernel",
        action="store_true",
        help="the kernel benchmark instead: configurations per second against Drake, bounding against "
        "the paper, certification as batch jobs, CF, the first compile (default --out "
        "out/bench-kernel; uses --quick, --trials, --json)",
    )
    n.add_argument(
        "--realtime",
        action="store_true",
        help="the control-rate benchmark instead: on a kinematic station at 10 ms and 1 ms periods under "
        "steady pushes, the control stack's wall time per update, the command's largest acceleration, jerk "
        "and velocity change, collisions by Drake and the share of the push passed, beside Drake's "
        "DifferentialInverseKinematicsSystem (default --out out/bench-realtime; uses --quick, --cells, "
        "--trials as repeats, --json)",
    )
    n.add_argument(
        "--iris",
        action="store_true",
        help="the IrisZo comparison instead: at evenly spaced waypoints of the built-in paths and the mesh "
        "robot, the certified box beside the largest box inside Drake's IrisZo region, and certification "
        "time (default --out out/bench-iris; uses --quick, --cells, --trials as repeats, --json)",
    )
    n.add_argument("--cells", nargs="+", help="cells (default both)")
    n.add_argument("--paths", nargs="+", help="paths, e.g. 1 2 3 (default all)")
    n.add_argument("--resolutions", nargs="+", type=int, help="R values (default the paper's)")
    n.add_argument("--trials", type=int, help="timed trials per row (default 20)")
    n.add_argument("--cf-samples", type=int, help="CF samples per window N_m (default 10000)")
    n.add_argument("--no-iris", action="store_true", help="skip Drake's IrisZo comparison")
    n.add_argument("--no-reference", action="store_true", help="skip the reference (Drake) backend rows")
    n.add_argument(
        "--certify-resolutions",
        nargs="*",
        type=int,
        help="R values that also get certified bounds (default: every R; none: no certification)",
    )
    n.add_argument(
        "--adversarial-runs",
        type=int,
        help="adversarial push runs per cell, pattern, kind of bounds and filter on/off (default 16; --quick: 0)",
    )
    n.add_argument(
        "--adversarial-patterns",
        nargs="+",
        choices=PATTERNS,
        help=f"push patterns of the adversarial section (default all: {', '.join(PATTERNS)})",
    )
    n.add_argument(
        "--adversarial-only",
        action="store_true",
        help="run only the adversarial section (no paper tables, IrisZo or engine costs)",
    )
    n.add_argument(
        "--no-engine",
        action="store_true",
        help="skip the kernel's fresh-cache compile and command wall-time measurements",
    )
    n.add_argument("--out", default="out/bench", help="output folder (default out/bench)")
    n.add_argument(
        "--report-only", action="store_true", help="rewrite tables and plots from --out/results.json without running"
    )
    n.add_argument("--json", action="store_true", help="print one JSON object")
    n.set_defaults(func=cmd_bench)


def cmd_batch(args) -> int:
    from drake_cfvol.apps.batch_jobs import expand_jobs, load_jobs, output_files, run_batch, write_batch

    if args.scheduler and args.serial:
        raise ParameterError("--serial runs the jobs here, one after the other: leave out --scheduler.")
    if args.workers is not None and (args.workers < 1 or args.scheduler or args.serial):
        raise ParameterError("--workers sizes the local cluster: a number >= 1, without --scheduler or --serial.")
    jobs_file = _out_path(args.jobs)
    jobs, file = load_jobs(jobs_file)
    assert file is not None  # read from a file: its path
    todo = expand_jobs(jobs, file.parent)
    out = _out_path(args.out) or (file.parent / f"{file.stem}_results")
    output_files(todo, out, overwrite=args.force)  # checked before anything runs
    results = run_batch(
        todo, scheduler="serial" if args.serial else args.scheduler, workers=args.workers, progress=not args.json
    )
    files = write_batch(results, out, overwrite=args.force)
    if args.json:
        print(json.dumps({"jobs": [r.summary for r in results], "files": files}, default=float))
        return 0
    head = ("job", "cell", "path", "setting", "time ms", "CF %", "freedom", "certify ms")
    rows = [
        (
            str(r.summary["job"]),
            r.summary["cell"],
            r.summary["path"],
            r.summary["setting"],
            f"{r.summary['time_ms']:.1f}",
            f"{r.summary['cf_percent']:.4f}",
            f"{r.summary['freedom']:.3f}",
            f"{r.summary['certify_ms']:.0f}" if "certify_ms" in r.summary else "-",
        )
        for r in results
    ]
    widths = [max(len(x) for x in col) for col in zip(head, *rows)]
    for row in (head, *rows):
        print("  ".join(x.ljust(w) for x, w in zip(row, widths)).rstrip())
    print(f"written to {out} (results.json and one bounds file per job)")
    return 0


def _add_batch(sub) -> None:
    """The ``batch`` command."""
    b = sub.add_parser(
        "batch",
        help="bounds, certificates and CF for many cells x paths x settings, in parallel "
        "on Dask's distributed scheduler",
    )
    b.add_argument("jobs", help="a jobs YAML file (cells, paths, settings; see drake_cfvol.apps.batch_jobs)")
    b.add_argument("--scheduler", help="a Dask scheduler's address (tcp://host:8786; default: a local cluster)")
    b.add_argument("--workers", type=int, help="the local cluster's worker processes (default: one per core)")
    b.add_argument("--serial", action="store_true", help="run the jobs here one after the other (no Dask)")
    b.add_argument("--out", help="output folder (default: <jobs file>_results beside it)")
    b.add_argument("--force", action="store_true", help="overwrite existing files in --out")
    b.add_argument("--json", action="store_true", help="print one JSON object")
    b.set_defaults(func=cmd_batch)


def _add_demo(sub) -> None:
    """The ``demo`` command."""
    d = sub.add_parser("demo", help="the main job: plan, bound and run the automotive cell")
    d.add_argument("--out", default="out/demo", help="output folder (default out/demo)")
    d.add_argument("--seed", type=int, default=0)
    d.add_argument("--quick", action="store_true", help="fewer CF samples")
    d.set_defaults(func=cmd_demo)


def build_parser() -> argparse.ArgumentParser:
    """The ``cfvol`` command line: plan, bounds, simulate, bench, batch, demo."""
    p = argparse.ArgumentParser(prog="cfvol", description=_DESCRIPTION)
    p.add_argument("--version", action="version", version=f"cfvol (drake_cfvol) {__version__}")
    sub = p.add_subparsers(dest="command", required=True)
    for add in (_add_plan, _add_bounds, _add_simulate, _add_bench, _add_batch, _add_demo):
        add(sub)
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    _quiet_drake()
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        # Files are written whole or not at all (records and caches go through a temporary file).
        print("cfvol: interrupted", file=sys.stderr)
        return 130
    except CfvolError as e:
        print(f"cfvol: error: {e}", file=sys.stderr)
        return 2
    except OSError as e:  # a file system error the library did not name itself
        where = f" '{e.filename}'" if getattr(e, "filename", None) else ""
        print(f"cfvol: error: {e.strerror or e}{where}.", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
