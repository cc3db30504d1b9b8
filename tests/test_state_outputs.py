"""Issue 50, item 1: ``predictor = "plant-fmu"`` on a plant FMU whose continuous states are
its outputs, declared as the Reference FMUs declare them (``VanDerPol``: ``<Unknown
index="1" dependencies=""/>`` for the output ``x0``, the state of ``der(x0)``).

The FMU is ``tests/cfmu``'s Oscillator (``position' = velocity``, ``velocity' = force -
stiffness position - damping velocity``, ``mass = 1``) with its modelDescription rewritten
in that style: the outputs ``position`` and ``velocity`` are its continuous states, each
declared with ``dependencies=""`` (the other knowns it depends on: none). An output that
is a state determines that state whatever its list says, so the predictor accepts it;
an output that is no state and depends on no known determines nothing, and is still
refused.
"""

from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np
import pytest

from delaycomp.errors import ParameterError
from delaycomp.orchestrator.simulate import run_loop
from delaycomp.system.loopfile import read_loop
from delaycomp.system.plantfmu import read_interface, state_of
from tests.cfmu.build import build_oscillator

from .independent import solve_zoh_loop

pytestmark = pytest.mark.fmu

A = np.array([[0.0, 1.0], [1.0, -0.2]])  # stiffness = -1: unstable
B = np.array([[0.0], [1.0]])
K = np.array([[-3.0, -2.5]])
T, N, R, TAU = 0.5, 50, 0.3, 0.5
STOP = 10.0
X0, U0 = [1.0, 0.0], [0.0]

#: the Oscillator's Outputs as it declares them, and as the Reference FMUs would
OUTPUTS = (b'<Unknown index="1" dependencies="1" dependenciesKind="fixed"/>',
           b'<Unknown index="2" dependencies="2" dependenciesKind="fixed"/>')
REFERENCE_STYLE = (b'<Unknown index="1" dependencies=""/>',
                   b'<Unknown index="2" dependencies=""/>')
#: ``acceleration`` (no state: the derivative of ``velocity``) declared as depending on
#: no known, a constant as far as the description says (its Outputs entry: the same line
#: stands in Derivatives)
ACCELERATION = (b'<Unknown index="4" dependencies="1 2 5" '
                b'dependenciesKind="fixed fixed fixed"/>\n    </Outputs>')
CONSTANT = b'<Unknown index="4" dependencies=""/>\n    </Outputs>'
#: an alias of the state ``position`` (its value reference, 0), an output of its own
ALIAS = (b'<ScalarVariable name="sensor" valueReference="0" causality="output" '
         b'variability="continuous" initial="calculated"><Real/></ScalarVariable>\n'
         b'  </ModelVariables>')


def _loop(fmu: str, states: str = '["position", "velocity"]') -> str:
    # substep = 1e-3: ten RK4 steps a base step, so the plant's own solver error
    # (s^4 |M|^5 / 120 per unit time, |M| < 1.7: ~1e-13) is below what is checked
    return f"""
T = {T}
N = {N}
r = {R}
tau = {TAU}
stop_time = {STOP}
[plant]
fmu = "{fmu}"
states = {states}
inputs = ["force"]
x0 = {X0}
[plant.parameters]
stiffness = -1.0
damping = 0.2
mass = 1.0
position_start = 1.0
velocity_start = 0.0
substep = 0.001
[controller]
predictor = "plant-fmu"
K = {K.tolist()}
"""


def _rewrite(src: Path, target: Path, *pairs: tuple[bytes, bytes]) -> Path:
    """``src`` with its modelDescription.xml rewritten (each ``(old, new)`` once)."""
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(target, "w") as zout:
        for item in zin.namelist():
            data = zin.read(item)
            if item == "modelDescription.xml":
                for old, new in pairs:
                    assert data.count(old) == 1, old
                    data = data.replace(old, new)
            zout.writestr(item, data)
    return target


