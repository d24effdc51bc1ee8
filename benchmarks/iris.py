"""IrisZo comparison: the certified box beside the best box inside Drake's
IrisZo region, at evenly spaced waypoints of each path.

Per path (R = 1000, clearance 0.02 m, seed 0, the certificate's cache off):

- certification through the public API (``estimate_bounds(..., certify=
  Certify(cache=False))``): its time (median of ``repeats`` runs) and the
  path's freedom, certified against uncertified;
- at each compared waypoint: IrisZo grown around the nominal with the
  workcell's own ``SceneGraphCollisionChecker`` padded to the clearance, the
  domain the joint limits, its seed fixed; the largest axis-aligned box that
  contains the nominal and lies inside the region, the joint limits and the
  uncertified box (:func:`largest_box`); 2,000 uniform samples of that box
  checked by the same padded checker; each box's measure
  (:func:`~drake_cfvol.algorithm.metrics.box_freedom`: the package's freedom of one box).

Where the nominal itself is nearer than the clearance (a start or goal the
user placed near an obstacle) IrisZo refuses a seed inside its padding;
there its checker is padded to the nominal's own clearance less 1 mm, as the
boundary check judges a certified box there (the certificate keeps about
the nominal's own clearance). IrisZo may still refuse (its seed within its
configuration-space margin of a collision): such a waypoint is reported,
not compared.

:func:`iris_targets` reports the comparison's targets as met or not with the
figures. ``cfvol bench --iris`` runs it.
"""

import dataclasses
import logging
import statistics
import sys
import time
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike
from pydrake.common import Parallelism
from pydrake.geometry.optimization import HPolyhedron, Hyperellipsoid
from pydrake.planning import IrisZo, IrisZoOptions, SceneGraphCollisionChecker
from pydrake.solvers import ClarabelSolver, MathematicalProgram

from benchmarks.realtime import CELLS
from benchmarks.report import machine_lines, targets_lines, write_results
from drake_cfvol.algorithm.certificate.certify import Certify
from drake_cfvol.algorithm.metrics import box_freedom, freedom
from drake_cfvol.algorithm.pipeline import estimate_bounds
from drake_cfvol.algorithm.planning import plan_nominal_path
from drake_cfvol.algorithm.table import BoundsTable
from drake_cfvol.exceptions import CfvolError, ParameterError
from drake_cfvol.scene.workcell import Workcell, load_workcell

__all__ = [
    "IrisBenchConfig",
    "TIME_TARGETS_S",
    "largest_box",
    "box_freedom",
    "iris_region",
    "run_iris_bench",
    "iris_targets",
    "iris_markdown",
    "write_iris_outputs",
]

#: Certification time targets, s (medians): (cell, path) -> seconds.
TIME_TARGETS_S = {("automotive", "path1"): 5.0, ("aerospace", "path2"): 15.0, ("mesh", "path1"): 15.0}

#: The starting ellipsoid's radius around the nominal, rad.
_SEED_RADIUS = 1e-3

#: Where the nominal is nearer than the clearance, IrisZo's padding is the
#: nominal's own clearance less this, m (the boundary check's allowance).
_NEAR_ALLOWANCE = 1e-3


@dataclasses.dataclass
class IrisBenchConfig:
    """What the IrisZo comparison runs.

    Attributes:
        cells: keys of :data:`benchmarks.realtime.CELLS`.
        paths: path labels; a cell is compared on those it has.
        waypoints: compared waypoints per path, evenly spaced, the ends included
            (8: six inside the path, where the nominal keeps the clearance, and
            the start and goal, where IrisZo may refuse a nominal placed near
            an obstacle).
        resolution: the bounds' R.
        clearance: the margin of the bounds, the certificate and IrisZo's
            padded checker, m.
        seed: the planner's, IrisZo's and the samples' seed.
        repeats: certification runs per path (the time is their median).
        samples: uniform samples of IRIS's box checked by Drake.
        iris_threads: IrisZo's parallelism.
    """

    cells: list = dataclasses.field(default_factory=lambda: ["automotive", "aerospace", "mesh"])
    paths: list = dataclasses.field(default_factory=lambda: ["path1", "path2", "path3"])
    waypoints: int = 8
    resolution: int = 1000
    clearance: float = 0.02
    seed: int = 0
    repeats: int = 3
    samples: int = 2000
    iris_threads: int = 2

    @classmethod
    def quick(cls) -> "IrisBenchConfig":
        """A smoke test (a few minutes): automotive path 1 at its ends and
        its middle, one certification, IrisZo on one thread."""
        return cls(cells=["automotive"], paths=["path1"], waypoints=3, repeats=1, iris_threads=1)


