"""A run of native FMUs replayed from its recipe, without numpy, fmpy or the loop's model.

A run that the native stepping core stepped (``delaycomp.orchestrator.native_core``) and
in which no FMU said anything (no message logged, every FMI call returned OK) leaves its
recipe (``recipe_of``): everything the master did to the FMUs, as data. Which FMU binaries
it loaded and how it instantiated them; the experiment (tolerance, start, stop) and every
parameter it set, in order, with its type and value; the per-tick plan the core steps;
the reads with which it checked the initial outputs, and their values; the timing, the
recorded columns and the stop tick. ``replay(recipe)`` makes the same FMI calls with the
same arguments in the same order from ctypes, the stepping in the same core, and so gives
the same rows, bit for bit, at the price of a Python start and ctypes: numpy, fmpy, lxml
and the model of the loop are not imported.

A replay gives way (``NotReplayed``) the moment anything differs from the recorded run:
a binary or the core's library missing, an FMI call that does not return OK, an FMU that
logs a message, an initial output that is not the recorded value, a failure in the core.
Its caller then runs the loop whole, which reports whatever happened in its own words.
"""

from __future__ import annotations

import ctypes
import os
from collections.abc import Callable, Sequence
from ctypes import (
    POINTER,
    c_bool,
    c_char_p,
    c_double,
    c_float,
    c_int,
    c_int32,
    c_int64,
    c_size_t,
    c_uint,
    c_void_p,
)
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from delaycomp.errors import DelaycompError, Interrupted
from delaycomp.maths.grid import tick_time
from delaycomp.orchestrator.interrupts import interrupt_held
from delaycomp.orchestrator.native_core import (
    CORE_DONE,
    CoreCallbacks2,
    CoreComponent,
    CoreFailure,
    CoreLog,
    CoreLoop,
    core_library_loaded,
    core_ops,
    core_path,
    make_loop,
    run_blocks,
)

if TYPE_CHECKING:
    from delaycomp.orchestrator.master import Master, Recorder

__all__ = ["FORMAT", "NotReplayed", "Replayed", "recipe_of", "replay"]

#: the recipe's format: a recipe of another format is not replayed
FORMAT = 1

#: an FMI 3.0 parameter's setter and the ctypes type of its values, by variable type
_SETTERS3: dict[str, tuple[str, Any]] = {
    "Float64": ("fmi3SetFloat64", c_double), "Float32": ("fmi3SetFloat32", c_float),
    "Int32": ("fmi3SetInt32", c_int32), "Int64": ("fmi3SetInt64", c_int64),
    "Boolean": ("fmi3SetBoolean", c_bool), "String": ("fmi3SetString", c_char_p)}
#: an FMI 2.0 parameter's setter and the ctypes type of its value, by variable type
_SETTERS2: dict[str, tuple[str, Any]] = {
    "Real": ("fmi2SetReal", c_double), "Integer": ("fmi2SetInteger", c_int),
    "Boolean": ("fmi2SetBoolean", c_int), "String": ("fmi2SetString", c_char_p)}


class NotReplayed(DelaycompError):
    """The replay could not go as the recorded run went (the reason in words): the
    caller runs the loop whole. No row it handed on is a result."""


