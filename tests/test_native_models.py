"""The native plant of a user model (issue 23, items 1 and 2 for the plant): ``f`` (and an
exact ``step`` that translates) in C from ``delaycomp.fmu.translate``, the flow by
``fmus/native/ode.c``; the twin of the Python model plant FMU.

Against the Python FMUs in our master (the Python plant uses the model's exact step where
it has one), against an independent solve of the plant alone, and for the FMI semantics:
the same refusals with the same messages, the String choices and their Integer twins, the
FMU state.
"""

from __future__ import annotations

import textwrap

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from delaycomp.fmu.native import build_native_fmu, native_fmu_path
from delaycomp.fmu.translate import TranslationError
from delaycomp.maths.model import load_model
from delaycomp.orchestrator.fmu import FmuComponent
from delaycomp.orchestrator.inprocess import SlaveComponent
from delaycomp.orchestrator.simulate import run_loop, stop_ticks
from delaycomp.paper import scenarios

from .test_native import (
    _restore_run,
    assert_initialize_refused_alike,
    assert_same_table,
    assert_step_refused_alike,
)

#: DOP853's error control holds each step's local error to about ``tol (1 + |x|)`` (tol =
#: 1e-10, the FMUs' default); the Python plant steps exactly (or with the same method);
#: the loops are stable, so the differences of K steps add up to at most K tol of each
#: signal's scale. Measured: 0 (Example 2.4), 3.3e-16 (Example 3.8: its translated exact
#: step) and 0 (Corollary 4.1: its translated exact step) of the peak.
TOL = 1e-10

CASES = [("example-2.4", []), ("example-3.8", []), ("example-3.8", ["p=sin"]),
         ("corollary-4.1", [])]


def native_plant(loop):
    plant = next(i for i in loop.instances if i.name == "plant")
    return native_fmu_path("model_plant", plant.source.build_key()[1])


@pytest.mark.parametrize("name,sets", CASES, ids=lambda c: str(c))
def test_native_plant_in_the_loop_equals_the_python_plant(name, sets, fmu_dir):
    sc = scenarios.get(name)
    loop = sc.make(sc.resolve(sets))
    stop = min(sc.stop_time if hasattr(sc, "stop_time") else 10.0, 10.0)
    stop = stop_ticks(stop, loop.T, loop.N) * loop.h
    python = run_loop(loop, stop, fmu_dir)
    native = run_loop(loop, stop, fmu_dir, fmus={"plant": native_plant(loop)})
    assert python.success and native.success, native.message
    ticks = len(python.times)
    scale = np.maximum(1.0, np.max(np.abs(python.data), axis=0))
    assert np.all(np.abs(native.data - python.data) <= ticks * TOL * scale)


def _plant_alone(fmu, model, x0, inputs, h):
    comp = FmuComponent("plant", fmu)
    try:
        comp.setup(0.0, h * len(inputs), {f"x0[{i + 1}]": v for i, v in enumerate(x0)})
        comp.initialize()
        states = [np.array(comp.get_outputs(list(model.states)))]
        for k, u in enumerate(inputs):
            comp.set_inputs(list(model.inputs), list(u))
            comp.do_step(k * h, h)
            states.append(np.array(comp.get_outputs(list(model.states))))
        return np.array(states)
    finally:
        comp.terminate()


@pytest.mark.parametrize("model_name", ["example_2_4", "example_3_8", "corollary_4_1"])
def test_native_plant_equals_an_independent_solve(model_name):
    """The plant alone under random held inputs against scipy's ``solve_ivp`` (RK45 of
    another family, rtol = atol = 1e-12) of the model's Python ``f``: shares no code with
    the translation or ode.c. DOP853 at tol = 1e-10 and the reference at 1e-12: within
    1e-8 of the state's scale over 50 steps (measured: 1e-12)."""
    from delaycomp.paper.models import path

    model = load_model(path(model_name))
    fmu = native_fmu_path("model_plant", {"model": str(path(model_name))})
    rng = np.random.default_rng(11)
    x0 = rng.uniform(-1, 1, model.n)
    inputs = rng.uniform(-1, 1, (50, model.m))
    h = 0.1
    got = _plant_alone(fmu, model, x0, inputs, h)
    x, want = np.array(x0), [np.array(x0)]
    for u in inputs:
        sol = solve_ivp(lambda _t, s, u=u: model.f(s, u, dict(model.parameters)), (0.0, h),
                        x, method="RK45", rtol=1e-12, atol=1e-12)
        x = sol.y[:, -1]
        want.append(x)
    want = np.array(want)
    scale = np.maximum(1.0, np.max(np.abs(want)))
    assert np.max(np.abs(got - want)) <= 1e-8 * scale


