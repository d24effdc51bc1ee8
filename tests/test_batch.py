"""Batches of jobs (cfvol batch): the jobs file, Dask against the serial run, outputs."""

import json
import pickle
import sys

import numpy as np
import pytest

import drake_cfvol as cf
from drake_cfvol.apps.batch_jobs import expand_jobs, load_jobs, output_files, run_batch, write_batch
from drake_cfvol.apps.cli import main

#: Two paths of one cell at a small R and few CF samples: seconds per job.
SMALL = """
cells: [automotive]
paths: [path1, path2]
settings:
  - {resolution: 100, clearance: 0.0, cf_windows: 5, cf_samples: 400}
  - {name: fine, resolution: 2000, cf_windows: 5, cf_samples: 400, seed: 3}
"""


def _same(a, b):
    """Two job results agree in everything but where and how fast they ran."""
    skip = {"worker", "time_ms", "timing_ms", "cf_ms", "job_ms", "certify_ms"}
    assert {k: v for k, v in a.summary.items() if k not in skip} == {
        k: v for k, v in b.summary.items() if k not in skip
    }
    for name in ("lower", "upper", "nominal", "stretch_lower", "stretch_upper", "rate"):
        np.testing.assert_array_equal(getattr(a.table, name), getattr(b.table, name))


def test_jobs_expand_cells_paths_settings_in_order():
    """Every cell x path x setting is a job, numbered in that order, with its own file stem."""
    jobs, _ = load_jobs(text=SMALL)
    todo = expand_jobs(jobs)
    assert [(j.path, j.setting.label) for j in todo] == [
        ("path1", "R100-c0"),
        ("path1", "fine"),
        ("path2", "R100-c0"),
        ("path2", "fine"),
    ]
    assert [j.index for j in todo] == [0, 1, 2, 3]
    assert len({j.stem for j in todo}) == 4


@pytest.mark.parametrize(
    "text, field, words",
    [
        ("cells: [automotive]\nsettings: [{resolutoin: 10}]", "settings item 1: resolutoin", "known fields"),
        ("cells: [automotive]\nsettings: [{resolution: many}]", "settings item 1: resolution", "an integer"),
        ("cells: []", "cells", "at least one cell"),
        ("cells: [automotive]\nsettings: [{resolution: 0}]", "settings item 1: resolution", ">= 1"),
        ("cells: [automotive]\nsettings: [{epsilon: 2}]", "settings item 1: epsilon", "(0, 1)"),
        (
            "cells: [automotive]\nsettings: [{resolution: 100}, {resolution: 100}]",
            "settings item 2: name",
            "its own name",
        ),
    ],
)
def test_bad_jobs_file_names_the_field(text, field, words):
    """A wrong field, type or value raises BatchError naming the field and the fix."""
    with pytest.raises(cf.BatchError) as e:
        load_jobs(text=text)
    assert e.value.field == field and words in str(e.value)


def test_unknown_cell_lists_the_built_in_ones(tmp_path):
    """A cell that is neither built in nor a file is named with the built-in cells."""
    jobs, _ = load_jobs(text="cells: [nowhere.yaml]")
    with pytest.raises(cf.BatchError, match="automotive"):
        expand_jobs(jobs, tmp_path)


@pytest.mark.slow
def test_batch_on_dask_equals_the_serial_run():
    """The same jobs through Dask's distributed scheduler give exactly the serial results, in the jobs' order."""
    from distributed import Client

    jobs, _ = load_jobs(text=SMALL)
    todo = expand_jobs(jobs)[:2]  # (the CLI test below runs all four on worker processes)
    serial = run_batch(todo, scheduler="serial", progress=False)
    with Client(processes=False, n_workers=2, threads_per_worker=1, dashboard_address=None) as client:
        dist = run_batch(todo, client=client, progress=False)
    assert [r.job.index for r in dist] == [0, 1]
    for a, b in zip(serial, dist):
        _same(a, b)
    # The setting's seed reaches the planner: the two settings of a path plan different paths.
    assert serial[0].summary["waypoints_sha256"] != serial[1].summary["waypoints_sha256"]


