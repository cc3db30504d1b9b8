"""No orphans (issue 30, item 4): a sweep's worker processes never outlive its main process.

Each test starts ``delaycomp sweep`` on two worker processes as a child in its own session
(its own process group, as a shell's job), waits until the workers compute, records every
process of the tree (``/proc``: the main process, its workers, multiprocessing's resource
tracker), ends the main process as a user or the system would, and requires that none of
them is left: SIGKILL (nothing can run in the main process), SIGTERM, SIGHUP (the terminal
closing) and Ctrl-C (SIGINT to the whole group, as a terminal sends it, or to the main
process alone). The last three exit with ``128 + signal`` and one line on standard error,
within 1.5 s. Any process a failing test leaves is killed in its teardown.

Linux only: the process tree is read from ``/proc``.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from .tiers import tiered

pytestmark = [pytest.mark.skipif(not sys.platform.startswith("linux"),
                                 reason="reads the process tree from /proc"),
              # each test bounds how fast a two-worker sweep ends: the cores to itself
              pytest.mark.alone]

#: a sweep that runs for minutes on two workers (250 points a task, ~10 s each)
SWEEP = ["sweep", "example-3.6", "--engine", "inprocess", "--grid", "k=0.5:3:4000",
         "--workers", "2", "--stop-time", "50", "--out", "m.csv"]

#: seconds a test waits for the sweep's workers to start computing
START_LIMIT = 60.0


def _stat(pid: int) -> tuple[str, int, int] | None:
    """``(state, ppid, start time)`` of ``pid`` from ``/proc/PID/stat``, None if gone."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = text[text.rindex(")") + 2:].split()  # after "pid (comm) "
    return fields[0], int(fields[1]), int(fields[19])


def _tree(root: int) -> dict[int, int]:
    """Every living process below ``root`` and ``root`` itself: pid -> start time."""
    parents: dict[int, int] = {}
    starts: dict[int, int] = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit() and (st := _stat(int(entry))) is not None and st[0] != "Z":
            parents[int(entry)], starts[int(entry)] = st[1], st[2]
    found = {root: starts[root]} if root in starts else {}
    grew = True
    while grew:
        grew = False
        for pid, ppid in parents.items():
            if ppid in found and pid not in found:
                found[pid] = starts[pid]
                grew = True
    return found


def _living(procs: dict[int, int]) -> list[int]:
    """The processes of ``procs`` still running (a zombie has stopped; a reused pid is
    another process)."""
    out = []
    for pid, start in procs.items():
        st = _stat(pid)
        if st is not None and st[0] != "Z" and st[2] == start:
            out.append(pid)
    return out


def _cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
    except OSError:
        return ""


