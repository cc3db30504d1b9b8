"""Progress bars and verbosity of the command line (tqdm, on standard error).

A bar shows when standard error is a terminal of any kind (a console, or a pseudo-terminal:
``script``, an editor's terminal, ``ssh -t``; one that reports no size gets
``DEFAULT_COLUMNS`` columns) and never with ``-q``; ``--progress`` shows it whatever
standard error is (a file, a pipe, with ``-q`` too), ``--no-progress`` never
(``choose``). When standard error is redirected nothing but the results reach the
files, and standard output carries results only, whatever the verbosity.
"""

from __future__ import annotations

import os
import sys

#: ``-q``: errors only; default: progress on a terminal and notes; ``-v``: also details
QUIET, NORMAL, VERBOSE = 0, 1, 2


class NoBar:
    """What ``bar`` returns when no bar shows: counts, draws nothing, imports nothing.

    >>> with NoBar(10) as b:
    ...     b.update(4)
    >>> b.n, b.total
    (4, 10)
    """

    def __init__(self, total: int):
        self.total, self.n = total, 0

    def update(self, count: int = 1) -> None:
        """Count ``count`` more steps (nothing is shown)."""
        self.n += count

    def close(self) -> None:
        """Nothing to close."""
        pass

    def __enter__(self) -> NoBar:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


#: the width of a bar on a terminal that reports no size (a pty whose size was never set,
#: as ``script`` gives without a terminal of its own) and off a terminal (``--progress``)
DEFAULT_COLUMNS = 80
#: its height in rows (tqdm hides a bar beyond the terminal's last row)
DEFAULT_ROWS = 24

#: ``--progress`` (True), ``--no-progress`` (False), neither (None): ``choose``
_chosen: bool | None = None
#: the command's verbosity (``choose``), for the details told from deep inside (FMU
#: builds, cache hits: ``detail``); a library caller's default says nothing
_verbosity = NORMAL


def choose(shown: bool | None, verbosity: int = NORMAL) -> None:
    """Bars on (``True``: ``--progress``, even off a terminal and with ``-q``), off
    (``False``: ``--no-progress``) or as the terminal and the verbosity say (``None``);
    ``verbosity``: the command's, for ``detail``. The command line sets both for one
    command and puts them back (``None``, ``NORMAL``) when it ends."""
    global _chosen, _verbosity
    _chosen, _verbosity = shown, verbosity


def detail(message: str) -> None:
    """Print ``message`` to standard error under ``-v`` (``choose``), else nothing:
    what the code deep inside does that no caller hands a verbosity to (an FMU built, one
    found in the build cache).

    >>> detail("cache hit: DelaycompDelay (/tmp/x.fmu)")  # no -v: nothing
    """
    if _verbosity >= VERBOSE:
        print(message, file=sys.stderr, flush=True)


def _terminal(stream) -> bool:
    try:
        return stream.isatty()
    except (AttributeError, ValueError):  # no such method, or a closed stream
        return False


def _columns(stream) -> int:
    """The width of ``stream``'s terminal, or 0 where it has none or reports none."""
    try:
        return os.get_terminal_size(stream.fileno()).columns
    except (AttributeError, OSError, ValueError):
        return 0


def shows(verbosity: int = NORMAL) -> bool:
    """Whether ``bar`` draws a bar: ``--progress``/``--no-progress`` where given, else
    not with ``-q`` and only when standard error is a terminal (any kind: a pty too)."""
    if _chosen is not None:
        return _chosen
    return verbosity > QUIET and _terminal(sys.stderr)


def bar(total: int, desc: str, verbosity: int = NORMAL, unit: str = "it"):
    """A tqdm bar on standard error with an estimate of the time left.

    Where no bar shows (``shows``), a ``NoBar`` instead: tqdm (30 ms to import)
    is loaded only for a bar that shows. A terminal that reports its width gets a bar
    that follows it; one that reports none (a pty of ``script``, of size 0 x 0, where
    tqdm's own sizing hid the bar), or a file, ``DEFAULT_COLUMNS`` (or ``$COLUMNS``).
    """
    if not shows(verbosity):
        return NoBar(total)
    from tqdm import tqdm

    width = _columns(sys.stderr)
    if width > 0:
        sizing: dict = {"dynamic_ncols": True}
    else:
        try:
            width = int(os.environ.get("COLUMNS", "")) or DEFAULT_COLUMNS
        except ValueError:
            width = DEFAULT_COLUMNS
        # and rows: tqdm takes such a terminal for one of -1 rows and hides every bar
        sizing = {"ncols": width, "nrows": DEFAULT_ROWS}
    return tqdm(total=total, desc=desc, unit=unit, file=sys.stderr, leave=False,
                mininterval=0.2, **sizing)


def info(message: str, verbosity: int, level: int = NORMAL) -> None:
    """Print ``message`` to standard error when ``verbosity >= level``."""
    if verbosity >= level:
        print(message, file=sys.stderr)