def _both(kind_model, params):
    """The Python model plant (in-process slave) and the native one, set up with params."""
    from delaycomp.paper.models import path

    model_path = str(path(kind_model))
    slave = SlaveComponent("x", "model_plant", {"model": model_path})
    comp = FmuComponent("x", native_fmu_path("model_plant", {"model": model_path}))
    for c in (slave, comp):
        c.setup(0.0, 10.0, params)
    return slave, comp


BAD = [
    ("example_3_8", {"tolerance": 0.0}),
    ("example_3_8", {"tolerance": 1.5}),
    ("example_3_8", {"tolerance": float("nan")}),
    ("example_3_8", {"x0[2]": float("inf")}),
    ("example_3_8", {"p": "cube"}),
    ("example_3_8", {"p_index": 3}),
    ("example_3_8", {"p": "sin", "p_index": 1}),
    ("corollary_4_1", {"x0[1]": float("nan")}),
]


@pytest.mark.parametrize("model_name,params", BAD, ids=lambda p: str(p))
def test_a_bad_parameter_is_refused_with_the_python_message(model_name, params):
    slave, comp = _both(model_name, params)
    try:
        assert_initialize_refused_alike(slave, comp)
    finally:
        comp.terminate()


def test_a_bad_input_or_step_is_refused_with_the_python_message():
    for step, u in (((0.0, 0.1), float("nan")), ((0.0, -0.1), 1.0), ((0.0, float("inf")), 1.0)):
        slave, comp = _both("example_3_8", {"x0[1]": 0.5})
        try:
            assert_step_refused_alike(slave, comp, {"u": u}, step)
        finally:
            comp.terminate()


@pytest.mark.parametrize("params", [{"p": "sin"}, {"p_index": 2}], ids=["string", "index"])
def test_a_choice_by_string_or_by_index_selects_the_branch(params):
    """``p = "sin"`` and ``p_index = 2`` give the sine shape: the Python plant's numbers."""
    slave, comp = _both("example_3_8", {**params, "x0[1]": 0.3, "x0[2]": 1.1})
    try:
        rows = []
        for c in (slave, comp):
            c.initialize()
            c.set_inputs(["u"], [0.7])
            for k in range(20):
                c.do_step(k * 0.05, 0.05)
            rows.append(np.array(c.get_outputs(["x1", "x2"])))
        # the exact sine step against DOP853 at 1e-10 over 20 short steps
        assert np.allclose(rows[1], rows[0], rtol=0, atol=20 * TOL)
        x2 = 1.1 + 0.7 * 1.0
        assert rows[1][1] == pytest.approx(x2, rel=1e-14)
        # not the square shape: x1 differs by far more than the tolerance
        assert abs(rows[1][0] - (0.3 + 1.1 + 0.35 + (x2 ** 3 - 1.1 ** 3) / 3)) > 1e-3
    finally:
        comp.terminate()


