"""An FMI 2.0 or FMI 3.0 co-simulation FMU as a master component, through fmpy.

FMI 3.0 (``fmiVersion="3.0"``, fmpy's ``FMU3Slave``): the master addresses variables by
their FMI 2.0 names as everywhere else. Inputs and outputs are scalar ``Float64``
variables (an FMU with array inputs or outputs is refused, naming one); a parameter named
as an element of an array variable (``A[2,1]``: row 2, column 1, from 1, as FMI 2.0 FMUs
name their scalars) is set with the rest of its array in one ``fmi3SetFloat64`` (the
elements not given keep their start values); ``Integer`` is ``Int32``.

A clocked FMI 3.0 FMU (an input ``Clock``, time-based and periodic, ``intervalVariability``
fixed or constant, shift 0: delaycomp's clocked controller) runs with event mode: its
clocked inputs are kept by the component between ticks and handed to the FMU at each tick
``t0 + i T`` (event mode, the inputs, ``fmi3SetClock``, ``fmi3UpdateDiscreteStates``,
step mode) when the master writes them there, or at the latest before its step from that
instant; its clocked outputs hold their values between ticks.
"""

from __future__ import annotations

import atexit
import itertools
import json
import math
import shutil
import struct
import weakref
from collections.abc import Callable, Sequence
from ctypes import byref, c_bool, c_double, c_int, c_int32, c_size_t, c_void_p
from pathlib import Path
from typing import TYPE_CHECKING, Literal

import fmpy
from fmpy import read_model_description
from fmpy.fmi1 import FMICallException, calloc, free
from fmpy.fmi2 import (
    FMU2Slave,
    fmi2CallbackAllocateMemoryTYPE,
    fmi2CallbackFreeMemoryTYPE,
    fmi2CallbackFunctions,
    fmi2CallbackLoggerTYPE,
    fmi2Real,
    fmi2ValueReference,
)

from delaycomp.errors import DelaycompError, ParameterError
from delaycomp.maths.grid import on_tick
from delaycomp.names import array_element, flat_index
from delaycomp.orchestrator.master import ComponentBase, interrupt_held
from delaycomp.tmpfiles import mkdtemp
from delaycomp.unpack import extract

if TYPE_CHECKING:
    from fmpy.model_description import ModelDescription

FATAL = 4
_TRUE = c_int(1)  # fmi2True
_TRUE3 = c_bool(True)  # fmi3True
#: Callback structures handed to FMUs. The pythonfmu runtime outlives ``fmi2FreeInstance``
#: (it keeps a thread and its interpreter state until the library is unloaded at exit), so a
#: callback freed with its component can be called after the fact: keep them all alive.
_KEEPALIVE: list = []
#: fmpy's logger proxy keeps ONE Python logger for the whole process, so messages are routed
#: to their component by the componentEnvironment pointer the FMU passes back.
_COMPONENTS: dict[int, weakref.ReferenceType] = {}
_ENV_IDS = itertools.count(1)
#: FMI 2.0 names whose FMI 3.0 function is named otherwise
_FMI3_NAMES = {"GetReal": "GetFloat64", "SetReal": "SetFloat64"}
#: An FMI function of one instance as ``FmuComponent._raw`` returns it: the bare ctypes
#: function (it returns the fmi2Status) and the instance pointer to pass it first.
_RawCall = tuple[Callable[..., int], c_void_p]


def _route(env, instance_name, status, category, message):
    try:
        ref = _COMPONENTS.get(env or 0)
        comp = ref() if ref is not None else None
        if comp is not None:
            comp._logger(status, message)
    except KeyboardInterrupt:
        # Ctrl-C inside this callback, called by the FMU's C code: ctypes would print it
        # and drop it (the run went on, deaf to that Ctrl-C); raised again once Python
        # runs its handlers outside the callback (after the FMI call, or in the Python
        # FMU's slave, which reports it and the run knows it: Interrupted)
        import _thread

        _thread.interrupt_main()


_DISPATCH = fmi2CallbackLoggerTYPE(_route)


