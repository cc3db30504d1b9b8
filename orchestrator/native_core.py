"""The native stepping core: a loop of native FMUs stepped from C.

When every component of a run is a native FMU in this process (``FmuComponent``: a C
binary that runs no Python, not clocked, its FMI functions at hand), the master sets the
loop up, initializes it and terminates it as always, and ``NativeCore`` hands the
stepping in between to ``fmus/native/host/stepping.c`` (``delaycomp.fmu.host.core_library``,
loaded with ctypes): the same FMI calls with the same arguments in the same order as
``Master.step``, so the same rows, bit for bit, without a Python call per FMI call. The
rows come back in blocks, to the master's recorder and its sink; between blocks Python
runs (the progress bar, Ctrl-C). A failure inside the core is raised as the Python master
raises it: the same ``SimulationError``, at the same tick, with the same message.

``why_not(master)`` says why a master cannot hand its loop over (``None``: it can).
``run_blocks`` is the core's block loop, which a run replayed from its recipe
(``delaycomp.orchestrator.replay``) shares; this module imports neither numpy nor fmpy
until a master's run needs them.
"""

from __future__ import annotations

import ctypes
import time
from collections.abc import Callable
from ctypes import POINTER, Structure, c_double, c_int32, c_int64, c_uint, c_void_p
from typing import TYPE_CHECKING, cast

from delaycomp.orchestrator.interrupts import interrupt_held

if TYPE_CHECKING:
    from delaycomp.orchestrator.fmu import FmuComponent
    from delaycomp.orchestrator.master import Master, Recorder

__all__ = ["CORE_DONE", "CORE_FULL", "STEPPING", "CoreCallbacks2", "CoreComponent",
           "CoreFailure", "CoreLog", "CoreLoop", "CoreOp", "NativeCore", "core_library_loaded",
           "core_ops", "core_path", "core_status", "make_loop", "run_blocks", "why_not",
           "why_not_files"]

#: how a run is stepped: ``auto`` (the native core where ``why_not`` finds nothing against
#: it, else the Python master), ``native-core`` (the core, or the run is refused saying
#: why), ``python`` (the Python master)
STEPPING = ("auto", "native-core", "python")

_OP_GET, _OP_SET = 0, 1
_DONE, _FULL, _STEP, _STEP3, _CALL, _LOGGED, _NONFINITE, _BAD = range(8)
#: rows a block holds at most (a block is also at most about ``_BLOCK_SECONDS`` of work)
_MAX_BLOCK = 1 << 16
#: values a block's rows hold at most (8 MB: a loop of many states gets fewer rows)
_MAX_BLOCK_VALUES = 1 << 20
_BLOCK_SECONDS = 0.05


class _Component(Structure):
    _fields_ = [("instance", c_void_p), ("get", c_void_p), ("set", c_void_p),
                ("step", c_void_p), ("fmi", c_int32), ("worst", POINTER(c_int32))]


class _Op(Structure):
    _fields_ = [("kind", c_int32), ("comp", c_int32), ("n", c_int64),
                ("vrs", POINTER(c_uint)), ("slots", POINTER(c_int64))]


class _Loop(Structure):
    _fields_ = [("ncomp", c_int64), ("comps", POINTER(_Component)), ("nops", c_int64),
                ("ops", POINTER(_Op)), ("nslots", c_int64), ("slots", POINTER(c_double)),
                ("scratch", POINTER(c_double)), ("t0", c_double), ("T", c_double),
                ("h", c_double), ("N", c_int64), ("ncols", c_int64),
                ("cols", POINTER(c_int64)), ("every", c_int64), ("final", c_int64)]


class _Failure(Structure):
    _fields_ = [("code", c_int32), ("comp", c_int32), ("op", c_int32), ("status", c_int32),
                ("flag", c_int32)]


class _Log(Structure):
    """The core's logger's record of one instance (``CoreLog``): the worst status logged
    and the number of messages."""
    _fields_ = [("worst", c_int32), ("count", c_int32)]


class _Callbacks2(Structure):
    """``fmi2CallbackFunctions`` as the core fills it (``core_callbacks2``)."""
    _fields_ = [("logger", c_void_p), ("allocateMemory", c_void_p), ("freeMemory", c_void_p),
                ("stepFinished", c_void_p), ("componentEnvironment", c_void_p)]


#: the core's structures by their C names, for a host that sets FMUs up itself
#: (``delaycomp.orchestrator.replay``)
CoreComponent = _Component
CoreOp = _Op
CoreLoop = _Loop
CoreFailure = _Failure
CoreLog = _Log
CoreCallbacks2 = _Callbacks2
#: ``core_run``'s and ``core_propagate``'s codes: the stop tick reached, the row buffer full
CORE_DONE, CORE_FULL = _DONE, _FULL


