"""FMU state: a run restored from a saved state continues bit-identically.

Every FMU declares ``canGetAndSetFMUstate`` and ``canSerializeFMUstate``; the state holds
the hidden buffers (delay lines, predictor histories, controller state z, tick counters).
Each test runs a closed loop through fmpy, saves the state of every FMU at a tick that is
not a sampling instant (so held outputs, half-filled buffers and the sample counter all
matter), runs to the end, restores, runs again, and then restores the serialized state
into freshly instantiated FMUs. The three continuations must be equal bit for bit: no
tolerance, since the same code runs on the same numbers in one process (the same BLAS
kernel and libm on both sides), and a restored state is the same state, bytes and all
(the one place besides archives and generated text where bytes are the contract; every
other comparison of computed numbers is to round-off, tests/roundoff.py).
"""

from __future__ import annotations

import json

import pytest
from fmpy import read_model_description

from delaycomp.fmu.build import DEFAULT_CONFIG, FMUS, PACKAGE_DIR
from delaycomp.fmu.cache import fmu_path
from delaycomp.orchestrator.fmu import FmuComponent, FmuRefused
from delaycomp.orchestrator.simulate import make_master, parameters_of, stop_ticks
from delaycomp.paper import scenarios

pytestmark = pytest.mark.fmu

MODELS = PACKAGE_DIR / "paper" / "models"

#: (scenario, settings, stop time): every FMU kind of the registry appears at least once,
#: the model controller in both modes and with a numerical predictor.
CASES = {
    "lti-compensated": ("example-3.6", ["r=0.25", "tau=1", "u0=4", "N=4"], 6.0),
    "lti-uncompensated": ("example-3.6", ["mode=uncompensated", "r=0.5", "N=4"], 6.0),
    "continuous-closed": ("example-2.4", ["N=10"], 3.0),
    "zoh-numerical": ("example-3.8", ["N=10", "tau=1", "predictor=numerical"], 4.0),
}
#: the same with the controllers sampling the held input (``held_sample``, the loop of
#: ``delaycomp.verify.thirdparty.jacobi_variant``): the held input is hidden state too
HELD = {
    "lti-held-sample": ("example-3.6", ["r=0.5", "tau=1", "u0=4", "N=4"], 6.0),
    "zoh-held-sample": ("example-3.8", ["N=10", "tau=1"], 4.0),
}


def _run_with_restore(fmu_dir, name, settings, stop, held=False):
    sc = scenarios.get(name)
    spec = sc.make(sc.resolve(settings))
    if held:
        from delaycomp.verify.thirdparty import jacobi_variant

        spec = jacobi_variant(spec)
    ticks = stop_ticks(stop, spec.T, spec.N)
    if held:  # at a sampling instant, where the held input is what the controller samples
        save_at = (ticks // 2) // spec.N * spec.N
    else:
        save_at = ticks // 2 + 1
        assert save_at % spec.N != 0, "save between sampling instants"
    master, rec = make_master(spec, fmu_dir)
    try:
        master.setup(stop, parameters_of(spec))
        master.initialize()
        master.run_until(save_at)
        state = master.get_state()
        n0 = len(rec.rows)
        master.run_until(ticks)
        first = (rec.times[n0:], rec.rows[n0:])
        master.set_state(state)
        n1 = len(rec.rows)
        master.run_until(ticks)
        second = (rec.times[n1:], rec.rows[n1:])
    finally:
        master.terminate()
    fresh, rec2 = make_master(spec, fmu_dir)
    try:
        fresh.setup(stop, parameters_of(spec))
        fresh.initialize()
        n2 = len(rec2.rows)
        fresh.set_state(state)
        fresh.run_until(ticks)
        third = (rec2.times[n2:], rec2.rows[n2:])
    finally:
        fresh.terminate()
    return state, first, second, third


@pytest.mark.parametrize("case", sorted(CASES))
def test_restored_run_continues_bit_identically(fmu_dir, case):
    state, first, second, third = _run_with_restore(fmu_dir, *CASES[case])
    assert len(first[0]) > 5
    assert second == first
    assert third == first
    # the saved state really carries hidden state (not only the FMI variables)
    hidden = [json.loads(s)["hidden"] for s in state["components"].values()]
    assert all(h for h in hidden)


@pytest.mark.parametrize("case", sorted(HELD))
def test_restored_run_with_held_sample_continues_bit_identically(fmu_dir, case):
    state, first, second, third = _run_with_restore(fmu_dir, *HELD[case], held=True)
    assert len(first[0]) > 5
    assert second == first
    assert third == first
    controller = json.loads(state["components"]["controller"])
    assert controller["values"]["held_sample"] is True
    assert controller["hidden"]["y_held"] is not None  # saved, and restored above


@pytest.mark.parametrize("kind", sorted(FMUS))
def test_model_description_declares_state(fmu_dir, kind):
    # a template built for a model it takes: example 2.4 (continuous), or 3.8 (zero-order
    # hold) where the template takes only that (FmuSpec.controls)
    model = "example_3_8.py" if FMUS[kind].controls == ("zoh",) else "example_2_4.py"
    config = ({"model": str(MODELS / model)} if FMUS[kind].template
              else dict(DEFAULT_CONFIG[kind]))
    cs = read_model_description(str(fmu_path(kind, config, fmu_dir))).coSimulation
    assert cs.canGetAndSetFMUstate and cs.canSerializeFMUstate


def test_state_of_another_model_is_refused_and_the_host_survives(fmu_dir):
    plant = FmuComponent("plant", fmu_dir / "DelaycompPlantLTI.fmu")
    delay = FmuComponent("delay", fmu_dir / "DelaycompDelay.fmu")
    try:
        for c in (plant, delay):
            c.setup(0.0, 1.0, {})
            c.initialize()
        with pytest.raises(FmuRefused, match="FMU state of model 'DelaycompDelay' is not "
                                             "allowed: this FMU is DelaycompPlantLTI"):
            plant.set_state(delay.get_state())
    finally:
        plant.terminate()
        delay.terminate()
