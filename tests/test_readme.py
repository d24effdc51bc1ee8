"""The README's library example runs as written."""

import re
from pathlib import Path

import pytest

README = Path(__file__).resolve().parent.parent / "README.md"


@pytest.mark.slow
def test_library_example_runs(tmp_path, monkeypatch, capsys):
    """The first Python block of the README runs unchanged (in a temporary
    folder: it saves a file) and prints the certificate in words."""
    code = re.search(r"```python\n(.*?)```", README.read_text(), re.S).group(1)
    assert "cf.Certify(" in code
    monkeypatch.chdir(tmp_path)
    exec(compile(code, str(README), "exec"), {})
    assert (tmp_path / "bounds.npz").is_file()
    assert "consecutive samples" in capsys.readouterr().out