def test_fmu_state_continues_bit_identically():
    """Saved half-way, the loop with the native plant continues as it did, bit for bit,
    in the same master and in a fresh one (``tests/test_native.py``'s restore run)."""
    sc = scenarios.get("example-3.8")
    loop = sc.make(sc.resolve([]))
    fmus = {"plant": native_plant(loop)}
    ticks = stop_ticks(6.0, loop.T, loop.N)
    first, second, third = _restore_run(fmus, loop, 6.0, ticks // 2)
    assert len(first) > 10 and second == first and third == first


def write_model(tmp_path, body: str):
    path = tmp_path / "mine.py"
    path.write_text(textwrap.dedent('''
        import math
        import numpy as np
        STATES = ("x1", "x2")
        INPUTS = ("u",)
        CONTROL = "zoh"
        PARAMETERS = {"a": 0.5, "shape": "soft"}
        CHOICES = {"shape": ("soft", "hard")}
    ''') + textwrap.dedent(body), encoding="utf-8")
    return path


def test_a_users_model_with_a_numeric_parameter_and_a_choice(tmp_path):
    """A model that is not shipped: a numeric parameter set through the FMU, a String
    choice, ``math`` and ``np.where`` in ``f``; the native plant equals the Python one."""
    path = write_model(tmp_path, '''
        def f(x, u, p):
            damp = p["a"] * (np.tanh(x[1]) if p["shape"] == "soft" else x[1])
            return np.array([x[1], -math.sin(x[0]) - damp + np.where(x[0] > 0, u[0], 0.5 * u[0])])

        def k(x, p):
            return np.array([-x[0] - x[1]])
    ''')
    comp = FmuComponent("x", build_native_fmu("model_plant", tmp_path / "fmu",
                                              {"model": str(path)}))
    slave = SlaveComponent("x", "model_plant", {"model": str(path)})
    params = {"a": 0.8, "shape": "hard", "x0[1]": 1.0, "x0[2]": -0.5}
    try:
        for c in (slave, comp):
            c.setup(0.0, 10.0, params)
            c.initialize()
        for k in range(100):
            u = np.sin(0.3 * k)
            for c in (slave, comp):
                c.set_inputs(["u"], [u])
                c.do_step(k * 0.1, 0.1)
        py, nat = (np.array(c.get_outputs(["x1", "x2"])) for c in (slave, comp))
        # the same method (DOP853, tol 1e-10) in Python (scipy) and in C; the two take
        # different steps after a rejection (fmus/native/README.md): 100 steps of tol each
        assert np.max(np.abs(nat - py)) <= 100 * TOL * max(1.0, np.max(np.abs(py)))
    finally:
        comp.terminate()


def test_a_model_that_does_not_translate_is_refused_in_one_line(tmp_path):
    path = write_model(tmp_path, '''
        def f(x, u, p):
            if x[0] > 0:
                return np.array([x[1], u[0]])
            return np.array([x[1], -u[0]])

        def k(x, p):
            return np.array([-x[0]])
    ''')
    with pytest.raises(TranslationError, match=r"mine\.py:\d+ \(`if x\[0\] > 0:`\)"):
        build_native_fmu("model_plant", tmp_path / "fmu", {"model": str(path)})


@pytest.mark.parametrize("model_name", ["example_2_4", "example_3_8"])
def test_the_model_description_is_the_python_table_and_the_sources_compile(
        model_name, tmp_path):
    """Same variables, value references, types, starts, descriptions and dependencies as
    the Python model plant; ``sources/`` (generated model.c and headers included) compile
    on their own with strict warnings, and the build is reproducible."""
    import subprocess
    import zipfile

    from fmpy import read_model_description

    from delaycomp.fmu.build import build_fmu
    from delaycomp.fmu.native import CFLAGS, compiler
    from delaycomp.paper.models import path

    config = {"model": str(path(model_name))}
    nat_path = native_fmu_path("model_plant", config)
    nat = read_model_description(str(nat_path), validate=True)
    py = read_model_description(str(build_fmu("model_plant", tmp_path / "py", config)),
                                validate=True)
    assert_same_table(nat, py)
    assert nat.coSimulation.modelIdentifier == py.coSimulation.modelIdentifier
    assert not nat.coSimulation.needsExecutionTool and nat.guid != py.guid
    files = nat.buildConfigurations[0].sourceFileSets[0].sourceFiles
    assert files == ["fmi2.c", "core.c", "native.c", "pyrepr.c", "ode.c", "model_common.c",
                     "model_plant.c", "model.c"]
    with zipfile.ZipFile(nat_path) as zf:
        zf.extractall(tmp_path / "unzipped")
        model_c = zf.read("sources/model.c")
    src = tmp_path / "unzipped" / "sources"
    subprocess.run([*compiler(), *CFLAGS, "-I", str(src), "-o", str(tmp_path / "x.so"),
                    *(str(src / f) for f in files), "-lm"], check=True)
    again = build_native_fmu("model_plant", tmp_path / "again", config)
    with zipfile.ZipFile(again) as zf:
        assert zf.read("sources/model.c") == model_c
