"""Plots of recorded trajectories (matplotlib, no display needed).

:func:`figure` draws into a new :class:`matplotlib.figure.Figure` without pyplot, so it
never switches the caller's backend nor keeps figures alive in pyplot's registry.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path


def figure(results, title: str = "", labels: Sequence[str] | None = None):
    """One panel per recorded signal against time, one line per result; controller
    signals as staircases (they are held over each base step). Returns the Figure."""
    from matplotlib.figure import Figure

    results = list(results) if isinstance(results, (list, tuple)) else [results]
    names = list(results[0].names)
    n = len(names)
    fig = Figure(figsize=(8, 2.2 + 1.8 * n))
    axes = fig.subplots(n, 1, sharex=True, squeeze=False)[:, 0]
    for k, result in enumerate(results):
        label = labels[k] if labels else None
        for ax, name in zip(axes, names):
            if name not in result.names:
                continue
            style = "steps-post" if name.startswith("controller.") else "default"
            ax.plot(result.times, result.column(name), drawstyle=style, lw=1.4, label=label)
    for ax, name in zip(axes, names):
        ax.set_ylabel(name)
        ax.grid(True, alpha=0.3)
        ax.axhline(0.0, color="k", lw=0.6)
    if labels:
        axes[0].legend(fontsize=8)
    axes[-1].set_xlabel("time [s]")
    if title:
        fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    return fig


def save(fig, path: str | Path) -> None:
    """Write ``fig`` to ``path`` through a temporary file (no half-written image)."""
    path = Path(path)
    tmp = path.with_name(path.stem + ".part" + path.suffix)
    fig.savefig(tmp, dpi=110)
    tmp.replace(path)


def plot_result(result, path: str | Path, title: str) -> None:
    """One panel per recorded signal against time, written to ``path``."""
    save(figure(result, title), path)
