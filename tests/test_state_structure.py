"""Issue 30, item 7: a native FMU's state is validated in full before it is installed.

A serialized state of a native FMU is its memory (``tests/native_state.py`` mirrors the
layout): a crafted one that passes the header's checks reached the model unchecked, and a
state in 'step complete' without its buffer, or a controller marked unbuilt in 'step
complete', crashed the process at the next step (a NULL dereference, measured before:
SIGSEGV for the LTI plant, the model plant, both controllers). Now every field is checked
against what the rest of the state implies (``model_state_ok`` of each model and
``data_ok`` of ``fmus/native/fmi2.c``) and a state that fails is refused with
``fmi2Error`` and ``FMU state is not allowed: <field> = <value>: must be ...``, the instance
left as it was.

The fuzzer takes a legitimate state of each native FMU kind at seven phases (instantiated,
initialization mode, initialized, after steps, after a failed initialization, after a
refused step, terminated), sets each field to its boundary values (0, -1, 1, the type's
extremes, NaN, inf, -0.0, the values the same field has at the other phases, flags
flipped, the Strings unterminated), drops, truncates, extends and swaps the buffer (the
length in the header fixed, so that each mutation reaches the validation), and sets each
mutated state in a child process per kind (a crash fails the test instead of killing
pytest): each is refused (fmi2Error, a message of that form, the instance unchanged) or
accepted, and then the instance reads its outputs, steps and saves its state without a
crash. The same again with the FMUs compiled with ``-fsanitize=address``, where libasan is
here: no read or write outside the state, the buffers or the stack. Measured (18 301
mutations of the six kinds): before, 23 crashed the process (SIGSEGV: the LTI plant 9, the
model plant 9, the LTI controller 1, the model controller 2 + 2) and 1 442 were refused;
now none crashes and 13 322 are refused, each naming its field; a field of the header
(magic, GUID, size, length) is refused by the header's own checks, every other mutation
reaches the checks of the data.

The Python twins (pythonfmu) restore a JSON state: each of its fields mutated (other
types, boundary numbers, lists shortened or lengthened, objects emptied) is refused naming
the field, the instance keeping its own state (before, a truncated delay line or input
history was taken as it came, and 1 043 of 6 032 mutations were refused with the instance
half restored), or taken and run.
"""

from __future__ import annotations

import json
import math
import os
import re
import subprocess
import sys
import zipfile
from pathlib import Path
from typing import NamedTuple

import pytest
from fmpy.fmi1 import FMICallException

from delaycomp.fmu.build import PACKAGE_DIR
from delaycomp.fmu.native import native_fmu_path
from delaycomp.fmu.toolchain import system_compiler
from delaycomp.orchestrator.fmu import FmuComponent, FmuRefused

from .external import Absent, need
from .native_state import decode, encode, layout_of
from .tiers import tiered

pytestmark = pytest.mark.fmu

HELPER = Path(__file__).parent / "native_state.py"
MODELS = PACKAGE_DIR / "paper" / "models"
NAN = math.nan

class Case(NamedTuple):
    """One native kind under test."""

    kind: str  # of delaycomp.fmu.native
    config: dict  # its build configuration
    good: dict  # parameters
    bad: dict  # parameters refused at initialization
    h: float  # the step
    steps: int  # steps before the state 'after steps'
    refused_step: tuple[float, float]  # (t - t0, h) of a step refused then


