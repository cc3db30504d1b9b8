"""Property-based tests (hypothesis) over parameters and input sequences.

Properties: no exception escapes a slave (pythonfmu would turn it into fmi2Fatal), nothing
hangs, every refusal is a one-line message of a known, named form, and a healthy run stays
finite. Three layers:

- the slave adapters in-process (cheap: the same classes the FMUs run, without FMI);
- the FMUs through fmpy (a few examples each: instantiation costs milliseconds);
- the master and scenarios through ``run_loop`` (parameters as the CLI passes them).

The example budget comes from the hypothesis profile (``tests/conftest.py``): ``ci`` by
default, ``DELAYCOMP_HYPOTHESIS_PROFILE=sweep`` for a larger one-off run.
"""

from __future__ import annotations

import json
import math
import re
from collections import deque

import numpy as np
import pytest
from fmpy.fmi1 import FMICallException
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pythonfmu.enums import Fmi2Status
from pythonfmu.variables import Boolean, Integer, Real, String

import delaycomp
from delaycomp.fmu.slave import CONFIG_NAME
from delaycomp.fmus.controller.delaycomp_controller_lti import DelaycompControllerLTI
from delaycomp.fmus.controller.delaycomp_model_controller import ModelControllerSlave
from delaycomp.fmus.delay.delaycomp_delay import DelaycompDelay
from delaycomp.fmus.plant.delaycomp_model_plant import ModelPlantSlave
from delaycomp.fmus.plant.delaycomp_plant_lti import DelaycompPlantLTI
from delaycomp.maths.delayline import DelayLine
from delaycomp.maths.history import InputHistory
from delaycomp.orchestrator.fmu import FmuComponent, FmuRefused
from delaycomp.orchestrator.simulate import run_loop
from delaycomp.paper import scenarios
from delaycomp.paper.scenarios import ParameterError

#: the forms of every message a slave logs with status error (docs/explanation/reliability.md)
NAMED = re.compile(
    r"^(?:"
    r"(?:\S+|r \+ tau) = .+ is not allowed: (?:must|zero-order hold needs|model \S+ gives)"
    r"|input \S+ = \S+ at t = \S+ is not allowed: must be a finite number"
    r"|step size \S+ (?:at t = \S+ )?is not allowed: "
    r"|step \[.+\] is not allowed: it passes over the sampling instant"
    r"|step \(.+\) is not allowed: this controller steps from"
    r"|state \[.*\] = \[.*\] at t = \S+ is not allowed: must be finite"
    r"|state \[.*\] at t = \S+ is not allowed: must be finite"
    r"|control \[.*\] = \[.*\] at t = \S+ is not allowed: must be finite"
    r"|computing the control at t = \S+ failed: IntegrationError: ODE solve failed"
    r"|predictor ODE solve at t = \S+ failed: ODE solve failed"
    r"|plant step at t = \S+ failed: ODE solve failed"
    r")"
)

WEIRD = [0.0, -0.0, 1e-300, -1e-300, 1e300, -1e300, math.nan, math.inf, -math.inf]
reals = st.one_of(st.floats(-10, 10), st.sampled_from(WEIRD),
                  st.floats(allow_nan=True, allow_infinity=True))
finite_inputs = st.floats(-100, 100)
inputs = st.one_of(finite_inputs, finite_inputs, finite_inputs, st.sampled_from(WEIRD))

MODELS = "delaycomp.paper.models"


def _model_slave(base, module):
    return type(f"Fuzz{base.__name__}", (base,), {"model_module": f"{MODELS}.{module}",
                                                  "__module__": __name__})


#: slave class and build configuration, one per FMU of the registry (templates per mode)
SLAVES = {
    "plant": (DelaycompPlantLTI, {"n": 2, "m": 1, "state": "x", "input": "u"}),
    "delay": (DelaycompDelay, {"n": 2}),
    "controller": (DelaycompControllerLTI, {"n": 2, "m": 1}),
    "model_plant": (_model_slave(ModelPlantSlave, "example_3_8"), {"model_name": "example_3_8"}),
    "model_controller-zoh": (_model_slave(ModelControllerSlave, "example_3_8"),
                             {"model_name": "example_3_8"}),
    "model_controller-continuous": (_model_slave(ModelControllerSlave, "example_2_4"),
                                    {"model_name": "example_2_4"}),
}


