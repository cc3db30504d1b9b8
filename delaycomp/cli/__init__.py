"""delaycomp: predictor-based delay compensation for sampled-data loops, as FMUs.

Examples
--------
Build the FMUs (plant, transport delay, predictor-controller)::

    delaycomp build --out build/fmus

Reproduce Figure 3 of Karafyllis & Krstic (compensated, r = 0.3, u0 = 4)::

    delaycomp run example-3.6 --set r=0.3 --set u0=4 --out fig3.csv --plot fig3.png

The same FMUs of the LTI loop written in C (no Python in the host), and a run with them::

    delaycomp build --native --out build/native
    delaycomp run example-3.6 --set r=0.3 --set u0=4 --native

Run a packed SSP (``delaycomp build`` writes one per scenario) in the same master, with an
FMU parameter changed (``instance.parameter=value``)::

    delaycomp run build/fmus/example-3.6.ssp --set controller.mode=uncompensated

The critical measurement delay of the uncompensated loop (k = 2, T = 1)::

    delaycomp critical-delay example-3.6

Each FMU of the reference cases alone, in the FMI cross-check layout::

    delaycomp crosscheck --out crosscheck

The whole loop of Example 3.6 as one container FMU::

    delaycomp export-loop example-3.6 --set r=0.3 --out loop.fmu

A loop's controller as plain C for a microcontroller (ctl.h, ctl.c)::

    delaycomp export-c my_loop.toml --prefix ctl --out firmware/

List the scenarios and their parameters::

    delaycomp list
"""

from __future__ import annotations

import argparse
import os
import sys

from delaycomp import __version__
from delaycomp.cli.building import cmd_build, cmd_export_c, cmd_export_loop, cmd_ssp
from delaycomp.cli.checks import cmd_check, cmd_crosscheck
from delaycomp.cli.execute import compare_path, show_notes
from delaycomp.cli.listing import cmd_list
from delaycomp.cli.parsers import (
    COMMANDS_WITH_BARS,
    Parser,
    UsageError,
    build_parser,
    check_parser,
    critical_delay_parser,
    crosscheck_parser,
    export_c_parser,
    export_loop_parser,
    robustness_parser,
    run_parser,
    ssp_parser,
    sweep_parser,
)
from delaycomp.cli.running import cmd_run
from delaycomp.cli.signals import Terminated, interrupt_watch, stopped
from delaycomp.cli.studies import cmd_critical_delay, cmd_robustness, cmd_sweep
from delaycomp.errors import BadFileError, ParameterError, SspError
from delaycomp.maths.model import ModelError

# ``main`` and ``entry`` (the console script), and the public names of the command line's
# modules that callers take from ``delaycomp.cli``
__all__ = ["Terminated", "UsageError", "compare_path", "entry", "main", "show_notes"]


