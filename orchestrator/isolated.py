"""An FMU file of another tool, run in a child process of its own.

A user's plant FMU is code we did not write, loaded into our process: a ``doStep`` that
never returns would hang the master (Ctrl-C included: a signal reaches Python only
between bytecodes, never inside a C call), and one that calls ``exit()`` would end the
command with the FMU's exit status, 0 for a run that did not finish. Neither can be
contained inside the process that loaded the FMU, so ``IsolatedFmu`` runs such an
FMU in a child process (an ``FmuComponent`` there) and
talks to it over a pipe:

- every call waits at most the **watchdog**'s seconds (``default_watchdog``: 10 s or
  100 times the loop's base step, whichever is longer; six times that for instantiation,
  initialization and termination, which may solve an initial system or read files); a call
  that does not return in time stops the child and fails the run, naming the call;
- a child that ends during a call (``exit()``, a crash) fails the run naming its exit
  status or signal;
- Ctrl-C reaches this process, which is only waiting on the pipe, and is reported as an
  interrupt (``Interrupted``), never as the FMU's failure: the
  child runs in a session of its own, which the terminal's Ctrl-C does not reach, and
  ignores SIGINT besides; it is stopped when the run ends. The child also dies with this
  process (Linux: ``PR_SET_PDEATHSIG``; elsewhere it leaves when the pipe closes).

One round trip per tick: the inputs set are sent with the next step or read (FMI's order of
calls is kept), and the values of every output the master reads come back with the step.
A refusal of a set input is therefore reported by the next call that reaches the FMU.
Our own FMUs (built by delaycomp) run in this process, as before.
"""

from __future__ import annotations

import math
import queue
import signal
import subprocess
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

from delaycomp.child import parent_death_signal
from delaycomp.orchestrator.fmu import FATAL, FmuComponent, FmuRefused, interface
from delaycomp.orchestrator.master import ComponentBase
from delaycomp.system.plantfmu import check_declarations

__all__ = ["IsolatedFmu", "default_watchdog"]

#: the shortest watchdog a loop gets by default, seconds
WATCHDOG_FLOOR = 10.0
#: the default watchdog in base steps of the loop (a call may take 100 times real time)
WATCHDOG_STEPS = 100.0
#: the longest default watchdog, seconds (a day: the longest run delaycomp starts)
WATCHDOG_CEILING = 86400.0
#: instantiation, initialization, termination: this many times the watchdog
SLOW_CALLS = 6.0


def default_watchdog(h: float) -> float:
    """The default watchdog of a loop of base step ``h`` (seconds of simulated time), in
    seconds of wall time per FMI call: 100 steps of real time, at least 10 s and at most a
    day (the longest run delaycomp starts).

    >>> default_watchdog(0.01), default_watchdog(1.0), default_watchdog(1e308)
    (10.0, 100.0, 86400.0)
    """
    return min(WATCHDOG_CEILING, max(WATCHDOG_FLOOR, WATCHDOG_STEPS * h))


def check_watchdog(seconds: float) -> float:
    """``seconds`` as a watchdog, or ``ParameterError`` naming the allowed range."""
    from delaycomp.errors import ParameterError

    if not (isinstance(seconds, (int, float)) and math.isfinite(seconds) and seconds > 0):
        raise ParameterError(f"--watchdog {seconds!r} is not allowed: must be a finite "
                             "number of seconds > 0")
    return float(seconds)


def _exit_text(code: int | None) -> str:
    if code is None:
        return "it did not exit"
    if code < 0:
        try:
            return f"killed by signal {signal.Signals(-code).name}"
        except ValueError:
            return f"killed by signal {-code}"
    return f"exit status {code}" + (": it called exit()" if code == 0 else "")


