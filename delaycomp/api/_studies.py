"""The API's studies of a loop over many runs or values: a parameter grid (``sweep``,
``iter_sweep``), a Monte Carlo map over a channel's jitter x loss (``robustness``), the
critical measurement delay of the uncompensated loop (``critical_delay``,
``critical_delay_report``, ``critical_delay_table``)."""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from delaycomp.api._common import LoopLike, as_assignments, as_loop
from delaycomp.errors import ParameterError, short
from delaycomp.system.loop import refuse_channel

if TYPE_CHECKING:
    from delaycomp.studies.axes import Axis


def sweep(source: LoopLike, grid: Mapping[str, Sequence[float]] | Sequence[Axis], *,
          sets: Sequence[str] | Mapping[str, object] = (),
          stop_time: float | None = None, engine: str = "batch", workers: int = 1,
          exact: bool = False, array_backend: str = "numpy", chunk: int | None = None,
          scheduler: str | None = None, notes: list[str] | None = None,
          fmu_dir: str | Path | None = None, verbosity: int = 0) -> list[dict]:
    """Metrics (``rho``, ``stable``, ``final_norm``, ``peak_norm``, ``deadbeat_time``,
    ``failed``) of ``source`` at every point of ``grid`` (parameter name -> values), one
    dict per point in grid order (the last parameter varies fastest). ``failed`` is empty
    where the run reached its stop time, else why not; where that is not the loop's own
    divergence (which is unstable, ``rho = inf``) ``rho`` and ``stable`` are ``None``
    (``delaycomp.studies.sweep``).

    ``source`` is a scenario name, a loop file's path or a ``Loop`` (from
    ``load``, ``lti`` or ``model``: it keeps the loop-file data it was built
    from, and each point is built again from it); grid and ``sets`` names are a scenario's
    parameters or a loop's loop-file keys (``r``, ``T``, ``tau``, ``N``, ``controller.K``,
    ...) or their short names (``x0``, ``u0``, ``K``, ``mode``, a model's own parameters;
    a single number for a vector or matrix key is a list of one: ``K=-2`` is
    ``[[-2]]``). A ``Loop`` sweeps to the rows of the same loop given as a loop file.
    ``engine`` is ``batch`` (all points
    advanced together, vectorized; points it cannot take run on the per-point engine),
    ``inprocess`` or ``fmu`` (point by point); the results agree (tested). ``workers``
    processes or a Dask ``scheduler`` address share the work; ``array_backend`` (numpy,
    cupy, jax, auto) and ``chunk`` (points per batch) tune the batch engine; what it did is
    appended to ``notes``. The ``fmu`` engine takes the FMUs of ``fmu_dir`` first;
    ``verbosity`` 1 shows a progress bar on a terminal. See
    ``delaycomp.studies.sweep.run_sweep``.

    The rows are held together: a grid whose rows would not fit in half of the memory is
    refused before anything runs (a ``ParameterError`` naming the points and the
    estimate); ``iter_sweep`` hands them on one at a time instead.

    Examples
    --------
    Without compensation Example 3.6 loses stability between ``r = 0`` and ``r = 0.5``
    (for ``k = 2``: at ``r_c = 0.203``); at ``r = 0``, ``rho = e - k`` per period:

    >>> notes = []
    >>> rows = sweep("example-3.6", {"k": [1.5, 2.0], "r": [0.0, 0.5]},
    ...              sets=["mode=uncompensated"], stop_time=10.0, notes=notes)
    >>> [(row["k"], row["r"], row["stable"]) for row in rows]
    [(1.5, 0.0, 1), (1.5, 0.5, 0), (2.0, 0.0, 1), (2.0, 0.5, 0)]
    >>> round(rows[2]["rho"], 6)
    0.718282
    >>> notes
    ['batch engine (numpy, cpu): 4 of 4 points in 1 chunk']

    A loop of your own, over its gain and delay:

    >>> from delaycomp.api import lti
    >>> loop = lti([[1.0]], [[1.0]], [[-2.0]], T=1.0, x0=[1.0], mode="uncompensated",
    ...            allow_unstable=True)
    >>> rows = sweep(loop, {"K": [-1.5, -2.0], "r": [0.0, 0.5]}, stop_time=10.0)
    >>> [(row["K"], row["r"], row["stable"]) for row in rows]
    [(-1.5, 0.0, 1), (-1.5, 0.5, 0), (-2.0, 0.0, 1), (-2.0, 0.5, 0)]
    """
    from delaycomp.studies.sweep import run_sweep

    return run_sweep(_source(source), _axes(grid), as_assignments(sets),
                     _sweep_options(stop_time, engine, workers, scheduler, fmu_dir, exact,
                                    array_backend, chunk, verbosity), notes=notes)


