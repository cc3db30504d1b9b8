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
  (:func:`delaycomp.maths.lti.lifted_loop`);
- ``stable``: 1 if ``rho < 1``, else 0;
- ``final_norm``, ``peak_norm``: ``|x|`` at the end (of what was recorded) and its largest
  value;
- ``deadbeat_time``: the time from which ``|x| < 1e-9`` holds to the end (empty if never);
- ``failed``: empty where the run reached its stop time, else why it did not (the failing
  component, the time and its reason; the wording depends on the engine). A run that
  ends because the loop itself diverged (one of delaycomp's own components found its
  state, prediction or control overflowing: :func:`delaycomp.errors.is_divergence`) is
  unstable: ``rho = inf``, ``stable = 0``. Any other failure (a plant FMU file whose
  output turned NaN or infinite, a refused call, an exception in a model) says nothing
  about stability: ``rho`` and ``stable`` are empty (``None``), never "unstable".

Points run one after another, on local worker processes, or on a Dask cluster; every
point is computed by the same deterministic function, so the results do not depend on how
they are distributed. With ``engine="batch"`` the points are advanced together, vectorized
(:mod:`delaycomp.studies.batch`, :mod:`delaycomp.studies.sweep_batch`), in chunks spread
the same way; points it cannot take run on the per-point in-process engine, and ``notes``
says which.
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import gc
import itertools
import math
from dataclasses import dataclass
from pathlib import Path
from typing import cast

import numpy as np

from delaycomp.errors import ParameterError, is_divergence
from delaycomp.paper.scenarios import open_source
from delaycomp.studies.axes import Axis, base_loop, format_value, points
from delaycomp.studies.pool import Progress, on_dask, on_processes
from delaycomp.system import FmuFile, LtiBatch, Timing

#: ``|x|`` below this counts as zero for the dead-beat time (the issues' definition).
ZERO = 1e-9
METRICS = ("rho", "stable", "final_norm", "peak_norm", "deadbeat_time", "failed")


