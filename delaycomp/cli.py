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
import contextlib
import math
import os
import sys
import time
from pathlib import Path

from delaycomp import __version__
from delaycomp.errors import (
    BadFileError,
    DelaycompError,
    ParameterError,
    SimulationFailed,
    SspError,
    short,
)
from delaycomp.maths.model import ModelError
from delaycomp.names import LOOP_GROUPS
from delaycomp.paper import scenarios  # light: no numpy until a loop is read


class UsageError(DelaycompError):
    """Bad command-line input: reported as one line, exit status 2."""


class Terminated(KeyboardInterrupt):
    """SIGTERM or SIGHUP (the terminal closing) during a sweep (``_ending_signals``),
    raised in the main thread as Ctrl-C raises ``KeyboardInterrupt`` (an interrupt, not an
    error: whatever handles Ctrl-C handles it): the sweep stops the same way, its worker
    processes ended (``delaycomp.studies.pool.on_processes``), and ``main``
    reports it in one line, with exit status ``128 + signum``."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = signum


def _raise_terminated(signum, frame):
    raise Terminated(signum)


@contextlib.contextmanager
def _ending_signals():
    """SIGTERM and SIGHUP raise ``Terminated`` while the block runs, where they have
    their default action (under ``nohup`` SIGHUP stays ignored) and in the main thread only
    (where Python runs signal handlers); the previous handlers come back afterwards."""
    import signal
    import threading

    saved = {}
    if threading.current_thread() is threading.main_thread():
        for name in ("SIGTERM", "SIGHUP"):  # no SIGHUP on Windows
            signum = getattr(signal, name, None)
            if signum is not None and signal.getsignal(signum) is signal.SIG_DFL:
                saved[signum] = signal.signal(signum, _raise_terminated)
    try:
        yield
    finally:
        for signum, handler in saved.items():
            signal.signal(signum, handler)


#: the commands that run many co-simulations (a grid, the reference cases in every master),
#: whose interrupt names no one time
MANY_RUNS = ("sweep", "check", "crosscheck", "robustness")


@contextlib.contextmanager
def _interrupt_watch():
    """A list that gets an entry when SIGINT arrives while the command runs (Python's
    handler then raises KeyboardInterrupt as before), in the main thread only. Code that
    catches every exception (an FMU's slave, a build step, a check) may turn Ctrl-C into
    its own failure; ``main`` reports such a failure as the interrupt it was."""
    import signal
    import threading

    seen: list[bool] = []
    if (threading.current_thread() is not threading.main_thread()
            or signal.getsignal(signal.SIGINT) is not signal.default_int_handler):
        yield seen
        return

    def handler(signum, frame):
        seen.append(True)
        signal.default_int_handler(signum, frame)

    signal.signal(signal.SIGINT, handler)
    try:
        yield seen
    finally:
        signal.signal(signal.SIGINT, signal.default_int_handler)


def _stopped(exc: KeyboardInterrupt | Terminated, command: str | None = None) -> int:
    """Ctrl-C, SIGTERM or SIGHUP: one line on standard error, and the exit status a shell
    gives a process that the signal ended, ``128 + signum`` (130 for Ctrl-C). Ctrl-C
    during a co-simulation (``Interrupted``) names the simulation
    time reached, ``delaycomp: interrupted at t = 12.34``; elsewhere (a sweep's many
    runs, a build, an analysis) ``delaycomp: interrupted``."""
    import signal

    from delaycomp.errors import Interrupted

    if isinstance(exc, Terminated):
        signum, line = exc.signum, f"terminated ({signal.Signals(exc.signum).name})"
    elif isinstance(exc, Interrupted) and command not in MANY_RUNS:
        signum, line = signal.SIGINT, f"interrupted at t = {exc.time:.10g}"
    else:
        signum, line = signal.SIGINT, "interrupted"
    with contextlib.suppress(OSError):  # the terminal may be gone (SIGHUP)
        print(f"delaycomp: {line}", file=sys.stderr, flush=True)
    return 128 + int(signum)


class _Parser(argparse.ArgumentParser):
    def error(self, message: str):  # one line, no usage dump, exit 2
        raise UsageError(message)


class _Append(argparse.Action):
    """``action="append"`` without argparse's copy of the list at every occurrence (that
    copy made 60 000 ``--set`` quadratic)."""

    def __call__(self, parser, namespace, values, option_string=None):
        items = getattr(namespace, self.dest, None)
        if items is None or items is self.default:
            items = list(self.default or [])
            setattr(namespace, self.dest, items)
        items.append(values)


def _file_path(text: str) -> Path:
    """An output file's path; a name ending in a separator is a folder, refused here
    (``Path`` would drop the separator)."""
    if text.endswith(("/", os.sep)):
        raise argparse.ArgumentTypeError(f"{short(text)} is a folder: give a file name such as "
                                         f"{text}result.csv (or .png for a plot)")
    return Path(text)


#: what a scenario argument is, for the help of every subcommand that takes one
SCENARIO_HELP = "a scenario name (`delaycomp list` shows them)"

BUILD_EXAMPLES = """examples:
  delaycomp build my-loop.toml --out fmus          # my-loop_*.fmu and my-loop_wiring.txt
  delaycomp build my-loop.toml --only controller   # the controller alone, and the sheet
  delaycomp build my-loop.toml --set r=0.4 --python
  delaycomp build --out build/fmus                 # every kind, and each scenario's SSP
"""

RUN_EXAMPLES = """examples:
  delaycomp run example-3.6 --set r=0.3 --set u0=4 --out fig3.csv --plot fig3.png
  delaycomp run example-3.6 --stop-time 2000 --output-interval 1 --out long.csv
  delaycomp run example-3.6 --set r=0.3 --compare --out a.csv --plot both.png
                                 # a.csv, a.uncompensated.csv and both runs in both.png
  delaycomp run my-loop.toml --set r=0.4 --out loop.csv --plot loop.png
  delaycomp run build/fmus/example-3.6.ssp --set controller.mode=uncompensated
