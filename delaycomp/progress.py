"""Progress bars and verbosity of the command line (tqdm, on standard error).

A bar shows only on a terminal (``tqdm(disable=None)``) and never with ``-q``: when
standard error is redirected nothing but the results reach the files, and standard output
carries results only, whatever the verbosity.
"""

from __future__ import annotations

import sys

#: ``-q``: errors only; default: progress on a terminal and notes; ``-v``: also details
QUIET, NORMAL, VERBOSE = 0, 1, 2


class NoBar:
    """What :func:`bar` returns when no bar shows: counts, draws nothing, imports nothing.

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


def _terminal(stream) -> bool:
    try:
        return stream.isatty()
    except (AttributeError, ValueError):  # no such method, or a closed stream
        return False


def bar(total: int, desc: str, verbosity: int = NORMAL, unit: str = "it"):
    """A tqdm bar on standard error with an estimate of the time left.

    With ``verbosity == QUIET``, or when standard error is not a terminal, a :class:`NoBar`
    instead: tqdm (30 ms to import) is loaded only for a bar that shows.
    """
    if verbosity <= QUIET or not _terminal(sys.stderr):
        return NoBar(total)
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, unit=unit, file=sys.stderr, leave=False,
                dynamic_ncols=True, mininterval=0.2)


def info(message: str, verbosity: int, level: int = NORMAL) -> None:
    """Print ``message`` to standard error when ``verbosity >= level``."""
    if verbosity >= level:
        print(message, file=sys.stderr)
