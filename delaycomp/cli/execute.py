"""One co-simulation from the command line (``delaycomp run``, a scenario, a loop file or
an SSP archive): the CSV streamed to ``--out``, the progress bar, the other mode of
``--compare``, the run's notes, the plot and the one-line summary."""

from __future__ import annotations

import sys
import time
from pathlib import Path

from delaycomp.errors import SimulationFailed


def compare_path(out: Path, mode: str) -> Path:
    """Where ``run --compare --out FILE.csv`` writes the run of the other controller
    ``mode``: beside ``FILE.csv``, as ``FILE.<mode>.csv``.

    Examples
    --------
    >>> compare_path(Path("out/example-3.6.csv"), "uncompensated").as_posix()
    'out/example-3.6.uncompensated.csv'
    >>> compare_path(Path("run"), "compensated").as_posix()
    'run.compensated'
    """
    return out.with_name(f"{out.stem}.{mode}{out.suffix}")


def execute(args, loop, stop: float, name: str, title: str, timing, units,
            label: str | None = None, others: dict | None = None, fmus=None,
            runner=None, other_fmus: dict | None = None, remember=None) -> int:
    """Run ``loop`` (and, for ``--compare``, the ``others``, each with its
    ``other_fmus``) to ``stop`` with the CSV streamed to ``--out`` (an other run's to
    ``compare_path``) and decimated by ``--output-interval``; then plot and report.

    ``runner(stop)`` replaces our master (a third-party master: its rows come at the end
    and are decimated afterwards). ``remember(result, shown)``: after a run that went
    well and left a recipe (``Result.recipe``), what the command showed of it besides its
    rows and summary (``delaycomp.cli.recipes``)."""
    from delaycomp.api import run
    from delaycomp.formats.outputs import CsvStream, check_budget, clear_previous, output_every
    from delaycomp.progress import bar, info

    def run_or_failed(loop, **options):
        try:
            return run(loop, stop, engine=args.engine, fmu_dir=args.fmu_dir, every=every,
                       watchdog=args.watchdog,
                       stepping=getattr(args, "stepping", "auto"), **options)
        except SimulationFailed as exc:  # reported with its rows so far below
            return exc.result

    ticks = loop.timing.ticks(stop)
    every = output_every(args.output_interval, loop.T, loop.N)
    notes = undriven_note(loop, args.verbosity)
    keep = bool(args.plot)
    seconds, memory = check_budget(loop, ticks * (1 + len(others or {})),
                                   stepped_how(args, loop, fmus, runner), every, keep)
    estimate = (f"{ticks} base steps of h = {loop.h!r} s, a row every {every}; "
                f"estimated at least {seconds:.3g} s and {memory / 1e6:.3g} MB")
    info(f"{name}: {estimate}", args.verbosity, 2)
    other_paths = {other: compare_path(args.out, other) if args.out else None
                   for other in others or {}}
    if runner is None and getattr(args, "stepping", "auto") == "native-core":
        refuse_without_core(loop, fmus, (other_fmus or {}), others or {})
    clear_previous(args.out, args.plot, *other_paths.values())
    names = loop.columns
    stream = CsvStream(args.out, names) if args.out else None
    started = time.perf_counter()
    try:
        if runner is None:
            with bar(ticks, name, args.verbosity, unit="step") as progress:
                def tick(k, progress=progress):
                    progress.update(k - progress.n)

                result = run_or_failed(loop, fmus="python" if fmus is None else fmus,
                                       sink=stream, keep=keep, progress=tick)
        else:
            result = runner(stop)
            if stream is not None and result.success:
                for k, (t, row) in enumerate(zip(result.times, result.data)):
                    if k % every == 0 or k == len(result.times) - 1:
                        stream(t, row)
    except BaseException:
        if stream is not None:
            stream.finish(False)
        raise
    elapsed = time.perf_counter() - started
    stepped_note(name, result, args.verbosity)
    where = stream.finish(result.success) if stream is not None else None
    runs = None
    if others and result.success:
        runs = {label or "this run": result}
        for other_label, other_loop in others.items():
            path = other_paths[other_label]
            other_stream = CsvStream(path, other_loop.columns) if path else None
            try:
                with bar(ticks, f"{name}, {other_label}", args.verbosity,
                         unit="step") as progress:
                    def other_tick(k, progress=progress):
                        progress.update(k - progress.n)

                    chosen = (other_fmus or {}).get(other_label)
                    other = run_or_failed(other_loop,
                                          fmus="python" if chosen is None else chosen,
                                          sink=other_stream, keep=keep,
                                          progress=other_tick)
            except BaseException:
                if other_stream is not None:
                    other_stream.finish(False)
                raise
            other_where = (other_stream.finish(other.success) if other_stream is not None
                           else None)
            if not other.success:  # as this run's failure: its rows kept apart, no plot
                show_notes(other, args.verbosity)
                kept = ""
                if other_where is not None and other.row_count:
                    kept = (f"; {other.row_count} rows to t = {other.times[-1]:.6g} kept "
                            f"in {other_where}")
                print(f"delaycomp: error: --compare, the {other_label} run: "
                      f"{other.message}{kept}", file=sys.stderr)
                return 1
            runs[other_label] = other
    code = _report_run(args, result, elapsed, name, title, where, timing, units, runs)
    if code == 0 and remember is not None and result.recipe is not None and not others:
        remember(result, {"notes": notes, "estimate": estimate})
    if code == 0 and runs:
        for other_label, path in other_paths.items():
            if path is not None:
                print(f"{name}, {other_label}: {runs[other_label].row_count} rows in {path}")
    return code


