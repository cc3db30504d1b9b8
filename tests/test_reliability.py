"""Bad parameters, bad inputs and faults during a run, through fmpy, for every FMU.

What each case gets (docs/explanation/reliability.md): a bad parameter is logged with status error
when initialization ends (the message names the variable, its value and the allowed
range) and every later ``doStep`` returns fmi2Discard; a bad input or a fault during a
step ends that step with fmi2Discard and a logged reason. Never fmi2Fatal, and the host
frees the instance afterwards. (pythonfmu 0.7 cannot return fmi2Error:
docs/explanation/reliability.md, "Known limitations".)
"""

from __future__ import annotations

import math
import re
import textwrap

import pytest
from fmpy import read_model_description
from fmpy.fmi1 import FMICallException

from delaycomp.fmu.build import DEFAULT_CONFIG, PACKAGE_DIR
from delaycomp.fmu.cache import fmu_path
from delaycomp.orchestrator.fmu import FmuComponent, FmuRefused
from delaycomp.orchestrator.master import Connection, Master, Recorder, SimulationError
from delaycomp.orchestrator.simulate import run_loop
from delaycomp.paper.scenarios import model_loop

pytestmark = pytest.mark.fmu

MODELS = PACKAGE_DIR / "paper" / "models"
#: every FMU of the registry; the templates once per control mode
VARIANTS = {
    "plant": ("plant", None),
    "delay": ("delay", None),
    "controller": ("controller", None),
    "model_plant-zoh": ("model_plant", MODELS / "example_3_8.py"),
    "model_plant-continuous": ("model_plant", MODELS / "example_2_4.py"),
    "model_controller-zoh": ("model_controller", MODELS / "example_3_8.py"),
    "model_controller-continuous": ("model_controller", MODELS / "example_2_4.py"),
}
#: parameters per variant (checked below, so that a new parameter cannot go unchecked)
#: (with the Integer twin <name>_index of each String choice: mode, predictor, p, law)
N_PARAMETERS = {"plant": 3, "delay": 2, "controller": 11, "model_plant-zoh": 5,
                "model_plant-continuous": 6, "model_controller-zoh": 16,
                "model_controller-continuous": 17}
#: Boolean parameters have no bad value
UNCHECKABLE = {"pad", "held_sample"}


def variant_path(fmu_dir, variant):
    kind, model = VARIANTS[variant]
    config = {"model": str(model)} if model else dict(DEFAULT_CONFIG[kind])
    return fmu_path(kind, config, fmu_dir)


def bad_value(var):
    if var.type == "Real":
        return float("nan")
    if var.type == "Integer" and var.name.endswith("_index"):
        return 99  # a String's Integer twin: 0 .. number of choices
    if var.type == "Integer":
        return 0
    if var.type == "String":
        return "bogus"
    return None


def refusal(fmu_dir, variant, params):
    """The logged reason, after checking that the FMU refused and the host freed it."""
    comp = FmuComponent("c", variant_path(fmu_dir, variant))
    try:
        comp.setup(0.0, 1.0, params)
        with pytest.raises(FmuRefused) as info:
            comp.initialize()
        with pytest.raises(FMICallException) as step:
            comp.do_step(0.0, 0.1)
        assert step.value.status == 2  # fmi2Discard
        assert comp.worst_status == 3  # an error was logged; never fatal
        assert any(m.startswith("[error]") for m in comp.messages)
        return str(info.value)
    finally:
        comp.terminate()


@pytest.mark.parametrize("variant", sorted(VARIANTS))
def test_every_parameter_is_checked(fmu_dir, variant):
    """Each parameter in turn gets a bad value (NaN, N = 0, an index 99, an unknown string): the FMU
    refuses it with a one-line message naming it, its value and the allowed values."""
    md = read_model_description(str(variant_path(fmu_dir, variant)))
    params = [v for v in md.modelVariables if v.causality == "parameter"]
    assert len(params) == N_PARAMETERS[variant]
    unexplained = {}
    for var in params:
        value = bad_value(var)
        if var.name in UNCHECKABLE:
            assert value is None
            continue
        message = refusal(fmu_dir, variant, {var.name: value})
        shown = "nan" if isinstance(value, float) else repr(value)
        pattern = rf"^{re.escape(var.name)} = {re.escape(shown)} is not allowed: must be "
        if not re.search(pattern, message) or "\n" in message:
            unexplained[var.name] = message
    assert unexplained == {}


