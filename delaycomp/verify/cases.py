"""Reference cases and how a run is compared with one: the bottom of verification.

A ``RefCase`` is a loop (a scenario with parameters, or a loop file) and the
reference trace it must reproduce; ``compare`` holds a recorded trajectory to it
pointwise. The runners (our master, each FMU alone, the container, third-party masters)
import this module, and ``delaycomp.verify.check`` imports the runners: no ring. Naming
a case (``case``, ``CASES``) imports no numpy: ``delaycomp check --case`` refuses an
unknown one at once.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import delaycomp.reference
from delaycomp.errors import BadFileError, ParameterError

if TYPE_CHECKING:
    import numpy as np

#: the reference traces: ``reference/`` of the repository, installed as package data of
#: ``delaycomp.reference``
REFERENCE_DIR = Path(delaycomp.reference.__file__).resolve().parent

#: zero-order-hold tolerance: ``|error| <= EXACT_TOL (1 + |ref|)``
EXACT_TOL = 1e-9
#: continuous input at N = 100: ``max |error| <= FIRST_ORDER_FRACTION * max |ref|``
FIRST_ORDER_FRACTION = 0.02


@dataclass(frozen=True)
class RefCase:
    """A scenario with its parameters and the reference trace it must reproduce."""

    scenario: str
    case: str
    sets: tuple[str, ...]
    #: ``exact`` (zero-order hold, round-off only) or ``first-order`` (continuous input)
    kind: str
    #: a loop file's path (``scenario`` is then its name), else the scenario runs
    loop_file: str | None = None
    #: the reference CSV (default: ``reference/<scenario>/<case>_ref.csv``)
    csv: str | None = None
    #: ``exact`` cases: ``|error| <= tolerance (1 + |ref|)``
    tolerance: float = 1e-9

    def loop(self):
        """The loop this case runs (``delaycomp.system.Loop``)."""
        if self.loop_file is not None:
            from delaycomp.system.loopfile import LoopFile

            return LoopFile(self.loop_file).loop(list(self.sets))
        from delaycomp.paper.scenarios import get

        return get(self.scenario).loop(list(self.sets))

    @property
    def id(self) -> str:
        """``scenario/case``, how the check's table names the case."""
        return f"{self.scenario}/{self.case}"

    @property
    def csv_path(self) -> Path:
        """The reference trace (``reference/<scenario>/<case>_ref.csv``, or the case's own file)."""
        if self.csv is not None:
            return Path(self.csv)
        return REFERENCE_DIR / self.scenario / f"{self.case}_ref.csv"

    @property
    def opt_path(self) -> Path:
        """The reference's settings file (start, stop, step, tolerance)."""
        return REFERENCE_DIR / self.scenario / f"{self.case}_ref.opt"

    def reference(self) -> tuple[list[str], np.ndarray]:
        """Header (``time`` first) and the rows of the reference trace."""
        import numpy as np

        if not self.csv_path.exists():
            raise FileNotFoundError(
                f"reference trace {self.csv_path} of {self.id} not found: the installed "
                "package is incomplete (reinstall delaycomp)")
        with open(self.csv_path, newline="", encoding="utf-8") as fh:
            rows = list(csv.reader(fh))
        return rows[0], np.array(rows[1:], dtype=float)

    def stop_time(self) -> float:
        """The time of the reference trace's last row."""
        return float(self.reference()[1][-1, 0])


CASES: tuple[RefCase, ...] = (
    RefCase("example-3.6", "fig1", ("r=0.1", "mode=uncompensated"), "exact"),
    RefCase("example-3.6", "fig2", ("r=0.3", "mode=uncompensated"), "exact"),
    RefCase("example-3.6", "fig3", ("r=0.3", "mode=compensated", "u0=4"), "exact"),
    RefCase("example-2.4", "default", (), "first-order"),
    RefCase("example-2.4", "sparse", ("T=2",), "first-order"),
    RefCase("example-3.8", "default", (), "exact"),
    RefCase("example-3.8", "delayed", ("tau=1", "r=1.5"), "exact"),
    RefCase("example-3.8", "sin", ("p=sin",), "exact"),
    RefCase("corollary-3.7", "default", (), "exact"),
    RefCase("corollary-3.7", "n2", ("n=2", "T=0.5", "r=0.75", "tau=0.5", "x0=1,-2", "u0=0.7"),
            "exact"),
    RefCase("corollary-4.1", "default", (), "first-order"),
    RefCase("proposition-4.2", "default", (), "exact"),
    RefCase("proposition-4.2", "nodelay_r", ("tau=0", "x0=-2,0.5,2.5"), "exact"),
)


