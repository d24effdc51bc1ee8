"""Plots (matplotlib, headless)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["plot_bounds"]


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_bounds(bounds, path: str | Path, *, revolute=None, title: str = "") -> Path:
    """Writes a PNG: per joint, the nominal and [lower, upper] along s, with
    the joint's limits. Degrees for revolute joints, metres for prismatic."""
    plt = _pyplot()
    k = bounds.k
    revolute = np.ones(k, bool) if revolute is None else np.asarray(revolute, bool)
    cols = 2 if k > 3 else 1
    rows = int(np.ceil(k / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(6 * cols, 2.2 * rows), sharex=True, squeeze=False)
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
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