@dataclass(frozen=True)
class Job:
    """Everything one grid point needs; picklable for worker processes and Dask."""

    #: a scenario name or a loop file's path
    scenario: str
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
    tail = env[max(1, periods // 5):]
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
    """The sweep's metrics of a run of ``loop`` (a :class:`delaycomp.system.Loop`): its
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

        d = spec.lti
        lifted = lifted_loop(d.A, d.B, d.K, spec.T, d.r, d.tau, d.mode, d.r_true, d.tau_true)
        rho = lifted.spectral_radius
        return {"rho": rho, "stable": int(rho < 1.0), "final_norm": None, "peak_norm": None,
                "deadbeat_time": None, "failed": ""}
    kwargs = {} if job.engine == "fmu" else {"engine": job.engine}
    return result_metrics(spec, run_loop(spec, job.stop, job.fmu_dir, **kwargs))


def _prebuild(jobs: list[Job]) -> None:
    """Build every FMU the jobs need here, once, before workers start."""
    from delaycomp.fmu.cache import fmu_path

    seen = set()
    for job in jobs:
        for inst in open_source(job.scenario).loop(list(job.sets)).instances:
            key = inst.source.build_key()
            if key is None:
                continue
            kind, config = key
            ident = (kind, tuple(sorted(config.items())))
            if ident not in seen:
                seen.add(ident)
                fmu_path(kind, config, Path(job.fmu_dir) if job.fmu_dir else None)


#: Lower bound of the cost of one point of ``--exact`` (a lifted-model eigenvalue
#: problem), in seconds.
SECONDS_PER_EXACT_POINT = 50e-6
#: Bytes of one result row in memory (a dict of about ten floats).
BYTES_PER_ROW = 1000


def check_sweep_size(scenario: str, axes: list[Axis], sets: list[str],
                     stop: float | None = None, engine: str = "inprocess", workers: int = 1,
                     exact: bool = False) -> tuple[int, float]:
    """Refuse, in one line with the estimate, a grid that cannot finish or fit in memory.

    Returns the number of points and the estimated seconds (a lower bound).
    """
    from delaycomp.formats.outputs import (
        MAX_RUN_SECONDS,
        SECONDS_PER_TICK,
        format_bytes,
        format_duration,
        physical_memory,
    )

    count = math.prod(len(a.values) for a in axes)
    per_point = SECONDS_PER_EXACT_POINT
    base = None if exact else base_loop(scenario, sets)
    if base is not None:
        T, N = base.T, base.N
        for a in axes:  # the most expensive point when T or N is swept
            if a.name == "T" and min(a.values) > 0:
                T = min(a.values)
            if a.name == "N" and max(a.values) >= 1:
                N = max(a.values)
        source = open_source(scenario)
        stop_time = stop if stop is not None else (source.default_stop_time or base.stop_time)
        if stop_time:
            per_point = (stop_time / T) * N * SECONDS_PER_TICK.get(engine, 10e-6)
    if engine == "batch" and not exact:
        per_point = 0.0  # vectorized over the points: no per-point bound known; memory only
    seconds = count * per_point / max(1, workers)
    if seconds > MAX_RUN_SECONDS:
        raise ParameterError(
            f"--grid: {count:.4g} points at least {per_point * 1e3:.3g} ms each on "
            f"{max(1, workers)} workers take at least {format_duration(seconds)}, over the limit "
            f"of {format_duration(MAX_RUN_SECONDS)}; use fewer points or a shorter --stop-time")
    ram = physical_memory()
    if ram is not None and count * BYTES_PER_ROW > ram / 2:
        raise ParameterError(
            f"--grid: {count:.4g} points need at least {format_bytes(count * BYTES_PER_ROW)} for "
            f"their results, over half of this machine's {format_bytes(ram)}; use fewer points")
    return count, seconds


#: engines of :func:`run_sweep`: ``batch`` advances all points together (vectorized);
#: ``inprocess`` and ``fmu`` run point by point (:data:`delaycomp.orchestrator.simulate.ENGINES`)
SWEEP_ENGINES = ("batch", "inprocess", "fmu")


def run_sweep(scenario: str, axes: list[Axis], sets: list[str], stop: float | None = None,
              engine: str = "fmu", workers: int = 1, scheduler: str | None = None,
              fmu_dir: str | None = None, exact: bool = False,
              array_backend: str = "numpy", chunk: int | None = None,
              notes: list[str] | None = None, verbosity: int = 1) -> list[dict]:
    """Run the grid; return one row (grid values + metrics) per point, in grid order.

    ``scenario`` is a scenario name or a loop file's path (``.toml``). ``engine="batch"``
    advances the points together on ``array_backend`` (numpy, cupy, jax or auto;
    :func:`delaycomp.studies.batch.get_backend`) in chunks of at most ``chunk`` points (default:
    from the available memory); what it did, and which points fell back to the per-point
    in-process engine and why, is appended to ``notes``. ``verbosity`` 0 hides the progress
    bar (shown on a terminal otherwise).
    """
    names = [a.name for a in axes]
    sc, stop = _checked(scenario, axes, names, sets, stop, engine, workers, scheduler,
                        exact, chunk)
    source = (str(Path(scenario).resolve()) if str(scenario).endswith(".toml")
              else scenario)
    job_engine = "inprocess" if engine == "batch" else engine
    texts = [[f"{a.name}={format_value(v)}" for v in a.values] for a in axes]
    grid_texts = list(itertools.product(*texts))

    def job(i: int) -> Job:
        return Job(source, (*sets, *grid_texts[i]), float(stop), job_engine, fmu_dir, exact)

    batched = engine == "batch" and not exact
    with _gc_paused():
        loops = _grid_loops(sc, sets, grid_texts, batched)
        rows = [dict(zip(names, values)) for values in points(axes)]
    if not exact:  # --exact takes rho from the lifted model: no run, no stop time
        _check_stop(loops, grid_texts, float(stop))
    if batched:
        results = _run_batch(job, loops, float(stop), workers, scheduler, array_backend,
                             chunk, notes if notes is not None else [], verbosity)
    else:
        jobs = [job(i) for i in range(len(grid_texts))]
        if not exact and engine == "fmu":
            _prebuild(jobs)
        results = _run_jobs(jobs, workers, scheduler, Progress(len(jobs), verbosity))
    with _gc_paused():
        for row, res in zip(rows, results):
            row.update(res)
    return rows


def _checked(scenario: str, axes: list[Axis], names: list[str], sets: list[str],
             stop: float | None, engine: str, workers: int, scheduler: str | None,
             exact: bool, chunk: int | None):
    """The sweep's arguments checked (in one line each, before anything runs): the opened
    source and the stop time (the source's default where ``stop`` is ``None``)."""
    check_sweep_size(scenario, axes, sets, stop, engine, workers if not scheduler else 1,
                     exact)
    sc = open_source(scenario)
    if exact and sc.loop(list(sets)).lti is None:
        raise ParameterError(f"--exact needs an LTI scenario or loop file; {scenario} is not")
    if workers < 1:
        raise ParameterError(f"--workers {workers} is not allowed: must be a positive integer")
    if len(set(names)) != len(names):
        raise ParameterError("--grid: each parameter may be swept once")
    if engine not in SWEEP_ENGINES:
        raise ParameterError(f"--engine {engine!r} is not allowed: must be one of "
                             f"{', '.join(SWEEP_ENGINES)}")
    if chunk is not None and chunk < 1:
        raise ParameterError(f"--chunk {chunk} is not allowed: must be a positive integer")
    stop = sc.default_stop_time if stop is None else stop
    if stop is None:
        raise ParameterError(f"{scenario} has no stop time: give --stop-time")
    return sc, stop


def _grid_loops(sc, sets: list[str], grid_texts: list[tuple[str, ...]], batched: bool):
    """Every grid point validated before any runs: all at once where the source can
    (``Scenario.resolve_grid``), else (or to name a refused point) one by one. Returns
    the points' loops; for a batch sweep of an LTI source, their designs instead (what
    the batch engine reads): one :class:`delaycomp.system.LtiBatch` where the source
    validates them all at once (``Scenario.designs``, ``LoopFile.designs``), else one
    :class:`delaycomp.system.LtiPoint` (or, where a point has none, its loop) each."""
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
        loops.append(item if item is not None else _named(point_texts, sc.make, p))
    return loops


def _check_stop(loops, grid_texts: list[tuple[str, ...]], stop: float) -> None:
    """Refuse a stop time that is not a whole number of some point's base step, naming the
    first such point (before anything runs, for every engine)."""
    if not (math.isfinite(stop) and stop > 0):
        raise ParameterError(f"--stop-time {stop!r} is not allowed: must be a finite number > 0")
    if isinstance(loops, LtiBatch):
        pairs = list(zip(loops.T.tolist(), loops.N.tolist()))
    else:
        pairs = [(loop.timing.T, loop.timing.N) for loop in loops]
    seen = set()
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


def _run_batch(job, loops, stop: float, workers: int, scheduler: str | None,
               backend: str, chunk: int | None, notes: list[str],
               verbosity: int = 1) -> list[dict]:
    """The batch engine for the points it takes, the per-point engine for the others
    (``job(i)`` is point ``i``'s :class:`Job`)."""
    from delaycomp.studies import batch, sweep_batch
    try:
        be = batch.get_backend(backend)
    except batch.BatchError as exc:
        raise ParameterError(f"--array-backend: {exc}") from None
    chunks, fallback, msgs = sweep_batch.prepare(loops, stop, be.name, workers, chunk)
    notes.extend(msgs)
    total = len(loops)
    progress = Progress(total, verbosity)
    results: list[dict | None] = [None] * total
    try:
        for (idx, _), rows in zip(chunks, sweep_batch.run_chunks(chunks, workers, scheduler,
                                                                 progress)):
            for i, row in zip(idx, rows):
                results[i] = row
    except batch.BatchError as exc:
        raise ParameterError(str(exc)) from None
    done = sum(len(idx) for idx, _ in chunks)
    notes.append(f"batch engine ({be.name}, {be.device}): {done} of {total} points in "
                 f"{len(chunks)} chunk{'s' if len(chunks) != 1 else ''}")
    # the others point by point: in-process, or as FMUs where the loop holds an FMU file
    # (the in-process engine runs delaycomp's own slaves only)
    by_engine: dict[str, list[tuple[int, str]]] = {}
    for i, why in fallback:
        files = any(isinstance(inst.source, FmuFile) for inst in loops[i].instances)
        by_engine.setdefault("fmu" if files else "inprocess", []).append((i, why))
    for name, items in by_engine.items():
        reasons = sorted({why for _, why in items})
        notes.append(f"per-point engine ({name}): {len(items)} points, because "
                     + "; ".join(reasons))
        jobs = [dataclasses.replace(job(i), engine=name) for i, _ in items]
        if name == "fmu":
            _prebuild(jobs)
        for (i, _), row in zip(items, _run_jobs(jobs, workers, scheduler, progress)):
            results[i] = row
    # every point is filled: by its chunk, or by the per-point engine (the fallback)
    return cast("list[dict]", results)


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


def write_csv(rows: list[dict], names: list[str], path: str | Path) -> None:
    """Write the sweep's rows to ``path`` as CSV: the grid columns ``names``, then
    :data:`METRICS` (written to a ``.part`` file first, then moved into place; removed if
    the writing is interrupted or fails)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".part")
    try:
        with open(tmp, "w", newline="", encoding="utf-8") as fh:
            w = csv.writer(fh)
            w.writerow([*names, *METRICS])
            for row in rows:  # grid values as written (15 digits), metrics to the bit
                w.writerow([*(format_value(row[k]) for k in names),
                            *(_cell(row[k]) for k in METRICS)])
        tmp.replace(path)
    except BaseException:  # Ctrl-C, SIGTERM, a full disk: no half-written file is left
        tmp.unlink(missing_ok=True)
        raise


def _cell(value) -> str:
    if value is None:
        return ""
    if isinstance(value, str):
        return value
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    return repr(float(value))


def plot_sweep(rows: list[dict], axes: list[Axis], path: str | Path, title: str,
               critical: np.ndarray | None = None) -> None:
    """A curve of ``rho`` for one grid parameter, a heat map of it for two.

    ``critical``: rows ``(a, r)`` where the exact lifted model has ``rho = 1``
    (:func:`delaycomp.studies.critical.critical_curve`), drawn over the map and labelled.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rho = np.array([r["rho"] for r in rows], dtype=float)
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
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.stem + ".part" + path.suffix)
    fig.savefig(tmp, dpi=110)
    plt.close(fig)
    tmp.replace(path)


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
