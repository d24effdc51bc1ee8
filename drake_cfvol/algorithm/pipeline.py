"""The orchestrator: the paper's Algorithm 1 from a planned path to a bounds
table (docs/spec.md, section 1).

categorize -> grow the volume V -> bound every joint at every waypoint
(fast backend or the Drake reference) -> optionally certify whole boxes.
"""

from __future__ import annotations

import time

import numpy as np

from drake_cfvol import kernel as K
from drake_cfvol.algorithm.certificate.certify import CUTS_SHARE, Certify, certified_table, certify_bounds, warm_up_cuts
from drake_cfvol.algorithm.planning import NominalPath
from drake_cfvol.algorithm.reference import drake_sweep_bounds
from drake_cfvol.algorithm.reuse import fingerprint_of
from drake_cfvol.algorithm.sweep import default_rate, stretch_bounds
from drake_cfvol.algorithm.table import (
    BoundsTable,
    absolute_bounds,
    intersection_stretches,
    waypoint_boxes,
)
from drake_cfvol.algorithm.volume import build_volume, categorize, height_map_of
from drake_cfvol.exceptions import DimensionError, ParameterError
from drake_cfvol.io.arguments import instance
from drake_cfvol.io.progress import timed_steps
from drake_cfvol.scene.params import VolumeParams
from drake_cfvol.scene.workcell import Workcell

__all__ = ["estimate_bounds", "BACKENDS", "warm_up"]

#: The joint-bounding backends.
BACKENDS = ("fast", "drake")


_warm_up_ms: float | None = None


def warm_up(*, progress: bool = False, meanwhile=()) -> float:
    """Compiles the kernel and the certificate's compiled cuts (or loads
    them from numba's cache) once per process; returns the milliseconds it
    took (0 after the first call). Never part of the paper's timing:
    :func:`estimate_bounds` calls it before its clock starts and reports it
    as ``info["jit_warmup_ms"]``. With ``progress``, a compile that takes
    longer than ~2 s (a fresh cache) shows a bar.

    Args:
        meanwhile: (name, call, share) steps of the caller's (other compiled
            code), run while a helper process compiles part of the kernel
            (:func:`drake_cfvol.kernel.warm_up`); share: its seconds in
            :data:`~drake_cfvol.kernel.STEP_SHARES`' terms.
    """
    global _warm_up_ms
    if _warm_up_ms is not None:
        return 0.0
    extra = [("certify_cuts", warm_up_cuts, CUTS_SHARE), *meanwhile]
    shares = K.warm_up_shares()
    shares.update({name: share for name, _, share in extra})
    if "helper" in shares:  # the wait for the helper, shortened by the steps run before it
        shares["helper"] = max(0.0, shares.pop("helper") - sum(share for _, _, share in extra))  # last
    with timed_steps(shares, "Compiling the collision kernel (once; numba caches it)", enabled=progress) as step:
        _warm_up_ms = K.warm_up(on_step=lambda name, seconds: step(name), meanwhile=[(n, c) for n, c, _ in extra]) * 1e3
    return _warm_up_ms


def _check_inputs(workcell, path, params, backend: str, certify) -> None:
    instance(workcell, Workcell, "workcell", "drake_cfvol.load_workcell")
    if params is not None:
        instance(params, VolumeParams, "params", "drake_cfvol.VolumeParams.for_workcell, or keyword overrides")
    if not isinstance(path, NominalPath):
        raise ParameterError(f"path must be a NominalPath, got {type(path).__name__}.")
    if path.k != workcell.num_joints:
        raise DimensionError(
            "the path's configurations",
            workcell.num_joints,
            path.k,
            f"The workcell's robot has joints {', '.join(workcell.joint_names)}.",
        )
    if backend not in BACKENDS:
        raise ParameterError(f"backend must be one of {', '.join(map(repr, BACKENDS))}, got {backend!r}.")
    if certify is not None and not isinstance(certify, Certify):
        raise ParameterError(f"certify must be a drake_cfvol.Certify or None, got {type(certify).__name__}.")


def _bound(workcell, W, vb, params, backend: str, progress: bool):
    """The bounding step: (waypoint lower, upper, stretch lower, upper,
    rate, stats). The fast backend bounds each stretch (absolute bounds
    nominal +- pi for a joint without limits) and rate-limits the waypoint
    boxes; the Drake backend bounds waypoints (no rate)."""
    if backend == "fast":
        lo_w, hi_w = absolute_bounds(workcell.position_lower, workcell.position_upper, W)
        lim_lo_st = np.maximum(lo_w[:-1], lo_w[1:])
        lim_hi_st = np.minimum(hi_w[:-1], hi_w[1:])
        st_lower, st_upper, stats = stretch_bounds(workcell.scene_arrays(), W, vb.volume, params, lim_lo_st, lim_hi_st)
        rate = default_rate(W, workcell.velocity_limits, params.waypoint_time)
        lower, upper = waypoint_boxes(st_lower, st_upper, W, rate)
        return lower, upper, st_lower, st_upper, rate, stats
    lower, upper, stats = drake_sweep_bounds(workcell, W, vb.volume, params, progress=progress)
    st_lower, st_upper = intersection_stretches(lower, upper)
    return lower, upper, st_lower, st_upper, None, stats


