"""Your own system, end to end: loop files through every command and the Python API, held
to an independent solution (tests/independent.py: DOP853 method of steps, no delaycomp).

The LTI loop is the issue's: n = 3 states, m = 2 inputs, an LQR gain from python-control,
T = 0.2, r = 0.36 (> T, 36 base steps), tau = 0.4 = 2T. The nonlinear one is a user model
file without closed form (the controller solves the ODE for Phi).

Tolerances:
- LTI, zero-order hold: delaycomp's loop is exact (matrix exponentials), the reference is
  DOP853 at rtol 1e-12, atol 1e-14 over 60 periods of a stable loop; measured differences
  are below 1e-11, so ``1e-9 (1 + |ref|)`` (the project's exact-loop tolerance) holds with
  two decades to spare and still catches a one-base-step timing error (about 1e-2).
- Nonlinear: the plant and the predictor are DOP853 solves at the default tolerance
  (rtol = atol = 1e-10 per solve); ``1e-8 (1 + |ref|)`` leaves a factor 100 for that error
  accumulated over the windows and amplified by the loop gain (measured: 6e-12
  compensated, 4e-11 uncompensated), six decades below a one-step timing error.
"""

from __future__ import annotations

import csv
import importlib
import json
import os
import subprocess
import sys
import textwrap

import control
import numpy as np
import pytest

from delaycomp import api
from delaycomp.errors import ParameterError
from delaycomp.system.loopfile import SignError

from .independent import solve_zoh_loop
from .roundoff import COMMITTED_ULPS, SAME_ARITHMETIC_ULPS, assert_csv_close, assert_same_values

pytestmark = pytest.mark.fmu

A = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.5, -1.0, 0.2]])
B = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
T, N, R, TAU = 0.2, 20, 0.36, 0.4
X0, U0 = [1.0, -0.5, 0.25], [0.1, -0.2]
STOP = 12.0
EXACT = 1e-9


def lqr_gain() -> np.ndarray:
    """python-control's LQR gain of the plant (u = -K x in its convention)."""
    K, _, _ = control.lqr(control.ss(A, B, np.eye(3), np.zeros((3, 2))), np.eye(3),
                          np.eye(2))
    return np.asarray(K)


def toml_matrix(M) -> str:
    return "[" + ", ".join("[" + ", ".join(repr(float(v)) for v in row) + "]"
                           for row in np.atleast_2d(M)) + "]"


def write_lti_loop(folder, K, mode="compensated", extra=""):
    path = folder / "plant3.toml"
    path.write_text(textwrap.dedent(f"""\
        T = {T}
        N = {N}
        r = {R}
        tau = {TAU}
        stop_time = {STOP}

        [plant]
        A = {toml_matrix(A)}
        B = {toml_matrix(B)}
        x0 = {list(X0)}

        [controller]
        mode = "{mode}"
        K = {toml_matrix(K)}
        u0 = {list(U0)}
        {extra}
        """), encoding="utf-8")
    return path


def cli(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "delaycomp", *map(str, args)],
                          capture_output=True, text=True, timeout=900, cwd=cwd,
                          env=dict(os.environ))


def read_csv(path):
    with open(path, newline="") as fh:
        rows = list(csv.reader(fh))
    return rows[0], np.array(rows[1:], dtype=float)


def lti_reference(K, compensated, stop=STOP):
    return solve_zoh_loop(lambda x, u: A @ x + B @ u, lambda x: K @ x, T, R, TAU, X0, U0,
                          stop, N, compensated)


def assert_matches(header, data, ref, tol):
    times, xs, us = ref
    cols = [f"plant.x{i + 1}" for i in range(xs.shape[1])] + \
           [f"controller.u{j + 1}" for j in range(us.shape[1])]
    got = data[:, [header.index(c) for c in cols]]
    want = np.hstack([xs, us])
    assert np.allclose(data[:, 0], times, rtol=0, atol=1e-12)
    err = np.abs(got - want) / (1 + np.abs(want))
    assert err.max() <= tol, f"largest relative error {err.max():.3g}"
    return float(np.abs(got - want).max())


@pytest.fixture(scope="module")
def lti_case(tmp_path_factory):
    folder = tmp_path_factory.mktemp("loop")
    K = -lqr_gain()  # delaycomp applies u = K x
    return folder, K


