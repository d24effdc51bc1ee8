"""Many paths at once: ``cfvol batch JOBS.yaml`` computes bounds, their
certificates and CF for every cell x path x setting of a jobs file, in
parallel on Dask's distributed scheduler (the optional extra
``drake-cfvol[cluster]``): a ``LocalCluster`` on this machine by default, or
the cluster at a scheduler's address.

A jobs file (read over the defaults with ``yaml_load_typed``, as scenarios
are)::

    cells: [automotive, aerospace]      # built-in names or workcell YAML paths
    paths: [path1, path2, path3]
    settings:
      - {resolution: 1000, clearance: 0.0}
      - {resolution: 1000, certify: true, seed: 1}

Every job is deterministic (its seed fixes the path, the bounds, the
certificate and CF), so a batch gives exactly what the same jobs give one
after the other in one process (:func:`run_batch` with ``scheduler="serial"``;
``tests/test_batch.py`` checks it).
"""

import dataclasses
import functools
import json
import logging
import os
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from drake_cfvol.exceptions import BatchError, CfvolError
from drake_cfvol.io.progress import Progress
from drake_cfvol.io.records import path_label, prepare_outputs

if TYPE_CHECKING:  # imported where used: `cfvol batch --help` loads no Drake
    from drake_cfvol.algorithm.table import BoundsTable

__all__ = [
    "BatchSettings",
    "BatchJobs",
    "Job",
    "JobResult",
    "load_jobs",
    "expand_jobs",
    "run_job",
    "run_batch",
    "write_batch",
    "output_files",
]


@dataclasses.dataclass
class BatchSettings:
    """One setting, run on every cell and path of the batch.

    Attributes:
        name: the setting's label in file names and results (default
            ``R<resolution>``, ``-certified`` when certified, ``-c<clearance>``
            when one is given).
        resolution: height-map cells R, a count (>= 1).
        clearance: margin kept from the obstacles and the robot itself, m
            (>= 0; None: the cell's default); planning keeps it too.
        certify: certify the whole boxes (:class:`drake_cfvol.Certify`).
        epsilon, confidence: the certificate's largest colliding share and
            its probability of being right, each in (0, 1) (Certify's).
        boundary_proof: prove the boxes' edges and corners too (Certify's
            ``boundary``).
        cache: reuse a certificate computed before for the same inputs.
        cf_windows, cf_samples: the Confidence Factor's N_tw and N_m: the
            path split into this many equal windows, this many samples
            checked in each; counts (>= 1).
        seed: the planner's, the certificate's and CF's seed.
    """

    name: str = ""
    resolution: int = 1000
    clearance: float | None = None
    certify: bool = False
    epsilon: float = 1e-5
    confidence: float = 0.99
    boundary_proof: bool = True
    cache: bool = True
    cf_windows: int = 30
    cf_samples: int = 10000
    seed: int = 0

    @property
    def label(self) -> str:
        if self.name:
            return self.name
        return (
            f"R{self.resolution}"
            + ("-certified" if self.certify else "")
            + (f"-c{self.clearance:g}" if self.clearance is not None else "")
        )


@dataclasses.dataclass
class BatchJobs:
    """A jobs file: every cell x path x setting is one job.

    Attributes:
        cells: built-in cell names or workcell YAML paths (relative to the
            jobs file).
        paths: configuration pairs of each cell (``path1`` or ``1``).
        settings: the settings to run on each (cell, path).
    """

    cells: list[str] = dataclasses.field(default_factory=list)
    paths: list[str] = dataclasses.field(default_factory=lambda: ["path1"])
    settings: list[BatchSettings] = dataclasses.field(default_factory=lambda: [BatchSettings()])


@dataclasses.dataclass(frozen=True)
class Job:
    """One job: a cell (name or resolved file), a path label, a setting."""

    index: int
    cell: str
    path: str
    setting: BatchSettings

    @property
    def stem(self) -> str:
        return f"{Path(self.cell).stem}_{self.path}_{self.setting.label}"