def _route3(env, status, category, message):
    _route(env, None, status, category, message)


def _dispatch3():
    from fmpy.fmi3 import fmi3LogMessageCallback

    global _DISPATCH3
    if _DISPATCH3 is None:
        _DISPATCH3 = fmi3LogMessageCallback(_route3)
    return _DISPATCH3


_DISPATCH3 = None


#: FMUs unpacked in this process, by (path, modification time, size): unpacking costs
#: milliseconds per FMU, more than a short run of the loop; instances of one FMU, and later
#: runs, share the folder. Removed at exit.
_UNPACKED: dict[tuple[str, int, int], tuple[ModelDescription, str]] = {}
#: The binaries folders of this platform (FMI 2.0 names it ``linux64``, FMI 3.0
#: ``x86_64-linux``).
_PLATFORMS = {fmpy.platform, getattr(fmpy, "platform_tuple", fmpy.platform)}


def needed_to_run(name: str) -> bool:
    """Is the member ``name`` of an FMU needed to run it here? Its modelDescription, its
    ``resources/`` (handed to it as ``fmuResourceLocation``), and this platform's
    ``binaries/`` folder (the library and whatever it loads beside it); not its
    ``sources/``, ``documentation/`` or other platforms' binaries (a Python FMU carries a
    Windows DLL of 0.26 MB).

    >>> [needed_to_run(n) for n in ("modelDescription.xml", "resources/a.json",
    ...  f"binaries/{fmpy.platform}/m.so", "binaries/other64/m.dll", "sources/m.c")]
    [True, True, True, False, False]
    """
    top, _, rest = name.partition("/")
    if top == "binaries":
        return rest.partition("/")[0] in _PLATFORMS
    return top not in ("sources", "documentation")


def _unpacked(path: Path) -> tuple[ModelDescription, str]:
    """The model description and unpacked folder of the FMU file ``path`` (cached)."""
    st = path.stat()
    key = (str(path.resolve()), st.st_mtime_ns, st.st_size)
    hit = _UNPACKED.get(key)
    if hit is None or not Path(hit[1]).is_dir():
        # named after this process: a later process removes it if this one was killed;
        # within the limits of delaycomp.unpack (a zip bomb is refused before writing,
        # its modelDescription.xml included)
        folder = str(extract(path, mkdtemp("delaycomp-fmu-"), include=needed_to_run))
        hit = _UNPACKED[key] = (read_model_description(folder), folder)
    return hit


@atexit.register
def _remove_unpacked() -> None:
    for _, folder in _UNPACKED.values():
        shutil.rmtree(folder, ignore_errors=True)


def python_generated(generation_tool: str | None) -> bool:
    """Was an FMU generated by pythonfmu (its modelDescription's ``generationTool``)? Its
    binary runs its slave in the host's interpreter."""
    return (generation_tool or "").startswith("PythonFMU")


def interface(md: ModelDescription, path: Path
              ) -> tuple[list[str], list[str], frozenset[str], bool]:
    """What the master needs of an FMU's model description: its inputs and outputs (in
    the description's order), the outputs with direct feedthrough, and whether it runs
    Python in its host (pythonfmu's binary runs its slave in the host's interpreter).
    Raises ``ValueError`` for an FMU without co-simulation."""
    if md.coSimulation is None:
        raise ValueError(f"{path.name} is not a co-simulation FMU")
    ports = [v for v in md.modelVariables
             if v.causality in ("input", "output") and v.type != "Clock"]
    arrays = [v.name for v in ports if getattr(v, "dimensions", None)]
    if arrays:
        raise ValueError(f"{path.name}: {arrays[0]} is an array input or output: the master "
                         "connects scalar ports only (FMI 3.0 arrays as parameters are fine)")
    inputs = [v.name for v in ports if v.causality == "input"]
    outputs = [v.name for v in ports if v.causality == "output"]
    feedthrough = frozenset(
        u.variable.name for u in md.outputs
        if u.dependencies is None or any(d.causality == "input" for d in u.dependencies))
    return inputs, outputs, feedthrough, python_generated(md.generationTool)


