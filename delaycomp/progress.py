"""Progress bars and verbosity of the command line (tqdm, on standard error).

A bar shows only on a terminal (``tqdm(disable=None)``) and never with ``-q``: when
standard error is redirected nothing but the results reach the files, and standard output
carries results only, whatever the verbosity.
"""

from __future__ import annotations

import sys

#: ``-q``: errors only; default: progress on a terminal and notes; ``-v``: also details
QUIET, NORMAL, VERBOSE = 0, 1, 2


def bar(total: int, desc: str, verbosity: int = NORMAL, unit: str = "it"):
    """A tqdm bar on standard error with an estimate of the time left.

    Disabled with ``verbosity == QUIET`` and when standard error is not a terminal.
    """
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, unit=unit, file=sys.stderr, leave=False,
                disable=True if verbosity <= QUIET else None, dynamic_ncols=True,
                mininterval=0.2)


def info(message: str, verbosity: int, level: int = NORMAL) -> None:
    """Print ``message`` to standard error when ``verbosity >= level``."""
    if verbosity >= level:
        print(message, file=sys.stderr)
