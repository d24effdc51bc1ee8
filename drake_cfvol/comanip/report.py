"""A run's plots and its diagram as SVG (Graphviz)."""

import subprocess
from pathlib import Path

import numpy as np

from drake_cfvol.comanip.diagram import Comanipulation
from drake_cfvol.io.plotting import _pyplot


def plot_run(logs: dict, cm: Comanipulation, path: Path) -> Path:
    """Per joint over time: nominal, bounds, commanded; and the clearance.
    Shaded in every panel: when the co-worker pushes (joint torque or tool
    wrench not zero); ticks on the clearance panel: when the safety filter
    acted (at the logged samples)."""
    plt = _pyplot()
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
    rev = cm.workcell.revolute
    fig, axes = plt.subplots(k + 1, 1, figsize=(8, 1.6 * (k + 1)), sharex=True)
    for j in range(k):
        f = np.degrees if rev[j] else (lambda x: x)
        ax = axes[j]
        ax.fill_between(t, f(lo[:, j]), f(hi[:, j]), color="tab:green", alpha=0.25, label="bounds")
        ax.plot(t, f(nom[:, j]), "k--", lw=1, label="nominal")
        ax.plot(t, f(q[:, j]), color="tab:blue", lw=1.4, label="commanded")
        ax.set_ylabel(f"{cm.workcell.joint_names[j]}\n[{'deg' if rev[j] else 'm'}]", fontsize=8)
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
    fig.suptitle(f"{cm.workcell.name} {cm.scenario.path}: co-manipulation run")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def missing_dot_notice(stem: Path) -> str:
    """The one-line notice when Graphviz is missing: what was skipped, where
    the source is, how to get the SVG."""
    return (
        f"Graphviz 'dot' was not found, so {stem.with_suffix('.svg')} was not drawn (its source is in "
        f"{stem.with_suffix('.dot')}). Install Graphviz to get it (Debian/Ubuntu: sudo apt install graphviz)."
    )


def write_diagram_svg(diagram, stem: Path) -> dict:
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
