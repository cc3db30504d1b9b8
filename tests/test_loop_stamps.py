"""The time-stamp controller in a loop (issue 29, item 2): ``[controller] stamps = true``.

The README's loop of one's own (``docs/examples/myloop.toml``, n = 3, m = 2) over networks
on both sides: the measurement through a channel with uniform jitter 2 T and 30 % of the
packets lost, the commands through a jittered channel behind a play-out buffer (a constant
delay ``tau``). With time stamps the prediction is exact, so the plant's state at
``t_i + tau`` follows the delay-free sampled loop ``x_{i+1} = (e^{AT} + G(T) K) x_i``
(``u_i = K x(t_i + tau)`` is applied over ``[t_i + tau, t_{i+1} + tau)``): checked step by
step against that recursion computed here with scipy alone, to round-off (each step one
product with a matrix exponential accurate to a few ulps: ``1e-12`` of the state's size
allowed, ~1e-15 measured). Without time stamps the same check fails by orders of
magnitude.
"""

from __future__ import annotations

import copy
import itertools
from pathlib import Path

import numpy as np
import pytest
import tomllib
from scipy.linalg import expm

from delaycomp import api
from delaycomp.cli import main
from delaycomp.errors import ParameterError
from delaycomp.system.loopfile import build

REPO = Path(__file__).resolve().parents[1]
MYLOOP = tomllib.loads((REPO / "docs" / "examples" / "myloop.toml").read_text("utf-8"))
NETWORK = {
    "meas_delay": {"distribution": "uniform", "jitter": 0.4, "loss_model": "bernoulli",
                   "loss": 0.3, "seed": 7},
    "input_delay": {"distribution": "uniform", "delay": 0.2, "jitter": 0.2,
                    "policy": "playout", "seed": 3},
}


def _loop(stamps: bool = True, **changes):
    data = copy.deepcopy(MYLOOP)
    data.update(copy.deepcopy(NETWORK))
    data["controller"]["stamps"] = stamps
    for key, value in changes.items():
        table, _, name = key.rpartition(".")
        (data.setdefault(table, {}) if table else data)[name] = value
    return build(data, REPO / "docs" / "examples", name="myloop")


