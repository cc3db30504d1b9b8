"""Result files of a run: checked before it starts, written while it goes.

- ``check_output`` refuses an output path that cannot take a file (an existing folder,
  a name ending in a path separator, a parent that is a file, a plot format matplotlib
  cannot write) before anything runs, so a late failure cannot strand a half-made result.
- ``clear_previous`` removes an older result at the same path (and its ``.partial``)
  before a run, so a failed rerun never leaves an old file that looks like the new one.
- ``output_every`` turns ``--output-interval S`` into a decimation of the base step.
- ``CsvStream`` writes the CSV row by row as the master records it, into
  ``FILE.part``; it becomes ``FILE`` on success and ``FILE.partial`` (the rows up to the
  failure, never read as a result) on failure. Memory stays flat however long the run.
- ``check_budget`` estimates a run's time and memory before it starts and refuses,
  with the estimate in one line, what cannot finish.
"""

from __future__ import annotations

import csv
import math
import os
from pathlib import Path
from typing import TYPE_CHECKING, TextIO

from delaycomp.errors import ParameterError
from delaycomp.maths.grid import nearest_multiple

if TYPE_CHECKING:
    from _csv import Writer  # the type csv.writer() returns (not exported by csv)

#: suffix of the CSV of a failed run (rows up to the failure): never read as a result
PARTIAL_SUFFIX = ".partial"
#: suffix of a file being written (renamed when complete)
WORKING_SUFFIX = ".part"


class OutputError(ParameterError):
    """An output path or interval that cannot work (one line, exit status 2)."""