@pytest.mark.parametrize("mode,engine", [("compensated", "fmu"),
                                         ("uncompensated", "inprocess")])
def test_lti_loop_file_run_matches_the_independent_solution(lti_case, mode, engine):
    folder, K = lti_case
    path = write_lti_loop(folder, K, mode)
    out = folder / f"{mode}.csv"
    proc = cli("run", path, "--engine", engine, "--out", out)
    assert proc.returncode == 0, proc.stderr
    header, data = read_csv(out)
    assert header[0] == "time" and "plant.x3" in header and "controller.u2" in header
    assert_matches(header, data, lti_reference(K, mode == "compensated"), EXACT)


def test_set_takes_the_loop_files_keys(lti_case):
    folder, K = lti_case
    path = write_lti_loop(folder, K)
    out = folder / "set.csv"
    K2 = K * 0.8
    rows = ";".join(",".join(repr(float(v)) for v in row) for row in K2)
    proc = cli("run", path, "--engine", "inprocess", "--stop-time", 4, "--out", out,
               "--set", "r=0.4", "--set", "plant.x0=0.5,0,0", "--set", f"controller.K={rows}")
    assert proc.returncode == 0, proc.stderr
    header, data = read_csv(out)
    ref = solve_zoh_loop(lambda x, u: A @ x + B @ u, lambda x: K2 @ x, T, 0.4, TAU,
                         [0.5, 0.0, 0.0], U0, 4.0, N)
    assert_matches(header, data, ref, EXACT)


def test_the_sign_guard_refuses_python_controls_k_and_can_be_overridden(lti_case, tmp_path):
    _, K = lti_case
    path = write_lti_loop(tmp_path, -K)  # the lqr gain as python-control returns it
    proc = cli("run", path, "--engine", "inprocess")
    assert proc.returncode == 2
    line = proc.stderr.strip()
    assert "\n" not in line and "Traceback" not in proc.stderr
    assert "spectral radius" in line and "u = K x" in line and "lqr" in line
    ok = cli("run", path, "--engine", "inprocess", "--allow-unstable", "--stop-time", 1)
    assert ok.returncode == 0, ok.stderr


BAD = [
    ("[plant]\nA = [[1.0]]\nB = [[1.0]]\nx0 = [1.0]\n[controller]\nK = [[-2.0]]\n",
     "T (the sampling period) is required"),
    ("T = 1.0\nspeed = 3\n[plant]\nA = [[1.0]]\nB = [[1.0]]\nx0 = [1.0]\n[controller]\n"
     "K = [[-2.0]]\n", "unknown key 'speed'"),
    ("T = 1.0\n[plant]\nA = [[1.0]]\nB = [[1.0]]\nx0 = [1.0, 2.0]\n[controller]\n"
     "K = [[-2.0]]\n", "x0 has 2 values: must have n = 1"),
    ("T = 1.0\n[plant]\nA = [[1.0]]\nB = [[1.0]]\nx0 = [1.0]\n[controller]\nK = [[-2.0, 1]]\n",
     "matrix K has shape (1, 2): must be m x n = 1 x 1"),
    ("T = 1.0\nr = 0.305\n[plant]\nA = [[1.0]]\nB = [[1.0]]\nx0 = [1.0]\n[controller]\n"
     "K = [[-2.0]]\n", "must be a multiple of the base step"),
    ("T = 1.0\n[plant]\nA = [[1.0]]\nB = [[1.0]]\nx0 = [1.0]\n[controller]\nK = [[-2.0]]\n"
     "mode = \"fast\"\n", "controller.mode = 'fast' is not allowed"),
    ("T = 1.0\n[plant\n", "is not a TOML loop file"),
]


@pytest.mark.parametrize("text,message", BAD, ids=[m[:24] for _, m in BAD])
def test_bad_loop_files_are_one_line_errors(tmp_path, text, message):
    path = tmp_path / "bad.toml"
    path.write_text(text, encoding="utf-8")
    proc = cli("run", path, "--engine", "inprocess", "--stop-time", 1)
    assert proc.returncode == 2, proc.stderr
    assert message in proc.stderr and "Traceback" not in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1


