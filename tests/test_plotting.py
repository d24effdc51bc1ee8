"""Plots drawn in the helper process (``in_background``) are the ones drawn
in place, and a failure there reaches the caller."""

import numpy as np
import pytest

from drake_cfvol.algorithm.table import BoundsTable
from drake_cfvol.io import plotting


def _table(k=3, n=40):
    s = np.linspace(0.0, 1.0, n)[:, None]
    nominal = np.sin(3 * s + np.arange(k))
    return BoundsTable(
        nominal - 0.2, nominal + 0.3, nominal, [f"j{i}" for i in range(k)], -np.ones(k) * 2, np.ones(k) * 2
    )


def test_background_plot_equals_the_one_drawn_in_place(tmp_path):
    table = _table()
    here = plotting.plot_bounds(table, tmp_path / "here.png", title="t")
    with plotting.in_background():
        there = plotting.plot_bounds(table, tmp_path / "sub" / "there.png", title="t")
        assert plotting._BACKGROUND  # the helper process took it
    # Written when the block ends, byte for byte the same picture.
    assert there.read_bytes() == here.read_bytes()
    assert not plotting._BACKGROUND


def test_background_plot_failure_is_raised_at_the_block_end(tmp_path):
    bad = _table()
    bad.joint_names = None  # the drawing fails on the labels, in the helper process
    with pytest.raises(TypeError):
        with plotting.in_background():
            plotting.plot_bounds(bad, tmp_path / "bad.png")
    assert not plotting._BACKGROUND
    # After the failure, plots are drawn in place again.
    assert plotting.plot_bounds(_table(), tmp_path / "ok.png").is_file()