"""


#: the commands that draw a progress bar: they take --progress and --no-progress
COMMANDS_WITH_BARS = ("run", "sweep", "robustness")


def _parser() -> argparse.ArgumentParser:
    """The command line: one subparser per command (each built by its own function),
    each with ``-q`` / ``-v``."""
    p = _Parser(prog="delaycomp", description=__doc__,
                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--version", action="version", version=f"delaycomp {__version__}")
    sub = p.add_subparsers(dest="command", required=True, parser_class=_Parser)
    _build_parser(sub)
    _run_parser(sub)
    _critical_delay_parser(sub)
    _sweep_parser(sub)
    _robustness_parser(sub)
    _check_parser(sub)
    _crosscheck_parser(sub)
    _export_loop_parser(sub)
    _export_c_parser(sub)
    _ssp_parser(sub)
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


def _build_parser(sub) -> None:
    """``delaycomp build``: a loop's FMUs, or every kind's and each scenario's SSP."""
    b = sub.add_parser("build", help="build a loop's FMUs (LOOP.toml), or the FMUs and "
                                     "each scenario's SSP into a folder",
                       description="With LOOP.toml: the FMUs of that loop, named after it "
                                   "(LOOP_plant.fmu, LOOP_controller.fmu, ...), with the "
                                   "loop's values as their start values, and LOOP_wiring.txt "
                                   "(what connects to what, T and the base step, the delays "
                                   "a host provides when it takes only the controller). "
                                   "Without: the FMUs of every kind and each scenario's SSP "
                                   "(or with --model a model file's FMUs) into --out.",
                       epilog=BUILD_EXAMPLES,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    b.add_argument("loop", nargs="?", default=None, metavar="LOOP.toml",
                   help="a loop file (or a scenario name): build that loop's FMUs")
    b.add_argument("--out", type=Path, default=None, metavar="DIR",
                   help="output folder (with LOOP.toml: default the current folder)")
    b.add_argument("--only", action=_Append, default=[], choices=tuple(LOOP_GROUPS),
                   help="with LOOP.toml: build only the plant, the controller or the two "
                        "delays (repeatable; default: all)")
    b.add_argument("--set", action=_Append, default=[], metavar="NAME=VALUE",
                   help="with LOOP.toml: override one of its keys (repeatable)")
    b.add_argument("--allow-unstable", action="store_true",
                   help="with LOOP.toml: let an LTI gain through with which the delay-free "
                        "sampled loop is unstable (the sign guard; docs: reference/loop-files)")
    _fmu_kind(b, "build C FMUs only (the default builds them where it can): the delay, "
                 "LTI plant and LTI controller, or with --model the model's plant, "
                 "controller and delays (f, k, step translated to C); an error where it "
                 "cannot")
    b.add_argument("--model", type=Path, default=None, metavar="FILE.py",
                   help="build plant, controller and delay FMUs for this model module "
                        "(docs: reference/model-files)")
    _fmi_flag(b, "build FMI 3.0 FMUs (native C only; without LOOP.toml the FMUs alone, no "
                 "SSP archives)")
    _platforms_flag(b)


def _platforms_flag(p: argparse.ArgumentParser) -> None:
    """``--platforms LIST``: the platforms of the native FMUs' binaries."""
    p.add_argument("--platforms", type=_platform_list, default=None, metavar="LIST",
                   help="the native FMUs' binaries: comma-separated, of x86_64-linux, "
                        "aarch64-linux, x86_64-windows, x86_64-darwin, aarch64-darwin "
                        "(or linux64, win64, darwin64: both macOS); default all five "
                        "(docs: reference/native)")


def _platform_list(text: str) -> tuple[str, ...]:
    """``--platforms``' value: the platforms it names (``toolchain.parse_platforms``)."""
    from delaycomp.fmu.toolchain import NativeBuildError, parse_platforms

    try:
        names = parse_platforms(text, "--platforms")
    except NativeBuildError as exc:
        raise argparse.ArgumentTypeError(str(exc).removeprefix("--platforms ")) from None
    if not names:
        raise argparse.ArgumentTypeError("names no platform: give at least one")
    return names


def _run_parser(sub) -> None:
    """``delaycomp run``: co-simulate a scenario, a loop file or an SSP file."""
    r = sub.add_parser("run", help="co-simulate a scenario, a loop file or an SSP file",
                       description="Co-simulate a scenario, a loop file or a packed FILE.ssp "
                                   "in delaycomp's exact master.",
                       epilog=RUN_EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter)
    r.add_argument("scenario", help=SCENARIO_HELP + ", a LOOP.toml (then --set takes the "
                                    "file's keys: r=0.4, plant.x0=1,0, controller.K=...), "
                                    "or FILE.ssp (then --set takes instance.parameter=value)")
    _common(r)
    r.add_argument("--stop-time", type=float, default=None, metavar="S",
                   help="stop time in seconds (default: the scenario's)")
    r.add_argument("--out", type=_file_path, default=None, metavar="FILE.csv",
                   help="write the trajectory as CSV while the run goes (one row per base "
                        "step, or per --output-interval)")
    r.add_argument("--output-interval", type=float, default=None, metavar="S",
                   help="a row every S seconds (a multiple of the base step h = T/N) and "
                        "at the stop time (default: every base step)")
    r.add_argument("--plot", type=_file_path, default=None, metavar="FILE.png",
                   help="draw the run (png, pdf, svg, ...): every signal, the sampling "
                        "instants and the first sample's delay window")
    r.add_argument("--compare", action="store_true",
                   help="also run the other controller mode (compensated / uncompensated) "
                        "of a scenario or loop file whose controller has a mode: --out "
                        "FILE.csv gets this run, as without --compare, and FILE.MODE.csv "
                        "beside it the other (FILE.uncompensated.csv: the same columns and "
                        "row times); --plot draws both, on a symmetric log scale (said on "
                        "the plot) where one run's largest value exceeds 4 times the "
                        "other's; needs --out or --plot")
    r.add_argument("--engine", choices=("fmu", "inprocess"), default="fmu",
                   help="fmu: the built FMUs through fmpy (default); inprocess: the same "
                        "slaves called directly, same numbers, several times faster")
    _fmu_kind(r, "run the native C FMUs, an error where the loop has none (the default "
                 "runs them where it can); with --fmu-dir DIR those delaycomp build --out "
                 "DIR wrote there, missing ones built into DIR/native")
    _fmi_flag(r, "run delaycomp's FMUs as FMI 3.0 FMUs (native C only; a loop's own FMU "
                 "file, e.g. another tool's FMI 2.0 plant, runs beside them as it is)")
    r.add_argument("--watchdog", type=float, default=None, metavar="SECONDS",
                   help="an FMU file of another tool (run in a child process) may take "
                        "this long per call before the run is stopped (default: 10 s, or "
                        "100 base steps of wall time if longer)")
    r.add_argument("--master", choices=("delaycomp", "libcosim", "ecos", "omsimulator"),
                   default="delaycomp",
                   help="FILE.ssp only: the co-simulation master (default: ours; libcosim "
                        "and Ecos need the Jacobi variant, `delaycomp ssp --jacobi`; "
                        "omsimulator runs either; docs: reference/ssp)")
    r.add_argument("--period", type=float, default=None, metavar="T",
                   help="FILE.ssp of another tool (no delaycomp annotations): the sampling "
                        "period T [s]")
    r.add_argument("--steps", type=int, default=None, metavar="N",
                   help="FILE.ssp of another tool: base steps per period (h = T/N)")
    r.add_argument("--role", action="append", default=[], metavar="NAME=ROLE",
                   help="FILE.ssp of another tool: the role of component NAME (plant, "
                        "meas_delay, controller, input_delay); repeatable; roles not named "
                        "follow from the connections, walking the loop from the plant")


def _critical_delay_parser(sub) -> None:
    """``delaycomp critical-delay``: the largest stable measurement delay, uncompensated."""
    c = sub.add_parser("critical-delay",
                       help="largest measurement delay for which the uncompensated loop "
                            "is stable")
    c.add_argument("scenario", help="an LTI scenario name (`delaycomp list`) or LOOP.toml")
    _common(c)
    c.add_argument("--periods", type=int, default=40,
                   help="periods of each confirming co-simulation (default 40)")
    c.add_argument("--grid", default=None, metavar="NAME=START:STOP:COUNT",
                   help="r_c as a function of one parameter (T, k, ...): a table, no "
                        "co-simulation")
    c.add_argument("--out", type=_file_path, default=None, metavar="FILE.csv",
                   help="with --grid: write the table as CSV")
    c.add_argument("--plot", type=_file_path, default=None, metavar="FILE.png",
                   help="with --grid: draw r_c against the grid parameter")


def _sweep_parser(sub) -> None:
    """``delaycomp sweep``: a scenario or loop file over a parameter grid."""
    s = sub.add_parser("sweep", help="run a scenario or a loop file over a parameter grid")
    s.add_argument("scenario", help=SCENARIO_HELP + " or LOOP.toml")
    _common(s)
    s.add_argument("--grid", action=_Append, required=True, metavar="NAME=START:STOP:COUNT",
                   help="a swept parameter, COUNT values from START to STOP (repeatable); "
                        "values of delays off the base grid are snapped to it")
    s.add_argument("--stop-time", type=float, default=None, metavar="S",
                   help="stop time of every run in seconds (default: the scenario's)")
    s.add_argument("--engine", choices=("batch", "inprocess", "fmu"), default="batch",
                   help="batch (default): all points advanced together, vectorized (points "
                        "it cannot take run inprocess, and the output says so); inprocess: "
                        "point by point, the FMUs' slaves without the FMI layer, equal to "
                        "the FMU run to the bit; fmu: the built FMUs")
    s.add_argument("--array-backend", choices=("numpy", "cupy", "jax", "auto"),
                   default="numpy",
                   help="batch engine's array library (default numpy; cupy or jax when "
                        "installed, e.g. on a GPU; auto: a GPU library if one sees a GPU)")
    s.add_argument("--chunk", type=int, default=None, metavar="POINTS",
                   help="batch engine: points per chunk (default: from the available "
                        "memory, at most 16384)")
    s.add_argument("--workers", type=int, default=os.cpu_count() or 1,
                   help="local worker processes (default: one per core; 1 runs in this "
                        "process)")
    s.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="run on this Dask distributed scheduler")
    s.add_argument("--exact", action="store_true",
                   help="LTI scenarios: rho from the lifted discrete-time model")
    s.add_argument("--out", type=_file_path, required=True, metavar="FILE.csv",
                   help="write one row per grid point: the grid values and the metrics")
    s.add_argument("--plot", type=_file_path, default=None, metavar="FILE.png",
                   help="draw rho: a curve for one grid parameter, a map for two")


