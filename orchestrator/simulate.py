"""Run a ``Loop`` with the project's FMUs and master.

``make_master`` is the one function that wires a master from a loop; everything that
runs a loop (``run``, sweeps, the cross-check, the benchmark) goes through it.
"""

from __future__ import annotations

import contextlib
import csv
from dataclasses import dataclass, field
from pathlib import Path
from typing import cast

import numpy as np

from delaycomp.errors import Interrupted, ParameterError
from delaycomp.fmu.cache import source_fmu
from delaycomp.orchestrator.fmu import FmuComponent
from delaycomp.orchestrator.master import Master, Recorder, SimulationError
from delaycomp.orchestrator.native_core import STEPPING
from delaycomp.system import FmuFile, Loop, Timing

__all__ = ["ENGINES", "STEPPING", "Result", "SimulationError", "check_stepping",
           "make_components", "make_master", "parameters_of", "run_loop"]


@dataclass
class Result:
    """Recorded signals: ``data[k, j]`` is signal ``names[j]`` at ``times[k]``."""

    names: list[str]
    times: np.ndarray
    data: np.ndarray
    success: bool = True
    message: str = ""
    #: informational messages the components logged, as ``instance: text``
    notes: list[str] = field(default_factory=list)
    #: rows recorded (streamed to a sink, or kept here); ``None``: ``len(times)``
    rows: int | None = None
    #: the instance that failed the run (``None`` where it completed or no one is to blame)
    failed_by: str | None = None
    #: the components' logged messages of ``notes``, each ``(instance, status,
    #: text)`` with status ``"ok"`` (information: the command line shows it with ``-v``)
    #: or ``"warning"`` (always shown)
    logged: list[tuple[str, str, str]] = field(default_factory=list)
    #: what stepped the run: ``"native-core"`` (``delaycomp.orchestrator.native_core``),
    #: ``"python"`` (the Python master), or ``""`` (another tool's master)
    stepped_by: str = ""
    #: why the Python master stepped a run of the FMU engine that the native core did not
    #: (``""``: it was asked for, or the core stepped it)
    stepping_note: str = ""
    #: the run's recipe, where the native core stepped it and no FMU said anything
    #: (``delaycomp.orchestrator.replay.recipe_of``: a later run can replay it), else None
    recipe: dict | None = None

    @property
    def row_count(self) -> int:
        """Rows recorded in the run (more than ``times`` holds if the run streamed)."""
        return len(self.times) if self.rows is None else self.rows

    def checked_finite(self, who: str) -> Result:
        """This result, or where a recorded value is NaN or infinite, a failed one that
        keeps the rows before it and names the signal and the time (a master we drive
        that ran on through a plant's breakdown: ``who`` names it).

        Examples
        --------
        >>> res = Result(["plant.x"], np.array([0.0, 1.0]), np.array([[1.0], [np.nan]]))
        >>> bad = res.checked_finite("ecos")
        >>> bad.success, bad.message, len(bad.times)
        (False, 'ecos: plant.x = nan at t = 1 is not allowed: must be finite', 1)
        """
        if not self.success or self.data.size == 0 or np.all(np.isfinite(self.data)):
            return self
        k, j = (int(i[0]) for i in np.nonzero(~np.isfinite(self.data)))
        message = (f"{who}: {self.names[j]} = {float(self.data[k, j])!r} at "
                   f"t = {float(self.times[k]):.12g} is not allowed: must be finite")
        return Result(self.names, self.times[:k], self.data[:k], False, message,
                      list(self.notes), failed_by=self.names[j].split(".", 1)[0])

    def column(self, name: str) -> np.ndarray:
        """The signal ``name`` as an array over ``times`` (a view of ``data``)."""
        return self.data[:, self.names.index(name)]

    def __getitem__(self, name: str) -> np.ndarray:
        """The signal ``name`` (``"plant.x1"``, ``"controller.u"``) as an array."""
        if name not in self.names:
            raise KeyError(f"no signal {name!r}: the run recorded {', '.join(self.names)}")
        return self.column(name)

    @property
    def signals(self) -> dict[str, np.ndarray]:
        """Every recorded signal by name, one array each (``times`` is the time axis)."""
        return {name: self.data[:, j] for j, name in enumerate(self.names)}

    def to_pandas(self):
        """A ``pandas.DataFrame`` indexed by time, one column per signal (needs pandas)."""
        try:
            import pandas as pd
        except ImportError:
            raise ImportError("to_pandas() needs pandas: pip install pandas") from None
        return pd.DataFrame(self.data, index=pd.Index(self.times, name="time"),
                            columns=list(self.names))

    def write_csv(self, path: str | Path) -> None:
        """Write a CSV file: a ``time`` column and one column per signal, every value as
        ``repr`` of its float (exact round trip); written whole or not at all."""
        from delaycomp.tmpfiles import replacing

        with replacing(path) as fh:  # no half-written file, never through a link
            w = csv.writer(fh)
            w.writerow(["time", *self.names])
            for t, row in zip(self.times, self.data):
                w.writerow([repr(float(t)), *(repr(float(v)) for v in row)])


