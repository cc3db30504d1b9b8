"""What a command takes from its parsed arguments: the scenario or loop file with its
overrides (``source_of``, ``loop_of``), the FMUs it runs (``chosen_fmus``), the FMI version
(``fmi_of``); its output paths checked before anything runs (``check_outputs``)."""

from __future__ import annotations

from delaycomp.cli.parsers import UsageError
from delaycomp.errors import BadFileError
from delaycomp.paper import scenarios  # light: no numpy until a loop is read


def fmi_of(args) -> int:
    """The ``--fmi`` of a command, checked against ``--python``."""
    fmi = getattr(args, "fmi", 2)
    if fmi == 3 and getattr(args, "python", False):
        raise UsageError("--fmi 3 is not allowed with --python: delaycomp's FMI 3.0 FMUs are "
                         "the native C ones")
    if getattr(args, "clocked", False) and fmi != 3:
        raise UsageError("--clocked is not allowed without --fmi 3: the clocked controller "
                         "is an FMI 3.0 FMU")
    return fmi


def chosen_fmus(args, loop) -> dict | None:
    """The FMUs a command uses for ``loop`` (``parsers._fmu_kind``): native ones, or ``None`` for
    the Python FMUs of the build cache."""
    if args.fmu_dir is not None and args.fmu_dir.exists() and not args.fmu_dir.is_dir():
        raise BadFileError(args.fmu_dir, "is not a folder (--fmu-dir wants a folder of FMUs)")
    from delaycomp.api import choose_fmus
    from delaycomp.progress import info

    kind = "python" if args.python else "native" if args.native else "auto"
    try:
        fmus, why = choose_fmus(loop, kind, args.fmu_dir, fmi=fmi_of(args),
                                clocked=getattr(args, "clocked", False))
    except ValueError as exc:  # --native for a loop without native twins
        raise UsageError(str(exc)) from None
    if why:
        info(f"note: the Python FMUs run this loop (no native ones here: {why}); "
             "--python says so and skips the attempt", args.verbosity)
    return fmus


def source_of(args):
    """The scenario or loop file named on the command line, and its ``--set`` list (with
    ``--allow-unstable`` as the loop file's key)."""
    source = scenarios.open_source(args.scenario)
    sets = list(args.set)
    if getattr(args, "allow_unstable", False) and str(args.scenario).endswith(".toml"):
        sets.append("controller.allow_unstable=true")
    return source, sets


def loop_of(args):
    """``source_of``'s source and ``--set`` list, and the loop they make."""
    source, sets = source_of(args)
    return source, sets, source.loop(sets)


def check_outputs(args) -> None:
    """Check ``--out`` and ``--plot`` before anything runs (a bad path: exit 2)."""
    from delaycomp.formats.outputs import check_output

    check_output(getattr(args, "out", None), "--out")
    check_output(getattr(args, "plot", None), "--plot", "plot")