@dataclasses.dataclass
class JobResult:
    """What a job gives: its summary (figures as ``cfvol bounds --json``
    prints them) and its bounds table."""

    job: Job
    summary: dict
    table: "BoundsTable"


def _checked_settings(jobs: BatchJobs, file) -> None:
    if not jobs.cells:
        raise BatchError(file, "cells", "is empty: name at least one cell (a built-in name or a workcell YAML path)")
    if not jobs.paths or not jobs.settings:
        raise BatchError(file, "paths" if not jobs.paths else "settings", "is empty: give at least one")
    labels = [s.label for s in jobs.settings]
    for i, s in enumerate(jobs.settings, 1):
        where = f"settings item {i}"
        if s.resolution < 1:
            raise BatchError(file, f"{where}: resolution", f"must be >= 1, got {s.resolution}")
        if s.clearance is not None and s.clearance < 0:
            raise BatchError(file, f"{where}: clearance", f"must be >= 0 m, got {s.clearance}")
        if s.cf_windows < 1 or s.cf_samples < 1:
            raise BatchError(file, f"{where}: cf_windows", "and cf_samples must be >= 1")
        for name in ("epsilon", "confidence"):
            if not 0.0 < getattr(s, name) < 1.0:
                raise BatchError(file, f"{where}: {name}", f"must lie in (0, 1), got {getattr(s, name)}")
        if s.label in labels[: i - 1]:
            raise BatchError(
                file, f"{where}: name", f"'{s.label}' is used by another setting too: give each setting its own name"
            )


def load_jobs(file: str | Path | None = None, *, text: str | None = None) -> tuple[BatchJobs, Path | None]:
    """Reads a jobs file (or YAML ``text``) over the defaults and checks it:
    unknown fields and values of the wrong type are named with the file,
    the field and the fix (:class:`drake_cfvol.BatchError`)."""
    from drake_cfvol.io.typed_yaml import load_typed

    where = Path(file) if file is not None else Path("<text>")
    if file is not None and not where.is_file():
        raise BatchError(where, None, "does not exist: pass the path of a jobs YAML file")

    def error(field: str | None, message: str, line: int | None) -> BatchError:
        return BatchError(where, field, message, line)

    jobs, _ = load_typed(BatchJobs, where, error, text=None if file is not None else text or "", defaults=BatchJobs())
    _checked_settings(jobs, where)
    return jobs, (where.resolve() if file is not None else None)


def expand_jobs(jobs: BatchJobs, base_dir: Path | None = None) -> list[Job]:
    """Every cell x path x setting as a :class:`Job`, in that order; cell
    files relative to ``base_dir`` (the jobs file's folder)."""
    from drake_cfvol.comanip.scenario_checks import cell_file
    from drake_cfvol.scene.schema import builtin_cells

    labels = [path_label(label) for label in jobs.paths]
    out: list[Job] = []
    for cell in jobs.cells:
        if cell not in builtin_cells():
            p = cell_file(str(Path(cell).expanduser()), base_dir)
            if not p.is_file():
                raise BatchError(
                    base_dir or "<text>",
                    "cells",
                    f"'{cell}' is neither a built-in cell ({', '.join(sorted(builtin_cells()))}) nor a workcell file",
                )
            cell = str(p.resolve())
        for label in labels:
            for s in jobs.settings:
                out.append(Job(len(out), cell, label, s))
    return out


#: Jobs in one process run one at a time: they share its workcells (Drake's
#: checker and its contexts, not for two threads at once) and numba's
#: thread pool, which already uses the cores.
_JOB_LOCK = threading.Lock()


@functools.lru_cache(maxsize=8)
def _workcell(cell: str):
    """One workcell per cell and process (a worker runs many jobs)."""
    from drake_cfvol.scene.workcell import load_workcell

    return load_workcell(cell)