def test_ssp_of_a_loop_file_runs_in_our_master_as_the_file(lti_case, tmp_path):
    folder, K = lti_case
    path = write_lti_loop(folder, K)
    ssp = tmp_path / "plant3.ssp"
    assert cli("ssp", path, "--out", ssp).returncode == 0
    a, b = tmp_path / "a.csv", tmp_path / "b.csv"
    assert cli("run", path, "--out", a, "--stop-time", 4).returncode == 0
    proc = cli("run", ssp, "--out", b, "--stop-time", 4)
    assert proc.returncode == 0, proc.stderr
    assert_csv_close(b, a, SAME_ARITHMETIC_ULPS)  # the same loop in two processes


@pytest.mark.parametrize("master", ["libcosim", "ecos"])
def test_jacobi_archive_of_a_loop_file_in_third_party_masters(lti_case, tmp_path, master):
    folder, K = lti_case
    path = write_lti_loop(folder, K)
    ssp = tmp_path / "plant3-jacobi.ssp"
    proc = cli("ssp", path, "--jacobi", "--out", ssp)
    assert proc.returncode == 0, proc.stderr
    out = tmp_path / f"{master}.csv"
    proc = cli("run", ssp, "--master", master, "--stop-time", 6, "--out", out)
    assert proc.returncode == 0, proc.stderr
    header, data = read_csv(out)
    assert_matches(header, data, lti_reference(K, True, stop=6.0), EXACT)


def test_sweep_of_a_loop_file(lti_case, tmp_path):
    folder, K = lti_case
    path = write_lti_loop(folder, K)
    out = tmp_path / "sweep.csv"
    proc = cli("sweep", path, "--grid", "r=0.2:0.6:3", "--out", out, "--workers", 1,
               "--stop-time", 8)
    assert proc.returncode == 0, proc.stderr
    exact = tmp_path / "exact.csv"
    assert cli("sweep", path, "--grid", "r=0.2:0.6:3", "--out", exact, "--exact",
               "--workers", 1).returncode == 0
    with open(out) as fh:
        rows = list(csv.DictReader(fh))
    with open(exact) as fh:
        exact_rows = list(csv.DictReader(fh))
    assert [float(r["r"]) for r in rows] == pytest.approx([0.2, 0.4, 0.6])
    # compensated with the delay it assumes: the lifted spectrum is the delay-free one
    rho0 = max(abs(np.linalg.eigvals(_delay_free(K))))
    for row, ex in zip(rows, exact_rows):
        assert row["stable"] == "1"
        assert float(ex["rho"]) == pytest.approx(rho0, abs=1e-9)


def _delay_free(K):
    from scipy.linalg import expm

    M = np.zeros((5, 5))
    M[:3, :3], M[:3, 3:] = A, B
    F = expm(M * T)
    return F[:3, :3] + F[:3, 3:] @ K


def simulate_container(fmu, stop: float, interval: float) -> dict:
    """fmpy.simulate_fmu on a container FMU at the sampling period, in a child process (a
    pythonfmu FMU is not unloaded in this one, see delaycomp/verify/crosscheck.py)."""
    code = ("import sys, json, os; from fmpy import simulate_fmu; "
            "r = simulate_fmu(sys.argv[1], stop_time=float(sys.argv[2]), "
            "output_interval=float(sys.argv[3])); "
            "print(json.dumps({n: r[n].tolist() for n in r.dtype.names}), flush=True); "
            "os._exit(0)")
    proc = subprocess.run([sys.executable, "-c", code, str(fmu), repr(stop),
                           repr(interval)], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout.strip().splitlines()[-1])


def test_export_loop_of_a_loop_file(lti_case, tmp_path):
    folder, K = lti_case
    path = write_lti_loop(folder, K)
    fmu = tmp_path / "plant3_loop.fmu"
    proc = cli("export-loop", path, "--out", fmu)
    assert proc.returncode == 0, proc.stderr
    res = simulate_container(fmu, 6.0, T)
    _times, xs, _ = lti_reference(K, True, stop=6.0)
    for i in range(3):
        got = np.array(res[f"x{i + 1}"])
        want = xs[::N, i]
        assert np.max(np.abs(got - want) / (1 + np.abs(want))) <= EXACT


