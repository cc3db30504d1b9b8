"""The worker pool of the studies, written once: jobs run on spawned worker processes
(:func:`on_processes`, one BLAS thread each) or on a Dask cluster (:func:`on_dask`), their
results in the jobs' order, a progress bar (:class:`Progress`) ticking as each finishes.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

__all__ = ["Progress", "on_dask", "on_processes", "worker_init"]


class Progress:
    """Counts finished points on a tqdm bar (standard error, a terminal only, with the
    time left); ``verbosity`` 0 hides it."""

    def __init__(self, total: int, verbosity: int = 1):
        from delaycomp.progress import bar

        self.total, self.done = total, 0
        self._bar = bar(total, "sweep", verbosity, unit="point")

    def tick(self, count: int = 1) -> None:
        """Count ``count`` more finished points; the bar closes once all are done."""
        self.done += count
        self._bar.update(count)
        if self.done >= self.total:
            self._bar.close()


def on_processes(fn: Callable, jobs: Sequence, workers: int, progress,
                 sizes: Sequence[int] | None = None, chunksize: int = 1) -> list:
    """``fn(job)`` of every job on at most ``workers`` spawned processes, in order;
    ``progress.tick(sizes[i])`` (default 1) as job ``i``'s result comes back. ``fn`` and
    the jobs must be picklable (a top-level function, frozen dataclasses)."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    sizes = sizes or [1] * len(jobs)
    # spawn: a forked child would inherit the parent's FMU runtime threads and locks
    ctx = multiprocessing.get_context("spawn")
    results = []
    with ProcessPoolExecutor(max_workers=max(1, min(workers, len(jobs))), mp_context=ctx,
                             initializer=worker_init) as pool:
        for res, size in zip(pool.map(fn, jobs, chunksize=chunksize), sizes):
            results.append(res)
            progress.tick(size)
    return results


def worker_init() -> None:
    """Worker processes run small matrices: one BLAS thread each (no oversubscription)."""
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=1, user_api="blas")


def on_dask(fn: Callable, jobs: Sequence, address: str, progress,
            sizes: Sequence[int] | None = None) -> list:
    """``fn(job)`` of every job on the Dask cluster at ``address``, in order;
    ``progress.tick(sizes[i])`` (default 1) as job ``i`` finishes, in any order."""
    try:
        from distributed import Client
    except ImportError:
        raise RuntimeError("--scheduler needs Dask: pip install 'delaycomp[dask]'") from None

    from distributed import as_completed

    sizes = sizes or [1] * len(jobs)
    with Client(address) as client:
        futures = client.map(fn, jobs, pure=False)
        index = {f.key: i for i, f in enumerate(futures)}
        results: list = [None] * len(jobs)
        for future in as_completed(futures):  # the bar moves as each job finishes
            i = index[future.key]
            results[i] = future.result()
            progress.tick(sizes[i])
    return results
