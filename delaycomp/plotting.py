"""Plots of recorded trajectories (matplotlib, no display needed).

``figure`` draws into a new ``matplotlib.figure.Figure`` without pyplot, so it
never switches the caller's backend nor keeps figures alive in pyplot's registry.

A run's figure explains itself: a title that names the loop (``loop_title``), one
panel per signal with its unit where known, a legend, the sampling instants ``t_i`` and,
shaded, the delay window ``[t_i - r, t_i + tau]`` of the first sample whose prediction is
exact (``i = ceil(r/T)``, at least 1): the state measured at ``t_i`` is ``x(t_i - r)``, and
the input the controller computes then reaches the plant at ``t_i + tau``. Several runs of
the same loop (``run --compare``: compensated and uncompensated) share the panels, each
panel on a y scale on which every run reads (``choose_scale``): linear where the runs'
largest values are within ``LINEAR_RATIO`` of each other, else (a diverging baseline
beside a converging run) a symmetric log scale, linear within the smaller run's range, said
on the panel.
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
#: Runs drawn on one panel share a linear y axis while the largest ``|value|`` of one is at
#: most this many times that of another; beyond, the smaller run would fill less than a
#: quarter of the panel's half height (its dead-beat or its decay drawn flat on the zero
#: line), and the panel goes to a symmetric log scale (``choose_scale``).
LINEAR_RATIO = 4.0


@dataclass(frozen=True)
class Marks:
    """What the figure marks: period ``T`` and the delays ``r``, ``tau`` the controller
    assumes (seconds), from ``t0``. (The loop's base grid is
    ``delaycomp.system.Timing``; this is only what a figure draws.)"""

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


#: the earlier name of ``Marks`` (scripts written for it keep working)
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
    """``loop_title`` of a ``Loop``: its name and title, its
    period, the delays its controller assumes and (unless ``compare``) its mode."""
    ctrl = loop.by_role("controller")
    params = dict(ctrl.parameters) if ctrl is not None else {}
    params["T"] = loop.T
    if compare:
        params.pop("mode", None)
    return loop_title(loop.name, loop.title or None, params)


@dataclass(frozen=True)
class Scale:
    """The y scale of one panel: ``linear``, or ``symlog`` (linear within
    ``+-linthresh``, logarithmic beyond) with the words that say so on the figure."""

    kind: str = "linear"
    linthresh: float | None = None

    @property
    def note(self) -> str:
        """What the panel says about its scale (empty for a linear one)."""
        if self.kind != "symlog":
            return ""
        return (f"symmetric log scale: linear within \u00b1{self.linthresh:g}, "
                "logarithmic beyond")


def _nice_ceil(value: float) -> float:
    """The smallest of 1, 2, 5 times a power of ten that is >= ``value`` (> 0)."""
    decade = 10.0 ** math.floor(math.log10(value))
    for step in (1.0, 2.0, 5.0, 10.0):
        if step * decade >= value * (1 - 1e-12):
            return step * decade
    return 10.0 * decade  # pragma: no cover (10 * decade >= value always)


def choose_scale(columns: Sequence) -> Scale:
    """The y scale on which every run of one panel reads.

    Parameters
    ----------
    columns : sequence of array_like
        the panel's signal, one column per run.

    Returns
    -------
    Scale
        ``linear`` for a single run, or while the largest ``|value|`` of every run is
        within ``LINEAR_RATIO`` of the others'; else ``symlog`` whose linear part
        ``+-linthresh`` holds the run of the smallest range (its largest ``|value|``
        rounded up to 1, 2 or 5 times a power of ten), the larger runs growing
        logarithmically beyond.

    Examples
    --------
    >>> choose_scale([[1.0, -6.7, 0.3], [1.0, 14.6, -35.2]])
    Scale(kind='symlog', linthresh=10.0)
    >>> choose_scale([[1.0, -1.1, 0.1], [1.0, 0.6, -0.2]])
    Scale(kind='linear', linthresh=None)
    """
    peaks = [_peak(column) for column in columns]
    if len(peaks) < 2 or min(peaks) <= 0.0 or max(peaks) <= LINEAR_RATIO * min(peaks):
        return Scale()
    return Scale("symlog", _nice_ceil(min(peaks)))


def panel_scales(panels: Sequence[Sequence]) -> list[Scale]:
    """The y scales of a figure's panels, each a list of columns (one per run): linear
    for all while every panel reads on a linear axis; else every panel of several runs
    on its own symmetric log scale (``choose_scale``'s ``linthresh``, or that of its
    smallest nonzero run where the runs of that panel are close), so that the figure
    reads one way throughout.

    Examples
    --------
    >>> [s.kind for s in panel_scales([[[1, -6.7], [1, -35.2]], [[-5, 13], [-2, -50]]])]
    ['symlog', 'symlog']
    >>> [s.kind for s in panel_scales([[[1, -1.1], [1, 0.6]], [[-2, 2], [-2, 1]]])]
    ['linear', 'linear']
    """
    chosen = [choose_scale(columns) for columns in panels]
    if all(s.kind == "linear" for s in chosen):
        return chosen
    scales = []
    for columns, s in zip(panels, chosen):
        peaks = [p for p in (_peak(c) for c in columns) if p > 0]
        if s.kind == "linear" and len(columns) > 1 and peaks:
            s = Scale("symlog", _nice_ceil(min(peaks)))
        scales.append(s)
    return scales


def _apply_scale(ax, scale: Scale, top: float) -> None:
    """Set ``scale`` on ``ax`` with plain tick labels (0, +-linthresh and 1-2-5 steps
    or powers of ten beyond it up to ``top``, none closer than 1/12 of the axis) and its
    note in the panel's lower left corner."""
    if scale.kind != "symlog":
        return
    from matplotlib.ticker import FixedLocator, FormatStrFormatter

    assert scale.linthresh is not None
    lt = scale.linthresh
    ax.set_yscale("symlog", linthresh=lt, linscale=1.0)
    # ticks beyond lt at least 1/12 of the axis apart (the axis spans 2 (1 + log10(top /
    # lt)) decades: the linear part counts as one): 1-2-5 steps where that is close
    # enough, else powers of ten
    gap = 2 * (1 + math.log10(max(top, lt) / lt)) / 12
    steps = (1.0, 2.0, 5.0) if gap <= math.log10(2) else (1.0,)
    ticks = [lt]
    decade = 10.0 ** math.floor(math.log10(lt) + 1e-12)
    while decade <= top:
        for m in steps:
            v = m * decade
            if v <= top * (1 + 1e-12) and math.log10(v / ticks[-1]) >= gap - 1e-12:
                ticks.append(v)
        decade *= 10.0
    ax.yaxis.set_major_locator(FixedLocator([-t for t in reversed(ticks)] + [0.0] + ticks))
    ax.yaxis.set_major_formatter(FormatStrFormatter("%g"))
    ax.yaxis.set_minor_locator(FixedLocator([]))
    ax.text(0.01, 0.03, scale.note, transform=ax.transAxes, fontsize=7, va="bottom",
            ha="left", bbox={"boxstyle": "round", "fc": "white", "ec": "0.6", "alpha": 0.85})