_LIB: ctypes.CDLL | None = None
_LIB_PATH: str | None = None
_WHY: str | None = None


def _bind(lib: ctypes.CDLL) -> ctypes.CDLL:
    """``lib`` with its functions' types declared; ``ValueError`` where its structures'
    layout is not this module's (a library of another build: never pass it our structs)."""
    sizes = (c_int64 * 6)()
    lib.core_layout(sizes)
    ours = [ctypes.sizeof(s) for s in (_Component, _Op, _Loop, _Failure, _Log, _Callbacks2)]
    if list(sizes) != ours:
        raise ValueError(f"the native stepping core's layout {list(sizes)} is not this "
                         f"module's {ours}")
    lib.core_run.restype = c_int32
    lib.core_run.argtypes = [POINTER(_Loop), POINTER(c_int64), c_int64, POINTER(c_double),
                             POINTER(c_double), c_int64, POINTER(c_int64), POINTER(_Failure)]
    lib.core_propagate.restype = c_int32
    lib.core_propagate.argtypes = [POINTER(_Loop), POINTER(_Failure)]
    lib.core_callbacks2.restype = None
    lib.core_callbacks2.argtypes = [POINTER(_Callbacks2), POINTER(_Log)]
    lib.core_logger3.restype = None
    lib.core_logger3.argtypes = [POINTER(c_void_p)]
    return lib


def _load() -> ctypes.CDLL | None:
    """The core's library, compiled on first use (``core_library``) and loaded once per
    process; ``None`` where it cannot be had here (``_WHY`` says why)."""
    global _LIB, _WHY, _LIB_PATH
    if _LIB is None and _WHY is None:
        from delaycomp.fmu.host import core_library
        from delaycomp.fmu.toolchain import NativeBuildError

        try:
            path = str(core_library())
            _LIB, _LIB_PATH = _bind(ctypes.CDLL(path)), path
        except (NativeBuildError, OSError, ValueError) as exc:
            _WHY = (str(exc) if isinstance(exc, ValueError)
                    else f"the native stepping core is not available here: {exc}")
            return None
    return _LIB


def core_path() -> str | None:
    """The path of the core's library this process loaded (``None``: none yet)."""
    return _LIB_PATH


def core_library_loaded(path: str) -> ctypes.CDLL | None:
    """The core's library at ``path`` (a replayed run's, ``delaycomp.orchestrator.replay``),
    loaded once per process without compiling anything; ``None`` where it is not this
    process's core (another path once one is loaded, a missing file, another layout)."""
    global _LIB, _LIB_PATH
    if _LIB is not None:
        return _LIB if _LIB_PATH == path else None
    try:
        _LIB, _LIB_PATH = _bind(ctypes.CDLL(path)), path
    except (OSError, ValueError):
        return None
    return _LIB


def core_status() -> str | None:
    """``None`` where the native stepping core can be had here (compiling it on the first
    call), else why not."""
    _load()
    return _WHY


def why_not(master: Master) -> str | None:
    """Why ``master`` cannot hand its stepping to the native core, in words, or ``None``:
    every component must be a native FMU of this process (``FmuComponent``, no Python in
    its binary, no clock), and the core's library must be here (compiled on the first
    call). Asked before ``setup``: nothing runs yet."""
    from delaycomp.orchestrator.fmu import FmuComponent

    for c in master.components.values():
        if type(c) is not FmuComponent:
            kind = ("an FMU in a child process (another tool's)"
                    if type(c).__name__ == "IsolatedFmu" else f"a {type(c).__name__}")
            return f"{c.name} is {kind}, not a native FMU of this process"
        if c.runs_python:
            return f"{c.name} is a Python FMU"
        if c.clocked:
            return f"{c.name} is a clocked FMI 3.0 FMU (its ticks are scheduled in Python)"
    _load()
    return _WHY


