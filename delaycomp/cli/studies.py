"""The commands that study a loop over many runs or values: ``sweep`` (a parameter grid),
``robustness`` (a Monte Carlo map over a channel's jitter x loss), ``critical-delay`` (the
largest stable measurement delay, confirmed by co-simulation, or its table along one
parameter)."""

from __future__ import annotations

import sys
import time

from delaycomp.cli.arguments import check_outputs, source_of
from delaycomp.cli.execute import undriven_note
from delaycomp.cli.parsers import UsageError
from delaycomp.cli.signals import ending_signals
from delaycomp.errors import ParameterError, short


def cmd_sweep(args) -> int:
    """``delaycomp sweep``; SIGTERM and SIGHUP stop it as Ctrl-C does (the workers end
    with it, none is left behind)."""
    with ending_signals():
        return _sweep(args)


def _sweep(args) -> int:
    from delaycomp.formats.outputs import clear_previous
    from delaycomp.progress import info
    from delaycomp.studies.axes import parse_grid, snap_axes

    check_outputs(args)
    source, sets = source_of(args)  # the loop, opened once: everything below is handed it
    axes = [parse_grid(g) for g in args.grid]
    if args.plot and len(axes) > 2:
        raise UsageError("--plot draws one or two grid parameters")
    # the arguments read: now the sweep (numpy)
    import numpy as np

    from delaycomp.api import iter_sweep
    from delaycomp.studies import sweep

    options = sweep.SweepOptions(
        stop=args.stop_time, engine=args.engine, workers=args.workers,
        scheduler=args.scheduler, fmu_dir=str(args.fmu_dir) if args.fmu_dir else None,
        exact=args.exact, array_backend=args.array_backend, chunk=args.chunk,
        verbosity=args.verbosity)
    # the rows are written as they come (held: the plot's rho alone)
    count, _ = sweep.check_sweep_size(source, axes, sets, options, held=False,
                                      plot=bool(args.plot))
    axes, notes = snap_axes(source, axes, sets)
    for note in notes:
        info(f"note: {note}", args.verbosity)
    if str(args.scenario).endswith(".toml"):  # a plant FMU's free inputs, said once
        undriven_note(source.loop(sets), args.verbosity)
    clear_previous(args.out, args.plot)
    started = time.perf_counter()
    notes = []
    rows = iter_sweep(source, axes, sets=sets, stop_time=options.stop, engine=options.engine,
                      workers=options.workers, exact=options.exact,
                      array_backend=options.array_backend, chunk=options.chunk,
                      scheduler=options.scheduler, notes=notes, fmu_dir=options.fmu_dir,
                      verbosity=options.verbosity)
    tally = sweep.Tally(rho=np.empty(count) if args.plot else None)
    sweep.write_csv(tally.count(rows), [a.name for a in axes], args.out)
    for note in notes:  # what the batch engine did: part of the result (tests/test_batch.py)
        print(note)
    if args.plot:
        _sweep_plot(args, source, sets, axes, tally.rho)
    print(f"{args.scenario}: {tally.points} points in {time.perf_counter() - started:.1f} s, "
          f"{tally.stable} stable" + (f", {tally.failed} failed" if tally.failed else "")
          + f"; wrote {args.out}")
    if tally.failed:  # neither stable nor unstable: the run broke down (the column says why)
        print(f"delaycomp: error: {tally.failed} of {tally.points} points failed (column "
              f"failed of {args.out}); the first: {tally.first_failed}", file=sys.stderr)
        return 1
    return 0


def _sweep_plot(args, source, sets: list[str], axes: list, rho) -> None:
    """``--plot`` of a sweep: its ``rho``, the critical delays over it, a title giving what
    the grid holds fixed."""
    from delaycomp.plotting import loop_title
    from delaycomp.studies import sweep
    from delaycomp.studies.axes import format_value
    from delaycomp.studies.critical import critical_curve

    first = source.loop([*sets, *(f"{a.name}={format_value(a.values[0])}" for a in axes)])
    ctrl = first.by_role("controller")
    fixed = {**(ctrl.parameters if ctrl is not None else {}), "T": first.T}
    for a in axes:  # the title gives what the grid holds fixed
        fixed.pop(a.name, None)
    curve = critical_curve(source, sets, [a.name for a in axes], [a.values for a in axes])
    sweep.plot_sweep(rho, axes, args.plot, loop_title(source.name, source.title, fixed),
                     curve)


def cmd_robustness(args) -> int:
    """``delaycomp robustness``; SIGTERM and SIGHUP stop it as Ctrl-C does."""
    with ending_signals():
        return _robustness(args)


def _robustness(args) -> int:
    from delaycomp.formats.outputs import clear_previous
    from delaycomp.progress import bar
    from delaycomp.studies import robustness as rb
    from delaycomp.studies.axes import parse_grid

    check_outputs(args)
    if not str(args.scenario).endswith(".toml"):
        raise UsageError(f"{short(args.scenario)} is not allowed: robustness takes a loop "
                         "file (LOOP.toml)")
    def axis(option: str, text: str):
        try:
            return parse_grid(f"{option}={text}").values
        except ParameterError as exc:
            raise UsageError(str(exc).replace(f"--grid '{option}=", f"--{option} '")
                             .replace("NAME=START", "START")) from None

    jitter, loss = axis("jitter", args.jitter), axis("loss", args.loss)
    modes = tuple(m.strip() for m in args.modes.split(","))
    rb.check_grid(jitter, loss, args.runs, args.seed, args.on, modes, args.distribution)
    source, sets = source_of(args)
    from delaycomp.api import robustness  # the arguments are checked: now the study

    clear_previous(args.out, args.plot)
    started = time.perf_counter()
    total = len(jitter) * len(loss) * len(modes) * args.runs
    with bar(total, "robustness", args.verbosity, unit="run") as shown:
        result = robustness(source, jitter, loss, args.runs, seed=args.seed, on=args.on,
                            modes=modes, distribution=args.distribution, sets=sets,
                            stop_time=args.stop_time, chunk=args.chunk,
                            array_backend=args.array_backend, progress=shown.update)
    rb.write_csv(result, args.out)
    if args.plot:
        rb.plot_map(result, args.plot, f"{source.name}: {args.runs} runs per point, "
                    f"{args.on}")
    print(f"{args.scenario}: {len(result.rows)} rows ({total} runs) in "
          f"{time.perf_counter() - started:.1f} s; wrote {args.out}"
          + (f" and {args.plot}" if args.plot else ""))
    return 0


def cmd_critical_delay(args) -> int:
    """``delaycomp critical-delay``: ``r_c`` confirmed by co-simulation (exit status 1 where
    it is not), or with ``--grid`` its table along one parameter."""
    check_outputs(args)
    scenario, sets = source_of(args)
    if (args.out or args.plot) and not args.grid:
        raise UsageError("--out and --plot write the table of --grid: give --grid")
    # the arguments are checked: now the maths (scipy) the answer needs
    from delaycomp.api import critical_delay_report, critical_delay_table

    if args.grid:
        from delaycomp.formats.outputs import clear_previous

        clear_previous(args.out, args.plot)
        rows = critical_delay_table(scenario, args.grid, sets=sets, out=args.out,
                                    plot=args.plot)
        for line in rows:
            print(line)
        return 0
    if args.periods < 10:
        raise UsageError(f"--periods {args.periods} is not allowed: must be an integer >= 10")
    report = critical_delay_report(scenario, sets=sets, periods=args.periods,
                                   fmu_dir=args.fmu_dir)
    print(f"r_c = {report.r_c:.9f}")
    for line in report.lines:
        print(line)
    return 0 if report.confirmed else 1