def run_job(job: Job, threads: int | None = None) -> JobResult:
    """Runs one job where it is called (a Dask worker, or this process):
    plan the path, compute the bounds (and their certificate), CF and
    freedom. ``threads``: the kernel's threads (None: numba's default).
    A worker with several threads runs its jobs one after the other
    (:data:`_JOB_LOCK`)."""
    with _JOB_LOCK:
        return _run_job(job, threads)


def _run_job(job: Job, threads: int | None) -> JobResult:
    from drake_cfvol.algorithm.certificate.certify import Certify
    from drake_cfvol.algorithm.metrics import confidence_factor, freedom
    from drake_cfvol.algorithm.pipeline import estimate_bounds
    from drake_cfvol.algorithm.planning import plan_nominal_path

    if threads is not None:
        import numba

        # numba sets its config's names at run time (from the environment): no stub has them.
        numba.set_num_threads(max(1, min(int(threads), getattr(numba.config, "NUMBA_NUM_THREADS"))))
    s = job.setting
    wc = _workcell(job.cell)
    t0 = time.perf_counter()
    path = plan_nominal_path(wc, *wc.configuration(job.path), seed=s.seed, label=job.path, clearance=s.clearance)
    certify = (
        Certify(epsilon=s.epsilon, confidence=s.confidence, seed=s.seed, boundary=s.boundary_proof, cache=s.cache)
        if s.certify
        else None
    )
    extra: dict[str, Any] = {} if s.clearance is None else {"clearance": s.clearance}
    table = estimate_bounds(wc, path, resolution=s.resolution, certify=certify, **extra)
    t_cf = time.perf_counter()
    cf = confidence_factor(wc, table, windows=s.cf_windows, samples=s.cf_samples, seed=s.seed)
    cf_ms = (time.perf_counter() - t_cf) * 1e3
    summary = {
        "job": job.index,
        "cell": wc.name,
        "path": job.path,
        "setting": s.label,
        "seed": s.seed,
        "resolution": s.resolution,
        "clearance_m": table.params.get("clearance"),
        "g": table.g,
        "k": table.k,
        "waypoints_sha256": path.sha256,
        "time_ms": table.timing_ms["total"],
        "timing_ms": dict(table.timing_ms),
        "cf_percent": cf.percent,
        "cf_samples": cf.samples,
        "cf_colliding": cf.colliding,
        "cf_ms": cf_ms,
        "freedom": freedom(table, wc.revolute).mean,
        "certified": "certificate" in table.info,
        "job_ms": (time.perf_counter() - t0) * 1e3,
        "worker": os.getpid(),
    }
    if "certificate" in table.info:
        rep = table.info["certificate"]
        summary.update(
            {
                "certify_ms": rep["time_ms"],
                "certify_cached": bool(rep.get("cached")),
                "certify_shrinks": rep["shrinks"],
                "certify_n_samples": rep["n_samples"],
                "certify_samples": rep["samples"],
                "certify_region_tests": (rep.get("boundary") or {}).get("edge_tests", 0),
                "certified_freedom": rep["freedom_after"],
                "certified_freedom_kept": rep["freedom_after"] / rep["freedom_before"]
                if rep["freedom_before"]
                else None,
            }
        )
    return JobResult(job, summary, table)


def _client(scheduler: str | None, workers: int | None):
    """A Dask client: on the scheduler at ``scheduler``'s address, or on a
    new LocalCluster of ``workers`` single-threaded processes (default: one
    per core). Returns (client, cluster or None)."""
    try:
        from distributed import Client, LocalCluster
    except ImportError:
        raise BatchError(
            "--scheduler" if scheduler else "the batch",
            None,
            "needs Dask's distributed scheduler, an optional extra: pip install "
            "'drake-cfvol[cluster]' (or run the jobs one after the other with --serial)",
        ) from None
    if scheduler:
        try:
            return Client(scheduler, timeout="20s"), None
        except (OSError, TimeoutError) as e:
            raise BatchError(
                scheduler,
                None,
                f"no Dask scheduler answers there ({e}); start one (dask scheduler) "
                "or leave out --scheduler for a local cluster",
            ) from None
    n = workers or os.cpu_count() or 1
    cluster = LocalCluster(
        n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None, silence_logs=logging.ERROR
    )
    return Client(cluster), cluster