class IsolatedFmu(ComponentBase):
    """One instance of the FMU file ``path``, run in a child process, with a watchdog of
    ``watchdog`` seconds on every call (see the module's docstring)."""

    def __init__(self, name: str, path: str | Path, watchdog: float,
                 tolerance: float | None = None):
        from fmpy import read_model_description

        self.name = name
        self.path = Path(path)
        self.watchdog = check_watchdog(watchdog)
        #: the relative tolerance given to fmi2SetupExperiment in the child (None: none)
        self.tolerance = tolerance
        md = read_model_description(str(self.path), validate=False)
        check_declarations(self.path, [(v.name, v.type, v.causality, v.valueReference)
                                       for v in md.modelVariables])
        (self.input_names, self.output_names, self.feedthrough_outputs,
         _) = interface(md, self.path)
        self.runs_python = False  # whatever it runs, it runs in the child
        self._vars = {v.name: v for v in md.modelVariables}
        self.messages: list[str] = []
        self.last_message: str | None = None
        self.worst_status = 0
        self._readers: dict = {}
        self._writers: dict = {}
        self._reads: list[tuple[str, ...]] = []  # reader i reads these outputs
        self._writes: list[tuple[str, ...]] = []
        self._registered = (0, 0)  # readers, writers the child knows
        self._pending: list[tuple[int, list[float]]] = []  # writes not yet sent
        self._values: list[list[float] | None] = []  # reader i's values, while valid
        self._ft: list[bool] = []  # reader i reads an output with direct feedthrough
        self._proc: subprocess.Popen | None = None
        self._conn: _Pipe | None = None
        self._busy = False  # a call was sent and its answer not read
        self._dead: str | None = None
        #: set once the child is started: the master's cleanup looks for it
        self.fmu: object | None = None

    # -- the child -----------------------------------------------------------------------
    def _start(self) -> None:
        from delaycomp.child import module_argv

        # a session of its own: the terminal's Ctrl-C (SIGINT to the foreground process
        # group) never reaches the child, not even while it starts, before ``serve``
        # ignores SIGINT (a KeyboardInterrupt there ended it, and the run was reported as
        # the plant's failure, with the child's traceback); it ends with this process all
        # the same (``parent_death_signal``, the pipe)
        proc = subprocess.Popen(module_argv("delaycomp.orchestrator.isolated", self.name,
                                            str(self.path)),
                                stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                start_new_session=True)
        assert proc.stdin is not None and proc.stdout is not None  # both are pipes
        self._proc, self.fmu = proc, proc
        self._conn = _Pipe(proc.stdout.fileno(), proc.stdin.fileno())

    def _fatal(self, reason: str) -> FmuRefused:
        self.worst_status = FATAL
        self.last_message = reason
        self._dead = reason
        self._stop()
        return FmuRefused(reason)

    def _stop(self) -> None:
        proc = self._proc
        if proc is None:
            return
        if proc.poll() is None:
            proc.kill()
        proc.wait()
        for stream in (proc.stdin, proc.stdout):
            if stream is not None:
                stream.close()
        self._proc = self._conn = self.fmu = None

    def _call(self, what: str, message: tuple, limit: float):
        """Send ``message``, wait at most ``limit`` seconds for the answer; its messages
        logged, its result returned, its refusal raised."""
        if self._dead is not None:
            raise FmuRefused(self._dead)
        conn = self._conn
        assert conn is not None and self._proc is not None  # started by setup()
        try:
            self._busy = True
            conn.send(message)
            reply = conn.recv(limit)
            if reply is None:
                raise self._fatal(f"{what} did not return within {limit:g} s: the FMU is "
                                  "stopped (the watchdog; --watchdog SECONDS sets it)")
            ok, payload, messages, last, worst = reply
            self._busy = False
        except (EOFError, OSError):
            try:
                code = self._proc.wait(2)
            except Exception:  # noqa: BLE001 - still running: it closed its pipe
                code = None
            raise self._fatal(f"the FMU ended its process during {what} "
                              f"({_exit_text(code)})") from None
        self.messages.extend(messages)
        if self.last_message is None:
            self.last_message = last
        self.worst_status = max(self.worst_status, worst)
        if not ok:
            raise FmuRefused(payload)
        return payload

    def _news(self) -> tuple[list, list]:
        """Readers and writers registered since the child last heard of them."""
        r, w = self._registered
        self._registered = (len(self._reads), len(self._writes))
        return self._reads[r:], self._writes[w:]

    # -- Component protocol --------------------------------------------------------------
    def setup(self, start_time: float, stop_time: float, parameters: dict) -> None:
        """Start the child and there instantiate, set up (with ``tolerance``) and enter
        initialization."""
        self._start()
        self._call("fmi2Instantiate", ("setup", start_time, stop_time, parameters,
                                       *self._news(), self.tolerance),
                   SLOW_CALLS * self.watchdog)

    def initialize(self) -> None:
        """Leave initialization mode (after sending the inputs set)."""
        self._sync("fmi2ExitInitializationMode", None, SLOW_CALLS * self.watchdog,
                   initialize=True)

    def _sync(self, what: str, step: tuple[float, float] | None, limit: float,
              initialize: bool = False) -> None:
        """The pending writes, then a step (or leaving initialization), then every
        reader's values: one round trip."""
        writes, self._pending = self._pending, []
        values = self._call(what, ("sync", *self._news(), writes, step, initialize),
                            limit)
        self._values = values

    def reader(self, names: Sequence[str]) -> Callable[[], list[float]]:
        """``() -> [values]`` of the outputs ``names``, from the last round trip where
        still valid."""
        i = len(self._reads)
        self._reads.append(tuple(names))
        self._values.append(None)
        self._ft.append(any(n in self.feedthrough_outputs for n in names))

        def read() -> list[float]:
            if self._pending and self._ft[i]:
                self._values = [None] * len(self._reads)
            if i >= len(self._values) or self._values[i] is None:
                self._sync("fmi2GetReal", None, self.watchdog)
            out = self._values[i]
            assert out is not None  # every reader's values come back with a sync
            return out
        return read

    def writer(self, names: Sequence[str]) -> Callable[[Sequence[float]], None]:
        """``(values) -> None``: the inputs ``names``, sent with the next round trip."""
        i = len(self._writes)
        self._writes.append(tuple(names))

        def write(values: Sequence[float]) -> None:
            self._pending.append((i, [float(v) for v in values]))
        return write

    def do_step(self, t: float, h: float) -> None:
        """``fmi2DoStep`` from ``t`` to ``t + h`` in the child, within the watchdog."""
        self._sync(f"fmi2DoStep from t = {t:.12g}", (t, h), self.watchdog)

    def get_state(self) -> bytes:
        """The FMU's serialized state (from the child)."""
        self._sync("fmi2SetReal", None, self.watchdog)
        return self._call("fmi2GetFMUstate", ("get_state",), self.watchdog)

    def set_state(self, data: bytes) -> None:
        """Restore a state of ``get_state`` (in the child)."""
        self._sync("fmi2SetReal", None, self.watchdog)
        self._call("fmi2SetFMUstate", ("set_state", data), self.watchdog)
        self._values = [None] * len(self._reads)

    def terminate(self) -> None:
        """Terminate and free the instance in the child, and end it; a child that is busy
        (a call in flight: the run was interrupted) or does not answer is stopped. Safe in
        any phase and more than once."""
        if self._proc is None:
            return
        try:
            if not self._busy and self._dead is None:
                self._call("fmi2Terminate", ("terminate",), SLOW_CALLS * self.watchdog)
                self._proc.wait(SLOW_CALLS * self.watchdog)
        except Exception:  # noqa: BLE001 - refused, or slow to leave: stopped below
            pass
        finally:
            self._stop()


