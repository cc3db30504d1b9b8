"""The Jacobi variant of a loop: the same trajectory in a master that steps every
component and only then exchanges the outputs (libcosim, Ecos; see
``delaycomp.verify.thirdparty`` for the measurement of that latency).

A rewrite of the typed loop by roles, never by instance names:

- the **controller** samples the measurement held over the previous base step
  (``held_sample = true``), so its output no longer depends on its input at the same
  instant;
- the **measurement delay** is shortened by that one base step ``h``, so the held value is
  exactly ``x(t_i - r)``; it must keep at least one base step (``r >= 2 h``). A network
  channel there (``delaycomp.maths.channel``) is shortened packet by packet: its least
  ``delay``, each ``trace`` entry and a ``max_delay`` lose ``h``, so packet ``j`` is seen
  ``q_j - 1`` steps after it left instead of ``q_j`` (its loss draws and send steps are
  the same) and the held output is the original channel's at ``t_i``;
- a **delay with a zero delay** (pure feedthrough, which cannot be shortened) is bypassed:
  its input connection goes straight to its consumer. A channel with delay 0 is refused
  (its packets seen at once would arrive a step late, and its loss cannot be bypassed).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any, cast

from delaycomp.errors import DelaycompError
from delaycomp.maths import grid
from delaycomp.names import indexed
from delaycomp.system.loop import BuiltinFmu, Connection, Instance, Loop

#: base steps of latency a Jacobi master adds on a connection out of a direct-feedthrough
#: output (measured, see ``delaycomp.verify.thirdparty``)
JACOBI_LATENCY_STEPS = 1
DELAY_ROLES = ("meas_delay", "input_delay")


class CompensationError(DelaycompError, ValueError):
    """The loop cannot be made exact in a Jacobi master (one-line message)."""


def _delay_input_of(loop: Loop, name: str, output: str) -> str:
    """The input of delay instance ``name`` whose value its ``output`` carries."""
    key = cast(tuple, loop.instance(name).source.build_key())  # a delay: built by us
    n = int(key[1]["n"])
    return indexed("u", n)[indexed("y", n).index(output)]


def _is_channel(inst: Instance) -> bool:
    """Is ``inst`` a network channel (``delaycomp.maths.channel``, kind ``channel``)?"""
    return isinstance(inst.source, BuiltinFmu) and inst.source.kind == "channel"


def shifted_delay(params: Mapping[str, Any], shift: float) -> dict[str, Any]:
    """The parameters that change when a delay FMU's or a network channel's delay is
    lengthened by ``shift`` (shortened where ``shift < 0``): a delay's ``delay``; a
    channel's every packet's (its least ``delay``, so each drawn delay ``delay + X``, each
    ``trace[i]`` but the lost ones, ``-1``, and a ``max_delay`` given, ``> 0``).

    >>> shifted_delay({"delay": 0.3, "trace[1]": 0.5, "trace[2]": -1.0, "max_delay": 0.0},
    ...               0.25)
    {'delay': 0.55, 'trace[1]': 0.75}
    """
    out: dict[str, Any] = {"delay": float(params["delay"]) + shift}
    for key, value in params.items():
        if (key.startswith("trace[") and float(value) >= 0) or (
                key == "max_delay" and float(value) > 0):
            out[key] = float(value) + shift
    return out


def jacobi_variant(loop: Loop) -> Loop:
    """The loop for a Jacobi master: same total delays, same trajectory (module docstring).

    Examples
    --------
    >>> from delaycomp.system import lti_loop
    >>> loop = lti_loop([[1.0]], [[1.0]], [[-2.0]], 1.0, 0.3, 0.0, 100, "compensated",
    ...                 [1.0], [0.0])
    >>> variant = jacobi_variant(loop)
    >>> variant.by_role("meas_delay").parameters["delay"], variant.by_role("input_delay")
    (0.29, None)
    >>> variant.by_role("controller").parameters["held_sample"]
    True
    """
    h = loop.h
    lat = JACOBI_LATENCY_STEPS * h
    meas = loop.by_role("meas_delay")
    ctrl = loop.by_role("controller")
    if ctrl is None or meas is None:
        raise CompensationError("a Jacobi variant needs a controller fed by a measurement "
                                "delay")
    delay = float(meas.parameters["delay"])
    if delay < 2 * lat and not math.isclose(delay, 2 * lat, rel_tol=grid.GRID_RTOL):
        raise CompensationError(
            f"{meas.name}: delay {delay!r} < 2 h = {2 * lat!r}: in a Jacobi master "
            f"{ctrl.name} samples the measurement one base step late, so {meas.name} is "
            "shortened by h and must keep at least one base step (without it the "
            "controller would read the plant, whose output these masters take before "
            "initialization); use r >= 2 T/N")
    changed: dict[str, dict[str, Any]] = {meas.name: shifted_delay(meas.parameters, -lat),
                                          ctrl.name: {"held_sample": True}}
    instances = [i.with_parameters(**changed[i.name]) if i.name in changed else i
                 for i in loop.instances]
    for inst in instances:
        if (_is_channel(inst) and inst.role in DELAY_ROLES
                and grid.nearest_multiple(float(inst.parameters["delay"]), h) == 0):
            raise CompensationError(
                f"{inst.name}: a channel with delay 0 is not allowed in a Jacobi master: a "
                "packet seen in the step it is sent would reach its consumer one base step "
                "late there (a channel cannot be bypassed as a zero delay is); use delay >= "
                "T/N")
    bypass = {i.name for i in instances if i.role in DELAY_ROLES and not _is_channel(i)
              and grid.nearest_multiple(float(i.parameters["delay"]), h) == 0}
    labelled = {p for p, _ in loop.labels}
    if any(p.instance in bypass and p not in labelled for p in loop.recorded):
        raise CompensationError("a recorded signal belongs to a delay that is bypassed")
    # a plant FMU's input column (a labelled delay output) of a bypassed delay is its
    # source's signal, recorded already: it is left out of the variant
    recorded = tuple(p for p in loop.recorded if p.instance not in bypass)
    labels = tuple((p, n) for p, n in loop.labels if p.instance not in bypass)
    connections = []
    for con in loop.connections:
        if con.dst.instance in bypass:
            continue
        src = con.src
        while src.instance in bypass:  # follow the bypassed delay back to its own source
            port = _delay_input_of(loop, src.instance, src.variable)
            src = next(c.src for c in loop.connections
                       if c.dst.instance == src.instance and c.dst.variable == port)
        connections.append(Connection(src, con.dst))
    return loop.replace(instances=tuple(i for i in instances if i.name not in bypass),
                        connections=tuple(connections), recorded=recorded, labels=labels)
