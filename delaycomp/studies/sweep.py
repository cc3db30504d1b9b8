"""Parameter sweeps and stability maps: many runs of one loop (a scenario or a loop file)
over a grid.

Each grid point is one run (or, with ``exact``, one lifted-model eigenvalue computation for
LTI scenarios). Per point the sweep reports

- ``rho``: the per-period growth factor of the state, from the trajectory's tail: with
  ``e_j`` the root-sum-square of ``|x|`` over period ``j`` (which averages out the phase of
  oscillating modes), ``rho = exp(slope)`` of a least-squares line through ``log e_j``
  after the first fifth of the periods (0 if the state is exactly zero there, ``inf`` if
  the loop diverged); on Example 3.6 over 20 periods it is within 0.017 of the exact
  value. With ``exact`` it is the spectral radius of the lifted closed loop
  (``delaycomp.maths.lti.lifted_loop``);
- ``stable``: 1 if ``rho < 1``, else 0;
- ``final_norm``, ``peak_norm``: ``|x|`` at the end (of what was recorded) and its largest
  value;
- ``deadbeat_time``: the time from which ``|x| < 1e-9`` holds to the end (empty if never);
- ``failed``: empty where the run reached its stop time, else why it did not (the failing
  component, the time and its reason; the wording depends on the engine). A run that
  ends because the loop itself diverged (one of delaycomp's own components found its
  state, prediction or control overflowing: ``delaycomp.errors.is_divergence``) is
  unstable: ``rho = inf``, ``stable = 0``. Any other failure (a plant FMU file whose
  output turned NaN or infinite, a refused call, an exception in a model) says nothing
  about stability: ``rho`` and ``stable`` are empty (``None``), never "unstable".

Points run one after another, on local worker processes, or on a Dask cluster; every
point is computed by the same deterministic function, so the results do not depend on how
they are distributed. With ``engine="batch"`` the points are advanced together, vectorized
(``delaycomp.studies.batch``, ``delaycomp.studies.sweep_batch``), in chunks spread
the same way; points it cannot take run on the per-point in-process engine, and ``notes``
says which.

Memory stays bounded at any grid size: every point is validated, a piece
(``PIECE_POINTS``) at a time, before any runs; then the points are resolved, run and
handed on a stream chunk (``STREAM_POINTS``) at a time (``iter_sweep``), and
``delaycomp sweep`` writes their rows to its CSV as they come. ``run_sweep`` returns
the rows together: a grid whose rows would not fit in half of the memory is refused
before anything runs, with the estimate (``check_sweep_size``, ``sweep_memory``).
"""

from __future__ import annotations

import contextlib
import copy
import dataclasses
import gc
import itertools
import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TypeAlias

import numpy as np

from delaycomp.errors import ParameterError, is_divergence
from delaycomp.paper.scenarios import Scenario, open_source
from delaycomp.studies import sweep_size
from delaycomp.studies.axes import Axis, base_loop, format_value
from delaycomp.studies.metrics import METRICS, ZERO, tail_start
from delaycomp.studies.pool import Progress, on_dask, on_processes
from delaycomp.studies.sweep_output import Tally, plot_sweep, write_csv, write_table
from delaycomp.studies.sweep_size import (
    BYTES_PER_KEPT_LTI,
    BYTES_PER_KEPT_MODEL,
    BYTES_PER_RESOLVED,
    BYTES_PER_ROW,
    BYTES_PER_ROW_WIDE,
    BYTES_PER_RUN,
    BYTES_PER_STREAMED,
    KEEP_BYTES,
    PIECE_POINTS,
    PLOT_MAX_POINTS,
    SECONDS_PER_BATCH_TICK,
    SECONDS_PER_EXACT_POINT,
    SECONDS_PER_POINT,
    STREAM_POINTS,
    check_memory,
    check_time,
    sweep_memory,
)
from delaycomp.system import FmuFile, Loop, LtiBatch, Timing
from delaycomp.system.loop import refuse_channel
from delaycomp.system.loopfile import LoopData, LoopFile