def make_slave(kind, tmp_path_factory):
    cls, config = SLAVES[kind]
    res = tmp_path_factory.mktemp("res")
    (res / CONFIG_NAME).write_text(json.dumps({**config, "version": delaycomp.__version__}),
                                   encoding="utf-8")
    return cls(instance_name="fuzz", resources=str(res))


def value_for(var, draw):
    """A value for a parameter: None keeps the default (so that runs also get going)."""
    if isinstance(var, Real):
        return draw(st.one_of(st.none(), reals))
    if isinstance(var, Integer):
        return draw(st.one_of(st.none(), st.integers(-3, 50), st.integers()))
    if isinstance(var, Boolean):
        return draw(st.one_of(st.none(), st.booleans()))
    if isinstance(var, String):
        return draw(st.one_of(st.none(), st.sampled_from(
            ["compensated", "uncompensated", "zoh", "continuous", "closed", "numerical",
             "square", "sin", "corrected", "printed", "", "bogus", "é\n"])))
    raise AssertionError(var)


def check_messages(slave):
    errors = [m.msg for m in slave.log_queue if m.status == Fmi2Status.error]
    assert all(status in (Fmi2Status.ok, Fmi2Status.warning, Fmi2Status.error, Fmi2Status.discard)
               for status in (m.status for m in slave.log_queue))
    for msg in errors:
        assert "\n" not in msg.rstrip() or msg.count("\n") == 0, msg
        assert NAMED.match(msg), msg
    slave.log_queue.clear()
    return errors