def stop_ticks(stop_time: float, T: float, N: int) -> int:
    """Base steps to ``stop_time`` (``delaycomp.system.Timing.ticks``)."""
    return Timing(T, N).ticks(stop_time)


#: ``fmu``: the built FMUs through fmpy; ``inprocess``: the same slave classes called
#: directly (``orchestrator.inprocess``), same master, same numbers, much faster.
ENGINES = ("fmu", "inprocess")


def make_components(loop: Loop, engine: str = "fmu", fmu_dir: Path | None = None,
                    fp_guarded: bool = False, fmus: dict[str, Path] | None = None,
                    watchdog: float | None = None) -> list:
    """The master components of ``loop`` for ``engine``. ``fp_guarded`` (in-process only):
    the caller steps them under ``np.errstate(all="ignore")``. ``fmus`` (FMU engine only)
    gives the FMU file of some instances (e.g. from an SSP archive); the others come from
    ``source_fmu``. An instance whose source is an FMU file (another tool's FMU) runs
    in a child process with a watchdog of ``watchdog`` seconds per call (default
    ``default_watchdog`` of the loop's base step;
    ``delaycomp.orchestrator.isolated``); delaycomp's own FMUs run in this process."""
    if engine == "fmu":
        from delaycomp.orchestrator.isolated import IsolatedFmu, default_watchdog

        fmus = fmus or {}
        limit = default_watchdog(loop.h) if watchdog is None else watchdog
        # the tolerance only where one is given (a stand-in component that takes none
        # keeps working for the loops that give none)
        return [IsolatedFmu(i.name, fmus.get(i.name) or i.source.path, limit,
                            **({} if i.source.tolerance is None
                               else {"tolerance": i.source.tolerance}))
                if isinstance(i.source, FmuFile)
                else FmuComponent(i.name, fmus.get(i.name) or source_fmu(i.source, fmu_dir))
                for i in loop.instances]
    if fmus:
        raise ParameterError("FMU files are not allowed with the in-process engine")
    if engine == "inprocess":
        from delaycomp.orchestrator.inprocess import SlaveComponent

        files = [i.name for i in loop.instances if isinstance(i.source, FmuFile)]
        if files:
            raise ParameterError(f"instance {files[0]} is an FMU file: the in-process "
                                 "engine runs delaycomp's own slaves only (use --engine fmu)")
        # no FmuFile (refused above): every source has a build key
        return [SlaveComponent(i.name, *cast("tuple[str, dict]", i.source.build_key()),
                               fp_guarded)
                for i in loop.instances]
    raise ParameterError(f"engine {engine!r} is not allowed: must be one of "
                         f"{', '.join(ENGINES)}")


