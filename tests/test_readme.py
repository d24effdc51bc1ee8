"""The README's library example runs as written."""

import re
from pathlib import Path

import numpy as np
import pytest

README = Path(__file__).resolve().parent.parent / "README.md"


@pytest.mark.slow
def test_library_example_runs(tmp_path, monkeypatch, capsys):
    """The first Python block of the README runs unchanged (in a temporary
    folder: it saves a file) and prints the certificate in words, twice in a
    row (the second run replaces its own file, as the snippet asks)."""
    code = re.search(r"```python\n(.*?)```", README.read_text(), re.S).group(1)
    assert "cf.Certify(" in code
    monkeypatch.chdir(tmp_path)
    for _ in range(2):
        exec(compile(code, str(README), "exec"), {})
        assert (tmp_path / "bounds.npz").is_file()
        assert "consecutive samples" in capsys.readouterr().out


def test_diagram_example_runs(capsys):
    """The README's Drake-diagram block runs unchanged: it wires the systems
    by hand, simulates, and the push moves the robot off the nominal while
    the commanded motion stays inside the bounds."""
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(), re.S)
    code = next(b for b in blocks if "DiagramBuilder()" in b)
    scope = {}
    exec(compile(code, str(README), "exec"), scope)
    out = capsys.readouterr().out
    assert "commanded configurations" in out
    q = scope["q"]
    table = scope["table"]
    times = scope["log"].FindLog(scope["simulator"].get_context()).sample_times()
    lo, hi, nominal = table.boxes_at(np.array([scope["progress"].index_at(t) for t in times]))
    assert np.all(q >= lo - 1e-12) and np.all(q <= hi + 1e-12)
    assert np.abs(q - nominal).max() > 0.1  # pushed off the nominal


@pytest.mark.slow
def test_station_example_runs(capsys):
    """The README's own-station block runs unchanged: a workcell from a
    RobotDiagram with a free part, the systems in the user's builder under
    InverseDynamicsController, a real push; every measured configuration is
    free (Drake) and the robot ends at the path's goal."""
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(), re.S)
    code = next(b for b in blocks if "FromRobotDiagram" in b)
    scope = {}
    exec(compile(code, str(README), "exec"), scope)
    assert "collision-free: True" in capsys.readouterr().out
    q, table = scope["q"], scope["table"]
    lo, hi, nominal = table.at(table.g - 1)
    # At the goal the steady push holds the robot off the nominal, inside the box (within tracking).
    assert np.all(q[-1] >= lo - 0.01) and np.all(q[-1] <= hi + 0.01)
    assert np.abs(q[-1] - nominal).max() > 0.005
    assert "part" in scope["wc"].obstacles