def _recursion_error(result) -> float:
    """The largest ``|x(t_{i+1} + tau) - M x(t_i + tau)|`` over the run, relative to the
    state's size (``M`` from scipy's exponential of the augmented matrix)."""
    A, B = np.array(MYLOOP["plant"]["A"], float), np.array(MYLOOP["plant"]["B"], float)
    K = np.array(MYLOOP["controller"]["K"], float)
    T, tau, N = MYLOOP["T"], MYLOOP["tau"], MYLOOP["N"]
    n, m = B.shape
    F = expm(np.block([[A, B], [np.zeros((m, n + m))]]) * T)
    M = F[:n, :n] + F[:n, n:] @ K
    x = np.column_stack([result[f"plant.x{i + 1}"] for i in range(n)])
    D, steps = round(tau / T) * N, len(x) - 1
    at = [D + i * N for i in range((steps - D) // N + 1)]
    worst = max(np.abs(x[b] - M @ x[a]).max() for a, b in itertools.pairwise(at))
    return worst / np.abs(x).max()


@pytest.mark.parametrize("engine,fmus", [("inprocess", "auto"), ("fmu", "python"),
                                         ("fmu", "native")])
def test_time_stamps_compensate_a_lossy_jittered_network_exactly(fmu_dir, engine, fmus):
    # the session's Python FMUs for the Python run; the native ones from the native cache
    # (a folder of Python FMUs is the wrong kind for a native run: refused)
    fmu_dir = fmu_dir if fmus == "python" else None
    stamped = api.run(_loop(), engine=engine, fmus=fmus, fmu_dir=fmu_dir)
    assert _recursion_error(stamped) <= 1e-12
    plain = api.run(_loop(stamps=False), engine=engine, fmus=fmus, fmu_dir=fmu_dir)
    assert _recursion_error(plain) >= 1e-3
    # and the stamps act: without jitter and loss the two controllers agree
    # (test_a_constant_channel_gives_the_nominal_controller in tests/test_stamped.py)


@pytest.mark.parametrize("r", [0.0, 0.36])
def test_stamps_on_a_constant_delay_are_the_paper_controller(r):
    """``stamps = true`` without channels: the measurement delay becomes a constant
    channel carrying its stamp. With ``r = 0`` the loop is the paper's (Corollary 3.4) to
    round-off. With ``r > 0`` the first samples (``t_i < r``) are the history ``x0``: the
    paper's predictor carries them over ``r`` as if the plant had moved, the stamps say
    they are the state at ``t0`` (where the plant starts), so the runs part there."""
    data = copy.deepcopy(MYLOOP)
    data["r"] = r
    base = build(copy.deepcopy(data), REPO, name="myloop")
    data["controller"]["stamps"] = True
    stamped = build(data, REPO, name="myloop")
    assert stamped.by_role("meas_delay").source.kind == "channel"
    assert stamped.by_role("controller").source.kind == "stamped_controller"
    assert "meas_delay.stamp -> controller.stamp" in [str(c) for c in stamped.connections]
    a, b = api.run(base, engine="inprocess"), api.run(stamped, engine="inprocess")
    assert a.names == b.names
    worst = max(np.abs(a[name] - b[name]).max() / np.abs(a[name]).max() for name in a.names)
    assert (worst <= 1e-12) == (r == 0.0), worst


def test_age_max_defaults_to_the_channels_largest_delay_plus_T():
    ctrl = _loop().by_role("controller")
    assert ctrl.parameters["age_max"] == pytest.approx(0.36 + 0.4 + 0.2, abs=1e-15)
    assert _loop(**{"controller.age_max": 2.0}).by_role("controller").parameters[
        "age_max"] == 2.0


@pytest.mark.parametrize("changes, message", [
    ({"controller.stamps": "yes"}, "controller.stamps = 'yes' is not allowed: must be true "
                                   "or false"),
    ({"controller.age_max": -1.0}, "controller.age_max = -1.0 is not allowed"),
])
def test_bad_values_are_named(changes, message):
    with pytest.raises(ParameterError, match=message):
        _loop(**changes)


def test_age_max_without_stamps_is_refused():
    with pytest.raises(ParameterError, match=r"controller.age_max is not allowed without "
                                             r"controller.stamps = true"):
        _loop(stamps=False, **{"controller.age_max": 1.0})


def test_a_loop_without_a_delay_controller_is_refused_in_one_line(tmp_path, capsys):
    """A plant FMU's loop whose controller is not delaycomp's LTI or model controller
    (here: the predictor on the plant FMU's own derivatives) has no time-stamp controller.
    (A model loop has one: tests/test_loop_stamps_model.py.)"""
    from delaycomp.system.loop import BuiltinFmu, Instance

    loop = _loop(stamps=False)
    ctrl = loop.by_role("controller")
    other = loop.with_instances([Instance(i.name, i.role, BuiltinFmu("plant", {}), {})
                                 if i is ctrl else i for i in loop.instances])
    from delaycomp.system.loopfile import with_stamps

    with pytest.raises(ParameterError, match=r"^loop: controller.stamps = true is not allowed "
                                             r"for this loop: the time-stamp controller is an "
                                             r"LTI loop's"):
        with_stamps(other, {"controller": {"stamps": True}})


def _toml_text(data: dict) -> str:
    """A loop file's text (numbers, strings, booleans, lists of numbers and of lists)."""
    def value(v):
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, str):
            return f'"{v}"'
        if isinstance(v, list):
            return "[" + ", ".join(value(x) for x in v) + "]"
        return repr(v)
    lines = [f"{k} = {value(v)}" for k, v in data.items() if not isinstance(v, dict)]
    for table, body in data.items():
        if isinstance(body, dict):
            lines += [f"[{table}]", *(f"{k} = {value(v)}" for k, v in body.items())]
    return "\n".join(lines) + "\n"


@pytest.fixture(scope="module")
def stamped_file(tmp_path_factory):
    """The stamped loop over the network as a file, and ``run``'s CSV (4 s)."""
    folder = tmp_path_factory.mktemp("stamped-hosts")
    data = copy.deepcopy(MYLOOP)
    data.update(copy.deepcopy(NETWORK))
    data["controller"]["stamps"] = True
    data["stop_time"] = 4.0
    path = folder / "net.toml"
    path.write_text(_toml_text(data), encoding="utf-8")
    assert main(["run", str(path), "--out", str(folder / "run.csv")]) == 0
    return path, np.loadtxt(folder / "run.csv", delimiter=",", skiprows=1)


@pytest.mark.parametrize("argv, master", [([], "delaycomp"), (["--jacobi"], "delaycomp")])
def test_the_stamped_loop_in_an_archive_is_run_bit_for_bit(stamped_file, tmp_path, argv,
                                                           master):
    """``ssp`` (and its Jacobi variant, whose measurement channel is shortened by h) holds
    the time-stamp controller's FMU and the stamp's connection: our master runs the
    archive as ``run`` runs the loop file, the same doubles."""
    path, ours = stamped_file
    archive = tmp_path / "n.ssp"
    assert main(["ssp", str(path), *argv, "--out", str(archive)]) == 0
    out = tmp_path / "ssp.csv"
    assert main(["run", str(archive), "--master", master, "--out", str(out)]) == 0
    assert np.array_equal(np.loadtxt(out, delimiter=",", skiprows=1), ours)


def test_the_stamped_loop_exported_as_one_fmu_is_run_bit_for_bit(stamped_file, tmp_path):
    from fmpy import simulate_fmu

    path, ours = stamped_file
    out = tmp_path / "n.fmu"
    assert main(["export-loop", str(path), "--out", str(out)]) == 0
    res = simulate_fmu(str(out), stop_time=4.0, output_interval=0.2)
    at = ours[::20]
    for name, col in (("x1", 1), ("x2", 2), ("x3", 3)):
        assert np.array_equal(np.asarray(res[name]), at[:, col]), name


def test_the_batch_engine_refuses_stamps_and_never_runs_them_as_the_paper_controller(
        tmp_path, capsys):
    """A sweep's batch engine runs the paper's controller over constant delays: a loop
    file asking for stamps is refused in one line (before, it ran the paper's controller
    silently), and a built loop with a channel or the time-stamp controller is not batched
    (the per-point engine takes it, saying why)."""
    from delaycomp.studies.sweep_batch import lti_point

    path = tmp_path / "s.toml"
    data = copy.deepcopy(MYLOOP)
    data["controller"]["stamps"] = True
    path.write_text(_toml_text(data), encoding="utf-8")
    assert main(["sweep", str(path), "--grid", "r=0.2:0.4:3", "--out",
                 str(tmp_path / "s.csv")]) == 2
    err = capsys.readouterr().err
    assert "controller.stamps = true is not supported by the batch engine yet" in err
    assert len(err.strip().splitlines()) == 1
    assert lti_point(_loop()) == "the meas_delay is delaycomp's channel FMU"
    assert lti_point(_loop(meas_delay={}, input_delay={})) == (
        "the meas_delay is delaycomp's channel FMU")
    plain = copy.deepcopy(MYLOOP)
    plain["controller"]["stamps"] = True
    stamped = build(plain, REPO, name="myloop")
    assert lti_point(stamped) == "the meas_delay is delaycomp's channel FMU"
    no_stamp = stamped.with_instances(
        i if i.role != "meas_delay" else build(copy.deepcopy(MYLOOP), REPO).by_role(
            "meas_delay") for i in stamped.instances)
    assert lti_point(no_stamp) == "the controller is delaycomp's stamped controller FMU"