def case(case_id: str) -> RefCase:
    """The case ``scenario/case``."""
    for c in CASES:
        if c.id == case_id:
            return c
    raise KeyError(f"no reference case {case_id!r}: allowed are "
                   f"{', '.join(c.id for c in CASES)}")


@dataclass(frozen=True)
class CheckRow:
    """One line of the cross-check table."""

    case: str
    master: str
    max_error: float
    #: what ``max_error`` is held to, as text (``1e-09 x (1 + abs(ref))``, ...)
    tolerance: str
    #: ``None``: not run (an optional master that is not installed and not required)
    passed: bool | None
    note: str = ""


@dataclass(frozen=True)
class Comparison:
    """One comparison with a reference: the largest error, the tolerance it was held to (as text)
    and whether it passed."""

    max_error: float
    tolerance: str
    passed: bool


def compare(c: RefCase, names: list[str], times: np.ndarray, data: np.ndarray,
            stride: int = 1, ref_stride: int = 1) -> Comparison:
    """Compare a recorded trajectory with the reference of ``c``, pointwise.

    ``names`` are the trajectory's columns (``plant.x``, ...), ``data[k, j]`` their values at
    ``times[k]``; every reference column must be present (none is skipped). ``stride`` takes
    every ``stride``-th row of the trajectory (a run at a finer base step), ``ref_stride``
    every ``ref_stride``-th row of the reference (a run sampled at ``t0 + iT``). For
    ``first-order`` cases only the N = 100 bound is checked here (the halving needs a
    second run at 2N: ``tests/test_scenarios.py`` and ``tests/test_native_model_controller.py``
    check that the error halves).
    """
    import numpy as np

    header, ref = c.reference()
    ref = ref[::ref_stride]
    missing = [n for n in header[1:] if n not in names]
    if missing:
        raise ValueError(f"{c.id}: the run has no column {', '.join(missing)}")
    cols = [names.index(n) for n in header[1:]]
    got = np.asarray(data, dtype=float)[::stride][:, cols]
    t = np.asarray(times, dtype=float)[::stride]
    if got.shape != ref[:, 1:].shape or not np.allclose(t, ref[:, 0], rtol=0, atol=1e-9):
        return Comparison(float("inf"), "same time grid as the reference", False)
    err = np.abs(got - ref[:, 1:])
    if not np.all(np.isfinite(err)):
        return Comparison(float("inf"), "finite", False)
    if c.kind == "exact":
        ratio = err / (1.0 + np.abs(ref[:, 1:]))
        return Comparison(float(err.max()), f"{c.tolerance:g} x (1 + abs(ref))",
                          bool(np.all(ratio <= c.tolerance)))
    bound = FIRST_ORDER_FRACTION * float(np.abs(ref[:, 1:]).max())
    return Comparison(float(err.max()), f"{bound:.3g} (2% of max abs(ref))",
                      bool(err.max() <= bound))




def loop_case(path: str | Path, sets: list[str] | tuple[str, ...] = ()) -> RefCase:
    """The reference case a loop file names in its ``[reference]`` table::

        [reference]
        csv = "ref.csv"       # column time, then columns named as the run's (plant.x1, ...)
        tolerance = 1e-9      # |error| <= tolerance (1 + |ref|); default 1e-9

    The CSV's path is relative to the loop file's folder.
    """
    from delaycomp.system.loopfile import LoopFile

    lf = LoopFile(path)
    ref = lf.data.get("reference")
    if not isinstance(ref, dict) or not isinstance(ref.get("csv"), str):
        raise ParameterError(f"{lf.path.name}: check needs [reference] csv = \"FILE.csv\" "
                             "(the trajectory to compare with)")
    from delaycomp.system.loopkeys import DEFAULTS, allowed

    keys = allowed("reference", "lti")
    unknown = [k for k in ref if k not in keys]
    if unknown:
        raise ParameterError(f"{lf.path.name} [reference]: unknown key {unknown[0]!r}: "
                             f"allowed are {', '.join(keys)}")
    tol = ref.get("tolerance", DEFAULTS["reference.tolerance"])
    if isinstance(tol, bool) or not isinstance(tol, (int, float)) or not (
            math.isfinite(tol) and tol > 0):
        raise ParameterError(f"reference.tolerance = {tol!r} is not allowed: must be a "
                             "finite number > 0")
    csv_path = Path(ref["csv"])
    if not csv_path.is_absolute():
        csv_path = lf.base / csv_path
    if not csv_path.is_file():
        raise BadFileError(csv_path, "no such reference CSV (named by reference.csv)")
    return RefCase(lf.name, "reference", tuple(sets), "exact", str(lf.path.resolve()),
                   str(csv_path), float(tol))
