"""Model files as C (issue 23, item 1, first piece): ``delaycomp.fmu.translate``.

The generated C is compiled with the project's compiler and flags and called through
ctypes at random points, against the model's own Python functions, for every branch of the
string parameters; what cannot be traced is refused with the line of the user's file.
"""

from __future__ import annotations

import ctypes
import math
import subprocess
import textwrap

import casadi  # the native extra, part of the test extra: never skipped
import numpy as np
import pytest

from delaycomp.fmu.native import compiler
from delaycomp.fmu.translate import TranslationError, translate
from delaycomp.maths.model import load_model
from delaycomp.paper.models import path as builtin_model

from .roundoff import EPS

#: The C evaluates the expression graph CasADi traced from the Python function, rewritten
#: in a few places (``x**3`` as ``x*(x*x)``, ``2*x`` as a doubling, constants folded), with
#: C's libm for numpy's: each rewrite moves a result by a few roundings of the terms it
#: combines. At points with |x|, |u| <= 2 the terms are below 1e3, so 1e3 EPS of
#: max(1, |value|) holds a correct translation and refuses any wrong term or branch.
ULPS = 1e3


def compile_translation(tr, tmp_path):
    src = tmp_path / "model.c"
    src.write_text(tr.source(), encoding="utf-8")
    lib = tmp_path / "model.so"
    proc = subprocess.run([*compiler(), "-std=c11", "-O2", "-Wall", "-Wextra", "-Werror",
                           "-fPIC", "-shared", str(src), "-o", str(lib), "-lm"],
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    return ctypes.CDLL(str(lib))


def call_c(lib, fn, values: dict) -> np.ndarray:
    """Call the C function ``fn`` (a CFunction) with ``values`` for its arguments."""
    c_fn = getattr(lib, fn.name)
    args, keep = [], []
    for a in fn.args:
        if a in ("t", "h"):
            args.append(ctypes.c_double(values[a]))
        else:
            arr = np.ascontiguousarray(values[a], dtype=float)
            keep.append(arr)
            args.append(arr.ctypes.data_as(ctypes.POINTER(ctypes.c_double)))
    out = np.zeros(fn.n_out)
    args.append(out.ctypes.data_as(ctypes.POINTER(ctypes.c_double)))
    c_fn.restype = ctypes.c_int
    assert c_fn(*args) == 0
    return out


def check_against_python(tr, lib, points: int = 50, seed: int = 3):
    model = tr.model
    rng = np.random.default_rng(seed)
    compared = 0
    for (name, index), fn in tr.functions.items():
        choice = tr.choices[index]
        for _ in range(points):
            x = rng.uniform(-2, 2, model.n)
            u = rng.uniform(-2, 2, model.m)
            num = {key: (rng.uniform(0.2, 2.0) if key == "T" else
                         float(model.parameters[key]) * rng.uniform(0.5, 1.5))
                   for key in tr.numeric}
            t, h = rng.uniform(0, 10), rng.uniform(0.01, 0.5)
            p = {**model.parameters, **choice, **num}
            if name == "f":
                want = model.f(x, u, p)
            elif name == "step":
                want = model.step(x, u, h, p)
            else:
                want = model.k(t, x, p) if model.control == "continuous" else model.k(x, p)
            got = call_c(lib, fn, {"x": x, "u": u, "t": t, "h": h,
                                   "p": [num[key] for key in tr.numeric]})
            want = np.asarray(want, dtype=float)
            bound = ULPS * EPS * np.maximum(1.0, np.abs(want))
            assert np.all(np.abs(got - want) <= bound), (name, choice, x, u, got, want)
            compared += 1
    return compared


@pytest.mark.parametrize("name", ["example_2_4", "example_3_8", "corollary_4_1",
                                  "proposition_4_2"])
def test_a_shipped_model_translates_and_its_c_equals_its_python(name, tmp_path):
    tr = translate(load_model(builtin_model(name)))
    lib = compile_translation(tr, tmp_path)
    branches = max(1, len(tr.choices))
    assert {key[0] for key in tr.functions} == {"f", "k", "step"}
    assert len(tr.functions) == 3 * branches
    assert check_against_python(tr, lib) == 50 * len(tr.functions)


def test_branches_on_a_string_parameter_are_one_c_function_each(tmp_path):
    """Example 3.8's ``p = "square"`` or ``"sin"``: two f's that differ, each equal to the
    Python f with that choice."""
    tr = translate(load_model(builtin_model("example_3_8")))
    assert [c["p"] for c in tr.choices] == ["square", "sin"]
    assert "sin(" in tr.functions["f", 1].code and "sin(" not in tr.functions["f", 0].code
    lib = compile_translation(tr, tmp_path)
    x, u = np.array([0.3, 1.2]), np.array([0.7])
    square = call_c(lib, tr.functions["f", 0], {"x": x, "u": u, "p": [1.0]})
    sine = call_c(lib, tr.functions["f", 1], {"x": x, "u": u, "p": [1.0]})
    assert square[0] == pytest.approx(1.2 + 1.2 ** 2 * 0.7, rel=1e-15)
    assert sine[0] == pytest.approx(1.2 + math.sin(1.2) * 0.7, rel=1e-15)


def write_model(tmp_path, body: str, name: str = "mine"):
    path = tmp_path / f"{name}.py"
    path.write_text(textwrap.dedent('''
        import math
        import numpy as np
        STATES = ("x1", "x2")
        INPUTS = ("u",)
        CONTROL = "zoh"
        PARAMETERS = {"a": 0.5}
    ''') + textwrap.dedent(body), encoding="utf-8")
    return load_model(path)


def test_a_users_model_with_math_numpy_and_np_where_translates(tmp_path):
    """``math.sin`` of the state, numpy's functions, a numeric parameter and a branch on
    the state written as ``np.where``: traced, and equal to the Python on both sides."""
    model = write_model(tmp_path, '''
        def f(x, u, p):
            return np.array([x[1] + p["a"] * math.sin(x[0]),
                             np.where(x[0] > 0, -x[1], 2.0 * x[1]) + np.tanh(u[0])])

        def k(x, p):
            return np.array([-np.clip(x[0] + 2.0 * x[1], -1.0, 1.0) / p["T"]])
    ''')
    tr = translate(model)
    assert tr.numeric == ("a", "T")
    lib = compile_translation(tr, tmp_path)
    assert check_against_python(tr, lib, points=200) == 400


@pytest.mark.parametrize("body,operation,line", [
    ('''
        def f(x, u, p):
            if x[0] > 0:
                return np.array([x[1], u[0]])
            return np.array([-x[1], u[0]])

        def k(x, p):
            return np.array([-x[0]])
     ''', "a Python branch", "if x[0] > 0:"),
    ('''
        def f(x, u, p):
            return np.array([x[1], u[0]])

        def k(x, p):
            gain = float(x[0])
            return np.array([-gain])
     ''', "float() of a value", "gain = float(x[0])"),
    ('''
        def f(x, u, p):
            return np.array([x[1], max(u[0], 0.0)])

        def k(x, p):
            return np.array([-x[0]])
     ''', "a Python branch", "max(u[0], 0.0)"),
])
def test_what_does_not_trace_is_refused_with_its_line(tmp_path, body, operation, line):
    model = write_model(tmp_path, body)
    with pytest.raises(TranslationError) as err:
        translate(model)
    msg = str(err.value)
    assert "\n" not in msg
    assert operation in msg and "mine.py:" in msg and line in msg, msg
    assert "the Python FMUs run it" in msg
    # the tracer put back what it replaced
    assert math.cos(0.0) == 1.0 and isinstance(math.sin(0.5), float)
    assert math.isnan(float(casadi.SX.sym("z")))  # CasADi's own float() again


def test_a_step_that_does_not_trace_is_reported_not_fatal(tmp_path):
    """``step`` is optional (the plant can integrate ``f``): one that converts the input
    with ``float()`` is reported, and ``f`` and ``k`` stand; every shipped model's step
    translates, for every branch."""
    model = write_model(tmp_path, '''
        def f(x, u, p):
            return np.array([x[1], u[0]])

        def k(x, p):
            return np.array([-x[0] - x[1]])

        def step(x, u, h, p):
            v = float(u[0])
            return np.array([x[0] + x[1] * h + v * h * h / 2.0, x[1] + v * h])
    ''', name="floaty")
    tr = translate(model)
    assert ("step", 0) not in tr.functions and ("f", 0) in tr.functions
    assert "float()" in tr.untranslated["step"] and "floaty.py:" in tr.untranslated["step"]
    for name in ("example_2_4", "example_3_8", "corollary_4_1", "proposition_4_2"):
        tr = translate(load_model(builtin_model(name)))
        assert not tr.untranslated
        branches = range(max(1, len(tr.choices)))
        assert sorted(tr.functions) == [(fn, i) for fn in ("f", "k", "step") for i in branches]


#: The unicycle's C against its Python at the branch edges: the exact step's ``sinc`` (``omega
#: h / 2 == 0``: omega = 0, -0, or so small that the product underflows) and Proposition
#: 4.2's sets (chained ``x2 = 0`` or ``x1 = 0`` exactly, all zero, just inside and outside
#: ``SET_TOL``; printed: C3 and C2 states) and huge states. The Python and the C compute the
#: same operations in the same order with the same libm (glibc's ``sin`` for ``math.sin``),
#: only CasADi's graph in between: measured 0 at every point here. A few EPS of each value
#: allow another libm or a CasADi that folds a constant otherwise; a wrong set or a wrong
#: term is off by far more.
EDGE_ULPS = 4


def _unicycle_edge_points(rng):
    tol = 1e-12
    states = [np.zeros(3), np.array([0.0, 0.0, 0.5]), np.array([0.0, 0.0, -0.0]),
              np.array([1.0, 0.0, 0.0]), np.array([-2.0, -0.0, 0.0]),
              np.array([0.0, 0.3, 0.0]), np.array([1e60, -1e60, 1.0]),
              np.array([1e-300, -1e-300, 0.0])]
    for y in (tol, -tol, np.nextafter(tol, 0), np.nextafter(tol, 1), 2 * tol, 0.5 * tol):
        states += [np.array([0.0, y, 0.0]), np.array([1.0, y, 0.0]),
                   np.array([y, 0.0, 0.0]), np.array([y, 0.0, 0.7])]
    for a, theta in ((1.0, 0.4), (-1.5, 1.1), (0.2, -2.0)):  # chained x2 ~ 0, x3 != 0: C2
        states.append(np.array([a * math.cos(theta), a * math.sin(theta), theta]))
    states += [rng.uniform(-2, 2, 3) for _ in range(40)]
    inputs = [np.array([1.0, 0.0]), np.array([-0.5, -0.0]), np.array([0.7, 5e-324]),
              np.array([0.0, 0.0]), np.array([0.0, 1.3]), np.array([2.0, 1e-300]),
              np.array([1e100, 3.0])]
    inputs += [rng.uniform(-2, 2, 2) for _ in range(10)]
    return states, inputs


@pytest.mark.parametrize("name", ["proposition_4_2", "corollary_4_1"])
def test_the_unicycle_models_translate_and_their_c_equals_their_python_at_the_edges(
        name, tmp_path):
    """Section 4's models (the exact flow, Proposition 4.2's sets written with
    ``np.where``) translate fully; ``k`` and ``step`` in C equal the Python functions on
    both sides of every branch, within EDGE_ULPS EPS of each value (measured: 0)."""
    tr = translate(load_model(builtin_model(name)))
    assert not tr.untranslated
    branches = range(max(1, len(tr.choices)))
    assert sorted(tr.functions) == [(fn, i) for fn in ("f", "k", "step") for i in branches]
    lib = compile_translation(tr, tmp_path)
    model = tr.model
    states, inputs = _unicycle_edge_points(np.random.default_rng(7))
    worst, compared = 0.0, 0
    for index, choice in enumerate(tr.choices):
        for T in (1.0, 0.5, 1.7):
            p = {**model.parameters, **choice, "T": T}
            num = [p[key] for key in tr.numeric]
            for x in states:
                for fn_name in ("k", "step"):
                    cases = ([(None, 0.3 * T)] if fn_name == "k"
                             else [(u, h) for u in inputs for h in (T, 0.1, 0.0)])
                    for u, h in cases:
                        if fn_name == "k":
                            want = (model.k(h, x, p) if model.control == "continuous"
                                    else model.k(x, p))
                        else:
                            want = model.step(x, u, h, p)
                        got = call_c(lib, tr.functions[fn_name, index],
                                     {"x": x, "u": u, "t": h, "h": h, "p": num})
                        want = np.asarray(want, dtype=float)
                        assert np.all(np.isfinite(want)), (fn_name, x, u, h)
                        err = np.max(np.abs(got - want) / np.maximum(1.0, np.abs(want)))
                        worst = max(worst, err / EPS)
                        compared += 1
    assert compared > 1000
    assert worst <= EDGE_ULPS, worst


def test_a_string_parameter_without_choices_is_refused(tmp_path):
    model = write_model(tmp_path, '''
        PARAMETERS = {"mode": "fast"}

        def f(x, u, p):
            return np.array([x[1], u[0]])

        def k(x, p):
            return np.array([-x[0] if p["mode"] == "fast" else -2.0 * x[0]])
    ''', name="free")
    with pytest.raises(TranslationError, match="'mode' has no CHOICES"):
        translate(model)


def test_a_wrong_number_of_outputs_is_refused(tmp_path):
    model = write_model(tmp_path, '''
        def f(x, u, p):
            return np.array([x[1], u[0]])

        def k(x, p):
            if isinstance(x[0], float):
                return np.array([-x[0]])
            return np.array([-x[0], -x[1]])
    ''', name="wide")
    with pytest.raises(TranslationError, match=r"returned 2 values, must be 1"):
        translate(model)
