"""Child Python processes that run a module of this package, wherever they start.

``python -m delaycomp.X`` puts the working folder first on ``sys.path``: a folder that holds
a ``delaycomp/`` (a checkout, or a build's staging copy) would shadow the installed package.
``module_argv`` puts the folder that holds *this* process's ``delaycomp`` first instead,
so a child always runs the same code as its parent, from a wheel or an editable install.
"""

from __future__ import annotations

import sys
from pathlib import Path


def module_argv(module: str, *args: str) -> list[str]:
    """The argv of a child that runs ``module`` as ``__main__`` with ``args``.

    Examples
    --------
    >>> argv = module_argv("delaycomp.fmu.build", "{}")
    >>> argv[0] == sys.executable and argv[-1] == "{}"
    True
    """
    root = str(Path(__file__).resolve().parent.parent)  # the folder holding delaycomp/
    code = (f"import runpy, sys; sys.path.insert(0, {root!r}); "
            f"runpy.run_module({module!r}, run_name='__main__', alter_sys=True)")
    return [sys.executable, "-c", code, *args]


#: ``prctl`` option: the signal this process gets when its parent dies (linux/prctl.h)
PR_SET_PDEATHSIG = 1


def parent_death_signal(signum: int) -> bool:
    """Ask Linux to send ``signum`` to this process when its parent dies (a child that must
    not outlive it: a pool's worker, an FMU's own process); whether it took (another
    platform, a libc without ``prctl`` or a refusal is no error: ``False``)."""
    if not sys.platform.startswith("linux"):
        return False
    import ctypes

    try:
        prctl = ctypes.CDLL(None, use_errno=True).prctl
    except (OSError, AttributeError):
        return False
    prctl.argtypes = [ctypes.c_int, ctypes.c_ulong, ctypes.c_ulong, ctypes.c_ulong,
                      ctypes.c_ulong]
    prctl.restype = ctypes.c_int
    return prctl(PR_SET_PDEATHSIG, int(signum), 0, 0, 0) == 0