def iter_sweep(source: LoopLike, grid: Mapping[str, Sequence[float]] | Sequence[Axis], *,
               sets: Sequence[str] | Mapping[str, object] = (),
               stop_time: float | None = None, engine: str = "batch", workers: int = 1,
               exact: bool = False, array_backend: str = "numpy", chunk: int | None = None,
               scheduler: str | None = None, notes: list[str] | None = None,
               fmu_dir: str | Path | None = None, verbosity: int = 0) -> Iterator[dict]:
    """``sweep``'s rows one at a time, in grid order, in memory bounded at any grid
    size (``sweep`` holds them all, and refuses a grid whose rows would not fit in half
    of the memory): the points run a stream chunk at a time as the rows are taken. Every
    point is validated before this returns (a refusal raises here); ``notes`` are appended
    once the last row is taken. See ``delaycomp.studies.sweep.iter_sweep``.

    Examples
    --------
    Count the stable points of a map without holding its rows:

    >>> rows = iter_sweep("example-3.6", {"k": [1.5, 2.0], "r": [0.0, 0.5]},
    ...                   sets=["mode=uncompensated"], stop_time=10.0)
    >>> sum(row["stable"] for row in rows)
    2
    """
    from delaycomp.studies.sweep import iter_sweep as stream

    return stream(_source(source), _axes(grid), as_assignments(sets),
                  _sweep_options(stop_time, engine, workers, scheduler, fmu_dir, exact,
                                 array_backend, chunk, verbosity), notes=notes)


def _source(source: LoopLike):
    """What a study runs, opened once by the same reading as ``as_loop``
    (``open_source``: a ``Loop``'s loop-file data, a loop file, a scenario; an opened
    one passes as it is) and handed down opened."""
    from delaycomp.paper.scenarios import open_source

    return open_source(source)  # refuses what is none of them, in one short line


def _sweep_options(stop_time, engine, workers, scheduler, fmu_dir, exact, array_backend,
                   chunk, verbosity):
    """``sweep``'s and ``iter_sweep``'s keywords as the study's ``SweepOptions``."""
    from delaycomp.studies.sweep import SweepOptions

    return SweepOptions(stop=stop_time, engine=engine, workers=workers, scheduler=scheduler,
                        fmu_dir=None if fmu_dir is None else str(fmu_dir), exact=exact,
                        array_backend=array_backend, chunk=chunk, verbosity=verbosity)


def _axes(grid) -> list:
    """The ``Axis`` of each grid parameter: of a mapping of name -> values, or a list of
    ``delaycomp.studies.axes.Axis`` (the command line's ``--grid``, where a name may
    repeat: the sweep refuses that)."""
    from delaycomp.studies.axes import Axis

    if isinstance(grid, (list, tuple)) and grid and all(isinstance(a, Axis) for a in grid):
        items = [(a.name, a.values) for a in grid]
    elif isinstance(grid, Mapping):
        items = list(grid.items())
    else:
        raise ParameterError(f"grid = {short(grid)} is not allowed: give a mapping of "
                             "parameter name -> values")
    axes = []
    for name, values in items:
        try:
            axes.append(Axis(name, tuple(float(v) for v in np.ravel(values))))
        except (TypeError, ValueError):
            raise ParameterError(f"grid[{name!r}] = {short(values)} is not allowed: must "
                                 "be numbers") from None
    return axes