ROBUSTNESS_EXAMPLES = """examples:
  delaycomp robustness my-loop.toml --jitter 0:0.4:9 --loss 0:0.3:4 --runs 1000 \\
      --out map.csv --plot map.png
  delaycomp robustness my-loop.toml --jitter 0:0.2:5 --loss 0.1:0.1:1 --runs 500 \\
      --on input_delay --modes compensated --out input.csv
"""


def _robustness_parser(sub) -> None:
    """``delaycomp robustness``: P(stable) and cost quantiles over jitter x loss."""
    r = sub.add_parser("robustness",
                       help="Monte Carlo map of an LTI loop file over a channel's jitter x "
                            "loss: P(stable), cost and final-norm quantiles",
                       epilog=ROBUSTNESS_EXAMPLES,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    r.add_argument("scenario", metavar="LOOP.toml",
                   help="an LTI loop file (its [meas_delay]/[input_delay] tables the base)")
    r.add_argument("--set", action=_Append, default=[], metavar="NAME=VALUE",
                   help="set a loop file's key (repeatable), e.g. meas_delay.policy=drop_stale")
    r.add_argument("--jitter", required=True, metavar="START:STOP:COUNT",
                   help="the jitter amplitudes [s], COUNT values from START to STOP")
    r.add_argument("--loss", required=True, metavar="START:STOP:COUNT",
                   help="the Bernoulli loss rates, COUNT values from START to STOP")
    r.add_argument("--runs", type=int, required=True,
                   help="seeds per grid point and mode")
    r.add_argument("--seed", type=int, default=0,
                   help="base seed: run i draws seed + i (default 0)")
    r.add_argument("--on", default="meas_delay", metavar="ROLE",
                   help="the channel the grid acts on: meas_delay (default) or input_delay")
    r.add_argument("--modes", default="compensated,uncompensated", metavar="LIST",
                   help="comma-separated modes (default compensated,uncompensated)")
    r.add_argument("--distribution", default="uniform",
                   help="the jitter's distribution: uniform (default), exponential or gamma "
                        "(these two need the table's max_delay)")
    r.add_argument("--stop-time", type=float, default=None, metavar="S",
                   help="stop time of every run in seconds (default: the loop file's)")
    r.add_argument("--chunk", type=int, default=None, metavar="RUNS",
                   help="runs per batch-engine call at most (default: from the run's length)")
    r.add_argument("--array-backend", choices=("numpy", "cupy", "auto"), default="numpy",
                   help="batch engine's array library (default numpy; cupy on an NVIDIA GPU, "
                        "the same numbers; auto: cupy where it sees a GPU, else numpy)")
    r.add_argument("--out", type=_file_path, required=True, metavar="FILE.csv",
                   help="write one row per grid point and mode")
    r.add_argument("--plot", type=_file_path, default=None, metavar="FILE.png",
                   help="heat maps of P(stable) and of the median cost, one column per mode")


def _check_parser(sub) -> None:
    """``delaycomp check``: every reference case in every master."""
    k = sub.add_parser("check", help="cross-check every reference case in every master")
    k.add_argument("loop", nargs="?", default=None, metavar="LOOP.toml",
                   help="check this loop file against the reference CSV it names "
                        "([reference] csv = ...) instead of the built-in cases")
    k.add_argument("--set", action=_Append, default=[], metavar="NAME=VALUE",
                   help="with LOOP.toml: override one of its keys (repeatable)")
    k.add_argument("--master", action=_Append, default=None, metavar="NAME",
                   help="only this master (repeatable; default: all)")
    k.add_argument("--case", action=_Append, default=None, metavar="SCENARIO/CASE",
                   help="only this reference case (repeatable; default: all)")
    k.add_argument("--require-all", action="store_true",
                   help="an optional master that is not installed is a failure (CI), not "
                        "a skipped row")


def _crosscheck_parser(sub) -> None:
    """``delaycomp crosscheck``: each FMU of the reference cases alone, cross-check layout."""
    x = sub.add_parser("crosscheck",
                       help="write each FMU of the reference cases alone in the FMI "
                            "cross-check layout")
    x.add_argument("--out", required=True, type=Path, metavar="DIR",
                   help="root of the tree (DIR/fmus/2.0/cs/linux64/delaycomp/<version>/...)")
    x.add_argument("--case", action=_Append, default=None, metavar="SCENARIO/CASE",
                   help="only this reference case (repeatable; default: all)")
    x.add_argument("--no-fmu", action="store_true",
                   help="write the CSV, option and README files only (no .fmu)")
    x.add_argument("--fmu-dir", type=Path, default=None,
                   help="folder of built FMUs (default: a per-version cache, built on demand)")


def _export_loop_parser(sub) -> None:
    """``delaycomp export-loop``: a loop as one container FMU."""
    e = sub.add_parser("export-loop",
                       help="assemble a scenario's or a loop file's loop into one container "
                            "FMU")
    e.add_argument("scenario", help=SCENARIO_HELP + " or LOOP.toml")
    _common(e)
    e.add_argument("--out", required=True, type=Path, metavar="FILE.fmu",
                   help="the container FMU to write")
    _fmu_kind(e, "the container holds the native C FMUs, an error where the loop has "
                 "none (the default holds them where it can)")
    e.add_argument("--fmi", type=int, choices=(2, 3), default=2,
                   help="the FMI version of the container FMU and of delaycomp's FMUs inside "
                        "it (default 2); 3: an FMI 3.0 container of the FMI 3.0 native FMUs, "
                        "built with the loop's values (a loop's own FMU goes in as it is); "
                        "docs: reference/fmi3")


def _export_c_parser(sub) -> None:
    """``delaycomp export-c``: a loop's controller as plain C."""
    c = sub.add_parser("export-c",
                       help="write a loop's controller as plain C for an embedded target "
                            "(NAME.h, NAME.c: C99, no heap, no I/O, no global state)",
                       description="The controller of a scenario's or a loop file's loop "
                                   "as DIR/NAME.h and DIR/NAME.c: NAME_init, NAME_sample "
                                   "(the measurement of each sample instant), NAME_output "
                                   "(the control at each base time); the loop's values are "
                                   "constants. See docs/howto/microcontroller.md.")
    c.add_argument("scenario", help=SCENARIO_HELP + " or LOOP.toml")
    c.add_argument("--set", action=_Append, default=[], metavar="NAME=VALUE",
                   help="set a scenario parameter or a loop file's key (repeatable)")
    c.add_argument("--allow-unstable", action="store_true",
                   help="LOOP.toml: let an LTI gain through with which the delay-free sampled "
                        "loop is unstable (the sign guard; docs: reference/loop-files)")
    c.add_argument("--prefix", required=True, metavar="NAME",
                   help="the C prefix of the files and of every exported name")
    c.add_argument("--out", required=True, type=Path, metavar="DIR",
                   help="the folder to write NAME.h and NAME.c into (created)")


def _ssp_parser(sub) -> None:
    """``delaycomp ssp``: SSP descriptions, or one packed ``.ssp``."""
    p_ssp = sub.add_parser("ssp", help="write SSP descriptions (SSD + SSV) or pack one .ssp")
    p_ssp.add_argument("scenario", nargs="?", default=None,
                       help="pack this scenario or LOOP.toml into --out FILE.ssp (default: "
                            "write the SSD and SSVs of every scenario at its defaults into "
                            "--out DIR/<scenario>/)")
    _common(p_ssp)
    p_ssp.add_argument("--jacobi", action="store_true",
                       help="pack the Jacobi variant, for libcosim and Ecos (docs: reference/ssp)")
    _fmu_kind(p_ssp, "pack the native C FMUs, an error where the loop has none (the "
                     "default packs them where it can)")
    _fmi_flag(p_ssp, "pack FMI 3.0 FMUs (native C only), each with the loop's values as start "
                     "values; the SSD and parameter sets stay SSP 1.0")
    p_ssp.add_argument("--out", type=Path, required=True, metavar="DIR|FILE.ssp",
                       help="a FILE.ssp for one scenario, else a folder for all of them")


def _fmu_kind(p: argparse.ArgumentParser, native_help: str) -> None:
    """``--native`` / ``--python``: which FMUs a command builds, runs or packs. Neither:
    the native C FMUs wherever the loop has them here (LTI loops, model files that
    translate, a C compiler), the Python FMUs otherwise, with a note saying why."""
    kind = p.add_mutually_exclusive_group()
    kind.add_argument("--native", action="store_true", help=native_help)
    kind.add_argument("--python", action="store_true",
                      help="the Python FMUs (pythonfmu: the host needs Python; docs: "
                           "reference/native) instead of the native default")


def _fmi_flag(p: argparse.ArgumentParser, what: str) -> None:
    """``--fmi {2,3}``: the FMI version of delaycomp's FMUs (docs: reference/fmi3), and
    ``--clocked``: with 3, the controller driven by a clock."""
    p.add_argument("--fmi", type=int, choices=(2, 3), default=2,
                   help=f"the FMI version of delaycomp's FMUs (default 2); 3: {what}; "
                        "docs: reference/fmi3")
    p.add_argument("--clocked", action="store_true",
                   help="with --fmi 3: the LTI controller's clocked variant, whose sampling "
                        "an FMI 3.0 clock of interval T drives (the host schedules its ticks "
                        "in event mode); docs: reference/fmi3")


def _fmi_of(args) -> int:
    """The ``--fmi`` of a command, checked against ``--python``."""
    fmi = getattr(args, "fmi", 2)
    if fmi == 3 and getattr(args, "python", False):
        raise UsageError("--fmi 3 is not allowed with --python: delaycomp's FMI 3.0 FMUs are "
                         "the native C ones")
    if getattr(args, "clocked", False) and fmi != 3:
        raise UsageError("--clocked is not allowed without --fmi 3: the clocked controller "
                         "is an FMI 3.0 FMU")
    return fmi


def _chosen_fmus(args, loop) -> dict | None:
    """The FMUs a command uses for ``loop`` (``_fmu_kind``): native ones, or ``None`` for
    the Python FMUs of the build cache."""
    if args.fmu_dir is not None and args.fmu_dir.exists() and not args.fmu_dir.is_dir():
        raise BadFileError(args.fmu_dir, "is not a folder (--fmu-dir wants a folder of FMUs)")
    from delaycomp.api import choose_fmus
    from delaycomp.progress import info

    kind = "python" if args.python else "native" if args.native else "auto"
    try:
        fmus, why = choose_fmus(loop, kind, args.fmu_dir, fmi=_fmi_of(args),
                                clocked=getattr(args, "clocked", False))
    except ValueError as exc:  # --native for a loop without native twins
        raise UsageError(str(exc)) from None
    if why:
        info(f"note: the Python FMUs run this loop (no native ones here: {why}); "
             "--python says so and skips the attempt", args.verbosity)
    return fmus


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--set", action=_Append, default=[], metavar="NAME=VALUE",
                   help="set a scenario parameter or a loop file's key (repeatable)")
    p.add_argument("--allow-unstable", action="store_true",
                   help="LOOP.toml: let an LTI gain through with which the delay-free sampled "
                        "loop is unstable (the sign guard; docs: reference/loop-files)")
    p.add_argument("--fmu-dir", type=Path, default=None,
                   help="folder of built FMUs (default: a per-version cache, built on "
                        "demand): the FMUs that delaycomp build --out DIR wrote there run, "
                        "native or Python, missing ones are built into it; a stale one or "
                        "one of the wrong kind is an error naming it")


