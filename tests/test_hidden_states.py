"""Issue 25, items 1 and 2: a plant FMU as Modelica tools export it, its continuous states
hidden, with ``predictor = "plant-fmu"``; and an initial state that is checked, never
assumed.

The plant is ``tests/cfmu``'s ``Drive`` (README there): hidden states ``x = (body.phi,
body.w)`` with ``x' = A x + B u``, ``A = [[0, 1], [1, -0.2]]``, ``B = [[0], [1]]``, measured
as ``y = h(x)``: ``sensor.phi = -phi - cubic phi^3``, ``sensor.w = -w - mix phi``. With
``cubic = 0`` the map is ``y = C x``, ``C = [[-1, 0], [-mix, -1]]``, and the plant in the
measured coordinates is exactly ``y' = C A C^-1 y + C B u``: the matrix predictor of that
pair is the reference the FMU predictor must equal.
"""

from __future__ import annotations

import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

from delaycomp.errors import ParameterError
from delaycomp.orchestrator.simulate import run_loop
from delaycomp.system.loopfile import read_loop
from tests.cfmu.build import build_drive

pytestmark = pytest.mark.fmu

A = np.array([[0.0, 1.0], [1.0, -0.2]])
B = np.array([[0.0], [1.0]])
MIX = 0.5
C = np.array([[-1.0, 0.0], [-MIX, -1.0]])
KX = np.array([[-3.0, -2.5]])  # stabilises the sampled loop in the FMU's coordinates
K = KX @ np.linalg.inv(C)  # the same feedback on the measured outputs: u = K y = KX x
T, N, R, TAU = 0.5, 50, 0.3, 0.5
STOP = 10.0
PHI0 = 0.4  # the hidden initial state body.phi (body.w = 0)


def _loop_text(fmu: str, controller: str, x0, extra_plant: str = "",
               parameters: str = f'"sensor.mix" = {MIX}') -> str:
    return f"""
T = {T}
N = {N}
r = {R}
tau = {TAU}
stop_time = {STOP}
[plant]
fmu = "{fmu}"
states = ["sensor.phi", "sensor.w"]
inputs = ["motor.tau"]
x0 = {list(map(float, x0))}
parameters = {{ {parameters} }}
start = {{ "body.phi" = {PHI0} }}
{extra_plant}
[controller]
{controller}
K = {K.tolist()}
"""


def _x0(cubic: float = 0.0) -> np.ndarray:
    """The measured outputs of the hidden initial state (PHI0, 0)."""
    return np.array([-PHI0 - cubic * PHI0**3, -MIX * PHI0])