def stepped_how(args, loop, fmus, runner) -> str:
    """The engine of the run's estimate (``delaycomp.formats.outputs.estimate``):
    ``native-core`` where the native core will step it, else ``--engine``."""
    from delaycomp.orchestrator.native_core import why_not_files

    if (runner is None and args.engine == "fmu"
            and getattr(args, "stepping", "auto") != "python"
            and why_not_files(loop, fmus if isinstance(fmus, dict) else None) is None):
        return "native-core"
    return args.engine


def refuse_without_core(loop, fmus, other_fmus: dict, others: dict) -> None:
    """``--stepping native-core`` refused (``UsageError``) before any work where the native
    core cannot step this run or a ``--compare`` run (``why_not_files``)."""
    from delaycomp.cli.parsers import UsageError
    from delaycomp.orchestrator.native_core import why_not_files

    runs = [(loop, fmus), *((other, other_fmus.get(label)) for label, other in others.items())]
    for each, files in runs:
        why = why_not_files(each, files if isinstance(files, dict) else None)
        if why:
            raise UsageError(f"--stepping native-core is not allowed for this run: {why}")


#: what ``-v`` says of a run the native stepping core stepped
CORE_STEPPED = "stepped by the native core (C, no Python between the FMI calls)"


def stepped_note(name: str, result, verbosity: int) -> None:
    """Under ``-v``, what stepped the run: the native stepping core, or the Python master
    and why the core did not (``Result.stepped_by``, ``Result.stepping_note``).

    >>> from delaycomp.orchestrator.simulate import Result
    >>> stepped_note("ex", Result([], None, None, stepped_by="python",
    ...                           stepping_note="plant is a Python FMU"), 2)
    """
    from delaycomp.progress import VERBOSE, info

    if result.stepped_by == "native-core":
        info(f"{name}: {CORE_STEPPED}", verbosity, VERBOSE)
    elif result.stepped_by == "python":
        why = f" ({result.stepping_note})" if result.stepping_note else ""
        info(f"{name}: stepped by the Python master{why}", verbosity, VERBOSE)


def undriven_note(loop, verbosity: int) -> list[str]:
    """The note (once, unless ``-q``) naming the inputs of a user's FMU that the loop does
    not drive, with the start values they keep
    (``delaycomp.system.plantfmu.undriven_notes``); returns the notes."""
    from delaycomp.progress import info
    from delaycomp.system.plantfmu import undriven_notes

    notes = list(undriven_notes(loop))
    for note in notes:
        info(f"note: {note}", verbosity)
    return notes


def show_notes(result, verbosity: int) -> None:
    """A run's notes on standard error: an FMU's information (its messages of status OK)
    with ``-v`` only, as ``instance: text``; its warnings always (``-q`` too), as
    ``instance: warning: text``; delaycomp's own notes unless ``-q``, as ``note: ...``."""
    from delaycomp.progress import QUIET, VERBOSE, info

    logged = {f"{name}: {text}": (name, status, text)
              for name, status, text in getattr(result, "logged", ())}
    for note in result.notes:
        name, status, text = logged.get(note, ("", "", note))
        if status == "warning":
            print(f"{name}: warning: {text}", file=sys.stderr)
        elif status == "ok":
            info(note, verbosity, VERBOSE)
        elif verbosity > QUIET:
            info(f"note: {note}", verbosity)


def _report_run(args, result, elapsed: float, name: str, title: str, where=None,
                timing=None, units=None, runs=None) -> int:
    """Plot a successful run and print its summary; on failure nothing that looks like a
    result (no FILE.csv, no plot): the rows recorded before it are in FILE.csv.partial."""
    show_notes(result, args.verbosity)
    if not result.success:
        kept = ""
        if where is not None and result.row_count:
            kept = (f"; {result.row_count} rows to t = {result.times[-1]:.6g} kept in "
                    f"{where}")
        print(f"delaycomp: error: {result.message}{kept}", file=sys.stderr)
        return 1
    if args.plot:
        from delaycomp.plotting import plot_result

        plot_result(result, args.plot, title, timing, units, runs)
    print(summary(name, result.row_count, float(result.times[-1]), result.names,
                  result.data[-1], elapsed))
    return 0


def summary(name: str, rows: int, last_time: float, names, last_row, elapsed: float) -> str:
    """The one line that ends a run that went well: its rows, its last time and values.

    >>> summary("ex.ssp", 3, 0.02, ["plant.x"], [0.5], 0.0123)
    'ex.ssp: 3 rows to t = 0.02 in 0.01 s; final plant.x = 0.5'
    """
    last = ", ".join(f"{n} = {v:.6g}" for n, v in zip(names, last_row))
    return f"{name}: {rows} rows to t = {last_time:.6g} in {elapsed:.2f} s; final {last}"
