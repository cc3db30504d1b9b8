"""The time-stamp controller of a model loop (issue 29, item 2): ``[controller] stamps =
true`` with ``[plant] model``.

Example 3.8 (``x1' = x2 + sin(x2) u``, ``x2' = u``, ``p = "sin"``, its dead-beat law (3.29)
under zero-order hold), ``T = 1``, ``tau = T``, the measurement through a channel with
uniform jitter 1.5 T on top of 0.2 s and 30 % of the packets lost. With time stamps the
controller carries each new sample over its actual age plus ``tau`` through the model's
ODE, so the plant follows the delay-free sampled loop: ``u_i = k(x(t_i + tau))`` applied
over ``[t_i + tau, t_{i+1} + tau)``, the history ``u0 = 0`` before ``tau``. That loop is
computed here by scipy's ``solve_ivp`` with the held inputs alone (its own ``f`` and
``k``, nothing shared with delaycomp). Without time stamps the controller predicts over
the nominal ``r + tau`` from whatever sample the channel shows, and the same check fails
by orders of magnitude.
"""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest
import tomllib
from scipy.integrate import solve_ivp

from delaycomp import api
from delaycomp.cli import main
from delaycomp.errors import ParameterError
from delaycomp.system.loopfile import build, check

REPO = Path(__file__).resolve().parents[1]
MODELS = REPO / "delaycomp" / "paper" / "models"
T, N, TAU, STOP = 1.0, 10, 1.0, 8.0
X0 = (1.0, -1.0)
DATA = {
    "name": "stamped-3.8", "T": T, "N": N, "r": 0.5, "tau": TAU, "stop_time": STOP,
    "plant": {"model": str(MODELS / "example_3_8.py"), "x0": list(X0)},
    "controller": {"u0": [0.0], "p": "sin", "stamps": True},
    # jitter 1.5 T > T, 30 % lost
    "meas_delay": {"distribution": "uniform", "delay": 0.2, "jitter": 1.5,
                   "loss_model": "bernoulli", "loss": 0.3, "seed": 5},
}
#: The plant is Example 3.8's exact ``step``; the predictor's ODE solves run at rtol = atol =
#: 1e-10 (the default tolerance), a few solves per prediction, and the dead-beat law's gains
#: (1/T^2, 1.5/T) and one period's flow amplify a prediction error by a factor of order
#: 10: 1e-7 of the state's size leaves three orders of magnitude for the solves' error
#: (measured: 4e-13; the reference's own error, rtol = atol = 1e-13, is far below).
TOL = 1e-7


def _data(stamps: bool = True, **changes) -> dict:
    data = copy.deepcopy(DATA)
    data["controller"]["stamps"] = stamps
    for key, value in changes.items():
        table, _, name = key.rpartition(".")
        (data.setdefault(table, {}) if table else data)[name] = value
    return data


def _loop(stamps: bool = True, **changes):
    return build(_data(stamps, **changes), REPO, name="stamped-3.8")


def _delay_free(steps: int) -> np.ndarray:
    """The plant's state on the base grid ``k T/N`` in the delay-free sampled loop, by
    ``solve_ivp`` (DOP853, rtol = atol = 1e-13) one base step at a time."""
    def f(t, x, u):
        return [x[1] + np.sin(x[1]) * u, u]

    def k(x):  # (3.29) with P(w) = 1 - cos(w)
        return -(x[0] - (1.0 - np.cos(x[1]))) / T**2 - 1.5 * x[1] / T

    h, delay = T / N, round(TAU * N / T)
    xs = np.empty((steps + 1, 2))
    xs[0] = X0
    u = 0.0  # the history u0 before tau
    for j in range(steps):
        if j >= delay and (j - delay) % N == 0:  # t_i + tau: u_i = k(x(t_i + tau))
            u = k(xs[j])
        sol = solve_ivp(f, (j * h, (j + 1) * h), xs[j], method="DOP853", rtol=1e-13,
                        atol=1e-13, args=(u,))
        xs[j + 1] = sol.y[:, -1]
    return xs


def _states(result) -> np.ndarray:
    return np.column_stack([result["plant.x1"], result["plant.x2"]])


def _error(result) -> float:
    x = _states(result)
    ref = _delay_free(len(x) - 1)
    return float(np.abs(x - ref).max() / np.abs(ref).max())


def test_the_loop_holds_the_model_time_stamp_controller():
    loop = _loop()
    ctrl = loop.by_role("controller")
    assert ctrl.source.kind == "stamped_model_controller"
    assert loop.by_role("meas_delay").source.kind == "channel"
    assert "meas_delay.stamp -> controller.stamp" in [str(c) for c in loop.connections]
    # age_max defaults as for an LTI loop: the channel's largest delay (0.2 + 1.5) + T
    assert ctrl.parameters["age_max"] == pytest.approx(0.2 + 1.5 + T, abs=1e-15)
    assert ctrl.parameters["mode"] == "compensated" and ctrl.parameters["p"] == "sin"
    assert not {"r", "N", "pad", "predictor"} & set(ctrl.parameters)
    assert _loop(**{"controller.age_max": 3.0}).by_role("controller").parameters[
        "age_max"] == 3.0
    assert _loop(**{"controller.mode": "uncompensated"}).by_role("controller").parameters[
        "mode"] == "uncompensated"


@pytest.fixture(scope="module")
def inprocess():
    return (api.run(_loop(), engine="inprocess"),
            api.run(_loop(stamps=False), engine="inprocess"))


def test_in_process_follows_the_delay_free_loop(inprocess):
    stamped, plain = inprocess
    assert _error(stamped) <= TOL
    assert _error(plain) >= 1e-2  # measured: 8 (the state's size is 1)


