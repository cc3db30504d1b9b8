"""The system model: the typed description of a closed loop (``.loop``), the loop file
that describes one in TOML (``.loopfile``, its values checked by ``.loopvalues``, its
network channels and time stamps ``.loopchannels``, a plant FMU's tables
``.loopplantfmu``) and the rewrites that work on roles (``.jacobi``). It stands on the
maths and ``delaycomp.maths.grid``, and imports nothing above it (no FMI, no master).

The names below are ``.loop``'s, imported on first use (PEP 562): importing the package,
or its light modules alone (``.loopkeys``: the keys of a loop file and their allowed values
in words, which ``delaycomp list`` prints), imports no numpy.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from delaycomp.system.loop import (
        ROLES,
        BuiltinFmu,
        Connection,
        FmuFile,
        Instance,
        Loop,
        LtiBatch,
        LtiDesign,
        LtiPoint,
        ModelFmu,
        Origin,
        Port,
        Role,
        Source,
        Timing,
        check_zoh_delay,
        design_loop,
        lti_design,
        lti_designs,
        lti_loop,
        model_loop,
    )

__all__ = ["ROLES", "BuiltinFmu", "Connection", "FmuFile", "Instance", "Loop", "LtiBatch",
           "LtiDesign", "LtiPoint", "ModelFmu", "Origin", "Port", "Role", "Source", "Timing",
           "check_zoh_delay", "design_loop", "lti_design", "lti_designs", "lti_loop", "model_loop"]


def __getattr__(name: str):
    """A name of ``__all__``, from ``delaycomp.system.loop`` (imported on first access)."""
    if name in __all__:
        return getattr(importlib.import_module("delaycomp.system.loop"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    """The module's names and ``__all__``."""
    return sorted({*globals(), *__all__})