def recipe_of(master: Master, recorder: Recorder, ticks: int,
              initial: Sequence[tuple[str, Sequence[str], Sequence[float]]] = ()
              ) -> dict | None:
    """The recipe of a run that the native core stepped to tick ``ticks``, after it
    ended well (before ``master.terminate``), or ``None`` where it cannot be replayed: a
    component that is not a native FMU of this process or that logged a message, a
    binary that fmpy does not name, a parameter of a type the replay does not set.
    ``initial``: the reads with which the run checked its initial outputs, as
    ``(instance, outputs, values)``. The recipe is JSON (the FMUs' folders by path, as
    this process unpacked them: a caller that keeps it keeps their files too).

    Examples
    --------
    >>> from delaycomp.orchestrator.master import Master, Recorder
    >>> m = Master([], [], T=1.0, N=10)
    >>> recipe_of(m, Recorder(m, []), 10) is None  # no FMU: nothing to replay
    True
    """
    from delaycomp.orchestrator.fmu import FmuComponent

    comps = master.stepping
    path = core_path()
    if not comps or path is None:
        return None
    folders: list[str] = []
    components = []
    for c in comps:
        if (type(c) is not FmuComponent or c.runs_python or c.clocked or c.messages
                or c.worst_status or c.experiment is None or c.fmu is None):
            return None
        library = c.library()
        if library is None or os.path.commonpath([library, c.unzipped]) != c.unzipped:
            return None
        kinds = _SETTERS3 if c.fmi3 else _SETTERS2
        if any(kind not in kinds for kind, _, _ in c.parameter_calls):
            return None
        if c.unzipped not in folders:
            folders.append(c.unzipped)
        tolerance, start, stop = c.experiment
        components.append({
            "name": c.name, "fmi": 3 if c.fmi3 else 2, "folder": folders.index(c.unzipped),
            "library": os.path.relpath(library, c.unzipped),
            "guid": c.md.guid,
            "tolerance": None if tolerance is None else float(tolerance),
            "start": float(start), "stop": float(stop),
            "parameters": [[kind, vr, list(values)] for kind, vr, values in c.parameter_calls]})
    index = {c.name: i for i, c in enumerate(comps)}
    reads = [[index[name], comps[index[name]].value_references(list(outputs)),
              [float(v) for v in values]] for name, outputs, values in initial]
    return {"format": FORMAT, "core": path, "folders": folders, "components": components,
            "ops": [list(op) for op in core_ops(master)], "nslots": len(master.values),
            "initial": reads,
            "t0": master.t0, "T": master.T, "N": master.N, "h": master.h, "ticks": ticks,
            "every": recorder.every, "final": recorder.final if recorder.final is not None
            else -1, "columns": recorder.slots, "names": list(recorder.names)}


@dataclass
class Replayed:
    """What a replay recorded: ``rows`` rows, the last at ``last_time`` with the values
    ``last_row`` (one per column of ``names``)."""

    names: list[str]
    rows: int
    last_time: float
    last_row: list[float]


def _time_of(recipe: dict, k: int) -> float:
    """``Master.time_of``: tick ``k``'s time (``tick_time``)."""
    return tick_time(k, recipe["t0"], recipe["T"], recipe["h"], recipe["N"])


