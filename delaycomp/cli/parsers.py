"""The command line's parsers: one function per subcommand adds its arguments (the
``delaycomp`` parser itself is ``delaycomp.cli._parser``), with the options several share
(``--set``, ``--fmu-dir``, ``--native``/``--python``, ``--fmi``, ``--platforms``);
``UsageError``, the bad input they and the commands refuse (exit status 2)."""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from delaycomp.errors import DelaycompError, short
from delaycomp.names import LOOP_GROUPS


class UsageError(DelaycompError):
    """Bad command-line input: reported as one line, exit status 2."""


class Parser(argparse.ArgumentParser):
    """The parser of ``delaycomp`` and of each subcommand: bad input raises
    ``UsageError``."""

    def error(self, message: str):
        """Bad input as ``UsageError``: one line, no usage dump, exit status 2."""
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


def build_parser(sub) -> None:
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


def run_parser(sub) -> None:
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
    r.add_argument("--stepping", choices=("auto", "native-core", "python"), default="auto",
                   help="what steps a loop of FMUs: auto (default): the native stepping "
                        "core, in C, where every FMU is a native one (the same calls, the "
                        "same rows bit for bit, without Python between them), else the "
                        "Python master (-v says which, and why); native-core: the core, "
                        "an error where it cannot; python: the Python master. A second "
                        "run FILE.ssp of the same command (auto, native-core) is replayed "
                        "from the recipe its first run kept, without numpy or fmpy (the "
                        "same rows; docs: reference/native)")
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


def critical_delay_parser(sub) -> None:
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


def sweep_parser(sub) -> None:
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


def robustness_parser(sub) -> None:
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


def check_parser(sub) -> None:
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


def crosscheck_parser(sub) -> None:
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


def export_loop_parser(sub) -> None:
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


def export_c_parser(sub) -> None:
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


def ssp_parser(sub) -> None:
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