#: the sweep's names, its estimates' and its output's (``.sweep_size``, ``.sweep_output``)
#: among them: what ``delaycomp.studies.sweep`` offers
__all__ = [
    "BYTES_PER_KEPT_LTI",
    "BYTES_PER_KEPT_MODEL",
    "BYTES_PER_RESOLVED",
    "BYTES_PER_ROW",
    "BYTES_PER_ROW_WIDE",
    "BYTES_PER_RUN",
    "BYTES_PER_STREAMED",
    "KEEP_BYTES",
    "METRICS",
    "PIECE_POINTS",
    "PLOT_MAX_POINTS",
    "SECONDS_PER_BATCH_TICK",
    "SECONDS_PER_EXACT_POINT",
    "SECONDS_PER_POINT",
    "STREAM_POINTS",
    "SWEEP_ENGINES",
    "ZERO",
    "Job",
    "Source",
    "SweepOptions",
    "Tally",
    "check_sweep_size",
    "evaluate",
    "iter_sweep",
    "metrics_of",
    "plot_sweep",
    "result_metrics",
    "run_sweep",
    "sweep_memory",
    "write_csv",
    "write_table",
]


@dataclass(frozen=True)
class Job:
    """Everything one grid point needs; picklable for worker processes and Dask."""

    #: a scenario's name, or the opened loop file or loop-file data (``LoopFile``,
    #: ``LoopData``: its data travel with the job, so a worker process reads no file)
    scenario: str | LoopFile
    sets: tuple[str, ...]
    stop: float
    engine: str
    fmu_dir: str | None
    exact: bool


def metrics_of(times: np.ndarray, states: np.ndarray, N: int, success: bool = True,
               reason: str = "", diverged: bool = False) -> dict:
    """The sweep's metrics for a recorded trajectory (``states``: one row per base step).

    ``success`` False: the run stopped early for ``reason``; ``diverged``: because the
    loop diverged (``rho = inf``, unstable), else ``rho`` and ``stable`` are ``None``.

    Examples
    --------
    >>> t = np.arange(11) * 0.1
    >>> m = metrics_of(t, np.ones((11, 1)), 2, False, "plant failed at t = 1: ...")
    >>> m["rho"], m["stable"], m["failed"]
    (None, None, 'plant failed at t = 1: ...')
    """
    norms = np.linalg.norm(states, axis=1) if states.size else np.array([np.nan])
    peak = float(np.nanmax(norms)) if norms.size and not np.all(np.isnan(norms)) \
        else math.nan
    final = float(norms[-1])
    above = np.nonzero(~(norms < ZERO))[0]
    if above.size == 0:
        deadbeat = float(times[0])
    elif above[-1] + 1 < len(norms):
        deadbeat = float(times[above[-1] + 1])
    else:
        deadbeat = None
    if success and not np.all(np.isfinite(norms)):  # a master that ran on (never ours)
        k = int(np.nonzero(~np.isfinite(norms))[0][0])
        success, diverged = False, False
        reason = f"the plant state is not finite at t = {float(times[k]):.12g}"
    if not success:
        rho = math.inf if diverged else None
        return {"rho": rho, "stable": 0 if diverged else None, "final_norm": final,
                "peak_norm": peak, "deadbeat_time": None,
                "failed": " ".join(str(reason).split()) or "the run failed"}
    periods = (len(norms) - 1) // N
    env = np.array([math.sqrt(float(np.sum(norms[j * N:(j + 1) * N] ** 2)))
                    for j in range(periods)])
    tail = env[tail_start(periods):]
    if tail.size < 2:
        rho = math.nan  # too few periods to estimate a rate
    elif np.any(tail == 0.0):
        rho = 0.0
    else:
        slope = np.polyfit(np.arange(tail.size), np.log(tail), 1)[0]
        rho = float(math.exp(slope))
    return {"rho": rho, "stable": int(rho < 1.0), "final_norm": final, "peak_norm": peak,
            "deadbeat_time": deadbeat, "failed": ""}


def result_metrics(loop, res) -> dict:
    """The sweep's metrics of a run of ``loop`` (a ``delaycomp.system.Loop``): its
    plant's recorded states, and where the run failed, whether the loop diverged (one of
    delaycomp's own components said so; a plant FMU file's breakdown is a failure)."""
    plant = loop.by_role("plant").name
    n_states = sum(1 for port in loop.recorded if port.instance == plant)
    ours = {inst.name for inst in loop.instances if not isinstance(inst.source, FmuFile)}
    diverged = is_divergence(res.message, res.failed_by in ours)
    return metrics_of(res.times, res.data[:, :n_states], loop.N, res.success,
                      res.message, diverged)


