"""The axes of a grid over a loop's parameters, written once for sweeps and the
critical-delay tables: ``NAME=START:STOP:COUNT`` (``parse_grid``), each value as a
person would write it (``format_value``), the delay axes snapped to the base grid
(``snap_axes``) and the grid's points (``points``). A grid refused as written is refused
before numpy is imported (``delaycomp sweep``'s argument errors stay light).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

from delaycomp.errors import ParameterError
from delaycomp.paper.scenarios import open_source

__all__ = ["GRID_BOUND", "Axis", "format_value", "parse_grid", "points", "snap_axes"]


@dataclass(frozen=True)
class Axis:
    """One axis of a grid: a parameter's name and its values, in order."""

    name: str
    values: tuple[float, ...]


def parse_grid(text: str) -> Axis:
    """``NAME=START:STOP:COUNT`` -> an axis of ``COUNT`` evenly spaced values."""
    name, sep, spec = text.partition("=")
    parts = spec.split(":")
    if not sep or not name or len(parts) != 3:
        raise ParameterError(f"--grid {text!r}: expected NAME=START:STOP:COUNT")
    try:
        start, stop = float(parts[0]), float(parts[1])
        count = int(parts[2])
    except ValueError:
        raise ParameterError(f"--grid {text!r}: START and STOP must be numbers, COUNT an "
                             "integer") from None
    if not (math.isfinite(start) and math.isfinite(stop)):
        raise ParameterError(f"--grid {text!r}: START and STOP must be finite")
    if not 1 <= count <= 100_000:
        raise ParameterError(f"--grid {text!r}: COUNT = {count} is not allowed: must be an "
                             "integer from 1 to 100000")
    import numpy as np

    # each value as a person would write it: 0.05, not linspace's 0.049999999999999996
    return Axis(name.strip(), tuple(_decimal(v) for v in np.linspace(start, stop, count)))


def _decimal(value: float) -> float:
    """The float of ``value``'s 15 significant digits (undoes linspace's round-off)."""
    return float(f"{float(value):.15g}")


def format_value(value: float) -> str:
    """``value`` with 15 significant digits, as a ``--set NAME=VALUE`` takes it."""
    return f"{value:.15g}"


#: parameters that must be whole multiples of the base step h = T/N
GRID_BOUND = ("r", "tau", "r_true", "tau_true")


def base_loop(scenario, sets: list[str]):
    """The loop of ``scenario`` with ``sets`` and ``r = 0`` (on every grid), or ``None``
    if that does not resolve."""
    source = open_source(scenario)
    for attempt in (["r=0", *sets], list(sets)):
        try:
            return source.loop(attempt)
        except (ParameterError, ValueError):
            continue
    return None


def snap_axes(scenario, axes: list[Axis], sets: list[str]) -> tuple[list[Axis], list[str]]:
    """Snap the values of delay axes (``r``, ``tau``, ``r_true``, ``tau_true``) to the
    nearest multiple of the base step ``h = T/N``; return the axes and one note per
    snapped axis (what moved, and by how much at most).

    ``h`` comes from ``--set`` or the scenario's defaults; when ``T`` or ``N`` is itself
    swept, ``h`` differs between points and nothing is snapped (an off-grid point is then
    refused by name, as before).

    Examples
    --------
    >>> axes, notes = snap_axes("example-3.6", [parse_grid("r=0:0.98:20")], [])
    >>> axes[0].values[:3]
    (0.0, 0.05, 0.1)
    >>> notes[0].split(";")[0]
    'r: 18 of 20 values snapped to the base grid h = T/N = 0.01'
    """
    names = {a.name for a in axes}
    if names & {"T", "N"}:
        return list(axes), []
    base = base_loop(scenario, sets)
    if base is None:
        return list(axes), []  # the point's own validation names what is wrong
    timing = {"T": base.T, "N": base.N}
    h = timing["T"] / timing["N"]
    out, notes = [], []
    for axis in axes:
        if axis.name not in GRID_BOUND:
            out.append(axis)
            continue
        snapped = tuple(_decimal(round(v / h) * h) if v >= 0 else v for v in axis.values)
        moved = [abs(a - b) for a, b in zip(axis.values, snapped) if a != b]
        if moved:
            distinct = len(set(snapped))
            notes.append(f"{axis.name}: {len(moved)} of {len(snapped)} values snapped to the "
                         f"base grid h = T/N = {format_value(h)}; largest move {max(moved):.3g}"
                         + (f"; {len(snapped) - distinct} duplicates" if distinct
                            < len(snapped) else ""))
        out.append(Axis(axis.name, snapped))
    return out, notes


def points(axes: list[Axis]) -> list[tuple[float, ...]]:
    """Every point of the grid, the last axis fastest."""
    return list(itertools.product(*(a.values for a in axes)))