def why_not_files(loop, fmus: dict | None) -> str | None:
    """``why_not`` asked of a loop and the FMU files that will run it (``fmus``, instance
    -> file, as ``run_loop`` takes them; an instance without one runs its Python FMU),
    before anything is set up: for a command to refuse ``--stepping native-core`` before
    any work. ``why_not(master)`` has the last word."""
    import zipfile
    from xml.etree import ElementTree

    from delaycomp.orchestrator.fmu import python_generated
    from delaycomp.system import FmuFile

    for inst in loop.instances:
        if isinstance(inst.source, FmuFile):
            return (f"{inst.name} is an FMU file of another tool (it runs in a child "
                    "process)")
        path = (fmus or {}).get(inst.name)
        if path is None:
            return f"{inst.name} is a Python FMU"
        try:
            with zipfile.ZipFile(path) as zf:
                root = ElementTree.fromstring(zf.read("modelDescription.xml"))
        except (OSError, KeyError, zipfile.BadZipFile, ElementTree.ParseError):
            continue  # the run refuses the file itself, in its own words
        if python_generated(root.get("generationTool")):
            return f"{inst.name} is a Python FMU"
        if any(v.tag == "Clock" and v.get("causality") == "input"
               for v in root.iter("Clock")):
            return f"{inst.name} is a clocked FMI 3.0 FMU (its ticks are scheduled in Python)"
    _load()
    return _WHY


class NativeCore:
    """The stepping of ``master`` (set up and initialized, ``why_not(master)`` is ``None``)
    and its ``recorder`` handed to the native core: ``run_until(ticks)`` as
    ``Master.run_until`` does it. Raises ``RuntimeError`` where a component's FMI
    functions are not at hand (fmpy with an FMI call logger)."""

    def __init__(self, master: Master, recorder: Recorder):
        lib = _load()
        if lib is None:  # why_not(master) said so
            raise RuntimeError(_WHY)
        self._lib, self.master, self.recorder = lib, master, recorder
        comps = cast("list[FmuComponent]", master.stepping)  # why_not(master) is None
        table = (_Component * len(comps))()
        self._cells = [c_int32(0) for _ in comps]
        for i, c in enumerate(comps):
            functions = c.native_functions()
            if functions is None:  # an FMI call logger set on fmpy: calls go through it
                raise RuntimeError(f"{c.name}'s FMI functions are not at hand")
            table[i] = _Component(*functions, 3 if c.fmi3 else 2,
                                  ctypes.pointer(self._cells[i]))
        #: each op as the master's tick_plan names it
        self._ops = master.tick_plan()
        recorded = recorder.slots
        self._loop, self._keep = make_loop(
            table, core_ops(master), master.values, (master.t0, master.T, master.h, master.N),
            recorded, recorder.every, -1 if recorder.final is None else recorder.final)
        self._keep.append(table)
        self._slots = self._keep[0]
        self._comps = comps
        self._ncols = len(recorded)

    def run_until(self, ticks: int, progress: Callable[[int], None] | None = None) -> None:
        """Step until tick ``ticks`` (``Master.run_until``) with ``run_blocks``, the rows
        of each block handed to the recorder (``Recorder.record_block``); ``progress(k)``
        about every 1 % of the way, as the Python master's run reports it."""
        import numpy as np

        master, ncols = self.master, self._ncols

        def record(k: int, times, rows, n: int) -> None:
            master.k = k
            if n:
                self.recorder.record_block(np.frombuffer(times, count=n),
                                           np.frombuffer(rows, count=n * ncols
                                                         ).reshape(n, ncols))

        for c, cell in zip(self._comps, self._cells):
            cell.value = c.worst_status
            c.worst_cell = cell  # its logger keeps the cell at its worst status
        try:
            code, _, failure = run_blocks(self._lib, self._loop, master.k, ticks, ncols,
                                          record, progress)
            if code != _DONE:
                self._raise(code, failure)
        finally:
            values = master.values
            values[:] = self._slots[:len(values)]
            for c in self._comps:
                c.worst_cell = None

    def _raise(self, code: int, failure: _Failure):
        """Raise the error the Python master raises for the failure the core reports."""
        master = self.master
        values = master.values
        values[:] = self._slots[:len(values)]
        k = master.k
        if code in (_STEP, _STEP3):
            comp = self._comps[failure.comp]
            t = master.time_of(k)
            try:
                if code == _STEP:
                    comp.call_failed_with("DoStep", failure.status)
                comp.step_refused(t, master.h, failure.flag == 1, failure.flag == 2)
            except Exception as exc:  # noqa: BLE001 - reported as Master.step reports it
                master.step_failed(comp, exc, t)
        if code in (_CALL, _LOGGED):
            kind, op_comp, _, _ = self._ops[failure.op]
            comp = cast("FmuComponent", op_comp)
            try:
                if code == _CALL:
                    comp.call_failed_with("GetReal" if kind == "get" else "SetReal",
                                          failure.status)
                comp.read_refused()
            except Exception as exc:  # noqa: BLE001 - reported as the propagation reports it
                master.propagation_failed(exc, k)
        if code == _NONFINITE:
            master.refuse_nonfinite(k)
        raise RuntimeError(f"the native stepping core stopped with code {code}")