def test_bounds_table_pickles_without_its_volume():
    """A table crosses processes as it is saved: arrays equal, trajectory rebuilt, no volume."""
    wc = cf.load_workcell("automotive")
    table = cf.estimate_bounds(wc, cf.plan_nominal_path(wc, *wc.configuration("path1"), seed=0), resolution=100)
    back = pickle.loads(pickle.dumps(table))
    assert back.volume is None and table.volume is not None
    np.testing.assert_array_equal(back.lower, table.lower)
    np.testing.assert_array_equal(back.trajectory.value(3.5).ravel(), table.trajectory.value(3.5).ravel())


def test_outputs_are_checked_before_anything_runs(tmp_path):
    """An existing results file is refused (nothing is replaced) unless overwrite is given."""
    todo = expand_jobs(load_jobs(text=SMALL)[0])
    (tmp_path / "results.json").write_text("mine")
    with pytest.raises(cf.OutputExistsError):
        output_files(todo, tmp_path)
    assert (tmp_path / "results.json").read_text() == "mine"


def test_write_batch_files_load_back(tmp_path):
    """results.json lists every job; each bounds file loads back to the job's table."""
    todo = expand_jobs(load_jobs(text=SMALL)[0])[:1]
    res = run_batch(todo, scheduler="serial", progress=False)
    files = write_batch(res, tmp_path)
    rows = json.loads((tmp_path / "results.json").read_text())
    assert [r["job"] for r in rows] == [0] and rows[0]["bounds_file"] == files[todo[0].stem]
    np.testing.assert_array_equal(cf.BoundsTable.load(files[todo[0].stem]).upper, res[0].table.upper)


def test_cli_batch_without_dask_says_how_to_get_it(tmp_path, capsys, monkeypatch):
    """Without the cluster extra, cfvol batch exits 2 naming the extra and --serial."""
    jobs = tmp_path / "jobs.yaml"
    jobs.write_text(SMALL)
    monkeypatch.setitem(sys.modules, "distributed", None)
    assert main(["batch", str(jobs), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "drake-cfvol[cluster]" in err and "--serial" in err


def test_cli_batch_rejects_serial_with_a_scheduler(tmp_path, capsys):
    """--serial and --scheduler together exit 2 with the fix."""
    jobs = tmp_path / "jobs.yaml"
    jobs.write_text(SMALL)
    assert main(["batch", str(jobs), "--serial", "--scheduler", "tcp://localhost:1"]) == 2
    assert "leave out --scheduler" in capsys.readouterr().err


@pytest.mark.slow
def test_cli_batch_on_a_local_cluster_equals_serial(tmp_path, capsys):
    """cfvol batch on a LocalCluster of worker processes (results pickled back) writes what --serial writes."""
    jobs = tmp_path / "jobs.yaml"
    jobs.write_text(SMALL)
    assert main(["batch", str(jobs), "--out", str(tmp_path / "dist"), "--json"]) == 0
    assert main(["batch", str(jobs), "--out", str(tmp_path / "serial"), "--serial", "--json"]) == 0
    capsys.readouterr()
    a = json.loads((tmp_path / "dist" / "results.json").read_text())
    b = json.loads((tmp_path / "serial" / "results.json").read_text())
    skip = {"worker", "time_ms", "timing_ms", "cf_ms", "job_ms", "bounds_file"}
    assert [{k: v for k, v in r.items() if k not in skip} for r in a] == [
        {k: v for k, v in r.items() if k not in skip} for r in b
    ]
    assert len({r["worker"] for r in a}) >= 1
    for r, s in zip(a, b):
        np.testing.assert_array_equal(
            cf.BoundsTable.load(r["bounds_file"]).lower, cf.BoundsTable.load(s["bounds_file"]).lower
        )