def test_check_against_the_reference_csv_a_loop_file_names(lti_case, tmp_path):
    _folder, K = lti_case
    times, xs, us = lti_reference(K, True, stop=4.0)
    ref = tmp_path / "ref.csv"
    cols = ["plant.x1", "plant.x2", "plant.x3", "controller.u1", "controller.u2"]
    with open(ref, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["time", *cols])
        for t, x, u in zip(times, xs, us):
            w.writerow([repr(float(v)) for v in (t, *x, *u)])
    path = write_lti_loop(tmp_path, K, extra="")
    text = path.read_text().replace("stop_time = 12.0", "stop_time = 4.0")
    path.write_text(text + '\n[reference]\ncsv = "ref.csv"\n')
    proc = cli("check", path, "--master", "delaycomp")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "| plant3/reference | delaycomp |" in proc.stdout
    bad = tmp_path / "bad.toml"
    bad.write_text(path.read_text())
    proc = cli("check", bad, "--master", "delaycomp", "--set", "r=0.38")
    assert proc.returncode == 1  # a controller that assumes another delay: fails


def test_check_of_a_loop_file_whose_measurement_is_a_channel(lti_case, tmp_path):
    """``[meas_delay]`` a lossy channel with jitter 2T, ``stamps = true``: the prediction is
    exact (issue 29, item 2), so the loop is the compensated loop with ``r = 0``, computed
    independently (``solve_zoh_loop``: at ``r = 0`` the window ``[t_i, t_i + tau)`` holds
    only inputs the plant does receive, so its prediction is exact from ``t0`` on). Same
    tolerance as every exact row, ``EXACT``: measured 7.9e-13."""
    _folder, K = lti_case
    times, xs, us = solve_zoh_loop(lambda x, u: A @ x + B @ u, lambda x: K @ x, T, 0.0, TAU,
                                   X0, U0, 3.0, N, True)
    with open(tmp_path / "ref.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["time", "plant.x1", "plant.x2", "plant.x3", "controller.u1",
                    "controller.u2"])
        for t, x, u in zip(times, xs, us):
            w.writerow([repr(float(v)) for v in (t, *x, *u)])
    path = write_lti_loop(tmp_path, K, extra=textwrap.dedent("""\
        stamps = true

        [meas_delay]
        distribution = "uniform"
        jitter = 0.4
        loss_model = "bernoulli"
        loss = 0.3
        seed = 7

        [reference]
        csv = "ref.csv"
        """))
    path.write_text(path.read_text().replace("stop_time = 12.0", "stop_time = 3.0"))
    proc = cli("check", path)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    rows = [line for line in proc.stdout.splitlines() if line.startswith("| plant3/")]
    masters = {line.split("|")[2].strip() for line in rows}
    assert {"delaycomp", "fmu-alone"} <= masters, proc.stdout  # the others: where installed
    assert all(line.split("|")[5].strip().startswith("yes") for line in rows), proc.stdout
    # the channel acts: without the stamps the same loop misses the reference by far
    proc = cli("check", path, "--master", "delaycomp", "--set", "controller.stamps=false")
    assert proc.returncode == 1 and "| plant3/reference | delaycomp |" in proc.stdout
    # a bad value of the channel: the failed row names the channel's key and its range
    proc = cli("check", path, "--master", "delaycomp", "--set", "meas_delay.loss=1.5")
    assert proc.returncode == 1
    assert "meas_delay.loss = 1.5 is not allowed: must be a finite number >= 0.0 and <= 1.0" \
        in proc.stdout, proc.stdout


def test_critical_delay_of_a_loop_file(lti_case, tmp_path):
    folder, K = lti_case
    path = write_lti_loop(folder, K)
    proc = cli("critical-delay", path)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    r_c = float(proc.stdout.split("r_c = ")[1].split()[0])
    assert r_c == pytest.approx(api.critical_delay(api.load(path)), abs=1e-9)


# -- the Python API ---------------------------------------------------------------------

def test_api_from_a_statespace_with_an_lqr_gain(lti_case):
    _, K = lti_case
    sys_ = control.ss(A, B, np.eye(3), np.zeros((3, 2)))
    with pytest.raises(SignError, match="lqr"):
        api.lti(sys_, K=-K, T=T, r=R, tau=TAU, N=N, x0=X0, u0=U0)  # python-control's sign
    loop = api.lti(sys_, K=K, T=T, r=R, tau=TAU, N=N, x0=X0, u0=U0)
    res = api.run(loop, 4.0, engine="inprocess")
    assert set(res.signals) == {"plant.x1", "plant.x2", "plant.x3", "controller.u1",
                                "controller.u2"}
    header = ["time", *res.names]
    data = np.column_stack([res.times, res.data])
    assert_matches(header, data, lti_reference(K, True, stop=4.0), EXACT)
    with pytest.raises(ParameterError, match="continuous-time"):
        api.lti(control.c2d(sys_, T), K=K, T=T, x0=X0)