KINDS = {
    "plant": Case("plant", {"n": 2, "m": 1, "state": "x", "input": "u"},
                  {"A[1,2]": 1.0, "A[2,1]": -2.0, "A[2,2]": -3.0, "B[2,1]": 1.0,
                   "x0[1]": 1.0}, {"A[1,1]": NAN}, 0.1, 3, (0.3, -0.1)),
    "delay": Case("delay", {"n": 2}, {"delay": 0.3, "u0[2]": 1.5}, {"delay": -1.0}, 0.1, 4,
                  (0.4, 0.07)),
    # jitter over several steps and loss: packets in flight, out of order, lost
    "channel": Case("channel", {"n": 2, "L": 3},
                    {"delay": 0.1, "distribution": "uniform", "jitter": 0.35,
                     "loss_model": "bernoulli", "loss": 0.3, "seed": 3, "u0[2]": 1.5},
                    {"jitter": -1.0}, 0.1, 6, (0.6, 0.07)),
    "controller": Case("controller", {"n": 2, "m": 1},
                       {"T": 1.0, "r": 0.25, "tau": 1.0, "A[1,2]": 1.0, "B[2,1]": 1.0,
                        "K[1,1]": -1.0, "K[1,2]": -1.5, "u0[1]": 0.5, "held_sample": True},
                       {"tau": 1.0, "A[1,1]": 1000.0}, 0.25, 5, (1.25, 1.5)),
    # the time-stamp controller: stamps of age 0.25 (held_sample: 0.5), tau off the grid
    "stamped_controller": Case("stamped_controller", {"n": 2, "m": 1},
                               {"T": 1.0, "tau": 0.5, "age_max": 1.0, "A[1,2]": 1.0,
                                "B[2,1]": 1.0, "K[1,1]": -1.0, "K[1,2]": -1.5, "u0[1]": 0.5,
                                "held_sample": True},
                               {"T": 0.0}, 0.25, 5, (1.25, 1.5)),
    "model_plant": Case("model_plant", {"model": str(MODELS / "example_3_8.py")},
                        {"x0[1]": 0.5}, {"tolerance": 2.0}, 0.1, 3, (0.3, -0.1)),
    "model_controller-zoh": Case("model_controller",
                                 {"model": str(MODELS / "example_3_8.py")},
                                 {"N": 4, "tau": 1.0, "r": 0.25, "held_sample": True},
                                 {"N": 0}, 0.25, 5, (1.25, 0.3)),
    "model_controller-continuous": Case("model_controller",
                                        {"model": str(MODELS / "example_2_4.py")},
                                        {"N": 4, "tau": 0.5, "r": 0.25}, {"T": 0.0}, 0.25, 5,
                                        (1.25, 0.3)),
}
#: the form of a refusal: a field named (``<field> = <value>: must ...``), or this FMU's
#: header's own check (magic, GUID)
REFUSED = re.compile(r"^fmi2DeSerializeFMUstate: (?:FMU state is not allowed: (?:"
                     r"(?P<field>[^=:]+?) = .+"
                     r"|it is not a consistent state of this FMU \(\{[-0-9a-f]+\}\))"
                     r"|\d+ bytes are not allowed: not a state of this FMU \(wrong length\))$",
                     re.S)  # a crafted String value may hold a newline


@pytest.fixture(scope="module")
def fmus() -> dict[str, Path]:
    """Each kind's native FMU, for this platform only (the session's native build cache)."""
    return {name: native_fmu_path(case.kind, case.config) for name, case in KINDS.items()}


def _component(fmu: Path, name: str, parameters: dict, t0: float = 0.5) -> FmuComponent:
    comp = FmuComponent(name, fmu)
    comp.setup(t0, 1e9, parameters)
    return comp


def _inputs(comp: FmuComponent, k: int) -> None:
    comp.set_inputs(comp.input_names, [0.25 * (k + 1) * (-1) ** j
                                       for j in range(len(comp.input_names))])


def phases(fmu: Path, name: str) -> dict[str, bytes]:
    """Legitimate states of one kind: the state saved at each phase."""
    good, bad, h, steps, (t_bad, h_bad) = KINDS[name][2:]
    t0, out = 0.5, {}
    comp = _component(fmu, name, good)
    try:
        assert comp.fmu is not None
        comp.fmu.reset()
        comp.fmu.setupExperiment(startTime=t0)
        for pname, value in good.items():
            comp._set_parameter(pname, value)
        out["instantiated"] = comp.get_state()
        comp.call_failed = True  # fmi2Terminate is not allowed when instantiated
    finally:
        comp.terminate()
    comp = _component(fmu, name, good)
    try:
        out["initialization mode"] = comp.get_state()
        comp.initialize()
        out["initialized"] = comp.get_state()
        for k in range(steps):
            _inputs(comp, k)
            comp.do_step(t0 + k * h, h)
        out["after steps"] = comp.get_state()
        assert comp.fmu is not None
        comp.fmu.terminate()
        out["terminated"] = comp.get_state()
        comp.set_state(out["after steps"])
        with pytest.raises(FMICallException):
            comp.do_step(t0 + t_bad, h_bad)
        out["after a refused step"] = comp.get_state()
    finally:
        comp.terminate()
    comp = _component(fmu, name, bad)
    try:
        with pytest.raises((FmuRefused, FMICallException)):
            comp.initialize()
        out["after a failed initialization"] = comp.get_state()
    finally:
        comp.terminate()
    return out


