"""One fresh host process for the heap checks of the Python FMUs (issue 30, item 10).

Loads each FMU given with plain fmpy (``fmpy.fmi2.FMU2Slave``, fmpy's own callbacks, logging
on), runs one FMI 2.0 call sequence on every instance, legal or one of the illegal ones the
state-machine fuzzing draws (``tests/test_fmi_state_machine.py``), prints ``DONE`` and
leaves through the interpreter's normal exit: no ``os._exit``, so the FMU libraries and
the interpreter are torn down as in any Python host. A refused call (fmi2Discard,
fmi2Error) is expected; fmi2Fatal exits with status 5. Any other exit status, or no
``DONE``, is a crash. Usage::

    python scripts/fmi_sequence_child.py SEQUENCE FMU [FMU ...]

where SEQUENCE is a name of ``SEQUENCES``, or ``all`` for every one in turn.

``tests/test_python_fmu_heap.py`` and ``scripts/crash_rate.py --fmi-sequences`` run it.
"""

from __future__ import annotations

import math
import sys
import tempfile
from collections.abc import Callable

from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import FMU2Slave

H = 0.01
FATAL = 4
#: blobs that are no state of these FMUs
FOREIGN = (b"", b"{}", b"\xff\x00", b'{"model": "X"}', b'{"values": {}, "model": null}')


class Instance:
    """One instance of an FMU, with what a sequence needs to know about it."""

    def __init__(self, path: str, index: int):
        md = read_model_description(path)
        unzipped = extract(path, tempfile.mkdtemp(prefix="delaycomp-heap-"))
        self.fmu = FMU2Slave(guid=md.guid, unzipDirectory=unzipped,
                             modelIdentifier=md.coSimulation.modelIdentifier,
                             instanceName=f"heap{index}")
        self.fmu.instantiate(loggingOn=True)
        variables = md.modelVariables
        self.outputs = [v.valueReference for v in variables
                        if v.causality == "output" and v.type == "Real"]
        self.inputs = [v.valueReference for v in variables
                       if v.causality == "input" and v.type == "Real"]
        self.parameters = [v.valueReference for v in variables
                           if v.causality == "parameter" and v.type == "Real"]
        self.t = 0.0

    def call(self, fn: Callable, *args):
        """``fn(*args)``; a refusal (discard, error) returns None, fmi2Fatal exits 5."""
        try:
            return fn(*args)
        except FMICallException as exc:
            if exc.status >= FATAL:
                print(f"FATAL {fn.__name__}: {exc}", flush=True)
                sys.exit(5)
            return None

    def start(self) -> None:
        self.call(self.fmu.setupExperiment, None, 0.0)
        self.call(self.fmu.enterInitializationMode)
        self.call(self.fmu.exitInitializationMode)

    def step(self, t: float | None = None, h: float = H) -> None:
        self.call(self.fmu.doStep, self.t if t is None else t, h)
        self.t += H

    def end(self) -> None:
        self.call(self.fmu.terminate)
        self.fmu.freeInstance()


def legal(inst: Instance) -> None:
    """The control case: initialize, three steps, terminate, free."""
    inst.start()
    for _ in range(3):
        inst.call(inst.fmu.getReal, inst.outputs)
        inst.step()
    inst.end()


def set_output(inst: Instance) -> None:
    """The issue's sequence: set an output (logged, not applied), then get and step."""
    inst.start()
    inst.call(inst.fmu.setReal, inst.outputs[:1], [5.0])
    for _ in range(3):
        inst.call(inst.fmu.getReal, inst.outputs)
        inst.step()
    inst.end()


def nan_parameters(inst: Instance) -> None:
    """Every Real parameter NaN before initialization ends; steps are refused."""
    inst.call(inst.fmu.setupExperiment, None, 0.0)
    inst.call(inst.fmu.enterInitializationMode)
    inst.call(inst.fmu.setReal, inst.parameters, [math.nan] * len(inst.parameters))
    inst.call(inst.fmu.exitInitializationMode)
    inst.step()
    inst.step()
    inst.end()


