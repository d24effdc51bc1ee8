"""Steady corner-seeking pushes, safety filter on and off (a thin CLI over
drake_cfvol.comanip.adversarial.steady_push_runs).

    tools/dev.sh python tools/adversarial_runs.py --runs 16 --json out/adversarial.json
"""

import argparse
import json
import sys
import time

from drake_cfvol.comanip.adversarial import PATTERNS, steady_push_runs, summarize_runs


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--cells", nargs="+", default=["automotive", "aerospace"])
    p.add_argument("--runs", type=int, default=16, help="push seeds 0 .. runs-1 (default 16)")
    p.add_argument("--torque", type=float, default=1500.0, help="N m per joint (default 1500)")
    p.add_argument("--certify", action="store_true", help="certified bounds (default: the paper's, uncertified)")
    p.add_argument(
        "--clearance",
        type=float,
        nargs="+",
        default=[None],
        help="the filter's margin(s), m (default: the bounds' own)",
    )
    p.add_argument("--no-off", action="store_true", help="skip the runs without the filter")
    p.add_argument(
        "--pattern",
        choices=PATTERNS,
        default="random",
        help="push signs: random (seeded) or nearest (toward the nominal's nearest obstacle)",
    )
    p.add_argument("--json", help="write every row and the summary to this file")
    a = p.parse_args(argv)
    rows = []
    t0 = time.perf_counter()
    for cell in a.cells:
        kinds = [(True, c) for c in a.clearance] + ([] if a.no_off else [(False, None)])
        for on, clearance in kinds:
            rows += steady_push_runs(
                cell,
                a.runs,
                torque=a.torque,
                safety_filter=on,
                certify=a.certify,
                clearance=clearance,
                pattern=a.pattern,
                on_run=lambda r: print(
                    f"{r['cell']} seed {r['seed']:2d} filter {'on ' if r['safety_filter'] else 'off'}"
                    f" margin {r['margin_m']:.3f}: collisions {r['collisions']:4d} (Drake "
                    f"{r['drake_colliding_updates']:4d}), clearance {r['min_clearance_m'] * 1e3:7.1f} mm"
                    f" (nominal {r['nominal_min_clearance_m'] * 1e3:5.1f}), velocity ratio "
                    f"{r['max_velocity_ratio']:.4f}, filter steps {r['filter_steps']:4d}, max "
                    f"deviation {r['max_deviation']:.2f}, {r['sim_wall_s']:.1f} s",
                    flush=True,
                ),
            )
    summary = summarize_runs(rows)
    print()
    for s in summary:
        print(
            f"{s['cell']:10s} {s['pattern']} pushes, {'certified' if s['certify'] else 'uncertified'} bounds, "
            f"filter {'on ' if s['safety_filter'] else 'off'} margin {s['margin_m']:.3f} m: "
            f"{s['runs']} runs, {s['runs_with_collisions']} with collisions, {s['runs_margin_kept']} kept the "
            f"margin (worst shortfall {s['worst_shortfall_m'] * 1e3:.1f} mm), smallest clearance "
            f"{s['min_clearance_m'] * 1e3:.1f} mm (nominal's own {s['nominal_min_clearance_m'] * 1e3:.1f}), "
            f"largest velocity ratio {s['max_velocity_ratio']:.4f}, filter steps median "
            f"{s['filter_steps_median']:.0f} max {s['filter_steps_max']}, damper misses max "
            f"{s['damper_misses_max']}, max deviation {s['max_deviation']:.2f} (median {s['median_max_deviation']:.2f})"
        )
    print(f"wall {time.perf_counter() - t0:.0f} s")
    if a.json:
        with open(a.json, "w") as f:
            json.dump({"rows": rows, "summary": summary, "argv": sys.argv[1:]}, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