def _fuzz(fmu: Path, name: str, tmp_path: Path, env: dict | None = None,
          child_fmu: Path | None = None) -> dict:
    """Run the batch of one kind in a child (on ``child_fmu``, default ``fmu``); the
    records."""
    states = phases(fmu, name)
    good, h = KINDS[name].good, KINDS[name].h
    fmu = child_fmu or fmu
    spec = tmp_path / f"{name}.json"
    out = tmp_path / f"{name}.jsonl"
    spec.write_text(json.dumps({"fmu": str(fmu), "parameters": good, "h": h, "out": str(out),
                                "states": {p: b.hex() for p, b in states.items()}}),
                    encoding="utf-8")
    proc = subprocess.run([sys.executable, str(HELPER), str(spec)], capture_output=True,
                          text=True, timeout=600, env=env)
    lines = [json.loads(line) for line in out.read_text(encoding="utf-8").splitlines()]
    last = next((r["start"] for r in reversed(lines) if "start" in r), None)
    assert proc.returncode == 0, (f"the child died ({proc.returncode}) at {last!r}:\n"
                                  f"{proc.stderr[-3000:]}")
    return {"states": states, "records": [r for r in lines if "start" not in r]}


def _check(records: list[dict]) -> dict:
    """Every mutation refused as the issue asks, or accepted and then usable; counts."""
    counts = {"tried": len(records), "refused": 0, "by the header": 0, "accepted": 0}
    for r in records:
        where = f"{r['phase']}: {r['what']}"
        if r["status"]:
            assert r["status"] == 3, (where, r)  # fmi2Error, never fmi2Fatal
            assert r["unchanged"], where
            assert r["messages"], where
            match = REFUSED.match(r["messages"][0])
            assert match, (where, r["messages"])
            counts["refused"] += 1
            # a mutation of the data reaches the checks of the data: named
            by_header = match.group("field") in (None, "data_size")
            assert by_header == r["what"].startswith("h."), (where, r["messages"])
            counts["by the header"] += by_header
        else:
            assert not r["messages"], (where, r["messages"])
            assert all(s in (0, 3) for s in r["after"]), (where, r)
            counts["accepted"] += 1
    return counts


@pytest.mark.parametrize("name", sorted(KINDS))
def test_crafted_states_are_refused_or_run_never_crash(fmus, name, tmp_path):
    """Each structure-aware mutation of each phase's state: refused (fmi2Error, the field
    named, the instance unchanged) or accepted and then usable; never a crash."""
    result = _fuzz(fmus[name], name, tmp_path)
    counts = _check(result["records"])
    print(f"{name}: {counts}")
    assert counts["refused"] > 0.5 * counts["tried"]


# -- the legitimate states, each restored --------------------------------------------------
@pytest.mark.parametrize("name", sorted(KINDS))
def test_every_legitimate_state_is_restored_into_another_instance(fmus, name):
    """The seven phases' states, a failed initialization's included, are accepted by a
    fresh instance, which then behaves as the one they were saved from (same outputs, same
    refusal of a step, the same state again)."""
    fmu = fmus[name]
    good, h = KINDS[name].good, KINDS[name].h
    states = phases(fmu, name)
    layout = layout_of(fmu)
    for phase, blob in states.items():
        comp = _component(fmu, "restored", good, t0=0.0)
        try:
            comp.initialize()
            comp.set_state(blob)
            assert comp.get_state() == blob, phase
            snap, _ = decode(layout, blob)
            assert comp.fmu is not None
            try:
                comp.fmu.doStep(currentCommunicationPoint=snap.d.time, communicationStepSize=h)
                stepped = "ok"
            except FMICallException:
                stepped = comp.messages[-1].split("] ", 1)[-1]
            comp.call_failed = True  # free it only (fmi2Terminate: not in every phase)
            if phase in ("initialized", "after steps"):
                assert stepped == "ok", (phase, stepped)
            else:
                assert "fmi2DoStep is not allowed in state" in stepped, (phase, stepped)
        finally:
            comp.terminate()


