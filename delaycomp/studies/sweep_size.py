"""How big a sweep may be: the sizes it streams its grid in, the measured bytes and
seconds per point behind its estimates (``sweep_memory``), and the refusals, in one line
with the estimate, of a grid that cannot finish (``check_time``) or fit in memory
(``check_memory``), before anything runs. ``delaycomp.studies.sweep.check_sweep_size``
asks both.

The streaming sizes (``PIECE_POINTS``, ``STREAM_POINTS``, ``KEEP_BYTES``) are read here by
the estimate and by the sweep's run alike (``delaycomp.studies.sweep`` reads them through
this module): set them here to change both.
"""

from __future__ import annotations

from delaycomp.errors import ParameterError
from delaycomp.studies.axes import Axis

#: Lower bound of the cost of one point of ``--exact`` (a lifted-model eigenvalue
#: problem), in seconds.
SECONDS_PER_EXACT_POINT = 50e-6
#: Lower bound of resolving and validating one point, in seconds: done in this process,
#: whatever the workers (10.7 us measured end to end on the development machine, less the
#: batch engine's share: docs/reference/sweeps.md; 14 us on a busy machine).
SECONDS_PER_POINT = 8e-6
#: Lower bound of the batch engine's cost per point and base step, in seconds, shared by
#: the workers (3.5 ns measured: 7.0 s for 10^6 points of 2000 steps on one core).
SECONDS_PER_BATCH_TICK = 3e-9

# -- memory: a sweep streams its grid ------------------------------------------------------
#
# No stage holds the whole grid. The points are resolved and validated a piece at a time
# (PIECE_POINTS), every piece before any point runs (the validation pass); then a stream
# chunk at a time (STREAM_POINTS) they are resolved again, or taken from the validation
# pass (up to KEEP_BYTES of it), run, and handed on as rows. What grows with the grid is
# only what the caller keeps: run_sweep's list of rows; `delaycomp sweep` writes the rows
# to its CSV as they come. The byte constants below were measured with tracemalloc
# (Python 3.11, numpy 2; /proc VmHWM agrees): the bytes a stage holds, or its peak over
# what was held before it, divided by its points, on Example 3.6 (an LTI scenario, one
# state, 5 s) and Example 2.4 (a model scenario, 1 s), the larger, rounded up.

#: Points resolved and validated together (a piece): the batch engine's chunk on numpy
#: (``CHUNK_MAX``).
PIECE_POINTS = 16384
#: Points run together (a stream chunk, 16 pieces): their chunks go to the workers at once
#: (one pool of worker processes, or one Dask client, per stream chunk), and their rows are
#: handed on before the next stream chunk is resolved.
STREAM_POINTS = 1 << 18
#: Bytes of validated points kept from the validation pass for the run, so that they are
#: not resolved twice (at most: beyond it, the points are resolved again as they run).
KEEP_BYTES = 1 << 29
#: Bytes per point at the peak of resolving a piece: the loop-file data (a dict per point,
#: freed with the piece) and the point's design (LTI: 1.8 kB measured) or loop (a model
#: scenario's: 6.9 kB).
BYTES_PER_RESOLVED = 7000
#: Bytes per point of a batch chunk run in this process (one at a time; on workers, in
#: theirs): 2.5 kB (Example 3.6) and 3.9 kB (Example 2.4) measured; more for long runs at
#: large N, where the batch engine cuts smaller chunks (at most a quarter of the available
#: memory: ``MEMORY_SHARE``).
BYTES_PER_RUN = 4000
#: Bytes per point of a stream chunk in flight: its points' assignments and values, their
#: batches or per-point jobs, their metrics as they come back and their rows (batch
#: engine: 640 measured; per-point engines: about 1 kB).
BYTES_PER_STREAMED = 1000
#: Bytes of a point kept from the validation pass, grouped as the batch engine takes it
#: (``_Piece``): an LTI design with one state and one input (144 measured; 8 more per
#: further matrix entry), a model loop's timing and histories (178 measured).
BYTES_PER_KEPT_LTI = 144
BYTES_PER_KEPT_MODEL = 180
#: Bytes of one held result row (``run_sweep``, ``api.sweep``): a dict of the grid
#: values and the six metrics, its four floats and its slot in the list (356 measured with
#: 2, 3 or 4 grid parameters); a dict of 11 to 21 keys is 192 bytes larger.
BYTES_PER_ROW = 360
BYTES_PER_ROW_WIDE = 560
#: The most points ``--plot`` draws: its figure has 770 x 495 pixels, a map of more cells
#: than this draws several per pixel (and matplotlib needs about 250 bytes a cell).
PLOT_MAX_POINTS = 1_000_000


