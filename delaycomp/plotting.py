"""Plots of recorded trajectories (matplotlib, no display needed)."""

from __future__ import annotations

from pathlib import Path


def plot_result(result, path: str | Path, title: str) -> None:
    """One panel per recorded signal against time; controller signals as staircases."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(result.names)
    fig, axes = plt.subplots(n, 1, sharex=True, figsize=(8, 2.2 + 1.8 * n), squeeze=False)
    for ax, name in zip(axes[:, 0], result.names):
        style = "steps-post" if name.startswith("controller.") else "default"
        ax.plot(result.times, result.column(name), drawstyle=style, lw=1.4)
        ax.set_ylabel(name)
        ax.grid(True, alpha=0.3)
        ax.axhline(0.0, color="k", lw=0.6)
    axes[-1, 0].set_xlabel("time [s]")
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    path = Path(path)
    tmp = path.with_name(path.stem + ".part" + path.suffix)
    fig.savefig(tmp, dpi=110)
    plt.close(fig)
    tmp.replace(path)
