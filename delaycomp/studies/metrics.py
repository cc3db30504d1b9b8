"""What every engine of a sweep reports per point, and the two rules they share: when
``|x|`` counts as zero (``ZERO``) and which periods the growth rate ``rho`` is fitted over
(``tail_start``). The per-point metric (``delaycomp.studies.sweep.metrics_of``) and the
batch engine's vectorized one (``delaycomp.studies.batch``) both read them here, so that
their rows agree by construction.
"""

from __future__ import annotations

#: ``|x|`` below this counts as zero for the dead-beat time: far above the round-off that a
#: dead-beat loop leaves of a state of order one (about 1e-15), far below any state that
#: a loop still settling holds.
ZERO = 1e-9
#: the columns of a sweep's row after its grid values, in order
METRICS = ("rho", "stable", "final_norm", "peak_norm", "deadbeat_time", "failed")


def tail_start(periods: int) -> int:
    """The first period of the tail that ``rho`` is fitted over: after the first fifth of
    ``periods`` (the transient of the first sample and of the delay lines), and never the
    first period.

    Examples
    --------
    >>> tail_start(20), tail_start(4), tail_start(0)
    (4, 1, 1)
    """
    return max(1, periods // 5)
