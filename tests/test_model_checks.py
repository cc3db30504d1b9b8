"""A user model is checked once at load, its own exceptions are reported, it is imported
once per process, and ``sys.exit`` in it cannot end a run silently (issue 16, item 8).

Before: an ``f`` returning the wrong number of entries ran; an ``f`` that raised was
reported as scipy's "Function to integrate must not return a tuple"; a model module was
imported twice per run (its side effects repeated); a ``k`` calling ``sys.exit(0)`` ended
an in-process run with exit status 0 and no result.
"""

from __future__ import annotations

import os
import textwrap

import numpy as np
import pytest

from delaycomp.maths.model import ModelError, load_model
from delaycomp.maths.predictors import IntegrationError, integrate
from delaycomp.orchestrator.simulate import run_loop
from delaycomp.paper.scenarios import model_loop

pytestmark = pytest.mark.fmu

BASE = '''
import numpy as np
STATES = ("x1", "x2")
INPUTS = ("u",)
CONTROL = "zoh"
def f(x, u, p):
    return {f}
def k(x, p):
    return {k}
'''


def _model(tmp_path, name, f="np.array([x[1], u[0]])", k="np.array([-x[0] - x[1]])",
           extra=""):
    path = tmp_path / f"{name}.py"
    path.write_text(BASE.format(f=f, k=k) + textwrap.dedent(extra), encoding="utf-8")
    return path


@pytest.mark.parametrize("f,k,message", [
    ("np.array([x[1], u[0], 0.0])", "np.array([-x[0]])",
     r"f\(x, u, p\) returned shape \(3,\), must be \(2,\): one entry per state"),
    ("np.array([x[1]])", "np.array([-x[0]])", r"returned shape \(1,\), must be \(2,\)"),
    ("np.array([x[1], u[0]])", "np.array([-x[0], 0.0])",
     r"k\(x, p\) returned shape \(2,\), must be \(1,\): one entry per input"),
    ("np.array([x[1], u[0]])", "-x[0]", r"k\(x, p\) returned shape \(\), must be \(1,\)"),
])
def test_wrong_number_of_entries_is_refused_at_load(tmp_path, f, k, message):
    with pytest.raises(ModelError, match=message):
        load_model(_model(tmp_path, "wrong", f=f, k=k))


def test_a_model_undefined_at_zero_still_loads(tmp_path):
    """The load check calls f and k at 0; a model that raises there is not refused."""
    model = load_model(_model(tmp_path, "log", f="np.array([np.log(x[0]) if x[0] > 0 else "
                                                 "1 / 0, u[0]])"))
    assert model.n == 2


def test_the_models_own_exception_is_reported_at_once():
    """The compiled DOP853 cannot be stopped from inside f: after f raised it went on
    calling f until its step budget was spent (1.2e6 calls, 8 s, before the message).
    Now f is called once, and its exception is the message."""
    calls = []

    def f(x, u, p):
        calls.append(x)
        raise ValueError("the model gave up")
    with pytest.raises(IntegrationError, match=r"the model's f raised ValueError: the model "
                                               r"gave up"):
        integrate(f, {}, [1.0], [(0.1, np.array([0.0]))])
    assert len(calls) == 1


@pytest.mark.parametrize("engine", ["fmu", "inprocess"])
def test_a_model_is_imported_once_per_process(tmp_path, engine):
    """Its side effect (its process id appended to a file at import) happens once in each
    process: this one loads, wires and runs it (the FMUs import it by the same module
    name, so they find it loaded); each FMU build is a child process of its own."""
    marker = tmp_path / "imports.txt"
    path = _model(tmp_path, f"counted_{engine}", extra=f'''
        import os
        with open({str(marker)!r}, "a") as fh:
            fh.write(f"{{os.getpid()}}\\n")
    ''')
    spec = model_loop(path, T=0.1, r=0.0, tau=0.0, N=1, x0=[1.0, 0.0], u0=[0.0])
    result = run_loop(spec, 0.3, tmp_path / "fmus", engine=engine)
    assert result.success, result.message
    pids = marker.read_text().splitlines()
    assert pids.count(str(os.getpid())) == 1
    assert len(pids) == len(set(pids))  # the build processes: once each


@pytest.mark.parametrize("engine", ["fmu", "inprocess"])
def test_sys_exit_in_k_fails_the_run_with_the_reason(tmp_path, engine):
    path = _model(tmp_path, f"exits_{engine}", k="__import__('sys').exit(0) if x[0] < 0.99 "
                                                   "else np.array([-x[0] - x[1]])")
    spec = model_loop(path, T=0.1, r=0.0, tau=0.0, N=1, x0=[1.0, -1.0], u0=[0.0])
    result = run_loop(spec, 1.0, tmp_path / "fmus", engine=engine)
    assert not result.success
    assert "SystemExit" in result.message and "\n" not in result.message
