"""``delaycomp run``: a scenario or a loop file (with ``--compare``, in both controller
modes) in delaycomp's master; a packed FILE.ssp is handed to ``delaycomp.cli.foreign_ssp``."""

from __future__ import annotations

import argparse

from delaycomp.cli.arguments import check_outputs, chosen_fmus, source_of
from delaycomp.cli.execute import compare_path, execute
from delaycomp.cli.foreign_ssp import run_ssp
from delaycomp.cli.parsers import UsageError
from delaycomp.cli.recipes import replayed
from delaycomp.errors import ParameterError


def cmd_run(args) -> int:
    """``delaycomp run``: a scenario or loop file in our master (``--compare``: in both
    controller modes), or a packed FILE.ssp (``run_ssp``)."""
    from delaycomp.plotting import Marks, title_of_loop

    check_outputs(args)
    if args.compare and not (args.plot or args.out):
        raise UsageError("--compare writes both runs: give --out FILE.csv (this run there, "
                         "the other mode's beside it as FILE.<mode>.csv) and/or --plot "
                         "FILE.png (both drawn)")
    if args.scenario.endswith(".ssp"):
        if args.native or args.python:
            flag = "--native" if args.native else "--python"
            raise UsageError(f"{flag} is not allowed with a FILE.ssp: the archive's FMUs run")
        code = replayed(args)  # from the recipe of its first run, where there is one
        return run_ssp(args) if code is None else code
    if args.period is not None or args.steps is not None or args.role:
        raise UsageError("--period, --steps and --role apply to a FILE.ssp of another tool")
    if args.master != "delaycomp":
        raise UsageError("--master runs a FILE.ssp (pack one with `delaycomp ssp --jacobi`)")
    source, sets = source_of(args)
    params = source.resolve(sets)
    loop = source.make(params)
    stop = source.default_stop_time if args.stop_time is None else args.stop_time
    if stop is None:
        raise UsageError(f"{source.name} has no stop time: give --stop-time (or stop_time "
                         "in the loop file)")
    mode = _mode_of(loop)
    others = {}
    if args.compare:
        other = "uncompensated" if mode == "compensated" else "compensated"
        key = "controller.mode" if str(args.scenario).endswith(".toml") else "mode"
        try:
            others[other] = source.loop([*sets, f"{key}={other}"])
        except (ParameterError, ValueError):
            raise UsageError(f"--compare needs a loop whose controller has a mode "
                             f"(compensated or uncompensated); {source.name} has none"
                             ) from None
        if args.out is not None:  # checked, as --out, before anything runs
            from delaycomp.formats.outputs import check_output

            check_output(compare_path(args.out, other), "--out (--compare)")
    from delaycomp.plotting import UNITS_BY_LOOP

    if args.engine != "fmu":  # the Python FMUs' slaves, called in this process
        if args.stepping == "native-core":
            raise UsageError("--stepping native-core steps FMUs: --engine inprocess is "
                             "not allowed with it")
        if args.native or args.fmi == 3:
            raise UsageError(f"{'--native' if args.native else '--fmi 3'} runs FMUs: "
                             "--engine inprocess is not allowed with it")
        fmus = None
        other_fmus = {}
    else:
        fmus = chosen_fmus(args, loop)
        # the other mode with FMUs of the same kind (native where this run's are)
        quiet = argparse.Namespace(**{**vars(args), "verbosity": 0})  # its note said once
        other_fmus = {label: chosen_fmus(quiet, other_loop)
                      for label, other_loop in others.items()}
    return execute(args, loop, stop, source.name, title_of_loop(loop, args.compare),
                   Marks.of_loop(loop), UNITS_BY_LOOP.get(source.name), label=mode,
                   others=others, fmus=fmus, other_fmus=other_fmus)


def _mode_of(loop) -> str | None:
    """``compensated`` or ``uncompensated`` for a loop whose controller has a mode."""
    ctrl = loop.by_role("controller")
    if ctrl is None:
        return None
    if ctrl.parameters.get("predictor") == "none":
        return "uncompensated"
    return ctrl.parameters.get("mode", "compensated")
