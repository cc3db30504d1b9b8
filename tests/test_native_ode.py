"""The C integrator ``fmus/native/ode.c`` (DOP853), through ctypes.

``ode.c`` and the right-hand sides of ``tests/native_ode/rhs.c`` are compiled into a
shared library with the project's C compiler (``-Wall -Wextra -Werror``). What is checked,
and why each tolerance:

- against exact solutions (``expm`` for linear systems, closed forms for ``x' = x^2``,
  ``x' = -x^3``, the pendulum's energy) and against an independent solve much tighter than
  the tolerance (``solve_ivp``, DOP853 at 1e-13) for Van der Pol: DOP853 controls the local
  error per step to ``tol`` in its scaled norm, so the global error over a few time units is
  a modest multiple of ``tol`` times the size of the solution (the multiple depends on how
  the flow amplifies errors made along the way). Measured, relative to the solution's
  size: at most 0.18 ``tol`` on the linear systems, 2.8 ``tol`` on the closed forms, 0.54
  ``tol`` on Van der Pol (4.7 ``tol`` with scipy's rejection rule, as scipy itself); the
  bounds below are 10 and 50 ``tol``;
- against scipy's ``ode(...).set_integrator("dop853")`` (the solver of
  ``delaycomp.maths.predictors.integrate``) at the same tolerances: the same method, initial step
  and step control, so on a problem whose steps are all accepted the same steps are taken
  and the states differ by rounding only (measured <= 3e-15 relative, bound 1e-13);
  scipy 1.17's C translation retries a rejected step with ``0.3 h`` where Hairer's rule is
  ``h / min(1/0.3, err^(1/8) / 0.9)``, so after a rejection the steps differ: the build
  with ``-DODE_REJECT_LIKE_SCIPY_1_17`` takes scipy's steps exactly (Van der Pol: the same
  accepted steps, states within 1e-12, measured 2.4e-14), and both builds stay within the
  error bound against the independent solve;
- failures give DOP853's reason (or ours) and leave the state unchanged; the work memory of
  ``ode_work_size(n)`` doubles is enough (valgrind on a C driver, ``tests/native_ode/``).
"""

from __future__ import annotations

import ctypes
import subprocess
import warnings
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import ode, solve_ivp
from scipy.linalg import expm

from delaycomp.fmu.native import SOURCE_DIR, compiler
from delaycomp.maths.predictors import integrate

from .external import need

HERE = Path(__file__).resolve().parent / "native_ode"
FLAGS = ["-std=c11", "-O2", "-fPIC", "-Wall", "-Wextra", "-Werror"]
TOLS = (1e-10, 1e-6)
LINEAR, SQUARE, CUBE, PENDULUM, VAN_DER_POL, FAILS, NAN = range(7)
OK, BAD_INPUT, MAX_STEPS, TOO_SMALL, STIFF, NOT_FINITE, RHS_FAILED = 0, -1, -2, -3, -4, -5, -6


class Report(ctypes.Structure):
    """``OdeReport`` of ``ode.h``."""

    _fields_ = [("code", ctypes.c_int), ("reason", ctypes.c_char_p),
                ("steps", ctypes.c_long), ("accepted", ctypes.c_long),
                ("rejected", ctypes.c_long), ("evaluations", ctypes.c_long),
                ("t", ctypes.c_double), ("h", ctypes.c_double), ("scale", ctypes.c_double)]


def _build(out: Path, defines: tuple[str, ...] = ()) -> ctypes.CDLL:
    """Compile ``ode.c`` with the test right-hand sides into ``out`` and load it.

    Parameters
    ----------
    out : pathlib.Path
        The shared library to write.
    defines : tuple of str
        Extra ``-D`` flags.

    Returns
    -------
    ctypes.CDLL
        The library, with ``solve`` and ``ode_work_size`` typed.
    """
    subprocess.run([*compiler(), *FLAGS, *defines, "-shared", f"-I{SOURCE_DIR}", f"-I{HERE}",
                    "-o", str(out), str(SOURCE_DIR / "ode.c"), str(HERE / "rhs.c"), "-lm"],
                   check=True, capture_output=True)
    lib = ctypes.CDLL(str(out))
    dp = ctypes.POINTER(ctypes.c_double)
    lib.solve.argtypes = [ctypes.c_int, ctypes.c_size_t, dp, dp, ctypes.c_double,
                          ctypes.c_double, ctypes.c_double, ctypes.c_long, ctypes.c_double,
                          ctypes.POINTER(Report), ctypes.POINTER(ctypes.c_long)]
    lib.solve.restype = ctypes.c_int
    lib.ode_work_size.argtypes = [ctypes.c_size_t]
    lib.ode_work_size.restype = ctypes.c_size_t
    return lib


