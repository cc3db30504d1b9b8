"""Plots of recorded trajectories (matplotlib, no display needed).

:func:`figure` draws into a new :class:`matplotlib.figure.Figure` without pyplot, so it
never switches the caller's backend nor keeps figures alive in pyplot's registry.

A run's figure explains itself: a title that names the loop (:func:`loop_title`), one
panel per signal with its unit where known, a legend, the sampling instants ``t_i`` and,
shaded, the delay window ``[t_i - r, t_i + tau]`` of the first sample whose prediction is
exact (``i = ceil(r/T)``, at least 1): the state measured at ``t_i`` is ``x(t_i - r)``, and
the input the controller computes then reaches the plant at ``t_i + tau``. Several runs of
the same loop (``run --compare``: compensated and uncompensated) share the panels.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

#: Units of signals, by the variable's name, where the loop's model fixes them (the
#: unicycle of Proposition 4.2 and Corollary 4.1: positions in metres, heading in
#: radians). The paper's other examples are dimensionless.
UNITS_BY_LOOP: dict[str, dict[str, str]] = {
    "proposition-4.2": {"x": "m", "y": "m", "theta": "rad", "v": "m/s", "omega": "rad/s"},
    "corollary-4.1": {"x": "m", "y": "m", "theta": "rad", "v": "m/s", "omega": "rad/s"},
}
#: At most this many sampling instants are drawn as lines (beyond, they would fill the
#: panel; the title still gives T).
MAX_SAMPLE_LINES = 60


@dataclass(frozen=True)
class Marks:
    """What the figure marks: period ``T`` and the delays ``r``, ``tau`` the controller
    assumes (seconds), from ``t0``. (The loop's base grid is
    :class:`delaycomp.system.Timing`; this is only what a figure draws.)"""

    T: float
    r: float
    tau: float
    t0: float = 0.0

    @classmethod
    def of_loop(cls, loop) -> Marks | None:
        """From a loop's controller parameters (``None`` if it has no controller)."""
        ctrl = loop.by_role("controller")
        if ctrl is None:
            return None
        params = ctrl.parameters
        return cls(float(loop.T), float(params.get("r", 0.0)), float(params.get("tau", 0.0)))

    of_spec = of_loop


#: the earlier name of :class:`Marks` (scripts written for it keep working)
Timing = Marks


def loop_title(name: str, description: str | None, params: dict | None = None) -> str:
    """The title of a loop's figure: its name and description, then its timing.

    One function for every figure, so that scenarios, SSP files and loop files name
    their loop the same way.

    Parameters
    ----------
    name : str
        the scenario name or the file name of the loop.
    description : str or None
        one line saying what the loop is.
    params : dict, optional
        ``T``, ``r``, ``tau`` and ``mode`` go into the second line.

    Returns
    -------
    str
        two lines.

    Examples
    --------
    >>> print(loop_title("example-3.6", "x' = x + u", {"T": 1.0, "r": 0.3, "tau": 0.0,
    ...                                                "mode": "compensated"}))
    example-3.6: x' = x + u
    T = 1 s, r = 0.3 s, tau = 0 s, compensated
    """
    head = f"{name}: {description}" if description else name
    params = params or {}
    parts = [f"{k} = {params[k]:g} s" for k in ("T", "r", "tau")
             if isinstance(params.get(k), (int, float))]
    if params.get("mode"):
        parts.append(str(params["mode"]))
    return head + ("\n" + ", ".join(parts) if parts else "")


def title_of_loop(loop, compare: bool = False) -> str:
    """:func:`loop_title` of a :class:`~delaycomp.system.Loop`: its name and title, its
    period, the delays its controller assumes and (unless ``compare``) its mode."""
    ctrl = loop.by_role("controller")
    params = dict(ctrl.parameters) if ctrl is not None else {}
    params["T"] = loop.T
    if compare:
        params.pop("mode", None)
    return loop_title(loop.name, loop.title or None, params)