def test_api_plot_returns_a_figure_and_leaves_the_backend_alone(lti_case):
    import matplotlib

    _, K = lti_case
    before = matplotlib.get_backend()
    loop = api.lti(A, B, K, T=T, r=R, tau=TAU, N=N, x0=X0, u0=U0)
    res = api.run(loop, 2.0, engine="inprocess")
    fig = api.plot([res], title="plant3", labels=["compensated"])
    assert type(fig).__name__ == "Figure" and len(fig.axes) == 5
    assert matplotlib.get_backend() == before


def test_api_run_failure_raises_a_named_exception(tmp_path):
    model = tmp_path / "blowup.py"
    model.write_text(textwrap.dedent("""\
        import numpy as np
        STATES = ("x",)
        INPUTS = ("u",)
        CONTROL = "zoh"
        def f(x, u, p):
            return np.array([x[0] ** 2])
        def k(x, p):
            return np.array([0.0])
        """))
    loop = api.model(model, T=1.0, r=0.0, tau=0.0, N=10, x0=[2.0])
    with pytest.raises(api.SimulationFailed) as info:
        api.run(loop, 5.0, engine="inprocess")
    assert info.value.result is not None and not info.value.result.success


# -- a user's nonlinear model -----------------------------------------------------------

PENDULUM = """\
\"\"\"x1' = x2, x2' = gain sin(x1) + u under ZOH; k cancels the sine at the sample.\"\"\"
import numpy as np

STATES = ("x1", "x2")
INPUTS = ("u",)
CONTROL = "zoh"
PARAMETERS = {"gain": 1.0}


def f(x, u, p):
    return np.array([x[1], p["gain"] * np.sin(x[0]) + u[0]])


def k(x, p):
    return np.array([-p["gain"] * np.sin(x[0]) - 2.0 * x[0] - 2.5 * x[1]])
"""


def pendulum(x, u, gain=1.3):
    return np.array([x[1], gain * np.sin(x[0]) + u[0]])


def pendulum_k(x, gain=1.3):
    return np.array([-gain * np.sin(x[0]) - 2.0 * x[0] - 2.5 * x[1]])


@pytest.mark.parametrize("mode", ["compensated", "uncompensated"])
def test_user_model_loop_file_matches_the_independent_solution(tmp_path, mode):
    (tmp_path / "pend.py").write_text(PENDULUM)
    path = tmp_path / "pend.toml"
    path.write_text(textwrap.dedent(f"""\
        T = 0.25
        N = 10
        r = 0.3
        tau = 0.25
        stop_time = 8.0
        [plant]
        model = "pend.py"
        x0 = [0.8, 0.0]
        [controller]
        mode = "{mode}"
        u0 = [0.0]
        gain = 1.3
        """))
    out = tmp_path / "pend.csv"
    proc = cli("run", path, "--out", out, "--engine", "inprocess")
    assert proc.returncode == 0, proc.stderr
    header, data = read_csv(out)
    ref = solve_zoh_loop(pendulum, pendulum_k, 0.25, 0.3, 0.25, [0.8, 0.0], [0.0], 8.0, 10,
                         compensated=mode == "compensated")
    _times, xs, us = ref
    got = data[:, [header.index(c) for c in ("plant.x1", "plant.x2", "controller.u")]]
    want = np.hstack([xs, us])
    err = np.abs(got - want) / (1 + np.abs(want))
    assert err.max() <= 1e-8, err.max()


def test_api_model_loop_compensated_beats_uncompensated(tmp_path):
    (tmp_path / "pend.py").write_text(PENDULUM)
    runs = {mode: api.run(api.model(tmp_path / "pend.py", T=0.25, r=0.5, tau=0.5, N=10,
                                    x0=[0.8, 0.0], mode=mode, gain=1.3), 10.0,
                          engine="inprocess") for mode in ("compensated", "uncompensated")}
    tail = {m: np.abs(r["plant.x1"][-40:]).max() for m, r in runs.items()}
    assert tail["compensated"] < 1e-3 < tail["uncompensated"]


