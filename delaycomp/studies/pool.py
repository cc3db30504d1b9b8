"""The worker pool of the studies, written once: jobs run on spawned worker processes
(``on_processes``, one BLAS thread each) or on a Dask cluster (``on_dask``), their
results in the jobs' order, a progress bar (``Progress``) ticking as each finishes.

No worker outlives the process that started it. When the pool is left
by an exception (Ctrl-C's ``KeyboardInterrupt``, the command line's SIGTERM and SIGHUP, a
job's error) the jobs not started are cancelled and the workers are terminated at once,
not waited for. When the main process dies without a word (SIGKILL, a crash) each worker
ends by itself (``worker_init``): the kernel kills it (Linux), or a thread of its own
sees the parent gone (everywhere). Multiprocessing's resource tracker, the only other
process the pool starts (``start_resource_tracker``), ends when the main process and
the workers have.
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading
import time
from collections.abc import Callable, Sequence

from delaycomp.child import parent_death_signal

__all__ = ["Progress", "end_with_parent", "end_workers", "on_dask", "on_processes",
           "quiet_cancelled_futures", "start_resource_tracker", "watch_parent",
           "worker_init"]

#: seconds the terminated workers get to end before they are killed
END_GRACE = 1.0


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
    the jobs must be picklable (a top-level function, frozen dataclasses).

    An exception here (``KeyboardInterrupt`` included) or in a job cancels the jobs not
    started and ends the workers at once (``end_workers``) before it propagates.
    """
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    sizes = sizes or [1] * len(jobs)
    # spawn: a forked child would inherit the parent's FMU runtime threads and locks
    ctx = multiprocessing.get_context("spawn")
    results = []
    start_resource_tracker()
    pool = ProcessPoolExecutor(max_workers=max(1, min(workers, len(jobs))), mp_context=ctx,
                               initializer=worker_init, initargs=(os.getpid(),))
    try:
        for res, size in zip(pool.map(fn, jobs, chunksize=chunksize), sizes):
            results.append(res)
            progress.tick(size)
    except BaseException:
        end_workers(pool)
        raise
    pool.shutdown(wait=True)
    return results


def start_resource_tracker() -> None:
    """Start multiprocessing's resource tracker (POSIX), deaf to SIGHUP as it is to SIGINT
    and SIGTERM.

    The pool's queues register their semaphores with this process, which removes what is
    left once the main process and the workers have ended. It ignores SIGINT and SIGTERM
    but not SIGHUP: a terminal closing killed it, and the main process, stopping cleanly,
    relaunched it with a warning and tracebacks. Started here with SIGHUP blocked, a mask
    it inherits and keeps, it ends only as it should. One already running is kept.
    """
    if os.name != "posix" or not hasattr(signal, "pthread_sigmask"):
        return
    from multiprocessing import resource_tracker

    held = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGHUP})
    try:
        resource_tracker.ensure_running()
    finally:  # a SIGHUP that came meanwhile is delivered here
        signal.pthread_sigmask(signal.SIG_SETMASK, held)


def end_workers(pool, grace: float = END_GRACE) -> None:
    """Shut ``pool`` (a ``ProcessPoolExecutor``) down without waiting for its running
    jobs: cancel those not started, terminate the workers (SIGTERM on POSIX), kill those
    still there after ``grace`` seconds, and reap them (no zombies).

    The pool's manager thread, which then finds its workers gone and closes the pool's
    pipes, is given ``grace`` seconds to finish: an interpreter leaving meanwhile wrote to
    a pipe it was closing ("Exception ignored ... Bad file descriptor", a traceback after
    the one line of SIGTERM in 1 of 4 sweeps of the batch engine).
    """
    # the workers and the thread before shutdown() drops them
    # (ProcessPoolExecutor.terminate_workers of Python 3.14 does the same)
    processes = list((getattr(pool, "_processes", None) or {}).values())
    manager = getattr(pool, "_executor_manager_thread", None)
    if manager is not None:
        quiet_cancelled_futures(manager)
    pool.shutdown(wait=False, cancel_futures=True)
    for proc in processes:
        with contextlib.suppress(OSError, ValueError):  # already gone, or closed
            proc.terminate()
    deadline = time.monotonic() + grace
    for proc in processes:
        with contextlib.suppress(OSError, ValueError):
            proc.join(max(0.0, deadline - time.monotonic()))
            if proc.is_alive():
                proc.kill()
                proc.join(grace)
    if manager is not None:
        manager.join(grace)


