"""The sweep's metrics from a batch's blocks of ticks (``BlockMetrics``, the LTI
engines'), and ``rho`` from the per-period sums of ``|x|^2`` (``rates``, every engine's).

Every sum is taken in numpy's order, row after row, whatever the array library (a GPU's
reduction trees, a BLAS kernel's blocks would differ in the last bits): a point's metrics
depend on its own numbers alone, not on the library or on how many points share a call.
The rules the per-point engine shares (``ZERO``, the tail of ``rho``) are
``delaycomp.studies.metrics``'.
"""

from __future__ import annotations

import numpy as np

from delaycomp.studies.batch.backends import Backend
from delaycomp.studies.batch.base import BatchResult
from delaycomp.studies.metrics import ZERO, tail_start


class BlockMetrics:
    """The sweep's metrics, from blocks of ticks (norms computed a block at a time).

    Per point, ticks from ``end = min(cut, ticks + 1)`` on are not recorded: ``cut`` is the
    first tick a component refused (a control that is not finite), or the first tick whose
    state is not finite (the plant's step to it failed).
    """

    def __init__(self, be: Backend, P: int, N: int, ticks: np.ndarray, periods_max: int):
        xp = be.xp
        self.be, self.xp, self.P, self.N = be, xp, P, N
        self.ticks = ticks
        self.cut_at = np.full(P, np.iinfo(np.int64).max, dtype=np.int64)
        self.messages = [""] * P
        self.peak = xp.zeros(P)
        self.final = np.full(P, np.nan)
        self.last_above = xp.full(P, -1, dtype=xp.int64)
        self.envsq = np.zeros((max(periods_max, 1), P))
        self.periods_max = periods_max
        self.prev_last = np.full(P, np.nan)  # norm of the tick before the current block

    def cut(self, mask: np.ndarray, k: int, why: str, T, h) -> None:
        """End the record of the points ``mask`` at tick ``k`` (the first not recorded),
        saying ``why``; a point already cut keeps its first cut."""
        new = mask & (self.cut_at > k)
        if not new.any():
            return
        self.cut_at[new] = k
        t = (k // self.N) * T + (k % self.N) * h
        for p in np.flatnonzero(new):
            self.messages[p] = f"{why} at t = {float(t[p])!r}"

    def block(self, xs, start: int, T, h, sq=None) -> None:
        """Rows ``xs[j]`` (shape ``(n, P)``) are the states of ticks ``start + j``
        (``sq``: their ``|x|^2``, summed over the components in order, where the caller
        has them).

        Three passes over the block in the common case (squares, their column maxima and
        sums): ``sqrt`` is monotonic, so the largest norm is the root of the largest square,
        and norms are taken only on the rows a metric reads.
        """
        xp = self.xp
        R = xs.shape[0]
        if sq is None:
            sq = sumsq(xs)
        colmax = xp.max(sq, axis=0)
        finite = bool(xp.isfinite(xp.max(colmax)))
        if not finite:  # rare: states not finite, or |x|^2 overflow
            self._cut_diverged(xs, start, T, h)
        end = np.minimum(self.cut_at, self.ticks + 1)
        sq_in, above, last_row, need = self._peaks(sq, colmax, start, end, finite)
        self._last_above(sq, above, last_row, need, start)
        j = start // self.N
        if j < self.periods_max and R == self.N:
            self.envsq[j] = self.be.to_numpy(_rowsum(xp, sq_in))
        self._final(sq, start, end)

    def _cut_diverged(self, xs, start: int, T, h) -> None:
        """Cut each point at its first tick of the block whose state is not finite (a
        norm may overflow where the states are finite: those are not cut)."""
        xp = self.xp
        bad = ~xp.all(xp.isfinite(xs), axis=1)
        has = self.be.to_numpy(xp.any(bad, axis=0))
        first = self.be.to_numpy(xp.argmax(bad, axis=0))
        for p in np.flatnonzero(has):
            self.cut(np.arange(self.P) == p, start + int(first[p]),
                     "the plant state is not finite (the plant diverged: overflow)", T, h)

    def _peaks(self, sq, colmax, start: int, end: np.ndarray, finite: bool):
        """The peaks updated with the block's recorded rows; returns the squares of the
        recorded rows, where ``|x| >= ZERO`` (``None``: every row recorded), that on the
        last row, and the points whose last such row is to be searched."""
        xp = self.xp
        R = sq.shape[0]
        if np.any(end < start + R) or not finite:
            norms = xp.sqrt(sq)
            rows = xp.asarray(start + np.arange(R))[:, None]
            incl = rows < xp.asarray(end)[None, :]
            sq_in = xp.where(incl, sq, 0.0)
            above = incl & ~(norms < ZERO)
            self.peak = xp.maximum(self.peak, xp.max(xp.where(incl, norms, 0.0), axis=0))
            last_row = above[R - 1]
            need = self.be.to_numpy(xp.any(above, axis=0) & ~last_row)
            return sq_in, above, last_row, need
        self.peak = xp.maximum(self.peak, xp.sqrt(colmax))
        last_row = xp.sqrt(sq[R - 1]) >= ZERO
        need = self.be.to_numpy((xp.sqrt(colmax) >= ZERO) & ~last_row)
        return sq, None, last_row, need

    def _last_above(self, sq, above, last_row, need: np.ndarray, start: int) -> None:
        """The last tick with ``|x| >= ZERO``: the block's last row for most points; a
        search only where some earlier row is above and the last is not."""
        xp = self.xp
        R = sq.shape[0]
        self.last_above = xp.where(last_row, start + R - 1, self.last_above)
        if need.any():
            sel = np.flatnonzero(need)
            cols = self.be.asarray(sel)
            sub = above[:, cols] if above is not None else xp.sqrt(sq[:, cols]) >= ZERO
            last = (R - 1) - self.be.to_numpy(xp.argmax(sub[::-1], axis=0))
            host = self.be.to_numpy(self.last_above).copy()
            host[sel] = start + last
            self.last_above = self.be.asarray(host)

    def _final(self, sq, start: int, end: np.ndarray) -> None:
        """The last recorded norm of the points whose record ends in this block (or just
        before it)."""
        R = sq.shape[0]
        hit = (end - 1 >= start) & (end - 1 < start + R)
        if hit.any():
            sel = np.flatnonzero(hit)
            rows_sel = end[sel] - 1 - start
            self.final[sel] = np.sqrt(self.be.to_numpy(sq[self.be.asarray(rows_sel),
                                                          self.be.asarray(sel)]))
        at_start = end == start
        if at_start.any():
            self.final[at_start] = self.prev_last[at_start]
        self.prev_last = np.sqrt(self.be.to_numpy(sq[R - 1]))

    def finish(self, T, h) -> BatchResult:
        """The metrics per point from what the blocks streamed (on the host)."""
        to = self.be.to_numpy
        N = self.N
        peak = to(self.peak).copy()
        last = to(self.last_above)
        failed = self.cut_at <= self.ticks
        peak[failed & (self.cut_at == 0)] = np.nan  # nothing recorded
        nxt = last + 1
        db = (nxt // N) * T + (nxt % N) * h
        db = np.where(last < 0, 0.0, np.where(last < self.ticks, db, np.nan))
        rho = rates(self.envsq, self.ticks // N)
        bad = failed | ~np.isfinite(peak)
        rho[bad] = np.inf
        db[bad] = np.nan
        stable = (rho < 1.0).astype(np.int64)
        return BatchResult(rho, stable, self.final.copy(), peak, db, ~bad,
                           list(self.messages))


def _rowsum(xp, a):
    """``sum_j a[j]`` (rows of shape ``(P,)``), added row after row: numpy's ``sum(axis=0)``
    of a C-ordered array does exactly that (its pairwise summation is for the contiguous
    axis); other libraries (a GPU's reduction trees) are given the loop, so that they sum
    in numpy's order and give its doubles."""
    if xp is np:
        return np.sum(a, axis=0)
    acc = a[0].copy()
    for j in range(1, a.shape[0]):
        acc += a[j]
    return acc


def sumsq(xs):
    """``|x|^2`` of each row ``xs[j]`` (shape ``(n, P)``), the components added in order."""
    sq = xs[:, 0] * xs[:, 0]
    for a in range(1, xs.shape[1]):
        sq = sq + xs[:, a] * xs[:, a]
    return sq


def rates(envsq: np.ndarray, periods: np.ndarray) -> np.ndarray:
    """``rho`` per point from the per-period sums of ``|x|^2`` (``envsq[j, p]``)."""
    P = len(periods)
    rho = np.full(P, np.nan)
    for S in np.unique(periods):
        sel = np.flatnonzero(periods == S)
        start = tail_start(int(S))
        tail = np.sqrt(envsq[start:S, sel]).T  # (points, tail length)
        if tail.shape[1] < 2:
            continue  # too few periods to estimate a rate: nan, as the per-point metric
        zero = np.any(tail == 0.0, axis=1)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            # the least-squares slope of log e_j, its sums taken period after period
            # (elementwise over the points): a point's rho depends on its own numbers
            # alone, not on how many points share the call (a matrix product's BLAS
            # kernel sums in blocks that depend on the shape)
            y = np.log(tail)
            L = tail.shape[1]
            t = np.arange(L, dtype=float)
            tc = t - t.mean()
            ybar = y[:, 0].copy()
            for j in range(1, L):
                ybar += y[:, j]
            ybar /= L
            acc = (y[:, 0] - ybar) * tc[0]
            for j in range(1, L):
                acc += (y[:, j] - ybar) * tc[j]
            slope = acc / float(np.sum(tc * tc))
            rho[sel] = np.where(zero, 0.0, np.exp(slope))
    return rho