def run_blocks(lib: ctypes.CDLL, loop: _Loop, k: int, ticks: int, ncols: int,
               on_block: Callable[[int, ctypes.Array, ctypes.Array, int], None],
               progress: Callable[[int], None] | None = None) -> tuple[int, int, _Failure]:
    """``core_run`` of ``loop`` from tick ``k`` to ``ticks``, in blocks of at most
    ``_MAX_BLOCK`` rows (``_MAX_BLOCK_VALUES`` values) and about ``_BLOCK_SECONDS`` of
    work. After each block, with Ctrl-C held (``interrupt_held``: the tick reached and the
    rows kept then agree), ``on_block(k, times, rows, n)`` gets the tick reached and the
    block's ``n`` rows: ``times[:n]`` and ``rows[:n * ncols]``, one row after the other
    (ctypes arrays, reused by the next block). ``progress(k)`` about every 1 % of the way.
    Returns ``(code, k, failure)``: ``CORE_DONE``, or the code of the failure that
    stopped the core and its description, and the tick reached."""
    kk = c_int64(k)
    nrows = c_int64(0)
    failure = _Failure()
    chunk = max(1, ticks // 100) if progress is not None else None
    next_report = k + chunk if chunk else ticks
    block = 64  # ticks of the first block; then about _BLOCK_SECONDS of work each
    capacity = max(1, min(_MAX_BLOCK, _MAX_BLOCK_VALUES // max(1, ncols)))
    times = (c_double * capacity)()
    rows = (c_double * (capacity * max(1, ncols)))()
    while kk.value < ticks:
        begun = kk.value
        stop = min(ticks, next_report, begun + block)
        started = time.perf_counter()
        with interrupt_held():
            code = lib.core_run(ctypes.byref(loop), ctypes.byref(kk), stop, times, rows,
                                capacity, ctypes.byref(nrows), ctypes.byref(failure))
            spent = time.perf_counter() - started
            on_block(kk.value, times, rows, nrows.value)
        if code not in (_DONE, _FULL):
            return code, kk.value, failure
        if progress is not None and kk.value >= next_report:
            progress(kk.value)
        if kk.value >= next_report:
            next_report = min(ticks, kk.value + (chunk or ticks))
        if spent > 0:
            rate = max(1, kk.value - begun) / spent
            block = int(min(max(64.0, rate * _BLOCK_SECONDS), 1e12))
    return _DONE, kk.value, failure


def core_ops(master: Master) -> list[tuple[int, int, list[int], list[int]]]:
    """``master.tick_plan()`` as the core takes it: ``(kind, component, value references,
    slots)`` each, the kind ``0`` for a read and ``1`` for a write, the component by its
    index in ``master.stepping``."""
    index = {c.name: i for i, c in enumerate(master.stepping)}
    return [(_OP_GET if kind == "get" else _OP_SET, index[comp.name],
             cast("FmuComponent", comp).value_references(names), list(slots))
            for kind, comp, names, slots in master.tick_plan()]


def make_loop(components: ctypes.Array, ops, values, timing: tuple[float, float, float, int],
              columns, every: int, final: int) -> tuple[_Loop, list]:
    """The core's loop (``CoreLoop``) over ``components`` (a ``CoreComponent`` array, in
    stepping order) and ``ops`` (``core_ops``), its value vector starting at ``values``,
    ``timing`` ``(t0, T, h, N)``, recording the slots ``columns`` every ``every`` ticks and
    at tick ``final`` (-1: none); and every ctypes object it points into, to keep alive
    with it, the value vector first."""
    keep: list = []
    table = (_Op * max(1, len(ops)))()
    widest = 1
    for o, (kind, comp, vrs, where) in enumerate(ops):
        refs = (c_uint * max(1, len(vrs)))(*vrs)
        at = (c_int64 * max(1, len(where)))(*where)
        keep += [refs, at]
        table[o] = _Op(kind, comp, len(vrs), refs, at)
        widest = max(widest, len(vrs))
    slots = (c_double * max(1, len(values)))(*values)
    scratch = (c_double * widest)()
    cols = (c_int64 * max(1, len(columns)))(*columns)
    t0, T, h, N = timing
    loop = _Loop(len(components), components, len(ops), table, len(values), slots, scratch,
                 t0, T, h, N, len(columns), cols, every, final)
    return loop, [slots, table, scratch, cols, *keep]