def evaluate(job: Job) -> dict:
    """Metrics of one grid point (a top-level function, for processes and Dask)."""
    from delaycomp.orchestrator.simulate import run_loop

    spec = open_source(job.scenario).loop(list(job.sets))
    if job.exact:
        from delaycomp.maths.lti import lifted_loop

        d = spec.lti.equivalent(spec.T)  # pad: the loop of the padded delay
        lifted = lifted_loop(d.A, d.B, d.K, spec.T, d.r, d.tau, d.mode, d.r_true, d.tau_true)
        rho = lifted.spectral_radius
        return {"rho": rho, "stable": int(rho < 1.0), "final_norm": None, "peak_norm": None,
                "deadbeat_time": None, "failed": ""}
    fmu_dir = Path(job.fmu_dir) if job.fmu_dir is not None else None
    files = point_fmus(spec, fmu_dir) if job.engine == "fmu" else None
    return result_metrics(spec, run_loop(spec, job.stop, fmu_dir, engine=job.engine,
                                         fmus=files))


def point_fmus(loop, fmu_dir: Path | None = None) -> dict[str, Path] | None:
    """The FMU files of a grid point's run on the ``fmu`` engine, as ``delaycomp run``
    chooses them: the native ones where the loop has them here (stepped by the native
    core, ``delaycomp.orchestrator.native_core``), else ``None``, the Python FMUs
    (``delaycomp.fmu.twins.choose``)."""
    from delaycomp.fmu import twins

    return twins.choose(loop, "auto", fmu_dir)[0]


def native_point(loop) -> bool:
    """Can the ``fmu`` engine run ``loop`` (a point the batch engine does not take) with
    native FMUs, stepped by the native core? A C compiler, the core, and native twins of
    every instance (``delaycomp.fmu.twins.check_native``; a model that does not translate
    still runs, on its Python FMUs)."""
    from delaycomp.fmu import twins
    from delaycomp.orchestrator.native_core import core_status

    try:
        twins.check_native(loop)
    except ValueError:
        return False
    return core_status() is None


def _prebuild(jobs: list[Job]) -> None:
    """Build every FMU the jobs need here, once, before workers start: the native ones
    where the loop has them (``point_fmus``), else the Python ones."""
    from delaycomp.fmu.cache import fmu_path
    from delaycomp.orchestrator.native_core import core_status

    core_status()  # the native core compiled here once, not in each worker at once
    seen = set()
    for job in jobs:
        loop = open_source(job.scenario).loop(list(job.sets))
        keys = [inst.source.build_key() for inst in loop.instances]
        ident = tuple((k[0], tuple(sorted(k[1].items()))) for k in keys if k is not None)
        if ident in seen:
            continue
        seen.add(ident)
        fmu_dir = Path(job.fmu_dir) if job.fmu_dir else None
        if point_fmus(loop, fmu_dir) is not None:
            continue  # native, built (or found) by point_fmus
        for key in keys:
            if key is not None:
                fmu_path(key[0], key[1], fmu_dir)


def check_sweep_size(source: Source, axes: list[Axis], sets: list[str],
                     options: SweepOptions | None = None, held: bool = True,
                     plot: bool = False) -> tuple[int, float]:
    """Refuse, in one line with the estimate, a grid that cannot finish or fit in memory.

    ``source``: what ``open_source`` takes (an opened one is not read again);
    ``held``: the rows are returned together (``run_sweep``), else streamed
    (``iter_sweep``, ``delaycomp sweep``); ``plot``: ``--plot`` draws them (at most
    ``PLOT_MAX_POINTS``). Returns the number of points and the estimated seconds (a
    lower bound).

    Examples
    --------
    >>> from delaycomp.studies.axes import parse_grid
    >>> check_sweep_size("example-3.6", [parse_grid("k=1:2:11")], [],
    ...                  SweepOptions(stop=10.0, engine="batch"))[0]
    11
    """
    opts = options or SweepOptions()
    sc = open_source(source)
    count = math.prod(len(a.values) for a in axes)
    if plot and count > PLOT_MAX_POINTS:
        raise ParameterError(
            f"--plot: {count:.4g} points are more than a map can draw ({PLOT_MAX_POINTS:.4g} "
            "at most, more than its pixels); drop --plot or use fewer points")
    base = None if opts.exact else base_loop(sc, sets)
    workers = 1 if opts.scheduler else opts.workers
    seconds = check_time(sc, axes, count, base, opts.stop, opts.engine, workers, opts.exact)
    kept = 0
    if opts.engine == "batch" and not opts.exact:
        kept = BYTES_PER_KEPT_MODEL if base is None or base.lti is None else \
            BYTES_PER_KEPT_LTI + 8 * (base.lti.A.size + base.lti.B.size + base.lti.K.size - 3)
    check_memory(count, len(axes), held, kept)
    return count, seconds


