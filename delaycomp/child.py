"""Child Python processes that run a module of this package, wherever they start.

``python -m delaycomp.X`` puts the working folder first on ``sys.path``: a folder that holds
a ``delaycomp/`` (a checkout, or a build's staging copy) would shadow the installed package.
:func:`module_argv` puts the folder that holds *this* process's ``delaycomp`` first instead,
so a child always runs the same code as its parent, from a wheel or an editable install.
Worker processes started by :mod:`multiprocessing` (spawn) inherit the parent's
``sys.path``, where a Python FMU run in this process has put its resources folder (and the
``delaycomp`` it bundles, the maths only) first: :func:`own_package_first` puts this
process's package before it while they start.
"""

from __future__ import annotations

import contextlib
import sys
from collections.abc import Iterator
from pathlib import Path

import delaycomp


def module_argv(module: str, *args: str) -> list[str]:
    """The argv of a child that runs ``module`` as ``__main__`` with ``args``.

    Examples
    --------
    >>> argv = module_argv("delaycomp.fmu.build", "{}")
    >>> argv[0] == sys.executable and argv[-1] == "{}"
    True
    """
    root = _root()
    code = (f"import runpy, sys; sys.path.insert(0, {root!r}); "
            f"runpy.run_module({module!r}, run_name='__main__', alter_sys=True)")
    return [sys.executable, "-c", code, *args]


def _root() -> str:
    """The folder that holds this process's ``delaycomp``."""
    return str(Path(delaycomp.__file__).resolve().parent.parent)


@contextlib.contextmanager
def own_package_first() -> Iterator[None]:
    """``sys.path`` with the folder of this process's ``delaycomp`` first, for the duration:
    processes spawned inside (they copy ``sys.path``) import the same package as this one.

    Examples
    --------
    >>> with own_package_first():
    ...     sys.path[0] == _root()
    True
    """
    saved = list(sys.path)
    sys.path.insert(0, _root())
    try:
        yield
    finally:
        sys.path[:] = saved