# -- the child's side ----------------------------------------------------------------------

class _Child:
    """The FMU in the child process and its registered readers and writers."""

    def __init__(self, name: str, path: str):
        self.comp = FmuComponent(name, path)
        self.reads: list[Callable[[], list[float]]] = []
        self.writes: list[Callable[[Sequence[float]], None]] = []
        self.sent = 0  # messages forwarded so far

    def register(self, reads: Sequence, writes: Sequence) -> None:
        self.reads.extend(self.comp.reader(names) for names in reads)
        self.writes.extend(self.comp.writer(names) for names in writes)

    def handle(self, message: tuple):
        op = message[0]
        comp = self.comp
        if op == "setup":
            _, start, stop, parameters, reads, writes, comp.tolerance = message
            self.register(reads, writes)
            comp.setup(start, stop, parameters)
            return None
        if op == "sync":
            _, reads, writes, pending, step, initialize = message
            self.register(reads, writes)
            for i, values in pending:
                self.writes[i](values)
            if initialize:
                comp.initialize()
            if step is not None:
                comp.do_step(*step)
            return [read() for read in self.reads]
        if op == "get_state":
            return comp.get_state()
        if op == "set_state":
            comp.set_state(message[1])
            return None
        if op == "terminate":
            comp.terminate()
            return None
        raise ValueError(f"unknown request {op!r}")

    def answer(self, ok: bool, payload) -> tuple:
        comp = self.comp
        news = comp.messages[self.sent:]
        self.sent = len(comp.messages)
        return ok, payload, news, comp.last_message, comp.worst_status