#: engines of ``run_sweep``: ``batch`` advances all points together (vectorized);
#: ``inprocess`` and ``fmu`` run point by point (``delaycomp.orchestrator.simulate.ENGINES``)
SWEEP_ENGINES = ("batch", "inprocess", "fmu")


@dataclass(frozen=True)
class SweepOptions:
    """How a sweep runs (``run_sweep``, ``iter_sweep``, ``check_sweep_size``); each is
    checked, in one line naming it, before anything runs.

    Examples
    --------
    >>> SweepOptions(stop=10.0, engine="batch", workers=2).engine
    'batch'
    """

    #: each point's stop time [s] (``None``: the source's default)
    stop: float | None = None
    #: ``SWEEP_ENGINES``: ``batch`` advances the points together on ``array_backend``,
    #: ``inprocess`` and ``fmu`` run them point by point
    engine: str = "fmu"
    #: local worker processes (the points, or the batch engine's chunks, shared out)
    workers: int = 1
    #: a Dask scheduler's address: the points run on its cluster (``workers`` unused)
    scheduler: str | None = None
    #: a folder of FMUs the ``fmu`` engine takes first (built there where missing)
    fmu_dir: str | None = None
    #: ``rho`` from the exact lifted model of an LTI loop, no run (``stop`` unused)
    exact: bool = False
    #: the batch engine's array library: numpy, cupy, jax or auto
    #: (``delaycomp.studies.batch.get_backend``)
    array_backend: str = "numpy"
    #: the batch engine's points per chunk at most (default: from the available memory)
    chunk: int | None = None
    #: 0 hides the progress bar (shown on a terminal otherwise)
    verbosity: int = 1


#: what a sweep runs: anything ``open_source`` takes (a scenario's name, a loop file's
#: path, a ``Loop``), or a source it opened (read once: it is passed on as it is)
Source: TypeAlias = "str | Path | Loop | LoopFile | Scenario"


def run_sweep(source: Source, axes: list[Axis], sets: list[str],
              options: SweepOptions | None = None, *,
              notes: list[str] | None = None) -> list[dict]:
    """Run the grid; return one row (grid values + metrics) per point, in grid order.

    ``source`` is a scenario name, a loop file's path (``.toml``), a source opened by
    ``open_source`` (read once, by whoever opened it) or a ``Loop`` (built by the loop-file
    reader, ``api.lti`` or ``api.model``: the grid's and ``sets``' names are then its
    loop-file keys, or their short names: ``r``, ``T``, ``x0``, ``K``, a model's own
    parameters; the rows are those of the same loop given as a loop file). ``options``
    (``SweepOptions``) say how it runs; with ``engine="batch"``, what the batch engine
    did, and which points fell back to the per-point in-process engine and why, is
    appended to ``notes``.

    The rows are held together: a grid whose rows would not fit in half of the memory is
    refused before anything runs (``check_sweep_size``); ``iter_sweep`` hands them
    on as they come instead.
    """
    plan = _plan(source, axes, sets, options or SweepOptions(), held=True)
    rows: list[dict] = []
    for part in _stream(plan, notes if notes is not None else []):
        rows.extend(part)
    return rows


def iter_sweep(source: Source, axes: list[Axis], sets: list[str],
               options: SweepOptions | None = None, *,
               notes: list[str] | None = None) -> Iterator[dict]:
    """``run_sweep``'s rows, one at a time, in grid order, in memory bounded at any
    grid size: the points are resolved, run and handed on a stream chunk
    (``STREAM_POINTS``) at a time.

    Every point is validated before this returns (a refusal raises here, before anything
    runs); the points run as the rows are taken. ``notes`` are appended once the last row
    is taken.

    Examples
    --------
    >>> from delaycomp.studies.axes import parse_grid
    >>> rows = iter_sweep("example-3.6", [parse_grid("k=1.5:2:2")], ["r=0"],
    ...                   SweepOptions(stop=10.0, engine="batch"))
    >>> [(row["k"], row["stable"]) for row in rows]
    [(1.5, 1), (2.0, 1)]
    """
    plan = _plan(source, axes, sets, options or SweepOptions(), held=False)
    return itertools.chain.from_iterable(
        _stream(plan, notes if notes is not None else []))