@pytest.fixture(scope="module")
def libs(tmp_path_factory) -> dict[str, ctypes.CDLL]:
    tmp = tmp_path_factory.mktemp("ode")
    return {"hairer": _build(tmp / "libode.so"),
            "scipy-1.17": _build(tmp / "libode_scipy.so", ("-DODE_REJECT_LIKE_SCIPY_1_17",))}


@pytest.fixture(scope="module")
def lib(libs) -> ctypes.CDLL:
    return libs["hairer"]


def native(lib, which: int, x0, p, duration: float, tol: float, max_steps: int = 100_000,
           u_size: float = 0.0):
    """``ode_solve`` on one of ``rhs.c``'s right-hand sides.

    Parameters
    ----------
    lib : ctypes.CDLL
        A library from ``_build``.
    which : int
        The right-hand side (``RHS_*`` of ``rhs.h``).
    x0, p : array_like
        Initial state, parameters of the right-hand side.
    duration, tol : float
        The segment; rtol = atol = tol.
    max_steps : int
        The step budget.
    u_size : float
        The largest input magnitude (for the scaling of tiny states).

    Returns
    -------
    tuple
        ``(code, x, report, calls of f)``.
    """
    x = np.array(x0, dtype=float)
    p = np.ascontiguousarray(p if len(p) else [0.0], dtype=float)
    report, calls = Report(), ctypes.c_long()
    dp = ctypes.POINTER(ctypes.c_double)
    code = lib.solve(which, len(x), p.ctypes.data_as(dp), x.ctypes.data_as(dp), duration,
                     tol, tol, max_steps, u_size, ctypes.byref(report), ctypes.byref(calls))
    return code, x, report, calls.value


def scipy_dop853(fun, x0, duration: float, tol: float, nsteps: int = 100_000):
    """scipy's DOP853 as ``delaycomp.maths.predictors`` runs it: ``(code, x, accepted steps)``."""
    times = []
    solver = ode(lambda _t, y: fun(y)).set_integrator("dop853", rtol=tol, atol=tol,
                                                     nsteps=nsteps)
    solver.set_solout(lambda t, _y: times.append(t))
    solver.set_initial_value(np.array(x0, dtype=float), 0.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        x = solver.integrate(duration)
    return solver.get_return_code(), x, len(times) - 1  # solout is called at t0 too


def random_linear(seed: int, n: int):
    """A random ``A`` (spectral radius about 1), input ``b`` and state."""
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(n, n)) / np.sqrt(n)
    return A, rng.normal(size=n), rng.normal(size=n)


def linear_exact(A, b, x0, t):
    """``x(t)`` of ``x' = A x + b`` by the augmented matrix exponential."""
    n = len(x0)
    M = np.zeros((n + 1, n + 1))
    M[:n, :n], M[:n, n] = A, b
    return (expm(M * t) @ np.append(x0, 1.0))[:n]


def vdp(z, mu=1.0):
    return np.array([z[1], mu * (1.0 - z[0] ** 2) * z[1] - z[0]])


# -- accuracy ---------------------------------------------------------------------------
@pytest.mark.parametrize("tol", TOLS)
@pytest.mark.parametrize("seed,n", [(1, 1), (2, 2), (3, 3), (4, 5), (5, 8)])
def test_linear_against_expm(lib, tol, seed, n):
    A, b, x0 = random_linear(seed, n)
    code, x, report, calls = native(lib, LINEAR, x0, np.concatenate([A.ravel(), b]), 2.0,
                                    tol)
    assert code == OK and report.reason == b""
    exact = linear_exact(A, b, x0, 2.0)
    assert np.max(np.abs(x - exact)) <= 10 * tol * max(1.0, np.max(np.abs(exact)))
    assert report.evaluations == calls == 2 + 12 * report.accepted + 11 * report.rejected
    assert report.t == pytest.approx(2.0, rel=1e-15)


@pytest.mark.parametrize("tol", TOLS)
def test_closed_forms(lib, tol):
    # x' = x^2, x(0) = 1: x(t) = 1 / (1 - t); at t = 0.9, 10 (and x'' grows like x^3)
    code, x, _, _ = native(lib, SQUARE, [1.0], [], 0.9, tol)
    assert code == OK and abs(x[0] - 10.0) <= 10 * tol * 10.0
    # x' = -x^3, x(0) = 2: x(t) = 2 / sqrt(1 + 8 t)
    code, x, _, _ = native(lib, CUBE, [2.0], [], 5.0, tol)
    assert code == OK and abs(x[0] - 2.0 / np.sqrt(41.0)) <= 10 * tol
    # the pendulum x0'' = -sin x0 keeps E = x1^2 / 2 - cos x0 (10 time units, ~1.5 swings)
    code, x, _, _ = native(lib, PENDULUM, [2.0, 0.0], [1.0], 10.0, tol)
    assert code == OK
    assert abs(x[1] ** 2 / 2 - np.cos(x[0]) + np.cos(2.0)) <= 10 * tol