def _label(name: str, units: dict[str, str]) -> str:
    var = name.split(".", 1)[-1]
    unit = units.get(var)
    return f"{name} [{unit}]" if unit else name


def figure(results, title: str = "", labels: Sequence[str] | None = None,
           timing: Marks | None = None, units: dict[str, str] | None = None):
    """One panel per recorded signal against time, one line per result; controller
    signals as staircases (they are held over each base step).

    Parameters
    ----------
    results : Result or list of Result
        the runs (:class:`delaycomp.orchestrator.simulate.Result`); the first one's signals make the
        panels.
    title : str
        the figure's title (:func:`loop_title`).
    labels : sequence of str, optional
        one label per result, in the legend (``["compensated", "uncompensated"]``).
    timing : Marks, optional
        marks the sampling instants and the first sample's delay window.
    units : dict, optional
        unit of a signal by variable name (``{"theta": "rad"}``).

    Returns
    -------
    matplotlib.figure.Figure
    """
    from matplotlib.figure import Figure

    results = list(results) if isinstance(results, (list, tuple)) else [results]
    units = units or {}
    names = list(results[0].names)
    n = len(names)
    fig = Figure(figsize=(8, 2.4 + 1.9 * n))
    axes = fig.subplots(n, 1, sharex=True, squeeze=False)[:, 0]
    t_end = max(float(r.times[-1]) for r in results if len(r.times))
    for row, (ax, name) in enumerate(zip(axes, names)):
        style = "steps-post" if name.startswith("controller.") else "default"
        for k, result in enumerate(results):
            if name not in result.names:
                continue
            label = f"{name}, {labels[k]}" if labels else name
            ax.plot(result.times, result.column(name), drawstyle=style, lw=1.4, label=label)
        ax.set_ylabel(_label(name, units))
        ax.grid(True, alpha=0.3)
        ax.axhline(0.0, color="k", lw=0.6)
        if timing is not None:
            _mark_timing(ax, timing, t_end, legend=row == 0)
        ax.legend(fontsize=7, loc="best")
    axes[-1].set_xlabel("time t [s]")
    if title:
        fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    return fig


def result_figure(result, title: str, timing: Marks | None = None,
                  units: dict[str, str] | None = None, compare: dict | None = None):
    """:func:`figure` of ``result``, or of the labelled runs ``compare``
    (``{"compensated": r1, "uncompensated": r2}``) of the same loop."""
    if compare:
        return figure(list(compare.values()), title, list(compare), timing, units)
    return figure(result, title, None, timing, units)


def _mark_timing(ax, timing: Marks, t_end: float, legend: bool) -> None:
    T, r, tau, t0 = timing.T, timing.r, timing.tau, timing.t0
    count = math.floor((t_end - t0) / T + 1e-9) + 1
    if count <= MAX_SAMPLE_LINES:
        for i in range(count):
            ax.axvline(t0 + i * T, color="0.55", lw=0.6, ls=":",
                       label=f"sampling instants t_i = {t0:g} + i T" if legend and i == 0
                       else None)
    i = max(1, math.ceil(r / T - 1e-9))
    t_i = t0 + i * T
    if t_i <= t_end and (r > 0 or tau > 0):
        ax.axvspan(max(t0, t_i - r), min(t_end, t_i + tau), color="tab:orange", alpha=0.15,
                   label=(f"sample t_{i} = {t_i:g} s: measures x(t_{i} - r), acts at "
                          f"t_{i} + tau" if legend else None))


def save(fig, path: str | Path) -> None:
    """Write ``fig`` to ``path`` through a temporary file (no half-written image)."""
    from delaycomp.tmpfiles import replacing

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with replacing(path, binary=True) as fh:  # never through a link
        fig.savefig(fh, dpi=110, format=path.suffix.lstrip(".").lower() or "png")


def plot_result(result, path: str | Path, title: str, timing: Marks | None = None,
                units: dict[str, str] | None = None, compare: dict | None = None) -> None:
    """:func:`result_figure` written to ``path`` (its suffix picks the format)."""
    save(result_figure(result, title, timing, units, compare), path)