def robustness(loop: LoopLike, jitter: Sequence[float], loss: Sequence[float],
               runs: int, *, seed: int = 0, on: str = "meas_delay",
               modes: Sequence[str] = ("compensated", "uncompensated"),
               distribution: str = "uniform",
               sets: Sequence[str] | Mapping[str, object] = (),
               stop_time: float | None = None, chunk: int | None = None,
               array_backend: str = "numpy", progress: Callable[[int], None] | None = None):
    """A Monte Carlo robustness map of an LTI loop over a network channel's jitter x loss.

    At every ``(jitter, loss)`` the channel ``on`` (its loop-file table the base, else the
    loop's constant delay) draws its delays from ``distribution`` with that amplitude and
    loses packets with that Bernoulli rate; ``runs`` seeds per point and mode run on the
    batch engine (the same numbers as ``run(..., engine="inprocess")`` per seed). See
    ``delaycomp.studies.robustness`` for the seeds and the statistics.

    Parameters
    ----------
    loop : Loop, str or Path
        An LTI loop: a loop file's path or a ``Loop`` built from loop-file data (``lti``,
        ``load``).
    jitter, loss : sequence of float
        The grid: jitter amplitudes [s] (``>= 0``), loss rates (``0 .. 1``).
    runs : int
        Seeds per grid point and mode; run ``i`` draws seed ``seed + i``.
    seed : int
        The base seed (``0 .. 2^31 - 1``).
    on : {"meas_delay", "input_delay"}
        The channel the grid acts on.
    modes : sequence of str
        ``compensated``, ``uncompensated`` (and ``stamped`` once the batch engine reads
        time stamps: ``delaycomp.studies.robustness.stamped_available``).
    distribution : {"uniform", "exponential", "gamma"}
        The jitter's distribution (the latter two need the table's ``max_delay``).
    sets : sequence of str or mapping
        Overrides as ``load`` takes them (``meas_delay.policy=drop_stale``).
    stop_time : float, optional
        Each run's horizon (default: the loop's).
    chunk : int, optional
        Runs per batch-engine call at most.
    array_backend : {"numpy", "cupy", "auto"}
        The batch engine's array library: ``cupy`` runs on an NVIDIA GPU (the ``cupy``
        extra), ``auto`` there where CuPy reaches one, else numpy; the numbers are the
        same bit for bit.
    progress : callable, optional
        ``progress(k)`` hears each ``k`` runs done (a progress bar's update).

    Returns
    -------
    delaycomp.studies.robustness.RobustnessMap
        ``rows``: one dict per grid point and mode (``p_stable`` with its Wilson 95 %
        interval ``p_low``/``p_high``, quantiles of the cost and the final norm);
        ``array(column, mode)`` a column over the grid.

    Examples
    --------
    Example 3.6 with its measurement through a lossy, jittery network (delays from
    ``r = 0.3`` to ``0.5``): the predictor keeps every run stable, the feedback on the
    late sample alone none:

    >>> from delaycomp.api import lti
    >>> m = robustness(lti([[1.0]], [[1.0]], [[-2.0]], T=1.0, r=0.3, x0=[1.0]),
    ...                jitter=[0.0, 0.2], loss=[0.0, 0.3], runs=50, stop_time=20.0)
    >>> m.array("p_stable", "compensated").tolist()
    [[1.0, 1.0], [1.0, 1.0]]
    >>> [row["stable"] for row in m.rows if row["mode"] == "uncompensated"]
    [0, 0, 0, 0]
    """
    from delaycomp.studies import robustness as study
    from delaycomp.system.loopfile import LoopFile

    source = _source(loop)
    if not isinstance(source, LoopFile):
        raise ParameterError(f"loop = {short(loop)} is not allowed: give an LTI loop file's "
                             "path or a Loop built from loop-file data (a scenario: its "
                             "loop file, delaycomp.paper.scenarios.loop_file)")
    return study.robustness(source, jitter, loss, runs, seed=seed, on=on, modes=modes,
                            distribution=distribution, sets=as_assignments(sets),
                            stop_time=stop_time, chunk=chunk, array_backend=array_backend,
                            progress=progress)


