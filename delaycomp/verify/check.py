"""Cross-checks: every reference case, run by every master we support, against its trace.

The reference cases (``CASES``) are the paper's examples with the traces of
``reference/`` (independent computations, see ``reference/README.md``). A *provider* runs
some of them in one master (ours, a third-party one, one FMU alone, ...) and yields one
``CheckRow`` per case: the largest error against the reference and the tolerance it is
held to. ``delaycomp check`` prints them as a table and fails if any row fails.

Tolerances, from the maths:

- ``exact`` cases (zero-order hold): plant steps, predictors and the reference are exact
  flows, so the difference is round-off (measured <= 8.1e-12 where ``|u|`` reaches 50);
  ``|error| <= 1e-9 (1 + |ref|)`` leaves three decades and still catches a controller one
  base step late (an error of order 1e-2).
- ``first-order`` cases (continuous input): the reference is the paper's ideal continuous
  law, which FMI 2.0 realises with the control held over each base step ``h``, an
  ``O(h)`` perturbation; at ``N = 100`` the error must stay below 2 % of the signal range
  (measured 0.24 % at most) and it must halve when ``h`` halves (ratio in (1.8, 2.2)).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

import numpy as np

from delaycomp.verify.cases import (  # noqa: F401 - the cases are part of this module's interface
    CASES,
    EXACT_TOL,
    FIRST_ORDER_FRACTION,
    REFERENCE_DIR,
    CheckRow,
    Comparison,
    RefCase,
    case,
    compare,
    loop_case,
)

#: A provider runs cases in one master: ``provider(cases) -> rows``.
Provider = Callable[[Iterable[RefCase]], Iterable[CheckRow]]


@dataclass(frozen=True)
class Requirement:
    """What an optional master needs: importable ``modules`` and the command that installs
    them (``hint``)."""

    modules: tuple[str, ...]
    hint: str

    def missing(self) -> list[str]:
        """The modules of ``modules`` that cannot be imported here."""
        import importlib.util

        return [m for m in self.modules if importlib.util.find_spec(m) is None]


@dataclass(frozen=True)
class RegisteredMaster:
    """A registered master: its provider and, for an optional one, what it needs."""

    provider: Provider
    requires: Requirement | None = None

    def unavailable(self) -> str | None:
        """Why this master cannot run here (``"not installed: ..."``), else ``None``."""
        if self.requires is None:
            return None
        missing = self.requires.missing()
        if not missing:
            return None
        return f"not installed ({', '.join(missing)}): {self.requires.hint}"


@dataclass
class Registry:
    """Named masters, in the order their rows are printed."""

    masters: dict[str, RegisteredMaster] = field(default_factory=dict)

    def register(self, name: str, provider: Provider,
                 requires: Requirement | None = None) -> None:
        """Register a master by name: how it runs a case, and what it needs where it is optional."""
        self.masters[name] = RegisteredMaster(provider, requires)

    @property
    def providers(self) -> dict[str, Provider]:
        """Each registered master's provider, by name."""
        return {name: m.provider for name, m in self.masters.items()}


PROVIDERS = Registry()


def _run_ours(cases: Iterable[RefCase]) -> Iterable[CheckRow]:
    """Our master with the FMUs (from the build cache) against each reference."""
    from delaycomp.orchestrator.simulate import run_loop

    for c in cases:
        res = run_loop(c.loop(), c.stop_time())
        if not res.success:
            yield CheckRow(c.id, "delaycomp", float("inf"), "-", False, res.message)
            continue
        cmp = compare(c, res.names, res.times, res.data)
        yield CheckRow(c.id, "delaycomp", cmp.max_error, cmp.tolerance, cmp.passed)


PROVIDERS.register("delaycomp", _run_ours)


def _run_alone(cases: Iterable[RefCase]) -> Iterable[CheckRow]:
    """Each FMU alone against the ``_ref.csv`` of its cross-check model
    (``delaycomp.verify.crosscheck``)."""
    from delaycomp.verify.crosscheck import run_alone_cases

    return run_alone_cases(cases)


PROVIDERS.register("fmu-alone", _run_alone)


