"""Random FMI 2.0 call sequences, legal and illegal, against every FMU through fmpy
(issue 16, item 3): a hypothesis ``RuleBasedStateMachine``.

Invariants after every call: no call returns fmi2Fatal or raises anything but fmpy's
``FMICallException`` with status discard or error, every message logged with status error
is one line, and the instance can always be terminated and freed. Illegal calls include
setting outputs and fixed parameters after initialization, bad and backwards steps,
calls after terminate, foreign state blobs and double frees of a state (at most twice per
state: the handles tolerate 31 extra frees). The example budget comes from the profile in
``tests/conftest.py`` (``ci``: 15 sequences of up to 25 calls per FMU).
"""

from __future__ import annotations

import math

import pytest
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import FMU2Slave
from hypothesis import settings
from hypothesis import strategies as st
from hypothesis.stateful import RuleBasedStateMachine, invariant, precondition, rule

from delaycomp.orchestrator.fmu import FATAL, FmuComponent

from .test_reliability import VARIANTS, variant_path

pytestmark = pytest.mark.fmu

#: per FMU: how many calls of each kind the runs made, and how many were refused
COUNTS: dict[str, dict[str, int]] = {}
times = st.one_of(st.sampled_from([0.0, 0.01, 0.02, -0.01, math.nan, math.inf]),
                  st.floats(-1, 1))
steps = st.one_of(st.sampled_from([0.01, 0.0, -0.01, math.nan, 0.005]), st.floats(-1, 1))
values = st.one_of(st.floats(-10, 10), st.sampled_from([math.nan, math.inf, 1e300]))


def machine_for(path, variant):
    class FmiSequence(RuleBasedStateMachine):
        def __init__(self):
            super().__init__()
            self.comp = FmuComponent("fuzz", path)
            md = self.comp.md
            self.fmu = FMU2Slave(guid=md.guid, unzipDirectory=self.comp._unzipdir,
                                 modelIdentifier=md.coSimulation.modelIdentifier,
                                 instanceName="fuzz")
            self.fmu.instantiate(callbacks=self.comp._callbacks(), loggingOn=True)
            self.comp.fmu = self.fmu
            self.reals = [v for v in md.modelVariables if v.type == "Real"]
            self.states: list = []  # (pointer, times freed)
            self.t = 0.0
            self.counts = COUNTS.setdefault(variant, {"calls": 0, "refused": 0})

        def call(self, fn, *args):
            self.counts["calls"] += 1
            before = len(self.comp.messages)
            try:
                result = fn(*args)
            except FMICallException as exc:
                assert exc.status in (2, 3), exc  # discard or error, never fatal
                self.counts["refused"] += 1
                return None
            if any(m.startswith("[error]") for m in self.comp.messages[before:]):
                self.counts["refused"] += 1
            return result

        @rule()
        def setup_experiment(self):
            self.call(self.fmu.setupExperiment, None, 0.0)

        @rule()
        def enter_initialization(self):
            self.call(self.fmu.enterInitializationMode)

        @rule()
        def exit_initialization(self):
            self.call(self.fmu.exitInitializationMode)

        @rule(index=st.integers(0, 1000), value=values)
        def set_real(self, index, value):
            var = self.reals[index % len(self.reals)]
            self.call(self.fmu.setReal, [var.valueReference], [value])

        @rule(vr=st.integers(0, 10_000))
        def get_real(self, vr):
            self.call(self.fmu.getReal, [vr])

        @rule(legal=st.booleans(), t=times, h=steps)
        def do_step(self, legal, t, h):
            if legal:
                t, h = self.t, 0.01
            if self.call(self.fmu.doStep, t, h) is not None or legal:
                self.t = t + h if math.isfinite(t + h) else self.t

        @rule()
        def terminate(self):
            self.call(self.fmu.terminate)

        @rule()
        def get_state(self):
            state = self.call(self.fmu.getFMUstate)
            if state is not None:
                self.states.append([state, 0])

        @precondition(lambda self: self.states)
        @rule(index=st.integers(0, 100))
        def free_state(self, index):
            entry = self.states[index % len(self.states)]
            if entry[1] < 2:  # a double free at most
                entry[1] += 1
                self.call(self.fmu.freeFMUstate, entry[0])

        @precondition(lambda self: self.states)
        @rule(index=st.integers(0, 100))
        def set_state(self, index):
            self.call(self.fmu.setFMUstate, self.states[index % len(self.states)][0])

        @rule(blob=st.sampled_from([b"", b"{}", b"[]", b"\xff\x00", b'{"model": "X"}',
                                    b'{"values": {}, "model": null}']))
        def foreign_blob(self, blob):
            state = self.call(self.fmu.deSerializeFMUstate, blob)
            if state is not None:
                self.call(self.fmu.setFMUstate, state)
                self.call(self.fmu.freeFMUstate, state)

        @invariant()
        def never_fatal(self):
            assert self.comp.worst_status < FATAL
            errors = [m for m in self.comp.messages if m.startswith("[error]")]
            assert all("\n" not in m for m in errors)

        def teardown(self):
            for entry in self.states:
                if entry[1] == 0:
                    self.fmu.freeFMUstate(entry[0])
            self.comp.terminate()  # terminate and free: must work in any phase

    return FmiSequence


@pytest.mark.parametrize("variant", sorted(VARIANTS))
def test_random_fmi_call_sequences(fmu_dir, variant):
    machine = machine_for(variant_path(fmu_dir, variant), variant)
    current = settings()
    machine.TestCase.settings = settings(current, stateful_step_count=25)
    machine.TestCase().runTest()
    counts = COUNTS[variant]
    assert counts["calls"] > 0
    print(f"{variant}: {counts['calls']} calls, {counts['refused']} refused")