class _Instance:
    """One FMU instance of a replay, its calls checked: a status other than OK, or a
    message logged, is ``NotReplayed``."""

    def __init__(self, spec: dict, folder: str):
        self.spec = spec
        self.name = spec["name"]
        self.fmi3 = spec["fmi"] == 3
        self.folder = folder
        self.log = CoreLog(0, 0)
        self.handle: int | None = None
        self.terminated = False
        library = os.path.join(folder, spec["library"])
        if not os.path.isfile(library):
            raise NotReplayed(f"{self.name}'s binary is gone: {library}")
        here = os.getcwd()
        os.chdir(os.path.dirname(library))  # as fmpy loads it: beside its dependencies
        try:
            self.dll = ctypes.CDLL(library)
        except OSError as exc:
            raise NotReplayed(f"{self.name}'s binary does not load: {exc}") from None
        finally:
            os.chdir(here)

    def function(self, name: str, restype: Any, *argtypes: Any):
        fn = getattr(self.dll, name)
        fn.restype = restype
        fn.argtypes = list(argtypes)
        return fn

    def address(self, name: str) -> int:
        return ctypes.cast(getattr(self.dll, name), c_void_p).value or 0

    def check(self, what: str, status: int | None = 0) -> None:
        if status != 0 or self.log.count:
            raise NotReplayed(f"{self.name}: {what} returned {status} "
                              f"({self.log.count} messages logged)")

    def instantiate(self, lib: ctypes.CDLL) -> None:
        spec = self.spec
        if self.fmi3:
            logger = c_void_p()
            lib.core_logger3(ctypes.byref(logger))
            resources = os.path.join(self.folder, "resources") + "/"
            fn = self.function("fmi3InstantiateCoSimulation", c_void_p, c_char_p, c_char_p,
                               c_char_p, c_bool, c_bool, c_bool, c_bool, POINTER(c_uint),
                               c_size_t, c_void_p, c_void_p, c_void_p)
            self.handle = fn(self.name.encode(), spec["guid"].encode(), resources.encode(),
                             False, True, False, False, (c_uint * 0)(), 0,
                             ctypes.addressof(self.log), logger, None)
        else:
            from pathlib import Path

            self.callbacks = CoreCallbacks2()
            lib.core_callbacks2(ctypes.byref(self.callbacks), ctypes.byref(self.log))
            uri = Path(self.folder, "resources").as_uri()
            fn = self.function("fmi2Instantiate", c_void_p, c_char_p, c_int, c_char_p,
                               c_char_p, POINTER(CoreCallbacks2), c_int, c_int)
            self.handle = fn(self.name.encode(), 1, spec["guid"].encode(), uri.encode(),
                             ctypes.byref(self.callbacks), 0, 1)
        if not self.handle:
            raise NotReplayed(f"{self.name}: the FMU was not instantiated")
        self.check("instantiation", 0)

    def setup(self) -> None:
        spec = self.spec
        tolerance = spec["tolerance"]
        defined = tolerance is not None
        if self.fmi3:
            enter = self.function("fmi3EnterInitializationMode", c_int, c_void_p, c_bool,
                                  c_double, c_double, c_bool, c_double)
            self.check("fmi3EnterInitializationMode",
                       enter(self.handle, defined, tolerance if defined else 0.0,
                             spec["start"], True, spec["stop"]))
        else:
            experiment = self.function("fmi2SetupExperiment", c_int, c_void_p, c_int,
                                       c_double, c_double, c_int, c_double)
            self.check("fmi2SetupExperiment",
                       experiment(self.handle, int(defined), tolerance if defined else 0.0,
                                  spec["start"], 1, spec["stop"]))
            enter = self.function("fmi2EnterInitializationMode", c_int, c_void_p)
            self.check("fmi2EnterInitializationMode", enter(self.handle))
        for kind, vr, values in spec["parameters"]:
            name, ctype = (_SETTERS3 if self.fmi3 else _SETTERS2)[kind]
            data = (ctype * len(values))(*[v.encode("utf-8") if ctype is c_char_p else v
                                           for v in values])
            vrs = (c_uint * 1)(vr)
            if self.fmi3:
                setter = self.function(name, c_int, c_void_p, POINTER(c_uint), c_size_t,
                                       POINTER(ctype), c_size_t)
                status = setter(self.handle, vrs, 1, data, len(values))
            else:
                setter = self.function(name, c_int, c_void_p, POINTER(c_uint), c_size_t,
                                       POINTER(ctype))
                status = setter(self.handle, vrs, 1, data)
            self.check(name, status)

    def initialize(self) -> None:
        name = "fmi3ExitInitializationMode" if self.fmi3 else "fmi2ExitInitializationMode"
        self.check(name, self.function(name, c_int, c_void_p)(self.handle))

    def read(self, vrs: list[int]) -> list[float]:
        n = len(vrs)
        out = (c_double * max(1, n))()
        refs = (c_uint * max(1, n))(*vrs)
        if self.fmi3:
            get = self.function("fmi3GetFloat64", c_int, c_void_p, POINTER(c_uint), c_size_t,
                                POINTER(c_double), c_size_t)
            status = get(self.handle, refs, n, out, n)
        else:
            get = self.function("fmi2GetReal", c_int, c_void_p, POINTER(c_uint), c_size_t,
                                POINTER(c_double))
            status = get(self.handle, refs, n, out)
        self.check("the read of the initial outputs", status)
        return list(out[:n])

    def functions(self) -> tuple[int, int, int]:
        names = (("fmi3GetFloat64", "fmi3SetFloat64", "fmi3DoStep") if self.fmi3
                 else ("fmi2GetReal", "fmi2SetReal", "fmi2DoStep"))
        return tuple(self.address(n) for n in names)  # type: ignore[return-value]

    def terminate(self, ok: bool) -> bool:
        """``Terminate`` (where the run went well) and ``FreeInstance``: whether both
        went as recorded."""
        if self.handle is None:
            return True
        prefix = "fmi3" if self.fmi3 else "fmi2"
        status = 0
        try:
            if ok:
                status = self.function(prefix + "Terminate", c_int, c_void_p)(self.handle)
        finally:
            self.function(prefix + "FreeInstance", None, c_void_p)(self.handle)
            self.handle = None
        return status == 0 and not self.log.count