def test_a_failed_initialization_restores_with_its_refusal(fmus):
    """The LTI controller refused at fmi2ExitInitializationMode after it had allocated its
    predictor (A overflows e^(A (r + tau))): the state saved then was refused on restore
    before ('it is not a consistent state of this FMU'); now it is restored into a working
    instance, which then refuses to step as the one it was saved from did."""
    fmu = fmus["controller"]
    good, bad = KINDS["controller"].good, KINDS["controller"].bad
    failed = _component(fmu, "failed", bad)
    try:
        with pytest.raises(FMICallException):
            failed.initialize()
        assert "it overflows" in (failed.last_message or "")
        blob = failed.get_state()
        with pytest.raises(FMICallException):
            failed.do_step(0.5, 0.25)
        refusal = failed.messages[-1]
    finally:
        failed.terminate()
    working = _component(fmu, "working", good)
    try:
        working.initialize()
        working.do_step(0.5, 0.25)
        working.set_state(blob)
        with pytest.raises(FMICallException):
            working.do_step(0.5, 0.25)
        assert working.messages[-1].split("] ", 1)[-1] == refusal.split("] ", 1)[-1]
        assert working.fmu is not None
        assert working.fmu.getReal(working._vrs(working.output_names)) == [0.0]  # u0
    finally:
        working.terminate()


CRAFTED = {  # the issue's states: (kind, phase, what is changed)
    "plant in 'step complete' without its buffer": ("plant", "after steps", "buffer"),
    "model plant in 'step complete' without its buffer": ("model_plant", "initialized",
                                                          "buffer"),
    "LTI controller unbuilt in 'step complete'": ("controller", "after steps", "built"),
    "model controller unbuilt in 'step complete'": ("model_controller-zoh", "after steps",
                                                    "built"),
    "plant failed, marked 'step complete'": ("plant", "after a failed initialization",
                                             "state"),
}


@pytest.mark.parametrize("case", sorted(CRAFTED))
def test_the_crafted_states_of_the_issue_are_refused_naming_the_field(fmus, case):
    """Each crashed the process at the next step before (SIGSEGV); now refused, named."""
    name, phase, what = CRAFTED[case]
    fmu = fmus[name]
    layout = layout_of(fmu)
    snap, buf = decode(layout, phases(fmu, name)[phase])
    if what == "buffer":
        buf = []
    elif what == "built":
        snap.d.m.built = 0
        buf = []
    else:
        snap.d.state = 4
    blob = encode(snap, buf)
    comp = _component(fmu, "target", KINDS[name].good)
    try:
        comp.initialize()
        before = comp.get_state()
        with pytest.raises(FMICallException) as info:
            comp.set_state(blob)
        assert info.value.status == 3
        message = comp.messages[-1].split("] ", 1)[-1]
        expected = {"buffer": "nbuf = 0: must be ", "built": "built = 0: must be 1 in state "
                    "'step complete'", "state": "nbuf = 0: must be "}[what]
        assert message.startswith("fmi2DeSerializeFMUstate: FMU state is not allowed: "
                                  + expected), message
        assert comp.get_state() == before
        comp.do_step(0.5, KINDS[name].h)  # the instance is as it was: it steps
    finally:
        comp.terminate()


# -- the same under AddressSanitizer ---------------------------------------------------
def _asan_library() -> str:
    """The sanitizer's runtime library of the system C compiler (``Absent`` where it has
    none; Zig's has no shared one)."""
    try:
        lib = subprocess.run([*system_compiler(), "-print-file-name=libasan.so"],
                             capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError) as exc:
        raise Absent(f"the C compiler cannot name libasan.so: {exc}") from None
    if not (os.path.isabs(lib) and os.path.exists(lib)):
        raise Absent("the C compiler has no libasan.so")
    return lib