def _parser() -> argparse.ArgumentParser:
    """The command line: one subparser per command (each built by its own function),
    each with ``-q`` / ``-v``."""
    p = Parser(prog="delaycomp", description=__doc__,
               formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--version", action="version", version=f"delaycomp {__version__}")
    sub = p.add_subparsers(dest="command", required=True, parser_class=Parser)
    build_parser(sub)
    run_parser(sub)
    critical_delay_parser(sub)
    sweep_parser(sub)
    robustness_parser(sub)
    check_parser(sub)
    crosscheck_parser(sub)
    export_loop_parser(sub)
    export_c_parser(sub)
    ssp_parser(sub)
    sub.add_parser("list", help="list the scenarios and their parameters")
    for command in sub.choices.values():
        loud = command.add_mutually_exclusive_group()
        loud.add_argument("-q", "--quiet", dest="verbosity", action="store_const", const=0,
                          default=1, help="errors, an FMU's warnings and results only (no "
                                               "progress, no notes)")
        loud.add_argument("-v", "--verbose", dest="verbosity", action="store_const",
                          const=2, help="also say what is run (steps, estimates, snapping), "
                                           "each FMU built or found in the cache, and show "
                                           "the FMUs' information messages")
    for name in COMMANDS_WITH_BARS:
        shown = sub.choices[name].add_mutually_exclusive_group()
        shown.add_argument("--progress", dest="progress", action="store_true", default=None,
                           help="show the progress bar on standard error whatever it is (a "
                                "file, a pipe; with -q too); by default it shows when "
                                "standard error is a terminal of any kind (a console, a "
                                "pseudo-terminal such as script's) and not with -q")
        shown.add_argument("--no-progress", dest="progress", action="store_false",
                           help="never show the progress bar")
    return p


def _split_sets(argv: list[str]) -> tuple[list[str], list[str]]:
    """Take every ``--set VALUE`` / ``--set=VALUE`` out of ``argv`` in one pass.

    argparse matches the remaining arguments against a pattern string at every option it
    meets, so its time grows with the square of the option count: 60 000 ``--set`` took
    minutes. The assignments go straight into ``args.set`` instead (in order).

    Examples
    --------
    >>> _split_sets(["run", "x", "--set", "r=1", "--set=k=2", "--out", "a.csv"])
    (['r=1', 'k=2'], ['run', 'x', '--out', 'a.csv'])
    """
    sets: list[str] = []
    rest: list[str] = []
    i = 0
    while i < len(argv):
        arg = argv[i]
        if arg == "--":
            rest.extend(argv[i:])
            break
        if arg == "--set" and i + 1 < len(argv):
            sets.append(argv[i + 1])
            i += 2
            continue
        if arg.startswith("--set="):
            sets.append(arg[len("--set="):])
        else:
            rest.append(arg)
        i += 1
    return sets, rest


def _platform_notes(args) -> None:
    """The native builds' notes of this command (a platform left out for want of its
    cross compiler), each once, where the command writes FMUs for elsewhere (``build``,
    ``ssp``, ``export-loop``); a run builds them for this machine only."""
    native = sys.modules.get("delaycomp.fmu.native")
    if native is not None:
        from delaycomp.progress import info

        for text in native.pop_notes():
            if args.command in ("build", "ssp", "export-loop"):
                info(text, getattr(args, "verbosity", 1))


def main(argv: list[str] | None = None) -> int:
    """The command line: parse ``argv`` (default: ``sys.argv[1:]``), run the command, return the
    exit status (2 for bad input, 1 for a failed run, with one line on stderr; Ctrl-C, and
    SIGTERM or SIGHUP during a sweep, give ``128 + signal``: ``stopped``; a failure
    that follows a Ctrl-C, code that caught the interrupt as an error, is reported as the
    interrupt)."""
    command = None
    with interrupt_watch() as interrupted:
        try:
            sets, rest = _split_sets(list(sys.argv[1:] if argv is None else argv))
            args = _parser().parse_args(rest)
            command = args.command
            if sets:
                if not hasattr(args, "set"):
                    raise UsageError(f"unrecognized arguments: --set (delaycomp "
                                     f"{args.command} takes no --set)")
                args.set = [*args.set, *sets]
            from delaycomp import progress

            progress.choose(getattr(args, "progress", None), args.verbosity)
            handler = {"build": cmd_build, "run": cmd_run, "sweep": cmd_sweep,
                       "robustness": cmd_robustness,
                       "critical-delay": cmd_critical_delay, "check": cmd_check,
                       "crosscheck": cmd_crosscheck, "export-loop": cmd_export_loop,
                       "export-c": cmd_export_c,
                       "ssp": cmd_ssp, "list": cmd_list}[args.command]
            if getattr(args, "platforms", None) is not None:
                from delaycomp.fmu.toolchain import chosen

                with chosen(args.platforms):
                    rc = handler(args)
            else:
                rc = handler(args)
            if interrupted and rc != 0:  # a failure that Ctrl-C caused
                return stopped(KeyboardInterrupt(), command)
            _platform_notes(args)
            return rc
        except (UsageError, ParameterError, ModelError, BadFileError, SspError) as exc:
            if interrupted:
                return stopped(KeyboardInterrupt(), command)
            print(f"delaycomp: error: {exc}", file=sys.stderr)
            return 2
        except (KeyboardInterrupt, Terminated) as exc:
            return stopped(exc, command)
        except BrokenPipeError:  # `delaycomp list | head`: the reader left; stop quietly
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
            return 141  # as a shell reports a process ended by SIGPIPE
        except (OSError, RuntimeError, ValueError) as exc:
            if interrupted:
                return stopped(KeyboardInterrupt(), command)
            msg = (str(exc).strip().splitlines()[-1] if str(exc).strip()
                   else type(exc).__name__)
            print(f"delaycomp: error: {msg}", file=sys.stderr)
            return 1
        finally:  # --progress / --no-progress and -v hold for this command only
            progress_module = sys.modules.get("delaycomp.progress")
            if progress_module is not None:
                progress_module.choose(None)


def entry() -> None:
    """The ``delaycomp`` command: ``main``, then the exit.

    When an FMU was loaded in this process, the process leaves with ``os._exit`` after the
    atexit handlers have run and the streams are flushed: unloading a pythonfmu FMU in the
    interpreter's teardown corrupted the heap ("corrupted double-linked list", SIGABRT) in
    2 of 100 library runs that exited with instances loaded (measured), after the result
    was written. Our child processes leave the same way.
    """
    rc = main()
    fmu = sys.modules.get("delaycomp.orchestrator.fmu")
    # an interrupt leaves the same way: under ``python -m`` an interrupted command's
    # sys.exit(130) left by SIGINT instead (exit status -2 to a parent in Python)
    if rc >= 128 or (fmu is not None and getattr(fmu, "_UNPACKED", None)):
        import atexit

        atexit._run_exitfuncs()
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(rc)
    sys.exit(rc)