def replay(recipe: dict, on_rows: Callable[[list[float], int], None] | None = None,
           progress: Callable[[int], None] | None = None) -> Replayed:
    """Run ``recipe`` (``recipe_of``) again: the FMUs of its ``folders`` set up as the
    recorded run set them up, stepped by the native core to the recorded stop tick.
    ``on_rows(values, n)`` gets the recorded rows as they come, ``n`` rows of ``time`` and
    the columns, one after the other in ``values`` (``CsvStream.write_flat``);
    ``progress(k)`` about every 1 % of the way.

    Raises ``NotReplayed`` where anything differs from the recorded run (nothing it handed
    on is a result then), ``Interrupted`` on Ctrl-C (the time reached; the rows to it
    handed on)."""
    if recipe.get("format") != FORMAT:
        raise NotReplayed(f"a recipe of format {recipe.get('format')!r}, not {FORMAT}")
    lib = core_library_loaded(recipe["core"])
    if lib is None:
        raise NotReplayed(f"the native stepping core {recipe['core']} is not at hand")
    folders = recipe["folders"]
    instances: list[_Instance] = []
    ok = False
    k = 0
    try:
        for spec in recipe["components"]:
            instances.append(_Instance(spec, folders[spec["folder"]]))
        with interrupt_held():  # as the master's setup: a whole instantiation or none
            for inst in instances:
                inst.instantiate(lib)
                inst.setup()
        for inst in instances:
            inst.initialize()
        loop, keep = _loop(recipe, instances)
        ncols = len(recipe["columns"])
        replayed = Replayed(list(recipe["names"]), 0, 0.0, [])

        def rows_of(k_reached: int, times, rows, n: int) -> None:
            nonlocal k
            k = k_reached
            if not n:
                return
            replayed.rows += n
            replayed.last_time = times[n - 1]
            replayed.last_row = list(rows[(n - 1) * ncols:n * ncols])
            if on_rows is None:
                return
            width = ncols + 1
            flat = [0.0] * (n * width)
            flat[0::width] = times[:n]
            values = rows[:n * ncols]
            for j in range(ncols):
                flat[j + 1::width] = values[j::ncols]
            on_rows(flat, n)

        failure = CoreFailure()
        if lib.core_propagate(ctypes.byref(loop), ctypes.byref(failure)) != CORE_DONE:
            raise NotReplayed(f"the core stopped at tick 0 with code {failure.code}")
        _check_quiet(instances)
        slots = keep[0]
        # tick 0, as the master's initialize() records it (0 % every == 0: always due)
        rows_of(0, [_time_of(recipe, 0)], [slots[s] for s in recipe["columns"]], 1)
        for index, vrs, values in recipe["initial"]:  # check_initial's reads
            if instances[index].read(vrs) != values:
                raise NotReplayed(f"{instances[index].name}'s initial outputs differ")

        def block(k_reached: int, times, rows, n: int) -> None:
            rows_of(k_reached, times, rows, n)
            _check_quiet(instances)

        code, k, failure = run_blocks(lib, loop, 0, recipe["ticks"], ncols, block, progress)
        if code != CORE_DONE:
            raise NotReplayed(f"the core stopped at tick {k} with code {code}")
        ok = True
    except KeyboardInterrupt:  # as the master's run: the time reached
        raise Interrupted(_time_of(recipe, k)) from None
    finally:
        with interrupt_held():  # as Master.terminate: every instance freed
            clean = True
            for inst in instances:
                try:
                    clean = inst.terminate(ok) and clean
                except Exception:  # noqa: BLE001 - free the others; the run gives way
                    clean = False
    if not clean:
        raise NotReplayed("an FMU's termination did not go as recorded")
    return replayed


def _check_quiet(instances: Sequence[_Instance]) -> None:
    for inst in instances:
        if inst.log.count:
            raise NotReplayed(f"{inst.name} logged {inst.log.count} messages")


def _loop(recipe: dict, instances: Sequence[_Instance]) -> tuple[CoreLoop, list]:
    """The core's loop of a replay (``make_loop``), and the ctypes objects it points into
    (to keep; the value vector first)."""
    comps = (CoreComponent * len(instances))()
    for i, inst in enumerate(instances):
        comps[i] = CoreComponent(inst.handle, *inst.functions(), 3 if inst.fmi3 else 2,
                                 ctypes.cast(ctypes.pointer(inst.log), POINTER(c_int32)))
    loop, keep = make_loop(comps, recipe["ops"], [0.0] * recipe["nslots"],
                           (recipe["t0"], recipe["T"], recipe["h"], recipe["N"]),
                           recipe["columns"], recipe["every"], recipe["final"])
    return loop, [*keep, comps]