def sweep_memory(count: int, axes: int, held: bool = True, kept: int = 0) -> tuple[int, int]:
    """An estimate of the bytes a sweep of ``count`` points over ``axes`` grid parameters
    holds at its peak, and of those its rows' (``held``: ``run_sweep`` returns them
    together; else they are handed on as they come, ``iter_sweep``). ``kept``: bytes
    per point kept from the validation pass (a batch sweep's).

    Examples
    --------
    >>> total, rows = sweep_memory(10**7, 2)
    >>> rows, total - rows
    (3600000000, 442368000)
    >>> sweep_memory(10**7, 2, held=False) == sweep_memory(10**8, 2, held=False)
    True
    """
    from delaycomp.studies.sweep_batch import CHUNK_MAX

    row = BYTES_PER_ROW if axes <= 4 else BYTES_PER_ROW_WIDE + 400 * (axes > 15)
    rows = count * row if held else 0
    working = (min(count, PIECE_POINTS) * BYTES_PER_RESOLVED
               + min(count, CHUNK_MAX) * BYTES_PER_RUN
               + min(count, STREAM_POINTS) * BYTES_PER_STREAMED
               + min(count * kept, KEEP_BYTES))
    return rows + working, rows


def check_time(sc, axes: list[Axis], count: int, base, stop: float | None,
               engine: str, workers: int, exact: bool) -> float:
    """Refuse, in one line with the estimate, a sweep that cannot finish in
    ``MAX_RUN_SECONDS``; return its estimated seconds (a lower
    bound): every point resolved here, then run on the workers (``sc``: the opened source;
    ``base``: the loop at ``r = 0``, for its timing; ``None`` where unknown or not
    needed)."""
    from delaycomp.formats.outputs import MAX_RUN_SECONDS, SECONDS_PER_TICK, format_duration

    run = SECONDS_PER_EXACT_POINT
    if base is not None:
        T, N = base.T, base.N
        for a in axes:  # the most expensive point when T or N is swept
            if a.name == "T" and min(a.values) > 0:
                T = min(a.values)
            if a.name == "N" and max(a.values) >= 1:
                N = max(a.values)
        stop_time = stop if stop is not None else (sc.default_stop_time or base.stop_time)
        ticks = (stop_time / T) * N if stop_time else 0.0
        run = ticks * (SECONDS_PER_BATCH_TICK if engine == "batch"
                       else SECONDS_PER_TICK.get(engine, 10e-6))
    elif engine == "batch" and not exact:
        run = 0.0  # no timing known: the resolution alone
    workers = max(1, workers)
    seconds = count * (SECONDS_PER_POINT + run / workers)
    if seconds > MAX_RUN_SECONDS:
        raise ParameterError(
            f"--grid: {count:.4g} points at least {seconds / count * workers * 1e3:.3g} ms each "
            f"on {workers} workers take at least {format_duration(seconds)}, over the limit of "
            f"{format_duration(MAX_RUN_SECONDS)}; use fewer points or a shorter --stop-time")
    return seconds


def check_memory(count: int, axes: int, held: bool, kept: int) -> None:
    """Refuse, in one line with the estimate (``sweep_memory``), a sweep that would
    not fit in half of this machine's memory."""
    from delaycomp.formats.outputs import format_bytes, physical_memory

    need, rows = sweep_memory(count, axes, held, kept)
    ram = physical_memory()
    if ram is not None and need > ram / 2:
        what = (f"{format_bytes(rows)} of it for the rows returned together; stream them "
                "(delaycomp sweep --out, api.iter_sweep) or use fewer points") if held \
            else "use fewer points"
        raise ParameterError(
            f"--grid: {count:.4g} points need about {format_bytes(need)} of memory, over half "
            f"of this machine's {format_bytes(ram)} ({what})")