def _asan_build(fmu: Path, dest: Path) -> Path:
    """The FMU with its binary compiled from its own sources with -fsanitize=address."""
    work = dest.parent / (dest.stem + "-src")
    with zipfile.ZipFile(fmu) as zf:
        zf.extractall(work)
        names = zf.namelist()
    binary = next(n for n in names if n.startswith("binaries/linux64/"))
    sources = sorted(str(p) for p in (work / "sources").glob("*.c"))
    subprocess.run([*system_compiler(), "-std=c99", "-O1", "-g", "-fPIC", "-shared",
                    "-fsanitize=address", "-fno-omit-frame-pointer", "-Wall", "-Wextra",
                    "-Werror", "-I", str(work / "sources"), "-o", str(work / binary),
                    *sources, "-lm"], check=True)
    with zipfile.ZipFile(fmu) as zf, zipfile.ZipFile(dest, "w") as out:
        for n in names:
            out.writestr(n, (work / binary).read_bytes() if n == binary else zf.read(n))
    return dest


@pytest.mark.parametrize("name", tiered(sorted(KINDS), {"channel", "stamped_controller"}))
def test_no_access_outside_the_state_under_address_sanitizer(fmus, name, tmp_path):
    lib = need("libasan", _asan_library)
    asan = _asan_build(fmus[name], tmp_path / fmus[name].name)
    env = {**os.environ, "LD_PRELOAD": lib,
           "ASAN_OPTIONS": "detect_leaks=0:abort_on_error=1:allocator_may_return_null=1"}
    result = _fuzz(fmus[name], name, tmp_path, env, child_fmu=asan)
    counts = _check(result["records"])
    print(f"{name} (ASan): {counts}")


# -- the Python FMUs: a state's JSON with inconsistent fields ---------------------------------
def _model_slave(base, module):
    return type(f"State{base.__name__}", (base,), {
        "model_module": f"delaycomp.paper.models.{module}", "__module__": __name__})


def _python_slaves() -> dict:
    from delaycomp.fmus.controller.delaycomp_controller_lti import DelaycompControllerLTI
    from delaycomp.fmus.controller.delaycomp_controller_stamped import (
        DelaycompControllerStamped,
    )
    from delaycomp.fmus.controller.delaycomp_model_controller import ModelControllerSlave
    from delaycomp.fmus.delay.delaycomp_channel import DelaycompChannel
    from delaycomp.fmus.delay.delaycomp_delay import DelaycompDelay
    from delaycomp.fmus.plant.delaycomp_model_plant import ModelPlantSlave
    from delaycomp.fmus.plant.delaycomp_plant_lti import DelaycompPlantLTI

    return {"plant": (DelaycompPlantLTI, {"n": 2, "m": 1, "state": "x", "input": "u"}),
            "delay": (DelaycompDelay, {"n": 2}),
            "channel": (DelaycompChannel, {"n": 2, "L": 3}),
            "controller": (DelaycompControllerLTI, {"n": 2, "m": 1}),
            "stamped_controller": (DelaycompControllerStamped, {"n": 2, "m": 1}),
            "model_plant": (_model_slave(ModelPlantSlave, "example_3_8"),
                            {"model_name": "example_3_8"}),
            "model_controller-zoh": (_model_slave(ModelControllerSlave, "example_3_8"),
                                     {"model_name": "example_3_8"}),
            "model_controller-continuous": (_model_slave(ModelControllerSlave, "example_2_4"),
                                            {"model_name": "example_2_4"})}


def _python_slave(name: str, parameters: dict, tmp_path: Path, t0: float = 0.5):
    import delaycomp
    from delaycomp.fmu.slave import CONFIG_NAME

    cls, config = _python_slaves()[name]
    res = tmp_path / f"res-{name}"
    res.mkdir(exist_ok=True)
    (res / CONFIG_NAME).write_text(json.dumps({**config, "version": delaycomp.__version__}),
                                   encoding="utf-8")
    slave = cls(instance_name="state", resources=str(res))
    by_name = {v.name: v for v in slave.vars.values()}
    for pname, value in parameters.items():
        by_name[pname].setter(value)
    slave.setup_experiment(t0, None, None)
    slave.enter_initialization_mode()
    return slave


