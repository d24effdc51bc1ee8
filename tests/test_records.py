"""Saved paths and tables: one clear error for every file that is not one."""

import json

import numpy as np
import pytest

import drake_cfvol as cf
from drake_cfvol.io.records import output_stem, prepare_output


@pytest.fixture(scope="module")
def saved(tmp_path_factory):
    """A small path saved as .npz and .json."""
    folder = tmp_path_factory.mktemp("saved")
    path = cf.NominalPath(np.array([[0.0, 0.1], [0.2, 0.3]]), ["a", "b"], "cell", "path1", 0)
    return path, path.save(folder / "p.npz"), path.save(folder / "p.json")


@pytest.mark.parametrize("loader", [cf.NominalPath.load, cf.BoundsTable.load])
@pytest.mark.parametrize(
    "content, reason",
    [
        (b"", "empty or truncated"),
        (b"PK\x03\x04 truncated", "empty or truncated"),
        (b"\x93NUMPY not a zip", "not valid"),
    ],
)
def test_broken_npz(tmp_path, loader, content, reason):
    """An empty, truncated or foreign .npz is a RecordFormatError naming the file."""
    f = tmp_path / "x.npz"
    f.write_bytes(content)
    with pytest.raises(cf.RecordFormatError, match=reason) as e:
        loader(f)
    assert str(f) in str(e.value)


@pytest.mark.parametrize("loader", [cf.NominalPath.load, cf.BoundsTable.load])
@pytest.mark.parametrize(
    "content, reason",
    [
        ("", "not valid"),
        ('{"waypoints": [[0, 1]', "not valid"),
        ("[1, 2, 3]", "no JSON object"),
        ('{"something": "else"}', "lacks"),
    ],
)
def test_broken_json(tmp_path, loader, content, reason):
    """An empty, truncated or foreign .json is a RecordFormatError."""
    f = tmp_path / "x.json"
    f.write_text(content)
    with pytest.raises(cf.RecordFormatError, match=reason):
        loader(f)


def test_other_kind_of_record(saved):
    """A path file given as a bounds table says which kind it is."""
    _, npz, js = saved
    for f in (npz, js):
        with pytest.raises(cf.RecordFormatError, match="NominalPath.*not a drake_cfvol.BoundsTable"):
            cf.BoundsTable.load(f)


def test_missing_file(tmp_path):
    """A file that does not exist is named as such, not a raw FileNotFoundError."""
    with pytest.raises(cf.RecordFormatError, match="no such file"):
        cf.NominalPath.load(tmp_path / "nope.npz")


def test_round_trip_still_works(saved):
    """The checks let a good file through unchanged."""
    path, npz, js = saved
    for f in (npz, js):
        np.testing.assert_array_equal(cf.NominalPath.load(f).waypoints, path.waypoints)


def test_unwritable_output(tmp_path):
    """A folder that cannot be created is an OutputPathError (a CfvolError)."""
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(cf.OutputPathError, match="cannot write"):
        prepare_output(blocker / "sub" / "p.json", overwrite=False)
    path = cf.NominalPath(np.zeros((2, 1)), ["a"])
    with pytest.raises(cf.OutputPathError):
        path.save(blocker / "p.json")


def test_existing_output_kept(tmp_path):
    """An existing file is refused (still a FileExistsError) and left as it was."""
    f = tmp_path / "p.json"
    f.write_text("mine")
    with pytest.raises(FileExistsError):
        cf.NominalPath(np.zeros((2, 1)), ["a"]).save(f)
    assert f.read_text() == "mine"
    assert issubclass(cf.OutputExistsError, cf.CfvolError)


def test_output_stem():
    """One naming scheme: <cell>_<path>[_R<R>]."""
    assert output_stem("automotive", "path1", 1000) == "automotive_path1_R1000"
    assert output_stem("automotive", "path1") == "automotive_path1"
    assert json.dumps(output_stem("a", "b"))  # a plain string


def test_certified_outputs_say_so():
    """Certified bounds get their own file names, never an uncertified one's."""
    from drake_cfvol.io.records import output_stem

    assert output_stem("automotive", "path1", 1000) == "automotive_path1_R1000"
    assert output_stem("automotive", "path1", 1000, certified=True) == "automotive_path1_R1000_certified"


# The children load io/cache.py alone (the package's import would take
# seconds; the module imports nothing of it).
_WRITER = """
import importlib.util, sys
from pathlib import Path
spec = importlib.util.spec_from_file_location("cache", sys.argv[3])
cache = importlib.util.module_from_spec(spec)
spec.loader.exec_module(cache)
write_atomic = cache.write_atomic

path, letter = Path(sys.argv[1]), sys.argv[2]
text = letter * 2_000_000
(path.parent / ("ready-" + letter)).touch()
while not (path.parent / "go").exists():
    pass
for _ in range(60):
    write_atomic(path, text)
"""


def test_a_file_written_atomically_is_never_read_in_part(tmp_path):
    """Two processes rewrite one cache file (2 MB of 'a', of 'b') 60 times
    each while this one reads it: every read is one writer's whole text,
    and no temporary file is left behind."""
    import subprocess
    import sys
    import time

    from drake_cfvol.io import cache as io_cache

    path = tmp_path / "model.urdf"
    path.write_text("a" * 2_000_000)
    procs = [subprocess.Popen([sys.executable, "-c", _WRITER, str(path), c, io_cache.__file__]) for c in "ab"]
    deadline = time.monotonic() + 120
    while not all((tmp_path / f"ready-{c}").exists() for c in "ab") and time.monotonic() < deadline:
        time.sleep(0.01)
    (tmp_path / "go").touch()
    reads = 0
    while any(p.poll() is None for p in procs):
        text = path.read_text()
        assert text in ("a" * 2_000_000, "b" * 2_000_000), (len(text), set(text))
        reads += 1
    assert [p.returncode for p in procs] == [0, 0]
    assert reads > 0
    assert sorted(f.name for f in tmp_path.iterdir()) == ["go", "model.urdf", "ready-a", "ready-b"]
