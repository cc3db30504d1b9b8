"""Errors the command line reports as one line with exit status 2 (bad user input).

``BadFileError`` is for any file the user hands over (an ``.fmu`` in ``--fmu-dir``,
an ``.ssp``, a CSV): missing, corrupt, or of the wrong kind. Raise it with the path and a
reason that says what was expected; ``delaycomp.cli`` prints ``delaycomp: error: PATH:
REASON`` and exits with status 2, without a traceback.
"""

from __future__ import annotations

from pathlib import Path

#: The word with which delaycomp's own components (the Python and native FMUs, the batch
#: engine) say that a refusal was caused by the loop itself diverging: a state, prediction
#: or control that overflowed from finite values (``... must be finite (the plant
#: diverged: overflow)``). A sweep counts such a point unstable (``rho = inf``); any other
#: failure (a plant FMU file whose output turned NaN, a refused call) is marked failed,
#: neither stable nor unstable. See ``is_divergence``.
DIVERGED = "diverged"


def shown(text: str, limit: int = 60) -> str:
    """``text`` as a message quotes a user's input: whole up to ``limit`` characters, else
    its start and end around ``...`` (an error message stays one readable line).

    >>> shown("0.4"), shown("[" * 100 + "1" + "]" * 100, 20)
    ('0.4', '[[[[[[[[...]]]]]]]]')
    """
    if len(text) <= limit:
        return text
    half = (limit - 3) // 2
    return f"{text[:half]}...{text[-half:]}"


def short(obj, limit: int = 80) -> str:
    """``obj`` as a message names what a user passed in: a string quoted (``shown``:
    its start and end where long), anything else by its type and the start and end of its
    ``repr``, on one line of at most about ``limit`` characters (never a multi-kilobyte
    ``repr`` of a loop, a dict or an array).

    >>> short("example-9.9"), short(3.5), short(["a"] * 100, 30)
    ("'example-9.9'", 'float 3.5', "list ['a', 'a...a', 'a', 'a']")
    >>> len(short({"plant": {"A": [[0.0] * 50] * 50}})) <= 80
    True
    """
    if isinstance(obj, str):
        return repr(shown(obj, limit))
    try:
        text = repr(obj)
    except Exception:  # noqa: BLE001 - a broken repr still gets its type named
        text = object.__repr__(obj)
    text = " ".join(text.split())
    kind = type(obj).__name__
    if not text.startswith(("<", kind)):
        text = f"{kind} {text}"
    return shown(text, limit)


def is_divergence(reason: str, ours: bool = True) -> bool:
    """Whether a failure's ``reason`` is the loop's own divergence, as reported by one of
    delaycomp's own components (``ours``; another tool's FMU may use the same word for
    anything).

    Examples
    --------
    >>> is_divergence("plant failed at t = 2: state ['x'] = [inf] at t = 2.0 is not "
    ...               "allowed: must be finite (the plant diverged: overflow)")
    True
    >>> is_divergence("plant failed at t = 2: its output x = nan is not allowed: must be "
    ...               "finite")
    False
    >>> is_divergence("plant failed at t = 2: the model diverged", ours=False)
    False
    """
    return ours and DIVERGED in reason


class DelaycompError(Exception):
    """Base of the errors delaycomp raises for bad input or a failed run (the CLI prints
    them as one line)."""


class BadFileError(DelaycompError):
    """A user-supplied file is missing, corrupt or foreign; the message names it."""

    def __init__(self, path: str | Path, reason: str):
        self.path = Path(path)
        self.reason = " ".join(str(reason).split())  # one line
        super().__init__(f"{self.path}: {self.reason}")


class ParameterError(DelaycompError, ValueError):
    """A loop or scenario parameter is unknown or outside its allowed range (one-line
    message naming the parameter and the allowed range)."""


class SimulationFailed(DelaycompError, RuntimeError):
    """A co-simulation stopped before its stop time (a component refused a step). The
    rows recorded up to the failure are in ``result`` (``success`` is False)."""

    def __init__(self, message: str, result=None):
        super().__init__(message)
        self.result = result


class SspError(DelaycompError, ValueError):
    """An SSD, SSV or SSP archive that ``delaycomp.formats.ssp`` cannot read (one-line
    message)."""


class Interrupted(KeyboardInterrupt):
    """Ctrl-C during a co-simulation: a ``KeyboardInterrupt`` (whatever handles Ctrl-C
    handles it: an interrupt, not an error) that knows the simulation time reached,
    ``time`` (the last tick the master completed). The command line reports it as
    ``delaycomp: interrupted at t = <time>``, exit status 130; the rows so far are kept
    (``.partial``)."""

    def __init__(self, time: float):
        super().__init__(time)
        self.time = float(time)