def _label(name: str, units: dict[str, str]) -> str:
    var = name.split(".", 1)[-1]
    unit = units.get(var)
    return f"{name} [{unit}]" if unit else name


def figure(results, title: str = "", labels: Sequence[str] | None = None,
           timing: Marks | None = None, units: dict[str, str] | None = None,
           scale: str = "auto"):
    """One panel per recorded signal against time, one line per result; controller
    signals as staircases (they are held over each base step). Several results share
    each panel on the y scale of ``choose_scale``, said on the panel.

    Parameters
    ----------
    results : Result or list of Result
        the runs (``delaycomp.orchestrator.simulate.Result``); the first one's signals make the
        panels.
    title : str
        the figure's title (``loop_title``).
    labels : sequence of str, optional
        one label per result, in the legend (``["compensated", "uncompensated"]``).
    timing : Marks, optional
        marks the sampling instants and the first sample's delay window.
    units : dict, optional
        unit of a signal by variable name (``{"theta": "rad"}``).
    scale : {"auto", "linear"}
        ``auto``: each panel on ``choose_scale``'s scale (linear for one result);
        ``linear``: every panel linear.

    Returns
    -------
    matplotlib.figure.Figure
    """
    if scale not in ("auto", "linear"):
        raise ValueError(f"scale {scale!r} is not allowed: auto or linear")
    from matplotlib.figure import Figure

    results = list(results) if isinstance(results, (list, tuple)) else [results]
    units = units or {}
    names = list(results[0].names)
    n = len(names)
    fig = Figure(figsize=(8, 2.4 + 1.9 * n))
    axes = fig.subplots(n, 1, sharex=True, squeeze=False)[:, 0]
    t_end = max(float(r.times[-1]) for r in results if len(r.times))
    panels: list[list] = []
    for row, (ax, name) in enumerate(zip(axes, names)):
        style = "steps-post" if name.startswith("controller.") else "default"
        columns = []
        for k, result in enumerate(results):
            if name not in result.names:
                continue
            label = f"{name}, {labels[k]}" if labels else name
            columns.append(result.column(name))
            ax.plot(result.times, columns[-1], drawstyle=style, lw=1.4, label=label)
        panels.append(columns)
        ax.set_ylabel(_label(name, units))
        ax.grid(True, alpha=0.3)
        ax.axhline(0.0, color="k", lw=0.6)
        if timing is not None:
            _mark_timing(ax, timing, t_end, legend=row == 0)
        ax.legend(fontsize=7, loc="best")
    scales = panel_scales(panels) if scale == "auto" else [Scale()] * n
    for ax, columns, scaled in zip(axes, panels, scales):
        _apply_scale(ax, scaled, max((_peak(c) for c in columns), default=0.0))
        if scaled.kind == "symlog":
            ax.set_ylabel(ax.get_ylabel() + "\n(symmetric log)")
    axes[-1].set_xlabel("time t [s]")
    if title:
        fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    return fig


def _peak(column) -> float:
    """The largest finite ``|value|`` of a column (0 for none)."""
    import numpy as np

    values = np.abs(np.asarray(column, dtype=float))
    values = values[np.isfinite(values)]
    return float(values.max()) if values.size else 0.0


def result_figure(result, title: str, timing: Marks | None = None,
                  units: dict[str, str] | None = None, compare: dict | None = None):
    """``figure`` of ``result``, or of the labelled runs ``compare``
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
    """``result_figure`` written to ``path`` (its suffix picks the format)."""
    save(result_figure(result, title, timing, units, compare), path)