@dataclass
class _SweepPlan:
    """A checked, validated sweep: what its run needs (``_plan``)."""

    sc: object  # the opened source
    axes: list[Axis]
    sets: list[str]
    stop: float
    job: Job  # every point's job, less the point's own assignments
    batched: bool
    backend: str  # the batch engine's array library (its name)
    workers: int
    scheduler: str | None
    chunk: int | None
    verbosity: int
    piece: int  # points resolved together
    stream: int  # points run together: a multiple of ``piece``
    kept: dict[int, _Piece] = dataclasses.field(default_factory=dict)  # by piece number

    @property
    def names(self) -> list[str]:
        """The grid parameters' names."""
        return [a.name for a in self.axes]


def _plan(source: Source, axes: list[Axis], sets: list[str], opts: SweepOptions,
          held: bool) -> _SweepPlan:
    """The sweep's arguments checked, and every point validated (a piece at a time), before
    anything runs; the validated points of the first pieces kept (``KEEP_BYTES``). The
    source is opened here, once (an opened one passes as it is), and handed down."""
    sc = open_source(source)
    stop = _checked(sc, axes, sets, opts, held)
    batched = opts.engine == "batch" and not opts.exact
    # a stream chunk holds whole pieces and whole chunks of --chunk points, so that its
    # chunks are cut as from the whole grid (a larger --chunk makes pieces that large)
    chunk = opts.chunk
    # the streaming sizes read through sweep_size, as its estimate reads them: one
    # assignment there changes both
    piece = (chunk * max(1, sweep_size.PIECE_POINTS // chunk) if chunk
             else sweep_size.PIECE_POINTS)
    plan = _SweepPlan(sc, list(axes), list(sets), float(stop),
                      Job(_job_source(sc), tuple(sets), float(stop),
                          "inprocess" if batched else opts.engine, opts.fmu_dir, opts.exact),
                      batched, opts.array_backend, opts.workers, opts.scheduler, chunk,
                      opts.verbosity, piece, piece * max(1, sweep_size.STREAM_POINTS // piece))
    _validate(plan)
    if batched:
        from delaycomp.studies import batch
        try:
            plan.backend = batch.get_backend(opts.array_backend).name
        except batch.BatchError as exc:
            raise ParameterError(f"--array-backend: {exc}") from None
    return plan


def _job_source(sc) -> str | LoopFile:
    """What a job carries of the opened source ``sc``: a scenario's name; a loop file
    as read (its data and its path made absolute, for its relative paths in a worker
    process whose working directory differs); a loop's data as they are."""
    if isinstance(sc, LoopData):
        return sc
    if isinstance(sc, LoopFile):
        if sc.path.is_absolute():
            return sc
        held = copy.copy(sc)
        held.path = sc.path.resolve()
        return held
    return sc.name


def _checked(sc, axes: list[Axis], sets: list[str], opts: SweepOptions,
             held: bool = True) -> float:
    """The sweep's arguments checked (in one line each, before anything runs), on the
    opened source ``sc``: its stop time (the source's default where ``stop`` is
    ``None``)."""
    names = [a.name for a in axes]
    check_sweep_size(sc, axes, sets, opts, held)
    if opts.exact:
        refuse_channel(sc.loop(list(sets)), "`sweep --exact` (its lifted model has constant "
                       "delays; run the points: --engine inprocess or fmu)")
    if opts.exact and sc.loop(list(sets)).lti is None:
        raise ParameterError(f"--exact needs an LTI scenario or loop file; {_label(sc)} is "
                             "not")
    if opts.workers < 1:
        raise ParameterError(f"--workers {opts.workers} is not allowed: must be a positive "
                             "integer")
    if len(set(names)) != len(names):
        raise ParameterError("--grid: each parameter may be swept once")
    if opts.engine not in SWEEP_ENGINES:
        raise ParameterError(f"--engine {opts.engine!r} is not allowed: must be one of "
                             f"{', '.join(SWEEP_ENGINES)}")
    if opts.chunk is not None and opts.chunk < 1:
        raise ParameterError(f"--chunk {opts.chunk} is not allowed: must be a positive integer")
    stop = sc.default_stop_time if opts.stop is None else opts.stop
    if stop is None:
        raise ParameterError(f"{_label(sc)} has no stop time: give --stop-time")
    return stop


def _label(sc) -> str:
    """How a message names an opened source: a scenario's name, a loop file's name, a
    loop's ``loop 'NAME'``."""
    return getattr(sc, "where", None) or sc.name


def _pieces(axes: list[Axis], size: int, values: bool = False) -> Iterator[tuple]:
    """The grid in pieces of ``size`` points, in grid order: each point's assignments
    (``NAME=VALUE`` texts) and, with ``values``, its values."""
    texts = itertools.product(*([f"{a.name}={format_value(v)}" for v in a.values]
                                for a in axes))
    nums = itertools.product(*(a.values for a in axes)) if values else None
    while True:
        part = list(itertools.islice(texts, size))
        if not part:
            return
        yield (part, list(itertools.islice(nums, size))) if nums is not None else (part,)


def _validate(plan: _SweepPlan) -> None:
    """Every point validated, a piece at a time, before any runs (a refusal names the
    point); for a batch sweep, the validated points of the first pieces kept in
    ``plan.kept`` as the batch engine takes them while they take at most
    ``KEEP_BYTES`` (a grid of one piece: all of it)."""
    seen: set = set()
    kept_bytes = 0
    for k, (texts,) in enumerate(_pieces(plan.axes, plan.piece)):
        with _gc_paused():
            loops = _grid_loops(plan.sc, plan.sets, texts, plan.batched,
                                timings=not plan.batched)
        if not plan.job.exact:  # --exact takes rho from the lifted model: no stop time
            _check_stop(loops, texts, plan.stop, seen)
        if plan.batched and (k == 0 or kept_bytes < sweep_size.KEEP_BYTES):
            piece = _Piece.of(loops)
            if k == 0 or kept_bytes + piece.nbytes() <= sweep_size.KEEP_BYTES:
                plan.kept[k] = piece
            kept_bytes += piece.nbytes()
            del piece
        del loops  # before the next piece is resolved


@dataclass
class _Piece:
    """A piece's validated points as the batch engine takes them: in groups that share a
    batch (``delaycomp.studies.sweep_batch.groups``: indices in the piece, points
    stacked), each model group's model, and the points it cannot take, each with its
    reason and its per-point engine: ``fmu`` where the loop holds an FMU file (the
    in-process engine runs delaycomp's own slaves only) or has native FMUs here (the
    native core steps them: ``native_point``), else in-process."""

    groups: dict
    models: dict
    fallback: list[tuple[int, str, str]]

    @classmethod
    def of(cls, loops) -> _Piece:
        """The piece of validated points ``loops`` (``_grid_loops``)."""
        from delaycomp.studies import sweep_batch

        found, others, models = sweep_batch.groups(loops)
        fallback = []
        for i, why in others:
            files = any(isinstance(inst.source, FmuFile) for inst in loops[i].instances)
            fallback.append((i, why, "fmu" if files or native_point(loops[i])
                             else "inprocess"))
        return cls(found, models, fallback)

    def nbytes(self) -> int:
        """Bytes it holds: its arrays, and an index (a Python int and its list slot) and
        a pointer per point."""
        arrays = sum(getattr(points, f.name).nbytes for _, points in self.groups.values()
                     for f in dataclasses.fields(points))
        return arrays + 48 * sum(len(idx) for idx, _ in self.groups.values())


def _grid_loops(sc, sets: list[str], grid_texts: list[tuple[str, ...]], batched: bool,
                timings: bool = False):
    """Every grid point validated before any runs: all at once where the source can
    (``Scenario.resolve_grid``), else (or to name a refused point) one by one. Returns
    the points' loops (with ``timings``, only their ``delaycomp.system.Timing``); for a
    batch sweep of an LTI source, their designs instead (what the batch engine reads): one
    ``delaycomp.system.LtiBatch`` where the source validates them all at once
    (``Scenario.designs``, ``LoopFile.designs``), else one
    ``delaycomp.system.LtiPoint`` (or, where a point has none, its loop) each."""
    params = (sc.resolve_grid(list(sets), grid_texts) if hasattr(sc, "resolve_grid")
              else None)
    if params is None:
        params = [_named(texts, sc.resolve, [*sets, *texts]) for texts in grid_texts]
    # a batch sweep of an LTI source needs each point's design, not its loop's
    # instances: Scenario.designs (all points at once), else Scenario.design /
    # LoopFile.design (one by one) validate it with the same checks as make
    if batched and hasattr(sc, "designs"):
        try:
            designs = sc.designs(params)
        except ParameterError:  # one by one below, which names the point
            designs = None
        if designs is not None:
            return designs
    design = getattr(sc, "design", None) if batched else None
    loops = []
    for p, point_texts in zip(params, grid_texts):
        item = _named(point_texts, design, p) if design is not None else None
        item = item if item is not None else _named(point_texts, sc.make, p)
        loops.append(item.timing if timings else item)
    return loops


def _check_stop(loops, grid_texts: list[tuple[str, ...]], stop: float,
                seen: set | None = None) -> None:
    """Refuse a stop time that is not a whole number of some point's base step, naming the
    first such point (before anything runs, for every engine); ``seen`` holds the timings
    already checked (of earlier pieces)."""
    if not (math.isfinite(stop) and stop > 0):
        raise ParameterError(f"--stop-time {stop!r} is not allowed: must be a finite number > 0")
    if isinstance(loops, LtiBatch):
        pairs = list(zip(loops.T.tolist(), loops.N.tolist()))
    else:
        pairs = [(t.T, t.N) for t in (x if isinstance(x, Timing) else x.timing
                                      for x in loops)]
    seen = set() if seen is None else seen
    for i, (T, N) in enumerate(pairs):
        if (T, N) not in seen:
            seen.add((T, N))
            _named(grid_texts[i], Timing(T, N).ticks, stop)


@contextlib.contextmanager
def _gc_paused():
    """Python's cyclic garbage collector paused while a grid's points are built: millions
    of small dicts and no cycles, where each collection would walk every live object
    (measured: a fifth of a 250 000-point sweep). Reference counting still frees
    everything; the collector runs again afterwards, as it was."""
    was = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was:
            gc.enable()


def _named(point_texts: tuple[str, ...], fn, arg):
    """``fn(arg)``, with a refusal named after the grid point."""
    try:
        return fn(arg)
    except ParameterError as exc:
        raise ParameterError(f"grid point {', '.join(point_texts)}: {exc}") from None


def _stream(plan: _SweepPlan, notes: list[str]) -> Iterator[list[dict]]:
    """The rows of the validated sweep ``plan``, a stream chunk at a time; the notes of the
    batch engine appended after the last."""
    names = plan.names
    progress = Progress(math.prod(len(a.values) for a in plan.axes), plan.verbosity)
    tally = _BatchNotes()
    for k, (texts, values) in enumerate(_pieces(plan.axes, plan.stream, values=True)):
        if plan.batched:
            results = _run_batch(plan, k * (plan.stream // plan.piece), texts, tally,
                                 progress)
        else:
            jobs = [_job(plan.job, t) for t in texts]
            if not plan.job.exact and plan.job.engine == "fmu":
                _prebuild(jobs)
            results = _run_jobs(jobs, plan.workers, plan.scheduler, progress)
        with _gc_paused():
            rows = []
            for j, point in enumerate(values):
                row = dict(zip(names, point))
                row.update(results[j])
                results[j] = {}  # freed as its row is made
                rows.append(row)
        yield rows
    if plan.batched:
        notes.extend(tally.notes())


def _job(job: Job, point_texts: tuple[str, ...]) -> Job:
    """The job of one grid point: ``job`` with the point's assignments."""
    return dataclasses.replace(job, sets=(*job.sets, *point_texts))


@dataclass
class _BatchNotes:
    """What the batch engine did over a sweep's stream chunks, for its notes."""

    backend: str = ""
    total: int = 0
    done: int = 0
    chunks: int = 0
    others: list[str] = dataclasses.field(default_factory=list)  # prepare's, in order
    fallback: dict[str, tuple[int, set]] = dataclasses.field(default_factory=dict)

    def notes(self) -> list[str]:
        """The notes: prepare's, the batch engine's, then one per per-point engine."""
        out = [*self.others,
               f"batch engine ({self.backend}): {self.done} of {self.total} points in "
               f"{self.chunks} chunk{'s' if self.chunks != 1 else ''}"]
        for name, (count, reasons) in self.fallback.items():
            out.append(f"per-point engine ({name}): {count} points, because "
                       + "; ".join(sorted(reasons)))
        return out


def _run_batch(plan: _SweepPlan, first: int, texts: list[tuple[str, ...]], tally: _BatchNotes,
               progress: Progress) -> list[dict]:
    """One stream chunk (the points ``texts``, from piece number ``first`` on) on the batch
    engine, the points it cannot take on the per-point engine; their metrics in order."""
    from delaycomp.studies import batch, sweep_batch

    be = batch.get_backend(plan.backend)
    tally.backend = f"{be.name}, {be.device}"
    chunks, fallback = _prepared(plan, first, texts, be.name, tally)
    results: list[dict] = [{}] * len(texts)
    try:
        for (idx, _), rows in zip(chunks, sweep_batch.run_chunks(
                chunks, plan.workers, plan.scheduler, progress)):
            for i, row in zip(idx, rows):
                results[i] = row
    except batch.BatchError as exc:
        raise ParameterError(str(exc)) from None
    tally.total += len(texts)
    tally.done += sum(len(idx) for idx, _ in chunks)
    tally.chunks += len(chunks)
    for name, items in fallback.items():
        count, reasons = tally.fallback.get(name, (0, set()))
        tally.fallback[name] = (count + len(items), reasons | {why for _, why in items})
        jobs = [dataclasses.replace(_job(plan.job, texts[i]), engine=name) for i, _ in items]
        if name == "fmu":
            _prebuild(jobs)
        for (i, _), row in zip(items, _run_jobs(jobs, plan.workers, plan.scheduler,
                                                progress)):
            results[i] = row
    return results


def _prepared(plan: _SweepPlan, first: int, texts: list[tuple[str, ...]], backend: str,
              tally: _BatchNotes) -> tuple[list, dict[str, list[tuple[int, str]]]]:
    """The batch chunks of one stream chunk (each with the indices it covers in it) and
    its points for the per-point engine (by engine: ``(index, reason)``). Each piece is
    grouped as it is resolved (its loops are not held); the groups of all pieces are
    joined, so that the chunks are cut as from the whole stream chunk."""
    from delaycomp.studies import sweep_batch

    merged: dict[tuple, tuple[list[int], list]] = {}
    models: dict = {}
    fallback: dict[str, list[tuple[int, str]]] = {}
    for s in range(0, len(texts), plan.piece):
        piece = plan.kept.pop(first + s // plan.piece, None)
        if piece is None:  # not kept from the validation pass: resolved again
            with _gc_paused():
                piece = _Piece.of(_grid_loops(plan.sc, plan.sets, texts[s:s + plan.piece],
                                              True))
        for key, (idx, points) in piece.groups.items():
            into = merged.setdefault(key, ([], []))
            into[0].extend(s + i for i in idx)
            into[1].append(points)
        models.update(piece.models)
        for i, why, engine in piece.fallback:
            fallback.setdefault(engine, []).append((s + i, why))
        del piece
    found = {}
    while merged:  # each group's parts freed as it is joined
        key, (idx, parts) = next(iter(merged.items()))
        del merged[key]
        found[key] = (idx, sweep_batch.join(parts))
    chunks, msgs = sweep_batch.cut(found, models, plan.stop, backend, plan.workers,
                                   plan.chunk)
    tally.others.extend(m for m in msgs if m not in tally.others)
    return chunks, fallback


def _run_jobs(jobs: list[Job], workers: int, scheduler: str | None,
              progress: Progress | None = None) -> list[dict]:
    """Per-point jobs, one after another, on worker processes or on Dask."""
    progress = progress or Progress(len(jobs))
    if scheduler:
        results = on_dask(evaluate, jobs, scheduler, progress)
    elif workers > 1:
        results = on_processes(evaluate, jobs, workers, progress,
                               chunksize=max(1, len(jobs) // (workers * 8)))
    else:
        from delaycomp.orchestrator.simulate import single_threaded_blas

        results = []
        with single_threaded_blas():  # once for the whole sweep, not per point
            for job in jobs:
                results.append(evaluate(job))
                progress.tick()
    return results