RANGES = [
    ("plant", {"x0[1]": math.inf}, r"x0\[1\] = inf is not allowed: must be a finite number"),
    ("delay", {"delay": -0.5}, r"delay = -0.5 is not allowed: must be >= 0"),
    ("controller", {"T": 0.0}, r"T = 0.0 is not allowed: must be > 0"),
    ("controller", {"T": 1.0, "r": -1.0}, r"r = -1.0 is not allowed: must be >= 0"),
    ("controller", {"T": 1.0, "tau": 0.5},
     r"tau = 0.5 is not allowed: zero-order hold needs a multiple l\*T \(l >= 0\) of "
     r"T = 1.0"),
    ("controller", {"mode": "open"}, r"mode = 'open' is not allowed: must be one of"),
    ("model_plant-zoh", {"tolerance": 1.5}, r"tolerance = 1.5 is not allowed: must be in"),
    ("model_plant-zoh", {"p": "cube"},
     r"p = 'cube' is not allowed: must be one of square, sin"),
    ("model_controller-zoh", {"N": -3}, r"N = -3 is not allowed: must be a positive integer"),
    ("model_controller-zoh", {"T": 1.0, "N": 10, "tau": 0.5},
     r"tau = 0.5 is not allowed: zero-order hold needs a multiple l\*T \(l >= 0\) of "
     r"T = 1.0; pad = true pads it up to 1.0 \(Remark 3.3\(b\)\)"),
    ("model_controller-zoh", {"T": 1.0, "N": 10, "r": 0.55},
     r"r = 0.55 is not allowed: must be a multiple of the base step h = 0.1"),
    ("model_controller-zoh", {"predictor": "guess"},
     r"predictor = 'guess' is not allowed: must be one of closed, numerical"),
    ("model_controller-continuous", {"mode": "zoh"},
     r"mode = 'zoh' is not allowed: model example_2_4 gives a continuous feedback"),
    ("model_controller-continuous", {"tolerance": 0.0},
     r"tolerance = 0.0 is not allowed: must be in \(0, 1\)"),
    ("model_controller-continuous", {"law": "guess"},
     r"law = 'guess' is not allowed: must be one of corrected, printed"),
]


@pytest.mark.parametrize("variant,params,message", RANGES,
                         ids=[f"{v}-{'-'.join(p)}" for v, p, _ in RANGES])
def test_out_of_range_parameter_is_named(fmu_dir, variant, params, message):
    assert re.search(message, refusal(fmu_dir, variant, params))


INPUTS = [("plant", "u"), ("delay", "u"), ("controller", "y"),
          ("model_plant-zoh", "u"), ("model_controller-zoh", "y_x1"),
          ("model_controller-continuous", "y_x3")]


@pytest.mark.parametrize("variant,name", INPUTS, ids=[v for v, _ in INPUTS])
@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf], ids=["nan", "inf", "-inf"])
def test_non_finite_input_ends_the_step_with_a_named_reason(fmu_dir, variant, name, value):
    comp = FmuComponent("c", variant_path(fmu_dir, variant))
    h = 0.01
    try:
        comp.setup(0.0, 1.0, {"N": 100} if "controller-" in variant else {})
        comp.initialize()
        comp.do_step(0.0, h)
        comp.set_inputs([name], [value])
        with pytest.raises(FMICallException) as info:
            comp.do_step(h, h)
        assert info.value.status == 2  # fmi2Discard
        assert comp.last_message == (f"input {name} = {value!r} at t = {h!r} is not "
                                     "allowed: must be a finite number")
        with pytest.raises(FMICallException):  # and it stays refused
            comp.do_step(h, h)
    finally:
        comp.terminate()


