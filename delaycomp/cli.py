"""delaycomp: predictor-based delay compensation for sampled-data loops, as FMUs.

Examples
--------
Build the FMUs (plant, transport delay, predictor-controller)::

    delaycomp build --out build/fmus

Reproduce Figure 3 of Karafyllis & Krstic (compensated, r = 0.3, u0 = 4)::

    delaycomp run example-3.6 --set r=0.3 --set u0=4 --out fig3.csv --plot fig3.png

Run a packed SSP (``delaycomp build`` writes one per scenario) in the same master, with an
FMU parameter changed (``instance.parameter=value``)::

    delaycomp run build/fmus/example-3.6.ssp --set controller.mode=uncompensated

The critical measurement delay of the uncompensated loop (k = 2, T = 1)::

    delaycomp critical-delay example-3.6

Each FMU of the reference cases alone, in the FMI cross-check layout::

    delaycomp crosscheck --out crosscheck

The whole loop of Example 3.6 as one container FMU::

    delaycomp export-loop example-3.6 --set r=0.3 --out loop.fmu

List the scenarios and their parameters::

    delaycomp list
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path

from . import __version__, scenarios
from .errors import BadFileError
from .model import ModelError
from .scenarios import ParameterError
from .ssp import SspError

#: suffix of the CSV of a failed run (rows up to the failure): never read as a result
PARTIAL_SUFFIX = ".partial"


class UsageError(Exception):
    """Bad command-line input: reported as one line, exit status 2."""


class _Parser(argparse.ArgumentParser):
    def error(self, message: str):  # one line, no usage dump, exit 2
        raise UsageError(message)


def _parser() -> argparse.ArgumentParser:
    p = _Parser(prog="delaycomp", description=__doc__,
                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--version", action="version", version=f"delaycomp {__version__}")
    sub = p.add_subparsers(dest="command", required=True, parser_class=_Parser)

    b = sub.add_parser("build", help="build the FMUs and each scenario's SSP into a folder")
    b.add_argument("--out", required=True, type=Path, help="output folder")
    b.add_argument("--model", type=Path, default=None, metavar="FILE.py",
                   help="build plant, controller and delay FMUs for this model module "
                        "(see README: the model interface)")

    r = sub.add_parser("run", help="co-simulate a scenario, a loop file or an SSP file")
    r.add_argument("scenario", help="a scenario name, a LOOP.toml (then --set takes the "
                                    "file's keys: r=0.4, plant.x0=1,0, controller.K=...), "
                                    "or FILE.ssp (then --set takes instance.parameter=value)")
    _common(r)
    r.add_argument("--stop-time", type=float, default=None, metavar="S",
                   help="stop time in seconds (default: the scenario's)")
    r.add_argument("--out", type=Path, default=None, metavar="FILE.csv",
                   help="write one row per base step")
    r.add_argument("--plot", type=Path, default=None, metavar="FILE.png")
    r.add_argument("--engine", choices=("fmu", "inprocess"), default="fmu",
                   help="fmu: the built FMUs through fmpy (default); inprocess: the same "
                        "slaves called directly, same numbers, several times faster")
    r.add_argument("--master", choices=("delaycomp", "libcosim", "ecos"), default="delaycomp",
                   help="FILE.ssp only: the co-simulation master (default: ours; libcosim "
                        "and Ecos need the Jacobi variant, `delaycomp ssp --jacobi`)")
    r.add_argument("--period", type=float, default=None, metavar="T",
                   help="FILE.ssp of another tool (no delaycomp annotations): the sampling "
                        "period T [s]")
    r.add_argument("--steps", type=int, default=None, metavar="N",
                   help="FILE.ssp of another tool: base steps per period (h = T/N)")
    r.add_argument("--role", action="append", default=[], metavar="NAME=ROLE",
                   help="FILE.ssp of another tool: the role of component NAME (plant, "
                        "meas_delay, controller, input_delay); repeatable; roles not named "
                        "follow from the connections, walking the loop from the plant")

    c = sub.add_parser("critical-delay",
                       help="largest measurement delay for which the uncompensated loop "
                            "is stable")
    c.add_argument("scenario", help="an LTI scenario name or LOOP.toml")
    _common(c)
    c.add_argument("--periods", type=int, default=40,
                   help="periods of each confirming co-simulation (default 40)")
    c.add_argument("--grid", default=None, metavar="NAME=START:STOP:COUNT",
                   help="r_c as a function of one parameter (T, k, ...): a table, no "
                        "co-simulation")
    c.add_argument("--out", type=Path, default=None, metavar="FILE.csv")
    c.add_argument("--plot", type=Path, default=None, metavar="FILE.png")

    s = sub.add_parser("sweep", help="run a scenario or a loop file over a parameter grid")
    s.add_argument("scenario", help="a scenario name or LOOP.toml")
    _common(s)
    s.add_argument("--grid", action="append", required=True, metavar="NAME=START:STOP:COUNT",
                   help="a swept parameter (repeatable)")
    s.add_argument("--stop-time", type=float, default=None, metavar="S")
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
    s.add_argument("--out", type=Path, required=True, metavar="FILE.csv")
    s.add_argument("--plot", type=Path, default=None, metavar="FILE.png")

    k = sub.add_parser("check", help="cross-check every reference case in every master")
    k.add_argument("loop", nargs="?", default=None, metavar="LOOP.toml",
                   help="check this loop file against the reference CSV it names "
                        "([reference] csv = ...) instead of the built-in cases")
    k.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                   help="with LOOP.toml: override one of its keys (repeatable)")
    k.add_argument("--master", action="append", default=None, metavar="NAME",
                   help="only this master (repeatable; default: all)")
    k.add_argument("--case", action="append", default=None, metavar="SCENARIO/CASE",
                   help="only this reference case (repeatable; default: all)")
    k.add_argument("--require-all", action="store_true",
                   help="an optional master that is not installed is a failure (CI), not "
                        "a skipped row")

    x = sub.add_parser("crosscheck",
                       help="write each FMU of the reference cases alone in the FMI "
                            "cross-check layout")
    x.add_argument("--out", required=True, type=Path, metavar="DIR",
                   help="root of the tree (DIR/fmus/2.0/cs/linux64/delaycomp/<version>/...)")
    x.add_argument("--case", action="append", default=None, metavar="SCENARIO/CASE",
                   help="only this reference case (repeatable; default: all)")
    x.add_argument("--no-fmu", action="store_true",
                   help="write the CSV, option and README files only (no .fmu)")
    x.add_argument("--fmu-dir", type=Path, default=None,
                   help="folder of built FMUs (default: a per-version cache, built on demand)")

    e = sub.add_parser("export-loop",
                       help="assemble a scenario's or a loop file's loop into one container "
                            "FMU")
    e.add_argument("scenario", help="a scenario name or LOOP.toml")
    _common(e)
    e.add_argument("--out", required=True, type=Path, metavar="FILE.fmu")

    p_ssp = sub.add_parser("ssp", help="write SSP descriptions (SSD + SSV) or pack one .ssp")
    p_ssp.add_argument("scenario", nargs="?", default=None,
                       help="pack this scenario or LOOP.toml into --out FILE.ssp (default: "
                            "write the SSD and SSVs of every scenario at its defaults into "
                            "--out DIR/<scenario>/)")
    _common(p_ssp)
    p_ssp.add_argument("--jacobi", action="store_true",
                       help="pack the Jacobi variant, for libcosim and Ecos (see README)")
    p_ssp.add_argument("--out", type=Path, required=True, metavar="DIR|FILE.ssp")

    sub.add_parser("list", help="list the scenarios and their parameters")
    return p


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                   help="set a scenario parameter or a loop file's key (repeatable)")
    p.add_argument("--allow-unstable", action="store_true",
                   help="LOOP.toml: let an LTI gain through with which the delay-free sampled "
                        "loop is unstable (the sign guard; see README: loop files)")
    p.add_argument("--fmu-dir", type=Path, default=None,
                   help="folder of built FMUs (default: a per-version cache, built on demand)")


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


def _cmd_build(args) -> int:
    from .build import build_all, build_model

    if args.model:
        paths = build_model(args.model, args.out)
    else:
        from .ssp import pack_scenarios

        paths = build_all(args.out)
        paths += pack_scenarios(args.out, args.out)
    for path in paths:
        print(path)
    return 0


def _cmd_ssp(args) -> int:
    from . import ssp

    if args.scenario is None:
        if args.set or args.jacobi:
            raise UsageError("--set and --jacobi need a scenario to pack")
        for path in ssp.write_all(args.out):
            print(path.parent)
        return 0
    if args.out.suffix != ".ssp":
        raise UsageError(f"--out {args.out}: a packed scenario goes into a FILE.ssp")
    _, _, loop = _loop(args)
    if args.jacobi:
        from .thirdparty import CompensationError, pack_jacobi

        try:
            print(pack_jacobi(loop, args.out, args.fmu_dir))
        except CompensationError as exc:
            raise UsageError(str(exc)) from None
        return 0
    print(ssp.pack(*ssp.loop_system(loop), args.out, args.fmu_dir))
    return 0


def _cmd_run(args) -> int:
    from .simulate import run_loop

    if args.scenario.endswith(".ssp"):
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
    started = time.perf_counter()
    result = run_loop(loop, stop, args.fmu_dir, engine=args.engine)
    elapsed = time.perf_counter() - started
    detail = _describe(params) if isinstance(params, dict) and not str(
        args.scenario).endswith(".toml") else " ".join(args.set)
    return _report_run(args, result, elapsed, source.name, f"{source.title}\n" + detail)


def _foreign(args):
    """The :class:`delaycomp.ssp.Foreign` settings of ``--period``, ``--steps``, ``--role``
    (None when none is given)."""
    from .ssp import Foreign

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
            raise UsageError(f"--role {item!r}: expected NAME=ROLE")
        roles[name.strip()] = role.strip()
    return Foreign(args.period, args.steps, roles)


def _run_ssp(args) -> int:
    from .simulate import run_loop, stop_ticks
    from .ssp import Archive, apply_sets

    if args.engine != "fmu":
        raise UsageError("--engine inprocess runs a scenario by name; a FILE.ssp runs its "
                         "FMUs")
    with Archive(Path(args.scenario), _foreign(args)) as archive:
        system = archive.system
        spec = apply_sets(system.spec, args.set, archive.fmus())
        stop = system.info.stop_time if args.stop_time is None else args.stop_time
        if stop is None:
            raise UsageError(f"{Path(args.scenario).name} has no stop time: give --stop-time")
        stop_ticks(stop, spec.T, spec.N)  # a bad stop time is a usage error
        started = time.perf_counter()
        if args.master == "delaycomp":
            result = run_loop(spec, stop, fmus=archive.fmus())
        else:
            if args.set:
                raise UsageError("--set applies to our master only (libcosim and Ecos take "
                                 "the parameters packed in the SSP)")
            from .check import PROVIDERS
            from .thirdparty import run_ssp

            absent = PROVIDERS.masters[args.master].unavailable()
            if absent is not None:
                raise UsageError(f"--master {args.master}: {absent}")
            result = run_ssp(args.master, args.scenario, stop)
            if not result.success:
                raise RuntimeError(result.message)
        elapsed = time.perf_counter() - started
    title = f"{system.info.description or system.info.name}\n" + " ".join(args.set)
    return _report_run(args, result, elapsed, Path(args.scenario).name, title)


def _report_run(args, result, elapsed: float, name: str, title: str) -> int:
    """Write the CSV and plot of a successful run; on failure nothing that looks like a
    result (no FILE.csv, no plot): the rows recorded before it go to FILE.csv.partial."""
    for note in result.notes:
        print(f"note: {note}")
    if not result.success:
        where = ""
        if args.out and len(result.times):
            partial = args.out.with_name(args.out.name + PARTIAL_SUFFIX)
            args.out.parent.mkdir(parents=True, exist_ok=True)
            result.write_csv(partial)
            where = (f"; {len(result.times)} rows to t = {result.times[-1]:.6g} kept in "
                     f"{partial}")
        print(f"delaycomp: error: {result.message}{where}", file=sys.stderr)
        return 1
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        result.write_csv(args.out)
    if args.plot:
        from .plotting import plot_result

        args.plot.parent.mkdir(parents=True, exist_ok=True)
        plot_result(result, args.plot, title)
    last = ", ".join(f"{n} = {v:.6g}" for n, v in zip(result.names, result.data[-1]))
    print(f"{name}: {len(result.times)} rows to t = {result.times[-1]:.6g} "
          f"in {elapsed:.2f} s; final {last}")
    return 0


def _describe(params: dict) -> str:
    """``k=v, ...`` for a plot title; parameters left to their derived default (``None``,
    such as ``r_true``) are omitted."""
    return ", ".join(f"{k}={v}" for k, v in params.items() if v is not None)


def _cmd_sweep(args) -> int:
    from . import sweep

    axes = [sweep.parse_grid(g) for g in args.grid]
    if args.plot and len(axes) > 2:
        raise UsageError("--plot draws one or two grid parameters")
    started = time.perf_counter()
    notes: list[str] = []
    source, sets = _source(args)
    rows = sweep.run_sweep(args.scenario, axes, sets, args.stop_time, args.engine,
                           args.workers, args.scheduler,
                           str(args.fmu_dir) if args.fmu_dir else None, args.exact,
                           args.array_backend, args.chunk, notes)
    for note in notes:
        print(note)
    sweep.write_csv(rows, [a.name for a in axes], args.out)
    if args.plot:
        from .critical import critical_curve

        curve = critical_curve(source, sets, [a.name for a in axes],
                               [a.values for a in axes])
        sweep.plot_sweep(rows, axes, args.plot, f"{args.scenario}: " + " ".join(args.set),
                         curve)
    stable = sum(r["stable"] for r in rows)
    print(f"{args.scenario}: {len(rows)} points in {time.perf_counter() - started:.1f} s, "
          f"{stable} stable; wrote {args.out}")
    return 0


def _cmd_critical_delay(args) -> int:
    from .critical import critical_delay_report, critical_delay_table

    scenario, sets = _source(args)
    if args.grid:
        rows = critical_delay_table(scenario, sets, args.grid, args.out, args.plot)
        for line in rows:
            print(line)
        return 0
    if args.periods < 10:
        raise UsageError(f"--periods {args.periods} is not allowed: must be an integer >= 10")
    report = critical_delay_report(scenario, sets, args.periods, args.fmu_dir)
    print(f"r_c = {report.r_c:.9f}")
    for line in report.lines:
        print(line)
    return 0 if report.confirmed else 1


def _cmd_check(args) -> int:
    from . import check

    try:
        if args.loop is not None:
            if args.case:
                raise KeyError("--case and LOOP.toml exclude each other")
            cases = [check.loop_case(args.loop, args.set)]
        elif args.set:
            raise KeyError("--set applies to a LOOP.toml")
        else:
            cases = [check.case(c) for c in args.case] if args.case else list(check.CASES)
        if args.master:
            for name in args.master:
                if name not in check.PROVIDERS.masters:
                    raise KeyError(f"unknown master {name!r}: allowed are "
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
    from . import check, crosscheck

    try:
        cases = [check.case(c) for c in args.case] if args.case else list(check.CASES)
    except KeyError as exc:
        raise UsageError(exc.args[0]) from None
    if args.out.exists() and not args.out.is_dir():
        raise UsageError(f"--out {str(args.out)!r} is not a folder")
    made = crosscheck.generate(args.out, cases, args.fmu_dir, with_fmus=not args.no_fmu)
    print(f"wrote {len(made)} cross-check models under {crosscheck.models_dir(args.out)}")
    return 0


def _cmd_export_loop(args) -> int:
    from .container import export_loop

    if args.out.suffix != ".fmu":
        raise UsageError(f"--out {str(args.out)!r} is not allowed: must end in .fmu")
    _, _, loop = _loop(args)
    path = export_loop(loop, args.out, args.fmu_dir)
    print(path)
    return 0


def _cmd_list(args) -> int:
    for sc in scenarios.SCENARIOS.values():
        print(f"{sc.name}: {sc.title} (stop time {sc.default_stop_time:g} s)")
        for p in sc.params:
            if isinstance(p.default, tuple):
                default = ",".join(f"{v:g}" for v in p.default)
            elif p.default is None:  # derived from other parameters
                default = {"r_true": "(= r)", "tau_true": "(= tau)"}.get(p.name,
                                                                        "(depends on n)")
            else:
                default = p.default
            print(f"    {p.name:<9} default {default!s:<12} {p.help}; {p.allowed}")
    return 0


def main(argv: list[str] | None = None) -> int:
    try:
        args = _parser().parse_args(argv)
        handler = {"build": _cmd_build, "run": _cmd_run, "sweep": _cmd_sweep,
                   "critical-delay": _cmd_critical_delay, "check": _cmd_check,
                   "crosscheck": _cmd_crosscheck, "export-loop": _cmd_export_loop,
                   "ssp": _cmd_ssp, "list": _cmd_list}[args.command]
        return handler(args)
    except (UsageError, ParameterError, ModelError, BadFileError, SspError) as exc:
        print(f"delaycomp: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("delaycomp: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # `delaycomp list | head`: the reader left; stop quietly
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141  # as a shell reports a process ended by SIGPIPE
    except (OSError, RuntimeError, ValueError) as exc:
        msg = str(exc).strip().splitlines()[-1] if str(exc).strip() else type(exc).__name__
        print(f"delaycomp: error: {msg}", file=sys.stderr)
        return 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