def _run_container(cases: Iterable[RefCase]) -> Iterable[CheckRow]:
    """The loop as one container FMU (``delaycomp.verify.container``), at ``t0 + iT``."""
    from delaycomp.verify.container import run_container_cases

    return run_container_cases(cases)


#: the extra that brings fmu-manipulation-toolbox
CONTAINER = Requirement(("fmu_manipulation_toolbox",),
                        "pip install 'delaycomp[container]'")
PROVIDERS.register("container", _run_container, CONTAINER)


#: native FMUs against the Python FMUs: ``max |native - python| <= NATIVE_RTOL * max |python|``
#: per signal; the maths is the same and only the rounding of the exponentials and of the
#: sums differs (measured <= 4e-14 on every LTI case)
NATIVE_RTOL = 1e-12


def _native_runs(cases: Iterable[RefCase], master: str, stepping: str,
                 second: Callable) -> Iterable[CheckRow]:
    """For each case whose loop has native FMUs, the native FMUs stepped by ``stepping``:
    the row ``master`` against the reference, then, where the run succeeded, the row
    ``second(case, loop, fmus, result)`` (its comparison with another run)."""
    from delaycomp.fmu.twins import native_fmus
    from delaycomp.orchestrator.simulate import run_loop

    for c in cases:
        spec = c.loop()
        try:
            fmus = native_fmus(spec)
        except ValueError:  # a user model's plant or controller: no native twin
            continue
        res = run_loop(spec, c.stop_time(), fmus=fmus, stepping=stepping)
        if not res.success:
            yield CheckRow(c.id, master, float("inf"), "-", False, res.message)
            continue
        cmp = compare(c, res.names, res.times, res.data)
        yield CheckRow(c.id, master, cmp.max_error, cmp.tolerance, cmp.passed)
        yield second(c, spec, fmus, res)


def _run_native(cases: Iterable[RefCase]) -> Iterable[CheckRow]:
    """The native C FMUs (``delaycomp.fmu.native``) in our Python master, for the cases
    whose loop has native FMUs (the LTI ones): one row against the reference, one against
    the Python FMUs (``native-vs-python``)."""
    from delaycomp.orchestrator.simulate import run_loop

    def against_python(c, spec, fmus, res) -> CheckRow:
        py = run_loop(spec, c.stop_time())
        if not py.success or py.names != res.names:
            return CheckRow(c.id, "native-vs-python", float("inf"), "-", False, py.message)
        peak = np.maximum(np.abs(py.data).max(axis=0), np.finfo(float).tiny)
        rel = float((np.abs(res.data - py.data) / peak).max())
        return CheckRow(c.id, "native-vs-python", rel,
                        f"{NATIVE_RTOL:g} x max abs(python) (relative)", rel <= NATIVE_RTOL)

    return _native_runs(cases, "native", "python", against_python)


def _run_native_core(cases: Iterable[RefCase]) -> Iterable[CheckRow]:
    """The native C FMUs stepped by the native core (``delaycomp.orchestrator.native_core``),
    for the cases whose loop has native FMUs: one row against the reference, one against
    the same FMUs in the Python master (``native-core-vs-master``), which must be the same
    rows bit for bit (the same binaries called with the same arguments in the same
    order: a difference of zero, not a tolerance)."""
    from delaycomp.orchestrator.simulate import run_loop

    def against_master(c, spec, fmus, res) -> CheckRow:
        py = run_loop(spec, c.stop_time(), fmus=fmus, stepping="python")
        if not py.success or py.names != res.names or py.data.shape != res.data.shape:
            return CheckRow(c.id, "native-core-vs-master", float("inf"), "-", False,
                            py.message)
        same = (res.times.tobytes() == py.times.tobytes()
                and res.data.tobytes() == py.data.tobytes())
        diff = float(np.abs(res.data - py.data).max(initial=0.0))
        return CheckRow(c.id, "native-core-vs-master", diff, "0 (bit for bit)", same)

    return _native_runs(cases, "native-core", "native-core", against_master)