def serve(name: str, path: str) -> None:
    """The child process: open the FMU, answer requests (standard input to standard
    output, which is then standard error for whatever the FMU prints) until
    ``terminate`` or until the pipe closes (the parent is gone)."""
    import os

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle
    parent_death_signal(signal.SIGKILL)  # Linux: a killed parent takes the child along
    conn = _Pipe(os.dup(0), os.dup(1))
    os.dup2(os.open(os.devnull, os.O_RDONLY), 0)
    os.dup2(2, 1)  # the FMU's own prints: standard error, not the requests' pipe
    try:
        child = _Child(name, path)
    except BaseException as exc:  # noqa: BLE001 - reported to the parent, in one line
        conn.recv(None)
        conn.send((False, f"{type(exc).__name__}: {exc}", [], None, FATAL))
        os._exit(0)
    while True:
        try:
            message = conn.recv(None)
        except (EOFError, OSError):
            break
        try:
            reply = child.answer(True, child.handle(message))
        except BaseException as exc:  # noqa: BLE001 - the reason goes to the parent
            reason = child.comp.last_message or str(exc) or type(exc).__name__
            reply = child.answer(False, reason)
        conn.send(reply)
        if message[0] == "terminate":
            break
    os._exit(0)  # no interpreter teardown: unloading the FMU there may crash (pythonfmu)


class _Pipe:
    """Pickled messages, each after its length (8 bytes), over a pair of file
    descriptors; ``recv`` waits at most ``timeout`` seconds (``None``: for ever) and
    gives ``None`` when the time is up."""

    def __init__(self, read_fd: int, write_fd: int):
        self.rfd, self.wfd = read_fd, write_fd
        #: Windows: the queue of the thread reading the next frame
        self._waiting: queue.Queue | None = None

    def send(self, message) -> None:
        import os
        import pickle

        data = pickle.dumps(message, protocol=pickle.HIGHEST_PROTOCOL)
        view = memoryview(len(data).to_bytes(8, "little") + data)
        while view:
            view = view[os.write(self.wfd, view):]

    def _read(self, n: int) -> bytes:
        import os

        parts, left = [], n
        while left:
            chunk = os.read(self.rfd, left)
            if not chunk:
                raise EOFError("the pipe closed")
            parts.append(chunk)
            left -= len(chunk)
        return b"".join(parts)

    def _frame(self):
        import pickle

        size = int.from_bytes(self._read(8), "little")
        return pickle.loads(self._read(size))

    def recv(self, timeout: float | None):
        if timeout is None:
            return self._frame()
        if sys.platform != "win32":
            import select

            if not select.select([self.rfd], [], [], timeout)[0]:
                return None
            return self._frame()
        return self._recv_by_thread(timeout)

    def _recv_by_thread(self, timeout: float):
        """Windows (``select`` takes sockets only): a thread reads the next frame; wait
        for it at most ``timeout`` (a frame that comes later is the next call's)."""
        import threading

        if self._waiting is None:
            waiting: queue.Queue = queue.Queue()

            def read() -> None:
                try:
                    waiting.put((True, self._frame()))
                except BaseException as exc:  # noqa: BLE001 - handed to the waiter
                    waiting.put((False, exc))
            threading.Thread(target=read, daemon=True).start()
            self._waiting = waiting
        try:
            ok, value = self._waiting.get(timeout=timeout)
        except queue.Empty:
            return None
        self._waiting = None
        if not ok:
            raise value
        return value


if __name__ == "__main__":
    serve(sys.argv[1], sys.argv[2])