def largest_box(
    A: ArrayLike, b: ArrayLike, q: ArrayLike, lower: ArrayLike, upper: ArrayLike
) -> tuple[np.ndarray, np.ndarray]:
    """The axis-aligned box [lo, hi] of the largest geometric mean of widths
    that contains ``q`` and lies inside {x : A x <= b} and inside [lower, upper].

    For a row a of A, the largest value of a.x over the box is
    a+.hi - a-.lo (a+ = max(a, 0), a- = max(-a, 0)), so containment is
    linear in (lo, hi) and the problem is convex (Clarabel, a geometric-mean
    cone). Joints with no room (lower = upper = q) are held at q and left out
    of the mean, which would otherwise be 0 for every box. The solver's box
    is then scaled about ``q`` until every row holds exactly.

    Args:
        A, b: (m, k), (m,) the polytope.
        q: (k,) a point inside it and inside [lower, upper].
        lower, upper: (k,) the box the answer must lie in.

    Returns:
        (lo, hi), each (k,), lo <= q <= hi.

    Raises:
        ParameterError: shapes disagree, ``q`` lies outside the polytope or
            outside [lower, upper], or the solver fails.
    """
    A, b = np.atleast_2d(np.asarray(A, float)), np.asarray(b, float).ravel()
    q, lower, upper = (np.asarray(v, float).ravel() for v in (q, lower, upper))
    m, k = A.shape
    if b.shape != (m,) or q.shape != (k,) or lower.shape != (k,) or upper.shape != (k,):
        raise ParameterError(
            f"largest_box: A is {A.shape}, so b needs ({m},) and q, lower, upper ({k},); got b {b.shape}, "
            f"q {q.shape}, lower {lower.shape}, upper {upper.shape}."
        )
    slack = b - A @ q
    if np.any(slack < -1e-9 * (1.0 + np.abs(b))):
        raise ParameterError(
            f"largest_box: q lies outside the polytope (row {int(np.argmin(slack))} exceeded by "
            f"{-slack.min():.3g}); pass a point inside A x <= b."
        )
    if np.any(q < lower) or np.any(q > upper):
        raise ParameterError("largest_box: q lies outside [lower, upper]; pass bounds that contain it.")
    slack = np.maximum(slack, 0.0)
    Ap, Am = np.maximum(A, 0.0), np.maximum(-A, 0.0)
    room = upper > lower  # a joint may have room on one side of q only
    if not room.any():
        return q.copy(), q.copy()
    prog = MathematicalProgram()
    lo = prog.NewContinuousVariables(k, "lo")
    hi = prog.NewContinuousVariables(k, "hi")
    prog.AddBoundingBoxConstraint(np.where(room, lower, q), q, lo)
    prog.AddBoundingBoxConstraint(q, np.where(room, upper, q), hi)
    # a+.hi - a-.lo <= b for every row.
    prog.AddLinearConstraint(np.hstack([-Am, Ap]), np.full(m, -np.inf), b, np.concatenate([lo, hi]))
    j = np.flatnonzero(room)
    # Widths of the joints with room; scaled by their room so the cone is well conditioned
    # (the same argmax: a constant factor per width).
    M = np.zeros((len(j), 2 * k))
    M[np.arange(len(j)), j] = -1.0 / (upper[j] - lower[j])
    M[np.arange(len(j)), k + j] = 1.0 / (upper[j] - lower[j])
    if len(j) == 1:  # Drake's geometric-mean cost needs two terms: one width is maximised as it is
        prog.AddLinearCost(-M[0], 0.0, np.concatenate([lo, hi]))
    else:
        prog.AddMaximizeGeometricMeanCost(M, np.zeros(len(j)), np.concatenate([lo, hi]))
    result = ClarabelSolver().Solve(prog)
    if not result.is_success():
        raise ParameterError(f"largest_box: Clarabel failed ({result.get_solution_result()}).")
    lo_v = np.clip(result.GetSolution(lo), np.where(room, lower, q), q)
    hi_v = np.clip(result.GetSolution(hi), q, np.where(room, upper, q))
    # The solver meets the rows to its tolerance: scaling the box about q by
    # t <= slack / reach makes every row hold (a box's largest a.x grows linearly in t).
    reach = Ap @ (hi_v - q) + Am @ (q - lo_v)
    over = reach > slack
    if over.any():
        t = float(np.min(slack[over] / reach[over]))
        lo_v, hi_v = q + t * (lo_v - q), q + t * (hi_v - q)
    return lo_v, hi_v