def plot_formats() -> set[str]:
    """File suffixes (without the dot) the Agg canvas of matplotlib writes."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    return set(FigureCanvasAgg(Figure()).get_supported_filetypes())


def check_output(path: str | Path | None, option: str, kind: str = "csv") -> Path | None:
    """Check that ``path`` can receive the output file of ``option`` before a run.

    Parameters
    ----------
    path : str or Path or None
        the path as the user gave it (``None``: no such output, nothing checked).
    option : str
        the option's name for the message (``--out``).
    kind : str
        ``csv`` (any file name) or ``plot`` (a suffix matplotlib writes: png, pdf, svg...).

    Returns
    -------
    Path or None
        the path.

    Raises
    ------
    OutputError
        the path is a folder, a FIFO, a device or a socket, names a folder (ends in
        ``/``), lies under a file or in a folder that does not exist or where no file can
        be made, or (for a plot) has a suffix matplotlib cannot write.
        (A link there is allowed: the result replaces it, its target is left alone.)

    Examples
    --------
    >>> import tempfile
    >>> folder = tempfile.mkdtemp()
    >>> check_output(f"{folder}/run.csv", "--out").name
    'run.csv'
    >>> check_output(f"{folder}/missing/run.csv", "--out")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    delaycomp.formats.outputs.OutputError: --out '.../missing/run.csv': folder ... does not ...
    >>> check_output("out/", "--plot", "plot")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    delaycomp.formats.outputs.OutputError: --plot 'out/' is a folder: give a file name ...
    >>> try:
    ...     check_output("out/", "--plot", "plot")
    ... except OutputError as exc:
    ...     print(str(exc).split(": ")[1])
    give a file name such as out/plot.png
    """
    if path is None:
        return None
    text = str(path)
    p = Path(path)
    example = "plot.png" if kind == "plot" else "run.csv"
    if text.endswith(("/", os.sep)) or p.is_dir():
        raise OutputError(f"{option} {text!r} is a folder: give a file name such as "
                          f"{p / example}")
    kind_of = _special(p)
    if kind_of:
        raise OutputError(f"{option} {text!r} is not allowed: it is {kind_of}, not a "
                          "regular file (results are written to a new file and renamed "
                          "into place)")
    parent = p.parent
    missing = parent
    while not missing.exists() and missing != missing.parent:
        missing = missing.parent
    if missing.exists() and not missing.is_dir():
        raise OutputError(f"{option} {text!r}: {missing} is a file, not a folder")
    if not parent.is_dir():  # never created silently: a typo in the path would be kept
        raise OutputError(f"{option} {text!r}: folder {parent} does not exist (create it "
                          "first)")
    why = _unwritable(parent)
    if why:
        raise OutputError(f"{option} {text!r}: folder {parent} is not writable ({why})")
    if kind == "plot":
        suffix = p.suffix.lower().lstrip(".")
        formats = plot_formats()
        if suffix not in formats:
            raise OutputError(f"{option} {text!r}: the suffix must name a plot format, one "
                              f"of {', '.join(sorted(formats))}")
    return p


def _unwritable(folder: Path) -> str | None:
    """Why a new file cannot be made in ``folder`` (tried: permissions alone say nothing
    for root, or on a read-only file system), or ``None``."""
    probe = folder / f".delaycomp-probe-{os.getpid()}-{os.urandom(4).hex()}"
    try:
        fd = os.open(probe, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    except OSError as exc:
        return exc.strerror or type(exc).__name__
    os.close(fd)
    os.unlink(probe)
    return None


def _special(path: Path) -> str | None:
    """What ``path`` is when it exists as something other than a regular file, a folder
    or a link (a link is replaced by the result, its target left alone): a FIFO, a
    device, a socket."""
    import stat

    try:
        mode = path.lstat().st_mode
    except OSError:
        return None
    if stat.S_ISFIFO(mode):
        return "a FIFO"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device"
    if stat.S_ISSOCK(mode):
        return "a socket"
    return None


def partial_path(path: Path) -> Path:
    """``FILE.partial``: the rows of a failed run."""
    return path.with_name(path.name + PARTIAL_SUFFIX)


def clear_previous(*paths: Path | None) -> None:
    """Remove an older result at each path and its ``.partial`` (a failed rerun must not
    leave the previous CSV or plot beside the new partial rows)."""
    for path in paths:
        if path is None:
            continue
        for old in (path, partial_path(path)):
            if old.is_file() or old.is_symlink():
                old.unlink()


def output_every(interval: float | None, T: float, N: int) -> int:
    """Base steps per output row for ``--output-interval interval`` (``None``: 1).

    Examples
    --------
    >>> output_every(0.5, T=1.0, N=100)
    50
    >>> output_every(None, T=1.0, N=100)
    1
    """
    if interval is None:
        return 1
    h = T / N
    if not (math.isfinite(interval) and interval > 0):
        raise OutputError(f"--output-interval {interval!r} is not allowed: must be a finite "
                          "number > 0")
    k = nearest_multiple(interval, h)
    if k == 0:  # rounds to no step: never silently one
        raise OutputError(f"--output-interval {interval!r} is not allowed: it is less than "
                          f"one base step h = T/N = {h!r}")
    if k is None:
        raise OutputError(f"--output-interval {interval!r} is not allowed: must be a "
                          f"multiple of the base step h = T/N = {h!r}")
    return k


class CsvStream:
    """A CSV written row by row: ``time`` then one column per name.

    Use as ``sink`` of ``delaycomp.orchestrator.simulate.run_loop``; call ``finish`` once.
    Rows go to ``FILE.part``; ``finish`` renames it to ``FILE`` (success) or
    ``FILE.partial`` (failure). Numbers are written with ``repr`` (17 significant digits,
    read back bit for bit).
    """

    def __init__(self, path: str | Path, names: list[str]):
        self.path = Path(path)
        self.names = list(names)
        self.tmp = self.path.with_name(self.path.name + WORKING_SUFFIX)
        # opened with the first row: a run that fails before has no file
        self._fh: TextIO | None = None
        self._writer: Writer | None = None
        self.rows = 0

    def _open(self) -> None:
        from delaycomp.tmpfiles import new_file

        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._fh = new_file(self.tmp)  # a new file: never through a link at FILE.part
        self._writer = csv.writer(self._fh)
        self._writer.writerow(["time", *self.names])

    def __call__(self, t: float, row) -> None:
        if self._writer is None:
            self._open()
        assert self._writer is not None  # _open() made it
        self._writer.writerow([repr(float(t)), *(repr(float(v)) for v in row)])
        self.rows += 1

    def write_rows(self, times, rows) -> None:
        """Many rows at once (a stepping core's block): ``times`` and ``rows`` (a 2-D
        array, one row a time), the same text as calling the stream row by row."""
        n = len(times)
        if not n:
            return
        width = len(self.names)
        import numpy as np

        flat = np.column_stack([np.asarray(times, dtype=float),
                                np.asarray(rows, dtype=float).reshape(n, width)])
        self.write_flat(flat.ravel().tolist(), n)

    def write_flat(self, values, n: int) -> None:
        """``n`` rows at once from ``values``, a list of floats: each row's time then its
        values, one row after the other (the same text as the stream row by row)."""
        if not n:
            return
        if self._writer is None:
            self._open()
        assert self._fh is not None  # _open() made it
        # repr of every float (%r): the text csv.writer writes for these strings, which
        # hold no delimiter, quote or line break
        self._fh.write((",".join(["%r"] * (len(self.names) + 1)) + "\r\n") * n
                       % tuple(values))
        self.rows += n

    def discard(self) -> None:
        """Close and remove what was written: no result, not even a partial one."""
        if self._fh is not None:
            self._fh.close()
            self._fh = self._writer = None
            self.tmp.unlink(missing_ok=True)
        self.rows = 0

    def finish(self, success: bool) -> Path:
        """Close the file; return where it is now (``FILE`` or ``FILE.partial``)."""
        final = self.path if success else partial_path(self.path)
        if self._fh is None:  # no row came: nothing was written
            if success:
                self._open()
            else:
                return final
        assert self._fh is not None  # _open() made it
        self._fh.close()
        self.tmp.replace(final)
        return final


# -- budget ----------------------------------------------------------------------------

#: Lower bounds of the cost of one base step of a four-component loop, in seconds, from
#: BENCHMARKS.md (section 1: 11.8 us per step in-process and 43 us with FMUs for the
#: cheapest scenario). Estimates are lower bounds: a refused run would take longer still.
SECONDS_PER_TICK = {"inprocess": 10e-6, "fmu": 40e-6, "native-core": 0.1e-6}
#: Lower bound of the cost of one recorded row where the native stepping core steps the
#: loop (its base step is then cheaper than the row: formatting a CSV row of Example 3.6
#: takes about 2 us, its base step in the core about 0.2 us)
SECONDS_PER_ROW_CORE = 1e-6
#: A run whose estimate exceeds this is refused (one day).
MAX_RUN_SECONDS = 86400.0
#: Bytes per held value of a delay line or input history (a Python tuple of ``n`` floats
#: and its slot in a deque: 56 + 8 n bytes of tuple, 24 n of floats, 8 of pointer).
BYTES_PER_HELD = 64
BYTES_PER_HELD_VALUE = 32
#: Bytes per kept value of a recorded row (a Python float in a tuple, plus the list
#: slot and the time).
BYTES_PER_KEPT_VALUE = 40


def physical_memory() -> int | None:
    """Bytes of physical memory, or ``None`` where the system does not say."""
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return None


def format_duration(seconds: float) -> str:
    """``seconds`` in the largest unit that gives at least 2 of it (``"3.5 hours"``)."""
    for unit, size in (("years", 365.25 * 86400), ("days", 86400), ("hours", 3600),
                       ("minutes", 60)):
        if seconds >= 2 * size:
            return f"{seconds / size:.3g} {unit}"
    return f"{seconds:.3g} s"


def format_bytes(n: float) -> str:
    """``n`` bytes in MB, GB or TB, three digits (``"1.2 GB"``)."""
    for unit, size in (("TB", 1e12), ("GB", 1e9), ("MB", 1e6)):
        if n >= size:
            return f"{n / size:.3g} {unit}"
    return f"{n:.3g} B"


def estimate(loop, ticks: int, engine: str = "fmu", every: int = 1,
             keep: bool = True) -> tuple[float, float]:
    """Lower bounds of a run's wall time (s) and memory (bytes) before it starts.
    ``engine``: ``fmu``, ``inprocess``, or ``native-core`` (the FMU engine's loop stepped
    by the native core: ``SECONDS_PER_TICK`` a base step and ``SECONDS_PER_ROW_CORE`` a
    recorded row).

    Memory counts the delay lines (``delay / h`` held values each), the controller's
    input history (``(r + tau) / h`` values) and, with ``keep``, the recorded rows.
    ``loop`` is a ``Loop``.
    """
    h = loop.T / loop.N
    held = 0.0
    for inst in loop.instances:
        config = getattr(inst.source, "config", None)
        config = config() if callable(config) else (config or {})
        params = inst.parameters
        if inst.role in ("meas_delay", "input_delay"):
            width, window = int(config.get("n", 1)), float(params.get("delay", 0.0))
        elif inst.role == "controller":
            width = int(config.get("m", 1))
            window = float(params.get("r", 0.0)) + float(params.get("tau", 0.0))
        else:
            continue
        held += (window / h) * (BYTES_PER_HELD + BYTES_PER_HELD_VALUE * width)
    kept = 0.0
    if keep:
        kept = (ticks / every + 1) * (len(loop.recorded) + 1) * BYTES_PER_KEPT_VALUE
    seconds = ticks * SECONDS_PER_TICK.get(engine, SECONDS_PER_TICK["inprocess"])
    if engine == "native-core":
        seconds += (ticks / every + 1) * SECONDS_PER_ROW_CORE
    return seconds, held + kept


def check_budget(loop, ticks: int, engine: str = "fmu", every: int = 1,
                 keep: bool = True) -> tuple[float, float]:
    """Refuse a run that cannot finish (``MAX_RUN_SECONDS``) or cannot fit in half
    the physical memory; return the estimate ``(seconds, bytes)`` otherwise."""
    seconds, memory = estimate(loop, ticks, engine, every, keep)
    steps = f"{ticks:.4g} base steps (T = {loop.T!r}, N = {loop.N})"
    if seconds > MAX_RUN_SECONDS:
        per = SECONDS_PER_TICK.get(engine, SECONDS_PER_TICK["inprocess"]) * 1e6
        rate = (f"{per:g} us per step and {SECONDS_PER_ROW_CORE * 1e6:g} us per row (the "
                "native stepping core)" if engine == "native-core"
                else f"{per:g} us per step ({engine} engine)")
        raise OutputError(
            f"this run needs {steps}: at least {format_duration(seconds)} at {rate}, over "
            f"the limit of {format_duration(MAX_RUN_SECONDS)}; lower --stop-time or N")
    ram = physical_memory()
    if ram is not None and memory > ram / 2:
        what = "delay buffers and kept rows" if keep else "delay buffers"
        raise OutputError(
            f"this run needs at least {format_bytes(memory)} of memory for its {what} "
            f"(T = {loop.T!r}, N = {loop.N}), over half of this machine's {format_bytes(ram)}; "
            "lower N" + (" or give --output-interval" if keep else ""))
    return seconds, memory