def estimate_bounds(
    workcell: Workcell,
    path: NominalPath,
    params: VolumeParams | None = None,
    *,
    backend: str = "fast",
    certify: Certify | None = None,
    progress: bool = False,
    **overrides: float | None,
) -> BoundsTable:
    """Algorithm 1: categorize, grow the volume, bound every joint at every
    waypoint.

    Args:
        workcell: the workcell.
        path: a nominal path of this workcell's robot.
        params: the parameters (default: the workcell's, see
            :meth:`VolumeParams.for_workcell`); ``overrides`` replace fields.
        backend: ``"fast"`` (primitives + height-field queries, any R) or
            ``"drake"`` (one SceneGraph box per column and Drake's checker;
            the reference, practical up to R ~ 1000-2000).
        certify: a :class:`drake_cfvol.Certify` to shrink the boxes until
            every stretch holds a sampled safety certificate (beyond the
            paper); its report is in ``info["certificate"]`` (``time_ms``: the
            run that computed it; ``cached``: loaded from the cache) and this
            call's time in ``timing_ms["certify"]`` (not part of the paper's
            ``total``).
        progress: progress bars on a terminal for the long steps (the
            kernel's first compile, the reference backend, certification);
            the fast bounding ends before a bar would show.

    Returns:
        The bounds table, its ``volume`` field set; ``timing_ms["total"]`` is
        the paper's "time to compute the boundaries" (categorization +
        volume + bounding).
    """
    _check_inputs(workcell, path, params, backend, certify)
    if params is None:
        params = VolumeParams.for_workcell(workcell, **overrides)
    elif overrides:
        params = params.replace(**overrides)
    height_map_of(workcell, params)  # checks R (memory) before any work
    jit_ms = warm_up(progress=progress) if backend == "fast" else 0.0
    workcell.scene_arrays()  # read from Drake once per workcell, like loading it
    t0 = time.perf_counter()
    cats = categorize(workcell, path, params)
    t1 = time.perf_counter()
    vb = build_volume(workcell, path, params, categories=cats)
    t2 = time.perf_counter()
    W = path.waypoints
    lower, upper, st_lower, st_upper, rate, stats = _bound(workcell, W, vb, params, backend, progress)
    t3 = time.perf_counter()
    lim_lo, lim_hi = absolute_bounds(workcell.position_lower, workcell.position_upper, W[0])
    stats.setdefault("clearance_m", float(params.clearance))
    info = {
        "cell": workcell.name,
        "path": path.label,
        "seed": path.seed,
        "backend": backend,
        "resolution": params.resolution,
        "n_boxes": vb.volume.n_boxes,
        "lowered_columns": vb.volume.lowered,
        "dropped_columns": vb.volume.dropped,
        "categories": {"trail": cats.trail, "goal": cats.goal, "no_goal": cats.no_goal},
        "cell_side_m": vb.volume.heightmap.side,
        "grid": list(vb.volume.heightmap.shape),
        "jit_warmup_ms": jit_ms,
        **stats,
        "fingerprint": fingerprint_of(workcell, path),
    }
    timing = {
        "categorize": (t1 - t0) * 1e3,
        "volume": (t2 - t1) * 1e3,
        "bounding": (t3 - t2) * 1e3,
        "total": (t3 - t0) * 1e3,
    }
    table = BoundsTable(
        lower,
        upper,
        W.copy(),
        list(workcell.joint_names),
        lim_lo,
        lim_hi,
        params.to_dict(),
        timing,
        info,
        volume=vb,
        stretch_lower=st_lower,
        stretch_upper=st_upper,
        rate=rate,
    )
    if certify is not None:
        info["uncertified_lower"], info["uncertified_upper"] = lower, upper
        t_c = time.perf_counter()
        c_lower, c_upper, report = certify_bounds(workcell, table, certify, progress=progress)
        certify_ms = (time.perf_counter() - t_c) * 1e3
        table = certified_table(table, c_lower, c_upper)
        table.info["certificate"] = report.to_dict()
        table.timing_ms["certify"] = certify_ms  # this call's (a cached certificate loads in ms)
    return table