def make_master(loop: Loop, fmu_dir: Path | None = None, t0: float = 0.0,
                every: int = 1, engine: str = "fmu", fp_guarded: bool = False,
                fmus: dict[str, Path] | None = None,
                components: list | None = None, sink=None, keep: bool = True,
                final: int | None = None, watchdog: float | None = None
                ) -> tuple[Master, Recorder]:
    """The master of ``loop``: its components (fresh ones for ``engine``, or the given
    ``components``, e.g. wrapped to tap their signals), its connections, its timing, and a
    recorder of its recorded ports at every ``every``-th tick and at tick ``final``
    (``sink`` and ``keep`` as in ``Recorder``). Not yet
    set up: call ``master.setup(stop_time, loop.parameters())``. ``watchdog``: seconds per
    call of an FMU file's instance (``make_components``)."""
    if components is None:
        components = make_components(loop, engine, fmu_dir, fp_guarded, fmus, watchdog)
    try:
        master = Master(components, loop.connections, loop.T, loop.N, t0)
    except ValueError as exc:  # an algebraic loop, named by its members: a loop to fix
        for c in components:
            if hasattr(c, "terminate") and getattr(c, "fmu", None) is not None:
                c.terminate()
        raise ParameterError(f"loop {loop.name}: {exc}") from None
    recorder = Recorder(master, [(p.instance, p.variable) for p in loop.recorded], every,
                        sink, keep, final)
    recorder.names = loop.columns  # a labelled port's column (Loop.labels)
    master.add_observer(recorder)
    return master, recorder


def parameters_of(loop: Loop) -> dict[str, dict]:
    """The parameters of every instance of ``loop``, by instance name, as
    ``Master.setup`` takes them (``loop.parameters()``)."""
    return loop.parameters()


def check_stepping(stepping: str, engine: str = "fmu") -> None:
    """Refuse (``ParameterError``) a ``stepping`` that is not one of ``STEPPING``, or the
    native core asked of the in-process engine (whose slaves are Python)."""
    if stepping not in STEPPING:
        raise ParameterError(f"stepping {stepping!r} is not allowed: must be one of "
                             f"{', '.join(STEPPING)}")
    if stepping == "native-core" and engine != "fmu":
        raise ParameterError(f"stepping 'native-core' is not allowed with the {engine} "
                             "engine: the native core steps native FMUs (engine fmu)")


def run_loop(loop: Loop, stop_time: float, fmu_dir: Path | None = None,
             t0: float = 0.0, engine: str = "fmu",
             fmus: dict[str, Path] | None = None, every: int = 1, sink=None,
             keep: bool = True, progress=None, watchdog: float | None = None,
             stepping: str = "auto") -> Result:
    """Co-simulate ``loop`` from ``t0`` to ``stop_time``.

    Parameters
    ----------
    loop : Loop
        the loop.
    stop_time, t0 : float
        the interval; ``stop_time - t0`` must be a multiple of the base step.
    fmu_dir : Path, optional
        folder of built FMUs (default: the per-version cache).
    engine : str
        ``fmu`` (the FMUs through fmpy) or ``inprocess`` (the same slaves without the FMI
        layer).
    fmus : dict, optional
        the FMU file of some instances (e.g. from an SSP archive); the others come from
        ``source_fmu``.
    every : int
        record every ``every``-th base step (and the stop time); 1: every base step.
    sink : callable, optional
        ``sink(t, row)`` receives every recorded row as the run goes (a streamed CSV).
    keep : bool
        keep the recorded rows in the result; ``False`` keeps only the last one (memory
        stays flat however long the run).
    progress : callable, optional
        ``progress(ticks_done)`` called about every 1 % of the run.
    watchdog : float, optional
        seconds of wall time an FMU file's instance (another tool's FMU, run in a child
        process) may take per call before the run is stopped; default
        ``default_watchdog`` (10 s, or 100 base
        steps if longer).
    stepping : str
        ``auto``: where every FMU is a native one of this process (the default FMUs of a
        loop that has them, an archive's native FMUs), the native stepping core steps
        the loop (``delaycomp.orchestrator.native_core``: the same calls from C, the same
        rows bit for bit), else the Python master (``Result.stepping_note`` says why);
        ``native-core``: the core, or ``ParameterError`` saying why not before anything
        runs; ``python``: the Python master.

    Returns
    -------
    Result
        On a component failure the result so far, with ``success=False`` and the failure
        in ``message``.
    """
    check_stepping(stepping, engine)
    ticks = loop.timing.ticks(stop_time - t0)
    return _run(loop, ticks, stop_time, fmu_dir, t0, engine, fmus, every, sink, keep,
                progress, watchdog, stepping)