def test_diverging_plant_stops_the_master_with_partial_results(fmu_dir):
    """x' = 700 x from 1 overflows at the second step of h = 1; the master names the FMU,
    the time and the reason and keeps the rows recorded so far."""
    plant = FmuComponent("plant", fmu_dir / "DelaycompPlantLTI.fmu")
    master = Master([plant], [], T=1.0, N=1)
    rec = Recorder(master, [("plant", "x")])
    master.add_observer(rec)
    try:
        master.setup(10.0, {"plant": {"A[1,1]": 700.0, "x0[1]": 1.0}})
        master.initialize()
        with pytest.raises(SimulationError) as info:
            master.run_until(10)
    finally:
        master.terminate()
    assert str(info.value) == ("plant failed at t = 1: state ['x'] = [inf] at t = 2.0 is "
                               "not allowed: must be finite (the plant diverged: overflow)")
    assert rec.times == [0.0, 1.0]
    assert list(rec.rows[0]) == [1.0] and 1e300 < rec.rows[1][0] < math.inf


def test_step_the_delay_cannot_honour_is_refused(fmu_dir):
    comp = FmuComponent("d", fmu_dir / "DelaycompDelay.fmu")
    try:
        comp.setup(0.0, 1.0, {"delay": 0.2})
        comp.initialize()
        comp.do_step(0.0, 0.1)
        with pytest.raises(FMICallException) as info:
            comp.do_step(0.1, 0.05)
        assert info.value.status == 2
        assert comp.last_message == ("step size 0.05 is not allowed: this delay runs on a "
                                     "fixed communication step, 0.1")
    finally:
        comp.terminate()


BLOWUP = textwrap.dedent('''
    """x' = x^2 + u: not forward complete, so the predictor's ODE solve can fail."""
    import numpy as np
    STATES = ("x",)
    INPUTS = ("u",)
    CONTROL = "zoh"
    def f(x, u, p):
        return np.array([x[0] ** 2 + u[0]])
    def k(x, p):
        return np.array([-x[0] ** 2 - x[0]])
''')


def test_failing_predictor_solve_stops_the_run_with_the_reason(tmp_path):
    """From y = 5 with r = 1 and no input, the predicted state escapes to infinity (x(t) =
    5/(1 - 5t) blows up at t = 0.2 < r): the controller cannot compute u at t0. The run
    stops there naming the controller, and no row with the bad output is recorded."""
    model = tmp_path / "blowup.py"
    model.write_text(BLOWUP, encoding="utf-8")
    spec = model_loop(model, T=1.0, r=1.0, tau=0.0, N=10, x0=[5.0], u0=[0.0],
                      predictor="numerical")
    result = run_loop(spec, 5.0, tmp_path / "fmus")
    assert not result.success
    assert re.match(r"controller failed at t = 0: computing the control at t = 0.0 failed: "
                    r"IntegrationError: ODE solve failed", result.message), result.message
    assert "\n" not in result.message
    assert len(result.times) == 0


def test_failing_plant_solve_ends_the_step_with_the_reason(tmp_path):
    """The plant alone, x' = x^2 from 5, escapes at t = 0.2: the step over [0.2, 0.3)
    cannot be taken (the ODE solver's step size underflows)."""
    model = tmp_path / "blowup.py"
    model.write_text(BLOWUP, encoding="utf-8")
    comp = FmuComponent("plant", fmu_path("model_plant", {"model": str(model)},
                                          tmp_path / "fmus"))
    try:
        comp.setup(0.0, 1.0, {"x0[1]": 5.0})
        comp.initialize()
        with pytest.raises(FMICallException) as info:
            for k in range(10):
                comp.do_step(k * 0.1, 0.1)
        assert info.value.status == 2
        assert k in (1, 2)
        assert comp.last_message.startswith(f"plant step at t = {k * 0.1!r} failed: ODE solve "
                                            "failed")
    finally:
        comp.terminate()


def test_connection_to_a_missing_variable_is_named(fmu_dir):
    plant = FmuComponent("plant", fmu_dir / "DelaycompPlantLTI.fmu")
    with pytest.raises(ValueError, match="plant has no input 'v'"):
        Master([plant], [Connection.parse("plant.x -> plant.v")], T=1.0, N=1)


@pytest.mark.parametrize("config", [{"n": 0}, {"n": -1}, {"n": 1.5}, {"n": True}],
                         ids=["zero", "negative", "float", "bool"])
def test_bad_dimension_is_refused_before_building(tmp_path, config):
    from delaycomp.fmu.build import build_fmu

    with pytest.raises(ValueError, match=r"^n = .+ is not allowed: must be an integer from 1"):
        build_fmu("delay", tmp_path, config)
    assert list(tmp_path.iterdir()) == []
