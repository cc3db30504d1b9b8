"""``pad = true`` for the LTI controller (issue 50, item 5; Remark 3.3(b)).

A ``tau`` that is no multiple of ``T`` is padded up to ``tau_eff = ceil(tau / T) T``: the
controller predicts over ``tau_eff`` (Theorem 3.2 with ``l = ceil(tau / T)``) and delays
its own output by ``tau_eff - tau``, so the plant sees ``u(t - tau_eff)``.

What is checked, and why each tolerance:

- the padded loop (Python controller, in process) against ``tests/independent.py``'s
  solve of the loop with the padded delay (DOP853 at rtol 1e-12, atol 1e-14 over each
  piece of constant input, the prediction another DOP853 solve; no matrix exponential):
  the two differ by the ODE solver's error, carried along the loop, ``1e-9`` relative
  (``1 + |x|``), the bound tests/test_loopfile.py uses for the same reference; the
  controller's output column is the reference's ``u_i`` shifted by the padding;
- Python FMU = native FMU, FMI 2.0 and 3.0: the same maths rounded apart only in the
  exponentials and sums, 1e-12 of each signal's peak (tests/test_native.py's bound);
- ``tau`` a multiple of ``T``: ``pad`` changes nothing, bit for bit;
- the refusal without ``pad`` names it (CLI: exit 2, one line; the native FMU's message
  is the Python FMU's: tests/test_native.py's ``BAD_PARAMETERS``);
- an FMU state saved between ``t_i`` and ``t_i + padding`` carries the padding line.
"""

from __future__ import annotations

import re
import subprocess
import sys

import numpy as np
import pytest

from delaycomp.errors import ParameterError
from delaycomp.orchestrator.simulate import run_loop
from delaycomp.system import lti_loop

from .independent import solve_zoh_loop

A = np.array([[0.0, 1.0], [0.5, -0.2]])
B = np.array([[0.0], [1.0]])
K = np.array([[-1.2, -1.5]])
T, N, R, TAU = 0.5, 10, 0.2, 0.7
TAU_EFF, D = 1.0, 6  # ceil(0.7 / 0.5) 0.5, and the padding 0.3 in base steps of 0.05
X0, U0 = [1.0, -0.5], [0.3]
STOP = 6.0


def padded(tau=TAU, **kw):
    return lti_loop(A, B, K, T, R, tau, N, "compensated", X0, U0, pad=True, **kw)


def test_padded_loop_equals_an_independent_solve_with_the_padded_delay():
    res = run_loop(padded(), STOP, engine="inprocess")
    assert res.success, res.message
    times, xs, us = solve_zoh_loop(lambda x, u: A @ x + B @ u, lambda x: K @ x, T, R,
                                   TAU_EFF, X0, U0, STOP, N)
    assert np.allclose(res.times, times, rtol=0, atol=1e-12)
    x = res.data[:, :2]
    err = np.abs(x - xs) / (1 + np.abs(xs))
    assert err.max() <= 1e-9, err.max()
    # the output: u_i from t_i + padding on (u0 before)
    want_u = np.vstack([np.tile(U0, (D, 1)), us[:-D]])
    err_u = np.abs(res.data[:, 2:] - want_u) / (1 + np.abs(want_u))
    assert err_u.max() <= 1e-9, err_u.max()


def test_padded_loop_is_the_unpadded_loop_of_the_padded_delay():
    """The plant's state bit for bit: the same predictor matrices, the same values
    delayed by 0.3 + 0.7 instead of 1.0."""
    pad = run_loop(padded(), STOP, engine="inprocess")
    plain = run_loop(lti_loop(A, B, K, T, R, TAU_EFF, N, "compensated", X0, U0), STOP,
                     engine="inprocess")
    assert np.array_equal(pad.data[:, :2], plain.data[:, :2])
    assert np.array_equal(pad.data[D:, 2], plain.data[:-D, 2])


def test_pad_with_tau_a_multiple_of_t_changes_nothing():
    with_pad = run_loop(padded(tau=1.0), STOP, engine="inprocess")
    without = run_loop(lti_loop(A, B, K, T, R, 1.0, N, "compensated", X0, U0), STOP,
                       engine="inprocess")
    assert np.array_equal(with_pad.data, without.data)


def test_without_pad_the_refusal_names_pad():
    with pytest.raises(ParameterError, match=r"pad = true .* accepts it, delaying the output "
                                             r"to the next multiple, 1 \(Remark 3.3\(b\)\)"):
        lti_loop(A, B, K, T, R, TAU, N, "compensated", X0, U0)