@dataclass(frozen=True)
class CompilerRequirement(Requirement):
    """The native FMUs need a C compiler (``delaycomp.fmu.native.compiler``)."""

    modules: tuple[str, ...] = ()
    hint: str = "install a C compiler, e.g. `apt-get install gcc`, or set CC"

    def missing(self) -> list[str]:
        """What is missing for the native FMUs here (a C compiler), as lines; empty if nothing."""
        from delaycomp.fmu.native import NativeBuildError, compiler

        try:
            compiler()
        except NativeBuildError:
            return ["a C compiler"]
        return []


PROVIDERS.register("native", _run_native, CompilerRequirement())
PROVIDERS.register("native-core", _run_native_core, CompilerRequirement())


def _third_party(master: str) -> Provider:
    def run(cases: Iterable[RefCase]) -> Iterable[CheckRow]:
        from delaycomp.verify.thirdparty import provider

        return provider(master)(cases)

    return run


#: libcosim and Ecos run each case's Jacobi variant (see ``delaycomp.verify.thirdparty``)
PROVIDERS.register("libcosim", _third_party("libcosim"),
                   Requirement(("libcosimpy",), "pip install 'delaycomp[masters]'"))
PROVIDERS.register("ecos", _third_party("ecos"),
                   Requirement(("ecospy",), "pip install 'delaycomp[masters]'"))


@dataclass(frozen=True)
class _OMSimulatorRequirement(Requirement):
    """OMSimulator is found by ``$DELAYCOMP_OMSIMULATOR`` or as a package
    (``delaycomp.verify.omsimulator.locate``), not by a module name alone."""

    def missing(self) -> list[str]:
        from delaycomp.verify.omsimulator import missing

        return missing()


def _run_omsimulator(cases: Iterable[RefCase]) -> Iterable[CheckRow]:
    """Each case's plain archive in OMSimulator's Python API
    (``delaycomp.verify.omsimulator``)."""
    from delaycomp.verify.omsimulator import provider

    return provider(cases)


def _omsimulator_hint() -> str:
    from delaycomp.verify.omsimulator import INSTALL_HINT

    return INSTALL_HINT


PROVIDERS.register("omsimulator", _run_omsimulator,
                   _OMSimulatorRequirement(("OMSimulator",), _omsimulator_hint()))


def run_checks(cases: Iterable[RefCase] = CASES, masters: Iterable[str] | None = None,
               require_all: bool = False) -> list[CheckRow]:
    """Every master (or those named in ``masters``) over ``cases``.

    An optional master that is not installed gives one row with ``passed=None`` (not run,
    not a failure of the software) and the command that installs it; it is a failed row
    (``passed=False``) when it was named in ``masters`` or ``require_all`` is set.
    """
    cases = list(cases)
    names = list(PROVIDERS.masters) if masters is None else list(masters)
    rows: list[CheckRow] = []
    for name in names:
        if name not in PROVIDERS.masters:
            raise KeyError(f"unknown master {name!r}: allowed are "
                           f"{', '.join(PROVIDERS.masters)}")
        master = PROVIDERS.masters[name]
        absent = master.unavailable()
        if absent is not None:
            required = require_all or masters is not None
            rows.append(CheckRow("*", name, math.nan, "-", False if required else None,
                                 absent))
            continue
        try:
            rows.extend(master.provider(cases))
        except Exception as exc:  # noqa: BLE001 - a broken master is a failed row, not a crash
            rows.append(CheckRow("*", name, float("inf"), "-", False,
                                 f"{type(exc).__name__}: {exc}"))
    return rows


def format_table(rows: list[CheckRow]) -> str:
    """The rows as a Markdown table (scenario, master, largest error, tolerance, pass)."""
    lines = ["| case | master | largest error | tolerance | pass |",
             "|---|---|---|---|---|"]
    for r in rows:
        note = f" ({r.note})" if r.note else ""
        verdict = {True: "yes", False: "NO", None: "skipped"}[r.passed]
        error = "-" if math.isnan(r.max_error) else f"{r.max_error:.3g}"
        lines.append(f"| {r.case} | {r.master} | {error} | {r.tolerance} | {verdict}{note} |")
    return "\n".join(lines)
