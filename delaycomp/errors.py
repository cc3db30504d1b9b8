"""Errors the command line reports as one line with exit status 2 (bad user input).

:class:`BadFileError` is for any file the user hands over (an ``.fmu`` in ``--fmu-dir``,
an ``.ssp``, a CSV): missing, corrupt, or of the wrong kind. Raise it with the path and a
reason that says what was expected; ``delaycomp.cli`` prints ``delaycomp: error: PATH:
REASON`` and exits with status 2, without a traceback.
"""

from __future__ import annotations

from pathlib import Path


class BadFileError(Exception):
    """A user-supplied file is missing, corrupt or foreign; the message names it."""

    def __init__(self, path: str | Path, reason: str):
        self.path = Path(path)
        self.reason = " ".join(str(reason).split())  # one line
        super().__init__(f"{self.path}: {self.reason}")