def _python_phases(name: str, tmp_path: Path) -> dict[str, dict]:
    """Legitimate states of one Python slave (as plain data) at five phases."""
    good, bad, h, steps, (t_bad, h_bad) = KINDS[name][2:]
    slave = _python_slave(name, good, tmp_path)
    out = {"initialization mode": slave._state_data()}
    slave.exit_initialization_mode()
    out["initialized"] = slave._state_data()
    ins = [v for v in slave.vars.values() if v.causality.name == "input"]
    for k in range(steps):
        for j, var in enumerate(ins):
            var.setter(0.25 * (k + 1) * (-1) ** j)
        assert slave.do_step(0.5 + k * h, h)
    out["after steps"] = slave._state_data()
    assert not slave.do_step(0.5 + t_bad, h_bad)
    out["after a refused step"] = slave._state_data()
    failed = _python_slave(name, bad, tmp_path)
    failed.exit_initialization_mode()
    assert failed.error is not None
    out["after a failed initialization"] = failed._state_data()
    return out


def _json_mutations(state, path: str = ""):
    """(path, mutated copy) for each field of a state's JSON: other types, boundary
    numbers, lists shortened, lengthened, emptied, objects emptied or missing a key."""
    import copy

    def variants(value):
        if isinstance(value, bool):
            return [not value, 0, 1, None, "true"]
        if isinstance(value, (int, float)):
            return [-1, 0, 2**63, 1e308, NAN, math.inf, -0.0, "x", None, True]
        if isinstance(value, str):
            return [5, None, "", "bogus"]
        if value is None:
            return [0, "x", [], {}]
        if isinstance(value, list):
            return [[], value[:-1], [*value, value[-1] if value else 0.0], None]
        return [{}, None, *({k: v for k, v in value.items() if k != key} for key in value)]

    def leaves(node, where):
        yield where, node
        if isinstance(node, dict):
            for key, child in node.items():
                yield from leaves(child, (*where, key))
        elif isinstance(node, list):
            for k, child in enumerate(node):
                yield from leaves(child, (*where, k))

    for where, value in leaves(state, ()):
        if not where or where[0] == "model":
            continue
        for new in variants(value):
            mutated = copy.deepcopy(state)
            node = mutated
            for key in where[:-1]:
                node = node[key]
            node[where[-1]] = new
            yield ".".join(map(str, where)) + f" = {new!r}", mutated


#: a refusal of a Python slave's restored state: a field named, or not this build's
PY_REFUSED = re.compile(r"^FMU state (?:is not allowed: [^=]+ = .+|with variables .+ is not "
                        r"allowed: this FMU has no such variables \(another build\))$", re.S)


@pytest.mark.parametrize("name", sorted(KINDS))
def test_python_fmus_refuse_inconsistent_states_by_name_and_keep_their_own(name, tmp_path):
    """The Python twins: each field of a state's JSON mutated; a refusal names the field
    (before, a truncated delay line or input history was taken as it came, and a refused
    state left the instance half restored), the instance keeps its own state (only its
    error is the refusal), and nothing else ever escapes (a TypeError of the restore)."""
    from delaycomp.fmu.statehandle import StateHandle

    good, h = KINDS[name].good, KINDS[name].h
    counts = {"tried": 0, "refused": 0}
    for phase, base in _python_phases(name, tmp_path).items():
        slave = _python_slave(name, good, tmp_path)
        slave.exit_initialization_mode()
        slave._set_fmu_state(StateHandle.new(base))
        assert slave.error == base["error"], phase  # legitimate: restored
        own = {k: v for k, v in slave._state_data().items() if k != "error"}
        for what, mutated in _json_mutations(base):
            slave.log_queue.clear()
            slave._set_fmu_state(StateHandle.new(mutated))
            errors = [m.msg for m in slave.log_queue if m.status.name == "error"]
            counts["tried"] += 1
            if errors and errors[-1] != base["error"]:
                assert PY_REFUSED.match(errors[-1]), (phase, what, errors)
                assert {k: v for k, v in slave._state_data().items() if k != "error"} \
                    == own, (phase, what)
                counts["refused"] += 1
            else:  # taken: it runs (a slave never raises) and saves again
                slave.do_step(float(mutated["t_next"] or 0.0), h)
                slave._state_data()
            slave._set_fmu_state(StateHandle.new(base))
    print(f"{name} (Python): {counts}")
    assert counts["refused"] > 0.3 * counts["tried"]