def test_the_fmus_follow_it_and_agree_with_in_process(inprocess, fmu_dir):
    """fmpy's master over the built FMUs (the Python ones: this controller has no native
    twin): the same loop, the same numbers as in-process (the same slave code: to
    round-off of the orders the two masters evaluate in)."""
    stamped = api.run(_loop(), engine="fmu", fmus="python", fmu_dir=fmu_dir)
    assert _error(stamped) <= TOL
    ours = _states(inprocess[0])
    assert np.abs(_states(stamped) - ours).max() <= 1e-12 * np.abs(ours).max()
    plain = api.run(_loop(stamps=False), engine="fmu", fmus="python", fmu_dir=fmu_dir)
    assert _error(plain) >= 1e-2


def _file(tmp_path, data) -> Path:
    lines = [f"{k} = {v!r}".replace("'", '"') for k, v in data.items()
             if not isinstance(v, dict)]
    for table, body in data.items():
        if isinstance(body, dict):
            lines.append(f"[{table}]")
            lines += [f"{k} = " + ("true" if v is True else repr(v).replace("'", '"'))
                      for k, v in body.items()]
    path = tmp_path / "s.toml"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def test_run_on_the_command_line_follows_it(tmp_path):
    path = _file(tmp_path, _data())
    out = tmp_path / "s.csv"
    assert main(["run", str(path), "--engine", "inprocess", "--out", str(out)]) == 0
    table = np.loadtxt(out, delimiter=",", skiprows=1)
    x = table[:, 1:3]
    ref = _delay_free(len(x) - 1)
    assert np.abs(x - ref).max() <= TOL * np.abs(ref).max()


def test_a_continuous_model_is_refused_in_one_line(tmp_path, capsys):
    """Example 2.4 (``CONTROL = "continuous"``): the time-stamp controller holds
    ``k(x, p)`` over each period, so the loop file is refused naming
    ``controller.stamps``, and so is the FMU's build."""
    from delaycomp.fmu.build import build_fmu

    path = tmp_path / "c.toml"
    path.write_text(f'T = 0.5\nN = 10\nstop_time = 1.0\n[plant]\nmodel = '
                    f'"{MODELS / "example_2_4.py"}"\nx0 = [1.0, 0.0, 0.0]\n[controller]\n'
                    'stamps = true\n', encoding="utf-8")
    why = "controller.stamps = true is not allowed for model 'example_2_4'"
    assert main(["run", str(path)]) == 2
    err = capsys.readouterr().err
    assert why in err and "Traceback" not in err and len(err.strip().splitlines()) == 1
    data = tomllib.loads(path.read_text(encoding="utf-8"))
    with pytest.raises(ParameterError, match=why):  # a sweep's point check, unbuilt
        check(data, tmp_path)
    with pytest.raises(ParameterError, match=r"^model = 'example_2_4' is not allowed for the "
                                             r"stamped_model_controller FMU: its CONTROL is "
                                             r"'continuous'; must be 'zoh'$"):
        build_fmu("stamped_model_controller", tmp_path,
                  {"model": str(MODELS / "example_2_4.py")})


@pytest.mark.parametrize("mode", ["compensated", "uncompensated"])
@pytest.mark.parametrize("argv", [[], ["--jacobi"]])
def test_the_archive_runs_as_the_loop_file_bit_for_bit(tmp_path, argv, mode):
    """``ssp`` (and its Jacobi variant) holds the stamped model controller, the stamp's
    connection and its ``mode`` as the Integer twin ``mode_index`` (for importers without
    String parameters): our master runs the archive as ``run`` runs the loop file, the same
    doubles, in either mode."""
    import zipfile

    path = _file(tmp_path, _data(**{"controller.mode": mode}))
    ours, archive, out = tmp_path / "run.csv", tmp_path / "s.ssp", tmp_path / "ssp.csv"
    assert main(["run", str(path), "--out", str(ours)]) == 0
    assert main(["ssp", str(path), *argv, "--out", str(archive)]) == 0
    with zipfile.ZipFile(archive) as z:
        ssv = z.read("resources/controller.ssv").decode()
    assert 'name="mode_index"' in ssv and 'name="mode"' not in ssv
    assert f'<ssv:Integer value="{1 if mode == "compensated" else 2}"/>' in ssv
    assert main(["run", str(archive), "--out", str(out)]) == 0
    want = np.loadtxt(ours, delimiter=",", skiprows=1)
    assert np.array_equal(np.loadtxt(out, delimiter=",", skiprows=1), want)
    assert (np.abs(want[-1, 1:3]).max() < 1e-6) == (mode == "compensated")


def test_the_loop_exported_as_one_fmu_runs_as_the_loop_file_bit_for_bit(tmp_path):
    """``export-loop``: the container FMU of the stamped model loop, run by fmpy, gives
    ``run``'s samples to the bit (its outputs at the communication points)."""
    from fmpy import simulate_fmu

    path = _file(tmp_path, _data())
    ours, out = tmp_path / "run.csv", tmp_path / "s.fmu"
    assert main(["run", str(path), "--out", str(ours)]) == 0
    assert main(["export-loop", str(path), "--out", str(out)]) == 0
    want = np.loadtxt(ours, delimiter=",", skiprows=1)
    res = simulate_fmu(str(out), stop_time=STOP, output_interval=T / N)
    assert len(res) == len(want)
    for name, col in (("x1", 1), ("x2", 2)):
        assert np.array_equal(np.asarray(res[name]), want[:, col]), name