def critical_delay(loop: LoopLike, *,
                   sets: Sequence[str] | Mapping[str, object] = ()) -> float:
    """The largest measurement delay ``r_c`` for which the *uncompensated* LTI loop is
    stable, from the spectral radius of the exact lifted model (the loop's own ``r`` is not
    used). ``loop``: a ``Loop``, a loop file's path or a scenario's name, with
    ``sets`` as ``load`` takes them.

    Examples
    --------
    Example 3.6 with ``k = 2`` (``r_c = 0.203``, see ``sweep``):

    >>> round(critical_delay("example-3.6", sets={"k": 2.0}), 3)
    0.203
    """
    from delaycomp.maths.lti import critical_delay as search
    from delaycomp.maths.lti import lifted_loop

    loop = as_loop(loop, sets)
    refuse_channel(loop, "critical_delay (its lifted model has constant delays)")
    d = loop.lti
    if d is None:
        raise ParameterError(f"critical_delay needs an LTI loop; {loop.name} is not")
    d = d.equivalent(loop.T)  # pad: the loop of the padded delay

    def rho(r: float) -> float:
        return lifted_loop(d.A, d.B, d.K, loop.T, r, d.tau, "uncompensated").spectral_radius

    return search(rho, r_max=50 * loop.T, step=loop.T / 100)


def critical_delay_report(loop: LoopLike, *,
                          sets: Sequence[str] | Mapping[str, object] = (),
                          periods: int = 40, fmu_dir: str | Path | None = None):
    """``critical_delay``'s ``r_c``, confirmed by co-simulation (``delaycomp
    critical-delay``): the uncompensated loop runs ``periods`` periods just below and just
    above ``r_c`` on its FMUs (those of ``fmu_dir`` first), and the spectral radius fitted
    to each trajectory must fall on the side the lifted model says.

    Returns
    -------
    delaycomp.studies.critical.CriticalDelayReport
        ``r_c``, ``confirmed``, ``checks`` (``r``, the lifted model's spectral radius,
        the fitted one) and the report's ``lines``.

    Examples
    --------
    >>> report = critical_delay_report("example-3.6", sets={"k": 2.0}, periods=10)
    >>> round(report.r_c, 3), report.confirmed
    (0.203, True)
    """
    from delaycomp.studies.critical import critical_delay_report as report

    if isinstance(periods, bool) or not isinstance(periods, int) or periods < 10:
        raise ParameterError(f"periods = {periods!r} is not allowed: must be an integer >= 10")
    return report(_source(loop), as_assignments(sets), periods,
                  None if fmu_dir is None else Path(fmu_dir))


def critical_delay_table(loop: LoopLike, grid: str, *,
                         sets: Sequence[str] | Mapping[str, object] = (),
                         out: str | Path | None = None,
                         plot: str | Path | None = None) -> list[str]:
    """``r_c`` of the uncompensated and of the compensated loop along one parameter
    (``grid``: ``NAME=START:STOP:COUNT``), from the exact lifted model alone (``delaycomp
    critical-delay --grid``); the table written as CSV to ``out`` and drawn to ``plot``
    where given. Returns the table's text lines (a header, then one line per value;
    ``stable r<=R`` where no ``r`` up to the search's end loses stability, ``unstable at
    r=0`` where ``r = 0`` already does). See ``delaycomp.studies.critical``.

    Examples
    --------
    >>> for line in critical_delay_table("example-3.6", "k=1.5:2:2"):
    ...     print(line)
             k  r_c uncompensated    r_c compensated
           1.5        0.281372633        stable r<=5
             2        0.203267055        stable r<=5
    """
    from delaycomp.studies.critical import critical_delay_table as table

    return table(_source(loop), as_assignments(sets), grid,
                 None if out is None else Path(out), None if plot is None else Path(plot))
