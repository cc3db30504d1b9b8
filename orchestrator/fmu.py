"""An FMI 2.0 co-simulation FMU as a master component, through fmpy."""

from __future__ import annotations

import shutil
import tempfile
from ctypes import byref
from pathlib import Path
from typing import Sequence

from fmpy import extract, read_model_description
from fmpy.fmi2 import (
    FMU2Slave,
    fmi2CallbackAllocateMemoryTYPE,
    fmi2CallbackFreeMemoryTYPE,
    fmi2CallbackFunctions,
    fmi2CallbackLoggerTYPE,
)
from fmpy.fmi1 import calloc, free

_STATUS = ["ok", "warning", "discard", "error", "fatal", "pending"]


class FmuComponent:
    """One instance of a co-simulation FMU.

    Outputs that the modelDescription declares with an empty ``dependencies`` list have no
    direct feedthrough; every other output (declared dependencies, or none declared) is
    treated as depending on the inputs at the same instant.
    """

    def __init__(self, name: str, path: str | Path):
        self.name = name
        self.path = Path(path)
        self.md = read_model_description(str(self.path))
        if self.md.coSimulation is None:
            raise ValueError(f"{self.path.name} is not a co-simulation FMU")
        self._vars = {v.name: v for v in self.md.modelVariables}
        self.input_names = [v.name for v in self.md.modelVariables if v.causality == "input"]
        self.output_names = [v.name for v in self.md.modelVariables if v.causality == "output"]
        self.feedthrough_outputs = frozenset(
            u.variable.name for u in self.md.outputs
            if u.dependencies is None or len(u.dependencies) > 0
        )
        self.messages: list[str] = []
        self.last_message: str | None = None
        self._vr_cache: dict[tuple[str, ...], list[int]] = {}
        self._unzipdir: str | None = None
        self.fmu: FMU2Slave | None = None

    # -- logging -----------------------------------------------------------------------
    def _logger(self, component, instance_name, status, category, message):
        text = message.decode("utf-8", "replace") if isinstance(message, bytes) else str(message)
        self.messages.append(f"[{_STATUS[status] if 0 <= status < 6 else status}] {text}")
        if status >= 2:  # discard, error, fatal
            self.last_message = text

    def _callbacks(self) -> fmi2CallbackFunctions:
        cb = fmi2CallbackFunctions()
        cb.logger = fmi2CallbackLoggerTYPE(self._logger)
        cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
        cb.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
        try:  # fmpy's proxy formats the variadic message arguments
            from fmpy.logging import addLoggerProxy
            addLoggerProxy(byref(cb))
        except Exception:  # pragma: no cover - older fmpy: messages unformatted
            pass
        return cb

    # -- Component protocol ------------------------------------------------------------
    def _vrs(self, names: Sequence[str]) -> list[int]:
        key = tuple(names)
        vrs = self._vr_cache.get(key)
        if vrs is None:
            vrs = [self._var(n).valueReference for n in names]
            self._vr_cache[key] = vrs
        return vrs

    def _var(self, name: str):
        try:
            return self._vars[name]
        except KeyError:
            raise ValueError(f"{self.name}: no variable named {name!r}") from None

    def setup(self, start_time: float, stop_time: float, parameters: dict) -> None:
        self._unzipdir = extract(str(self.path), tempfile.mkdtemp(prefix="delaycomp-fmu-"))
        self.fmu = FMU2Slave(guid=self.md.guid, unzipDirectory=self._unzipdir,
                             modelIdentifier=self.md.coSimulation.modelIdentifier,
                             instanceName=self.name)
        self.fmu.instantiate(callbacks=self._callbacks(), loggingOn=True)
        self.fmu.setupExperiment(startTime=start_time, stopTime=stop_time)
        self.fmu.enterInitializationMode()
        for pname, value in parameters.items():
            var = self._var(pname)
            vr = [var.valueReference]
            if var.type == "Real":
                self.fmu.setReal(vr, [float(value)])
            elif var.type in ("Integer", "Enumeration"):
                self.fmu.setInteger(vr, [int(value)])
            elif var.type == "Boolean":
                self.fmu.setBoolean(vr, [bool(value)])
            else:
                self.fmu.setString(vr, [str(value)])

    def initialize(self) -> None:
        self.fmu.exitInitializationMode()

    def set_inputs(self, names: Sequence[str], values: Sequence[float]) -> None:
        self.fmu.setReal(self._vrs(names), values)

    def get_outputs(self, names: Sequence[str]) -> list[float]:
        return self.fmu.getReal(self._vrs(names))

    def do_step(self, t: float, h: float) -> None:
        self.fmu.doStep(currentCommunicationPoint=t, communicationStepSize=h)

    def terminate(self) -> None:
        try:
            if self.fmu is not None:
                try:
                    self.fmu.terminate()
                finally:
                    self.fmu.freeInstance()
                    self.fmu = None
        finally:
            if self._unzipdir:
                shutil.rmtree(self._unzipdir, ignore_errors=True)
                self._unzipdir = None