def quiet_cancelled_futures(manager: threading.Thread) -> None:
    """Keep the pool's manager thread from printing a traceback for futures it finds
    cancelled: on Python 3.11, when workers die (a SIGHUP or SIGTERM to the process group
    reaches them too) after ``shutdown(cancel_futures=True)``, the manager marks the pool
    broken and sets an exception on every pending future, a cancelled one included, which
    raises ``InvalidStateError`` in that thread: 15 lines on stderr after the one line of
    SIGHUP (seen once, in a CI run of ``tests/test_sweep_orphans.py``). Nothing is lost
    (the futures were cancelled on purpose); only that exception of that thread is
    silenced, anything else is reported by the hook installed before.

    Examples
    --------
    >>> import threading
    >>> from concurrent.futures import InvalidStateError
    >>> seen = []
    >>> before, threading.excepthook = threading.excepthook, lambda a: seen.append(a.exc_type)
    >>> manager = threading.Thread(target=lambda: None)
    >>> quiet_cancelled_futures(manager)
    >>> threading.excepthook(threading.ExceptHookArgs(
    ...     (InvalidStateError, InvalidStateError(), None, manager)))
    >>> threading.excepthook(threading.ExceptHookArgs((ValueError, ValueError(), None, manager)))
    >>> seen
    [<class 'ValueError'>]
    >>> threading.excepthook = before
    """
    from concurrent.futures import InvalidStateError

    earlier = threading.excepthook

    def hook(args) -> None:
        if args.thread is manager and issubclass(args.exc_type, InvalidStateError):
            return
        earlier(args)

    threading.excepthook = hook


def worker_init(parent: int | None = None) -> None:
    """Set a worker process up: it ends with its parent (``end_with_parent``), leaves
    Ctrl-C to it, and runs small matrices on one BLAS thread (no oversubscription).

    Ctrl-C in a terminal sends SIGINT to every process of the job: a worker ignores it
    (instead of a ``KeyboardInterrupt`` traceback each), and the parent, interrupted,
    terminates the workers (``on_processes``). A program a worker started would
    inherit the ignored SIGINT; no worker starts one.
    """
    from threadpoolctl import threadpool_limits

    end_with_parent(parent)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    threadpool_limits(limits=1, user_api="blas")


def end_with_parent(parent: int | None = None) -> None:
    """End this process, a worker, when its parent (pid ``parent``) dies, by any means.

    On Linux the kernel sends it SIGKILL then (``prctl(PR_SET_PDEATHSIG)``); a parent that
    died before that call is seen by the pid of the parent, which has changed. Everywhere,
    in a process multiprocessing started, a daemon thread waits on the parent's sentinel
    (a pipe that closes when the parent dies; its process handle on Windows) and ends the
    process when it fires, within milliseconds where the thread gets to run
    (``watch_parent``). (Linux's signal comes when the parent's thread that started
    the worker ends: ``on_processes`` starts them from the thread that waits for them.)
    """
    if parent_death_signal(signal.SIGKILL):
        if parent is not None and os.getppid() != parent:
            os._exit(1)  # the parent is gone already
    watch_parent()


def watch_parent() -> bool:
    """In a process multiprocessing started, a daemon thread that ends the process at once
    (``os._exit``) when its parent dies; whether there is one (False in a process that
    multiprocessing did not start)."""
    import multiprocessing

    watched = multiprocessing.parent_process()
    if watched is None:
        return False
    threading.Thread(target=_exit_with, args=(watched.sentinel,), daemon=True,
                     name="delaycomp-parent-watch").start()
    return True


def _exit_with(sentinel) -> None:
    """Wait until ``sentinel`` (the parent's) fires, then end this process at once."""
    from multiprocessing.connection import wait

    wait([sentinel])
    os._exit(1)


def on_dask(fn: Callable, jobs: Sequence, address: str, progress,
            sizes: Sequence[int] | None = None) -> list:
    """``fn(job)`` of every job on the Dask cluster at ``address``, in order;
    ``progress.tick(sizes[i])`` (default 1) as job ``i`` finishes, in any order. An
    exception here (``KeyboardInterrupt`` included) cancels the jobs on the cluster."""
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
        try:
            for future in as_completed(futures):  # the bar moves as each job finishes
                i = index[future.key]
                results[i] = future.result()
                progress.tick(sizes[i])
        except BaseException:
            with contextlib.suppress(Exception):  # the cluster's, not ours: best effort
                client.cancel(futures)
            raise
    return results