def _source(args):
    """The scenario or loop file named on the command line, and its ``--set`` list (with
    ``--allow-unstable`` as the loop file's key)."""
    source = scenarios.open_source(args.scenario)
    sets = list(args.set)
    if getattr(args, "allow_unstable", False) and str(args.scenario).endswith(".toml"):
        sets.append("controller.allow_unstable=true")
    return source, sets


def _loop(args):
    source, sets = _source(args)
    return source, sets, source.loop(sets)


def _cmd_build_loop(args) -> int:
    """``build LOOP.toml``: the loop's FMUs with its values as start values, and its
    wiring sheet (``delaycomp.api.build``)."""
    from delaycomp.progress import info

    if args.model is not None:
        raise UsageError("--model is not allowed with LOOP.toml (a loop file names its "
                         "model itself: [plant] model = \"FILE.py\")")
    if str(args.loop).endswith(".ssp"):
        raise UsageError(f"{args.loop}: build takes a loop file or a scenario name, not an "
                         "SSP archive (its FMUs are inside it)")
    _, _, loop = _loop(argparse.Namespace(scenario=args.loop, set=args.set,
                                          allow_unstable=args.allow_unstable))
    from delaycomp.api import build  # the arguments and the loop are checked

    kind = "python" if args.python else "native" if args.native else "auto"
    built = build(loop, args.out if args.out is not None else Path.cwd(),
                  only=args.only or None, fmus=kind,
                  info=lambda text: info(text, args.verbosity), fmi=_fmi_of(args),
                  clocked=args.clocked)
    for path in built.paths:
        print(path)
    return 0


