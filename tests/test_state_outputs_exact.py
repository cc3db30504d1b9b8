"""Issue 50, item 1 (follow-up): a plant FMU shaped like the Reference FMUs' ``VanDerPol``
in full, its continuous states its outputs declared ``initial="exact"`` with start values.

``tests/test_state_outputs.py`` rewrites the Oscillator's outputs to ``dependencies=""``,
but they stay ``initial="calculated"`` (the state follows ``position_start``). The
Reference FMUs declare them as ``<ScalarVariable name="x0" ... causality="output"
variability="continuous" initial="exact"><Real start="2"/>``: FMI 2.0 lets a master set
such a variable before initialization, and that start value is the state the FMU starts
from. The FMU here is ``tests/cfmu/vanderpol.c`` (``x0' = x1``, ``x1' = mu (1 - x0^2) x1
- x0 + u``, start values 2 and 0, ``u`` an input added to ``der(x1)``): a nonlinear plant,
and the FMU is the predictor's own model, so the prediction is nonlinear as well.

With ``predictor = "plant-fmu"`` and no ``plant.start``, ``plant.x0`` reaches the plant
through those start values (found from x0 through the outputs' map, here the identity,
and set before initialization in the plant and in the predictor's instance): the loop
starts at x0, not at the FMU's (2, 0). A ``plant.start`` the user gives is kept, and a
plant that it puts elsewhere than x0 is refused before the first step.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from delaycomp.orchestrator.simulate import run_loop
from delaycomp.system.loopfile import read_loop
from delaycomp.system.plantfmu import read_interface, start_variables, state_of
from tests.cfmu.build import build_vanderpol

from .independent import solve_zoh_loop

pytestmark = pytest.mark.fmu

MU = 1.0
K = np.array([[-1.0, -2.5]])
T, N, R, TAU = 0.5, 50, 0.3, 0.5
STOP = 10.0
#: the loop's x0: not the FMU's start values (2, 0)
X0, U0 = [1.5, -1.0], [0.0]
#: the predictor's rtol = atol (controller.tolerance, its default)
TOL = 1e-10


def _f(x, u):
    """The Van der Pol field with its input, written here from the equations."""
    return np.array([x[1], MU * (1.0 - x[0] ** 2) * x[1] - x[0] + u[0]])


def _loop(fmu: str, start: str = "") -> str:
    # substep = 1e-3: ten RK4 steps a base step; RK4's global error, ~s^4 L^5 / 120 per
    # unit time (L < 3.3 on this run), ~3e-12 over it, is below what is checked
    return f"""
