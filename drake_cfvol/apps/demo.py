"""``cfvol demo``: the main job, end to end on the automotive cell."""

import json
import sys
import time
from pathlib import Path

from drake_cfvol.algorithm.metrics import confidence_factor, freedom, shown_percent
from drake_cfvol.algorithm.pipeline import estimate_bounds, warm_up
from drake_cfvol.algorithm.planning import plan_nominal_path
from drake_cfvol.comanip import load_scenario, run_scenario
from drake_cfvol.io.plotting import in_background, plot_bounds
from drake_cfvol.io.records import output_stem
from drake_cfvol.scene.params import VolumeParams
from drake_cfvol.scene.workcell import load_workcell
from drake_cfvol.systems.filter.compile_ahead import WARM_UP_SHARE
from drake_cfvol.systems.filter.compile_ahead import warm_up as warm_up_filter


def run_demo(*, out_dir: Path, seed: int = 0, quick: bool = False, resolution: int = 1000) -> int:
    """Plans the automotive cell's three paths, bounds path 1 (volume, CF,
    freedom; certified when the scenario asks, as it does by default), runs
    the ``automotive_push`` co-manipulation scenario on it with
    an offscreen Meshcat recording, and writes everything to ``out_dir``.

    Returns:
        Process exit code (0).
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    # The plots are drawn on the other core while the demo goes on.
    with in_background():
        t0 = time.perf_counter()
        wc = load_workcell("automotive")
        print(
            f"Cell '{wc.name}': {wc.robot_name}, k = {wc.num_joints}, {len(wc.obstacles)} obstacles "
            f"({(time.perf_counter() - t0) * 1e3:.0f} ms)\n"
        )

        # The kernel (compiled once, then loaded; the planner asks it first)
        # and, while a helper process compiles part of it, the safety filter.
        warm_up(progress=True, meanwhile=[("safety_filter", warm_up_filter, WARM_UP_SHARE)])
        print("1. Nominal paths (RRT-Connect, seed %d)" % seed)
        print(f"   {'path':<6} {'g':>4} {'length':>8} {'plan ms':>8} {'total ms':>9}  sha256[:12]")
        paths = {}
        for label in wc.configurations:
            p = plan_nominal_path(wc, *wc.configuration(label), seed=seed, label=label)
            p.save(out_dir / f"{output_stem(wc.name, label)}_path.json", overwrite=True)
            paths[label] = p
            print(
                f"   {label:<6} {p.g:>4} {p.length:>8.3f} {p.stats['plan_time_ms']:>8.1f} "
                f"{p.stats['total_time_ms']:>9.1f}  {p.sha256[:12]}"
            )

        scenario, _ = load_scenario("automotive_push")
        name, certify = scenario.path.name, scenario.certify()
        path = paths[name] if scenario.random_seed == seed else None
        if path is None:
            path = plan_nominal_path(
                wc,
                *wc.configuration(name),
                seed=scenario.random_seed,
                label=name,
                clearance=VolumeParams.for_workcell(wc, **scenario.bounds.overrides()).clearance,
            )
        print(f"\n2. Bounds for {path.label} at R = {resolution}" + (", certified" if certify else ""))
        table = estimate_bounds(wc, path, resolution=resolution, progress=True, certify=certify)
        cf = confidence_factor(wc, table, samples=2000 if quick else 10000, seed=seed, judge="kernel", progress=True)
        fr = freedom(table, wc.revolute)
        stem = output_stem(wc.name, path.label, resolution, certified=certify is not None)
        table.save(out_dir / f"{stem}_bounds.npz", overwrite=True)
        plot_bounds(
            table,
            out_dir / f"{stem}_bounds.png",
            revolute=wc.revolute,
            title=f"{wc.name} {path.label}, R = {resolution}" + (", certified" if certify else ""),
        )
        t = table.timing_ms
        print(
            f"   time {t['total']:.0f} ms (categorize {t['categorize']:.0f}, volume {t['volume']:.0f}, "
            f"bounding {t['bounding']:.0f}); {table.info['n_boxes']} columns"
        )
        if "certificate" in table.info:
            rep = table.info["certificate"]
            how = "loaded from the cache" if rep["cached"] else f"{table.timing_ms['certify'] / 1e3:.1f} s"
            print(
                f"   certified whole boxes ({how}): freedom {rep['freedom_before']:.3f} -> {rep['freedom_after']:.3f}; "
                f"{rep['n_samples']} samples free (epsilon {rep['epsilon']:g}, confidence "
                f"{rep['confidence']:g})"
            )
        print(
            f"   CF {shown_percent(cf.percent, cf.colliding, 3):.3f} % ({cf.colliding} of {cf.samples} samples collide; "
            f"Drake agrees on {cf.cross_checked - cf.kernel_only_colliding} of {cf.cross_checked} cross-checked); "
            f"freedom {fr.mean:.3f}"
        )
        cats = table.info["categories"]
        print(
            f"   trail: {', '.join(cats['trail']) or '-'} | goal: {', '.join(cats['goal']) or '-'} | "
            f"no-goal: {', '.join(cats['no_goal'])}"
        )

        print("\n3. Co-manipulation run (scenario automotive_push), recorded offscreen")
        s = run_scenario(
            "automotive_push",
            out_dir,
            path=path,
            bounds=table if scenario.bounds.resolution == resolution else None,
            progress=True,
            overwrite=True,  # the demo's folder is its own: each demo replaces the last
        )
        print(f"   {s.steps} logged steps over {s.duration_s:.1f} s (simulated in {s.sim_wall_s:.2f} s)")
        low = "-" if s.min_clearance_m is None else f"{s.min_clearance_m * 100:.1f} cm"  # None: no update logged
        print(
            f"   min clearance {low}, collisions {s.collisions}, "
            f"bound violation {s.max_bound_violation:.1e}, safety filter acted on {s.filter_steps} updates"
        )
        for note in s.notices:
            print(f"cfvol: note: {note}", file=sys.stderr)
        summary = {"cf_percent": cf.percent, "freedom": fr.mean, "bounds_time_ms": t["total"], "run": s.to_dict()}
        (out_dir / "demo_summary.json").write_text(json.dumps(summary, indent=1))
    print(f"\nEverything is in {out_dir.resolve()}:")
    for f in sorted(out_dir.iterdir()):
        print(f"   {f.name}")
    print("Open recording.html in a browser to replay the run.")
    return 0
