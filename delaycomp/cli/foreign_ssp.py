"""``delaycomp run FILE.ssp``: a packed SSP archive, delaycomp's or another tool's
(``--period``, ``--steps``, ``--role`` say what its SSD does not), in our master or in
another one (``--master libcosim``, ``ecos``, ``omsimulator``)."""

from __future__ import annotations

import math
from pathlib import Path

from delaycomp.cli.execute import execute
from delaycomp.cli.parsers import UsageError
from delaycomp.cli.recipes import remember
from delaycomp.errors import short


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


def run_ssp(args) -> int:
    """``delaycomp run FILE.ssp``: the archive's FMUs in our master, or in ``--master``'s."""
    from delaycomp.formats.ssp import Archive, apply_sets
    from delaycomp.plotting import Marks, title_of_loop

    if args.engine != "fmu":
        raise UsageError("--engine inprocess runs a scenario by name; a FILE.ssp runs its "
                         "FMUs")
    if args.master != "delaycomp" and args.stepping != "auto":
        raise UsageError(f"--stepping chooses how our master steps: --master {args.master} "
                         "steps the archive itself")
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
        fmus = archive.fmus()

        def keep_recipe(result, shown):
            # only a loop whose every FMU is the archive's (no FMU from elsewhere, which
            # the key does not see): a later run of the same command replays it
            if all(inst.name in fmus for inst in loop.instances):
                remember(args, result, shown)

        return execute(args, loop, stop, name, title_of_loop(loop), Marks.of_loop(loop),
                       None, fmus=fmus, runner=runner, remember=keep_recipe)


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
