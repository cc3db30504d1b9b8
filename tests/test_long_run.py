"""Long runs: hidden buffers stay bounded by the delay window, memory stays flat, and a
long run agrees with a shorter one where they overlap (to the last bits).

The CI test runs 20 000 base steps; ``scripts/long_run_memory.py`` measured 10^6
(docs/explanation/reliability.md).
"""

from __future__ import annotations

import json
import tracemalloc

import pytest

from delaycomp.orchestrator.simulate import make_master, parameters_of
from delaycomp.paper import scenarios

from .roundoff import SAME_ARITHMETIC_ULPS, assert_columns_close

pytestmark = pytest.mark.fmu

SETTINGS = ["r=0.3", "tau=1", "N=100"]  # h = 0.01: windows of 30 and 100 base steps


def _spec():
    sc = scenarios.get("example-3.6")
    return sc.make(sc.resolve(SETTINGS))


def _run(fmu_dir, ticks, every, between=None):
    spec = _spec()
    master, rec = make_master(spec, fmu_dir, every=every)
    try:
        master.setup(ticks * spec.T / spec.N, parameters_of(spec))
        master.initialize()
        if between is not None:
            between(master, ticks)
        master.run_until(ticks)
        hidden = {name: json.loads(s)["hidden"]
                  for name, s in master.get_state()["components"].items()}
    finally:
        master.terminate()
    return rec, hidden


def test_buffers_are_bounded_by_the_delay_window(fmu_dir):
    _, hidden = _run(fmu_dir, 5000, 1000)
    assert len(hidden["meas_delay"]["buffer"]) == 30  # r / h
    assert len(hidden["input_delay"]["buffer"]) == 100  # tau / h
    # u_{i-1} .. u_{i-l-q-1}: l = tau/T = 1, q = floor(r/T) = 0 (Corollary 3.4)
    assert len(hidden["controller"]["ctrl"]["history"]) == 2


@pytest.mark.slow  # a soak: 20 000 base steps under tracemalloc
def test_memory_is_flat(fmu_dir):
    """Python-side memory of the FMUs and the master (tracemalloc, which also sees the
    objects pythonfmu's C++ layer creates through the Python C API) grows by less than
    64 KiB from tick 2 000 to tick 20 000, with no rows recorded in between (measured:
    about 9 KiB, the allocator's slack). A leak of one float per tick would be about
    430 KiB and fail."""
    marks = {}

    def measure(master, ticks):
        master.run_until(2000)
        tracemalloc.start()
        marks["start"] = tracemalloc.get_traced_memory()[0]
        master.run_until(ticks)
        marks["end"] = tracemalloc.get_traced_memory()[0]
        tracemalloc.stop()

    rec, _ = _run(fmu_dir, 20000, 10**9, measure)
    assert len(rec.rows) == 1  # tick 0 only
    growth = marks["end"] - marks["start"]
    assert growth < 64 * 1024, f"{growth} bytes"


def test_long_run_matches_short_run_where_they_overlap(fmu_dir):
    """A decimated long run (one row per 100 ticks) and a full short run: the rows they
    share are the same (the same arithmetic: to the last bits, measured bit-equal)."""
    long, _ = _run(fmu_dir, 6000, 100)
    short, _ = _run(fmu_dir, 3000, 1)
    overlap = [(t, *row) for k, (t, row) in enumerate(zip(short.times, short.rows))
               if k % 100 == 0]
    assert len(overlap) == 31 and len(long.rows) == 61
    shared = [(t, *row) for t, row in zip(long.times, long.rows)][: len(overlap)]
    assert_columns_close(shared, overlap, SAME_ARITHMETIC_ULPS, "overlap")