def single_threaded_blas():
    """Context in which BLAS/LAPACK run on one thread.

    The loop's matrices are tiny (n, m <= 12): a BLAS thread pool only adds hand-offs,
    and on a loaded machine those cost more than the maths (measured: a sweep point of
    Example 3.6 took 2.5 times longer with OpenBLAS's default threads on 2 busy cores).
    The previous limits are restored on exit.
    """
    from threadpoolctl import threadpool_limits

    return threadpool_limits(limits=1, user_api="blas")


def _run(spec: Loop, ticks: int, stop_time: float, fmu_dir, t0: float,
         engine: str, fmus: dict[str, Path] | None, every: int = 1, sink=None,
         keep: bool = True, progress=None, watchdog: float | None = None,
         stepping: str = "auto") -> Result:
    from delaycomp.orchestrator.native_core import NativeCore, why_not
    from delaycomp.orchestrator.replay import recipe_of

    # In-process, the slaves' floating-point guard is set once for the run, not per step
    # (the FMUs keep their own: their host's numpy settings are not ours to assume).
    guard = engine == "inprocess"
    master, recorder = make_master(spec, fmu_dir, t0, every, engine=engine,
                                   fp_guarded=guard, fmus=fmus, sink=sink, keep=keep,
                                   final=ticks, watchdog=watchdog)
    components = list(master.components.values())
    why = "" if stepping == "python" or engine != "fmu" else why_not(master) or ""
    if why and stepping == "native-core":  # asked for: refused before anything runs
        master.terminate()
        raise ParameterError(f"stepping 'native-core' is not allowed for loop {spec.name}: "
                             f"{why}")
    use_core = engine == "fmu" and stepping != "python" and not why
    success, message, culprit = True, "", None
    recipe = None
    with contextlib.ExitStack() as stack:
        interrupted = stack.enter_context(_interrupts_seen())
        # BLAS on one thread where Python maths runs in this process (the in-process
        # slaves, pythonfmu FMUs); a loop of native FMUs does not pay for threadpoolctl
        if any(getattr(c, "runs_python", True) for c in components):
            stack.enter_context(single_threaded_blas())
        try:
            master.setup(stop_time, spec.parameters())
            master.initialize()
            reads: list = []
            if t0 == 0.0:  # a run that starts where the loop's history ends
                reads = check_initial(spec, master)
            core = None
            if use_core:
                try:
                    core = NativeCore(master, recorder)
                except RuntimeError as exc:  # an FMI call logger on fmpy: Python steps
                    if stepping == "native-core":
                        raise ParameterError(f"stepping 'native-core' is not allowed for "
                                             f"loop {spec.name}: {exc}") from None
                    use_core, why = False, str(exc)
            if core is not None:
                core.run_until(ticks, progress)
                recipe = recipe_of(master, recorder, ticks, reads)
            elif guard:
                with np.errstate(all="ignore"):
                    _run_until(master, ticks, progress)
            else:
                _run_until(master, ticks, progress)
        except SimulationError as exc:
            if interrupted:  # Ctrl-C inside a component's code, which reported it as a
                # failure: it is the user's interrupt
                raise Interrupted(master.time_of(master.k)) from None
            success, message, culprit = False, str(exc), exc.instance
        except Interrupted:
            raise
        except KeyboardInterrupt:  # Ctrl-C between the components' calls: the time too
            raise Interrupted(master.time_of(master.k)) from None
        finally:
            master.terminate()
    data = np.array(recorder.rows, dtype=float).reshape(len(recorder.rows), len(spec.recorded))
    logged = [(c.name, *cast("tuple[str, str]", tuple(m[1:].split("] ", 1))))
              for c in components for m in getattr(c, "messages", ())
              if m.startswith(("[ok]", "[warning]"))]
    notes = [f"{name}: {text}" for name, _, text in logged]
    return Result(recorder.names, np.array(recorder.times), data, success, message, notes,
                  recorder.count, culprit, logged,
                  stepped_by="native-core" if use_core else "python", stepping_note=why,
                  recipe=recipe if success and not any(getattr(c, "messages", ())
                                                       for c in components) else None)