class _Warnings(logging.Handler):
    """Collects drake's warnings (IrisZo's iteration caps void its guarantees)."""

    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.messages: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.messages.append(record.getMessage())


def iris_region(
    checker: SceneGraphCollisionChecker, q: ArrayLike, lower: ArrayLike, upper: ArrayLike, *, seed: int, threads: int
) -> tuple[HPolyhedron, list[str]]:
    """IrisZo grown around ``q`` with Drake's ``checker`` (a
    ``SceneGraphCollisionChecker``), the domain [lower, upper], IrisZo's
    default options but the seed and the threads. Returns the region and
    drake's warnings during the call."""
    opts = IrisZoOptions()
    opts.sampled_iris_options.random_seed = int(seed)
    opts.sampled_iris_options.parallelism = Parallelism(int(threads))
    log = logging.getLogger("drake")
    handler, level = _Warnings(), log.level
    log.addHandler(handler)
    log.setLevel(logging.WARNING)  # its INFO lines per iteration are noise here
    try:
        region = IrisZo(
            checker,
            Hyperellipsoid.MakeHypersphere(_SEED_RADIUS, np.asarray(q, float)),
            HPolyhedron.MakeBox(lower, upper),
            opts,
        )
    finally:
        log.removeHandler(handler)
        log.setLevel(level)
    return region, handler.messages


def _padding(wc: Workcell, q: np.ndarray, clearance: float) -> float:
    """IrisZo's padding at ``q``: the clearance, or where the nominal is
    nearer, its own clearance less :data:`_NEAR_ALLOWANCE`."""
    if wc.padded_checker(clearance).CheckConfigCollisionFree(q):
        return clearance
    return max(0.0, min(clearance, wc.clearance(q)) - _NEAR_ALLOWANCE)


def _compare(wc: Workcell, i: int, unc: BoundsTable, cert: BoundsTable | None, cfg: IrisBenchConfig) -> dict:
    """One waypoint: IrisZo, the largest box inside it and the uncertified
    box, its samples by Drake and the measures (``cert`` None: no
    certified table, its measure NaN)."""
    q = unc.nominal[i]
    lim_lo, lim_hi = unc.limit_lower, unc.limit_upper
    pad = _padding(wc, q, cfg.clearance)
    checker = wc.padded_checker(pad)
    row = {
        "waypoint": int(i),
        "padding_m": pad,
        "uncertified": box_freedom(unc.lower[i], unc.upper[i], lim_lo, lim_hi),
        "certified": float("nan") if cert is None else box_freedom(cert.lower[i], cert.upper[i], lim_lo, lim_hi),
    }
    t0 = time.perf_counter()
    try:
        region, warnings = iris_region(checker.drake, q, lim_lo, lim_hi, seed=cfg.seed, threads=cfg.iris_threads)
    except RuntimeError as e:  # IrisZo refuses a seed in collision
        return {**row, "iris_s": time.perf_counter() - t0, "refused": str(e)}
    row["iris_s"] = time.perf_counter() - t0
    row["faces"], row["warnings"] = int(region.A().shape[0]), warnings
    if not region.PointInSet(q, 1e-9):
        return {**row, "refused": "IrisZo's region does not contain the nominal"}
    t0 = time.perf_counter()
    lo, hi = largest_box(region.A(), region.b(), q, np.maximum(lim_lo, unc.lower[i]), np.minimum(lim_hi, unc.upper[i]))
    row["box_s"] = time.perf_counter() - t0
    rng = np.random.default_rng([cfg.seed, int(i)])
    S = lo + rng.random((cfg.samples, len(q))) * (hi - lo)
    free = np.asarray(checker.CheckConfigsCollisionFree(S, parallelize=True), bool)
    iris = box_freedom(lo, hi, lim_lo, lim_hi)
    return {
        **row,
        "iris": iris,
        "ratio": row["certified"] / iris if iris > 0 else float("inf"),  # NaN without a certified table
        "samples": int(len(S)),
        "colliding": int((~free).sum()),
        "free_share": float(free.mean()),
        "iris_lower": lo.tolist(),
        "iris_upper": hi.tolist(),
    }