@pytest.mark.parametrize("tol", TOLS)
def test_van_der_pol_against_a_tight_solve(libs, tol):
    ref = solve_ivp(lambda _t, z: vdp(z), (0.0, 20.0), [2.0, 0.0], method="DOP853",
                    rtol=1e-13, atol=1e-13).y[:, -1]
    for lib in libs.values():
        code, x, report, _ = native(lib, VAN_DER_POL, [2.0, 0.0], [1.0], 20.0, tol)
        assert code == OK and report.rejected > 0
        # two limit-cycle periods; measured 0.54 tol (Hairer's rule) and 4.7 tol (scipy's)
        assert np.max(np.abs(x - ref)) <= 50 * tol * np.max(np.abs(ref))


def test_n_40(lib):
    A, b, x0 = random_linear(40, 40)
    A -= 0.5 * np.eye(40)
    code, x, _, _ = native(lib, LINEAR, x0, np.concatenate([A.ravel(), b]), 1.0, 1e-10)
    exact = linear_exact(A, b, x0, 1.0)
    assert code == OK and np.max(np.abs(x - exact)) <= 1e-9 * np.max(np.abs(exact))
    assert lib.ode_work_size(40) == 17 * 40


def test_tiny_state_is_scaled_like_predictors(lib):
    """A state near 1e-150: ode.c solves it scaled by a power of two, as
    ``predictors._scaled_segment`` does (the squared scaled errors would underflow)."""
    x0 = np.array([1e-150, -3e-151])
    A = np.array([[-1.0, 0.5], [-0.5, -1.0]])
    code, x, report, _ = native(lib, LINEAR, x0, np.concatenate([A.ravel(), [0, 0]]), 3.0,
                                1e-10)
    assert code == OK and report.scale == 2.0 ** round(np.log2(1e-150))
    exact = expm(3.0 * A) @ x0
    assert np.max(np.abs(x - exact)) <= 1e-9 * np.max(np.abs(x0))
    python = integrate(lambda z, u, p: A @ z + u, {}, x0, [(3.0, np.zeros(2))])
    # the same scaled ODE, no rejections: the same steps; rounding only
    assert np.max(np.abs(x - python)) <= 1e-13 * np.max(np.abs(x0))
    # an input above the threshold keeps the state unscaled, as in Python: then the
    # squared scaled errors underflow and the step control fails, as scipy's does (Python
    # retries such a segment with solve_ivp; ode.c has no second solver)
    code, x, report, _ = native(lib, LINEAR, x0, np.concatenate([A.ravel(), [0, 0]]), 3.0,
                                1e-10, u_size=1.0)
    assert (code, report.scale, list(x)) == (TOO_SMALL, 1.0, list(x0))


# -- agreement with scipy's DOP853 --------------------------------------------------------
@pytest.mark.parametrize("tol", TOLS)
@pytest.mark.parametrize("seed,n", [(1, 1), (2, 2), (3, 3), (4, 5), (5, 8)])
def test_same_steps_as_scipy_without_rejections(libs, tol, seed, n):
    A, b, x0 = random_linear(seed, n)
    expected = scipy_dop853(lambda z: A @ z + b, x0, 2.0, tol)
    for lib in libs.values():
        code, x, report, _ = native(lib, LINEAR, x0, np.concatenate([A.ravel(), b]), 2.0,
                                    tol)
        assert report.rejected == 0  # else the two rejection rules could differ
        assert (code, report.accepted) == (OK, expected[2]) and expected[0] == 1
        # same steps, same formulas, sums in the same order: measured <= 3e-15
        assert np.max(np.abs(x - expected[1])) <= 1e-13 * max(1.0, np.max(np.abs(x)))