def test_cli_refusal_is_one_line_naming_pad():
    proc = subprocess.run([sys.executable, "-m", "delaycomp", "run", "example-3.6", "--set",
                           "T=0.5", "--set", "tau=0.7", "--engine", "inprocess"],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in proc.stderr
    assert "tau = 0.7 is not allowed" in lines[0] and "--set pad=1" in lines[0]


def test_fmu_refusal_says_what_pad_gives():
    from delaycomp.orchestrator.inprocess import SlaveComponent, SlaveRefused

    comp = SlaveComponent("c", "controller", {"n": 1, "m": 1})
    comp.setup(0.0, 1.0, {"T": 0.5, "tau": 0.7})
    with pytest.raises(SlaveRefused, match=r"multiple l\*T \(l >= 0\) of T = 0.5; pad = true "
                                           r"pads it up to 1.0 \(Remark 3.3\(b\)\)"):
        comp.initialize()


def test_state_saved_inside_the_padding_carries_the_pad_line():
    """Saved at t_1 + 0.1 (u_1 computed, not yet out), restored into a fresh controller:
    the same outputs after it."""
    from delaycomp.orchestrator.inprocess import SlaveComponent

    params = {"T": T, "r": R, "tau": TAU, "pad": True, "A[1,1]": 0.0, "A[1,2]": 1.0,
              "A[2,1]": 0.5, "A[2,2]": -0.2, "B[1,1]": 0.0, "B[2,1]": 1.0,
              "K[1,1]": -1.2, "K[1,2]": -1.5, "u0[1]": 0.3}
    h = T / N

    def fresh():
        c = SlaveComponent("c", "controller", {"n": 2, "m": 1})
        c.setup(0.0, 10.0, params)
        c.initialize()
        return c

    def drive(c, k0, k1):
        out = []
        for k in range(k0, k1):
            c.set_inputs(["y1", "y2"], [np.cos(k * h), np.sin(k * h)])
            out.append(c.get_outputs(["u"])[0])
            c.do_step(k * h, h)
        return out

    a = fresh()
    drive(a, 0, N + 2)  # t_1 = 0.5 committed, at 0.6 < 0.8 = t_1 + padding
    state = a.get_state()
    hidden = a.slave._hidden_state()
    assert hidden["released"] is False and len(hidden["ctrl"]["pad_line"]) == 1
    rest = drive(a, N + 2, 3 * N)
    b = fresh()
    b.set_state(state)
    assert drive(b, N + 2, 3 * N) == rest
    assert rest[0] == rest[D - 3] != rest[D - 2]  # u_0 until 0.8 = t_1 + padding, then u_1


# -- the native twins ---------------------------------------------------------------------
@pytest.mark.fmu
@pytest.mark.parametrize("fmi", [2, 3])
def test_native_equals_python_fmus(native_dir, fmu_dir, fmi):
    from delaycomp.fmu.twins import native_fmus

    spec = padded()
    native = run_loop(spec, STOP, fmus=native_fmus(spec, native_dir / f"pad{fmi}", fmi=fmi))
    python = run_loop(spec, STOP, fmu_dir / "cache") if fmi == 2 else run_loop(
        spec, STOP, engine="inprocess")
    assert native.success and python.success, (native.message, python.message)
    peak = np.max(np.abs(python.data), axis=0)
    assert np.all(np.abs(native.data - python.data) <= 1e-12 * peak)


@pytest.mark.fmu
def test_native_state_inside_the_padding_restores_bit_identically(native_dir):
    from delaycomp.fmu.twins import native_fmus

    from .test_native import _restore_run

    spec = padded()
    fmus = native_fmus(spec, native_dir / "pad2")
    first, second, third = _restore_run(fmus, spec, 3.0, N + 2)
    assert len(first) > 5
    assert second == first and third == first


# -- the Python API -----------------------------------------------------------------------
def test_api_lti_takes_pad():
    """``api.lti(..., pad=True)``: the loop of ``lti_loop(pad=True)``; the plant's state
    bit for bit that of the unpadded loop with ``tau = 1.0``; its loop-file data carries
    ``pad`` (a sweep of it rebuilds padded points); without ``pad`` the refusal names it."""
    from delaycomp import api

    kw = dict(T=T, r=R, N=N, x0=X0, u0=U0)
    loop = api.lti(A, B, K, tau=TAU, pad=True, **kw)
    assert loop.lti is not None and loop.lti.pad and loop.lti.tau == TAU
    assert loop.origin is not None and loop.origin.data["controller"]["pad"] is True
    res = api.run(loop, STOP, engine="inprocess")
    want = run_loop(padded(), STOP, engine="inprocess")
    assert np.array_equal(res.data, want.data)
    plain = api.run(api.lti(A, B, K, tau=TAU_EFF, **kw), STOP, engine="inprocess")
    assert np.array_equal(res.data[:, :2], plain.data[:, :2])
    assert "pad" not in api.lti(A, B, K, tau=TAU_EFF, **kw).origin.data["controller"]
    with pytest.raises(ParameterError, match=r"tau = 0.7 is not allowed: .*pad = true"):
        api.lti(A, B, K, tau=TAU, **kw)


# -- sweeps and the batch engine ----------------------------------------------------------
PADDED_SETS = ["T=0.5", "tau=0.7", "pad=1", "N=10"]


def test_a_sweep_runs_padded_points_on_the_per_point_engine():
    """The batch engine has no padded LTI controller: a sweep of a padded scenario (the
    default engine, batch) runs each point on the per-point engine, its notes saying why
    (before: every point refused, ``controller.pad = true is not supported by the batch
    engine yet``). Its rows are the unpadded ``tau = 1.0`` sweep's: the same arithmetic
    as the per-point engine's (the plant sees the same inputs), the batch engine's to its
    bound against the per-point engine (tests/test_batch.py's ``LTI_REL``), and with
    ``--exact`` the very same numbers."""
    from delaycomp import api

    from .roundoff import NATIVE_ULPS, SAME_ARITHMETIC_ULPS, assert_same_values
    from .test_batch import LTI_REL, assert_same

    grid = {"r": [0.0, 0.3]}
    notes: list[str] = []
    rows = api.sweep("example-3.6", grid, sets=PADDED_SETS, stop_time=8.0, notes=notes)
    # the fmu engine where the native FMUs and the native core are here, else in-process
    from delaycomp.orchestrator.native_core import core_status

    engine = "fmu" if core_status() is None else "inprocess"
    assert notes == ["batch engine (numpy, cpu): 0 of 2 points in 0 chunks",
                     f"per-point engine ({engine}): 2 points, because controller.pad = true "
                     "(the batch engine has no padded LTI controller)"], notes
    unpadded = ["T=0.5", "tau=1.0", "N=10"]
    per_point = api.sweep("example-3.6", grid, sets=unpadded, stop_time=8.0,
                          engine="inprocess")
    assert [row["r"] for row in rows] == [0.0, 0.3] and all(row["stable"] for row in rows)
    assert_same_values(rows, per_point,
                       NATIVE_ULPS if engine == "fmu" else SAME_ARITHMETIC_ULPS, "rows")
    batched = api.sweep("example-3.6", grid, sets=unpadded, stop_time=8.0)
    for got, want in zip(rows, batched):
        assert_same(got, want, LTI_REL)
    # --exact: the lifted loop of the padded delay (LtiDesign.equivalent), bit for bit
    assert api.sweep("example-3.6", grid, sets=PADDED_SETS, exact=True) == api.sweep(
        "example-3.6", grid, sets=unpadded, exact=True)


def test_the_cli_sweep_of_a_padded_scenario_runs(tmp_path):
    out = tmp_path / "s.csv"
    proc = subprocess.run([sys.executable, "-m", "delaycomp", "sweep", "example-3.6",
                           *(a for s in PADDED_SETS for a in ("--set", s)), "--grid",
                           "r=0:0.3:2", "--stop-time", "8", "--out", str(out), "-v"],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert re.search(r"per-point engine \((inprocess|fmu)\): 2 points, because "
                     r"controller.pad = true", proc.stderr + proc.stdout), proc.stderr
    assert len(out.read_text().splitlines()) == 3


def test_the_batch_engine_takes_no_padded_loop_and_says_why(tmp_path):
    """No design for the batch engine (``loopfile.design``: ``None``, the point's loop
    built instead), ``lti_point``'s reason names pad; ``robustness`` (the batch engine
    only) refuses a padded loop file in one line naming it."""
    from delaycomp.paper import scenarios
    from delaycomp.studies.sweep_batch import lti_point

    sc = scenarios.get("example-3.6")
    params = sc.resolve(PADDED_SETS)
    assert sc.design(params) is None and sc.designs([params]) is None
    assert sc.design(sc.resolve(["T=0.5", "tau=1.0", "N=10"])) is not None
    assert lti_point(sc.make(params)) == ("controller.pad = true (the batch engine has no "
                                          "padded LTI controller)")
    path = tmp_path / "pad.toml"
    path.write_text("T = 0.5\nN = 10\nr = 0.2\ntau = 0.7\nstop_time = 4.0\n[plant]\n"
                    "A = [[0.0, 1.0], [0.5, -0.2]]\nB = [[0.0], [1.0]]\nx0 = [1.0, -0.5]\n"
                    "[controller]\nK = [[-1.2, -1.5]]\npad = true\n", encoding="utf-8")
    proc = subprocess.run([sys.executable, "-m", "delaycomp", "robustness", str(path),
                           "--jitter", "0:0.1:2", "--loss", "0:0.1:2", "--runs", "2",
                           "--out", str(tmp_path / "rob.csv")],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert "robustness takes an LTI loop" in lines[0] and "controller.pad = true" in lines[0]
    assert not (tmp_path / "rob.csv").exists()
