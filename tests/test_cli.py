"""The cfvol command line, run in-process."""

import json

import pytest

import drake_cfvol as cf
from drake_cfvol.apps.cli import main


def test_plan_json(capsys):
    """cfvol plan --json prints one object with the promised keys; the hash is
    stable for a seed."""
    assert main(["plan", "automotive", "--path", "2", "--seed", "1", "--json"]) == 0
    a = json.loads(capsys.readouterr().out)
    for key in ("cell", "path", "seed", "g", "plan_time_ms", "path_length", "waypoints_sha256"):
        assert key in a
    assert a["cell"] == "automotive" and a["path"] == "path2" and a["seed"] == 1
    assert main(["plan", "automotive", "--path", "2", "--seed", "1", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["waypoints_sha256"] == a["waypoints_sha256"]


def test_plan_unknown_cell(capsys):
    """An unknown cell exits 2 with the known cells listed."""
    assert main(["plan", "nowhere"]) == 2
    assert "automotive" in capsys.readouterr().err


def test_plan_refuses_to_overwrite(tmp_path, capsys):
    """--out does not overwrite an existing file without --force."""
    out = tmp_path / "p.json"
    out.write_text("mine")
    assert main(["plan", "automotive", "--out", str(out)]) == 2
    assert out.read_text() == "mine"
    assert "overwrite" in capsys.readouterr().err
    assert main(["plan", "automotive", "--out", str(out), "--force"]) == 0
    assert json.loads(out.read_text())["format"] == "drake_cfvol.NominalPath"


def test_bounds_json_and_files(tmp_path, capsys):
    """cfvol bounds --json --out --plot writes bounds, path and a PNG."""
    rc = main(
        [
            "bounds",
            "aerospace",
            "--path",
            "1",
            "--resolution",
            "300",
            "--cf-samples",
            "200",
            "--out",
            str(tmp_path),
            "--plot",
            "--json",
        ]
    )
    assert rc == 0
    d = json.loads(capsys.readouterr().out)
    for key in ("cell", "path", "resolution", "g", "k", "time_ms", "cf_percent", "freedom", "n_boxes", "out"):
        assert key in d
    assert d["k"] == 7 and 0 <= d["cf_percent"] <= 100 and 0 < d["freedom"] <= 1
    for f in d["files"].values():
        assert (tmp_path / f.split("/")[-1]).stat().st_size > 0
    assert open(d["files"]["plot_png"], "rb").read(8) == b"\x89PNG\r\n\x1a\n"


@pytest.mark.slow  # 5.5 s: a whole co-manipulation run through the CLI
def test_simulate_json(tmp_path, capsys):
    """cfvol simulate --json prints the run's summary with the promised keys."""
    assert (
        main(
            [
                "simulate",
                "automotive_push",
                "--out",
                str(tmp_path),
                "--json",
                "--scenario-text",
                "{bounds: {certify: null}}",
            ]
        )
        == 0
    )
    d = json.loads(capsys.readouterr().out)
    for key in (
        "scenario",
        "steps",
        "min_clearance_m",
        "max_bound_violation",
        "recording_html",
        "plot_png",
        "max_velocity_ratio",
        "collisions",
        "filter_steps",
        "faults",
    ):
        assert key in d
    # Inside the bounds to rounding (the filter set each command against the
    # bounds one period ahead, at a path index rounded differently).
    assert d["steps"] > 100 and d["max_bound_violation"] <= 1e-12
    assert d["collisions"] == 0 and d["max_velocity_ratio"] <= 1.0 and d["faults"] == 0
    assert (tmp_path / "recording.html").stat().st_size > 100_000


@pytest.mark.slow  # 3.4 s: CI's slow group runs it
def test_bounds_certify_json(capsys):
    """cfvol bounds --certify reports the certificate it holds."""
    assert (
        main(
            [
                "bounds",
                "automotive",
                "-R",
                "300",
                "--certify",
                "--no-boundary-proof",
                "--epsilon",
                "0.05",
                "--confidence",
                "0.9",
                "--cf-windows",
                "3",
                "--cf-samples",
                "100",
                "--json",
            ]
        )
        == 0
    )
    d = json.loads(capsys.readouterr().out)
    c = d["certificate"]
    assert c["epsilon"] == 0.05 and c["n_samples"] == 47
    assert c["freedom_after"] <= c["freedom_before"]


def test_bench_quick_flags(tmp_path, capsys):
    """cfvol bench parses its flags and writes its tables (tiny run)."""
    assert (
        main(
            [
                "bench",
                "--quick",
                "--cells",
                "automotive",
                "--resolutions",
                "200",
                "--trials",
                "1",
                "--cf-samples",
                "20",
                "--no-iris",
                "--no-engine",
                "--out",
                str(tmp_path),
                "--json",
            ]
        )
        == 0
    )
    d = json.loads(capsys.readouterr().out)
    assert [r["resolution"] for r in d["rows"]] == [200]
    assert (tmp_path / "results.md").is_file() and (tmp_path / "trials.csv").is_file()


def test_push_patterns_are_written_once(capsys):
    """The CLI's push-pattern choices are the library's own tuple (one place,
    :mod:`drake_cfvol.comanip.push_patterns`), and ``cfvol bench --help``
    lists them."""
    from drake_cfvol.apps import cli
    from drake_cfvol.comanip.adversarial import PATTERNS

    assert cli.PATTERNS is PATTERNS
    assert not hasattr(cli, "PUSH_PATTERNS")
    with pytest.raises(SystemExit):
        cli.main(["bench", "--help"])
    help_text = capsys.readouterr().out
    assert all(p in help_text for p in PATTERNS), help_text


@pytest.mark.parametrize(
    "flags, message",
    [
        (["--adversarial-runs", "-1"], "--adversarial-runs must be >= 0"),
        (["--adversarial-only", "--adversarial-runs", "0"], "--adversarial-only needs --adversarial-runs >= 1"),
    ],
)
def test_bench_adversarial_flags_refused(tmp_path, flags, message, capsys):
    """A negative run count, or an adversarial-only run with no runs, is
    refused in one line before anything runs."""
    assert main(["bench", *flags, "--out", str(tmp_path / "b")]) == 2
    assert message in capsys.readouterr().err


def test_version(capsys):
    """--version prints the package's one version."""
    with pytest.raises(SystemExit) as e:
        main(["--version"])
    assert e.value.code == 0
    assert cf.__version__ in capsys.readouterr().out


def test_simulate_help_lists_every_bundled_scenario(capsys):
    """simulate --help names every scenario file shipped in diagrams/."""
    from drake_cfvol.comanip import diagrams_dir

    with pytest.raises(SystemExit):
        main(["simulate", "--help"])
    out = " ".join(capsys.readouterr().out.split())
    names = sorted(p.stem for p in diagrams_dir().glob("*.yaml"))
    assert len(names) >= 6 and all(n in out for n in names)


def test_help_has_no_markup(capsys):
    """--help reads as plain text (no reST double backquotes)."""
    with pytest.raises(SystemExit):
        main(["--help"])
    out = capsys.readouterr().out
    assert "``" not in out and "co-worker" in out


def test_unwritable_out_before_planning(capsys):
    """--out in a folder that cannot exist: one line, exit 2, no traceback."""
    assert main(["plan", "automotive", "--out", "/proc/nope/p.json"]) == 2
    assert main(["bounds", "automotive", "--out", "/proc/nope"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and all(e.startswith("cfvol: error: cannot write '/proc/nope") for e in err)


def test_missing_workcell_file(tmp_path, capsys):
    """A workcell path that does not exist is reported as a missing file."""
    assert main(["bounds", str(tmp_path / "nope.yaml")]) == 2
    err = capsys.readouterr().err
    assert "does not exist" in err and "Unknown cell" not in err


def test_bad_cf_samples_before_planning(capsys):
    """A CF sample count of 0 is refused before any planning."""
    assert main(["bounds", "automotive", "--cf-samples", "0"]) == 2
    assert "--cf-samples must be >= 1" in capsys.readouterr().err


@pytest.mark.parametrize(
    "flag",
    [
        ["--epsilon", "1e-4"],
        ["--clamp-epsilon", "1e-3"],
        ["--confidence", "0.9"],
        ["--no-cache"],
        ["--no-boundary-proof"],
        ["--regrow"],
    ],
)
def test_certificate_options_need_certify(flag, capsys):
    """An option that does nothing without --certify is refused, not ignored."""
    assert main(["bounds", "automotive", *flag]) == 2
    err = capsys.readouterr().err
    assert err.startswith("cfvol: error: ") and "--certify" in err and flag[0] in err


def test_regrow_needs_the_boundary_proof(capsys):
    """--regrow with --no-boundary-proof is refused before any planning."""
    assert main(["bounds", "automotive", "--certify", "--regrow", "--no-boundary-proof"]) == 2
    assert "--no-boundary-proof" in capsys.readouterr().err


def test_plot_without_out(capsys):
    """--plot without --out has the same error: prefix as every message."""
    assert main(["bounds", "automotive", "--plot"]) == 2
    assert capsys.readouterr().err.startswith("cfvol: error: --plot needs --out")


def test_relative_out_from_caller_folder(tmp_path, monkeypatch, capsys):
    """A relative --out is written under the caller's folder and printed in full."""
    monkeypatch.chdir(tmp_path)
    assert main(["plan", "automotive", "--out", "rel/p.json", "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["out"] == str(tmp_path / "rel" / "p.json") and (tmp_path / "rel" / "p.json").is_file()


def test_plain_output_reads_well(capsys):
    """Plain output: one labelled fact per line, units, no Python reprs."""
    assert main(["plan", "automotive"]) == 0
    out = capsys.readouterr().out
    assert "waypoints (g)" in out and "joints (k)" in out and " ms" in out
    for repr_ in ("None", "{", "}", "[", "'"):
        assert repr_ not in out
    assert all(":" not in line.split()[0] for line in out.splitlines())


def test_saved_table_error_one_line(tmp_path, capsys):
    """A library error about a broken file reaches the CLI as one line."""
    from drake_cfvol.apps.cli import _emit

    f = tmp_path / "t.npz"
    f.write_bytes(b"")
    with pytest.raises(cf.CfvolError):
        cf.BoundsTable.load(f)
    _emit({"g": 3, "timing_ms": {"total": 1.0}, "out": None}, False)
    out = capsys.readouterr().out
    assert "total 1.0 ms" in out and "written to" in out and "-" in out


@pytest.mark.parametrize("json_flag, expected", [([], True), (["--json"], False)])
def test_bars_asked_for_unless_json(monkeypatch, capsys, json_flag, expected):
    """Plain output asks for progress bars (drawn only on a terminal);
    --json never does."""
    import drake_cfvol.algorithm.metrics as metrics
    from drake_cfvol.io.progress import Progress

    asked = []

    class Recorder(Progress):
        def __init__(self, *a, enabled=True, **kw):
            asked.append(enabled)
            super().__init__(*a, enabled=enabled, **kw)

    monkeypatch.setattr(metrics, "Progress", Recorder)
    assert main(["bounds", "automotive", "-R", "100", "--cf-windows", "2", "--cf-samples", "20", *json_flag]) == 0
    assert asked == [expected]
    assert capsys.readouterr().err == ""  # not a terminal: nothing drawn either way