#: how far an output may be from its value in ``Loop.initial`` once initialized,
#: relative to 1 + the largest |value| (inf-norm): round-off, and the residual a tool's
#: initialization solver leaves (its tolerance, typically 1e-6 to 1e-10 relative); a wrong
#: x0 is off by the size of the state
INITIAL_RTOL = 1e-6


def check_initial(spec: Loop, master: Master) -> list[tuple[str, list[str], list[float]]]:
    """Refuse (``SimulationError``, one line naming both vectors) a loop whose outputs
    in ``Loop.initial`` (a plant FMU's measured outputs) are not the values the loop
    assumes (``x0``, the measured history) once the master has initialized it. Returns
    the reads it made, ``(instance, outputs, values)`` each (a recipe replays them)."""
    reads: list[tuple[str, list[str], list[float]]] = []
    if not spec.initial:
        return reads
    by_instance: dict[str, list[tuple[str, float]]] = {}
    for port, value in spec.initial:
        by_instance.setdefault(port.instance, []).append((port.variable, value))
    for name, pairs in by_instance.items():
        names = [v for v, _ in pairs]
        want = np.array([x for _, x in pairs])
        values = list(master.components[name].get_outputs(names))
        reads.append((name, names, values))
        got = np.array(values, dtype=float)
        tol = INITIAL_RTOL * (1.0 + float(np.max(np.abs(want))))
        if not (np.all(np.isfinite(got)) and np.all(np.abs(got - want) <= tol)):
            raise SimulationError(
                f"{name} starts elsewhere: its outputs after initialization, "
                f"({', '.join(names)}) = {np.round(got, 12).tolist()}, are not x0 = "
                f"{want.tolist()}, the measured history the loop assumes: set the FMU's "
                f"initial state (plant.start or plant.parameters) to give x0, or change "
                "x0", instance=name)
    return reads


@contextlib.contextmanager
def _interrupts_seen():
    """A list that gets an entry when SIGINT arrives while the block runs (the previous
    handler then runs as before: Python's, or the command line's, raises
    KeyboardInterrupt). A component that runs Python code (a model's ``f``, a pythonfmu
    slave) catches every exception and reports it as its own failure; with this the run
    knows that it was the user's Ctrl-C. Only in the main thread, and only over a handler
    of Python code (not where SIGINT is ignored)."""
    import signal
    import threading

    seen: list[bool] = []
    previous = (signal.getsignal(signal.SIGINT)
                if threading.current_thread() is threading.main_thread() else None)
    if not callable(previous):  # another thread, SIG_IGN, SIG_DFL, or not Python's
        yield seen
        return

    def handler(signum, frame):
        seen.append(True)
        previous(signum, frame)

    signal.signal(signal.SIGINT, handler)
    try:
        yield seen
    finally:
        signal.signal(signal.SIGINT, previous)


def _run_until(master: Master, ticks: int, progress) -> None:
    """``master.run_until(ticks)``, in about a hundred chunks when ``progress`` is given."""
    if progress is None:
        master.run_until(ticks)
        return
    chunk = max(1, ticks // 100)
    while master.k < ticks:
        master.run_until(min(ticks, master.k + chunk))
        progress(master.k)