def _cmd_build(args) -> int:
    from delaycomp.fmu.build import build_all, build_model
    from delaycomp.fmu.native import NativeBuildError, build_native, build_native_model
    from delaycomp.progress import info

    if args.loop is not None:
        return _cmd_build_loop(args)
    for flag, given in (("--only", args.only), ("--set", args.set),
                        ("--allow-unstable", args.allow_unstable)):
        if given:
            raise UsageError(f"{flag} is not allowed without LOOP.toml (delaycomp build "
                             f"LOOP.toml {flag} ...)")
    if args.out is None:
        raise UsageError("the following arguments are required: --out (or name a LOOP.toml "
                         "to build its FMUs)")

    def fallback(exc) -> None:
        info(f"note: building the Python FMUs (no native ones here: "
             f"{str(exc).splitlines()[0]}); --python says so and skips the attempt",
             args.verbosity)

    paths: list[Path] | None = None
    fmi = _fmi_of(args)
    if args.native or fmi == 3:
        # no compiler: one line naming what to install; a model that does not translate:
        # one line naming the function, the operation and the line
        if args.model and args.clocked:
            raise UsageError("--clocked is not allowed with --model: the clocked controller "
                             "is the LTI controller's variant")
        paths = build_native_model(args.model, args.out, fmi) if args.model else \
            build_native(args.out, fmi, args.clocked)
    elif args.model:
        from delaycomp.maths.model import load_model

        load_model(args.model)  # a bad model file is an error, not a reason to fall back
        if not args.python:
            try:
                paths = build_native_model(args.model, args.out)
            except (NativeBuildError, ModelError) as exc:
                fallback(exc)
        if paths is None:
            paths = build_model(args.model, args.out)
    else:
        from delaycomp.formats.ssp import pack_scenarios

        if not args.python:
            try:
                paths = build_native(args.out)  # packed below in place of the Python ones
            except NativeBuildError as exc:
                fallback(exc)
        native = paths is not None
        paths = paths if paths is not None else build_all(args.out)
        archives = pack_scenarios(args.out, args.out)
        if native:
            _native_archives(archives, args.verbosity)
        paths += archives
    for path in paths:
        print(path)
    return 0