class FmuRefused(DelaycompError, RuntimeError):
    """The FMU logged an error while its call returned OK (see ``delaycomp.fmu.slave``)."""


class FmuComponent(ComponentBase):
    """One instance of a co-simulation FMU.

    Outputs whose declared ``dependencies`` name no input (an empty list, or only states,
    as Model Exchange FMUs declare a state output) have no direct feedthrough; every other
    output (an input among its dependencies, or none declared) is treated as depending on
    the inputs at the same instant.
    """

    def __init__(self, name: str, path: str | Path, tolerance: float | None = None):
        self.name = name
        self.path = Path(path)
        #: the relative tolerance given to fmi2SetupExperiment (None: not defined)
        self.tolerance = tolerance
        self.md, self._unzipdir = _unpacked(self.path)
        (self.input_names, self.output_names, self.feedthrough_outputs,
         self.runs_python) = interface(self.md, self.path)
        self._vars = {v.name: v for v in self.md.modelVariables}
        #: an FMI 3.0 FMU (fmpy's FMU3Slave; the FMI calls under their 3.0 names)
        self.fmi3 = (self.md.fmiVersion or "").startswith("3")
        #: fmi3DoStep's outputs (eventHandlingNeeded, terminateSimulation, earlyReturn,
        #: lastSuccessfulTime) and their pointers, made once for the hot path
        self._flags = (c_bool(), c_bool(), c_bool(), c_double())
        self._flag_refs = tuple(byref(f) for f in self._flags)
        #: a clocked FMI 3.0 FMU: its input clock, the inputs it clocks (names), and the
        #: schedule (interval, start, index of the next tick, in event mode, time)
        self._clock = next((v for v in self.md.modelVariables
                            if v.type == "Clock" and v.causality == "input"), None)
        if self._clock is not None and not self.fmi3:
            self._clock = None
        self._clocked = {v.name for v in self.md.modelVariables
                         if self._clock is not None and v.causality == "input"
                         and v.type != "Clock" and v.clocks}
        self._pending: dict[str, float] = {}
        self._interval = 0.0
        self._t0 = self._time = 0.0
        self._tick = 0
        self._in_event = False
        self.messages: list[str] = []
        self.last_message: str | None = None
        #: worst status an FMI call of this instance returned (0 = ok .. 4 = fatal)
        self.worst_status = 0
        self._vr_cache: dict[tuple[str, ...], list[int]] = {}
        self._readers: dict[tuple[str, ...], object] = {}
        self._writers: dict[tuple[str, ...], object] = {}
        self.fmu: FMU2Slave | None = None
        #: the instance's raw fmi2DoStep (None: not looked up yet; False: use fmpy's wrapper)
        self._do_step_fn: _RawCall | Literal[False] | None = None
        self._env_id = next(_ENV_IDS)
        _COMPONENTS[self._env_id] = weakref.ref(self)
        #: a ctypes ``c_int32`` kept at ``worst_status`` while a stepping core in C runs
        #: this component (``delaycomp.orchestrator.native_core``), else None
        self.worst_cell: c_int32 | None = None
        #: what ``setup`` did, for a replay of it (``delaycomp.orchestrator.replay``): the
        #: experiment ``(tolerance, start, stop)`` and every parameter set, in order, as
        #: ``(type, value reference, values)`` (FMI 3.0's type names, ``Real`` and the
        #: others of FMI 2.0)
        self.experiment: tuple[float | None, float, float] | None = None
        self.parameter_calls: list[tuple[str, int, list]] = []

    def _fn(self, name: str) -> str:
        """The FMI function ``name`` (FMI 2.0's: ``GetReal``) of this FMU's version."""
        return "fmi3" + _FMI3_NAMES.get(name, name) if self.fmi3 else "fmi2" + name

    # -- logging -----------------------------------------------------------------------
    def _logger(self, status, message):
        text = message.decode("utf-8", "replace") if isinstance(message, bytes) else str(message)
        self._note(status, text)
        if self.worst_cell is not None:  # a stepping core in C reads it after each read
            self.worst_cell.value = self.worst_status

    def _callbacks(self) -> fmi2CallbackFunctions:
        cb = fmi2CallbackFunctions()
        cb.logger = _DISPATCH
        cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
        cb.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
        cb.componentEnvironment = self._env_id
        try:  # fmpy's proxy formats the variadic message arguments
            from fmpy.logging import addLoggerProxy
            addLoggerProxy(byref(cb))
        except Exception:  # noqa: BLE001 - older fmpy has no proxy: messages unformatted
            pass
        _KEEPALIVE.append(cb)
        return cb

    # -- Component protocol ------------------------------------------------------------
    def _vrs(self, names: Sequence[str]) -> list[int]:
        key = tuple(names)
        vrs = self._vr_cache.get(key)
        if vrs is None:
            vrs = [self._var(n).valueReference for n in names]
            self._vr_cache[key] = vrs
        return vrs

    def setup(self, start_time: float, stop_time: float, parameters: dict) -> None:
        """Instantiate the FMU, set up the experiment from ``start_time`` to ``stop_time``
        (with ``tolerance`` where one is given: ``toleranceDefined = true``), enter
        initialization mode and set the ``parameters`` (by variable name)."""
        if self.fmi3:
            from fmpy.fmi3 import FMU3Slave as Slave
        else:
            Slave = FMU2Slave
        fmu = Slave(guid=self.md.guid, unzipDirectory=self._unzipdir,
                    modelIdentifier=self.md.coSimulation.modelIdentifier,
                    instanceName=self.name)
        try:
            with interrupt_held():
                if self.fmi3:
                    self._instantiate3(fmu)
                else:
                    fmu.instantiate(callbacks=self._callbacks(), loggingOn=True)
        except Exception:
            fmu.freeLibrary()
            self.worst_status = FATAL
            raise
        self.fmu = fmu
        self._do_step_fn = None
        self.experiment = (self.tolerance, start_time, stop_time)
        self.parameter_calls = []
        try:
            if self.fmi3:
                self._t0 = self._time = float(start_time)
                fmu.enterInitializationMode(tolerance=self.tolerance, startTime=start_time,
                                            stopTime=stop_time)
                self._set_parameters3(parameters)
                return
            fmu.setupExperiment(tolerance=self.tolerance, startTime=start_time,
                                stopTime=stop_time)
            fmu.enterInitializationMode()
            for pname, value in parameters.items():
                self._set_parameter(pname, value)
        except FMICallException as exc:
            self._failed(exc)
            raise

    def _instantiate3(self, fmu) -> None:
        """An FMI 3.0 FMU instantiated for co-simulation without event mode, its log routed
        to this component (the instance environment: fmpy's ``instantiate`` passes none)."""
        from fmpy.fmi3 import (
            fmi3Boolean,
            fmi3InstanceEnvironment,
            fmi3IntermediateUpdateCallback,
            fmi3ValueReference,
        )

        resources = str(Path(self._unzipdir) / "resources") + "/"
        fmu.component = fmu.fmi3InstantiateCoSimulation(
            self.name.encode("utf-8"), self.md.guid.encode("utf-8"), resources.encode("utf-8"),
            fmi3Boolean(False), fmi3Boolean(True), fmi3Boolean(self._clock is not None),
            fmi3Boolean(False),
            (fmi3ValueReference * 0)(), 0, fmi3InstanceEnvironment(self._env_id),
            _dispatch3(), fmi3IntermediateUpdateCallback())
        if not fmu.component:
            raise FmuRefused(self.last_message or f"{self.path.name}: "
                             "fmi3InstantiateCoSimulation failed")

    def _set_parameters3(self, parameters: dict) -> None:
        """An FMI 3.0 FMU's parameters: an element of an array (``A[2,1]``) goes into its
        array (the others keep their start values), set whole in one call."""
        arrays: dict[str, list] = {}
        for pname, value in parameters.items():
            element = array_element(pname)
            var = self._vars.get(element[0]) if element else None
            if element and var is not None and var.dimensions:
                values = arrays.setdefault(var.name, self._array_start(var))
                values[self._flat_index(var, element[1], pname)] = value
            else:
                self._set_parameter(pname, value)
        for aname, values in arrays.items():
            self._set_parameter(aname, values)

    @staticmethod
    def _array_start(var) -> list:
        count = 1
        for extent in var.shape:
            count *= extent
        start = (var.start or "").split()
        return [float(v) for v in start] if len(start) == count else [0.0] * count

    def _flat_index(self, var, index: tuple[int, ...], name: str) -> int:
        """The row-major position of ``name``'s element in the array ``var``."""
        flat = flat_index(index, var.shape)
        if flat is None:
            raise ParameterError(f"{self.name}.{name} is not allowed: {var.name} has shape "
                                 f"{' x '.join(map(str, var.shape))} (indices from 1)")
        return flat

    def _set_parameter(self, name: str, value) -> None:
        var = self._var(name)
        vr = [var.valueReference]
        assert self.fmu is not None  # called by setup() once it is instantiated
        if self.fmi3:
            values = value if isinstance(value, list) else [value]
            setter = {"Float64": self.fmu.setFloat64, "Float32": self.fmu.setFloat32,
                      "Int32": self.fmu.setInt32, "Int64": self.fmu.setInt64,
                      "Enumeration": self.fmu.setInt64, "Boolean": self.fmu.setBoolean,
                      "String": self.fmu.setString}.get(var.type)
            if setter is None:
                raise ParameterError(f"{self.name}.{name} is not allowed: a {var.type} "
                                     "variable (the master sets Float, Int32, Int64, "
                                     "Boolean and String parameters)")
            cast_to = {"Boolean": bool, "String": str}.get(
                var.type, float if var.type.startswith("Float") else int)
            cast_values = [cast_to(v) for v in values]
            setter(vr, cast_values)
            self.parameter_calls.append(
                ("Int64" if var.type == "Enumeration" else var.type, vr[0], cast_values))
            return
        cast_value: object
        if var.type == "Real":
            kind, cast_value = "Real", float(value)
            self.fmu.setReal(vr, [cast_value])
        elif var.type in ("Integer", "Enumeration"):
            kind, cast_value = "Integer", int(value)
            self.fmu.setInteger(vr, [cast_value])
        elif var.type == "Boolean":
            kind, cast_value = "Boolean", bool(value)
            self.fmu.setBoolean(vr, [cast_value])
        else:
            kind, cast_value = "String", str(value)
            self.fmu.setString(vr, [cast_value])
        self.parameter_calls.append((kind, vr[0], [cast_value]))

    def _failed(self, exc: FMICallException) -> None:
        self.worst_status = max(self.worst_status, exc.status)
        #: a call returned fmi2Error (native FMUs): FMI 2.0 then allows only
        #: fmi2Reset and fmi2FreeInstance, so terminate() skips fmi2Terminate
        self.call_failed = True

    def initialize(self) -> None:
        """Leave initialization mode; raise ``FmuRefused`` if the FMU logged an
        error (it would refuse to step)."""
        assert self.fmu is not None  # after setup()
        try:
            if self._clock is not None:
                self._interval = self._clock_interval()
            self.fmu.exitInitializationMode()
        except FMICallException as exc:
            self._failed(exc)
            raise
        if self.worst_status >= 3:  # it logged an error: it will refuse to step
            raise FmuRefused(self.last_message or "the FMU logged an error")
        if self._clock is not None:  # in event mode: the tick at t0 comes first
            self._tick, self._in_event = 0, True

    # -- a clocked FMI 3.0 FMU ------------------------------------------------------------
    def _clock_interval(self) -> float:
        """The clock's interval (``fmi3GetIntervalDecimal``; its XML value where constant);
        its shift must be 0 (the first tick at the start time)."""
        from ctypes import c_uint

        assert self.fmu is not None and self._clock is not None
        vr = (c_uint * 1)(self._clock.valueReference)
        interval, qualifier, shift = (c_double * 1)(), (c_int * 1)(), (c_double * 1)()
        if self._clock.intervalVariability == "constant" and self._clock.intervalDecimal:
            interval[0] = float(self._clock.intervalDecimal)
        else:
            self.fmu.getIntervalDecimal(vr, interval, qualifier)
        self.fmu.getShiftDecimal(vr, shift)
        if not (math.isfinite(interval[0]) and interval[0] > 0) or shift[0] != 0.0:
            raise FmuRefused(f"{self.name}: clock {self._clock.name} has interval "
                             f"{interval[0]!r} and shift {shift[0]!r}: the master schedules "
                             "periodic clocks of interval > 0 and shift 0")
        return interval[0]

    def _tick_if_due(self) -> None:
        """At the next tick's instant: the event iteration that hands the FMU the clocked
        inputs written since the last tick and latches its clocked outputs."""
        if not on_tick(self._time, self._t0 + self._tick * self._interval, self._interval,
                       self._t0):
            return
        fmu = self.fmu
        assert fmu is not None and self._clock is not None
        try:
            if not self._in_event:
                fmu.enterEventMode()
            if self._pending:
                names = list(self._pending)
                fmu.setFloat64(self._vrs(names), [self._pending[n] for n in names])
            fmu.setClock([self._clock.valueReference], [True])
            fmu.updateDiscreteStates()
            fmu.enterStepMode()
        except FMICallException as exc:
            self._failed(exc)
            raise
        self._in_event = False
        self._tick += 1

    def _raw(self, fname: str) -> _RawCall | None:
        """``(fn, component)``: the FMU's function ``fname`` as a bare ctypes pointer (no
        argtypes: the caller passes ctypes values; no fmpy wrapper, which logs and checks
        the status) and the instance pointer, or None where fmpy has no library handle or
        an FMI call logger is set. Half the cost of fmpy's call (measured 2 us against
        4 us); the hot path checks the status itself."""
        dll = getattr(self.fmu, "dll", None)
        if dll is None or getattr(self.fmu, "fmiCallLogger", None) is not None:
            return None
        try:
            fn = dll[fname]  # a new pointer object: fmpy's own keeps its argtypes
        except AttributeError:
            return None
        fn.restype = c_int
        assert self.fmu is not None  # it has a library handle
        return fn, c_void_p(self.fmu.component)

    def _raise(self, fname: str, status: int):
        exc = FMICallException(function=fname, status=status)
        self._failed(exc)
        raise exc

    # -- what a stepping core needs (delaycomp.orchestrator.native_core) -----------------
    @property
    def clocked(self) -> bool:
        """A clocked FMI 3.0 FMU (its ticks are scheduled by this component)."""
        return self._clock is not None

    def native_functions(self) -> tuple[int, int, int, int] | None:
        """The instance pointer and the addresses of its ``GetReal``, ``SetReal`` and
        ``DoStep`` (FMI 3.0: ``GetFloat64``, ``SetFloat64``, ``DoStep``), for a caller in C
        that calls them as this component does; ``None`` before ``setup`` or where fmpy
        holds no library handle or an FMI call logger is set (every call goes through
        fmpy then)."""
        if self.fmu is None:
            return None
        raws = [self._raw(self._fn(f)) for f in ("GetReal", "SetReal", "DoStep")]
        if any(r is None for r in raws):
            return None
        from ctypes import cast

        addresses = [cast(r[0], c_void_p).value or 0  # type: ignore[arg-type]
                     for r in raws if r is not None]
        return (int(self.fmu.component), *addresses)  # type: ignore[return-value]

    @property
    def unzipped(self) -> str:
        """The folder the FMU is unpacked in (what it needs to run: ``needed_to_run``)."""
        return self._unzipdir

    def library(self) -> str | None:
        """The path of the binary fmpy loaded for this instance (``None`` before ``setup``,
        or where fmpy does not say)."""
        dll = getattr(self.fmu, "dll", None)
        name = getattr(dll, "_name", None)
        return name if isinstance(name, str) else None

    def value_references(self, names: Sequence[str]) -> list[int]:
        """The value references of the variables ``names``."""
        return list(self._vrs(names))

    def call_failed_with(self, function: str, status: int):
        """Raise what this component raises when its FMI call ``function`` (FMI 2.0's
        name, ``DoStep``, ``GetReal``, ``SetReal``) returned ``status`` (> warning)."""
        self._raise(self._fn(function), status)

    def read_refused(self):
        """Raise what this component raises when it logged an error (worst status >=
        error) and its outputs are read."""
        raise FmuRefused(self.last_message or "the FMU logged an error")

    def reader(self, names: Sequence[str]) -> Callable[[], list[float]]:
        """``() -> [values]`` of the outputs ``names``: the master's hot path."""
        vrs = self._vrs(names)
        n = len(vrs)
        vr_array = (fmi2ValueReference * n)(*vrs)
        values = (fmi2Real * n)()
        raw: list[_RawCall | None] = []  # the instance's fmi2GetReal, looked up at the first call

        count = c_size_t(n)

        def read():
            if not raw:
                raw.append(self._raw(self._fn("GetReal")))
            fast = raw[0]
            if fast is None:
                assert self.fmu is not None  # after setup()
                try:
                    out = (self.fmu.getFloat64 if self.fmi3 else self.fmu.getReal)(vrs)
                except FMICallException as exc:
                    self._failed(exc)
                    raise
            else:
                status = (fast[0](fast[1], vr_array, count, values, count) if self.fmi3
                          else fast[0](fast[1], vr_array, count, values))
                if status > 1:
                    self._raise(self._fn("GetReal"), status)
                out = list(values)
            if self.worst_status >= 3:  # it logged an error computing them: do not use them
                self.read_refused()
            return out
        return read

    def writer(self, names: Sequence[str]) -> Callable[[Sequence[float]], None]:
        """``(values) -> None`` setting the inputs ``names``: the master's hot path (a
        clocked FMU's clocked inputs are kept until their tick)."""
        clocked = [n for n in names if n in self._clocked]
        if clocked:
            others = [n for n in names if n not in self._clocked]
            write_others = self.writer(others) if others else None
            at = [names.index(n) for n in clocked]
            rest = [names.index(n) for n in others]

            def write_clocked(values):
                for n, i in zip(clocked, at):
                    self._pending[n] = float(values[i])
                if write_others is not None:
                    write_others([values[i] for i in rest])
                self._tick_if_due()
            return write_clocked
        vrs = self._vrs(names)
        n = len(vrs)
        vr_array = (fmi2ValueReference * n)(*vrs)
        buffer = (fmi2Real * n)()
        raw: list[_RawCall | None] = []

        count = c_size_t(n)

        def write(values):
            if not raw:
                raw.append(self._raw(self._fn("SetReal")))
            fast = raw[0]
            if fast is None:
                assert self.fmu is not None  # after setup()
                try:
                    (self.fmu.setFloat64 if self.fmi3 else self.fmu.setReal)(vrs, values)
                except FMICallException as exc:
                    self._failed(exc)
                    raise
                return
            buffer[:] = values
            status = (fast[0](fast[1], vr_array, count, buffer, count) if self.fmi3
                      else fast[0](fast[1], vr_array, count, buffer))
            if status > 1:
                self._raise(self._fn("SetReal"), status)
        return write

    def do_step(self, t: float, h: float) -> None:
        """``fmi2DoStep`` (``fmi3DoStep``) from ``t`` to ``t + h`` (through the bare
        function where it can). An FMI 3.0 FMU that asks to end the simulation
        (``terminateSimulation``) or returns early is refused (the master's ticks are
        exact)."""
        if self._clock is not None:  # its tick first, if none came at this instant
            self._tick_if_due()
            self._time = t + h
        fast = self._do_step_fn
        if fast is None:
            fast = self._do_step_fn = self._raw(self._fn("DoStep")) or False
        if fast is False:
            assert self.fmu is not None  # after setup()
            try:
                out = self.fmu.doStep(currentCommunicationPoint=t, communicationStepSize=h)
            except FMICallException as exc:
                self._failed(exc)
                raise
            if self.fmi3:
                self.step_refused(t, h, out[1], out[2])
            return
        if self.fmi3:
            flags = self._flags
            status = fast[0](fast[1], c_double(t), c_double(h), _TRUE3, *self._flag_refs)
            if status > 1:
                self._raise("fmi3DoStep", status)
            if flags[1].value or flags[2].value:
                self.step_refused(t, h, flags[1].value, flags[2].value)
            return
        status = fast[0](fast[1], c_double(t), c_double(h), _TRUE)
        if status > 1:
            self._raise("fmi2DoStep", status)

    def step_refused(self, t: float, h: float, terminate: bool, early: bool) -> None:
        """Raise what this component raises when ``fmi3DoStep`` from ``t`` (step ``h``) asks
        to ``terminate`` the simulation or returns ``early`` (nothing where neither)."""
        if terminate or early:
            self.worst_status = max(self.worst_status, 3)
            raise FmuRefused(self.last_message or (
                f"fmi3DoStep from t = {t!r} (step {h!r}) "
                f"{'asked to terminate the simulation' if terminate else 'returned early'}"))

    # -- FMU state (canGetAndSetFMUstate, canSerializeFMUstate) ------------------------
    def get_state(self) -> bytes:
        """The instance's complete state, serialized (``fmi2GetFMUstate`` and
        ``fmi2SerializeFMUstate``; the FMU-side state is freed again)."""
        assert self.fmu is not None  # after setup()
        if self.fmi3:
            state = self._call(self.fmu.getFMUState)
            try:
                data = bytes(self._call(self.fmu.serializeFMUState, state))
            finally:
                self._call(self.fmu.freeFMUState, state)
            if self._clock is None:
                return data
            # a clocked FMU: the schedule and the inputs kept for the next tick go along
            head = json.dumps({"time": self._time.hex(), "tick": self._tick,
                               "in_event": self._in_event,
                               "pending": {n: v.hex() for n, v in self._pending.items()}}
                              ).encode()
            return struct.pack("<q", len(head)) + head + data
        state = self._call(self.fmu.getFMUstate)
        try:
            return bytes(self._call(self.fmu.serializeFMUstate, state))
        finally:
            self._call(self.fmu.freeFMUstate, state)

    def set_state(self, data: bytes) -> None:
        """Restore a state from ``get_state``, possibly of another instance."""
        assert self.fmu is not None  # after setup()
        if self._clock is not None:
            (size,) = struct.unpack_from("<q", data)
            head = json.loads(data[8:8 + size])
            data = data[8 + size:]
            self._time, self._tick = float.fromhex(head["time"]), int(head["tick"])
            self._in_event = bool(head["in_event"])
            self._pending = {n: float.fromhex(v) for n, v in head["pending"].items()}
        names = (("deserializeFMUState", "setFMUState", "freeFMUState") if self.fmi3
                 else ("deSerializeFMUstate", "setFMUstate", "freeFMUstate"))
        deserialize, set_state, free_state = (getattr(self.fmu, n) for n in names)
        state = self._call(deserialize, data)
        try:
            self._call(set_state, state)
        finally:
            self._call(free_state, state)
        if self.worst_status >= 3:
            raise FmuRefused(self.last_message or "the FMU refused the state")

    def _call(self, fn, *args):
        try:
            return fn(*args)
        except FMICallException as exc:
            self._failed(exc)
            raise

    def terminate(self) -> None:
        """``fmi2Terminate`` (where FMI still allows it) and ``fmi2FreeInstance``; safe in
        any phase and more than once."""
        try:
            if self.fmu is not None:
                try:
                    # After fmi2Fatal only fmi2FreeInstance is allowed (pythonfmu 0.7 has
                    # dropped the Python object then, and fmi2Terminate would crash the host);
                    # after fmi2Error only fmi2Reset and fmi2FreeInstance (FMI 2.0, 2.1.3).
                    if self.worst_status < FATAL and not getattr(self, "call_failed", False):
                        self.fmu.terminate()
                finally:
                    self.fmu.freeInstance()
                    self.fmu = None
        finally:
            _COMPONENTS.pop(self._env_id, None)
