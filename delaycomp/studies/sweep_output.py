"""A sweep's rows written out: as CSV (``write_csv``, through ``write_table``, which the
robustness map shares), as a map of ``rho`` (``plot_sweep``), and counted as they pass
(``Tally``: what the end of a streamed sweep reports and plots).
"""

from __future__ import annotations

import csv
import math
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from delaycomp.errors import ParameterError
from delaycomp.studies.axes import Axis, format_value
from delaycomp.studies.metrics import METRICS
from delaycomp.studies.sweep_size import PLOT_MAX_POINTS
from delaycomp.tmpfiles import new_file


@dataclass
class Tally:
    """What the end of a streamed sweep needs of its rows, counted as they pass
    (``count``): the points, the stable ones, the failed ones (neither stable nor
    unstable) and the first failure's reason; with ``rho`` (an array of one float per
    point), each point's ``rho`` (``nan`` where empty), for ``--plot``.

    Examples
    --------
    >>> tally = Tally(rho=np.empty(2))
    >>> rows = [{"rho": 0.5, "stable": 1, "failed": ""},
    ...         {"rho": None, "stable": None, "failed": "plant failed at t = 1"}]
    >>> len(list(tally.count(rows))), tally.points, tally.stable, tally.failed
    (2, 2, 1, 1)
    >>> tally.first_failed, tally.rho.tolist()[1]
    ('plant failed at t = 1', nan)
    """

    points: int = 0
    stable: int = 0
    failed: int = 0
    first_failed: str = ""
    rho: np.ndarray | None = None

    def count(self, rows: Iterable[dict]) -> Iterator[dict]:
        """``rows`` passed on, one at a time, counted."""
        for row in rows:
            if self.rho is not None:
                self.rho[self.points] = math.nan if row["rho"] is None else row["rho"]
            self.points += 1
            if row["stable"] == 1:
                self.stable += 1
            elif row["failed"] and row["stable"] is None:
                self.failed += 1
                self.first_failed = self.first_failed or row["failed"]
            yield row


def write_csv(rows: Iterable[dict], names: list[str], path: str | Path) -> None:
    """Write the sweep's rows to ``path`` as CSV: the grid columns ``names``, then
    ``METRICS``. ``rows`` may be an iterator (``iter_sweep``): each row is written
    as it comes, to a ``.part`` file (a new file: never through a link) moved into place
    once the last is written (and removed if the rows stop with an error, Ctrl-C or
    SIGTERM included: no half-written file looks like a result).
    """
    # grid values as written (15 digits), metrics to the bit
    write_table(path, [*names, *METRICS],
                ([*(format_value(row[k]) for k in names), *(_cell(row[k]) for k in METRICS)]
                 for row in rows))


def write_table(path: str | Path, header: Sequence[str],
                lines: Iterable[Sequence[str]]) -> None:
    """Write CSV ``lines`` (each written as it comes) under ``header`` to ``path``, through a
    ``.part`` file (a new file: never through a link) moved into place once the last line
    is written, removed if the lines stop (an error, Ctrl-C, SIGTERM, a full disk: no
    half-written file looks like a result). ``write_csv``'s and the robustness map's."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".part")
    try:
        with new_file(tmp) as fh:
            w = csv.writer(fh)
            w.writerow(header)
            for line in lines:
                w.writerow(line)
    except BaseException:  # Ctrl-C, SIGTERM, a full disk: no half-written file is left
        tmp.unlink(missing_ok=True)
        raise
    tmp.replace(path)


def _cell(value) -> str:
    if value is None:
        return ""
    if isinstance(value, str):
        return value
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    return repr(float(value))


def plot_sweep(rows: list[dict] | np.ndarray, axes: list[Axis], path: str | Path, title: str,
               critical: np.ndarray | None = None) -> None:
    """A curve of ``rho`` for one grid parameter, a heat map of it for two.

    ``rows``: the sweep's rows, or their ``rho`` alone as an array in grid order
    (``Tally.rho``); at most ``PLOT_MAX_POINTS``. ``critical``: rows ``(a, r)``
    where the exact lifted model has ``rho = 1``
    (``delaycomp.studies.critical.critical_curve``), drawn over the map and labelled.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if len(rows) > PLOT_MAX_POINTS:
        raise ParameterError(f"--plot draws at most {PLOT_MAX_POINTS:.4g} points")
    rho = (np.asarray(rows, dtype=float) if isinstance(rows, np.ndarray)
           else np.array([r["rho"] for r in rows], dtype=float))
    fig, ax = plt.subplots(figsize=(7, 4.5))
    if len(axes) == 1:
        ax.plot(axes[0].values, rho, "o-", ms=3)
        ax.axhline(1.0, color="k", lw=0.8, ls="--")
        ax.set_xlabel(axes[0].name)
        ax.set_ylabel("rho (growth per period)")
        ax.set_yscale("symlog", linthresh=1e-3)
        ax.grid(True, alpha=0.3)
    elif len(axes) == 2:
        Z = np.clip(rho.reshape(len(axes[0].values), len(axes[1].values)), 0, 2)
        mesh = ax.pcolormesh(axes[1].values, axes[0].values, Z, cmap="RdYlGn_r", vmin=0,
                             vmax=2, shading="nearest")
        if np.nanmin(Z) < 1 < np.nanmax(Z):
            ax.contour(axes[1].values, axes[0].values, Z, levels=[1.0], colors="k")
        fig.colorbar(mesh, ax=ax, label="rho (clipped to [0, 2]); black: rho = 1")
        ax.set_xlabel(axes[1].name)
        ax.set_ylabel(axes[0].name)
    else:
        raise ParameterError("--plot draws one or two grid parameters")
    if critical is not None:
        _draw_critical(ax, axes, critical)
    ax.set_title(title, fontsize=9)
    fig.tight_layout()
    from delaycomp.plotting import save

    try:
        save(fig, path)  # whole, never through a link
    finally:
        plt.close(fig)


def _draw_critical(ax, axes: list[Axis], points: np.ndarray) -> None:
    label = "exact lifted model: rho = 1 (critical delays)"
    if len(points) == 0:
        return
    if len(axes) == 1:
        for j, r in enumerate(points[:, 1]):
            ax.axvline(r, color="tab:blue", ls="--", lw=1.2,
                       label=f"{label}: r = {r:.6g}" if j < 3 else None)
    elif axes[1].name == "r":  # r on the horizontal axis
        ax.plot(points[:, 1], points[:, 0], "o", color="tab:blue", ms=3.5, label=label)
    else:
        ax.plot(points[:, 0], points[:, 1], "o", color="tab:blue", ms=3.5, label=label)
    ax.legend(fontsize=8, loc="upper right")
