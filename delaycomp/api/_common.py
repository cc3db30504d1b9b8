"""What the API's functions share: the forms a loop is given in (``LoopLike``), the one
reading of a loop with its overrides (``as_loop``, ``as_assignments``) and the checks of the
FMUs asked for (``fmu_kind``, ``fmi_version``)."""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from delaycomp.errors import ParameterError, short
from delaycomp.names import FMU_KINDS
from delaycomp.system import Loop

#: a loop, as every function of the API takes one: a ``Loop``, a loop file's path, or a
#: scenario's name
LoopLike = Loop | str | Path


def as_loop(source: LoopLike, sets: Sequence[str] | Mapping[str, object] = (),
            overrides: Mapping[str, object] | None = None) -> Loop:
    """The ``Loop`` of ``source`` with ``sets`` and ``overrides`` applied: the one
    reading of a loop for every function of the API (``open_source``:
    a ``Loop``, a loop file's path, a scenario's name; anything else is refused in
    one short line naming it)."""
    from delaycomp.paper.scenarios import open_source

    assignments = as_assignments(sets, overrides)
    if isinstance(source, Loop) and not assignments:
        return source
    return open_source(source).loop(assignments)


def as_assignments(sets: Sequence[str] | Mapping[str, object] = (),
                   overrides: Mapping[str, object] | None = None) -> list[str]:
    """``sets`` (``NAME=VALUE`` texts, or a mapping) and ``overrides`` (``section__key``
    names) as ``NAME=VALUE`` texts, as ``--set`` takes them."""
    if isinstance(sets, str):
        raise ParameterError(f"sets = {short(sets)} is not allowed: give a list of "
                             "NAME=VALUE texts or a mapping")
    items: list[str | tuple[str, object]] = [
        *(sets.items() if isinstance(sets, Mapping) else sets),
        *((k.replace("__", "."), v) for k, v in (overrides or {}).items())]
    return [item if isinstance(item, str) else f"{item[0]}={_text(item[1])}"
            for item in items]


def _text(value) -> str:
    """A Python value as ``--set`` reads it (numbers to the bit, lists as TOML arrays)."""
    if isinstance(value, (bool, np.bool_)):
        return "true" if value else "false"
    if isinstance(value, str):
        return value
    if isinstance(value, Mapping):
        return "{" + ", ".join(f"{json.dumps(str(k))} = {_text(v)}"
                               for k, v in value.items()) + "}"
    if isinstance(value, (int, float, np.number)):
        return repr(float(value))
    try:
        return json.dumps(np.asarray(value, dtype=float).tolist())
    except (TypeError, ValueError):
        return str(value)


#: which FMUs ``run`` and ``to_ssp`` use: the native C FMUs where the loop has
#: them here, else the Python ones (``auto``, the default, as the CLI); only native ones
#: (an error where there are none); only the Python ones


def fmu_kind(fmus: str) -> None:
    """``fmus`` checked: one of ``FMU_KINDS`` (``auto``, ``native``, ``python``)."""
    if fmus not in FMU_KINDS:
        raise ParameterError(f"fmus = {short(fmus)} is not allowed: must be one of "
                             f"{', '.join(FMU_KINDS)}")


def fmi_version(fmi, clocked=False) -> int:
    """``fmi`` checked (2 or 3), and ``clocked`` with it (a bool, true only with 3)."""
    if fmi not in (2, 3) or isinstance(fmi, bool):
        raise ParameterError(f"fmi = {short(fmi)} is not allowed: must be 2 or 3 (the FMI "
                             "version of delaycomp's FMUs)")
    if not isinstance(clocked, bool):
        raise ParameterError(f"clocked = {short(clocked)} is not allowed: must be true or "
                             "false")
    if clocked and fmi != 3:
        raise ParameterError("clocked = true is not allowed with fmi = 2: the clocked "
                             "controller is an FMI 3.0 FMU (fmi = 3)")
    return int(fmi)