@pytest.mark.parametrize("kind", sorted(SLAVES))
@settings(suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_slave_never_raises_and_names_every_refusal(kind, data, tmp_path_factory):
    slave = make_slave(kind, tmp_path_factory)
    params = [v for v in slave.vars.values() if v.causality.name == "parameter"]
    ins = [v for v in slave.vars.values() if v.causality.name == "input"]
    outs = [v for v in slave.vars.values() if v.causality.name == "output"]
    for var in params:
        value = value_for(var, data.draw)
        if value is not None:
            var.setter(value)
    slave.setup_experiment(0.0, None, None)
    slave.enter_initialization_mode()
    slave.exit_initialization_mode()
    refused = bool(check_messages(slave))
    assert refused == (slave.error is not None)
    T = getattr(slave, "T", 1.0)
    N = int(getattr(slave, "N", 4)) if isinstance(getattr(slave, "N", 4), int) else 4
    good_h = T / N if (isinstance(T, float) and math.isfinite(T) and T > 0 and N > 0) else 0.1
    h = data.draw(st.one_of(st.just(good_h), st.sampled_from([0.1, 0.25, -0.1, 0.0, math.nan])))
    t = 0.0
    for _ in range(data.draw(st.integers(0, 12))):
        for var in ins:
            var.setter(data.draw(inputs))
        values = [var.getter() for var in outs]
        check_messages(slave)
        ok = slave.do_step(t, h)
        assert isinstance(ok, bool)
        errors = check_messages(slave)
        if not ok:
            assert slave.error is not None
            assert errors or refused or slave.error
            break
        assert slave.error is None
        assert all(isinstance(v, float) for v in values)
        t += h
    # the state round trip never raises either
    state = slave._get_fmu_state()
    slave._set_fmu_state(type(slave)._fmu_state_from_bytes(type(slave)._fmu_state_to_bytes(state)))
    check_messages(slave)


# -- the maths objects -----------------------------------------------------------------
@given(D=st.integers(0, 20), n=st.integers(1, 3),
       seq=st.lists(st.lists(finite_inputs, min_size=3, max_size=3), max_size=60))
def test_delay_line_is_the_shifted_sequence_and_bounded(D, n, seq):
    init = [0.5] * n
    line = DelayLine(n, D, init)
    for k, u in enumerate(seq):
        u = tuple(u[:n])
        expected = tuple(seq[k - D][:n]) if k >= D else tuple(init)
        assert line.output(u) == expected
        line.push(u)
        assert len(line.buffer) == D


@given(W=st.integers(0, 30), h=st.floats(1e-3, 1.0),
       seq=st.lists(st.sampled_from([-1.0, 0.0, 2.5]), max_size=80))
def test_input_history_covers_exactly_the_window(W, h, seq):
    hist = InputHistory(W, h, [0.0])
    window = deque([0.0] * W, maxlen=W)
    for u in seq:
        hist.push([u])
        if W:
            window.append(u)
        segs = hist.segments()
        assert sum(round(d / h) for d, _ in segs) == W
        assert [v for d, u_ in segs for v in [float(u_[0])] * round(d / h)] == list(window)
        assert len(hist.values) == W


# -- the FMUs through fmpy -------------------------------------------------------------
FMU_FILES = {"plant": "DelaycompPlantLTI.fmu", "delay": "DelaycompDelay.fmu",
             "controller": "DelaycompControllerLTI.fmu"}


@pytest.mark.fmu
@pytest.mark.parametrize("kind", sorted(FMU_FILES))
@settings(suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_fmu_never_fatal_and_names_every_refusal(fmu_dir, kind, data):
    comp = FmuComponent(kind, fmu_dir / FMU_FILES[kind])
    params = {}
    for var in comp.md.modelVariables:
        if var.causality == "parameter":
            if var.type == "Real":
                value = data.draw(st.one_of(st.none(), reals))
            elif var.type == "Integer":  # mode_index: 0 .. 2 are allowed, the rest refused
                value = data.draw(st.one_of(st.none(), st.integers(-3, 5)))
            else:
                value = data.draw(st.one_of(st.none(),
                                            st.sampled_from(["compensated", "bogus"])))
            if value is not None:
                params[var.name] = value
    h = data.draw(st.sampled_from([0.25, 0.5, 1.0, 0.3]))
    try:
        comp.setup(0.0, 10.0, params)
        try:
            comp.initialize()
            for k in range(data.draw(st.integers(0, 8))):
                u = [data.draw(inputs) for _ in comp.input_names]
                comp.set_inputs(comp.input_names, u)
                values = comp.get_outputs(comp.output_names)
                # an output may pass a non-finite input straight through (a delay of 0);
                # the step then refuses that input
                if all(math.isfinite(v) for v in u):
                    assert all(math.isfinite(v) for v in values), (u, values)
                comp.do_step(k * h, h)
        except FmuRefused as exc:
            assert NAMED.match(str(exc)), str(exc)
        except FMICallException as exc:
            assert exc.status == 2, comp.messages  # fmi2Discard
            assert NAMED.match(comp.last_message), comp.last_message
        assert comp.worst_status < 4, comp.messages
    finally:
        comp.terminate()


# -- the master, through the scenarios -------------------------------------------------
scenario_settings = st.fixed_dictionaries({}, optional={
    "k": st.sampled_from(["2", "0", "-1", "1e300", "nan", "abc"]),
    "T": st.sampled_from(["1", "0.5", "0", "-1", "inf"]),
    "r": st.sampled_from(["0", "0.25", "0.5", "1.75", "-0.5", "0.3"]),
    "tau": st.sampled_from(["0", "0.5", "1", "0.25"]),
    "N": st.sampled_from(["1", "2", "4", "0", "2.5"]),
    "mode": st.sampled_from(["compensated", "uncompensated", "bogus"]),
    "x0": st.sampled_from(["1", "1e308", "-3", "nan"]),
    "u0": st.sampled_from(["0", "4", "1e308"]),
    "r_true": st.sampled_from(["0", "0.5", "1"]),
})


@pytest.mark.fmu
@settings(suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(values=scenario_settings, periods=st.integers(1, 6))
def test_master_runs_or_names_the_failure(fmu_dir, values, periods):
    sc = scenarios.get("example-3.6")
    try:
        params = sc.resolve([f"{k}={v}" for k, v in values.items()])
    except ParameterError as exc:
        assert " is not allowed" in str(exc) or "unknown" in str(exc), str(exc)
        return
    stop = periods * params["T"]
    result = run_loop(sc.make(params), stop, fmu_dir)
    if result.success:
        assert len(result.times) == periods * params["N"] + 1
        assert np.all(np.isfinite(result.data))
    else:
        assert re.match(r"^\S+ failed at t = \S+: ", result.message), result.message
        reason = result.message.split(": ", 1)[1]
        assert NAMED.match(reason), reason
        assert np.all(np.isfinite(result.data))  # no bad row was recorded