def _kernel_threads(workers: int) -> int:
    """The kernel's threads in each of a local cluster's ``workers``
    processes: the cores shared out (one each when there are as many
    workers as cores)."""
    return max(1, (os.cpu_count() or 1) // max(1, workers))


def run_batch(
    jobs: list[Job], *, scheduler: str | None = None, workers: int | None = None, progress: bool = True, client=None
) -> list[JobResult]:
    """Runs the jobs and returns their results in the jobs' order.

    Args:
        jobs: from :func:`expand_jobs`.
        scheduler: ``"serial"`` (one after the other, in this process, no
            Dask), a Dask scheduler's address (``tcp://host:8786``), or None:
            a LocalCluster here.
        workers: the LocalCluster's processes (default: one per core); the
            cores are shared out among them (one kernel thread each by
            default; both cores for ``workers=1`` on two).
        progress: a bar of the jobs done (on a terminal).
        client: a ``distributed.Client`` of your own (then ``scheduler``
            and ``workers`` are not used).
    """
    if client is None and scheduler is None:
        # Compiled here first (once, with its own bar): the local workers then load it from numba's cache.
        from drake_cfvol.algorithm.pipeline import warm_up

        warm_up(progress=progress)
    bar = Progress(len(jobs), "Batch jobs", enabled=progress, unit="jobs")
    out: list[JobResult | None] = [None] * len(jobs)
    try:
        if scheduler == "serial" and client is None:
            for job in jobs:
                out[job.index] = run_job(job)
                bar.update(1)
            return _every_job(out)
        own = client is None
        cluster = None
        if own:
            client, cluster = _client(scheduler, workers)
        try:
            from distributed import as_completed

            threads = _kernel_threads(len(cluster.workers)) if cluster is not None else None
            futures = client.map(run_job, jobs, threads=threads, pure=False)
            for fut in as_completed(futures):
                res = fut.result()
                out[res.job.index] = res
                bar.update(1, last=res.job.stem)
        finally:
            if own:
                client.close()
                if cluster is not None:
                    cluster.close()
    finally:
        bar.close()
    return _every_job(out)


def _every_job(out: list[JobResult | None]) -> list[JobResult]:
    """The results, every job's slot filled (run_batch ran them all)."""
    done = [r for r in out if r is not None]
    assert len(done) == len(out)
    return done


def output_files(jobs: list[Job], out: str | Path, *, overwrite: bool = False) -> dict:
    """The files a batch writes into the folder ``out``: each job's bounds
    (``<cell>_<path>_<setting>_bounds.npz``) and ``results.json``; checked
    before anything runs (the folder can be made, nothing that exists is
    replaced unless ``overwrite``)."""
    keys = [j.stem for j in jobs] + ["results"]
    names = [f"{j.stem}_bounds.npz" for j in jobs] + ["results.json"]
    return dict(zip(keys, prepare_outputs(out, names, overwrite=overwrite)))


def write_batch(results: list[JobResult], out: str | Path, *, overwrite: bool = False) -> dict:
    """Writes every job's bounds and ``results.json`` (every job's summary)
    into the folder ``out`` (:func:`output_files`). Returns the files."""
    files = output_files([r.job for r in results], out, overwrite=overwrite)
    for r in results:
        r.table.save(files[r.job.stem], overwrite=overwrite)
    files["results"].write_text(
        json.dumps([dict(r.summary, bounds_file=str(files[r.job.stem])) for r in results], indent=1, default=_plain)
    )
    return {k: str(v) for k, v in files.items()}


def _plain(v):
    if isinstance(v, np.generic):
        return v.item()
    if isinstance(v, np.ndarray):
        return v.tolist()
    raise CfvolError(f"cannot write {type(v).__name__} to results.json")