@pytest.fixture(scope="module")
def folder(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("drive")
    build_drive(out)
    build_drive(out, "DriveNoJacobian.fmu", directional=False)
    return out


def _write(folder: Path, name: str, text: str) -> Path:
    path = folder / name
    path.write_text(text, encoding="utf-8")
    return path


@pytest.mark.parametrize("fmu", ["Drive.fmu", "DriveNoJacobian.fmu"])
def test_hidden_states_predictor_equals_the_matrix_predictor(folder, fmu):
    """Item 1's headline. Same plant FMU, same feedback, the runs differ by the predictor
    only: the FMU's Model Exchange derivatives integrated by DOP853 (rtol = atol = 1e-10)
    from the state found by Newton's method on the outputs, against the exact flow of
    (C A C^-1, C B). Bound: the inversion is exact to round-off for a linear map (one
    Newton step; with central differences, the Jacobian's ~1e-10 relative error is
    corrected by the next steps); DOP853's global error over the window r + tau = 0.8 s
    stays within ~10 tol e^(|A| 0.8) (< 3e-9), u within |K| (~ 4.4) times that, and the
    stable loop does not amplify a sample's error (it decays by ~ 0.25 a period): so
    1e-8 (1 + |y|), as for the Oscillator whose outputs are its states
    (tests/test_plant_fmu.py); measured ~1e-11."""
    x0 = _x0()
    fmu_loop = read_loop(_write(folder, f"hidden-{fmu}.toml", _loop_text(
        fmu, 'predictor = "plant-fmu"', x0)))
    Ay, By = C @ A @ np.linalg.inv(C), C @ B
    matrix_loop = read_loop(_write(folder, f"matrix-{fmu}.toml", _loop_text(
        fmu, f"A = {Ay.tolist()}\nB = {By.tolist()}", x0)))
    ours, ref = run_loop(fmu_loop, STOP), run_loop(matrix_loop, STOP)
    assert ours.success and ref.success, (ours.message, ref.message)
    np.testing.assert_allclose(ours.data[0, :2], x0, rtol=0, atol=1e-12)
    assert np.max(np.abs(ours.data[:, :2])) > 0.1  # the loop moves: a real comparison
    diff = np.abs(ours.data - ref.data)
    assert np.all(diff <= 1e-8 * (1 + np.abs(ref.data))), diff.max()


def _prediction_error(res, K_: np.ndarray) -> float:
    """max over samples t = iT >= r of |u(t) - K y(t + tau)| / (1 + |y(t + tau)|): the
    control at a sample is K times the prediction of y at t + tau, so this is the
    prediction's error (before r the controller predicts from the history x0)."""
    t = res.times
    y, u = res.data[:, :2], res.data[:, 2]
    worst = 0.0
    for i in range(1, int(STOP / T)):
        ts = i * T
        if ts < R - 1e-9 or ts + TAU > STOP + 1e-9:
            continue
        a, b = np.argmin(np.abs(t - ts)), np.argmin(np.abs(t - ts - TAU))
        yf = y[b]
        worst = max(worst, float(abs(u[a] - (K_ @ yf)[0]) / (1 + np.max(np.abs(yf)))))
    return worst


def test_nonlinear_sensor_prediction_is_the_future(folder):
    """A nonlinear output map (sensor.cubic = 0.5, still invertible): at each sample the
    control is K y_pred with y_pred the plant's own output tau later. The prediction uses
    the exact derivatives; the plant in the loop integrates with its own Heun-Euler 2(1)
    at the default tolerance 1e-4 (h = 0.01 accepted: the error estimate h^2/2 |x''| is
    below it), whose local error h^3/6 |x'''| <= 3e-7 over the 80 steps of r + tau leaves
    y within ~3e-5 (|dh/dx| <= 1.5 here), u within |K| times that: bound 5e-4 (1 + |y|);
    measured 2.9e-5. The uncompensated controller misses by more than 1e-2: the check can
    tell."""
    cubic = 0.5
    params = f'"sensor.mix" = {MIX}, "sensor.cubic" = {cubic}'
    text = _loop_text("Drive.fmu", 'predictor = "plant-fmu"', _x0(cubic), parameters=params)
    res = run_loop(read_loop(_write(folder, "cubic.toml", text)), STOP)
    assert res.success, res.message
    assert _prediction_error(res, K) <= 5e-4
    # the plant's solver to 1e-10 ([plant] tolerance, item 3): its error falls to ~1e-10
    # (Heun's local error, controlled to the tolerance, over the window), and what is left
    # is the predictor's own, DOP853 at 1e-10: bound 1e-8 (1 + |y|) as above; measured
    # 5.2e-11
    tight = run_loop(read_loop(_write(folder, "cubic-tight.toml", text.replace(
        "[controller]", "tolerance = 1e-10\n[controller]"))), STOP)
    assert tight.success, tight.message
    assert _prediction_error(tight, K) <= 1e-8
    unc = run_loop(read_loop(_write(folder, "cubic-unc.toml", text.replace(
        'predictor = "plant-fmu"', 'predictor = "plant-fmu"\nmode = "uncompensated"'))),
        STOP)
    assert _prediction_error(unc, K) > 1e-2


def test_outputs_that_cannot_give_the_states_are_refused(folder, tmp_path):
    """Fewer outputs than states, and an output map whose Jacobian loses rank where the
    loop starts (sensor.cubic = -1/3 at body.phi = 1: d sensor.phi / d phi = 0), are
    refused in one line that says what to give instead."""
    base = _loop_text("Drive.fmu", 'predictor = "plant-fmu"', _x0())
    path = _write(folder, "hidden-checks.toml", base)
    with pytest.raises(ParameterError, match=r"plant\.states names 1 output\(s\) \(sensor\.phi\)"
                       r" for the 2 continuous states of Drive\.fmu \(body\.phi, body\.w\): "
                       r".*or give A and B \(or model\) for the predictor"):
        read_loop(path, ['plant.states=["sensor.phi"]', "plant.x0=[0.4]", "controller.K=[[1]]"])
    flat = _loop_text("Drive.fmu", 'predictor = "plant-fmu"',
                      [-1.0 + 1.0 / 3.0, -MIX * 1.0],
                      parameters=f'"sensor.mix" = {MIX}, "sensor.cubic" = {-1 / 3}'
                      ).replace(f'"body.phi" = {PHI0}', '"body.phi" = 1.0')
    proc = subprocess.run([sys.executable, "-m", "delaycomp", "run",
                           str(_write(folder, "flat.toml", flat)), "--out",
                           str(tmp_path / "flat.csv"), "--stop-time", "1"],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 1, proc.stderr
    err = [line for line in proc.stderr.splitlines() if "error" in line]
    assert len(err) == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert ("the map from the outputs (sensor.phi, sensor.w) to the states (body.phi, "
            "body.w) is not invertible at x = [1.0, 0.0]: its Jacobian has rank 1 of 2"
            in err[0]), err[0]
    # a modelDescription in which no named output depends on body.w (ModelStructure)
    src = zipfile.ZipFile(folder / "Drive.fmu")
    with zipfile.ZipFile(tmp_path / "Drive.fmu", "w") as out:
        for item in src.namelist():
            data = src.read(item)
            if item == "modelDescription.xml":
                data = data.replace(b'<Unknown index="6" dependencies="1 2" '
                                    b'dependenciesKind="fixed fixed"/>',
                                    b'<Unknown index="6" dependencies="1" '
                                    b'dependenciesKind="fixed"/>')
            out.writestr(item, data)
    with pytest.raises(ParameterError, match=r"no output in plant\.states \(sensor\.phi, "
                       r"sensor\.w\) is or depends on the state 'body\.w' of Drive\.fmu"):
        read_loop(_write(tmp_path, "dep.toml", base))


@pytest.mark.parametrize("controller", ['predictor = "plant-fmu"',
                                        f"A = {A.tolist()}\nB = {(-B).tolist()}"])
def test_a_wrong_x0_is_refused_naming_both_vectors(folder, tmp_path, controller):
    """Item 2: x0 is the measured history the controller assumes; a plant FMU that starts
    elsewhere (here body.phi = 0.4, while x0 says the outputs are [1, 0]) fails the run
    before its first step, both vectors named, with the matrix predictor too."""
    text = _loop_text("Drive.fmu", controller, [1.0, 0.0])
    path = _write(folder, f"wrong-x0-{len(controller)}.toml", text)
    proc = subprocess.run([sys.executable, "-m", "delaycomp", "run", str(path), "--out",
                           str(tmp_path / "w.csv"), "--stop-time", "1"],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 1, proc.stderr
    assert "Traceback" not in proc.stderr
    want = (f"plant starts elsewhere: its outputs after initialization, (sensor.phi, "
            f"sensor.w) = {np.round(_x0(), 12).tolist()}, are not x0 = [1.0, 0.0]")
    assert want in proc.stderr, proc.stderr
    assert not (tmp_path / "w.csv").exists()


def test_start_values_set_the_hidden_state(folder):
    """Item 2: ``[plant] start`` sets the start values of the FMU's hidden states (FMI 2.0
    allows it for initial = "exact" before initialization): the first row is the outputs
    of that state, which equal x0."""
    for phi in (0.4, -0.7):
        x0 = np.array([-phi, -MIX * phi])
        text = _loop_text("Drive.fmu", 'predictor = "plant-fmu"', x0).replace(
            f'"body.phi" = {PHI0}', f'"body.phi" = {phi}')
        res = run_loop(read_loop(_write(folder, "start.toml", text)), 1.0)
        assert res.success, res.message
        np.testing.assert_allclose(res.data[0, :2], x0, rtol=0, atol=1e-15)


@pytest.mark.parametrize("start, message", [
    ('{ "spring.c" = 1 }', r"'spring\.c' is a parameter: give it in plant\.parameters"),
    ('{ "motor.tau" = 1 }', r"'motor\.tau' is driven by the loop: it is in plant\.inputs"),
    ('{ "sensor.phi" = 1 }', r"plant\.start: 'sensor\.phi' is not a start value that the "
                             r"master may set in Drive\.fmu: allowed are body\.phi, body\.w, "
                             r"load\.tau, brake\.engaged"),
    ('{ "body.phi" = "a" }', r"plant\.start: body\.phi = 'a' is not allowed: must be a finite"),
    ('{ "brake.engaged" = 1 }', r"brake\.engaged = 1 is not allowed: must be true or false"),
    ('[1, 2]', r"plant\.start is not allowed: must be a table"),
])
def test_start_values_are_checked(folder, start, message):
    text = _loop_text("Drive.fmu", 'predictor = "plant-fmu"', _x0()).replace(
        f'start = {{ "body.phi" = {PHI0} }}', f"start = {start}")
    with pytest.raises(ParameterError, match=message):
        read_loop(_write(folder, "start-bad.toml", text))


def test_hidden_states_loop_in_omsimulator_equals_our_master(folder, tmp_path, oms):
    """The same loop as an SSP in OMSimulator: the start value of the hidden state travels
    as a parameter binding, and the controller FMU carries the plant FMU for its predictor.
    Same FMUs, same fixed step: equal to round-off (1e-12 (1 + |y|); measured 5e-15)."""
    from delaycomp.cli import main
    from delaycomp.verify.omsimulator import run_ssp

    path = _write(folder, "oms.toml", _loop_text("Drive.fmu", 'predictor = "plant-fmu"',
                                                 _x0()))
    assert main(["ssp", str(path), "--out", str(tmp_path / "hidden.ssp"), "-q"]) == 0
    theirs = run_ssp(tmp_path / "hidden.ssp", 5.0)
    ours = run_loop(read_loop(path), 5.0)
    assert theirs.success, theirs.message
    cols = [theirs.names.index(n) for n in ours.names]
    rows = np.rint(theirs.times / (T / N)).astype(int)
    diff = np.abs(theirs.data[:, cols] - ours.data[rows])
    assert np.all(diff <= 1e-12 * (1 + np.abs(ours.data[rows]))), diff.max()


@pytest.mark.parametrize("cubic", [0.0, 0.5])
def test_without_start_x0_is_applied_through_the_outputs_map(folder, cubic):
    """Item 2: no ``start`` given, and the FMU's states settable (initial = "exact"): their
    start values are found from x0 through the outputs' map (Newton's method on the FMU's
    own outputs), so the plant starts where x0 says: the first row is x0 (to the
    inversion's round-off, 1e-12), and the run is the one with the start given by hand."""
    params = f'"sensor.mix" = {MIX}, "sensor.cubic" = {cubic}'
    phi = -0.7
    x0 = np.array([-phi - cubic * phi**3, -MIX * phi])
    given = _loop_text("Drive.fmu", 'predictor = "plant-fmu"', x0, parameters=params
                       ).replace(f'"body.phi" = {PHI0}', f'"body.phi" = {phi}')
    found = given.replace(f'start = {{ "body.phi" = {phi} }}', "")
    assert "start" not in found
    loop = read_loop(_write(folder, "found.toml", found))
    start = loop.instance("plant").parameters
    assert abs(start["body.phi"] - phi) <= 1e-12 and abs(start["body.w"]) <= 1e-12
    res = run_loop(loop, 2.0)
    ref = run_loop(read_loop(_write(folder, "given.toml", given)), 2.0)
    assert res.success and ref.success, (res.message, ref.message)
    np.testing.assert_allclose(res.data[0, :2], x0, rtol=0, atol=1e-12)
    np.testing.assert_allclose(res.data, ref.data, rtol=0, atol=1e-9)


def test_set_a_start_value_by_its_fmu_name(folder):
    """``--set plant.start.NAME=VALUE`` (the FMU's dotted name as it is, or quoted) replaces
    one start value and keeps the others: here the hidden angle, with x0 to match (a sweep
    over the hidden initial state)."""
    path = _write(folder, "set-start.toml", _loop_text(
        "Drive.fmu", 'predictor = "plant-fmu"', _x0()).replace(
        f'start = {{ "body.phi" = {PHI0} }}', f'start = {{ "body.phi" = {PHI0}, "load.tau" = 0 }}'))
    for name in ("body.phi", '"body.phi"'):
        loop = read_loop(path, [f"plant.start.{name}=-0.7", "plant.x0=[0.7, 0.35]"])
        params = loop.instance("plant").parameters
        assert params["body.phi"] == -0.7 and params["load.tau"] == 0.0
        res = run_loop(loop, 0.5)
        assert res.success, res.message
        np.testing.assert_allclose(res.data[0, :2], [0.7, 0.35], rtol=0, atol=1e-15)