T = {T}
N = {N}
r = {R}
tau = {TAU}
stop_time = {STOP}
[plant]
fmu = "{fmu}"
states = ["x0", "x1"]
inputs = ["u"]
x0 = {X0}
{start}
[plant.parameters]
mu = {MU}
substep = 0.001
[controller]
predictor = "plant-fmu"
K = {K.tolist()}
tolerance = {TOL}
"""


@pytest.fixture(scope="module")
def folder(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("state-outputs-exact")
    build_vanderpol(out)
    build_vanderpol(out, "VanDerPolNoDD.fmu", directional=False)
    return out


def _write(folder: Path, name: str, text: str) -> Path:
    path = folder / name
    path.write_text(text, encoding="utf-8")
    return path


def test_the_fmu_has_the_reference_shape(folder):
    """What ``read_interface`` reads: the states are the outputs, ``initial="exact"``
    with the start values 2 and 0, ``dependencies=""``, and settable before
    initialization (``start_variables``); ``time`` is the independent variable."""
    fmu = read_interface(folder / "VanDerPol.fmu")
    assert fmu.states == ("x0", "x1") and fmu.derivatives == ("der(x0)", "der(x1)")
    assert fmu.of("output") == ["x0", "x1"] and fmu.of("input") == ["u"]
    assert [(fmu.variables[x].initial, fmu.variables[x].start) for x in fmu.states] == [
        ("exact", "2"), ("exact", "0")]
    assert fmu.dependencies == {"x0": (), "x1": ()}
    assert [state_of(fmu, x) for x in ("x0", "x1")] == ["x0", "x1"]
    assert start_variables(fmu, ["u"]) == ["x0", "x1"]
    assert fmu.variables["time"].causality == "independent" and fmu.directional


@pytest.mark.parametrize("fmu", ["VanDerPol.fmu", "VanDerPolNoDD.fmu"])
def test_x0_starts_the_nonlinear_loop_as_the_independent_solve(folder, fmu):
    """The loop from x0 = (1.5, -1), not the FMU's (2, 0), against ``tests/independent.py``'s
    solve of the same sampled loop (scipy's DOP853 at rtol = 1e-12, atol = 1e-14 on the
    field ``_f`` written here; no delaycomp code), with the FMU's directional derivatives
    and without them (central differences, for the state found from the outputs).

    Bound, from the maths: the predictor integrates the FMU's field with DOP853 at rtol =
    atol = 1e-10 over the window r + tau = 0.8 s; its global error stays within ~10 tol
    e^(L 0.8), L the Lipschitz constant of the field on the run (the inf-norm of its
    Jacobian [[0, 1], [-2 mu x0 x1 - 1, mu (1 - x0^2)]], 3.25 here, checked below):
    1.4e-8. u = K x_pred is within |K| (3.5) times that, 4.7e-8; a sample's error in u
    moves x by at most T e^(L T) (2.5) times it, 1.2e-7, and the stable loop does not
    amplify it (the state decays by ~0.25 a period). The state found from the outputs
    is the outputs themselves to round-off (Newton's method on the identity map, to
    1e-12); the plant's RK4 (~3e-12) and the reference's own error (~1e-11) are below
    the rest. So 2e-7 (1 + |x|). A predictor that linearized the FMU at the origin would
    be off by more than 1 (checked below: the reference with the linearized field)."""
    res = run_loop(read_loop(_write(folder, f"{fmu}.toml", _loop(fmu))), STOP)
    assert res.success, res.message
    times, xs, us = solve_zoh_loop(_f, lambda x: K @ x, T, R, TAU, X0, U0, STOP, N)
    assert np.allclose(res.times, times, rtol=0, atol=1e-12)
    cols = [res.names.index(c) for c in ("plant.x0", "plant.x1", "controller.u")]
    got, want = res.data[:, cols], np.hstack([xs, us])
    assert np.array_equal(got[0, :2], X0)  # the plant started at x0, set before init
    lipschitz = max(abs(-2 * MU * a * b - 1) + abs(MU * (1 - a * a)) for a, b in xs)
    assert 1.0 <= lipschitz <= 3.3, lipschitz  # the bound's premise
    err = np.abs(got - want) / (1 + np.abs(want))
    assert err.max() <= 2e-7, err.max()
    A = np.array([[0.0, 1.0], [-1.0, MU]])
    B = np.array([[0.0], [1.0]])
    _, linear, _ = solve_zoh_loop(lambda x, u: A @ x + B @ u, lambda x: K @ x, T, R, TAU,
                                  X0, U0, STOP, N)
    assert np.max(np.abs(linear - xs)) > 1.0


def test_a_start_given_is_kept_and_a_plant_elsewhere_refused(folder):
    """``plant.start`` at the FMU's own start values (2, 0) is what the plant starts
    from, not x0: the master stops the run before its first step, both vectors
    named in its message (the loop would assume a history the plant never had)."""
    text = _loop("VanDerPol.fmu", "start = {x0 = 2.0, x1 = 0.0}")
    res = run_loop(read_loop(_write(folder, "kept.toml", text)), STOP)
    assert not res.success and res.failed_by == "plant" and len(res.times) == 1
    assert res.message.startswith(
        "plant starts elsewhere: its outputs after initialization, (x0, x1) = [2.0, 0.0], "
        "are not x0 = [1.5, -1.0]"), res.message
