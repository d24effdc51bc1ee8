"""Plots (matplotlib, headless), drawn where they are asked for or, inside
:func:`in_background`, by a helper process on the machine's other core."""

from __future__ import annotations

import contextlib
import sys
from pathlib import Path

import numpy as np

__all__ = ["in_background", "plot_bounds"]


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def figure(rows: int, cols: int, *, size: tuple[float, float], margins: tuple[float, float, float, float], **kw):
    """A figure of ``rows`` x ``cols`` axes without pyplot (no global state,
    nothing to close), its margins fixed in inches (left, right, bottom,
    top; matplotlib's tight layout measures every label, a large share of a
    plot's time). Returns (figure, axes as a 2-D array)."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=size)
    axes = fig.subplots(rows, cols, squeeze=False, **kw)
    w, h = size
    left, right, bottom, top = margins
    fig.subplots_adjust(left=left / w, right=1 - right / w, bottom=bottom / h, top=1 - top / h)
    return fig, axes


#: The helper process's pool while :func:`in_background` is active, and the plots handed to it.
_BACKGROUND: list = []


@contextlib.contextmanager
def in_background():
    """Within the block, :func:`plot_bounds` and
    :func:`~drake_cfvol.comanip.report.plot_run` hand their drawing to one
    helper process (forked on entry, where it imports matplotlib while the
    caller goes on) and return at once; leaving the block waits for every
    plot and raises the first error. Where fork is not the platform's way
    (macOS, Windows), or inside another such block, the plots are drawn at
    once as outside it. Enter it before the program starts threads of its
    own (a fork copies only the calling thread): the demo enters it first
    thing."""
    if _BACKGROUND or not sys.platform.startswith("linux"):
        yield
        return
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    # Forked before the caller starts threads of its own (numba's, Drake's).
    pool = ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("fork"))
    _BACKGROUND[:] = [pool, [pool.submit(_import_matplotlib)]]
    try:
        yield
        for done in _BACKGROUND[1]:
            done.result()
    finally:
        _BACKGROUND.clear()
        pool.shutdown(wait=True, cancel_futures=True)


def _import_matplotlib() -> None:
    from matplotlib.figure import Figure  # noqa: F401


def draw(fn, *args) -> None:
    """Calls ``fn(*args)`` (a module-level drawing function with picklable
    arguments) here, or in the helper process within :func:`in_background`."""
    if _BACKGROUND:
        _BACKGROUND[1].append(_BACKGROUND[0].submit(fn, *args))
    else:
        fn(*args)


def plot_bounds(bounds, path: str | Path, *, revolute=None, title: str = "") -> Path:
    """Writes a PNG: per joint, the nominal and [lower, upper] along s, with
    the joint's limits. Degrees for revolute joints, metres for prismatic.
    Returns the file's path (written on return, or when
    :func:`in_background`'s block ends)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    revolute = np.ones(bounds.k, bool) if revolute is None else np.asarray(revolute, bool)
    draw(_draw_bounds, bounds, path, revolute, title)
    return path


def _draw_bounds(bounds, path: Path, revolute, title: str) -> None:
    k = bounds.k
    cols = 2 if k > 3 else 1
    rows = int(np.ceil(k / cols))
    fig, axes = figure(
        rows, cols, size=(6 * cols, 2.2 * rows), margins=(0.8, 0.15, 0.55, 0.5 if title else 0.2), sharex=True
    )
    fig.subplots_adjust(wspace=0.25, hspace=0.12)
    s = bounds.s
    for j in range(k):
        ax = axes[j // cols][j % cols]
        f = np.degrees if revolute[j] else (lambda x: x)
        ax.fill_between(
            s, f(bounds.lower[:, j]), f(bounds.upper[:, j]), color="tab:green", alpha=0.3, label="[lower, upper]"
        )
        ax.plot(s, f(bounds.nominal[:, j]), color="k", lw=1.2, label="nominal")
        for lim in (bounds.limit_lower[j], bounds.limit_upper[j]):
            ax.axhline(f(lim), color="tab:red", ls="--", lw=0.8)
        ax.set_ylabel(f"{bounds.joint_names[j]} [{'deg' if revolute[j] else 'm'}]")
        ax.grid(alpha=0.3)
    for ax in axes[-1]:
        ax.set_xlabel("path index s")
    axes[0][0].legend(loc="upper right", fontsize=7)
    for j in range(k, rows * cols):
        axes[j // cols][j % cols].axis("off")
    if title:
        fig.suptitle(title)
    fig.savefig(path, dpi=110)