def _say(progress: bool, text: str) -> None:
    if progress:
        print(f"[iris] {text}", file=sys.stderr, flush=True)


def run_path(cell: str, label: str, cfg: IrisBenchConfig, *, progress: bool = False) -> dict:
    """One path: certification timed first (nothing else running), then the
    comparison at ``cfg.waypoints`` evenly spaced waypoints."""
    wc = load_workcell(CELLS[cell])
    if wc.slice.extra:
        raise ParameterError(
            f"the IrisZo comparison needs a cell whose plant moves only the robot's joints; {cell} has "
            f"{wc.plant.num_positions()} positions for {wc.num_joints} joints (IrisZo would grow in all of them)."
        )
    path = plan_nominal_path(wc, *wc.configuration(label), seed=cfg.seed, label=label, clearance=cfg.clearance)
    unc = estimate_bounds(wc, path, resolution=cfg.resolution, clearance=cfg.clearance)
    times, cert, error = [], None, None
    for _ in range(cfg.repeats):
        try:
            cert = estimate_bounds(
                wc, path, resolution=cfg.resolution, clearance=cfg.clearance, certify=Certify(cache=False)
            )
        except CfvolError as e:  # kept as the path's result; IRIS is still measured against the uncertified box
            cert, error = None, f"{type(e).__name__}: {e}"
            _say(progress, f"{cell} {label}: certification failed: {error}")
            break
        times.append(cert.timing_ms["certify"] / 1e3)
        _say(progress, f"{cell} {label}: certified in {times[-1]:.1f} s")
    idx = np.unique(np.linspace(0, path.g - 1, cfg.waypoints).round().astype(int))
    rows = []
    for i in idx:
        rows.append(_compare(wc, int(i), unc, cert, cfg))
        r = rows[-1]
        _say(
            progress,
            f"{cell} {label} waypoint {i}: "
            + (
                f"refused ({r['refused']})"
                if "refused" in r
                else f"ours {r['certified']:.3f}, IRIS's box {r['iris']:.3f}, free {r['free_share']:.4f}, "
                f"IrisZo {r['iris_s']:.1f} s"
            ),
        )
    iris_s = [r["iris_s"] for r in rows if "refused" not in r]
    return {
        "cell": cell,
        "path": label,
        "g": path.g,
        "k": path.k,
        "certify_error": error,
        "certify_s": statistics.median(times) if times and not error else float("nan"),
        "certify_s_runs": times,
        "freedom_uncertified": freedom(unc).mean,
        "freedom_certified": freedom(cert).mean if cert is not None else float("nan"),
        "certificate": {}
        if cert is None
        else {k: v for k, v in cert.info.get("certificate", {}).items() if k not in ("proven", "sampled")},
        "iris_s_median": statistics.median(iris_s) if iris_s else float("nan"),
        "waypoints": rows,
    }


def run_iris_bench(cfg: IrisBenchConfig, *, progress: bool = True) -> dict:
    """Every path of ``cfg`` (see the module)."""
    t0 = time.perf_counter()
    paths = []
    for cell in cfg.cells:
        wc = load_workcell(CELLS[cell])
        for label in cfg.paths:
            if label in wc.configurations:
                paths.append(run_path(cell, label, cfg, progress=progress))
    return {"config": dataclasses.asdict(cfg), "paths": paths, "wall_s": time.perf_counter() - t0}


def _compared(p: dict) -> list[dict]:
    """A path's waypoints where IRIS's box is free by every sample."""
    return [r for r in p["waypoints"] if "refused" not in r and r["colliding"] == 0]


