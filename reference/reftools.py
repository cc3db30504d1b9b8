"""What the reference scripts share: writing a trace and its settings, the ODE solve, the
split of a delay into periods, the command line.

It imports nothing from delaycomp, so the traces stay independent of what they check
(``tests/test_references.py``, ``tests/test_layers.py``): the standard library, and numpy
and scipy for the solve only. The scripts run as files (``python reference/<name>.py``),
so they import it by its bare name from their own folder.
"""

from __future__ import annotations

import csv
import math
import sys
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path


def split_delay(r: float, T: float) -> tuple[int, float]:
    """``q = [r/T]`` and ``r~ = r - qT``, robust when ``r/T`` is an integer up to round-off
    (``0.3 / 0.1``: ``q = 3``, ``r~ = 0``).

    >>> split_delay(0.3, 0.1)
    (3, 0.0)
    >>> split_delay(1.25, 1.0)
    (1, 0.25)
    """
    ratio = r / T
    q = round(ratio) if abs(ratio - round(ratio)) < 1e-12 else math.floor(ratio)
    rt = r - q * T
    return q, (0.0 if abs(rt) < 1e-12 * T else rt)


def solve(rhs, y0, t0: float, t1: float, rtol: float, atol: float | None = None,
          method: str = "DOP853", max_step: float = math.inf):
    """``y(t1)`` of ``y' = rhs(t, y)``, ``y(t0) = y0``: scipy's ``solve_ivp`` (DOP853 unless
    ``method`` says otherwise) at ``rtol`` and ``atol`` (default: ``rtol``); ``y0`` itself,
    as an array, where ``t1 <= t0``. A solve that fails raises ``RuntimeError`` with the
    solver's message."""
    import numpy as np
    from scipy.integrate import solve_ivp

    y0 = np.array(y0, dtype=float)
    if t1 <= t0:
        return y0
    sol = solve_ivp(rhs, (t0, t1), y0, method=method, rtol=rtol,
                    atol=rtol if atol is None else atol, max_step=max_step)
    if not sol.success:
        raise RuntimeError(sol.message)
    return sol.y[:, -1]


def write_trace(out: Path, name: str, header: Sequence[str], rows: Iterable[Sequence],
                stop: float, step: float, rel_tol: float, positive_zero: bool = False) -> Path:
    """``out/<name>_ref.csv`` (a quoted header, then each value as ``repr`` writes it, so it
    reads back exactly; ``positive_zero``: ``-0.0`` written as ``0.0``) and
    ``out/<name>_ref.opt`` (start, stop, step and the relative tolerance, the settings a
    checker reads beside the trace). Returns the CSV's path."""
    out.mkdir(parents=True, exist_ok=True)
    path = out / f"{name}_ref.csv"
    with open(path, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh, quoting=csv.QUOTE_MINIMAL)
        fh.write(",".join(f'"{h}"' for h in header) + "\n")
        for row in rows:
            w.writerow([repr(float(v) + 0.0) if positive_zero else repr(v) for v in row])
    (out / f"{name}_ref.opt").write_text(
        f"StartTime, 0.0\nStopTime, {stop!r}\nStepSize, {step!r}\nRelTol, {rel_tol!r}\n",
        encoding="utf-8")
    return path


def main(out: Path, cases: dict, write: Callable[[str, dict], None],
         modes: dict[str, Callable[[], None]] | None = None) -> None:
    """A script's command line: a flag of ``modes`` (``--check``: the script's own
    verification) runs that, else every case of ``cases`` is written by ``write``."""
    for flag, run in (modes or {}).items():
        if flag in sys.argv:
            run()
            return
    for case_name, case_args in cases.items():
        write(case_name, case_args)
        print(f"wrote {out / case_name}_ref.csv")