@pytest.mark.parametrize("tol", TOLS)
def test_steps_after_rejections_like_scipy(libs, tol):
    """Van der Pol rejects steps. One build takes scipy's very steps: the one with scipy
    1.17's rule (0.3 h), or Hairer's, which earlier scipy (Fortran) used."""
    expected = scipy_dop853(vdp, [2.0, 0.0], 20.0, tol)
    runs = {name: native(lib, VAN_DER_POL, [2.0, 0.0], [1.0], 20.0, tol)
            for name, lib in libs.items()}
    same = [name for name, run in runs.items() if run[2].accepted == expected[2]]
    assert same, {name: run[2].accepted for name, run in runs.items()}
    code, x, _, _ = runs[same[0]]
    assert code == OK and expected[0] == 1
    # the same steps: rounding only (measured 2.4e-14 at 1e-10, 0 at 1e-6)
    assert np.max(np.abs(x - expected[1])) <= 1e-12


# -- failures -----------------------------------------------------------------------------
def test_rhs_fails(lib):
    code, x, report, calls = native(lib, FAILS, [1.0, 2.0], [30.0], 5.0, 1e-10)
    assert code == RHS_FAILED and report.reason == b"the model's f failed"
    assert list(x) == [1.0, 2.0] and report.evaluations == calls == 30
    code, x, report, calls = native(lib, FAILS, [1.0], [1.0], 5.0, 1e-10)  # the first call
    assert code == RHS_FAILED and calls == 1 and x[0] == 1.0


def test_blow_up(lib):
    code, x, report, _ = native(lib, SQUARE, [1.0], [], 2.0, 1e-10)
    assert (code, report.reason) == (TOO_SMALL, b"step size becomes too small")
    assert x[0] == 1.0 and abs(report.t - 1.0) < 1e-6  # stuck at the singularity t = 1
    assert scipy_dop853(lambda z: z * z, [1.0], 2.0, 1e-10)[0] == TOO_SMALL


def test_max_steps(lib):
    code, x, report, _ = native(lib, VAN_DER_POL, [2.0, 0.0], [1.0], 20.0, 1e-10,
                                max_steps=10)
    assert (code, report.reason) == (MAX_STEPS, b"larger nsteps is needed")
    assert list(x) == [2.0, 0.0] and report.steps == 11  # DOP853 tries nmax + 1 steps
    assert scipy_dop853(vdp, [2.0, 0.0], 20.0, 1e-10, nsteps=10)[0] == MAX_STEPS


def test_stiff(lib):
    lam = 1e4
    code, x, report, _ = native(lib, LINEAR, [1.0], [-lam, 0.0], 10.0, 1e-6)
    assert (code, report.reason) == (STIFF, b"problem is probably stiff (interrupted)")
    assert x[0] == 1.0 and report.accepted > 1000
    assert scipy_dop853(lambda z: -lam * z, [1.0], 10.0, 1e-6)[0] == STIFF


def test_not_finite(lib):
    # f gives NaN from x = 0.5: every step reaching it is rejected until h is too small
    code, x, report, _ = native(lib, NAN, [0.0], [0.5], 1.0, 1e-10)
    assert code == TOO_SMALL and x[0] == 0.0 and 0.49 < report.t <= 0.5
    code, x, report, _ = native(lib, LINEAR, [np.inf], [-1.0, 0.0], 1.0, 1e-10)
    assert (code, report.reason) == (NOT_FINITE, b"the state is not finite")


def test_no_ops_and_bad_input(lib):
    for duration in (0.0, -1.0):
        code, x, report, calls = native(lib, LINEAR, [3.0], [-1.0, 0.0], duration, 1e-10)
        assert (code, x[0], calls, report.steps) == (OK, 3.0, 0, 0)
    for duration, tol, max_steps in [(np.nan, 1e-10, 10), (np.inf, 1e-10, 10),
                                     (1.0, 0.0, 10), (1.0, 1e-20, 10), (1.0, 1e-10, 0)]:
        code, x, report, calls = native(lib, LINEAR, [3.0], [-1.0, 0.0], duration, tol,
                                        max_steps)
        assert (code, report.reason, x[0], calls) == (BAD_INPUT, b"input is not consistent",
                                                      3.0, 0)


# -- memory -------------------------------------------------------------------------------
def test_valgrind(tmp_path):
    valgrind = need("valgrind")
    exe = tmp_path / "driver"
    subprocess.run([*compiler(), *FLAGS[:2], "-g", *FLAGS[3:], f"-I{SOURCE_DIR}",
                    f"-I{HERE}", "-o", str(exe), str(SOURCE_DIR / "ode.c"),
                    str(HERE / "rhs.c"), str(HERE / "driver.c"), "-lm"],
                   check=True, capture_output=True)
    run = subprocess.run([valgrind, "-q", "--error-exitcode=1", "--leak-check=full",
                          str(exe)], capture_output=True, text=True)
    assert run.returncode == 0, run.stdout + run.stderr
    assert "0 failures" in run.stdout
