"""Ctrl-C, SIGTERM and SIGHUP on the command line: ``Terminated`` (SIGTERM or SIGHUP
during a sweep, raised as Ctrl-C is), the handlers a sweep installs (``ending_signals``),
the watch that tells a failure Ctrl-C caused (``interrupt_watch``) and the one line and
exit status of an interrupted command (``stopped``)."""

from __future__ import annotations

import contextlib
import sys


class Terminated(KeyboardInterrupt):
    """SIGTERM or SIGHUP (the terminal closing) during a sweep (``ending_signals``),
    raised in the main thread as Ctrl-C raises ``KeyboardInterrupt`` (an interrupt, not an
    error: whatever handles Ctrl-C handles it): the sweep stops the same way, its worker
    processes ended (``delaycomp.studies.pool.on_processes``), and ``main``
    reports it in one line, with exit status ``128 + signum``."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = signum


def _raise_terminated(signum, frame):
    raise Terminated(signum)


@contextlib.contextmanager
def ending_signals():
    """SIGTERM and SIGHUP raise ``Terminated`` while the block runs, where they have
    their default action (under ``nohup`` SIGHUP stays ignored) and in the main thread only
    (where Python runs signal handlers); the previous handlers come back afterwards."""
    import signal
    import threading

    saved = {}
    if threading.current_thread() is threading.main_thread():
        for name in ("SIGTERM", "SIGHUP"):  # no SIGHUP on Windows
            signum = getattr(signal, name, None)
            if signum is not None and signal.getsignal(signum) is signal.SIG_DFL:
                saved[signum] = signal.signal(signum, _raise_terminated)
    try:
        yield
    finally:
        for signum, handler in saved.items():
            signal.signal(signum, handler)


#: the commands that run many co-simulations (a grid, the reference cases in every master),
#: whose interrupt names no one time
MANY_RUNS = ("sweep", "check", "crosscheck", "robustness")


@contextlib.contextmanager
def interrupt_watch():
    """A list that gets an entry when SIGINT arrives while the command runs (Python's
    handler then raises KeyboardInterrupt as before), in the main thread only. Code that
    catches every exception (an FMU's slave, a build step, a check) may turn Ctrl-C into
    its own failure; ``main`` reports such a failure as the interrupt it was."""
    import signal
    import threading

    seen: list[bool] = []
    if (threading.current_thread() is not threading.main_thread()
            or signal.getsignal(signal.SIGINT) is not signal.default_int_handler):
        yield seen
        return

    def handler(signum, frame):
        seen.append(True)
        signal.default_int_handler(signum, frame)

    signal.signal(signal.SIGINT, handler)
    try:
        yield seen
    finally:
        signal.signal(signal.SIGINT, signal.default_int_handler)


def stopped(exc: KeyboardInterrupt | Terminated, command: str | None = None) -> int:
    """Ctrl-C, SIGTERM or SIGHUP: one line on standard error, and the exit status a shell
    gives a process that the signal ended, ``128 + signum`` (130 for Ctrl-C). Ctrl-C
    during a co-simulation (``Interrupted``) names the simulation
    time reached, ``delaycomp: interrupted at t = 12.34``; elsewhere (a sweep's many
    runs, a build, an analysis) ``delaycomp: interrupted``."""
    import signal

    from delaycomp.errors import Interrupted

    if isinstance(exc, Terminated):
        signum, line = exc.signum, f"terminated ({signal.Signals(exc.signum).name})"
    elif isinstance(exc, Interrupted) and command not in MANY_RUNS:
        signum, line = signal.SIGINT, f"interrupted at t = {exc.time:.10g}"
    else:
        signum, line = signal.SIGINT, "interrupted"
    with contextlib.suppress(OSError):  # the terminal may be gone (SIGHUP)
        print(f"delaycomp: {line}", file=sys.stderr, flush=True)
    return 128 + int(signum)
