"""FMI 2.0 call sequences a real importer may make (issue 16, item 3), through fmpy, for
every FMU: what the state machine forbids is refused with a named reason, never fatal.

"Refused" for these pythonfmu FMUs: a refused set returns fmi2OK (pythonfmu 0.7 can only
turn an exception into fmi2Fatal) with status error logged, and every later ``doStep``
returns fmi2Discard; a refused ``doStep`` returns fmi2Discard with the reason logged.
Sequences that crashed the host before (a double ``fmi2FreeFMUstate``) run in a child
process, so that a regression fails the test instead of killing pytest.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
import textwrap

import pytest
from fmpy.fmi1 import FMICallException

from delaycomp.orchestrator.fmu import FmuComponent

from .test_reliability import VARIANTS, variant_path

pytestmark = pytest.mark.fmu

H = 0.01  # the base step of the loops below: N = 100 with T = 1


def _params(variant):
    return {"N": 100} if "controller-" in variant else {}


def _started(fmu_dir, variant):
    comp = FmuComponent("c", variant_path(fmu_dir, variant))
    comp.setup(0.0, 1.0, _params(variant))
    comp.initialize()
    return comp


def _errors(comp):
    return [m for m in comp.messages if m.startswith("[error]")]


def _discarded(comp, t, h):
    with pytest.raises(FMICallException) as info:
        comp.do_step(t, h)
    assert info.value.status == 2  # fmi2Discard, never fatal
    return comp.last_message


def _first_var(comp, causality, type_="Real"):
    return next(v for v in comp.md.modelVariables
                if v.causality == causality and v.type == type_)


@pytest.mark.parametrize("variant", sorted(VARIANTS))
def test_parameter_set_after_initialization_is_refused(fmu_dir, variant):
    """Before: fmi2OK and ignored (the LTI plant kept the old A until the step size
    changed; the delay reported -1 and ran 0.3). Every parameter is fixed: refused."""
    comp = _started(fmu_dir, variant)
    try:
        var = _first_var(comp, "parameter")
        comp.fmu.setReal([var.valueReference], [0.5])
        assert comp.worst_status == 3 and comp.last_message == (
            f"setting {var.name} is not allowed after initialization: it is a fixed "
            "parameter (set it before fmi2ExitInitializationMode)")
        _discarded(comp, 0.0, H)
        assert any("refusing to step: setting" in m for m in comp.messages)
    finally:
        comp.terminate()


@pytest.mark.parametrize("variant", sorted(VARIANTS))
def test_output_set_is_refused_and_reading_stays_safe(fmu_dir, variant):
    """Before: fmi2OK, then getReal was fatal and the fourth call segfaulted the host."""
    comp = _started(fmu_dir, variant)
    try:
        var = _first_var(comp, "output")
        for _ in range(4):
            comp.fmu.setReal([var.valueReference], [5.0])
            value = comp.fmu.getReal([var.valueReference])[0]
            assert isinstance(value, float)
        assert comp.last_message == (f"setting {var.name} is not allowed: it is an output, "
                                     "not a parameter or an input")
        assert comp.worst_status == 3
    finally:
        comp.terminate()


@pytest.mark.parametrize("variant", sorted(VARIANTS))
@pytest.mark.parametrize("h", [0.0, -H, math.nan, math.inf], ids=["0", "neg", "nan", "inf"])
def test_bad_step_size_is_refused(fmu_dir, variant, h):
    """Before: the LTI controller accepted zero, negative and NaN steps."""
    comp = _started(fmu_dir, variant)
    try:
        assert _discarded(comp, 0.0, h) == (f"step size {h!r} at t = 0.0 is not allowed: "
                                            "must be a finite number > 0 from a finite time")
    finally:
        comp.terminate()


@pytest.mark.parametrize("variant", sorted(VARIANTS))
@pytest.mark.parametrize("t", [math.nan, -H, 2 * H], ids=["nan", "back", "ahead"])
def test_time_must_continue_where_the_last_step_ended(fmu_dir, variant, t):
    """Before: the plant and delay accepted time going backwards, the model controller a
    NaN time. After one step to 0.01, a step from NaN, from -0.01 or from 0.02 is
    refused."""
    comp = _started(fmu_dir, variant)
    try:
        comp.do_step(0.0, H)
        message = _discarded(comp, t, H)
        if math.isnan(t):
            assert message.startswith("step size 0.01 at t = nan is not allowed")
        else:
            word = "backwards" if t < H else "jumps ahead"
            assert message.startswith(f"step from t = {t!r} is not allowed: time")
            assert word in message and "the last step ended at 0.01" in message
    finally:
        comp.terminate()


@pytest.mark.parametrize("variant", sorted(VARIANTS))
def test_calls_after_terminate_are_refused(fmu_dir, variant):
    """Before: every call after fmi2Terminate returned OK and the FMU kept stepping."""
    comp = _started(fmu_dir, variant)
    try:
        comp.do_step(0.0, H)
        comp.fmu.terminate()
        assert _discarded(comp, H, H).startswith(
            "fmi2DoStep is not allowed in the terminated phase")
        var = _first_var(comp, "input")
        comp.fmu.setReal([var.valueReference], [1.0])
        assert f"setting {var.name} is not allowed: the instance is terminated" in \
            "\n".join(comp.messages)
    finally:
        comp.fmu.freeInstance()
        comp.fmu = None


def test_unknown_value_reference_is_refused(fmu_dir):
    comp = _started(fmu_dir, "plant")
    try:
        comp.fmu.setReal([999], [1.0])
        assert comp.last_message.startswith("value reference 999 is not allowed")
        assert math.isnan(comp.fmu.getReal([999])[0])
    finally:
        comp.terminate()


@pytest.mark.parametrize("variant", sorted(VARIANTS))
def test_foreign_state_blobs_are_named_refusals(fmu_dir, variant):
    """Not JSON, JSON that is not a state, another model's state: before, not-JSON was
    fmi2Fatal. Now each is refused by name and the instance stays safe to free."""
    other = "delay" if variant != "delay" else "plant"
    donor = _started(fmu_dir, other)
    try:
        foreign = donor.get_state()
    finally:
        donor.terminate()
    for blob, expected in [(b"\x00\xffnot json", "is not a state saved by a delaycomp FMU"),
                           (b"[1, 2]", "is not a state saved by a delaycomp FMU"),
                           (foreign, "is not allowed: this FMU is")]:
        comp = _started(fmu_dir, variant)
        try:
            comp.set_state(blob)
        except Exception as exc:  # noqa: BLE001 - FmuRefused, checked below
            assert expected in str(exc), str(exc)
            assert comp.worst_status == 3
        else:
            pytest.fail(f"{blob[:20]!r} was accepted")
        finally:
            comp.terminate()


@pytest.mark.parametrize("variant", sorted(VARIANTS))
def test_state_saved_before_initialization_refuses_to_step(fmu_dir, variant):
    """A state saved in initialization mode and restored after a run: the instance is
    then not initialized, and it refuses to step instead of running on stale buffers."""
    comp = FmuComponent("c", variant_path(fmu_dir, variant))
    try:
        comp.setup(0.0, 1.0, _params(variant))
        early = comp.get_state()
        comp.initialize()
        for k in range(3):
            comp.do_step(k * H, H)
        comp.set_state(early)
        assert "not initialized" in _discarded(comp, 3 * H, H)
    finally:
        comp.terminate()


DOUBLE_FREE = textwrap.dedent('''
    import json, sys
    from delaycomp.orchestrator.fmu import FmuComponent
    comp = FmuComponent("c", sys.argv[1])
    comp.setup(0.0, 1.0, json.loads(sys.argv[2]))
    comp.initialize()
    fmu = comp.fmu
    state = fmu.getFMUstate()
    fmu.freeFMUstate(state)
    fmu.freeFMUstate(state)
    for _ in range(3):
        fresh = fmu.getFMUstate()  # the freed state's data is swept here
        fmu.freeFMUstate(fresh)
    try:
        fmu.setFMUstate(state)
    except Exception as exc:
        print("raised", exc)
    print("LAST", comp.last_message)
    comp.terminate()
    print("DONE")
    # leave as `delaycomp` does with FMUs loaded (delaycomp.cli.entry): unloading a pythonfmu
    # FMU in the interpreter's teardown corrupts the heap now and then, after the test
    import os
    sys.stdout.flush()
    os._exit(0)
''')


@pytest.mark.parametrize("variant", sorted(VARIANTS))
def test_double_free_of_a_state_then_restore_is_a_named_refusal(fmu_dir, tmp_path, variant):
    """Before: freeFMUstate twice, then setFMUstate segfaulted the host (5 of 5). In a
    child process: a crash would be a non-zero exit status, not a dead pytest."""
    script = tmp_path / "double_free.py"
    script.write_text(DOUBLE_FREE, encoding="utf-8")
    proc = subprocess.run([sys.executable, str(script), str(variant_path(fmu_dir, variant)),
                           json.dumps(_params(variant))],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "DONE" in proc.stdout
    assert ("LAST FMU state is not allowed: it was freed (fmi2FreeFMUstate) or was not made "
            "by this FMU") in proc.stdout