def iris_targets(result: dict) -> list[tuple[str, bool, str]]:
    """(target, met, the figures) for the freedom target on every path and
    the time targets on the paths that have one."""
    out = []
    for p in result["paths"]:
        name = f"{p['cell']} {p['path']}"
        error = p.get("certify_error")
        if error:
            out.append((f"{name}: certification", False, f"failed: {error}"))
            continue
        free = _compared(p)
        short = [r for r in free if r["certified"] < r["iris"]]
        others = len(p["waypoints"]) - len(free)
        text = f"{len(free)} waypoints compared ({others} not: IRIS's box collided or IrisZo refused)"
        if free:
            worst = min(free, key=lambda r: r["ratio"])
            text += f"; smallest ours / IRIS's {worst['ratio']:.2f} at waypoint {worst['waypoint']}"
        if short:
            text += "; narrower at " + ", ".join(
                f"{r['waypoint']} ({r['certified']:.3f} < {r['iris']:.3f})" for r in short
            )
        out.append((f"{name}: certified box >= IRIS's box ∩ uncertified where IRIS's is free", not short, text))
        limit = TIME_TARGETS_S.get((p["cell"], p["path"]))
        if limit is not None:
            s = p["certify_s"]
            runs = ", ".join(f"{t:.1f}" for t in p["certify_s_runs"])
            out.append(
                (
                    f"{name}: certification <= {limit:g} s",
                    s <= limit,
                    f"median {s:.1f} s of {len(p['certify_s_runs'])} ({runs})"
                    + ("" if s <= limit else f", {s / limit:.1f}x over"),
                )
            )
    return out


def iris_markdown(result: dict, machine: dict | None = None) -> str:
    """The comparison as Markdown: the targets, then a table per path."""
    cfg = result["config"]
    lines = [
        "# IrisZo comparison: the certified box beside the best box inside Drake's IrisZo region",
        "",
        f"R = {cfg['resolution']}, clearance {cfg['clearance']} m, seed {cfg['seed']}, the certificate's cache "
        f"off; certification time the median of {cfg['repeats']} runs. At {cfg['waypoints']} evenly spaced "
        f"waypoints per path: IrisZo ({cfg['iris_threads']} threads, default options) around the nominal with "
        "the workcell's checker padded to the clearance (to the nominal's own clearance less 1 mm where the "
        "nominal is nearer), the domain the joint limits; IRIS's box is the largest axis-aligned box containing "
        "the nominal inside its region, the joint limits and the uncertified box (the geometric mean of widths "
        f"maximised, Clarabel); {cfg['samples']:,} uniform samples of it checked by the same padded checker. "
        "Measure of a box: the geometric mean over joints of width / joint range (the package's freedom). "
        "`cfvol bench --iris` writes it.",
        "",
    ]
    lines += machine_lines(machine, result["wall_s"]) + targets_lines(iris_targets(result))
    lines += [
        "",
        "## Paths",
        "",
        "| cell | path | g | certification s (median) | freedom uncertified | freedom certified | "
        "IrisZo s per region (median) | IrisZo s for every waypoint (extrapolated) |",
        "|---|---|---:|---:|---:|---:|---:|---:|",
    ]
    for p in result["paths"]:
        lines.append(
            f"| {p['cell']} | {p['path']} | {p['g']} | {p['certify_s']:.1f} | {p['freedom_uncertified']:.3f} | "
            f"{p['freedom_certified']:.3f} | {p['iris_s_median']:.1f} | {p['iris_s_median'] * p['g']:.0f} |"
        )
    for p in result["paths"]:
        lines += [
            "",
            f"### {p['cell']} {p['path']}",
            "",
            *([f"Certification failed: {p['certify_error']}", ""] if p.get("certify_error") else []),
            "| waypoint | padding mm | uncertified | certified (ours) | IRIS's box ∩ uncertified | ours / IRIS's "
            "| IRIS's box free share | IrisZo s | faces | IrisZo warnings |",
            "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
        ]
        for r in p["waypoints"]:
            head = f"| {r['waypoint']} | {1e3 * r['padding_m']:.1f} | {r['uncertified']:.3f} | {r['certified']:.3f} "
            if "refused" in r:
                lines.append(head + f"| refused: {r['refused']} | | | {r['iris_s']:.1f} | | |")
                continue
            lines.append(
                head + f"| {r['iris']:.3f} | {r['ratio']:.2f} | {r['free_share']:.4f} ({r['colliding']} of "
                f"{r['samples']:,} collide) | {r['iris_s']:.1f} | {r['faces']} | {len(r['warnings'])} |"
            )
    return "\n".join(lines) + "\n"


def write_iris_outputs(result: dict, out_dir: str | Path, machine: dict | None = None) -> dict:
    """results.json and results.md in ``out_dir``."""
    return write_results(out_dir, result, iris_markdown(result, machine), machine)
