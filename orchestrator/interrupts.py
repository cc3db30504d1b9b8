"""Ctrl-C held over a block of FMI calls (``interrupt_held``): light, for the master and
for a replayed run (``delaycomp.orchestrator.replay``), which imports neither numpy nor
fmpy."""

from __future__ import annotations

import contextlib

__all__ = ["interrupt_held"]


@contextlib.contextmanager
def interrupt_held():
    """SIGINT while the block runs is held, and raised once it ends (the previous handler
    called: Python's, or the command line's, raises KeyboardInterrupt): for the FMI calls
    in which a Python FMU runs code of its runtime that an interrupt breaks (pythonfmu's
    instantiation: a KeyboardInterrupt there crashed the process, SIGSEGV) and for the
    teardown of a run, which frees every component before the interrupt goes on. In the
    main thread only, where a handler of Python code is installed.

    >>> with interrupt_held():
    ...     pass
    """
    import signal
    import threading

    previous = (signal.getsignal(signal.SIGINT)
                if threading.current_thread() is threading.main_thread() else None)
    if not callable(previous):
        yield
        return
    held: list = []
    signal.signal(signal.SIGINT, lambda signum, frame: held.append(frame))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
        if held:
            previous(signal.SIGINT, held[0])