def _cpu_seconds(pid: int) -> float:
    """User and system time of ``pid`` so far, in seconds."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return 0.0
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


class Sweep:
    """The sweep (or another Python command) as a child process in its own session, and
    the processes it started."""

    def __init__(self, cwd: Path, command: tuple[str, ...] = ("-m", "delaycomp", *SWEEP)):
        env = {**os.environ, "PYTHONUNBUFFERED": "1"}
        self.proc = subprocess.Popen([sys.executable, *command], cwd=cwd, env=env,
                                     start_new_session=True,
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        self.cwd = cwd
        self.procs: dict[int, int] = {}

    def wait_for_workers(self) -> None:
        """Until both workers have computed for half a second; the tree is recorded."""
        deadline = time.monotonic() + START_LIMIT
        while time.monotonic() < deadline:
            assert self.proc.poll() is None, self.proc.communicate()
            self.procs = _tree(self.proc.pid)
            workers = [p for p in self.procs if "spawn_main" in _cmdline(p)]
            # a worker's first second or so is its imports
            if len(workers) == 2 and min(_cpu_seconds(p) for p in workers) > 1.5:
                return
            time.sleep(0.1)
        pytest.fail(f"no two computing workers within {START_LIMIT} s")

    def ended(self, limit: float) -> float | None:
        """Seconds until the main process and every process it started are gone, if they
        are within ``limit`` seconds; else None."""
        started = time.monotonic()
        while time.monotonic() - started < limit:
            self.proc.poll()
            if not _living(self.procs):
                return time.monotonic() - started
            time.sleep(0.02)
        return None

    def kill_all(self) -> None:
        """The teardown: every process of the tree is killed, whatever happened."""
        for pid in _living(self.procs):
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        try:
            os.killpg(self.proc.pid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            pass
        self.proc.communicate()


@pytest.fixture
def sweep(tmp_path):
    """A running sweep with its workers computing; killed in the teardown."""
    s = Sweep(tmp_path)
    try:
        s.wait_for_workers()
        yield s
    finally:
        s.kill_all()


def _no_result(s: Sweep) -> None:
    """An ended sweep left no CSV: neither the result nor its ``.part``."""
    assert sorted(p.name for p in s.cwd.iterdir()) == []


def test_sigkill_of_the_main_process_leaves_no_worker(sweep):
    names = {p: _cmdline(p) for p in sweep.procs}
    assert any("resource_tracker" in c for c in names.values()), names
    os.kill(sweep.proc.pid, signal.SIGKILL)
    took = sweep.ended(3.0)
    left = {p: names[p] for p in _living(sweep.procs)}
    assert took is not None, f"still running 3 s after SIGKILL: {left}"


@pytest.mark.parametrize("signum, status, line, to_group", tiered([
    (signal.SIGTERM, 143, "delaycomp: terminated (SIGTERM)", False),
    (signal.SIGHUP, 129, "delaycomp: terminated (SIGHUP)", True),
    (signal.SIGTERM, 143, "delaycomp: terminated (SIGTERM)", True),
    (signal.SIGHUP, 129, "delaycomp: terminated (SIGHUP)", False),
], 2), ids=["SIGTERM-main", "SIGHUP-group", "SIGTERM-group", "SIGHUP-main"])
def test_sigterm_and_sighup_end_the_sweep(sweep, signum, status, line, to_group):
    if to_group:  # systemd stopping a service, a terminal closing (the shell's SIGHUP)
        os.killpg(sweep.proc.pid, signum)
    else:
        os.kill(sweep.proc.pid, signum)
    took = sweep.ended(1.5)
    assert took is not None, f"still running 1.5 s after {signum.name}"
    _, err = sweep.proc.communicate()
    assert (sweep.proc.returncode, err.decode().splitlines()) == (status, [line])
    _no_result(sweep)


@pytest.mark.parametrize("to_group", [True, False], ids=["group", "main"])
def test_ctrl_c_ends_the_sweep_within_a_second(sweep, to_group):
    if to_group:  # what a terminal does on Ctrl-C
        os.killpg(sweep.proc.pid, signal.SIGINT)
    else:
        os.kill(sweep.proc.pid, signal.SIGINT)
    took = sweep.ended(1.5)
    assert took is not None, "still running 1.5 s after Ctrl-C"
    _, err = sweep.proc.communicate()
    assert (sweep.proc.returncode, err.decode().splitlines()) == (130,
                                                                  ["delaycomp: interrupted"])
    _no_result(sweep)


#: a parent that starts one spawned child which only watches it (watch_parent, the
#: portable fallback: no prctl) and sleeps; the child prints its pid once it watches
WATCHED = """
import multiprocessing, os, time
from delaycomp.studies.pool import watch_parent

def child():
    assert watch_parent()
    print(os.getpid(), flush=True)
    time.sleep(600)

if __name__ == "__main__":
    multiprocessing.get_context("spawn").Process(target=child).start()
    time.sleep(600)
"""


def test_the_watching_thread_alone_ends_a_child_with_its_parent(tmp_path):
    """Where the kernel does not end a worker with its parent (not Linux), its own thread
    does: here without prctl, the parent SIGKILLed."""
    (tmp_path / "parent.py").write_text(WATCHED)
    s = Sweep(tmp_path, ("parent.py",))
    try:
        child = int(s.proc.stdout.readline())
        s.procs = _tree(s.proc.pid)
        assert child in s.procs
        os.kill(s.proc.pid, signal.SIGKILL)
        assert s.ended(1.5) is not None, "the child outlived its parent by 1.5 s"
    finally:
        s.kill_all()


def test_sigterm_and_sighup_are_handled_during_a_sweep_only(tmp_path, monkeypatch):
    """The sweep's handlers raise Terminated; an ignored SIGHUP (``nohup``) stays ignored;
    the handlers before the sweep come back after it."""
    from delaycomp import cli
    from delaycomp.cli import signals, studies

    seen = {}

    def sweep(args):
        seen.update(term=signal.getsignal(signal.SIGTERM), hup=signal.getsignal(signal.SIGHUP))
        return 0

    monkeypatch.setattr(studies, "_sweep", sweep)
    monkeypatch.chdir(tmp_path)
    before = signal.signal(signal.SIGHUP, signal.SIG_IGN)
    try:
        term = signal.getsignal(signal.SIGTERM)
        assert cli.main(["sweep", "example-3.6", "--grid", "k=1:2:2", "--out", "m.csv"]) == 0
        assert seen == {"term": signals._raise_terminated, "hup": signal.SIG_IGN}
        assert signal.getsignal(signal.SIGTERM) is term
        assert signal.getsignal(signal.SIGHUP) is signal.SIG_IGN
    finally:
        signal.signal(signal.SIGHUP, before)
