"""The FMU state a Python slave hands its host: a pinned token, its state kept here.

pythonfmu 0.7's ``fmi2FreeFMUstate`` drops one reference to the object the host got and
never clears the host's pointer, so a state freed twice would be freed twice in the host
(point 8 of ``delaycomp.fmu.slave``). ``StateHandle`` gives ``TableSlave`` tokens whose
pins absorb the extra frees and whose data is dropped once the host has let go.
"""

from __future__ import annotations

import ctypes
import sys
from typing import ClassVar

from delaycomp.errors import ParameterError


class StateHandle:
    """What ``fmi2GetFMUstate`` hands the host: a pinned token for a state kept here.

    See point 8 of ``delaycomp.fmu.slave``'s docstring. The token is a fresh ``int``
    object (ints hold no references, so the garbage collector never examines them: pins
    that were lists or objects pointing back at the token made the collector crash once a
    double free left the count below the references it can see). pythonfmu frees a state
    by dropping one reference to the token; ``PINS`` references held here absorb further
    frees. A token that only its pins and the registry hold was freed by the host: its
    data is dropped at the next ``new``.
    """

    PINS = 32
    #: id(token) -> (token, pins, state)
    _registry: ClassVar[dict[int, tuple[int, list, dict]]] = {}
    _serial = 0
    #: references a token has with no owner: its pins, the registry tuple, and the
    #: argument and loop variable of ``_sweep`` (measured by ``sys.getrefcount``)
    _UNOWNED = PINS + 1 + 2

    @classmethod
    def new(cls, state: dict) -> int:
        """A new pinned token for ``state`` (the data of states the host freed dropped
        first)."""
        cls._sweep()
        cls._serial += 1
        token = (1 << 62) + cls._serial  # computed: a new int object, never a cached one
        pins = [token] * cls.PINS
        _never_freed(pins)
        cls._registry[id(token)] = (token, pins, state)
        return token

    @classmethod
    def _sweep(cls) -> None:
        for key, entry in list(cls._registry.items()):
            token = entry[0]
            del entry
            if sys.getrefcount(token) <= cls._UNOWNED:
                del cls._registry[key]  # its pins stay: point 8 of delaycomp.fmu.slave

    @classmethod
    def data_of(cls, token) -> dict:
        """The state of ``token``; ``ParameterError`` for a freed token or one not ours."""
        entry = cls._registry.get(id(token))
        if entry is None or entry[0] is not token:
            raise ParameterError("FMU state is not allowed: it was freed "
                                 "(fmi2FreeFMUstate) or was not made by this FMU")
        return entry[2]


def _never_freed(pins: list) -> None:
    """Hold one reference to ``pins`` that nothing drops, not even the interpreter's
    teardown: a pin list is never freed, so a token the host freed more than once never
    reaches zero. Pins in a module variable would be freed by the teardown: a token freed
    twice by the host would then reach zero one pin early, and freeing the rest would read
    and write the freed token (valgrind: "Invalid read of size 8 ...
    list_dealloc", 0 bytes inside a block of 40 freed by the same ``list_dealloc``)."""
    ctypes.pythonapi.Py_IncRef(ctypes.py_object(pins))
