"""The commands that write files for other tools: ``build`` (a loop's FMUs, or every
kind's and each scenario's SSP), ``ssp`` (SSP descriptions, a packed archive),
``export-loop`` (a loop as one container FMU) and ``export-c`` (a controller as plain C)."""

from __future__ import annotations

import argparse
from pathlib import Path

from delaycomp.cli.arguments import check_outputs, chosen_fmus, fmi_of, loop_of
from delaycomp.cli.execute import undriven_note
from delaycomp.cli.parsers import UsageError
from delaycomp.errors import short
from delaycomp.maths.model import ModelError


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
    _, _, loop = loop_of(argparse.Namespace(scenario=args.loop, set=args.set,
                                            allow_unstable=args.allow_unstable))
    from delaycomp.api import build  # the arguments and the loop are checked

    kind = "python" if args.python else "native" if args.native else "auto"
    built = build(loop, args.out if args.out is not None else Path.cwd(),
                  only=args.only or None, fmus=kind,
                  info=lambda text: info(text, args.verbosity), fmi=fmi_of(args),
                  clocked=args.clocked)
    for path in built.paths:
        print(path)
    return 0


def cmd_build(args) -> int:
    """``delaycomp build``: a loop's FMUs (``build LOOP.toml``), or every kind's FMUs
    (or a model file's, ``--model``) and each scenario's SSP into ``--out``."""
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
    fmi = fmi_of(args)
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


def cmd_ssp(args) -> int:
    """``delaycomp ssp``: a scenario or loop file packed into ``--out FILE.ssp``; without
    one, the SSD and parameter sets of every scenario at its defaults under ``--out``."""
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
    check_outputs(args)
    _, _, loop = loop_of(args)
    from delaycomp.api import to_ssp  # the arguments are checked: now the SSP writer (lxml)
    from delaycomp.fmu.native import NativeBuildError
    from delaycomp.progress import info
    from delaycomp.system.jacobi import CompensationError

    notes: list[str] = []
    kind = "python" if args.python else "native" if args.native else "auto"
    try:
        path = to_ssp(loop, args.out, jacobi=args.jacobi, fmu_dir=args.fmu_dir, fmus=kind,
                      notes=notes, fmi=fmi_of(args), clocked=args.clocked)
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


def cmd_export_loop(args) -> int:
    """``delaycomp export-loop``: the loop as one container FMU, ``--out FILE.fmu``."""
    if args.out.suffix != ".fmu":
        raise UsageError(f"--out {short(str(args.out))} is not allowed: must end in .fmu")
    fmi = fmi_of(args)
    check_outputs(args)
    _, _, loop = loop_of(args)
    from delaycomp.verify.container import export_loop  # the arguments and the loop are read

    fmus = chosen_fmus(args, loop) if fmi == 2 else None  # 3: built with the loop's values
    undriven_note(loop, args.verbosity)
    path = export_loop(loop, args.out, args.fmu_dir, fmus, fmi=fmi)
    print(path)
    return 0


def cmd_export_c(args) -> int:
    """``delaycomp export-c``: the loop's controller as ``NAME.h`` and ``NAME.c``
    (``delaycomp.api.export_c``)."""
    from delaycomp.formats.exportc import check_prefix

    check_prefix(args.prefix)  # before the loop: the cheaper refusal first
    if str(args.scenario).endswith(".ssp"):
        raise UsageError(f"{args.scenario}: export-c takes a loop file or a scenario name, "
                         "not an SSP archive")
    _, _, loop = loop_of(args)
    from delaycomp.api import export_c

    for path in export_c(loop, args.out, args.prefix):
        print(path)
    return 0
