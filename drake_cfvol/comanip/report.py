"""A run's plots and its diagram as SVG (Graphviz)."""

import subprocess
from pathlib import Path

import numpy as np
from pydrake.systems.framework import Diagram

from drake_cfvol.comanip.diagram import CoManipulation
from drake_cfvol.io.plotting import draw, figure


def plot_run(logs: dict, cm: CoManipulation, path: Path) -> Path:
    """Per joint over time: nominal, bounds, commanded; and the clearance.
    Shaded in every panel: when the co-worker pushes (joint torque or tool
    wrench not zero); ticks on the clearance panel: when the safety filter
    acted (at the logged samples). Returns the file's path (written on
    return, or when :func:`~drake_cfvol.io.plotting.in_background`'s block
    ends)."""
    names = ("commanded_position", "human_torque", "human_wrench", "lower", "upper", "nominal", "min_distance")
    wc = cm.workcell
    draw(
        _draw_run,
        {name: logs[name] for name in names + ("filter_active",) if name in logs},
        list(wc.joint_names),
        np.asarray(wc.revolute, bool),
        f"{wc.name} {cm.path.label}: co-manipulation run",
        Path(path),
    )
    return Path(path)


def _draw_run(logs: dict, joint_names, rev, title: str, path: Path) -> None:
    t, q = logs["commanded_position"]
    pushing = np.zeros(len(t), bool)
    for name in ("human_torque", "human_wrench"):
        if name in logs and len(logs[name][1]) == len(t):
            pushing |= np.any(logs[name][1] != 0, axis=1)
    spans = _runs(t, pushing)
    _, lo = logs["lower"]
    _, hi = logs["upper"]
    _, nom = logs["nominal"]
    td, dist = logs["min_distance"]
    k = q.shape[1]
    fig, axes = figure(k + 1, 1, size=(8, 1.6 * (k + 1)), margins=(0.85, 0.15, 0.5, 0.4), sharex=True)
    fig.subplots_adjust(hspace=0.12)
    axes = axes[:, 0]
    for j in range(k):
        f = np.degrees if rev[j] else (lambda x: x)
        ax = axes[j]
        ax.fill_between(t, f(lo[:, j]), f(hi[:, j]), color="tab:green", alpha=0.25, label="bounds")
        ax.plot(t, f(nom[:, j]), "k--", lw=1, label="nominal")
        ax.plot(t, f(q[:, j]), color="tab:blue", lw=1.4, label="commanded")
        ax.set_ylabel(f"{joint_names[j]}\n[{'deg' if rev[j] else 'm'}]", fontsize=8)
        ax.grid(alpha=0.3)
    for ax in axes:
        for n, (a, b) in enumerate(spans):
            ax.axvspan(a, b, color="tab:orange", alpha=0.15, lw=0, label="push" if n == 0 else None)
    axes[0].legend(loc="upper right", fontsize=7, ncol=4)
    axes[-1].plot(td, dist[:, 0], color="tab:red")
    if "filter_active" in logs:
        tg, g = logs["filter_active"]
        acted = tg[g[:, 0] > 0]
        if len(acted):
            axes[-1].plot(
                acted, np.full(len(acted), float(dist[:, 0].min())), "|", color="k", ms=8, label="filter acted"
            )
            axes[-1].legend(loc="upper right", fontsize=7)
    axes[-1].set_ylabel("clearance\n[m]", fontsize=8)
    axes[-1].set_xlabel("time [s]")
    axes[-1].grid(alpha=0.3)
    fig.suptitle(title)
    fig.savefig(path, dpi=100)


def missing_dot_notice(stem: Path) -> str:
    """The one-line notice when Graphviz is missing: what was skipped, where
    the source is, how to get the SVG."""
    return (
        f"Graphviz 'dot' was not found, so {stem.with_suffix('.svg')} was not drawn (its source is in "
        f"{stem.with_suffix('.dot')}). Install Graphviz to get it (Debian/Ubuntu: sudo apt install graphviz)."
    )


def write_diagram_svg(diagram: Diagram, stem: Path) -> dict:
    """Writes the diagram's GraphViz source and, if ``dot`` is installed,
    an SVG. Returns the written files."""
    dot = diagram.GetGraphvizString(max_depth=1)
    files = {}
    dot_path = stem.with_suffix(".dot")
    dot_path.write_text(dot)
    files["diagram_dot"] = str(dot_path)
    try:
        svg = subprocess.run(["dot", "-Tsvg"], input=dot.encode(), capture_output=True, check=True, timeout=60)
        stem.with_suffix(".svg").write_bytes(svg.stdout)
        files["diagram_svg"] = str(stem.with_suffix(".svg"))
    except (OSError, subprocess.SubprocessError):
        pass
    return files


def _runs(t: np.ndarray, on: np.ndarray) -> list[tuple[float, float]]:
    """[start, end) times of the runs where ``on`` holds (logged samples)."""
    out, start = [], None
    for i, flag in enumerate(on):
        if flag and start is None:
            start = t[i]
        if not flag and start is not None:
            out.append((start, t[i]))
            start = None
    if start is not None:
        out.append((start, t[-1]))
    return out