# -- the scenarios as data --------------------------------------------------------------

@pytest.mark.parametrize("name", list(importlib.import_module("delaycomp.paper.scenarios")
                                      .SCENARIOS))
def test_each_scenario_ships_as_a_loop_file_that_builds_the_same_loop(name):
    from delaycomp.paper import scenarios
    from delaycomp.system.loopfile import LoopFile

    sc = scenarios.get(name)
    lf = LoopFile(scenarios.loop_file(name))
    # instances, sources, parameters, connections, timing: all exactly but the numbers,
    # which are compared to round-off (a committed gain against the code's:
    # COMMITTED_ULPS)
    assert_same_values(lf.loop(), sc.loop(), COMMITTED_ULPS, "loop")
    assert (lf.name, lf.default_stop_time) == (name, sc.default_stop_time)


def write_pendulum(folder, mode: str):
    (folder / "pend.py").write_text(PENDULUM)
    path = folder / f"pend_{mode}.toml"
    path.write_text(textwrap.dedent(f"""\
        T = 0.25
        N = 10
        r = 0.3
        tau = 0.25
        stop_time = 4.0
        [plant]
        model = "pend.py"
        x0 = [0.8, 0.0]
        [controller]
        mode = "{mode}"
        gain = 1.3
        """))
    return path


@pytest.mark.parametrize("mode", ["compensated", "uncompensated"])
def test_user_model_loop_file_through_ssp_masters_sweep_and_export(tmp_path, mode):
    """The nonlinear loop file everywhere the loop goes: its SSP in our master (the same
    CSV as the file), its Jacobi archive in libcosim and Ecos, a sweep, and the container
    FMU, each against the independent solution (1e-8 (1 + |ref|), see the module)."""
    path = write_pendulum(tmp_path, mode)
    ref = solve_zoh_loop(pendulum, pendulum_k, 0.25, 0.3, 0.25, [0.8, 0.0], [0.0], 4.0, 10,
                         compensated=mode == "compensated")
    want = np.hstack([ref[1], ref[2]])

    def close(header, data, rows=slice(None)):
        got = data[:, [header.index(c) for c in ("plant.x1", "plant.x2", "controller.u")]]
        err = np.abs(got - want[rows]) / (1 + np.abs(want[rows]))
        assert err.max() <= 1e-8, err.max()

    direct, packed = tmp_path / "direct.csv", tmp_path / "packed.csv"
    assert cli("run", path, "--out", direct).returncode == 0
    close(*read_csv(direct))
    ssp = tmp_path / "pend.ssp"
    assert cli("ssp", path, "--out", ssp).returncode == 0
    proc = cli("run", ssp, "--out", packed)
    assert proc.returncode == 0, proc.stderr
    assert_csv_close(packed, direct, SAME_ARITHMETIC_ULPS)  # the same loop, two processes
    jacobi = tmp_path / "pend-jacobi.ssp"
    assert cli("ssp", path, "--jacobi", "--out", jacobi).returncode == 0
    for master in ("libcosim", "ecos"):
        out = tmp_path / f"{master}.csv"
        proc = cli("run", jacobi, "--master", master, "--out", out)
        assert proc.returncode == 0, proc.stderr
        close(*read_csv(out))
    sweep = tmp_path / "sweep.csv"
    proc = cli("sweep", path, "--grid", "r=0.2:0.4:3", "--workers", 1, "--out", sweep)
    assert proc.returncode == 0, proc.stderr
    with open(sweep) as fh:
        assert [float(r["r"]) for r in csv.DictReader(fh)] == pytest.approx([0.2, 0.3, 0.4])
    fmu = tmp_path / "pend_loop.fmu"
    proc = cli("export-loop", path, "--out", fmu)
    assert proc.returncode == 0, proc.stderr
    res = simulate_container(fmu, 4.0, 0.25)
    got = np.column_stack([res["x1"], res["x2"]])
    err = np.abs(got - ref[1][::10]) / (1 + np.abs(ref[1][::10]))
    assert err.max() <= 1e-8, err.max()