def _native_archives(archives, verbosity: int) -> None:
    """Each archive of ``delaycomp build`` with its FMUs' native twins, where they exist
    here (a note names an archive that keeps Python FMUs, and why)."""
    from delaycomp.fmu.native import NativeBuildError, native_archive
    from delaycomp.progress import info

    for path in archives:
        try:
            native_archive(path, path)
        except (ValueError, NativeBuildError) as exc:
            Path(path).with_name(Path(path).name + ".part").unlink(missing_ok=True)
            info(f"note: {Path(path).name} holds the Python FMUs (no native ones here: "
                 f"{str(exc).splitlines()[0]})", verbosity)


def _cmd_ssp(args) -> int:
    if args.scenario is None:
        if args.set or args.jacobi or args.native or args.python or args.fmi == 3 or \
                args.clocked:
            raise UsageError("--set, --jacobi, --native, --python, --fmi and --clocked need a "
                             "scenario to pack")
        from delaycomp.formats import ssp
        for path in ssp.write_all(args.out):
            print(path.parent)
        return 0
    if args.out.suffix != ".ssp":
        raise UsageError(f"--out {args.out}: a packed scenario goes into a FILE.ssp")
    _outputs(args)
    _, _, loop = _loop(args)
    from delaycomp.api import to_ssp  # the arguments are checked: now the SSP writer (lxml)
    from delaycomp.fmu.native import NativeBuildError
    from delaycomp.progress import info
    from delaycomp.system.jacobi import CompensationError

    notes: list[str] = []
    kind = "python" if args.python else "native" if args.native else "auto"
    try:
        path = to_ssp(loop, args.out, jacobi=args.jacobi, fmu_dir=args.fmu_dir, fmus=kind,
                      notes=notes, fmi=_fmi_of(args), clocked=args.clocked)
    except CompensationError as exc:
        raise UsageError(str(exc)) from None
    except (ValueError, NativeBuildError) as exc:  # --native without native twins
        if not args.native:
            raise
        raise UsageError(str(exc).splitlines()[0]) from None
    for note in notes:
        info(f"note: {note}; --python says so and skips the attempt", args.verbosity)
    print(path)
    return 0


def _outputs(args) -> None:
    """Check ``--out`` and ``--plot`` before anything runs (a bad path: exit 2)."""
    from delaycomp.formats.outputs import check_output

    check_output(getattr(args, "out", None), "--out")
    check_output(getattr(args, "plot", None), "--plot", "plot")


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


