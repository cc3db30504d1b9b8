"""The commands that check delaycomp against references: ``check`` (every reference case,
or a loop file's own reference, in every master) and ``crosscheck`` (each FMU of the
reference cases alone, in the FMI cross-check layout)."""

from __future__ import annotations

from delaycomp.cli.parsers import UsageError
from delaycomp.errors import short


def cmd_check(args) -> int:
    """``delaycomp check``: the reference cases (or a loop file's reference CSV) in every
    master, one row each; exit status 1 when one fails."""
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


def cmd_crosscheck(args) -> int:
    """``delaycomp crosscheck``: each FMU of the reference cases alone, in the FMI
    cross-check layout under ``--out``."""
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