def after_terminate(inst: Instance) -> None:
    """Step, set, get and save a state after fmi2Terminate, then terminate again."""
    inst.start()
    inst.step()
    inst.call(inst.fmu.terminate)
    inst.step()
    inst.call(inst.fmu.setReal, inst.inputs, [1.0] * len(inst.inputs))
    inst.call(inst.fmu.getReal, inst.outputs)
    state = inst.call(inst.fmu.getFMUstate)
    if state is not None:
        inst.call(inst.fmu.setFMUstate, state)
        inst.call(inst.fmu.freeFMUstate, state)
    inst.end()


def double_terminate(inst: Instance) -> None:
    """fmi2Terminate twice, then free."""
    inst.start()
    inst.call(inst.fmu.terminate)
    inst.end()


def free_without_terminate(inst: Instance) -> None:
    """Free a stepping instance without fmi2Terminate."""
    inst.start()
    inst.step()
    inst.fmu.freeInstance()


def never_freed(inst: Instance) -> None:
    """Leave the process with the instance stepping: no terminate, no free."""
    inst.start()
    inst.step()


def bad_steps(inst: Instance) -> None:
    """Steps of size NaN, -h and 0, a step back in time and one from NaN."""
    inst.start()
    for h in (math.nan, -H, 0.0, math.inf):
        inst.call(inst.fmu.doStep, 0.0, h)
    inst.step()
    inst.step(t=-H)
    inst.step(t=math.nan)
    inst.end()


def bad_references(inst: Instance) -> None:
    """Unknown value references, a Real set as an Integer, a fixed parameter after
    initialization."""
    inst.start()
    inst.call(inst.fmu.setReal, [9999], [1.0])
    inst.call(inst.fmu.getReal, [9999, 10_000])
    inst.call(inst.fmu.setInteger, inst.parameters[:1], [3])
    inst.call(inst.fmu.setReal, inst.parameters[:1], [0.5])
    inst.step()
    inst.end()


def state_odd_phases(inst: Instance) -> None:
    """A state saved before initialization and restored after steps, a state freed twice
    and restored, foreign state blobs, a restore after fmi2Terminate."""
    early = inst.call(inst.fmu.getFMUstate)
    inst.start()
    inst.step()
    if early is not None:
        inst.call(inst.fmu.setFMUstate, early)
        inst.step()
    state = inst.call(inst.fmu.getFMUstate)
    if state is not None:
        inst.call(inst.fmu.freeFMUstate, state)
        inst.call(inst.fmu.freeFMUstate, state)
        inst.call(inst.fmu.setFMUstate, state)
    for blob in FOREIGN:
        foreign = inst.call(inst.fmu.deSerializeFMUstate, blob)
        if foreign is not None:
            inst.call(inst.fmu.setFMUstate, foreign)
            inst.call(inst.fmu.freeFMUstate, foreign)
    inst.call(inst.fmu.terminate)
    if early is not None:
        inst.call(inst.fmu.setFMUstate, early)
        inst.call(inst.fmu.freeFMUstate, early)
    inst.fmu.freeInstance()


SEQUENCES: dict[str, Callable[[Instance], None]] = {
    "legal": legal, "set-output": set_output, "nan-parameters": nan_parameters,
    "after-terminate": after_terminate, "double-terminate": double_terminate,
    "free-without-terminate": free_without_terminate, "never-freed": never_freed,
    "bad-steps": bad_steps, "bad-references": bad_references,
    "state-odd-phases": state_odd_phases,
}
SEQUENCES["never-freed"] = SEQUENCES.pop("never-freed")  # last: it leaves its instances


def main(argv: list[str]) -> None:
    """Run the sequence ``argv[0]`` on one instance of each FMU ``argv[1:]``; ``all`` runs
    every sequence in turn, each on fresh instances (``never-freed`` last)."""
    names = list(SEQUENCES) if argv[0] == "all" else [argv[0]]
    for name in names:
        instances = [Instance(path, i) for i, path in enumerate(argv[1:])]
        for inst in instances:
            SEQUENCES[name](inst)
    print("DONE", argv[0], flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