def _cmd_run(args) -> int:
    from delaycomp.plotting import Marks, title_of_loop

    _outputs(args)
    if args.compare and not (args.plot or args.out):
        raise UsageError("--compare writes both runs: give --out FILE.csv (this run there, "
                         "the other mode's beside it as FILE.<mode>.csv) and/or --plot "
                         "FILE.png (both drawn)")
    if args.scenario.endswith(".ssp"):
        if args.native or args.python:
            flag = "--native" if args.native else "--python"
            raise UsageError(f"{flag} is not allowed with a FILE.ssp: the archive's FMUs run")
        return _run_ssp(args)
    if args.period is not None or args.steps is not None or args.role:
        raise UsageError("--period, --steps and --role apply to a FILE.ssp of another tool")
    if args.master != "delaycomp":
        raise UsageError("--master runs a FILE.ssp (pack one with `delaycomp ssp --jacobi`)")
    source, sets = _source(args)
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
        if args.native or args.fmi == 3:
            raise UsageError(f"{'--native' if args.native else '--fmi 3'} runs FMUs: "
                             "--engine inprocess is not allowed with it")
        fmus = None
        other_fmus = {}
    else:
        fmus = _chosen_fmus(args, loop)
        # the other mode with FMUs of the same kind (native where this run's are)
        quiet = argparse.Namespace(**{**vars(args), "verbosity": 0})  # its note said once
        other_fmus = {label: _chosen_fmus(quiet, other_loop)
                      for label, other_loop in others.items()}
    return _execute(args, loop, stop, source.name, title_of_loop(loop, args.compare),
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


def _execute(args, loop, stop: float, name: str, title: str, timing, units,
             label: str | None = None, others: dict | None = None, fmus=None,
             runner=None, other_fmus: dict | None = None) -> int:
    """Run ``loop`` (and, for ``--compare``, the ``others``, each with its
    ``other_fmus``) to ``stop`` with the CSV streamed to ``--out`` (an other run's to
    ``compare_path``) and decimated by ``--output-interval``; then plot and report.

    ``runner(stop)`` replaces our master (a third-party master: its rows come at the end
    and are decimated afterwards)."""
    from delaycomp.api import run
    from delaycomp.formats.outputs import CsvStream, check_budget, clear_previous, output_every
    from delaycomp.progress import bar, info

    def run_or_failed(loop, **options):
        try:
            return run(loop, stop, engine=args.engine, fmu_dir=args.fmu_dir, every=every,
                       watchdog=args.watchdog, **options)
        except SimulationFailed as exc:  # reported with its rows so far below
            return exc.result

    ticks = loop.timing.ticks(stop)
    every = output_every(args.output_interval, loop.T, loop.N)
    _undriven_note(loop, args.verbosity)
    keep = bool(args.plot)
    seconds, memory = check_budget(loop, ticks * (1 + len(others or {})),
                                   args.engine, every, keep)
    info(f"{name}: {ticks} base steps of h = {loop.h!r} s, a row every {every}; "
         f"estimated at least {seconds:.3g} s and {memory / 1e6:.3g} MB", args.verbosity, 2)
    other_paths = {other: compare_path(args.out, other) if args.out else None
                   for other in others or {}}
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
    if code == 0 and runs:
        for other_label, path in other_paths.items():
            if path is not None:
                print(f"{name}, {other_label}: {runs[other_label].row_count} rows in {path}")
    return code


def _foreign(args):
    """The ``delaycomp.formats.ssp.Foreign`` settings of ``--period``, ``--steps``, ``--role``
    (None when none is given)."""
    from delaycomp.formats.ssp import Foreign

    if args.period is None and args.steps is None and not args.role:
        return None
    if (args.period is None) != (args.steps is None):
        raise UsageError("--period and --steps go together (the master settings of an SSP "
                         "of another tool)")
    if args.period is not None and not (math.isfinite(args.period) and args.period > 0):
        raise UsageError(f"--period {args.period!r} is not allowed: must be a finite "
                         "number > 0")
    if args.steps is not None and args.steps < 1:
        raise UsageError(f"--steps {args.steps!r} is not allowed: must be a positive integer")
    if args.master != "delaycomp":
        raise UsageError("--period, --steps and --role run an SSP of another tool in our "
                         "master only (for libcosim and Ecos, pack a loop with `delaycomp "
                         "ssp --jacobi`)")
    roles = {}
    for item in args.role:
        name, sep, role = item.partition("=")
        if not sep or not name:
            raise UsageError(f"--role {short(item)}: expected NAME=ROLE")
        roles[name.strip()] = role.strip()
    return Foreign(args.period, args.steps, roles)


def _run_ssp(args) -> int:
    from delaycomp.formats.ssp import Archive, apply_sets
    from delaycomp.plotting import Marks, title_of_loop

    if args.engine != "fmu":
        raise UsageError("--engine inprocess runs a scenario by name; a FILE.ssp runs its "
                         "FMUs")
    if args.compare:
        raise UsageError("--compare runs a scenario or a loop file (a FILE.ssp: run it "
                         "twice, with --set controller.mode=compensated and "
                         "=uncompensated)")
    with Archive(Path(args.scenario), _foreign(args)) as archive:
        system = archive.system
        assert system is not None  # read by Archive.__enter__
        spec = apply_sets(system.spec, args.set, archive.fmus())
        stop = system.info.stop_time if args.stop_time is None else args.stop_time
        if stop is None:
            raise UsageError(f"{Path(args.scenario).name} has no stop time: give --stop-time")
        runner = None
        if args.master != "delaycomp":
            if args.set:
                raise UsageError("--set applies to our master only (libcosim, Ecos and "
                                 "OMSimulator take "
                                 "the parameters packed in the SSP)")
            from delaycomp.verify.check import PROVIDERS

            absent = PROVIDERS.masters[args.master].unavailable()
            if absent is not None:
                raise UsageError(f"--master {args.master}: {absent}")

            _tolerance_note(args, spec)

            def runner(stop, master=args.master, path=args.scenario):
                if master == "omsimulator":
                    from delaycomp.verify.omsimulator import run_ssp as run_oms

                    result = run_oms(path, stop)
                else:
                    from delaycomp.verify.thirdparty import run_ssp

                    result = run_ssp(master, path, stop)
                if not result.success:
                    raise RuntimeError(result.message)
                return result

        name = Path(args.scenario).name
        loop = spec.replace(name=name, title=system.info.description or system.info.name)
        return _execute(args, loop, stop, name, title_of_loop(loop), Marks.of_loop(loop),
                        None, fmus=archive.fmus(), runner=runner)


def _undriven_note(loop, verbosity: int) -> None:
    """The note (once, unless ``-q``) naming the inputs of a user's FMU that the loop does
    not drive, with the start values they keep
    (``delaycomp.system.plantfmu.undriven_notes``)."""
    from delaycomp.progress import info
    from delaycomp.system.plantfmu import undriven_notes

    for note in undriven_notes(loop):
        info(f"note: {note}", verbosity)


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


def _tolerance_note(args, spec) -> None:
    """Say that ``--master`` (libcosim, Ecos, OMSimulator) cannot hand an archive's plant
    tolerance to the plant FMU: SSP 1.0 has no component tolerance, libcosim's and Ecos's
    Python APIs take none, OMSimulator's Python API sets its own solvers' (measured: not a
    co-simulation FMU's; its command line's ``--tolerance`` does reach one)."""
    from delaycomp.progress import info
    from delaycomp.system import FmuFile

    plant = spec.by_role("plant")
    if (plant is not None and isinstance(plant.source, FmuFile)
            and plant.source.tolerance is not None):
        info(f"note: --master {args.master} cannot hand plant.tolerance = "
             f"{plant.source.tolerance!r} to the plant FMU (no component tolerance in SSP "
             "or its API): the FMU uses its own default", args.verbosity)


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
    last = ", ".join(f"{n} = {v:.6g}" for n, v in zip(result.names, result.data[-1]))
    print(f"{name}: {result.row_count} rows to t = {result.times[-1]:.6g} "
          f"in {elapsed:.2f} s; final {last}")
    return 0


def _cmd_sweep(args) -> int:
    """``delaycomp sweep``; SIGTERM and SIGHUP stop it as Ctrl-C does (the workers end
    with it, none is left behind)."""
    with _ending_signals():
        return _sweep(args)


def _sweep(args) -> int:
    from delaycomp.formats.outputs import clear_previous
    from delaycomp.progress import info
    from delaycomp.studies.axes import parse_grid, snap_axes

    _outputs(args)
    source, sets = _source(args)  # the loop, opened once: everything below is handed it
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
        _undriven_note(source.loop(sets), args.verbosity)
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


def _cmd_robustness(args) -> int:
    """``delaycomp robustness``; SIGTERM and SIGHUP stop it as Ctrl-C does."""
    with _ending_signals():
        return _robustness(args)


def _robustness(args) -> int:
    from delaycomp.formats.outputs import clear_previous
    from delaycomp.progress import bar
    from delaycomp.studies import robustness as rb
    from delaycomp.studies.axes import parse_grid

    _outputs(args)
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
    source, sets = _source(args)
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


def _cmd_critical_delay(args) -> int:
    _outputs(args)
    scenario, sets = _source(args)
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


def _cmd_check(args) -> int:
    from delaycomp.verify import cases as refs
    try:  # the cases first: a bad one is refused before the masters (fmpy, ...) load
        if args.loop is not None:
            if args.case:
                raise KeyError("--case and LOOP.toml exclude each other")
            cases = [refs.loop_case(args.loop, args.set)]
        elif args.set:
            raise KeyError("--set applies to a LOOP.toml")
        else:
            cases = [refs.case(c) for c in args.case] if args.case else list(refs.CASES)
        from delaycomp.verify import check
        if args.master:
            for name in args.master:
                if name not in check.PROVIDERS.masters:
                    raise KeyError(f"unknown master {short(name)}: allowed are "
                                   f"{', '.join(check.PROVIDERS.masters)}")
    except KeyError as exc:
        raise UsageError(exc.args[0]) from None
    rows = check.run_checks(cases, args.master, require_all=args.require_all)
    print(check.format_table(rows))
    failed = sum(r.passed is False for r in rows)
    skipped = [r for r in rows if r.passed is None]
    for r in skipped:
        print(f"{r.master}: {r.note}; not counted as a failure (name it with --master, or "
              "give --require-all, to require it)")
    passed = sum(r.passed is True for r in rows)
    tail = f", {len(skipped)} skipped" if skipped else ""
    print(f"{passed} passed, {failed} failed{tail}")
    return 1 if failed else 0


def _cmd_crosscheck(args) -> int:
    from delaycomp.verify import check, crosscheck
    try:
        cases = [check.case(c) for c in args.case] if args.case else list(check.CASES)
    except KeyError as exc:
        raise UsageError(exc.args[0]) from None
    if args.out.exists() and not args.out.is_dir():
        raise UsageError(f"--out {short(str(args.out))} is not a folder")
    made = crosscheck.generate(args.out, cases, args.fmu_dir, with_fmus=not args.no_fmu)
    print(f"wrote {len(made)} cross-check models under {crosscheck.models_dir(args.out)}")
    return 0


def _cmd_export_loop(args) -> int:
    if args.out.suffix != ".fmu":
        raise UsageError(f"--out {short(str(args.out))} is not allowed: must end in .fmu")
    fmi = _fmi_of(args)
    _outputs(args)
    _, _, loop = _loop(args)
    from delaycomp.verify.container import export_loop  # the arguments and the loop are read

    fmus = _chosen_fmus(args, loop) if fmi == 2 else None  # 3: built with the loop's values
    _undriven_note(loop, args.verbosity)
    path = export_loop(loop, args.out, args.fmu_dir, fmus, fmi=fmi)
    print(path)
    return 0


def _cmd_export_c(args) -> int:
    from delaycomp.formats.exportc import check_prefix

    check_prefix(args.prefix)  # before the loop: the cheaper refusal first
    if str(args.scenario).endswith(".ssp"):
        raise UsageError(f"{args.scenario}: export-c takes a loop file or a scenario name, "
                         "not an SSP archive")
    _, _, loop = _loop(args)
    from delaycomp.api import export_c

    for path in export_c(loop, args.out, args.prefix):
        print(path)
    return 0


#: width of ``delaycomp list`` (it fits a 100-column terminal)
LIST_WIDTH = 100


def _cmd_list(args) -> int:
    import textwrap

    indent = " " * 30
    for number, sc in enumerate(scenarios.SCENARIOS.values()):
        if number:
            print()
        shown = sc.listing()  # the shipped files as TOML holds them: no numpy
        print(textwrap.fill(f"{sc.name}: {shown.title} (stop time {shown.stop_time:g} s)",
                            LIST_WIDTH, subsequent_indent="  "))
        print(f"    {'NAME':<9} {'DEFAULT':<15} MEANING; ALLOWED VALUES")
        for p in shown.params:
            if isinstance(p.default, tuple):
                default = ",".join(f"{v:g}" for v in p.default)
            elif p.default is None:  # derived from other parameters
                default = {"r_true": "(= r)", "tau_true": "(= tau)"}.get(p.name,
                                                                        "(depends on n)")
            elif isinstance(p.default, float):
                default = f"{p.default:g}"
            else:
                default = str(p.default)
            head = f"    {p.name:<9} {default:<15} "
            if len(head) > len(indent):  # a long default: the text on the next line
                print(head.rstrip())
                head = indent
            # an equation ("h = T/N", "u = -k x") stays on one line: its spaces are held by
            # a placeholder while the text is wrapped
            text = f"{p.help}; {p.allowed}".replace(" = ", "\0=\0")
            print(textwrap.fill(text, LIST_WIDTH, initial_indent=head,
                                subsequent_indent=indent,
                                break_on_hyphens=False).replace("\0", " "))
    return 0


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
    SIGTERM or SIGHUP during a sweep, give ``128 + signal``: ``_stopped``; a failure
    that follows a Ctrl-C, code that caught the interrupt as an error, is reported as the
    interrupt)."""
    command = None
    with _interrupt_watch() as interrupted:
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
            handler = {"build": _cmd_build, "run": _cmd_run, "sweep": _cmd_sweep,
                       "robustness": _cmd_robustness,
                       "critical-delay": _cmd_critical_delay, "check": _cmd_check,
                       "crosscheck": _cmd_crosscheck, "export-loop": _cmd_export_loop,
                       "export-c": _cmd_export_c,
                       "ssp": _cmd_ssp, "list": _cmd_list}[args.command]
            if getattr(args, "platforms", None) is not None:
                from delaycomp.fmu.toolchain import chosen

                with chosen(args.platforms):
                    rc = handler(args)
            else:
                rc = handler(args)
            if interrupted and rc != 0:  # a failure that Ctrl-C caused
                return _stopped(KeyboardInterrupt(), command)
            _platform_notes(args)
            return rc
        except (UsageError, ParameterError, ModelError, BadFileError, SspError) as exc:
            if interrupted:
                return _stopped(KeyboardInterrupt(), command)
            print(f"delaycomp: error: {exc}", file=sys.stderr)
            return 2
        except (KeyboardInterrupt, Terminated) as exc:
            return _stopped(exc, command)
        except BrokenPipeError:  # `delaycomp list | head`: the reader left; stop quietly
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
            return 141  # as a shell reports a process ended by SIGPIPE
        except (OSError, RuntimeError, ValueError) as exc:
            if interrupted:
                return _stopped(KeyboardInterrupt(), command)
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


if __name__ == "__main__":  # pragma: no cover
    entry()