@pytest.fixture(scope="module")
def folder(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("state-outputs")
    osc = build_oscillator(out)
    style = list(zip(OUTPUTS, REFERENCE_STYLE))
    _rewrite(osc, out / "RefStyle.fmu", *style)
    # the index of the alias is the 12th ScalarVariable, after the Oscillator's 11
    _rewrite(osc, out / "Alias.fmu", *style, (b"  </ModelVariables>", ALIAS),
             (b"</Outputs>", b'  <Unknown index="12" dependencies=""/>\n    </Outputs>'),
             (b"</InitialUnknowns>", b'  <Unknown index="12"/>\n    </InitialUnknowns>'))
    _rewrite(osc, out / "Constant.fmu", *style, (ACCELERATION, CONSTANT))
    return out


def _write(folder: Path, name: str, text: str) -> Path:
    path = folder / name
    path.write_text(text, encoding="utf-8")
    return path


def test_reference_style_description_is_read_as_it_says(folder):
    """The shape of the issue: the states are the outputs, with an empty list."""
    fmu = read_interface(folder / "RefStyle.fmu")
    assert fmu.states == ("position", "velocity")
    assert fmu.dependencies["position"] == () and fmu.dependencies["velocity"] == ()
    assert [state_of(fmu, s) for s in ("position", "velocity", "acceleration")] == [
        "position", "velocity", None]
    alias = read_interface(folder / "Alias.fmu")
    assert alias.dependencies["sensor"] == () and state_of(alias, "sensor") == "position"


@pytest.mark.parametrize("fmu, states", [
    ("RefStyle.fmu", '["position", "velocity"]'),
    ("Alias.fmu", '["sensor", "velocity"]'),
])
def test_states_as_outputs_predict_as_the_independent_solve(folder, fmu, states):
    """The loop with the FMU's own derivatives as the predictor's model, against
    ``tests/independent.py``'s solve of the same sampled loop (scipy's DOP853 at rtol =
    1e-12, atol = 1e-14 over each held interval and each prediction window; no delaycomp
    code). Bound, from the maths: the predictor integrates the FMU's derivatives with
    DOP853 at rtol = atol = 1e-10, whose global error over the window r + tau = 0.8 s
    stays within ~10 tol e^(|A| 0.8) (|A| ~ 1.1: < 3e-9); u = K x_pred is within |K|
    (~3.9) times that; a sample's error in u moves x by at most T |B| e^(|A| T) (< 0.9)
    times it, and the stable loop does not amplify it (its state decays by ~0.25 a
    period); the plant's RK4 (substep 1e-3, ~1e-12 over the run) and the reference's
    own error (~1e-11) are below that. So 2e-8 (1 + |x|): the bound of the existing
    plant-fmu tests (1e-8) with the factor |K| 3e-9 / 1e-8 rounded up."""
    res = run_loop(read_loop(_write(folder, f"{fmu}.toml", _loop(fmu, states))), STOP)
    assert res.success, res.message
    times, xs, us = solve_zoh_loop(lambda x, u: A @ x + B @ u, lambda x: K @ x, T, R, TAU,
                                   X0, U0, STOP, N)
    assert np.allclose(res.times, times, rtol=0, atol=1e-12)
    names = states.strip("[]").replace('"', "").split(", ")
    cols = [res.names.index(f"plant.{s}") for s in names] + [
        res.names.index("controller.force")]
    got, want = res.data[:, cols], np.hstack([xs, us])
    assert np.max(np.abs(want[:, 0])) >= 1.0 and np.max(np.abs(want[:, 2])) > 1.0
    err = np.abs(got - want) / (1 + np.abs(want))
    assert err.max() <= 2e-8, err.max()


def test_outputs_that_are_no_state_and_depend_on_none_are_still_refused(folder):
    """``acceleration`` declared with ``dependencies=""`` and no state: beside
    ``position`` it leaves ``velocity`` undetermined, in one line naming both and what to
    give instead. The other refusals stand on the Reference-style FMU: too few outputs,
    and ``acceleration`` as declared (direct feedthrough from ``force``)."""
    path = _write(folder, "constant.toml", _loop("Constant.fmu",
                                                 '["position", "acceleration"]'))
    with pytest.raises(ParameterError) as err:
        read_loop(path)
    text = str(err.value)
    assert text == (
        'controller.predictor = "plant-fmu" is not allowed: no output in plant.states '
        "(position, acceleration) is or depends on the state 'velocity' of Constant.fmu "
        "(ModelStructure), so the outputs cannot determine it; name an output that does, "
        "or give A and B (or model) for the predictor"), text
    ref = _write(folder, "ref-bad.toml", _loop("RefStyle.fmu"))
    with pytest.raises(ParameterError, match=r"plant\.states names 1 output\(s\) "
                       r"\(position\) for the 2 continuous states of RefStyle\.fmu"):
        read_loop(ref, ['plant.states=["position"]', "plant.x0=[1.0]",
                        "controller.K=[[-3]]"])
    with pytest.raises(ParameterError, match=r"output 'acceleration' of RefStyle\.fmu "
                       r"depends on the input 'force' at the same instant"):
        read_loop(ref, ['plant.states=["position", "acceleration"]'])
